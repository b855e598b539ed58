"""Properties of Buzz int32 and float32 arithmetic, through translated and interpreted code.

The oracle for floats is numpy's binary32 arithmetic (the hardware's single precision),
which is independent of bvm's double-then-round implementation; for ints, Python's
exact arithmetic wrapped to 32 bits and C's truncating division.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import bvm
from bvm.values import f32

INT32 = st.integers(min_value=-(2**31), max_value=2**31 - 1)
FLOAT32 = st.floats(width=32, allow_nan=False)

SRC = """
function add(a, b) { return a + b }
function sub(a, b) { return a - b }
function mul(a, b) { return a * b }
function div(a, b) { return a / b }
function mod(a, b) { return a % b }
function neg(a) { return -a }
function lt(a, b) { return (a < b) }
function eq(a, b) { return (a == b) }
function shl(a, b) { return a << b }
function shr(a, b) { return a >> b }
function tadd(t) { return t.a + t.b }
function tsub(t) { return t.a - t.b }
function tmul(t) { return t.a * t.b }
function tlt(t) { return (t.a < t.b) }
function tle(t) { return (t.a <= t.b) }
function tlt0(t) { return (t.a < 0) }
function tgtbig(t) { return (t.a > 16777217) }
function tltf(t) { return (t.a < 0.5) }
function tdiv(t) { return t.a / t.b }
function tdiv16(t) { return t.a / 16 }
function tmod(t) { return t.a % t.b }
function tband(t) { return t.a & t.b }
function tbor(t) { return t.a | t.b }
function tshl(t) { return t.a << t.b }
function tshr(t) { return t.a >> t.b }
function ftadd(t) { var x = 0.75
  return x + t.b }
function tfsub(t) { var x = 0.75
  return t.b - x }
function ftmul(t) { var x = 3.0
  return x * t.b }
"""


def _vm(translate: bool) -> bvm.VM:
    vm = bvm.VM(translate=translate)
    vm.load(bvm.compile_source(SRC))
    vm.execute()
    return vm


# One VM per path for the whole module: the translated one specializes on the first
# argument types it sees and must stay right for every later call.
VMS = {True: _vm(True), False: _vm(False)}
PATHS = pytest.mark.parametrize("translate", [True, False], ids=["translated", "interpreted"])


def wrap(x: int) -> int:
    return ((x + 2**31) % 2**32) - 2**31


def c_div(a: int, b: int) -> int:
    q = abs(a) // abs(b)
    return q if (a < 0) == (b < 0) else -q


def c_mod(a: int, b: int) -> int:
    r = abs(a) % abs(b)
    r = -r if a < 0 else r
    return wrap(r + b) if r < 0 else r


def np32(op: str, a: float, b: float) -> float:
    x, y = np.float32(a), np.float32(b)
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        r = {"add": x + y, "sub": x - y, "mul": x * y, "div": x / y}[op]
    return float(r)


def same_float(a: float, b: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)


@PATHS
@settings(max_examples=300, deadline=None)
@given(a=INT32, b=INT32)
def test_int32_add_sub_mul_wrap(translate: bool, a: int, b: int) -> None:
    vm = VMS[translate]
    assert vm.call("add", a, b) == wrap(a + b)
    assert vm.call("sub", a, b) == wrap(a - b)
    assert vm.call("mul", a, b) == wrap(a * b)
    assert vm.call("neg", a) == wrap(-a)


@PATHS
@settings(max_examples=300, deadline=None)
@given(a=INT32, b=INT32.filter(lambda b: b != 0))
def test_int32_division_truncates_and_modulo_follows_the_reference(
    translate: bool, a: int, b: int
) -> None:
    vm = VMS[translate]
    assert vm.call("div", a, b) == wrap(c_div(a, b))
    assert vm.call("mod", a, b) == c_mod(a, b)


@PATHS
@settings(max_examples=300, deadline=None)
@given(
    a=st.one_of(INT32, st.floats(allow_nan=False, allow_infinity=False, width=32)),
    b=st.one_of(INT32.filter(lambda b: b != 0), st.integers(-64, 64).filter(lambda b: b != 0)),
)
def test_untyped_int_division_and_bitwise_follow_the_reference(
    translate: bool, a: int | float, b: int
) -> None:
    """Ints read from a table (no known type): translated code uses Python's operators
    where they are Buzz's rule (a positive divisor, int operands) and the full rule
    otherwise: both must agree with the reference, and a float still fails bitwise."""
    vm = VMS[translate]
    t = bvm.Table(a=a, b=b)
    if isinstance(a, float):
        assert same_float(vm.call("tdiv", t), np32("div", a, f32(float(b)))), (a, b)
        with pytest.raises(bvm.BuzzError, match="expected integer"):
            vm.call("tbor", t)
        vm.reset_error()
        return
    assert vm.call("tdiv", t) == wrap(c_div(a, b)), (a, b)
    assert vm.call("tdiv16", t) == c_div(a, 16), a


@PATHS
@pytest.mark.parametrize(("a", "b"), [(2**40, 3), (-(2**40), 7), (5, 2**40), (-5, 2**40)])
def test_ints_a_host_stored_beyond_int32_divide_as_the_rule_says(
    translate: bool, a: int, b: int
) -> None:
    # Buzz ints are int32, but a host may put any Python int in a table: translated code
    # must then give what the rule gives (it wraps), not Python's operator.
    vm = VMS[translate]
    t = bvm.Table(a=a, b=b)
    assert vm.call("tdiv", t) == bvm.ops.div(a, b)
    assert vm.call("tmod", t) == bvm.ops.mod(a, b)
    assert vm.call("tband", t) == a & b
    assert vm.call("tbor", t) == a | b
    assert vm.call("tshl", t) == wrap(a << (b & 31)), (a, b)
    assert vm.call("tshr", t) == a >> (b & 31), (a, b)


@PATHS
@settings(max_examples=200, deadline=None)
@given(a=INT32, b=st.integers(min_value=-64, max_value=64))
def test_shifts_use_the_low_five_bits(translate: bool, a: int, b: int) -> None:
    vm = VMS[translate]
    assert vm.call("shl", a, b) == wrap(a << (b & 31))
    assert vm.call("shr", a, b) == a >> (b & 31)


@PATHS
@settings(max_examples=300, deadline=None)
@given(a=FLOAT32, b=FLOAT32)
def test_float32_arithmetic_matches_single_precision(translate: bool, a: float, b: float) -> None:
    vm = VMS[translate]
    for op in ("add", "sub", "mul", "div"):
        got = vm.call(op, a, b)
        assert same_float(got, np32(op, a, b)), (op, a, b, got)
        assert got != got or f32(got) == got  # always a binary32 value


@PATHS
@settings(max_examples=300, deadline=None)
@given(a=st.floats(allow_nan=False), b=st.one_of(FLOAT32, st.floats(allow_nan=False)))
def test_untyped_float_sums_round_their_operands_first(translate: bool, a: float, b: float) -> None:
    """Operands read from a table have no known type (translated code adds them in Python
    and redoes what is not a small int); a host may even store unrounded doubles there.
    Either way the result is binary32 arithmetic on the operands rounded to binary32."""
    vm = VMS[translate]
    t = bvm.Table(a=a, b=b)
    with np.errstate(over="ignore"):
        a32, b32 = float(np.float32(a)), float(np.float32(b))
    assert same_float(vm.call("tadd", t), np32("add", a32, b32)), (a, b)
    assert same_float(vm.call("tsub", t), np32("sub", a32, b32)), (a, b)
    assert same_float(vm.call("tmul", t), np32("mul", a32, b32)), (a, b)


@PATHS
@settings(max_examples=300, deadline=None)
@given(b=st.one_of(FLOAT32, st.floats(allow_nan=False)))
@example(b=2.0**-24 + 2.0**-50)  # rounds to 2**-24 first: 0.75 + it is then 0.75
def test_a_typed_float_with_an_untyped_one_rounds_it_first(translate: bool, b: float) -> None:
    """A float the translator knows (a literal in a local) with one read from a table: the
    table's value is rounded to binary32 before the operation, as the rule does."""
    vm = VMS[translate]
    t = bvm.Table(b=b)
    with np.errstate(over="ignore"):
        b32 = float(np.float32(b))
    assert same_float(vm.call("ftadd", t), np32("add", 0.75, b32)), b
    assert same_float(vm.call("tfsub", t), np32("sub", b32, 0.75)), b
    assert same_float(vm.call("ftmul", t), np32("mul", 3.0, b32)), b


