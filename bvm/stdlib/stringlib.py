"""The `string` table (docs/stdlib.md#string): length, sub, concat, tostring, toint, tofloat.

Deliberate differences from the reference (see docs/compat.md):

* `tostring(x)` formats every type: ints `%d`, floats `%f` (inf, -inf, nan, -nan), strings
  unchanged, nil "nil", tables `[table with N elems]`, closures and userdata as `log` prints
  them. The reference returns "0.000000" for anything that is not a number.
* `sub(s, n [, m])` clamps a negative n to 0 (undefined behaviour in the reference).
* `toint` is C strtol (base 10, 64-bit saturation) followed by truncation to int32; `tofloat`
  is C strtof (decimal, hex floats, inf/infinity, nan; longest valid prefix) with correct
  rounding to binary32. Both return nil when no number can be read.
"""

from __future__ import annotations

import math
import re
from decimal import Decimal
from fractions import Fraction
from typing import TYPE_CHECKING, Any

from bvm.errors import BuzzError
from bvm.inline import inline
from bvm.values import MAX_STRING_BYTES, Table, f32, format_value, type_name

if TYPE_CHECKING:
    from bvm.host import LibraryHost

_LONG_MAX = 0x7FFFFFFFFFFFFFFF

# Leading blanks are C isspace() in the "C" locale: " \t\n\v\f\r" only.
_INT_RE = re.compile(r"[ \t\n\v\f\r]*([+-]?)([0-9]+)")
_FLOAT_RE = re.compile(
    r"[ \t\n\v\f\r]*([+-]?)(?:"
    r"0[xX]((?:[0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+))(?:[pP]([+-]?[0-9]+))?"
    r"|([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?"
    r"|([iI][nN][fF])"
    r"|([nN][aA][nN])"
    r")"
)
_FLT_MAX = f32(3.4028234663852886e38)
_TWO128 = 2.0**128
_F32_BITS = memoryview(bytearray(4))
_F32_AS_U32 = _F32_BITS.cast("I")
_F32_AS_F = _F32_BITS.cast("f")


def _expected(what: str, x: Any) -> BuzzError:
    return BuzzError(f"type mismatch: expected {what}, got {type_name(x)}")


# ---------------------------------------------------------------- conversions


def strtol32(s: str) -> int | None:
    """C strtol(s, NULL, 10) (64-bit long, saturating) truncated to int32; None if no digits."""
    m = _INT_RE.match(s)
    if m is None:
        return None
    digits = m.group(2).lstrip("0")
    if len(digits) > 19:  # beyond any 64-bit value: strtol saturates
        v = _LONG_MAX + 1
    else:
        v = int(digits) if digits else 0
    if m.group(1) == "-":
        v = -v
        if v < -_LONG_MAX - 1:
            v = -_LONG_MAX - 1
    elif v > _LONG_MAX:
        v = _LONG_MAX
    v &= 0xFFFFFFFF
    return v - 0x100000000 if v & 0x80000000 else v


def _f32_step(f: float, up: bool) -> float:
    """The binary32 value next to the non-negative binary32 f, up or down."""
    _F32_AS_F[0] = f
    _F32_AS_U32[0] += 1 if up else -1
    return _F32_AS_F[0]


def _round_f32(d: float, exact: Any) -> float:
    """Round the value x, whose nearest double is d >= 0, to binary32 correctly.

    f32(d) is right unless d is exactly halfway between two binary32 values (then x may lie
    on either side of d); only then is `exact()` called, returning -1, 0 or 1 as x <, ==
    or > d.
    """
    f = f32(d)
    if f == d:
        return f
    if f == math.inf:
        lo, hi = _FLT_MAX, _TWO128
    elif f > d:
        lo, hi = _f32_step(f, False), f
    else:
        lo, hi = f, _f32_step(f, True)
        if hi == math.inf:
            hi = _TWO128
    if d != (lo + hi) / 2:
        return f
    try:
        c = exact()
    except (ArithmeticError, ValueError):  # absurd exponents: keep the double rounding
        return f
    if c == 0:
        return f  # f32 already rounded the tie to even
    r = hi if c > 0 else lo
    return math.inf if r == _TWO128 else r


