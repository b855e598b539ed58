"""A serial device that may vanish and come back: the ports of the non-MAVLink links.

A USB cable that works loose makes a device vanish (reads fail with EIO, or the tty reads end
of file; the node file goes) and come back a moment later, possibly as another ttyUSBn behind
the same udev symlink. `ReopeningSerial` is one pyserial port opened by path that never
raises into the node's loop for that: a read or write that fails closes the port and tells
`on_lost` once per outage with a short reason (`read failed: Input/output error`), what is
written meanwhile is dropped and counted (`bytes_dropped`), and `try_reopen()` (on each poll)
opens the same path again at `ReopenPolicy`'s pace, telling `on_back` the seconds it was down.
Its `reopen` is that policy, read by the node for STATUS and summary.json as it reads the
MAVLink link's (`fieldkit.node.autopilot_port`).

    port = ReopeningSerial("/dev/m100", 230400, clock=clock, name="/dev/m100")
    port.on_lost = lambda reason: event("link", f"/dev/m100 lost ({reason}); reopening")
    port.on_back = lambda down: event("reopened", f"/dev/m100 back after {down:g} s")
    while running:
        port.try_reopen()          # nothing unless it is down and an attempt is due
        data = port.read(4096)     # b"" when nothing came, or while down
        port.write_some(frame)     # bytes the line took (0 while down: dropped)

`port_reason` and `close_quietly` are the wording and the close the MAVLink link
(`fieldkit.vehicle.link.Autopilot`, on pymavlink's own serial connection) uses as well.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

import serial

from fieldkit.vehicle.autopilot import describe_error
from fieldkit.vehicle.reopen import DEFAULT_INTERVAL_S, ReopenPolicy

#: What pyserial and the OS raise when a device cannot be opened, read or written.
PORT_ERRORS: tuple[type[BaseException], ...] = (serial.SerialException, OSError, ValueError)


def close_quietly(conn: Any) -> None:
    """Close a port or connection; a dead port's close must not fail."""
    try:
        conn.close()
    except Exception:  # noqa: BLE001  # the device is gone already: nothing to report
        pass


def port_reason(what: str, e: BaseException) -> str:
    """Why a serial port failed, short: "read failed: Input/output error".

    pyserial wraps the OS error in text of its own ("read failed: [Errno 5] ..."), and
    reports a tty at end of file (the USB device went away) as "device reports readiness
    to read but returned no data (device disconnected or multiple access on port?)".
    """
    cause = e.__cause__ or e.__context__
    if isinstance(e, OSError) and isinstance(e.errno, int) and e.errno > 0:
        return f"{what}: {os.strerror(e.errno)}"
    if isinstance(cause, OSError) and isinstance(cause.errno, int) and cause.errno > 0:
        return f"{what}: {os.strerror(cause.errno)}"
    if "returned no data" in str(e):
        return f"{what}: end of file, device disconnected"
    return f"{what}: {describe_error(e)}"


