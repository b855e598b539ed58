"""The `math` table (docs/stdlib.md#math): abs floor ceil round log log2 log10 exp sqrt sin cos
tan asin acos atan min max pi, and `math.rng` (setseed uniform gaussian exponential).

Float results are binary32: the double-precision result of the float32 argument, rounded
once to binary32. C single-precision edge cases come out as C gives them, never as a Python
exception: log(0) = -inf, log(-1), sqrt(-1), asin(2), sin(inf) ... = NaN. A NaN argument is
passed through unchanged; a NaN made from a number has the sign glibc 2.36 gives it on x86-64
(printed `-nan` for log, log2, sqrt, sin, cos, tan; `nan` for log10, asin, acos).

Deliberate differences from the reference (see docs/compat.md):

* `math.rng.gaussian(sd)` gives N(0, sd) and `gaussian(mean, sd)` gives mean + sd*N(0, 1)
  (the reference rejects one argument and uses its first argument for both mean and sd).
  The draw is the reference's polar Box-Muller step, so `gaussian()` consumes the
  generator exactly as the reference does.
* `math.rng.exponential(mean)` works (the reference segfaults): one draw u, then
  float32(mean * -ln((u + 1) / 2**32)), i.e. an inverse transform on a uniform in (0, 1].
* `min`/`max` compare with `bvm.ops.order`, so the strcmp quirks of the reference's cmp
  (`min("c", "a")` = "c") do not leak in, and comparing nil with a value is a type error.
"""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any

from bvm import ops
from bvm.errors import BuzzError
from bvm.stdlib.rng import MersenneTwister
from bvm.values import INT_MAX, INT_MIN, Table, f32, type_name

if TYPE_CHECKING:
    from bvm.host import LibraryHost

_INF = math.inf
_NAN = math.nan
_NEG_NAN = -math.nan  # the x86 default NaN (sign bit set)
_floor = math.floor
_ceil = math.ceil
_sqrt = math.sqrt
_log = math.log
_log2 = math.log2
_log10 = math.log10
_exp = math.exp
_sin = math.sin
_cos = math.cos
_tan = math.tan
_asin = math.asin
_acos = math.acos
_atan2 = math.atan2

# float32(4294967295): the divisor of the reference's uniform forms, as C converts it.
_U32_MAX_F = 4294967296.0
_M64 = 0xFFFFFFFFFFFFFFFF

PI = f32(math.pi)


def _arg(x: Any) -> float:
    """A numeric argument as binary32; the reference type error otherwise."""
    cls = x.__class__
    if cls is float:
        return x
    if cls is int:
        return f32(x)
    raise BuzzError(f"type mismatch: expected float or integer, got {type_name(x)}")


# ---------------------------------------------------------------- natives


def m_abs(_self: Any, x: Any) -> Any:
    """math.abs(x): |x|; for ints C abs, so abs(INT_MIN) = INT_MIN."""
    cls = x.__class__
    if cls is int:
        return x if x >= 0 or x == INT_MIN else -x
    if cls is float:
        return abs(x)
    raise BuzzError(f"type mismatch: expected float or integer, got {type_name(x)}")


def _to_int(x: Any, rounding: Any) -> int:
    """An int argument unchanged; a float rounded, with x86's INT_MIN for NaN, inf and out of
    range; anything else a type error."""
    cls = x.__class__
    if cls is int:
        return x
    if cls is float:
        try:
            r = rounding(x)
        except (ValueError, OverflowError):  # NaN, infinities
            return INT_MIN
        return r if INT_MIN <= r <= INT_MAX else INT_MIN
    raise BuzzError(f"type mismatch: expected float or integer, got {type_name(x)}")


def m_floor(_self: Any, x: Any) -> int:
    """math.floor(x) -> int; ints unchanged; NaN, inf and out of range -> INT_MIN."""
    return _to_int(x, _floor)


def m_ceil(_self: Any, x: Any) -> int:
    """math.ceil(x) -> int; ints unchanged; NaN, inf and out of range -> INT_MIN."""
    return _to_int(x, _ceil)


def m_round(_self: Any, x: Any) -> int:
    """math.round(x) -> int, half away from zero (C roundf); NaN, inf, out of range -> INT_MIN."""
    return _to_int(x, _round_half_away)


def _round_half_away(x: float) -> int:
    a = -x if x < 0 else x
    r = _floor(a)
    if a - r >= 0.5:  # exact: a - floor(a) is representable
        r += 1
    return -r if x < 0 else r


def _logf(fn: Any, invalid: float) -> Any:
    """A C logf-like function: log(+-0) = -inf, log(x < 0) = `invalid`, log(inf) = inf."""

    def impl(_self: Any, x: Any) -> float:
        f = _arg(x)
        if f > 0.0:
            return _INF if f == _INF else f32(fn(f))
        if f == 0.0:
            return -_INF
        return f if f != f else invalid

    return impl


