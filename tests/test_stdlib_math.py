"""The `math` table (docs/stdlib.md#math), except math.rng (tests/test_stdlib_rng.py)."""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import struct
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bvm.errors import BuzzError
from bvm.stdlib import mathlib
from bvm.values import INT_MAX, INT_MIN, Closure, Table, Userdata, f32, format_value

try:
    from test_stdlib_install import call, make_vm
except ImportError:  # tests/ imported as a package
    from tests.test_stdlib_install import call, make_vm

NAN = math.nan
INF = math.inf
FLT_MAX = f32(3.4028234663852886e38)
floats32 = st.floats(width=32)  # every binary32 value, NaN and infinities included
finite32 = st.floats(width=32, allow_nan=False, allow_infinity=False)


@pytest.fixture(scope="module")
def vm() -> Any:
    return make_vm()


def neg(x: float) -> bool:
    """The sign bit (what printf shows as -nan)."""
    return math.copysign(1.0, x) < 0


def is_f32(x: float) -> bool:
    return x != x or f32(x) == x


def fn(name: str) -> Any:
    """The bare implementation of math.<name> (called with self = None)."""
    return getattr(mathlib, f"m_{name}")


# ---------------------------------------------------------------- abs


@pytest.mark.parametrize(
    "x,expected",
    [(5, 5), (-5, 5), (0, 0), (INT_MAX, INT_MAX), (-INT_MAX, INT_MAX), (INT_MIN, INT_MIN)],
)
def test_abs_int(vm: Any, x: int, expected: int) -> None:
    r = call(vm, "math.abs", x)
    assert r == expected and r.__class__ is int


def test_abs_float(vm: Any) -> None:
    assert call(vm, "math.abs", -2.5) == 2.5
    assert call(vm, "math.abs", 2.5) == 2.5
    r = call(vm, "math.abs", -0.0)
    assert r == 0.0 and not neg(r)
    assert call(vm, "math.abs", -INF) == INF
    r = call(vm, "math.abs", -NAN)
    assert math.isnan(r) and not neg(r)


# ---------------------------------------------------------------- floor, ceil, round


@pytest.mark.parametrize(
    "x,fl,ce,ro",
    [
        (2.5, 2, 3, 3),
        (-2.5, -3, -2, -3),
        (2.4, 2, 3, 2),
        (-2.6, -3, -2, -3),
        (0.5, 0, 1, 1),
        (-0.5, -1, 0, -1),
        (0.49999997, 0, 1, 0),  # the binary32 just below 0.5
        (-0.0, 0, 0, 0),
        (1.0, 1, 1, 1),
        (8388609.0, 8388609, 8388609, 8388609),
        (2147483520.0, 2147483520, 2147483520, 2147483520),
        (-2147483648.0, INT_MIN, INT_MIN, INT_MIN),
        (2147483648.0, INT_MIN, INT_MIN, INT_MIN),
        (-3e9, INT_MIN, INT_MIN, INT_MIN),
        (FLT_MAX, INT_MIN, INT_MIN, INT_MIN),
        (INF, INT_MIN, INT_MIN, INT_MIN),
        (-INF, INT_MIN, INT_MIN, INT_MIN),
        (NAN, INT_MIN, INT_MIN, INT_MIN),
    ],
)
def test_floor_ceil_round(vm: Any, x: float, fl: int, ce: int, ro: int) -> None:
    for name, expected in (("floor", fl), ("ceil", ce), ("round", ro)):
        r = call(vm, f"math.{name}", x)
        assert r == expected and r.__class__ is int, (name, x)


@pytest.mark.parametrize("name", ["floor", "ceil", "round"])
@pytest.mark.parametrize("x", [0, 7, -7, INT_MIN, INT_MAX])
def test_floor_ceil_round_return_ints_unchanged(vm: Any, name: str, x: int) -> None:
    assert call(vm, f"math.{name}", x) == x


