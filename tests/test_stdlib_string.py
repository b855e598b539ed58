"""The `string` table (docs/stdlib.md#string): length, sub, concat, tostring, toint, tofloat."""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import re
from decimal import Decimal
from fractions import Fraction
from typing import Any

import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from bvm.errors import BuzzError
from bvm.stdlib import stringlib
from bvm.values import INT_MIN, Closure, Table, Userdata, f32, i32

try:
    from test_stdlib_install import buzz_fn, call, make_vm
except ImportError:  # tests/ imported as a package
    from tests.test_stdlib_install import buzz_fn, call, make_vm


@pytest.fixture(scope="module")
def vm() -> Any:
    return make_vm()


latin1 = st.text(st.characters(min_codepoint=0, max_codepoint=255), max_size=30)


# ---------------------------------------------------------------- length


@pytest.mark.parametrize("s,n", [("", 0), ("abc", 3), ("\xe9\xff\x00", 3), ("x" * 1000, 1000)])
def test_length(vm: Any, s: str, n: int) -> None:
    assert call(vm, "string.length", s) == n


@pytest.mark.parametrize("fname", ["length", "toint", "tofloat"])
@pytest.mark.parametrize("value,tname", [(1, "integer"), (1.0, "float"), (None, "nil")])
def test_string_argument_required(vm: Any, fname: str, value: Any, tname: str) -> None:
    with pytest.raises(BuzzError) as e:
        call(vm, f"string.{fname}", value)
    assert e.value.message == f"type mismatch: expected string, got {tname}"


# ---------------------------------------------------------------- sub


@pytest.mark.parametrize(
    "args,expected",
    [
        (("hello", 0), "hello"),
        (("hello", 1), "ello"),
        (("hello", 4), "o"),
        (("hello", 5), None),  # n >= length
        (("hello", 99), None),
        (("", 0), None),
        (("hello", 1, 3), "el"),
        (("hello", 1, 1), ""),
        (("hello", 3, 2), None),  # m < n
        (("hello", 2, 99), "llo"),  # m clipped
        (("hello", 0, 5), "hello"),
        (("hello", -3), "hello"),  # negative n clamped to 0
        (("hello", -3, 2), "he"),
        (("hello", 0, -1), None),
    ],
)
def test_sub(vm: Any, args: tuple, expected: str | None) -> None:
    assert call(vm, "string.sub", *args) == expected


@given(latin1, st.integers(-50, 50), st.one_of(st.none(), st.integers(-50, 50)))
def test_sub_property(s: str, n: int, m: int | None) -> None:
    r = stringlib.s_sub(None, s, n) if m is None else stringlib.s_sub(None, s, n, m)
    start = max(n, 0)
    end = len(s) if m is None else m
    if start >= len(s) or end < start:
        assert r is None
    else:
        assert r == s[start : min(end, len(s))]


def test_sub_errors(vm: Any) -> None:
    for args, msg in (
        (("abc",), "wrong number of local variables: expected 2 or 3 parameters, got 1"),
        (("abc", 1, 2, 3), "wrong number of local variables: expected 2 or 3 parameters, got 4"),
        ((1, 1), "type mismatch: expected string, got integer"),
        (("abc", 1.0), "type mismatch: expected integer, got float"),
        (("abc", 0, "2"), "type mismatch: expected integer, got string"),
    ):
        with pytest.raises(BuzzError) as e:
            call(vm, "string.sub", *args)
        assert e.value.message == msg


# ---------------------------------------------------------------- concat


def test_concat(vm: Any) -> None:
    assert call(vm, "string.concat", "ab", "cd") == "abcd"
    assert call(vm, "string.concat", "", "x", "", "yz", "\xff") == "xyz\xff"
    assert call(vm, "string.concat", "", "") == ""


