"""stdlib registration (docs/stdlib.md#registration-order), plus the helpers the stdlib tests share.

The other tests/test_stdlib_*.py files import `make_vm`, `call` and `buzz_fn` from here.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from bvm.errors import BuzzError
from bvm.stdlib import install
from bvm.stdlib.rng import MersenneTwister
from bvm.values import Closure, Table, format_value
from bvm.vm import VM


def make_vm(robot_id: int = 1, rng_seed: int | None = 0) -> VM:
    """A VM with the standard library installed (no program needed for calling natives)."""
    vm = VM(robot_id, rng_seed=rng_seed)
    install(vm)
    return vm


def lookup(vm: Any, path: str) -> Any:
    """The value at a dotted global path such as "math.rng.uniform"."""
    first, *rest = path.split(".")
    v = vm.globals[first]
    for k in rest:
        v = v[k]
    return v


def call(vm: Any, path: str, *args: Any) -> Any:
    """Call the function at a dotted global path with Buzz arguments."""
    return vm.call_closure(lookup(vm, path), *args)


def buzz_fn(f: Callable[..., Any], self_value: Any = None) -> Closure:
    """A stand-in for a bytecode closure: calling it runs f(*args)."""
    return Closure(4242, False, (self_value,), lambda c, *args: f(*args))


# ---------------------------------------------------------------- the tests

EXPECTED_IDS = {
    "neighbors.get": 0,
    "neighbors.filter": 1,
    "neighbors.kin": 2,
    "neighbors.nonkin": 3,
    "neighbors.foreach": 4,
    "neighbors.map": 5,
    "neighbors.reduce": 6,
    "neighbors.count": 7,
    "neighbors.broadcast": 8,
    "neighbors.listen": 9,
    "neighbors.ignore": 10,
    "type": 11,
    "int": 12,
    "float": 13,
    "clone": 14,
    "size": 15,
    "foreach": 16,
    "map": 17,
    "reduce": 18,
    "filter": 19,
    "isnil": 20,
    "isint": 21,
    "isfloat": 22,
    "isstring": 23,
    "istable": 24,
    "isclosure": 25,
    "isuserdata": 26,
    "stigmergy.create": 27,
    "swarm.create": 28,
    "swarm.union": 29,
    "swarm.intersection": 30,
    "swarm.difference": 31,
    "swarm.id": 32,
    "math.abs": 33,
    "math.floor": 34,
    "math.ceil": 35,
    "math.round": 36,
    "math.log": 37,
    "math.log2": 38,
    "math.log10": 39,
    "math.exp": 40,
    "math.sqrt": 41,
    "math.sin": 42,
    "math.cos": 43,
    "math.tan": 44,
    "math.asin": 45,
    "math.acos": 46,
    "math.atan": 47,
    "math.min": 48,
    "math.max": 49,
    "math.rng.setseed": 50,
    "math.rng.uniform": 51,
    "math.rng.gaussian": 52,
    "math.rng.exponential": 53,
    "io.fopen": 54,
    "io.fclose": 55,
    "io.fsize": 56,
    "io.fforeach": 57,
    "io.fwrite": 58,
    "string.length": 59,
    "string.sub": 60,
    "string.concat": 61,
    "string.tostring": 62,
    "string.toint": 63,
    "string.tofloat": 64,
}


@pytest.mark.parametrize("path,fid", sorted(EXPECTED_IDS.items(), key=lambda kv: kv[1]))
def test_c_function_ids_follow_the_reference_order(path: str, fid: int) -> None:
    vm = make_vm()
    c = lookup(vm, path)
    assert c.__class__ is Closure and c.native
    assert c.ref == fid
    assert format_value(c) == f"[c-closure @{fid}]"
    assert vm.natives[fid].ref == fid and vm.natives[fid].fn is c.fn


def test_the_library_takes_ids_0_to_64_and_the_next_id_is_65() -> None:
    vm = make_vm()
    assert len(vm.natives) == 65
    assert None not in vm.natives
    log = vm.new_native(lambda _self, *args: None, None, "log")
    assert log.ref == 65  # bzzrun's `log`


def test_global_and_table_key_order() -> None:
    vm = make_vm()
    assert [k for k in vm.globals if not k.startswith("_")] == [
        "neighbors",
        "id",
        *[k for k in EXPECTED_IDS if "." not in k],
        "stigmergy",
        "swarm",
        "math",
        "io",
        "string",
    ]
    assert list(vm.globals["math"]) == [
        *[k.split(".")[1] for k in EXPECTED_IDS if k.startswith("math.") and k.count(".") == 1],
        "pi",
        "rng",
    ]
    assert list(vm.globals["math"]["rng"]) == ["setseed", "uniform", "gaussian", "exponential"]
    assert list(vm.globals["io"]) == [
        "fopen",
        "fclose",
        "fsize",
        "fforeach",
        "fwrite",
        "errno",
        "error_message",
    ]
    assert vm.globals["io"]["errno"] == 0
    assert vm.globals["io"]["error_message"] == "No error"
    assert list(vm.globals["string"]) == [
        "length",
        "sub",
        "concat",
        "tostring",
        "toint",
        "tofloat",
    ]


def test_every_table_is_a_buzz_table() -> None:
    vm = make_vm()
    for name in ("math", "io", "string"):
        assert vm.globals[name].__class__ is Table
    assert vm.globals["math"]["rng"].__class__ is Table


def test_methods_are_bound_to_their_table_and_globals_to_nil() -> None:
    vm = make_vm()
    for path in EXPECTED_IDS:
        c = lookup(vm, path)
        owner = lookup(vm, path.rsplit(".", 1)[0]) if "." in path else None
        assert c.actrec[0] is owner, path


@pytest.mark.parametrize("rid", [0, 1, 7, 65535])
def test_id_is_the_robot_id(rid: int) -> None:
    assert make_vm(robot_id=rid).globals["id"] == rid


def test_rng_is_seeded_from_rng_seed() -> None:
    vm = make_vm(rng_seed=5)
    assert isinstance(vm.rng, MersenneTwister)
    assert call(vm, "math.rng.uniform") == -1327749956


def test_rng_seed_none_uses_the_unix_time(monkeypatch: pytest.MonkeyPatch) -> None:
    import bvm.stdlib.mathlib as mathlib

    monkeypatch.setattr(mathlib.time, "time", lambda: 5.75)
    vm = make_vm(rng_seed=None)
    assert call(vm, "math.rng.uniform") == -1327749956


def test_each_vm_has_its_own_generator() -> None:
    a, b = make_vm(rng_seed=9), make_vm(rng_seed=9)
    first = call(a, "math.rng.uniform")
    call(a, "math.rng.uniform")
    assert call(b, "math.rng.uniform") == first


def test_fixed_arity_is_checked_by_the_vm() -> None:
    vm = make_vm()
    with pytest.raises(BuzzError, match="expected 1 parameters, got 2"):
        call(vm, "type", 1, 2)