def _c_round(x: float) -> int:
    r = math.floor(abs(x) + 0.5) if abs(x) < 2**52 else abs(x)
    return int(math.copysign(r, x))


@given(finite32.filter(lambda x: -(2.0**31) < x < 2.0**31))
def test_floor_ceil_round_agree_with_python_in_range(x: float) -> None:
    for name, ref in (("floor", math.floor), ("ceil", math.ceil), ("round", _c_round)):
        expected = ref(x)
        if not INT_MIN <= expected <= INT_MAX:
            expected = INT_MIN
        assert fn(name)(None, x) == expected, (name, x)


@given(floats32)
def test_floor_ceil_round_always_int32(x: float) -> None:
    for name in ("floor", "ceil", "round"):
        r = fn(name)(None, x)
        assert r.__class__ is int and INT_MIN <= r <= INT_MAX


# ---------------------------------------------------------------- log exp sqrt trig


@pytest.mark.parametrize(
    "name,x,expected",
    [
        ("log", 1, 0.0),
        ("log", f32(math.e), f32(math.log(f32(math.e)))),
        ("log2", 8, 3.0),
        ("log2", 0.5, -1.0),
        ("log10", 1000, 3.0),
        ("log10", 0.001, f32(math.log10(f32(0.001)))),
        ("exp", 0, 1.0),
        ("exp", 1, f32(math.e)),
        ("exp", 88.0, f32(math.exp(88.0))),
        ("exp", 89, INF),
        ("exp", 1000.0, INF),
        ("exp", -1000.0, 0.0),
        ("exp", -INF, 0.0),
        ("exp", INF, INF),
        ("sqrt", 2, f32(math.sqrt(2))),
        ("sqrt", 16.0, 4.0),
        ("sqrt", INF, INF),
        ("sin", 0, 0.0),
        ("sin", 1.5707963705062866, 1.0),
        ("cos", 0, 1.0),
        ("cos", 3.1415927410125732, -1.0),
        ("tan", 0.7853981852531433, f32(math.tan(0.7853981852531433))),
        ("asin", 1, f32(math.pi / 2)),
        ("asin", -1.0, f32(-math.pi / 2)),
        ("acos", -1, f32(math.pi)),
        ("acos", 1.0, 0.0),
        ("log", 0, -INF),
        ("log", 0.0, -INF),
        ("log", -0.0, -INF),
        ("log2", 0, -INF),
        ("log10", -0.0, -INF),
        ("log", INF, INF),
        ("log2", INF, INF),
        ("log10", INF, INF),
    ],
)
def test_unary_values(vm: Any, name: str, x: Any, expected: float) -> None:
    r = call(vm, f"math.{name}", x)
    assert r.__class__ is float
    assert r == expected and is_f32(r)


def test_sqrt_of_minus_zero_is_minus_zero(vm: Any) -> None:
    r = call(vm, "math.sqrt", -0.0)
    assert r == 0.0 and neg(r)


# (function, argument, sign bit of the resulting NaN), as glibc 2.36 gives them on x86-64.
INVALID = [
    ("log", -1, True),
    ("log", -INF, True),
    ("log2", -0.5, True),
    ("log10", -1.0, False),
    ("sqrt", -1, True),
    ("sqrt", -INF, True),
    ("sin", INF, True),
    ("sin", -INF, True),
    ("cos", INF, True),
    ("tan", -INF, True),
    ("asin", 2, False),
    ("asin", -1.0000001, False),
    ("asin", INF, False),
    ("acos", -2.0, False),
    ("acos", INF, False),
]


@pytest.mark.parametrize("name,x,negative", INVALID)
def test_invalid_arguments_give_nan_not_exceptions(
    vm: Any, name: str, x: Any, negative: bool
) -> None:
    r = call(vm, f"math.{name}", x)
    assert math.isnan(r)
    assert neg(r) == negative
    assert format_value(r) == ("-nan" if negative else "nan")


