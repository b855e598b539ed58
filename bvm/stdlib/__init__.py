"""The Buzz standard library (docs/stdlib.md): `install(vm)` registers it into a VM's globals.

Registration follows the reference order (docs/stdlib.md#registration-order) exactly, because
C-function ids are
handed out in registration order and show up when a closure is printed (`[c-closure @N]`):

    neighbors 0-10 | id | type int float clone size foreach map reduce filter 11-19,
    isnil isint isfloat isstring istable isclosure isuserdata 20-26 | stigmergy 27 |
    swarm 28-32 | math 33-49, math.rng 50-53 | io 54-58 | string 59-64

so the host's first own native (bzzrun's `log`) gets id 65.

The VM interface used is `bvm.host.LibraryHost`: `vm.new_native(impl, arity, name)`,
`vm.call_closure(c, *args)`, `vm.globals`, `vm.robot_id`, `vm.rng_seed`, and the swarm
primitives' state objects `vm.neighbors`, `vm.stigmergies`, `vm.swarms`
(bvm/stdlib/neighbors.py, stigmergy.py, swarm.py); `install` sets `vm.rng` (the
`MersenneTwister` behind `math.rng`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from bvm.stdlib import base, iolib, mathlib, stringlib

if TYPE_CHECKING:
    from bvm.host import LibraryHost

__all__ = ["install"]


def install(vm: LibraryHost) -> None:
    """Register the standard library into `vm.globals`, in the reference order (see above)."""
    vm.neighbors.register()  # get filter kin nonkin foreach map reduce count
    # broadcast listen ignore, ids 0-10
    vm.globals["id"] = vm.robot_id
    base.register(vm)  # type ... isuserdata, ids 11-26
    vm.stigmergies.register()  # stigmergy.create, id 27
    vm.swarms.register()  # swarm.create union intersection difference id, ids 28-32
    mathlib.register(vm)  # math 33-49, math.rng 50-53 (creates vm.rng)
    iolib.register(vm)  # io 54-58
    stringlib.register(vm)  # string 59-64