class ReopeningSerial:
    """One serial device opened by path, closed when it fails and reopened when it is back."""

    def __init__(
        self,
        path: str,
        baud: int,
        *,
        clock: Callable[[], float] = time.monotonic,
        reopen_interval_s: float = DEFAULT_INTERVAL_S,
        write_timeout: float | None = 0,
    ) -> None:
        """Open `path` at `baud` now (raises what pyserial raises: `PORT_ERRORS`).

        Reads never block; `write_timeout` is pyserial's for `write_all` (0: never block).
        A pyserial URL (`loop://`, `socket://...`) opens too, but is not a device that comes
        back: a failure there is only counted (`errors`). A lost device is tried again every
        `reopen_interval_s` seconds of `clock`.
        """
        self.path = path
        self.baud = baud
        self.url = "://" in path  # a pyserial URL handler, not a device node
        self.write_timeout = write_timeout
        self._clock = clock
        self.reopen = ReopenPolicy(reopen_interval_s)
        self.bytes_dropped = 0  # written while the device was gone
        self.errors = 0  # reads and writes that failed
        self.closed = False
        #: Told once per outage, with the reason; then when it is back, with seconds down.
        self.on_lost: Callable[[str], None] | None = None
        self.on_back: Callable[[float], None] | None = None
        #: Told of each failure of a port that is not reopened (a URL's), with the reason.
        self.on_error: Callable[[str], None] | None = None
        self.port: serial.SerialBase | None = self._open()

    def _open(self) -> serial.SerialBase:
        # A plain path gives a serial.Serial, as opening it directly would.
        return serial.serial_for_url(
            self.path, baudrate=self.baud, timeout=0, write_timeout=self.write_timeout
        )

    @property
    def down(self) -> bool:
        """Whether the device is lost and not reopened yet."""
        return self.port is None and not self.closed

    def fileno(self) -> int | None:
        """The descriptor to select() on (None while down, or for a URL port without one)."""
        port = self.port
        if port is None:
            return None
        try:
            fd = port.fileno()
        except Exception:  # noqa: BLE001  # URL handlers (loop://) may have none
            return None
        return fd if isinstance(fd, int) and fd >= 0 else None

    def read(self, size: int) -> bytes:
        """Up to `size` bytes the line holds now (b"" if none, or while down)."""
        port = self.port
        if port is None:
            return b""
        try:
            return bytes(port.read(size))
        except Exception as e:  # pyserial's errors and the OS's alike: the device failed
            self.failed("read failed", e)
            return b""

    def write_some(self, data: bytes | bytearray) -> int:
        """Write what the line takes now without blocking; the count (0 while down: the
        bytes are dropped and counted, for the caller to forget too)."""
        port = self.port
        if port is None:
            self.bytes_dropped += len(data)
            return 0
        fd = self.fileno()
        try:
            if fd is not None:
                return os.write(fd, data)
            return int(port.write(bytes(data)) or 0)
        except (BlockingIOError, InterruptedError):
            return 0  # full: the rest waits for the next try
        except Exception as e:  # the device failed: what it did not take is dropped
            self.failed("write failed", e)
            self.bytes_dropped += len(data)
            return 0

    def write_all(self, data: bytes | bytearray) -> bool:
        """Write all of `data` (pyserial's write, within `write_timeout`); False if it was
        dropped (down, or the device failed)."""
        port = self.port
        if port is None:
            self.bytes_dropped += len(data)
            return False
        try:
            port.write(bytes(data))
        except Exception as e:  # noqa: BLE001  # serial, OS and timeout errors alike
            self.failed("write failed", e)
            self.bytes_dropped += len(data)
            return False
        return True

    def failed(self, what: str, e: BaseException) -> None:
        """A read, write or select on the port failed: take the device down."""
        self.errors += 1
        if self.url:
            # Not a device that comes back: the caller counts, the port stays as it is.
            if self.on_error is not None:
                self.on_error(port_reason(what, e))
            return
        self.lost(port_reason(what, e))

    def lost(self, reason: str) -> None:
        """The device is gone: close it, say so once per outage, try again at the pace."""
        port, self.port = self.port, None
        if port is not None:
            close_quietly(port)
        if self.closed:
            return
        if self.reopen.lost(self._clock(), reason) and self.on_lost is not None:
            self.on_lost(reason)

    def try_reopen(self) -> bool:
        """Open the lost device's path again if an attempt is due; True if it is back now."""
        if self.port is not None or self.closed:
            return False
        now = self._clock()
        if not self.reopen.due(now):
            return False
        try:
            self.port = self._open()
        except Exception:  # noqa: BLE001  # still gone (ENOENT), not ready, not permitted
            self.reopen.failed(now)
            return False
        down = self.reopen.back(now)
        if self.on_back is not None:
            self.on_back(round(down, 1))
        return True

    def close(self) -> None:
        """Close the port for good: a lost device is not reopened after this."""
        self.closed = True
        port, self.port = self.port, None
        if port is not None:
            close_quietly(port)


__all__ = ["PORT_ERRORS", "ReopeningSerial", "close_quietly", "port_reason"]
