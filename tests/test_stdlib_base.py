"""Base functions: type, int, float, clone, size, foreach, map, reduce, filter, is*.

Facts: docs/stdlib.md#base-functions.
"""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bvm.errors import BuzzError
from bvm.stdlib import base
from bvm.values import INT_MIN, Closure, Table, Userdata, f32

try:
    from test_stdlib_install import buzz_fn, call, make_vm
except ImportError:  # tests/ imported as a package
    from tests.test_stdlib_install import buzz_fn, call, make_vm


@pytest.fixture
def vm() -> Any:
    return make_vm()


def T(*pairs: Any, **named: Any) -> Table:
    """A table from (key, value) pairs and keyword entries, in that order."""
    t = Table()
    for k, v in pairs:
        t[k] = v
    t.update(named)
    return t


CLOSURE = Closure(12, False, (None,), lambda actrec: None)
USERDATA = Userdata(object())
ALL = [
    (None, "nil"),
    (3, "integer"),
    (2.5, "float"),
    ("s", "string"),
    (Table(), "table"),
    (CLOSURE, "closure"),
    (USERDATA, "userdata"),
]


# ---------------------------------------------------------------- type, is*


@pytest.mark.parametrize("value,name", ALL)
def test_type(vm: Any, value: Any, name: str) -> None:
    r = call(vm, "type", value)
    assert r == name and r.__class__ is str


PREDICATES = {
    "isnil": "nil",
    "isint": "integer",
    "isfloat": "float",
    "isstring": "string",
    "istable": "table",
    "isclosure": "closure",
    "isuserdata": "userdata",
}


@pytest.mark.parametrize("pred", PREDICATES)
@pytest.mark.parametrize("value,name", ALL)
def test_is_predicates(vm: Any, pred: str, value: Any, name: str) -> None:
    r = call(vm, pred, value)
    assert r.__class__ is int
    assert r == (1 if PREDICATES[pred] == name else 0)


def test_is_predicates_on_falsy_values(vm: Any) -> None:
    assert call(vm, "isint", 0) == 1
    assert call(vm, "isfloat", 0.0) == 1
    assert call(vm, "isstring", "") == 1
    assert call(vm, "isclosure", call(vm, "type", 1)) == 0
    assert call(vm, "isclosure", vm.globals["type"]) == 1


# ---------------------------------------------------------------- int, float


@pytest.mark.parametrize(
    "x,expected",
    [
        (2.7, 2),
        (-2.7, -2),
        (-0.5, 0),
        (0.0, 0),
        (-0.0, 0),
        (2147483520.0, 2147483520),  # the largest float32 below 2^31
        (-2147483648.0, INT_MIN),
        (2147483648.0, INT_MIN),
        (-2147483904.0, INT_MIN),
        (math.inf, INT_MIN),
        (-math.inf, INT_MIN),
        (math.nan, INT_MIN),
    ],
)
def test_int_truncates_like_x86(vm: Any, x: float, expected: int) -> None:
    r = call(vm, "int", x)
    assert r == expected and r.__class__ is int


@pytest.mark.parametrize("x", [0, 5, -5, INT_MIN, 2147483647])
def test_int_of_an_int_is_the_int(vm: Any, x: int) -> None:
    assert call(vm, "int", x) == x


@pytest.mark.parametrize("value,name", [v for v in ALL if v[1] not in ("integer", "float")])
def test_int_type_errors(vm: Any, value: Any, name: str) -> None:
    with pytest.raises(BuzzError) as e:
        call(vm, "int", value)
    assert e.value.message == f"type mismatch: expected float, got {name}"


@pytest.mark.parametrize(
    "x,expected",
    [(0, 0.0), (7, 7.0), (-3, -3.0), (16777217, 16777216.0), (2147483647, 2147483648.0)],
)
def test_float_converts_to_binary32(vm: Any, x: int, expected: float) -> None:
    r = call(vm, "float", x)
    assert r == expected and r.__class__ is float


@pytest.mark.parametrize("x", [0.0, 1.5, -2.25, math.inf])
def test_float_of_a_float_is_the_float(vm: Any, x: float) -> None:
    assert call(vm, "float", x) == x


def test_float_of_nan_is_nan(vm: Any) -> None:
    assert math.isnan(call(vm, "float", math.nan))


@pytest.mark.parametrize("value,name", [v for v in ALL if v[1] not in ("integer", "float")])
def test_float_type_errors(vm: Any, value: Any, name: str) -> None:
    with pytest.raises(BuzzError) as e:
        call(vm, "float", value)
    assert e.value.message == f"type mismatch: expected integer, got {name}"


