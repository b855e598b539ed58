"""Operator semantics: arithmetic, comparison and table access on Buzz values.

These are the complete (slow-path) definitions. The translator inlines the int/int and
string-key fast paths and calls these for everything else, so there is one definition
of each rule. Deliberate differences from the reference are listed in docs/compat.md.
"""

from __future__ import annotations

import math
from typing import Any

from bvm.errors import BuzzError
from bvm.values import INT_MAX, INT_MIN, Closure, Table, f32, format_float, i32, type_name

_NUM = (int, float)

# The NaN an invalid operation makes on x86 (the "default NaN") has its sign bit set: C
# prints it "-nan". Python raises where C would produce it, so it is built here.
DEFAULT_NAN = -math.nan


def _numbers(a: Any, b: Any, verb: str) -> None:
    """Raise the arithmetic type error unless both operands are numbers."""
    if a.__class__ not in _NUM or b.__class__ not in _NUM:
        raise BuzzError(f"type mismatch: cannot {verb} {type_name(a)} and {type_name(b)}")


def add(a: Any, b: Any) -> Any:
    """a + b: int32 wrapping for two ints, binary32 otherwise."""
    if a.__class__ is int and b.__class__ is int:
        r = a + b
        return r if INT_MIN <= r <= INT_MAX else i32(r)
    _numbers(a, b, "add")
    return f32(f32(a) + f32(b))


def sub(a: Any, b: Any) -> Any:
    """a - b."""
    if a.__class__ is int and b.__class__ is int:
        r = a - b
        return r if INT_MIN <= r <= INT_MAX else i32(r)
    _numbers(a, b, "subtract")
    return f32(f32(a) - f32(b))


def mul(a: Any, b: Any) -> Any:
    """a * b."""
    if a.__class__ is int and b.__class__ is int:
        r = a * b
        return r if INT_MIN <= r <= INT_MAX else i32(r)
    _numbers(a, b, "multiply")
    return f32(f32(a) * f32(b))


def div(a: Any, b: Any) -> Any:
    """a / b: ints truncate toward zero (zero divisor is an error); floats follow IEEE."""
    if a.__class__ is int and b.__class__ is int:
        if b == 0:
            raise BuzzError("division by zero")
        q = abs(a) // abs(b)
        return i32(q if (a < 0) == (b < 0) else -q)
    _numbers(a, b, "divide")
    fa, fb = f32(a), f32(b)
    if fb == 0.0:
        if fa != fa:
            return fa
        if fa == 0.0:
            return DEFAULT_NAN
        return math.copysign(math.inf, fa) * math.copysign(1.0, fb)
    return f32(fa / fb)


def mod(a: Any, b: Any) -> Any:
    """a % b: C remainder, then the divisor is added once if the remainder is negative."""
    if a.__class__ is int and b.__class__ is int:
        if b == 0:
            raise BuzzError("division by zero")
        r = abs(a) % abs(b)
        if a < 0:
            r = -r
        return i32(r + b) if r < 0 else r
    _numbers(a, b, "take the modulo of")
    fa, fb = f32(a), f32(b)
    try:
        rem = math.fmod(fa, fb)
    except ValueError:  # x % 0.0 and inf % x are NaN in C
        return fa if fa != fa else DEFAULT_NAN
    return f32(rem + fb) if rem < 0 else rem


def power(a: Any, b: Any) -> float:
    """a ^ b: always a float."""
    _numbers(a, b, "raise")
    fa, fb = f32(a), f32(b)
    try:
        return f32(math.pow(fa, fb))
    except ZeroDivisionError:
        return math.inf
    except ValueError:  # negative base with a fractional exponent, or 0 ^ negative
        if fa == 0.0:
            return math.inf
        return DEFAULT_NAN
    except OverflowError:
        odd = fb == int(fb) and int(fb) % 2 == 1
        return -math.inf if fa < 0 and odd else math.inf


def unm(a: Any) -> Any:
    """-a."""
    if a.__class__ is int:
        return i32(-a)
    if a.__class__ is float:
        return -a
    raise BuzzError(f"type mismatch: cannot negate {type_name(a)}")


def _ints(a: Any, b: Any) -> None:
    for x in (a, b):
        if x.__class__ is not int:
            raise BuzzError(f"type mismatch: expected integer, got {type_name(x)}")


def band(a: Any, b: Any) -> int:
    """a & b (integers only)."""
    _ints(a, b)
    return a & b


