"""Where the fuzzers' random decisions come from.

Every generator in this package takes a `Chooser`, so one generator serves both
hypothesis (which records, replays and shrinks each decision) and the campaign's plain
seeded `random.Random` loop (which is much faster per input and has no example cap).
Decisions are arranged so that *small* draws mean *simple* programs: hypothesis shrinks
integers toward their lower bound, which then picks the first (simplest) option.
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from typing import Any, Protocol, TypeVar

T = TypeVar("T")


class Chooser(Protocol):
    """A source of random decisions."""

    def integer(self, lo: int, hi: int) -> int:
        """An integer in [lo, hi]; shrinks toward lo."""
        ...

    def chance(self, p: float) -> bool:
        """True with probability p; shrinks toward False."""
        ...

    def choice(self, options: Sequence[T]) -> T:
        """One of the options; shrinks toward the first one."""
        ...

    def raw(self, n: int) -> bytes:
        """n random bytes; shrinks toward zero bytes."""
        ...


class RandomChooser:
    """Decisions from a seeded `random.Random` (the campaign loop)."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng

    def integer(self, lo: int, hi: int) -> int:
        """An integer in [lo, hi]."""
        return self.rng.randint(lo, hi)

    def chance(self, p: float) -> bool:
        """True with probability p."""
        return self.rng.random() < p

    def choice(self, options: Sequence[T]) -> T:
        """One of the options, uniformly."""
        return options[self.rng.randrange(len(options))]

    def raw(self, n: int) -> bytes:
        """n random bytes."""
        return self.rng.randbytes(n)


class HypothesisChooser:
    """Decisions drawn from hypothesis's `st.data()`, so failures shrink."""

    def __init__(self, data: Any) -> None:
        from hypothesis import strategies as st

        self._st = st
        self.data = data

    def integer(self, lo: int, hi: int) -> int:
        """An integer in [lo, hi] (shrinks toward lo)."""
        return self.data.draw(self._st.integers(lo, hi))

    def chance(self, p: float) -> bool:
        """True with probability ~p (shrinks toward False)."""
        return self.data.draw(self._st.integers(0, 999)) >= 1000 - int(p * 1000)

    def choice(self, options: Sequence[T]) -> T:
        """One of the options (shrinks toward the first)."""
        return options[self.integer(0, len(options) - 1)]

    def raw(self, n: int) -> bytes:
        """n bytes (shrinks toward zeros)."""
        return self.data.draw(self._st.binary(min_size=n, max_size=n))