def test_concat_errors(vm: Any) -> None:
    for args, msg in (
        ((), "wrong number of local variables: expected at least 2 parameters, got 0"),
        (("a",), "wrong number of local variables: expected at least 2 parameters, got 1"),
        (("a", 1), "type mismatch: expected string, got integer"),
        ((1.5, "a"), "type mismatch: expected string, got float"),
        (("a", "b", None), "type mismatch: expected string, got nil"),
    ):
        with pytest.raises(BuzzError) as e:
            call(vm, "string.concat", *args)
        assert e.value.message == msg


# ---------------------------------------------------------------- tostring


@pytest.mark.parametrize(
    "x,text",
    [
        (0, "0"),
        (-42, "-42"),
        (INT_MIN, "-2147483648"),
        (1.0, "1.000000"),
        (-0.0, "-0.000000"),
        (f32(0.1), "0.100000"),
        (1e30, "1000000015047466219876688855040.000000"),
        (math.inf, "inf"),
        (-math.inf, "-inf"),
        (math.nan, "nan"),
        (-math.nan, "-nan"),
        ("already", "already"),
        ("", ""),
        (None, "nil"),
    ],
)
def test_tostring(vm: Any, x: Any, text: str) -> None:
    assert call(vm, "string.tostring", f32(x) if isinstance(x, float) else x) == text


def test_tostring_of_tables_closures_userdata(vm: Any) -> None:
    t = Table()
    t[1] = 2
    t["a"] = "b"
    assert call(vm, "string.tostring", t) == "[table with 2 elems]"
    assert call(vm, "string.tostring", vm.globals["string"]["sub"]) == "[c-closure @60]"
    assert call(vm, "string.tostring", buzz_fn(lambda: 0)) == "[n-closure @4242]"
    u = Userdata(object())
    assert re.fullmatch(r"\[userdata @0x[0-9a-f]+\]", call(vm, "string.tostring", u))


@given(st.integers(INT_MIN, 2**31 - 1))
def test_tostring_toint_round_trip(i: int) -> None:
    assert stringlib.strtol32(stringlib.to_string(i)) == i


@given(
    st.floats(
        width=32, allow_nan=False, allow_infinity=False, min_value=2.0**-10, max_value=2.0**20
    )
)
def test_tostring_tofloat_close(x: float) -> None:
    assert abs(stringlib.strtof(stringlib.to_string(x)) - x) <= 5e-7 + abs(x) * 2**-23


# ---------------------------------------------------------------- toint


@pytest.mark.parametrize(
    "s,expected",
    [
        ("42", 42),
        ("-42", -42),
        ("+7", 7),
        ("  \t\n\v\f\r12", 12),
        ("12abc", 12),
        ("1.9", 1),
        ("0x10", 0),
        ("007", 7),
        ("-0", 0),
        ("2147483647", 2147483647),
        ("2147483648", INT_MIN),
        ("-2147483649", 2147483647),
        ("99999999999", 1215752191),  # docs/stdlib.md#string
        ("9223372036854775807", -1),
        ("9223372036854775808", -1),  # saturates at LONG_MAX
        ("99999999999999999999999", -1),
        ("-9223372036854775808", 0),
        ("-99999999999999999999999", 0),  # saturates at LONG_MIN
        ("0" * 5000 + "3", 3),
        ("9" * 5000, -1),
        ("", None),
        ("   ", None),
        ("abc", None),
        ("-", None),
        ("+-1", None),
        ("- 1", None),
        ("\xa01", None),  # not C whitespace
        ("\x1c1", None),  # Python's isspace, not C's
    ],
)
def test_toint(vm: Any, s: str, expected: int | None) -> None:
    assert call(vm, "string.toint", s) == expected


def _libc() -> Any:
    path = ctypes.util.find_library("c")
    if path is None:
        return None
    try:
        lib = ctypes.CDLL(path)
    except OSError:
        return None
    lib.strtol.restype = ctypes.c_long
    lib.strtol.argtypes = [ctypes.c_char_p, ctypes.c_void_p, ctypes.c_int]
    lib.strtof.restype = ctypes.c_float
    lib.strtof.argtypes = [ctypes.c_char_p, ctypes.POINTER(ctypes.c_char_p)]
    return lib