@pytest.mark.parametrize(
    "name", ["log", "log2", "log10", "exp", "sqrt", "sin", "cos", "tan", "asin", "acos"]
)
@pytest.mark.parametrize("nan", [NAN, -NAN])
def test_nan_arguments_pass_through(vm: Any, name: str, nan: float) -> None:
    r = call(vm, f"math.{name}", nan)
    assert math.isnan(r) and neg(r) == neg(nan)


UNARY = ["log", "log2", "log10", "exp", "sqrt", "sin", "cos", "tan", "asin", "acos"]


@given(floats32)
def test_unary_results_are_binary32_floats(x: float) -> None:
    for name in UNARY:
        r = fn(name)(None, x)
        assert r.__class__ is float and is_f32(r), (name, x)


@given(st.integers(INT_MIN, INT_MAX))
def test_int_arguments_are_converted_to_binary32_first(i: int) -> None:
    for name in UNARY:
        a, b = fn(name)(None, i), fn(name)(None, f32(i))
        assert a == b or (math.isnan(a) and math.isnan(b)), (name, i)


def _libm() -> Any:
    path = ctypes.util.find_library("m")
    if path is None:
        return None
    try:
        return ctypes.CDLL(path)
    except OSError:
        return None


LIBM = _libm()


def _cfun(name: str, nargs: int = 1) -> Any:
    f = getattr(LIBM, name)
    f.restype = ctypes.c_float
    f.argtypes = [ctypes.c_float] * nargs
    return f


def _ulps(a: float, b: float) -> int:
    ia = struct.unpack("<i", struct.pack("<f", a))[0]
    ib = struct.unpack("<i", struct.pack("<f", b))[0]
    return abs(ia - ib)


@pytest.mark.skipif(LIBM is None, reason="no C math library")
@given(floats32)
def test_unary_agree_with_c_single_precision(x: float) -> None:
    """Same specials (inf, zero sign, NaN) as libm's *f functions; within 1 ulp otherwise."""
    for name in UNARY:
        r = fn(name)(None, x)
        c = _cfun(name + "f")(x)
        if math.isnan(c) or math.isnan(r):
            assert math.isnan(c) and math.isnan(r), (name, x)
            continue
        if math.isinf(c) or math.isinf(r) or c == 0.0 or r == 0.0:
            assert r == c and neg(r) == neg(c), (name, x, r, c)
            continue
        assert _ulps(r, c) <= 1, (name, x, r, c)


# ---------------------------------------------------------------- atan


@pytest.mark.parametrize(
    "y,x,expected",
    [
        (1, 1, f32(math.pi / 4)),
        (1.0, 0, f32(math.pi / 2)),
        (0, -1, f32(math.pi)),
        (-1, 0.0, f32(-math.pi / 2)),
        (INF, INF, f32(math.pi / 4)),
        (0.0, 0.0, 0.0),
    ],
)
def test_atan_is_atan2(vm: Any, y: Any, x: Any, expected: float) -> None:
    r = call(vm, "math.atan", y, x)
    assert r == expected and is_f32(r)


def test_atan_nan_and_signed_zero(vm: Any) -> None:
    assert math.isnan(call(vm, "math.atan", NAN, 1))
    r = call(vm, "math.atan", -0.0, -0.0)
    assert r == f32(-math.pi)


@pytest.mark.skipif(LIBM is None, reason="no C math library")
@given(floats32, floats32)
def test_atan_agrees_with_atan2f(y: float, x: float) -> None:
    r = mathlib.m_atan(None, y, x)
    c = _cfun("atan2f", 2)(y, x)
    if math.isnan(c):
        assert math.isnan(r)
    elif c == 0.0 or math.isinf(c):
        assert r == c and neg(r) == neg(c)
    else:
        assert _ulps(r, c) <= 1