@given(st.integers(-(2**31), 2**31 - 1))
def test_float_then_int_property(i: int) -> None:
    f = base.b_float(None, i)
    assert f32(f) == f
    assert base.b_int(None, f) == (int(f) if f < 2**31 else INT_MIN)


# ---------------------------------------------------------------- size


def test_size(vm: Any) -> None:
    assert call(vm, "size", Table()) == 0
    assert call(vm, "size", T((1, 2), ("a", None), x=3)) == 3


@pytest.mark.parametrize("value,name", [v for v in ALL if v[1] != "table"])
def test_size_type_errors(vm: Any, value: Any, name: str) -> None:
    with pytest.raises(BuzzError) as e:
        call(vm, "size", value)
    assert e.value.message == f"type mismatch: expected table, got {name}"


# ---------------------------------------------------------------- clone


@pytest.mark.parametrize("value", [None, 0, -3, 2.5, "abc", USERDATA])
def test_clone_of_scalars_is_the_value(vm: Any, value: Any) -> None:
    assert call(vm, "clone", value) is value


def test_clone_is_deep_and_keeps_order(vm: Any) -> None:
    inner = T((2, "b"), (1, "a"))
    t = T(("z", 1), (3.5, inner), (-1, "s"), (0, T(("k", inner))))
    c = call(vm, "clone", t)
    assert c is not t and c.__class__ is Table
    assert list(c) == list(t)
    assert c["z"] == 1 and c[-1] == "s"
    assert c[3.5] is not inner and list(c[3.5].items()) == [(2, "b"), (1, "a")]
    # Sharing inside the cloned graph is kept: both paths lead to one copy.
    assert c[0]["k"] is c[3.5]
    c[3.5][9] = 9
    assert 9 not in inner


def test_clone_of_cyclic_tables_keeps_the_cycle(vm: Any) -> None:
    a = Table()
    b = Table()
    a["next"] = b
    a["self"] = a
    b["back"] = a
    b["v"] = 1
    c = call(vm, "clone", a)
    assert c is not a
    assert c["self"] is c
    assert c["next"] is not b
    assert c["next"]["back"] is c
    assert list(c) == ["next", "self"] and list(c["next"]) == ["back", "v"]


def test_clone_of_a_deep_chain_does_not_recurse(vm: Any) -> None:
    head = t = Table()
    for i in range(100_000):
        n = Table()
        t["n"] = n
        t["i"] = i
        t = n
    c = call(vm, "clone", head)
    depth = 0
    while "n" in c:
        assert c["i"] == depth
        c = c["n"]
        depth += 1
    assert depth == 100_000


def test_clone_of_a_closure_copies_it_keeping_self(vm: Any) -> None:
    owner = Table()
    f = buzz_fn(lambda: 7, self_value=owner)
    c = call(vm, "clone", f)
    assert c.__class__ is Closure and c is not f
    assert c.actrec == f.actrec and c.actrec[0] is owner
    assert c.ref == f.ref and c.native == f.native
    assert vm.call_closure(c) == 7
    t = call(vm, "clone", T(("f", f)))
    assert t["f"] is not f and t["f"].actrec[0] is owner  # not re-bound to the copy


@given(
    st.recursive(
        st.one_of(st.none(), st.integers(-5, 5), st.text(max_size=3)),
        lambda children: st.dictionaries(
            st.one_of(st.integers(-9, 9), st.text(max_size=2)), children, max_size=4
        ),
        max_leaves=20,
    )
)
def test_clone_property(data: Any) -> None:
    def build(x: Any) -> Any:
        if isinstance(x, dict):
            return T(*((k, build(v)) for k, v in x.items() if v is not None))
        return x

    def same(a: Any, b: Any) -> bool:
        if a.__class__ is Table:
            return (
                b.__class__ is Table
                and a is not b
                and list(a) == list(b)
                and all(same(a[k], b[k]) for k in a)
            )
        return a == b

    t = build(data)
    assert same(t, base.clone(t))


# ---------------------------------------------------------------- foreach, map, reduce, filter


def sample() -> Table:
    return T((15, "a"), (5, "b"), ("x", "c"), (2.5, "d"), (-1, "e"))


def test_foreach_visits_in_insertion_order(vm: Any) -> None:
    seen: list[tuple[Any, Any]] = []
    r = call(vm, "foreach", sample(), buzz_fn(lambda k, v: seen.append((k, v)) or 99))
    assert r is None
    assert seen == list(sample().items())