LIBC = _libc()
needs_libc = pytest.mark.skipif(
    LIBC is None or ctypes.sizeof(ctypes.c_long) != 8, reason="needs a C library, 64-bit long"
)


def _strtol_model(s: str) -> int | None:
    """strtol base 10 + int32 truncation, written independently of the implementation."""
    m = re.match(r"[ \t\n\v\f\r]*([+-]?[0-9]+)", s)
    if not m:
        return None
    v = Fraction(m.group(1))  # no digit-count limit
    v = max(min(v, 2**63 - 1), -(2**63))
    return i32(int(v))


number_like = st.text(st.sampled_from(list(" \t\n+-0123456789xX.eEabc\xa0")), max_size=25)


@given(st.one_of(latin1, number_like))
@example("99999999999")
@example("-9223372036854775809")
def test_toint_agrees_with_the_model(s: str) -> None:
    assert stringlib.strtol32(s) == _strtol_model(s)


@needs_libc
@given(st.one_of(latin1, number_like).map(lambda s: s.replace("\0", "")))
@example(" -99999999999999999999")
def test_toint_agrees_with_libc_strtol(s: str) -> None:
    raw = s.encode("latin-1")
    end = ctypes.c_char_p()
    value = LIBC.strtol(raw, ctypes.byref(end), 10)
    consumed = (
        ctypes.cast(end, ctypes.c_void_p).value
        - ctypes.cast(ctypes.c_char_p(raw), ctypes.c_void_p).value
    )
    expected = None if consumed == 0 else i32(value)
    assert stringlib.strtol32(s) == expected


# ---------------------------------------------------------------- tofloat


@pytest.mark.parametrize(
    "s,expected",
    [
        ("1.5", 1.5),
        ("1e3", 1000.0),  # docs/stdlib.md#string
        ("1E-2", f32(0.01)),
        ("  -2.5xyz", -2.5),
        ("+.5", 0.5),
        ("5.", 5.0),
        ("1e", 1.0),
        ("1e+", 1.0),
        ("1.5.6", 1.5),
        ("0.1", f32(0.1)),
        ("3.14159", f32(3.14159)),
        ("16777217", 16777216.0),  # ties to even
        ("16777219", 16777220.0),
        ("1e39", math.inf),
        ("-1e39", -math.inf),
        ("3.4028235e38", f32(3.4028235e38)),
        ("340282356779733661637539395458142568447", 3.4028234663852886e38),
        ("340282356779733661637539395458142568448", math.inf),  # the overflow tie
        ("1e-46", 0.0),
        ("1e-45", 1.401298464324817e-45),
        ("inf", math.inf),
        ("-INF", -math.inf),
        ("Infinity", math.inf),
        ("infinit", math.inf),
        ("0x10", 16.0),
        ("0x1.8p1", 3.0),
        ("0X.8P-1", 0.25),
        ("-0x1p-149", -1.401298464324817e-45),
        ("0x1p200", math.inf),
        ("0x1p99999999999999", math.inf),
        ("0x1p-99999999999999", 0.0),
        ("0x", 0.0),  # just the 0
        ("0xg", 0.0),
        ("0x1p", 1.0),
        ("0x1.000001p0", 1.0),  # exact tie, to even
        ("0x1.000001000000000000000000001p0", f32(1 + 2**-23)),  # just above the tie
        ("0x1.000000ffffffffffffffffffffp0", 1.0),  # just below the tie
        ("", None),
        ("   ", None),
        ("abc", None),
        ("+", None),
        ("-.", None),
        (".e5", None),
        ("in", None),
        ("na", None),
        ("\xa01", None),
    ],
)
def test_tofloat(vm: Any, s: str, expected: float | None) -> None:
    r = call(vm, "string.tofloat", s)
    assert r == expected
    if expected is not None:
        assert r.__class__ is float and f32(r) == r
        assert math.copysign(1, r) == math.copysign(1, expected)


