"""The step budget: a bound on loop iterations, and on the processor time of one entry.

Loop iterations (backward jumps: one per `while` iteration, two per `for` iteration, as
the bytecode has them): each translated loop counts down a Python local from `_K` (1,000)
and settles with the budget once per `_K` (`_tick()`) and when it exits or returns
(`_charge(n)`), so the hot path is a local decrement and test. The count is deterministic:
simulations stay reproducible. Translated loops settle in chunks, so there a budget is
noticed at most one chunk per running loop late; the interpreter settles every jump.

Time needs nothing on the hot path: a timer thread wakes when the allowance could be
spent and raises `BudgetTimeout` inside the VM's thread (CPython delivers it at the next
bytecode boundary, wherever the script is: in a loop, deep in recursion, in a callback).
It is only delivered while the VM is inside the entry, and again every 50 ms in case a
host function swallowed it. What is counted is the VM thread's processor time where the
system can tell it (Linux, macOS), else wall time: a runaway loop burns processor time,
while a robot whose computer is busy elsewhere only waits, and must not lose its script
for it (a SITL run of six nodes on a loaded two-core machine did).
"""

from __future__ import annotations

import ctypes
import threading
import time
from typing import Any

from bvm.errors import BuzzBudgetExceeded

#: Loop iterations between two settlements with the budget (even: `for` loops count 2).
CHUNK = 1000
_RETRY = 0.05  # seconds between deliveries of a timeout that has not ended the entry

# PyThreadState_SetAsyncExc(thread, exc) raises exc in that thread.
_API = ("PyThreadState_SetAsyncExc", ctypes.pythonapi)
_raise_in = ctypes.PYFUNCTYPE(ctypes.c_int, ctypes.c_ulong, ctypes.py_object)(_API)


class _Flush(BaseException):
    """Replaces an undelivered timeout, to be taken at once (see `_flush_async_exception`)."""


def _flush_async_exception(thread: int) -> None:
    """Make sure no asynchronous exception is pending for this thread, and none signalled.

    Withdrawing with PyThreadState_SetAsyncExc(thread, NULL) looks simpler, but when the
    timeout was already delivered it leaves CPython's "async exception pending" signal set
    for good (3.11 clears it only on delivering one): every later bytecode check then takes
    the slow path, and with sys.settrace active (debuggers, coverage) the interpreter spins
    forever. So replace whatever is pending by a marker and take it here, on the first
    backward jump, where the loop below waits for it.
    """
    try:
        _raise_in(thread, _Flush)  # may be taken as the call returns: hence inside the try
        while True:
            pass
    except _Flush:
        pass


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
        self._active = False  # the VM thread is inside the entry: a timeout may land
        self._timed_out = False
        self._generation = 0
        self._clock: int | None = None  # the VM thread's CPU clock, if the system has one
        self._spent_at_start = 0.0
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
        if self._timed_out:
            raise BudgetTimeout()
        self.used += n
        if self.max_ticks is not None and self.used > self.max_ticks:
            raise BuzzBudgetExceeded(f"budget exceeded: more than {self.max_ticks} loop iterations")

    def start(self) -> None:
        """Begin an entry: a fresh allowance of iterations and, if set, of seconds."""
        self.used = 0
        if self.max_seconds is None and self._timer is None:
            # No timer thread exists to race with: the flags need no lock (the common,
            # per-step case of a simulator with thousands of robots).
            self._timed_out = False
            self._generation += 1
            self._active = True
            return
        with self._lock:
            self._timed_out = False
            self._generation += 1
            generation = self._generation
        if self.max_seconds is not None:
            self._thread = threading.get_ident()
            self._clock = _thread_clock(self._thread)
            self._spent_at_start = self._spent()
            self._arm(self.max_seconds, generation)
        with self._lock:
            # Only now, with the timer thread running, may a timeout land in this thread
            # (never inside the threading module's own bookkeeping).
            self._active = generation == self._generation

    def stop(self) -> None:
        """End an entry; a timeout that fired but was not yet delivered is withdrawn."""
        if self._timer is None and not self._timed_out and self.max_seconds is None:
            self._generation += 1
            self._active = False
            return
        with self._lock:
            self._generation += 1
            self._active = False
            timed_out = self._timed_out
        timer, self._timer = self._timer, None
        if timer is not None:
            timer.cancel()
        if timed_out and self._thread == threading.get_ident():
            _flush_async_exception(self._thread)

    def _arm(self, seconds: float, generation: int) -> None:
        timer = threading.Timer(seconds, self._expire, (generation,))
        timer.daemon = True
        self._timer = timer
        timer.start()

    def _spent(self) -> float:
        """Seconds on the entry's clock: the VM thread's processor time, else wall time."""
        if self._clock is not None:
            try:
                return time.clock_gettime(self._clock)
            except OSError:  # the thread is gone: nothing more is spent
                return self._spent_at_start
        return time.monotonic()

    def _expire(self, generation: int) -> None:
        with self._lock:
            if generation != self._generation:
                return  # that entry already ended
            left = (self.max_seconds or 0.0) - (self._spent() - self._spent_at_start)
            if left > 0.001 and not self._timed_out:
                # The thread waited (a busy machine) rather than ran: wake when it could
                # have spent the rest.
                self._arm(left, generation)
                return
            if self._active:
                self._timed_out = True
                _raise_in(self._thread, BudgetTimeout)
        # Not yet inside the entry, or the timeout may be swallowed: try again shortly.
        self._arm(_RETRY, generation)

    def timeout_message(self) -> str:
        """The message of a time-budget error."""
        what = "of processor time" if self._clock is not None else ""
        return f"budget exceeded: ran longer than {self.max_seconds} s {what}".rstrip()


def _thread_clock(thread: int) -> int | None:
    """The processor-time clock of `thread` (a `threading.get_ident()`), if the system has one."""
    try:
        return time.pthread_getcpuclockid(thread)
    except (AttributeError, OSError):
        return None
