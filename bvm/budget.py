"""The step budget: a bound on loop iterations plus calls, and on wall time.

Translated code pays for it with one C call per loop iteration and per function entry,
`_N()`, where `_N` is the `__next__` of `itertools.repeat(None, n)`: it raises
StopIteration once `n` ticks are spent, with no Python-level counter on the hot path.
A wall-time budget is enforced by a timer that swaps in an exhausted ticker.
"""

from __future__ import annotations

import itertools
import operator
import threading
from typing import Any

from bvm.errors import BuzzBudgetExceeded


def _exhausted() -> Any:
    it = itertools.repeat(None, 0)
    return it.__next__


class Budget:
    """Installs the ticker `_N` into a namespace for the duration of one VM entry."""

    def __init__(self, namespace: dict[str, Any]) -> None:
        self.namespace = namespace
        self.max_ticks: int | None = None
        self.max_seconds: float | None = None
        self._ticker: Any = itertools.repeat(None)
        self._timer: threading.Timer | None = None
        self._timed_out = False
        self._generation = 0
        namespace["_N"] = self._ticker.__next__

    def start(self) -> None:
        """Begin an entry: a fresh allowance of ticks and, if set, of seconds."""
        self._timed_out = False
        self._generation += 1
        if self.max_ticks is None:
            self._ticker = itertools.repeat(None)
        else:
            self._ticker = itertools.repeat(None, self.max_ticks)
        self.namespace["_N"] = self._ticker.__next__
        if self.max_seconds is not None:
            generation = self._generation
            self._timer = threading.Timer(self.max_seconds, self._expire, (generation,))
            self._timer.daemon = True
            self._timer.start()

    def stop(self) -> None:
        """End an entry."""
        self._generation += 1
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _expire(self, generation: int) -> None:
        if generation == self._generation:
            self._timed_out = True
            self.namespace["_N"] = _exhausted()

    def exceeded(self) -> BuzzBudgetExceeded | None:
        """The budget error if a StopIteration just raised came from the ticker, else None."""
        if self._timed_out:
            return BuzzBudgetExceeded(f"budget exceeded: ran longer than {self.max_seconds} s")
        if self.max_ticks is not None and operator.length_hint(self._ticker) == 0:
            return BuzzBudgetExceeded(
                f"budget exceeded: more than {self.max_ticks} loop iterations and calls"
            )
        return None
