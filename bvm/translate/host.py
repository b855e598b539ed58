"""What the translator needs of the VM it translates for."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

from bvm.program import Program


class FunctionEntry(Protocol):
    """The way into one bytecode function (bvm.vm.Entry)."""

    #: What a new closure of the function calls.
    fn: Callable[..., Any]

    def call_general(self, closure: Any, *args: Any) -> Any:
        """Where a specialized translation sends the calls its entry guard rejects."""
        ...


class TranslatorHost(Protocol):
    """The VM, as the translator sees it: the program, its globals and natives, and the
    entries that translated code calls into."""

    program: Program | None

    @property
    def globals(self) -> Mapping[str, Any]:
        """The Buzz globals; their values at translation time guide direct native calls."""
        ...

    def native_impl(self, fid: int) -> tuple[Callable[..., Any] | None, int | None]:
        """The implementation and fixed arity (None: any) of host function `fid`."""
        ...

    def entry(self, addr: int, n_actrec: int) -> FunctionEntry:
        """The shared entry of the bytecode function at `addr` for `n_actrec` slots."""
        ...

    def namespace(self) -> dict[str, Any]:
        """The module globals translated code runs in."""
        ...

    def member(self, table: Any, key: Any) -> Any:
        """`table.get(key)` of a table read earlier (a recording host notes the read)."""
        ...

    def path_of(self, value: Any) -> tuple[Any, ...] | None:
        """How a recording host read `value`; None for any other host."""
        ...
