"""math.rng (docs/stdlib.md#math): the quirkily seeded Mersenne Twister and four draw functions."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bvm.errors import BuzzError
from bvm.stdlib import mathlib
from bvm.stdlib.rng import MersenneTwister, quirky_init
from bvm.values import INT_MAX, INT_MIN, Table, f32, i32

try:
    from test_stdlib_install import call, make_vm
except ImportError:  # tests/ imported as a package
    from tests.test_stdlib_install import call, make_vm

U32_MAX = 0xFFFFFFFF
u32s = st.integers(0, U32_MAX)
int32s = st.integers(INT_MIN, INT_MAX)


class Fixed:
    """A stand-in generator returning given raw draws."""

    def __init__(self, *draws: int) -> None:
        self.draws = list(draws)

    def next_u32(self) -> int:
        return self.draws.pop(0)

    def seed(self, seed: int) -> None:
        raise AssertionError("not expected")


def vm_with(*draws: int) -> Any:
    vm = make_vm()
    vm.rng = Fixed(*draws)
    return vm


# ---------------------------------------------------------------- the generator


def test_reference_vector() -> None:
    vm = make_vm()
    assert call(vm, "math.rng.setseed", 5) is None
    assert call(vm, "math.rng.uniform") == -1327749956
    assert call(vm, "math.rng.uniform") == 1383343382
    assert [i32(u) for u in _model_outputs(_model_init(5), 2)] == [-1327749956, 1383343382]


def _standard_init(seed: int) -> list[int]:
    """Standard MT19937 init_genrand (logical shift)."""
    s = [seed & U32_MAX]
    for k in range(1, 624):
        x = s[-1]
        s.append((1812433253 * (x ^ (x >> 30)) + k) & U32_MAX)
    return s


def _model_init(seed: int) -> list[int]:
    """The seeding recurrence of docs/stdlib.md#math, written independently."""
    s = [seed & U32_MAX]
    for k in range(1, 624):
        x = i32(s[k - 1])
        s.append((1812433253 * ((x ^ (x >> 30)) & U32_MAX) + k) & U32_MAX)
    return s


def _model_outputs(state: list[int], count: int) -> list[int]:
    """Textbook MT19937 genrand_int32 from a given initial state (pure Python)."""
    s = list(state)
    out = []
    i = 624
    for _ in range(count):
        if i >= 624:
            for k in range(624):
                y = (s[k] & 0x80000000) | (s[(k + 1) % 624] & 0x7FFFFFFF)
                s[k] = s[(k + 397) % 624] ^ (y >> 1) ^ (0x9908B0DF if y & 1 else 0)
            i = 0
        y = s[i]
        i += 1
        y ^= y >> 11
        y ^= (y << 7) & 0x9D2C5680
        y ^= (y << 15) & 0xEFC60000
        y ^= y >> 18
        out.append(y)
    return out


def test_the_model_is_textbook_mt19937() -> None:
    # The published first outputs of MT19937 with init_genrand(5489).
    assert _model_outputs(_standard_init(5489), 2) == [3499211612, 581869302]


def test_standard_seeding_would_differ() -> None:
    # Standard MT19937 (logical shift) seeded with 5 starts with 953453411 (docs/stdlib.md#math).
    assert _model_outputs(_standard_init(5), 1) == [953453411]
    assert MersenneTwister(5).next_u32() != 953453411


@given(int32s)
def test_init_matches_the_spec_recurrence(seed: int) -> None:
    assert quirky_init(seed) == _model_init(seed)


@settings(max_examples=10)
@given(int32s)
def test_generation_is_standard_mt19937(seed: int) -> None:
    mt = MersenneTwister(seed)
    expected = _model_outputs(_model_init(seed), 1300)  # crosses two twists
    assert [mt.next_u32() for _ in range(1300)] == expected


def test_reseeding_restarts_the_sequence() -> None:
    mt = MersenneTwister(123)
    first = [mt.next_u32() for _ in range(700)]
    mt.seed(123)
    assert [mt.next_u32() for _ in range(700)] == first
    assert all(0 <= u <= U32_MAX for u in first)