def strtof(s: str) -> float | None:
    """C strtof(s, NULL): the binary32 value of the longest numeric prefix; None if none."""
    m = _FLOAT_RE.match(s)
    if m is None:
        return None
    sign, hexmant, hexexp, mant, exp, inf, _nan = m.groups()
    if mant is not None:
        text = mant + exp if exp else mant
        d = float(text)
        r = _round_f32(d, lambda: Decimal(text).compare(Decimal(d)))
    elif hexmant is not None:
        whole, _, frac = hexmant.partition(".")
        num = int(whole + frac, 16) if whole or frac else 0
        e2 = int(hexexp) - 4 * len(frac) if hexexp else -4 * len(frac)
        try:
            d = float.fromhex("0x" + hexmant + ("p" + hexexp if hexexp else ""))
        except OverflowError:
            d = math.inf

        def cmp() -> int:
            exact = Fraction(num) * Fraction(2) ** e2
            fd = Fraction(d)
            return (exact > fd) - (exact < fd)

        r = math.inf if d == math.inf else _round_f32(d, cmp)
    elif inf is not None:
        r = math.inf
    else:
        r = math.nan
    return -r if sign == "-" else r


def to_string(x: Any) -> str:
    """The text of any value: %d, %f, strings as is, nil "nil", others as `log` prints them."""
    return "nil" if x is None else format_value(x)


# ---------------------------------------------------------------- natives


# What the translator may emit instead of a call, for arguments of these types.
@inline("{len}({0})", "str")
def s_length(_self: Any, s: Any) -> int:
    """string.length(s): the byte length of s."""
    if s.__class__ is not str:
        raise _expected("string", s)
    return len(s)


# The common case inline; anything else (nil results, clamping, errors) calls s_sub.
@inline("{0}[{1}:{2}] if 0 <= {1} < {len}({0}) and {1} <= {2} else {call}", "str", "int", "int")
def s_sub(_self: Any, *args: Any) -> str | None:
    """string.sub(s, n [, m]): bytes [n, m) of s; nil if n >= length or m < n.

    m defaults to (and is clipped to) the length; a negative n is clamped to 0.
    """
    na = len(args)
    if na != 2 and na != 3:
        raise BuzzError(f"wrong number of local variables: expected 2 or 3 parameters, got {na}")
    s, n = args[0], args[1]
    if s.__class__ is not str:
        raise _expected("string", s)
    if n.__class__ is not int:
        raise _expected("integer", n)
    size = len(s)
    if n < 0:
        n = 0
    if n >= size:
        return None
    if na == 2:
        return s[n:]
    m = args[2]
    if m.__class__ is not int:
        raise _expected("integer", m)
    if m < n:
        return None
    return s[n:m]


@inline(
    f"{{0}} + {{1}} if {{len}}({{0}}) + {{len}}({{1}}) <= {MAX_STRING_BYTES} else {{call}}",
    "str",
    "str",
)
def s_concat(_self: Any, *args: Any) -> str:
    """string.concat(s1, s2, ...): the concatenation of two or more strings."""
    if len(args) < 2:
        raise BuzzError(
            f"wrong number of local variables: expected at least 2 parameters, got {len(args)}"
        )
    total = 0
    for a in args:
        if a.__class__ is not str:
            raise _expected("string", a)
        total += len(a)
    if total > MAX_STRING_BYTES:
        raise BuzzError(
            f"string too long: concat would make {total} bytes (the limit is {MAX_STRING_BYTES})"
        )
    return "".join(args)


@inline("{str}({0})", "int")
def s_tostring(_self: Any, x: Any) -> str:
    """string.tostring(x): see `to_string`."""
    return to_string(x)


def s_toint(_self: Any, s: Any) -> int | None:
    """string.toint(s): C strtol base 10, truncated to int32; nil without digits."""
    if s.__class__ is not str:
        raise _expected("string", s)
    return strtol32(s)


def s_tofloat(_self: Any, s: Any) -> float | None:
    """string.tofloat(s): C strtof, correctly rounded to binary32; nil without a number."""
    if s.__class__ is not str:
        raise _expected("string", s)
    return strtof(s)


def register(vm: LibraryHost) -> None:
    """Register the `string` table (C-function ids 59-64)."""
    new = vm.new_native
    t = Table()
    for name, impl, arity in (
        ("length", s_length, 1),
        ("sub", s_sub, None),
        ("concat", s_concat, None),
        ("tostring", s_tostring, 1),
        ("toint", s_toint, 1),
        ("tofloat", s_tofloat, 1),
    ):
        t[name] = new(impl, arity, name).rebind(t)
    vm.globals["string"] = t