m_log = _logf(_log, _NEG_NAN)
m_log2 = _logf(_log2, _NEG_NAN)
m_log10 = _logf(_log10, _NAN)
m_log.__doc__ = "math.log(x): natural logarithm, binary32."
m_log2.__doc__ = "math.log2(x): base-2 logarithm, binary32."
m_log10.__doc__ = "math.log10(x): base-10 logarithm, binary32."


def m_exp(_self: Any, x: Any) -> float:
    """math.exp(x): e**x, binary32 (overflow -> inf, underflow -> 0)."""
    f = _arg(x)
    if f != f:
        return f
    try:
        return f32(_exp(f))
    except OverflowError:
        return _INF


def m_sqrt(_self: Any, x: Any) -> float:
    """math.sqrt(x): binary32; sqrt(-0) = -0, sqrt(x < 0) = -nan."""
    f = _arg(x)
    if f >= 0.0:
        return f32(_sqrt(f))
    return f if f != f else _NEG_NAN


def _trig(fn: Any) -> Any:
    """A C sinf/cosf/tanf-like function: +-inf -> -nan, NaN passed through."""

    def impl(_self: Any, x: Any) -> float:
        f = _arg(x)
        if f != f:
            return f
        if f == _INF or f == -_INF:
            return _NEG_NAN
        return f32(fn(f))

    return impl


m_sin = _trig(_sin)
m_cos = _trig(_cos)
m_tan = _trig(_tan)
m_sin.__doc__ = "math.sin(x): binary32."
m_cos.__doc__ = "math.cos(x): binary32."
m_tan.__doc__ = "math.tan(x): binary32."


def _arc(fn: Any) -> Any:
    """A C asinf/acosf-like function: |x| > 1 -> nan, NaN passed through."""

    def impl(_self: Any, x: Any) -> float:
        f = _arg(x)
        if -1.0 <= f <= 1.0:
            return f32(fn(f))
        return f if f != f else _NAN

    return impl


m_asin = _arc(_asin)
m_acos = _arc(_acos)
m_asin.__doc__ = "math.asin(x): binary32; |x| > 1 -> nan."
m_acos.__doc__ = "math.acos(x): binary32; |x| > 1 -> nan."


def m_atan(_self: Any, y: Any, x: Any) -> float:
    """math.atan(y, x): atan2f(y, x), binary32."""
    cy, cx = y.__class__, x.__class__
    if cy is not float and cy is not int:
        raise BuzzError(
            f"type mismatch: expected float or integer for argument 1, got {type_name(y)}"
        )
    if cx is not float and cx is not int:
        raise BuzzError(
            f"type mismatch: expected float or integer for argument 2, got {type_name(x)}"
        )
    return f32(_atan2(f32(y), f32(x)))


def m_min(_self: Any, a: Any, b: Any) -> Any:
    """math.min(a, b): a unless a > b (unordered NaN pairs give a, as the reference's cmp)."""
    return b if ops.order(a, b) == 1 else a


def m_max(_self: Any, a: Any, b: Any) -> Any:
    """math.max(a, b): a if a >= b (unordered NaN pairs give a, as the reference's cmp)."""
    return b if ops.order(a, b) == -1 else a


# ---------------------------------------------------------------- math.rng