def test_negative_seed_is_its_int32_bits() -> None:
    a, b = MersenneTwister(-1), MersenneTwister(U32_MAX)
    assert [a.next_u32() for _ in range(5)] == [b.next_u32() for _ in range(5)]


def test_setseed_requires_an_integer() -> None:
    vm = make_vm()
    with pytest.raises(BuzzError) as e:
        call(vm, "math.rng.setseed", 5.0)
    assert e.value.message == "type mismatch: expected integer, got float"
    with pytest.raises(BuzzError, match="expected 1 parameters, got 0"):
        call(vm, "math.rng.setseed")


def test_setseed_resets_the_vm_generator() -> None:
    vm = make_vm(rng_seed=77)
    call(vm, "math.rng.setseed", 5)
    assert call(vm, "math.rng.uniform") == -1327749956


# ---------------------------------------------------------------- uniform


@pytest.mark.parametrize(
    "u,expected", [(0, 0), (1, 1), (0x7FFFFFFF, INT_MAX), (0x80000000, INT_MIN), (U32_MAX, -1)]
)
def test_uniform_no_args_is_the_raw_draw_as_int32(u: int, expected: int) -> None:
    assert call(vm_with(u), "math.rng.uniform") == expected


@pytest.mark.parametrize(
    "u,n,expected",
    [
        (0, 10, 0),
        (U32_MAX, 10, 10),
        (U32_MAX - 1, 10, 9),
        (2147483648, 10, 5),  # floor(2^31 * 10 / (2^32 - 1)) = 5
        (1000, 0, 0),
        # Negative n wraps to a huge u64: u * (2^64 - 1) mod 2^64 = 2^64 - u.
        (1, -1, i32((2**64 - 1) // U32_MAX)),
        (3, -1, i32((2**64 - 3) // U32_MAX)),
        (U32_MAX, INT_MAX, INT_MAX),
    ],
)
def test_uniform_int(u: int, n: int, expected: int) -> None:
    r = call(vm_with(u), "math.rng.uniform", n)
    assert r == expected and r.__class__ is int


@given(u32s, int32s)
def test_uniform_int_formula(u: int, n: int) -> None:
    expected = i32(((u * (n % 2**64)) % 2**64) // U32_MAX)
    assert mathlib.uniform_from(u, (n,)) == expected


@pytest.mark.parametrize(
    "u,x,expected",
    [
        (0, 1.0, 0.0),
        (U32_MAX, 1.0, 1.0),  # float32(2^32 - 1) = 2^32
        (2147483648, 1.0, 0.5),
        (2147483648, 3.0, 1.5),
        (1, 1.0, f32(1 / 2**32)),
        (2**31, -2.0, -1.0),
    ],
)
def test_uniform_float(u: int, x: float, expected: float) -> None:
    r = call(vm_with(u), "math.rng.uniform", x)
    assert r == expected and r.__class__ is float


@given(u32s, st.floats(width=32, allow_nan=False))
def test_uniform_float_formula(u: int, x: float) -> None:
    expected = f32(f32(f32(float(u)) * x) / 4294967296.0)
    r = mathlib.uniform_from(u, (x,))
    assert r == expected or (math.isnan(r) and math.isnan(expected))
    assert r != r or f32(r) == r


@pytest.mark.parametrize(
    "u,a,b,expected",
    [
        (0, 1, 2, 1),
        (U32_MAX - 1, 1, 2, 1),
        (U32_MAX, 1, 2, 2),  # uniform(1, 2) is 1 except for u = 2^32 - 1
        (2147483648, 0, 100, 50),
        (2147483648, -10, 10, 0),
        (U32_MAX, -10, 10, 10),
        (0, 5, 3, 5),
        # b < a: b - a = -2 sign-extends to 2^64 - 2; 1 * (2^64 - 2) // (2^32 - 1) wraps.
        (1, 5, 3, i32((2**64 - 2) // U32_MAX + 5)),
        # b - a overflows int32: INT_MAX - INT_MIN wraps to -1.
        (2, INT_MIN, INT_MAX, i32((2**64 - 2) // U32_MAX + INT_MIN)),
    ],
)
def test_uniform_int_range(u: int, a: int, b: int, expected: int) -> None:
    r = call(vm_with(u), "math.rng.uniform", a, b)
    assert r == expected and r.__class__ is int


@given(u32s, int32s, int32s)
def test_uniform_int_range_formula(u: int, a: int, b: int) -> None:
    d = i32(b - a) % 2**64
    expected = i32(((u * d) % 2**64) // U32_MAX + a)
    assert mathlib.uniform_from(u, (a, b)) == expected


@given(u32s, st.integers(-1000, 1000), st.integers(0, 1000))
def test_uniform_int_range_stays_in_range(u: int, a: int, span: int) -> None:
    r = mathlib.uniform_from(u, (a, a + span))
    assert a <= r <= a + span


@pytest.mark.parametrize(
    "u,a,b,expected",
    [
        (0, 1.0, 2.0, 1.0),
        (U32_MAX, 1.0, 2.0, 2.0),
        (2147483648, 0.0, 10.0, 5.0),
        (2147483648, -1, 1.0, 0.0),  # the int operand is converted
        (2147483648, 2.0, 4, 3.0),
    ],
)
def test_uniform_float_range(u: int, a: Any, b: Any, expected: float) -> None:
    r = call(vm_with(u), "math.rng.uniform", a, b)
    assert r == expected and r.__class__ is float


@given(u32s, st.floats(-1e6, 1e6, width=32), st.one_of(st.integers(-9, 9), st.floats(width=32)))
def test_uniform_float_range_formula(u: int, a: float, b: Any) -> None:
    fa, fb = f32(a), f32(b)
    expected = f32(f32(f32(f32(float(u)) * f32(fb - fa)) / 4294967296.0) + fa)
    r = mathlib.uniform_from(u, (a, b))
    assert r == expected or (math.isnan(r) and math.isnan(expected))


def test_uniform_arity_and_types() -> None:
    vm = vm_with()  # no draws: errors must not consume any
    with pytest.raises(BuzzError) as e:
        call(vm, "math.rng.uniform", 1, 2, 3)
    assert e.value.message == (
        "wrong number of local variables: expected 0, 1, or 2 parameters, got 3"
    )
    for args in (("1",), (1, None), (Table(), 2.0)):
        with pytest.raises(BuzzError, match="type mismatch: expected float or integer, got"):
            call(vm, "math.rng.uniform", *args)


def test_uniform_statistics_from_the_real_generator() -> None:
    vm = make_vm(rng_seed=42)
    draws = [call(vm, "math.rng.uniform", 0, 9) for _ in range(5000)]
    assert set(draws) == set(range(9))  # 9 only when u = 2^32 - 1
    floats = [call(vm, "math.rng.uniform", 1.0) for _ in range(5000)]
    assert all(0.0 <= x <= 1.0 for x in floats)
    assert abs(sum(floats) / len(floats) - 0.5) < 0.03


# ---------------------------------------------------------------- gaussian


def to_unit(u: int) -> float:
    """The [-1, 1] mapping of the polar method (as uniform(-1.0, 1.0))."""
    return f32(f32(f32(f32(float(u)) * 2.0) / 4294967296.0) - 1.0)


def polar(x1: float, x2: float) -> float:
    s = f32(f32(x1 * x1) + f32(x2 * x2))
    return x1 * math.sqrt(-2.0 * math.log(s) / s)


def test_gaussian_hand_computed() -> None:
    # u = 3 * 2^30 -> 0.5, u = 2^31 -> 0.0: s = 0.25, n = 0.5 * sqrt(-2 ln 0.25 / 0.25).
    n = 0.5 * math.sqrt(-2.0 * math.log(0.25) / 0.25)
    assert call(vm_with(3 * 2**30, 2**31), "math.rng.gaussian") == f32(n)
    assert call(vm_with(3 * 2**30, 2**31), "math.rng.gaussian", 2) == f32(2 * n)
    assert call(vm_with(3 * 2**30, 2**31), "math.rng.gaussian", 10, 2.0) == f32(10 + 2 * n)


def test_gaussian_rejects_pairs_outside_the_unit_disc() -> None:
    vm = vm_with(U32_MAX, U32_MAX, 2**31, 2**31, 3 * 2**30, 2**31, 7)
    # (1, 1): s = 2 rejected; (0, 0): s = 0 rejected; then (0.5, 0) accepted.
    assert call(vm, "math.rng.gaussian") == f32(polar(0.5, 0.0))
    assert vm.rng.draws == [7]  # exactly six draws consumed, the second deviate discarded


@given(st.lists(u32s, min_size=2, max_size=2), st.floats(-100, 100), st.floats(0, 10))
def test_gaussian_property(draws: list[int], mean: float, sd: float) -> None:
    x1, x2 = to_unit(draws[0]), to_unit(draws[1])
    s = f32(f32(x1 * x1) + f32(x2 * x2))
    if not 0.0 < s < 1.0:
        return
    mean, sd = f32(mean), f32(sd)
    r = mathlib.gaussian_from(iter(draws).__next__, mean, sd)
    assert r == f32(mean + sd * polar(x1, x2))
    assert f32(r) == r


def test_gaussian_statistics_from_the_real_generator() -> None:
    vm = make_vm(rng_seed=7)
    xs = [call(vm, "math.rng.gaussian", 3.0, 2) for _ in range(4000)]
    mean = sum(xs) / len(xs)
    sd = math.sqrt(sum((x - mean) ** 2 for x in xs) / len(xs))
    assert abs(mean - 3.0) < 0.15 and abs(sd - 2.0) < 0.15


def test_gaussian_arity_and_types() -> None:
    vm = vm_with()
    with pytest.raises(BuzzError, match="expected 0, 1, or 2 parameters, got 3"):
        call(vm, "math.rng.gaussian", 1, 2, 3)
    with pytest.raises(BuzzError, match="expected float or integer, got string"):
        call(vm, "math.rng.gaussian", "1")
    with pytest.raises(BuzzError, match="expected float or integer, got nil"):
        call(vm, "math.rng.gaussian", 0, None)


# ---------------------------------------------------------------- exponential


@pytest.mark.parametrize(
    "u,mean,expected",
    [
        (U32_MAX, 1.0, 0.0),  # u01 = 1
        (2**31 - 1, 1.0, f32(math.log(2))),  # u01 = 1/2
        (2**31 - 1, 3, f32(3 * math.log(2))),
        (0, 1.0, f32(32 * math.log(2))),  # u01 = 2^-32, the smallest
        (2**30 - 1, 2.0, f32(2 * math.log(4))),
    ],
)
def test_exponential_hand_computed(u: int, mean: Any, expected: float) -> None:
    r = call(vm_with(u), "math.rng.exponential", mean)
    assert r == expected and r.__class__ is float
    assert math.copysign(1.0, r) > 0


@given(u32s, st.floats(0, 1e6, width=32))
def test_exponential_property(u: int, mean: float) -> None:
    vm = vm_with(u)
    r = call(vm, "math.rng.exponential", mean)
    assert r >= 0.0 and f32(r) == r
    assert r == f32(mean * -math.log((u + 1) / 2**32)) or r == 0.0


def test_exponential_statistics_from_the_real_generator() -> None:
    vm = make_vm(rng_seed=11)
    xs = [call(vm, "math.rng.exponential", 4) for _ in range(4000)]
    assert abs(sum(xs) / len(xs) - 4.0) < 0.3


def test_exponential_arity_and_types() -> None:
    vm = vm_with()
    with pytest.raises(BuzzError, match="expected 1 parameters, got 0"):
        call(vm, "math.rng.exponential")
    with pytest.raises(BuzzError, match="expected float or integer, got table"):
        call(vm, "math.rng.exponential", Table())


def test_a_draw_held_across_a_reseed_follows_the_new_seed() -> None:
    """The state is made on the first draw; a re-seed after that reloads the same
    generator, so a `next_u32` taken before the re-seed draws the new sequence."""
    from bvm.stdlib.rng import MersenneTwister

    lazy = MersenneTwister(7)
    held_before_any_draw = lazy.next_u32
    first = held_before_any_draw()
    held = lazy.next_u32
    lazy.seed(7)
    assert held() == first
    fresh = MersenneTwister(5)
    lazy.seed(5)
    assert [held() for _ in range(3)] == [fresh.next_u32() for _ in range(3)]
    assert held_before_any_draw() == fresh.next_u32()
