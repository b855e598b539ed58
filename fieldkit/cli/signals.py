"""Ctrl-C and SIGTERM as a normal end of a long run: an event the run's loop checks."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def stop_on_signals() -> Iterator[threading.Event]:
    """An event Ctrl-C (SIGINT) and SIGTERM set: the run ends normally, results written.
    A second Ctrl-C interrupts at once.

    A handler, not KeyboardInterrupt: Python raises that wherever the main thread happens
    to be, and where it is in a garbage-collector callback, a weakref callback or a
    `__del__`, it is printed and dropped, and the run goes on (a `sim run --ground` of the
    suite, on a loaded machine, did not stop in 60 s). Only the main thread may take
    signals; elsewhere (a test running the command in a thread) nothing is installed.
    """
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return

    def first(signum: int, _frame: object) -> None:
        stop.set()
        signal.signal(signal.SIGINT, signal.default_int_handler)

    old = {sig: signal.signal(sig, first) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)


__all__ = ["stop_on_signals"]