def test_foreach_on_an_empty_table_calls_nothing(vm: Any) -> None:
    assert call(vm, "foreach", Table(), buzz_fn(lambda k, v: pytest.fail("called"))) is None


def test_foreach_survives_mutation_by_the_callback(vm: Any) -> None:
    t = sample()
    seen: list[Any] = []

    def f(k: Any, v: Any) -> None:
        seen.append(k)
        t.pop(5, None)
        t[len(t) + 100] = "new"

    call(vm, "foreach", t, buzz_fn(f))
    assert seen == [15, 5, "x", 2.5, -1]


def test_map_keeps_keys_omits_nil_and_does_not_rebind(vm: Any) -> None:
    g = buzz_fn(lambda: 0)

    def f(k: Any, v: Any) -> Any:
        if v == "b":
            return None
        if v == "c":
            return g
        return v + "!"

    t = sample()
    r = call(vm, "map", t, buzz_fn(f))
    assert r.__class__ is Table and r is not t
    assert list(r.items()) == [(15, "a!"), ("x", g), (2.5, "d!"), (-1, "e!")]
    assert r["x"] is g and g.actrec[0] is None  # stored directly
    assert list(t.items()) == list(sample().items())


def test_reduce_threads_the_accumulator(vm: Any) -> None:
    t = T((1, 10), (2, 20), (3, 30))
    calls: list[tuple[Any, Any, Any]] = []

    def f(k: Any, v: Any, acc: Any) -> Any:
        calls.append((k, v, acc))
        return acc + v

    assert call(vm, "reduce", t, buzz_fn(f), 0) == 60
    assert calls == [(1, 10, 0), (2, 20, 10), (3, 30, 30)]
    assert call(vm, "reduce", Table(), buzz_fn(f), "acc") == "acc"
    assert call(vm, "reduce", t, buzz_fn(lambda k, v, acc: None), 5) is None


def test_filter_keeps_truthy_entries_in_order(vm: Any) -> None:
    results = {15: 1, 5: 0, "x": 0.0, 2.5: None, -1: ""}  # only nil and 0 are false
    r = call(vm, "filter", sample(), buzz_fn(lambda k, v: results[k]))
    assert list(r.items()) == [(15, "a"), ("x", "c"), (-1, "e")]


def test_map_and_filter_survive_mutation(vm: Any) -> None:
    t = T((1, 1), (2, 2), (3, 3))

    def f(k: Any, v: Any) -> Any:
        t.clear()
        return v

    assert list(call(vm, "map", t, buzz_fn(f)).items()) == [(1, 1), (2, 2), (3, 3)]
    t = T((1, 1), (2, 2))
    assert list(call(vm, "filter", t, buzz_fn(f)).items()) == [(1, 1), (2, 2)]


def test_callbacks_may_be_natives(vm: Any) -> None:
    r = call(vm, "map", T((1, 2.5), (4, 3)), vm.globals["math"]["max"])
    assert list(r.items()) == [(1, 2.5), (4, 4)]


@pytest.mark.parametrize(
    "fname,extra", [("foreach", ()), ("map", ()), ("filter", ()), ("reduce", (0,))]
)
def test_iterator_type_errors(vm: Any, fname: str, extra: tuple) -> None:
    f = buzz_fn(lambda *a: None)
    with pytest.raises(BuzzError) as e:
        call(vm, fname, 3, f, *extra)
    assert e.value.message == "type mismatch: expected table, got integer"
    with pytest.raises(BuzzError) as e:
        call(vm, fname, Table(), "f", *extra)
    assert e.value.message == "type mismatch: expected closure, got string"
    with pytest.raises(BuzzError) as e:
        call(vm, fname, Table(), None, *extra)
    assert e.value.message == "type mismatch: expected closure, got nil"


@pytest.mark.parametrize("fname,arity", [("foreach", 2), ("map", 2), ("filter", 2), ("reduce", 3)])
def test_iterator_arity(vm: Any, fname: str, arity: int) -> None:
    with pytest.raises(BuzzError, match=f"expected {arity} parameters, got 1"):
        call(vm, fname, Table())


def test_callback_errors_propagate(vm: Any) -> None:
    def boom(*a: Any) -> None:
        raise BuzzError("inner")

    with pytest.raises(BuzzError, match="inner"):
        call(vm, "foreach", T((1, 1)), buzz_fn(boom))
