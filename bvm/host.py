"""What the standard library and the network layer need of the VM that hosts them.

`bvm.vm.VM` is the one implementation; the library modules and bvm/network.py are typed
against this protocol so the surface they use is written down in one place.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from bvm.network import Network
    from bvm.program import Program
    from bvm.stdlib.neighbors import Neighbors
    from bvm.stdlib.rng import MersenneTwister
    from bvm.stdlib.stigmergy import Stigmergies
    from bvm.stdlib.swarm import Swarms
    from bvm.values import Closure


class LibraryHost(Protocol):
    """The VM as its library sees it: identity, globals, natives, calls and swarm state."""

    #: This robot's id (u16), the `id` global.
    robot_id: int
    #: The seed `math.rng` starts from (None: the time, as the reference).
    rng_seed: int | None
    #: The generator behind `math.rng` (made by the math library's registration).
    rng: MersenneTwister
    #: The Buzz globals.
    globals: dict[str, Any]
    #: The loaded program (None before `load`).
    program: Program | None
    #: Host closures by C-function id (None for reserved ids).
    natives: list[Closure | None]
    net: Network
    neighbors: Neighbors
    stigmergies: Stigmergies
    swarms: Swarms

    def new_native(self, impl: Callable[..., Any], arity: int | None, name: str) -> Closure:
        """A host closure with the next C-function id."""
        ...

    def native_closure(self, fid: int) -> Closure:
        """The closure of host function `fid`."""
        ...

    def make_closure(self, addr: int, actrec: tuple[Any, ...]) -> Closure:
        """A bytecode closure at `addr` capturing `actrec`."""
        ...

    def call_closure(self, c: Any, *args: Any) -> Any:
        """Call a Buzz value with Buzz arguments; returns a Buzz value."""
        ...

    def invoke(self, c: Any, args: tuple[Any, ...]) -> Any:
        """Call `c(*args)` with Buzz semantics for non-closures and argument counts."""
        ...

    def call_failed(self, e: Exception, c: Any, args: tuple[Any, ...]) -> Any:
        """Tell a failed call from an error raised inside the callee (see VM.call_failed)."""
        ...