def test_atan_arity_and_types(vm: Any) -> None:
    with pytest.raises(BuzzError, match="expected 2 parameters, got 1"):
        call(vm, "math.atan", 1.0)
    with pytest.raises(BuzzError) as e:
        call(vm, "math.atan", "1", 1)
    assert e.value.message == "type mismatch: expected float or integer for argument 1, got string"
    with pytest.raises(BuzzError) as e:
        call(vm, "math.atan", 1, None)
    assert e.value.message == "type mismatch: expected float or integer for argument 2, got nil"


def test_there_is_no_atan2(vm: Any) -> None:
    assert "atan2" not in vm.globals["math"]


# ---------------------------------------------------------------- min, max, pi


@pytest.mark.parametrize(
    "a,b,lo,hi",
    [
        (3, 4.5, 3, 4.5),
        (4.5, 3, 3, 4.5),
        (1, 1.0, 1, 1),  # equal: both return a
        (1.0, 1, 1.0, 1.0),
        (-2, -3, -3, -2),
        ("a", "b", "a", "b"),
        ("b", "a", "a", "b"),
    ],
)
def test_min_max(vm: Any, a: Any, b: Any, lo: Any, hi: Any) -> None:
    rmin, rmax = call(vm, "math.min", a, b), call(vm, "math.max", a, b)
    assert rmin == lo and rmin.__class__ is lo.__class__
    assert rmax == hi and rmax.__class__ is hi.__class__


def test_min_max_return_the_original_object(vm: Any) -> None:
    t = Table()
    assert call(vm, "math.max", t, 5) is t  # a table is greater than anything else
    assert call(vm, "math.min", t, 5) == 5
    assert call(vm, "math.min", 5, t) == 5


def test_min_max_with_nan_return_the_first_argument(vm: Any) -> None:
    assert math.isnan(call(vm, "math.min", NAN, 1.0))
    assert math.isnan(call(vm, "math.max", NAN, 1.0))
    assert call(vm, "math.min", 1.0, NAN) == 1.0
    assert call(vm, "math.max", 1.0, NAN) == 1.0


@given(st.one_of(st.integers(INT_MIN, INT_MAX), finite32), st.one_of(st.integers(-9, 9), finite32))
def test_min_max_properties(a: Any, b: Any) -> None:
    lo, hi = mathlib.m_min(None, a, b), mathlib.m_max(None, a, b)
    assert lo is a or lo is b
    assert hi is a or hi is b
    assert f32(lo) <= f32(hi)


def test_min_max_of_unordered_values_is_a_buzz_error(vm: Any) -> None:
    with pytest.raises(BuzzError):
        call(vm, "math.min", None, 1)
    with pytest.raises(BuzzError):
        call(vm, "math.max", Table(), Table())


def test_pi(vm: Any) -> None:
    pi = vm.globals["math"]["pi"]
    assert pi == f32(math.pi) and pi.__class__ is float
    assert format_value(pi) == "3.141593"


# ---------------------------------------------------------------- errors


NUMERIC_1 = ["abs", "floor", "ceil", "round", *UNARY]
BAD = [(None, "nil"), ("1", "string"), (Table(), "table"), (Userdata(1), "userdata")]


@pytest.mark.parametrize("name", NUMERIC_1)
@pytest.mark.parametrize("value,tname", BAD)
def test_type_errors(vm: Any, name: str, value: Any, tname: str) -> None:
    with pytest.raises(BuzzError) as e:
        call(vm, f"math.{name}", value)
    assert e.value.message == f"type mismatch: expected float or integer, got {tname}"


def test_closure_argument_is_a_type_error(vm: Any) -> None:
    with pytest.raises(BuzzError, match="got closure"):
        call(vm, "math.sqrt", vm.globals["math"]["sqrt"])
    assert vm.globals["math"]["sqrt"].__class__ is Closure


@pytest.mark.parametrize("name", NUMERIC_1)
def test_arity(vm: Any, name: str) -> None:
    with pytest.raises(BuzzError, match="expected 1 parameters, got 0"):
        call(vm, f"math.{name}")
    with pytest.raises(BuzzError, match="expected 1 parameters, got 2"):
        call(vm, f"math.{name}", 1, 2)
