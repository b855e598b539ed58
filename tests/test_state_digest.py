"""The script-state digest a recording keeps per tick: equal for equal states, in any VM."""

from __future__ import annotations

import bvm
from bvm.digest import state_digest

SRC = """
t = {.a = 1, .b = {.c = 2.5, .d = "x"}}
t.self = t
f = function(x) { return x + 1 }
n = 0
function step() { n = n + 1  t.b.c = t.b.c * 2 }
"""


def vm_of(src: str = SRC) -> bvm.VM:
    vm = bvm.VM(robot_id=1, rng_seed=0)
    vm.load(bvm.compile_source(src, "s.bzz"))
    vm.execute()
    return vm


def test_two_vms_that_ran_the_same_have_the_same_digest() -> None:
    a, b = vm_of(), vm_of()
    assert state_digest(a) == state_digest(b) and len(state_digest(a)) == 32
    a.call("step")
    assert state_digest(a) != state_digest(b)
    b.call("step")
    assert state_digest(a) == state_digest(b)  # closures by code address, cycles by order


def test_any_nested_change_changes_it_and_host_functions_do_not() -> None:
    vm = vm_of()
    before = state_digest(vm)
    vm.globals["t"]["b"]["d"] = "y"
    assert state_digest(vm) != before
    vm.globals["t"]["b"]["d"] = "x"
    assert state_digest(vm) == before
    vm.globals["n"] = 0.0  # a float is not the int it equals
    assert state_digest(vm) != before
    vm.globals["n"] = 0
    vm.globals["hostfn"] = bvm.values.Closure(7, True, (None,), lambda *a: None)
    assert state_digest(vm) == before
