"""The Mersenne Twister behind `math.rng`, seeded with the reference's signed-shift quirk.

Generation and tempering are standard MT19937. Seeding is not: the reference keeps the
state as int32 and its init recurrence shifts right arithmetically (docs/stdlib.md#math):

    s[0] = seed
    s[k] = u32(1812433253 * u32(x ^ (x >> 30)) + k)    with x = s[k-1] as int32

so `setseed(5)` then `uniform()` gives -1327749956, 1383343382 (standard MT19937 would
start with 953453411).
"""

from __future__ import annotations

import random
from collections.abc import Callable
from functools import partial

_N = 624
_MASK = 0xFFFFFFFF
_UPPER = 0x80000000


def quirky_init(seed: int) -> list[int]:
    """The 624-word initial state the reference derives from `seed` (signed shift)."""
    x = seed & _MASK
    state = [x]
    append = state.append
    for k in range(1, _N):
        sx = x - 0x100000000 if x & _UPPER else x  # the previous word as int32
        x = (1812433253 * ((sx ^ (sx >> 30)) & _MASK) + k) & _MASK
        append(x)
    return state


class MersenneTwister:
    """MT19937 with the reference seeding quirk; `next_u32()` returns the raw 32-bit output.

    The generation runs in CPython's `random.Random`, which is standard MT19937 (genrand
    with tempering; `getrandbits(32)` is one raw output): it is loaded with the quirky
    initial state, so only the seeding is done here. The state is made on the first draw:
    every robot of a simulated swarm has a generator, and most scripts never draw.
    """

    __slots__ = ("_gen", "_seed", "next_u32")

    def __init__(self, seed: int = 5489) -> None:
        self._gen: random.Random | None = None
        self._seed = seed
        # The next tempered 32-bit output, as an unsigned int in [0, 2**32).
        self.next_u32: Callable[[], int] = self._first

    def seed(self, seed: int) -> None:
        """Re-seed (only the low 32 bits of `seed` matter, as for the reference's int32)."""
        self._seed = seed
        if self._gen is not None:  # drawn from already: the same generator, a new state
            self._gen.setstate(_state(seed))

    def _first(self) -> int:
        """The first draw: make the generator, then draw straight from it."""
        gen = self._gen
        if gen is None:  # a caller may hold this method across draws: make it only once
            gen = self._gen = random.Random(0)
            gen.setstate(_state(self._seed))
            self.next_u32 = partial(gen.getrandbits, 32)
        return gen.getrandbits(32)


def _state(seed: int) -> tuple[object, ...]:
    """`random.Random.setstate`'s argument for the reference's state from `seed`."""
    return (3, (*quirky_init(seed), _N), None)
