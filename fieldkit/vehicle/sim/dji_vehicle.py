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

import threading
import time
from collections.abc import Callable
from typing import Unpack

import serial

from fieldkit.robot.profiles import Profile
from fieldkit.vehicle.autopilot import describe_error
from fieldkit.vehicle.sim.dji import SimM100, SimM100Error, SimM100Options
from fieldkit.vehicle.sim.lines import FdLine, read_line, run_real_time, wait_readable


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
    def _open(device: str | int, baud: int) -> FdLine:
        if isinstance(device, int):
            return FdLine(device)
        try:
            port = serial.Serial(device, baud, timeout=0, write_timeout=0)
        except (serial.SerialException, OSError, ValueError) as e:
            raise SimM100Error(f"cannot open port {device}: {describe_error(e)}") from e
        return FdLine(port.fileno(), port)

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
        run_real_time(rate_hz, stop, clock, self.step, self.service)

    def service(self, timeout: float = 0.0) -> int:
        """Read and handle what the line holds, waiting up to `timeout` for the first byte."""
        if not wait_readable([self.line.fd], timeout):
            return 0
        return read_line(self.line.read, self.receive_data)

    def close(self) -> None:
        """Close the port this vehicle opened (a pty master given as a descriptor stays open)."""
        self.line.close()

    def _transmit(self, frame: bytes) -> None:
        sent = self.line.write(frame)
        self.bytes_sent += sent
        self.bytes_dropped += len(frame) - sent


__all__ = ["SimM100Vehicle"]