@pytest.mark.parametrize("s,negative", [("nan", False), ("NaN(123)", False), ("-nan", True)])
def test_tofloat_nan(vm: Any, s: str, negative: bool) -> None:
    r = call(vm, "string.tofloat", s)
    assert math.isnan(r) and (math.copysign(1, r) < 0) == negative


def test_tofloat_negative_zero(vm: Any) -> None:
    r = call(vm, "string.tofloat", "-0")
    assert r == 0.0 and math.copysign(1, r) < 0


def _decimal_text(q: Fraction) -> str:
    """The exact decimal expansion of a dyadic rational."""
    d = Decimal(q.numerator) / Decimal(q.denominator)
    exact = Fraction(d)
    assert exact == q, "not exact"
    return format(d, "f")


def test_tofloat_rounds_decimal_text_correctly_near_ties() -> None:
    """Text just above/below a binary32 tie whose nearest double is the tie itself."""
    from decimal import localcontext

    with localcontext() as ctx:
        ctx.prec = 400
        for base, ulp in ((1.0, 2**-23), (3.0, 2**-22), (1e10, 1024.0), (2**-140, 2**-149)):
            tie = Fraction(f32(base)) + Fraction(ulp) / 2
            below, above = f32(base), f32(float(Fraction(f32(base)) + Fraction(ulp)))
            tiny = Fraction(1, 2**90) * Fraction(ulp)
            assert float(tie + tiny) == float(tie)  # the double rounding trap
            assert stringlib.strtof(_decimal_text(tie + tiny)) == above
            assert stringlib.strtof(_decimal_text(tie - tiny)) == below
            even = below if _mantissa_even(below) else above
            assert stringlib.strtof(_decimal_text(tie)) == even
            assert stringlib.strtof("-" + _decimal_text(tie + tiny)) == -above


def _mantissa_even(x: float) -> bool:
    import struct

    return struct.unpack("<I", struct.pack("<f", x))[0] % 2 == 0


float_like = st.text(st.sampled_from(list(" +-0123456789.eEpPxXinfatyINFA(")), max_size=25)


def _libc_strtof(s: str) -> float | None:
    raw = s.encode("latin-1")
    buf = ctypes.c_char_p(raw)
    end = ctypes.c_char_p()
    value = LIBC.strtof(buf, ctypes.byref(end))
    consumed = ctypes.cast(end, ctypes.c_void_p).value - ctypes.cast(buf, ctypes.c_void_p).value
    return None if consumed == 0 else value


@needs_libc
@given(
    st.one_of(
        latin1,
        float_like,
        st.floats().map(repr),
        st.floats(width=32).map(lambda x: x.hex()),
        st.decimals(allow_nan=False, allow_infinity=False).map(str),
    ).map(lambda s: s.replace("\0", ""))
)
@example("1.00000005960464477539062500000000001")
@example("0x1.000001000000000001p0")
def test_tofloat_agrees_with_libc_strtof(s: str) -> None:
    r = stringlib.strtof(s)
    c = _libc_strtof(s)
    if c is None or r is None:
        assert c is None and r is None
    elif math.isnan(c):
        assert math.isnan(r) and math.copysign(1, r) == math.copysign(1, c)
    else:
        assert r == c and math.copysign(1, r) == math.copysign(1, c)


@given(latin1)
def test_conversions_never_raise_python_errors(s: str) -> None:
    r = stringlib.strtof(s)
    assert r is None or (r.__class__ is float and (r != r or f32(r) == r))
    i = stringlib.strtol32(s)
    assert i is None or (i.__class__ is int and INT_MIN <= i < 2**31)


def test_toint_tofloat_return_nil_and_not_errors_for_junk(vm: Any) -> None:
    assert call(vm, "string.toint", "nope") is None
    assert call(vm, "string.tofloat", "nope") is None


def test_string_methods_are_closures_bound_to_the_table(vm: Any) -> None:
    for name in ("length", "sub", "concat", "tostring", "toint", "tofloat"):
        c = vm.globals["string"][name]
        assert c.__class__ is Closure and c.actrec[0] is vm.globals["string"]
