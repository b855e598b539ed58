"""What the simulated machines' port wrappers share: their end of a line, serving it, pacing.

`SimVehicle` (ArduPilot, PX4), `SimM100Vehicle` and `SimHuskyPorts` each put a sans-I/O
simulator on one or two lines. The way they read a line, wait for it and pace their steps in
real time for `fieldkit vehicle-sim` is the same, so it lives here once:

    line = FdLine(pty.master)                        # the machine's end: raw, non-blocking
    if wait_readable([line.fd], timeout):            # select(); False if the line broke
        handled = read_line(line.read, sim.receive_data)
    run_real_time(10.0, stop, time.monotonic, sim.step, sim.service)
"""

from __future__ import annotations

import os
import select
import threading
from collections.abc import Callable
from typing import Any

#: Bytes one `read()` of a line asks for.
READ_CHUNK = 4096
#: Bytes one service reads from a line at the most: a flooded line cannot starve the steps.
MAX_READ = 1 << 16
#: The longest a real-time runner waits on its lines between two looks at `stop`.
MAX_WAIT_S = 0.05


class FdLine:
    """A machine's end of a line: a descriptor (a pty master, a serial port's) it reads raw."""

    def __init__(self, fd: int, owner: Any = None) -> None:
        """Use `fd`, made non-blocking; `owner` (a pyserial port that owns it) is closed with
        the line, a descriptor given alone is not."""
        os.set_blocking(fd, False)
        self.fd = fd
        self.owner = owner

    def fileno(self) -> int | None:
        """The descriptor."""
        return self.fd

    def read(self) -> bytes:
        """What the line holds (b"" if nothing, or nobody on the other end)."""
        try:
            return os.read(self.fd, READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            return b""  # EIO: nobody has the pty's other end open; nothing to read

    def write(self, data: bytes) -> int:
        """Bytes written; a full line takes fewer, as a UART's buffer would."""
        try:
            return os.write(self.fd, data)
        except OSError:  # full (EAGAIN), or nobody listening
            return 0

    def close(self) -> None:
        """Close a port this line opened (a descriptor it was given stays open)."""
        if self.owner is not None:
            try:
                self.owner.close()
            except Exception:  # closing a dead port must not fail
                pass


def wait_readable(fds: list[int], timeout: float) -> bool:
    """Wait up to `timeout` seconds for one of `fds` to have bytes (none, or 0 s: no wait);
    False when select() fails (a line closed under us), True otherwise."""
    if timeout > 0 and fds:
        try:
            select.select(fds, [], [], timeout)
        except (OSError, ValueError):
            return False
    return True


def read_line(read: Callable[[], bytes], receive: Callable[[bytes], int]) -> int:
    """Feed `receive` what `read` gives until the line is empty (or `MAX_READ` bytes have
    come); the good frames `receive` counted."""
    handled = 0
    total = 0
    while total < MAX_READ:
        data = read()
        if not data:
            break
        total += len(data)
        handled += receive(data)
    return handled


def run_real_time(
    rate_hz: float,
    stop: threading.Event,
    clock: Callable[[], float],
    step: Callable[[float], None],
    service: Callable[[float], object],
    *,
    can_wait: Callable[[], bool] | None = None,
) -> None:
    """Call `step(1 / rate_hz)` at `rate_hz` on `clock` until `stop` is set, and between
    steps `service(wait)`, which serves the lines waiting up to `wait` for a byte.

    `can_wait` says whether `service` can wait now (a line with a descriptor to select()
    on); when it cannot, the runner waits on `stop` instead, so that it does not spin.
    """
    period = 1.0 / rate_hz
    next_t = clock()
    while not stop.is_set():
        now = clock()
        if now >= next_t:
            step(period)
            next_t += period
            if next_t < now - 1.0:
                next_t = now  # suspended for a while: resume, do not race to catch up
            continue
        wait = min(next_t - now, MAX_WAIT_S)
        if can_wait is not None and not can_wait():
            stop.wait(wait)
        service(wait)


__all__ = ["MAX_READ", "READ_CHUNK", "FdLine", "read_line", "run_real_time", "wait_readable"]
