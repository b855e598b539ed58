"""The step budget: a bound on loop iterations, and on wall time.

Loop iterations: each translated loop counts down a Python local from `_K` (1,000) and
settles with the budget once per `_K` iterations (`_tick()`) and when it exits or returns
(`_charge(n)`), so the hot path is a local decrement and test. The count is deterministic:
simulations stay reproducible. It is settled in chunks, so a budget is noticed at most one
chunk per running loop late; the interpreter settles every iteration.

Wall time needs nothing on the hot path: when it runs out, a timer thread raises
`BudgetTimeout` inside the VM's thread (CPython delivers it at the next bytecode
boundary, wherever the script is: in a loop, deep in recursion, in a callback).
"""

from __future__ import annotations

import ctypes
import threading
from typing import Any

from bvm.errors import BuzzBudgetExceeded

#: Loop iterations between two settlements with the budget.
CHUNK = 1000

# PyThreadState_SetAsyncExc(thread, exc) raises exc in that thread; NULL withdraws it.
_API = ("PyThreadState_SetAsyncExc", ctypes.pythonapi)
_raise_in = ctypes.PYFUNCTYPE(ctypes.c_int, ctypes.c_ulong, ctypes.py_object)(_API)
_withdraw_in = ctypes.PYFUNCTYPE(ctypes.c_int, ctypes.c_ulong, ctypes.c_void_p)(_API)


class BudgetTimeout(BuzzBudgetExceeded):
    """Raised asynchronously in the VM's thread when a step runs out of wall time."""

    def __init__(self, message: str = "budget exceeded: ran out of time") -> None:
        super().__init__(message)


class Budget:
    """Counts one VM entry's loop iterations and arms its timer."""

    def __init__(self, namespace: dict[str, Any]) -> None:
        self.max_ticks: int | None = None
        self.max_seconds: float | None = None
        self.used = 0
        self._timer: threading.Timer | None = None
        self._lock = threading.Lock()
        self._thread = 0
        self._timed_out = False
        self._generation = 0
        self.install(namespace)

    def install(self, namespace: dict[str, Any]) -> None:
        """Give translated code its names: `_K`, `_tick()`, `_charge(n)`."""
        namespace["_K"] = CHUNK
        namespace["_tick"] = self.tick
        namespace["_charge"] = self.charge

    def tick(self) -> int:
        """A loop finished a chunk of iterations: settle it; returns the next chunk."""
        self.charge(CHUNK)
        return CHUNK

    def charge(self, n: int) -> None:
        """Count `n` loop iterations; raise once the budget is spent."""
        self.used += n
        if self.max_ticks is not None and self.used > self.max_ticks:
            raise BuzzBudgetExceeded(f"budget exceeded: more than {self.max_ticks} loop iterations")

    def start(self) -> None:
        """Begin an entry: a fresh allowance of iterations and, if set, of seconds."""
        with self._lock:
            self._timed_out = False
            self._generation += 1
            generation = self._generation
        self.used = 0
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
            _raise_in(self._thread, BudgetTimeout)

    def timeout_message(self) -> str:
        """The message of a time-budget error."""
        return f"budget exceeded: ran longer than {self.max_seconds} s"