def bor(a: Any, b: Any) -> int:
    """a | b (integers only)."""
    _ints(a, b)
    return a | b


def bnot(a: Any) -> int:
    """!a, the bitwise not (integers only)."""
    _ints(a, 0)
    return ~a


def lshift(a: Any, b: Any) -> int:
    """a << b with the x86 count rule (b & 31)."""
    _ints(a, b)
    return i32(a << (b & 31))


def rshift(a: Any, b: Any) -> int:
    """a >> b, arithmetic, count b & 31."""
    _ints(a, b)
    return a >> (b & 31)


# ---------------------------------------------------------------- comparison


def equals(a: Any, b: Any) -> bool:
    """a == b. Numbers by value (IEEE), strings by bytes, everything else by identity."""
    ca, cb = a.__class__, b.__class__
    if ca is cb:
        return a == b if ca in _NUM or ca is str else a is b
    if ca in _NUM and cb in _NUM:
        return f32(a) == f32(b)  # an int is converted to binary32 first
    if ca is str and cb in _NUM:
        return a == _as_text(b)
    if cb is str and ca in _NUM:
        return _as_text(a) == b
    return False


def not_equals(a: Any, b: Any) -> bool:
    """a != b."""
    return not equals(a, b)


def order(a: Any, b: Any) -> int | None:
    """-1, 0 or 1 for an ordered pair; None when a NaN makes it unordered.

    Raises a type error for pairs that have no order (nil with a value, two tables,
    closures, userdata), which the reference either answers wrongly or aborts on.
    """
    ca, cb = a.__class__, b.__class__
    if ca is int and cb is int:
        return -1 if a < b else (1 if a > b else 0)
    if ca in _NUM and cb in _NUM:
        fa = a if ca is float else f32(a)
        fb = b if cb is float else f32(b)
        if fa < fb:
            return -1
        if fa > fb:
            return 1
        return 0 if fa == fb else None
    if ca is str or cb is str:
        sa = a if ca is str else _as_text(a)
        sb = b if cb is str else _as_text(b)
        if sa is not None and sb is not None:
            return -1 if sa < sb else (1 if sa > sb else 0)
    if ca is Table and cb is not Table and b is not None:
        return 1
    if cb is Table and ca is not Table and a is not None:
        return -1
    if a is None and b is None:
        return 0
    if a is None or b is None:
        other = b if a is None else a
        raise BuzzError(f"type mismatch: cannot order nil and {type_name(other)}")
    raise BuzzError(f"type mismatch: cannot order {type_name(a)} and {type_name(b)}")


def _as_text(x: Any) -> str | None:
    """The reference compares strings with numbers through their printf text."""
    if x.__class__ is int:
        return str(x)
    if x.__class__ is float:
        return format_float(x)
    return None


def less(a: Any, b: Any) -> bool:
    """a < b."""
    return order(a, b) == -1


def less_equal(a: Any, b: Any) -> bool:
    """a <= b."""
    o = order(a, b)
    return o is not None and o <= 0


def greater(a: Any, b: Any) -> bool:
    """a > b."""
    return order(a, b) == 1


def greater_equal(a: Any, b: Any) -> bool:
    """a >= b."""
    o = order(a, b)
    return o is not None and o >= 0


# ---------------------------------------------------------------- tables


def check_key(k: Any) -> None:
    """Raise unless k can index a table: an int, a non-NaN float or a string."""
    ck = k.__class__
    if ck is int or ck is str:
        return
    if ck is float:
        if k != k:
            raise BuzzError("type mismatch: NaN can't be used as table key")
        return
    raise BuzzError(f"type mismatch: a {type_name(k)} value can't be used as table key")


def tget(t: Any, k: Any) -> Any:
    """t[k], nil when absent."""
    if t.__class__ is not Table:
        raise BuzzError(f"type mismatch: expected table, got {type_name(t)}")
    check_key(k)
    return t.get(k)


def tput(t: Any, k: Any, v: Any) -> None:
    """t[k] = v: nil deletes; a closure is re-bound so that its `self` is t."""
    if t.__class__ is not Table:
        raise BuzzError(f"type mismatch: expected table, got {type_name(t)}")
    check_key(k)
    if v is None:
        t.pop(k, None)
    elif v.__class__ is Closure:
        t[k] = v.rebind(t)
    else:
        t[k] = v