@PATHS
@settings(max_examples=300, deadline=None)
@given(
    a=st.one_of(INT32, FLOAT32, st.floats()),
    b=st.one_of(INT32, FLOAT32, st.floats(), st.just(math.nan)),
)
def test_untyped_comparisons_order_floats_as_ieee(translate: bool, a: float, b: float) -> None:
    """Two floats read from a table (no known type) order as IEEE does, NaN unordered;
    an int with a float is converted to binary32 first; the translated fast path for two
    floats must agree with the full rule."""
    vm = VMS[translate]
    t = bvm.Table(a=a, b=b)
    fa = float(np.float32(a)) if isinstance(a, int) and isinstance(b, float) else a
    fb = float(np.float32(b)) if isinstance(b, int) and isinstance(a, float) else b
    assert vm.call("tlt", t) == int(fa < fb), (a, b)
    assert vm.call("tle", t) == int(fa <= fb), (a, b)
    # Against literals: 0 converts exactly; 16777217 does not (binary32 makes it 2**24);
    # a float literal meets a float or an int converted to binary32.
    a32 = float(np.float32(a)) if isinstance(a, int) else a
    assert vm.call("tlt0", t) == int(a < 0), a
    assert vm.call("tgtbig", t) == int(a > (16777217 if isinstance(a, int) else 2.0**24)), a
    assert vm.call("tltf", t) == int(a32 < 0.5), a


@PATHS
@settings(max_examples=300, deadline=None)
@given(a=INT32, b=FLOAT32)
def test_mixed_int_float_converts_the_int_to_binary32_first(
    translate: bool, a: int, b: float
) -> None:
    vm = VMS[translate]
    assert same_float(vm.call("add", a, b), np32("add", float(np.float32(a)), b))
    assert same_float(vm.call("mul", b, a), np32("mul", b, float(np.float32(a))))


@PATHS
@settings(max_examples=200, deadline=None)
@given(a=st.one_of(INT32, FLOAT32), b=st.one_of(INT32, FLOAT32))
def test_comparisons_agree_between_paths_and_with_numbers(
    translate: bool, a: float, b: float
) -> None:
    vm = VMS[translate]
    fa = a if isinstance(a, float) else float(np.float32(a)) if isinstance(b, float) else a
    fb = b if isinstance(b, float) else float(np.float32(b)) if isinstance(a, float) else b
    assert vm.call("lt", a, b) == int(fa < fb)
    assert vm.call("eq", a, b) == int(fa == fb)