def uniform_from(u: int, args: tuple[Any, ...]) -> Any:
    """`math.rng.uniform(*args)` for the raw 32-bit draw u (docs/stdlib.md#math formulas).

    () -> u as int32; (n int) -> int32(floor(u * u64(n) / 4294967295)) in 64-bit unsigned
    arithmetic; (x float) -> float32(u) * x / 4294967295 in float32; (a, b) ints ->
    int32(floor(u * u64(b - a) / 4294967295) + a); (a, b) with a float -> float32
    u * (b - a) / 4294967295 + a. (4294967295 is 4294967296.0 once converted to float32.)
    """
    n = len(args)
    if n == 0:
        return u - 0x100000000 if u & 0x80000000 else u
    if n == 1:
        x = args[0]
        if x.__class__ is int:
            r = (u * (x & _M64) & _M64) // 0xFFFFFFFF & 0xFFFFFFFF
            return r - 0x100000000 if r & 0x80000000 else r
        x = _arg(x)
        return f32(f32(f32(u) * x) / _U32_MAX_F)
    a, b = args
    if a.__class__ is int and b.__class__ is int:
        d = (b - a) & 0xFFFFFFFF  # int32 subtraction, then sign-extended to 64 bits
        if d & 0x80000000:
            d |= 0xFFFFFFFF00000000
        r = ((u * d & _M64) // 0xFFFFFFFF + a) & 0xFFFFFFFF
        return r - 0x100000000 if r & 0x80000000 else r
    fa = _arg(a)
    fb = _arg(b)
    return f32(f32(f32(f32(u) * f32(fb - fa)) / _U32_MAX_F) + fa)


def _arity_0_to_2(n: int) -> None:
    """The reference's arity error of uniform/gaussian."""
    if n > 2:
        raise BuzzError(f"wrong number of local variables: expected 0, 1, or 2 parameters, got {n}")


def _minus_one_to_one(u: int) -> float:
    """A raw draw mapped to [-1, 1] in float32, as uniform(-1.0, 1.0) does.

    float32(u) * 2 / 2**32 is exact, so only the final subtraction rounds (and one double
    operation rounded to binary32 is the binary32 operation).
    """
    return f32(f32(u) / 2147483648.0 - 1.0)


def gaussian_from(next_u32: Any, mean: float, sd: float) -> float:
    """mean + sd * n with n ~ N(0, 1) by the polar Box-Muller method (docs/stdlib.md#math).

    Draw x1, x2 in [-1, 1] (float32) until s = x1*x1 + x2*x2 (float32) is in (0, 1);
    n = x1 * sqrt(-2 ln s / s) in double; the result is rounded to binary32. The second
    normal deviate is discarded, as in the reference.
    """
    while True:
        x1 = _minus_one_to_one(next_u32())
        x2 = _minus_one_to_one(next_u32())
        s = f32(f32(x1 * x1) + f32(x2 * x2))
        if 0.0 < s < 1.0:
            break
    return f32(mean + sd * (x1 * _sqrt(-2.0 * _log(s) / s)))


def _make_rng(vm: LibraryHost) -> tuple[Any, Any, Any, Any]:
    """setseed, uniform, gaussian and exponential drawing from `vm.rng`."""

    def r_setseed(_self: Any, seed: Any) -> None:
        """math.rng.setseed(i): re-seed the VM's generator with an integer."""
        if seed.__class__ is not int:
            raise BuzzError(f"type mismatch: expected integer, got {type_name(seed)}")
        vm.rng.seed(seed)
        return None

    def r_uniform(_self: Any, *args: Any) -> Any:
        """math.rng.uniform([n] | [x] | [a, b]): see `uniform_from`."""
        if not args:
            u = vm.rng.next_u32()
            return u - 0x100000000 if u & 0x80000000 else u
        _arity_0_to_2(len(args))
        for x in args:  # check before drawing, so an error consumes nothing
            if x.__class__ is not int and x.__class__ is not float:
                raise BuzzError(f"type mismatch: expected float or integer, got {type_name(x)}")
        return uniform_from(vm.rng.next_u32(), args)

    def r_gaussian(_self: Any, *args: Any) -> float:
        """math.rng.gaussian([[mean,] sd]): a normal deviate, N(0, 1) by default."""
        n = len(args)
        _arity_0_to_2(n)
        if n == 0:
            mean, sd = 0.0, 1.0
        elif n == 1:
            mean, sd = 0.0, _arg(args[0])
        else:
            mean, sd = _arg(args[0]), _arg(args[1])
        return gaussian_from(vm.rng.next_u32, mean, sd)

    def r_exponential(_self: Any, mean: Any) -> float:
        """math.rng.exponential(mean): float32(mean * -ln(u01)), u01 = (u + 1) / 2**32 in (0, 1]."""
        m = _arg(mean)
        u01 = (vm.rng.next_u32() + 1) / 4294967296.0
        return f32(m * (0.0 - _log(u01)))

    return r_setseed, r_uniform, r_gaussian, r_exponential


def register(vm: LibraryHost) -> None:
    """Create `vm.rng` and register the `math` table (C-function ids 33-53)."""
    seed = vm.rng_seed
    if seed is None:
        seed = int(time.time())  # as the reference: non-deterministic unless setseed
    vm.rng = MersenneTwister(seed)
    new = vm.new_native
    t = Table()
    arity: int | None  # a fixed argument count, or None for natives that check their own
    for name, impl, arity in (
        ("abs", m_abs, 1),
        ("floor", m_floor, 1),
        ("ceil", m_ceil, 1),
        ("round", m_round, 1),
        ("log", m_log, 1),
        ("log2", m_log2, 1),
        ("log10", m_log10, 1),
        ("exp", m_exp, 1),
        ("sqrt", m_sqrt, 1),
        ("sin", m_sin, 1),
        ("cos", m_cos, 1),
        ("tan", m_tan, 1),
        ("asin", m_asin, 1),
        ("acos", m_acos, 1),
        ("atan", m_atan, 2),
        ("min", m_min, 2),
        ("max", m_max, 2),
    ):
        t[name] = new(impl, arity, name).rebind(t)
    t["pi"] = PI
    rng = Table()
    r_setseed, r_uniform, r_gaussian, r_exponential = _make_rng(vm)
    for name, impl, arity in (
        ("setseed", r_setseed, 1),
        ("uniform", r_uniform, None),
        ("gaussian", r_gaussian, None),
        ("exponential", r_exponential, 1),
    ):
        rng[name] = new(impl, arity, name).rebind(rng)
    t["rng"] = rng
    vm.globals["math"] = t
