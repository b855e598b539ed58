"""`SimM100Vehicle`: the simulated M100 flight controller (`SimM100`) on a pty or a serial port.

    pty = open_pty()
    sim = SimM100Vehicle(load_profile("m100"), pty.master, home=(45.5017, -73.5673))
    link = DjiLink(pty.slave_path, app_id=TEST_APP_ID, app_key=TEST_APP_KEY, ...)
    sim.step(0.02)                         # line serviced, physics by 20 ms

Everything the flight controller does is `SimM100`'s; this adds the line only, as
`fieldkit.vehicle.sim.vehicle.SimVehicle` does for the simulated ArduPilot: `service()` reads
it into `receive_data`, each frame is written the moment it is made (a full pty drops it, as
a UART would), and `run(rate_hz, stop)` paces the steps in real time for `fieldkit
vehicle-sim --profile m100`.
"""

from __future__ import annotations

import os
import select
import threading
import time
from collections.abc import Callable
from typing import Any, Unpack

import serial

from fieldkit.robot.profiles import Profile
from fieldkit.vehicle.autopilot import describe_error
from fieldkit.vehicle.sim.dji import SimM100, SimM100Error, SimM100Options

_READ_CHUNK = 4096
_MAX_READ = 1 << 16


class _Line:
    """The flight controller's end of the line: a descriptor it reads and writes raw."""

    def __init__(self, fd: int, owner: Any = None) -> None:
        os.set_blocking(fd, False)
        self.fd = fd
        self.owner = owner  # a pyserial port that owns `fd`, closed with the line

    def read(self) -> bytes:
        """What the line holds (b"" if nothing, or nobody on the other end)."""
        try:
            return os.read(self.fd, _READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:
            return b""  # EIO: nobody has the pty's other end open

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


class SimM100Vehicle(SimM100):
    """A simulated M100 flight controller on a pty master or a serial device."""

    def __init__(
        self,
        profile: Profile,
        device: str | int,
        *,
        baud: int = 230400,
        **options: Unpack[SimM100Options],
    ) -> None:
        """An M100 at `home`, talking on `device`: a pty master descriptor (not closed by
        `close()`) or a serial device path opened at `baud`. The other options are
        `SimM100`'s."""
        super().__init__(profile, **options)
        self.line = self._open(device, baud)
        self.device_name = device if isinstance(device, str) else f"fd {device}"

    @staticmethod
    def _open(device: str | int, baud: int) -> _Line:
        if isinstance(device, int):
            return _Line(device)
        try:
            port = serial.Serial(device, baud, timeout=0, write_timeout=0)
        except (serial.SerialException, OSError, ValueError) as e:
            raise SimM100Error(f"cannot open port {device}: {describe_error(e)}") from e
        return _Line(port.fileno(), port)

    def attach(self, device: str | int, *, baud: int = 230400) -> None:
        """Move to another line, as `device` in the constructor: the same flight controller
        (flying, activated, holding what authority it had) on a new cable. The old line is
        closed as `close()` closes it."""
        line = self._open(device, baud)
        self.line.close()
        self.line = line
        self._reader.reset()  # the rest of a frame cut by the pull never comes
        self.device_name = device if isinstance(device, str) else f"fd {device}"

    def step(self, dt: float) -> None:
        """Service the line (no waiting), advance the physics by `dt`, send what is due."""
        self.service()
        super().step(dt)

    def run(
        self, rate_hz: float, stop: threading.Event, clock: Callable[[], float] = time.monotonic
    ) -> None:
        """Step at `rate_hz` in real time until `stop` is set; the line is served in between."""
        period = 1.0 / rate_hz
        next_t = clock()
        while not stop.is_set():
            now = clock()
            if now >= next_t:
                self.step(period)
                next_t += period
                if next_t < now - 1.0:
                    next_t = now  # suspended for a while: resume, do not race to catch up
                continue
            self.service(min(next_t - now, 0.05))

    def service(self, timeout: float = 0.0) -> int:
        """Read and handle what the line holds, waiting up to `timeout` for the first byte."""
        if timeout > 0:
            try:
                select.select([self.line.fd], [], [], timeout)
            except (OSError, ValueError):
                return 0
        handled = 0
        total = 0
        while total < _MAX_READ:
            data = self.line.read()
            if not data:
                break
            total += len(data)
            handled += self.receive_data(data)
        return handled

    def close(self) -> None:
        """Close the port this vehicle opened (a pty master given as a descriptor stays open)."""
        self.line.close()

    def _transmit(self, frame: bytes) -> None:
        sent = self.line.write(frame)
        self.bytes_sent += sent
        self.bytes_dropped += len(frame) - sent


__all__ = ["SimM100Vehicle"]
