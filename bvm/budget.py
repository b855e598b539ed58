"""The step budget: a bound on loop iterations, and on wall time.

Loop iterations are counted in translated code by one C call per iteration, `_N()`,
where `_N` is the `__next__` of `itertools.repeat(None, n)`: it raises StopIteration once
`n` iterations are spent, with no Python-level counter on the hot path. The count is
deterministic, so simulations stay reproducible.

Wall time needs nothing on the hot path: when it runs out, a timer thread raises
`BudgetTimeout` inside the VM's thread (CPython delivers it at the next bytecode
boundary, wherever the script is: in a loop, deep in recursion, in a callback), and also
swaps in an exhausted ticker.
"""

from __future__ import annotations

import ctypes
import itertools
import operator
import threading
from typing import Any

from bvm.errors import BuzzBudgetExceeded

# PyThreadState_SetAsyncExc(thread, exc) raises exc in that thread; NULL withdraws it.
_API = ("PyThreadState_SetAsyncExc", ctypes.pythonapi)
_raise_in = ctypes.PYFUNCTYPE(ctypes.c_int, ctypes.c_ulong, ctypes.py_object)(_API)
_withdraw_in = ctypes.PYFUNCTYPE(ctypes.c_int, ctypes.c_ulong, ctypes.c_void_p)(_API)


class BudgetTimeout(BuzzBudgetExceeded):
    """Raised asynchronously in the VM's thread when a step runs out of wall time."""

    def __init__(self, message: str = "budget exceeded: ran out of time") -> None:
        super().__init__(message)


def _exhausted() -> Any:
    return itertools.repeat(None, 0).__next__


class Budget:
    """Installs the ticker `_N` into a namespace and arms the timer, for one VM entry."""

    def __init__(self, namespace: dict[str, Any]) -> None:
        self.namespace = namespace
        self.max_ticks: int | None = None
        self.max_seconds: float | None = None
        self._ticker: Any = itertools.repeat(None)
        self._timer: threading.Timer | None = None
        self._lock = threading.Lock()
        self._thread = 0
        self._timed_out = False
        self._generation = 0
        namespace["_N"] = self._ticker.__next__

    def start(self) -> None:
        """Begin an entry: a fresh allowance of iterations and, if set, of seconds."""
        with self._lock:
            self._timed_out = False
            self._generation += 1
            generation = self._generation
        if self.max_ticks is None:
            self._ticker = itertools.repeat(None)
        else:
            self._ticker = itertools.repeat(None, self.max_ticks)
        self.namespace["_N"] = self._ticker.__next__
        if self.max_seconds is not None:
            self._thread = threading.get_ident()
            self._timer = threading.Timer(self.max_seconds, self._expire, (generation,))
            self._timer.daemon = True
            self._timer.start()

    def stop(self) -> None:
        """End an entry; a timeout that fired but was not yet delivered is withdrawn."""
        with self._lock:
            self._generation += 1
            if self._timed_out:
                _withdraw_in(self._thread, None)
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _expire(self, generation: int) -> None:
        with self._lock:
            if generation != self._generation:
                return  # that entry already ended
            self._timed_out = True
            self.namespace["_N"] = _exhausted()
            _raise_in(self._thread, BudgetTimeout)

    def timeout_message(self) -> str:
        """The message of a time-budget error."""
        return f"budget exceeded: ran longer than {self.max_seconds} s"

    def exceeded(self) -> BuzzBudgetExceeded | None:
        """The budget error if a StopIteration just raised came from the ticker, else None."""
        if self._timed_out:
            return BuzzBudgetExceeded(self.timeout_message())
        if self.max_ticks is not None and operator.length_hint(self._ticker) == 0:
            return BuzzBudgetExceeded(
                f"budget exceeded: more than {self.max_ticks} loop iterations"
            )
        return None
