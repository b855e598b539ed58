"""`SimHuskyPorts`: the simulated Husky (`SimHusky`) on two lines, its MCU's and its GPS's.

    mcu, gps = open_pty(), open_pty()
    sim = SimHuskyPorts(load_profile("husky"), mcu.master, gps.master, home=(45.5, -73.6))
    husky = Husky(mcu.slave_path, gps.slave_path, profile=...)   # the node's side
    sim.step(0.02)                                             # both lines served, physics

Everything the machine does is `fieldkit.vehicle.sim.husky.SimHusky`'s; this adds the ports
only: a pty master descriptor (not closed here) or a serial device path (pyserial) for each,
every frame and sentence written the moment it is made (a full line drops bytes, as a UART
would), and `run(rate_hz, stop)` pacing the steps in real time for `fieldkit vehicle-sim`.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from typing import Any, Unpack

import serial

from fieldkit.robot.profiles import Profile
from fieldkit.vehicle.autopilot import describe_error
from fieldkit.vehicle.sim.husky import HuskyOptions, HuskySimError, SimHusky
from fieldkit.vehicle.sim.lines import READ_CHUNK, read_line, run_real_time, wait_readable


class _Port:
    """One end of a line: a pty master descriptor (not owned) or a serial device (owned)."""

    def __init__(self, device: str | int, baud: int) -> None:
        self.conn: Any | None = None
        if isinstance(device, int):
            os.set_blocking(device, False)
            self.fd = device
            self.name = f"fd {device}"
            return
        try:
            self.conn = serial.Serial(device, baud, timeout=0, write_timeout=0)
        except (serial.SerialException, OSError, ValueError) as e:
            raise HuskySimError(f"cannot open port {device}: {describe_error(e)}") from e
        self.fd = self.conn.fileno()
        self.name = device

    def read(self) -> bytes:
        """What the line holds (b"" if nothing, or nobody on the other end)."""
        try:
            if self.conn is not None:
                return bytes(self.conn.read(READ_CHUNK))
            return os.read(self.fd, READ_CHUNK)
        except (BlockingIOError, InterruptedError):
            return b""
        except (OSError, serial.SerialException):
            return b""  # EIO: nobody has the slave open

    def write(self, data: bytes) -> int:
        """Bytes written; a full line takes fewer."""
        try:
            if self.conn is not None:
                return int(self.conn.write(data) or 0)
            return os.write(self.fd, data)
        except (BlockingIOError, InterruptedError, serial.SerialTimeoutException):
            return 0
        except (OSError, serial.SerialException):
            return 0

    def close(self) -> None:
        """Close a serial device this opened (a descriptor given stays open)."""
        if self.conn is not None:
            try:
                self.conn.close()
            except (OSError, serial.SerialException):
                pass


class SimHuskyPorts(SimHusky):
    """A simulated Husky whose MCU and GPS each talk on a line of their own."""

    def __init__(
        self,
        profile: Profile,
        mcu: str | int,
        gps: str | int,
        *,
        baud: int = 115200,
        gps_baud: int = 19200,
        **options: Unpack[HuskyOptions],
    ) -> None:
        """A Husky at `home` on `mcu` and `gps`: pty master descriptors or device paths.
        The other options are `SimHusky`'s."""
        super().__init__(profile, **options)
        self.mcu_port = _Port(mcu, baud)
        try:
            self.gps_port = _Port(gps, gps_baud)
        except BaseException:
            self.mcu_port.close()
            raise
        self.mcu.sink = self.mcu_port.write
        self.gps.sink = self.gps_port.write

    def attach(
        self,
        *,
        mcu: str | int | None = None,
        gps: str | int | None = None,
        baud: int = 115200,
        gps_baud: int = 19200,
    ) -> None:
        """Move the MCU or the GPS (or both) to another line, as in the constructor: the same
        machine, still driving, on a new cable. The old line is closed as `close()` does."""
        if mcu is not None:
            port = _Port(mcu, baud)
            self.mcu_port.close()
            self.mcu_port = port
            self.mcu.sink = port.write
        if gps is not None:
            port = _Port(gps, gps_baud)
            self.gps_port.close()
            self.gps_port = port
            self.gps.sink = port.write

    def step(self, dt: float) -> None:
        """Serve both lines (no waiting), then advance by `dt` and send what is due."""
        self.service()
        super().step(dt)

    def service(self, timeout: float = 0.0) -> int:
        """Read and handle what both lines hold, waiting up to `timeout` for a first byte."""
        if not wait_readable([self.mcu_port.fd, self.gps_port.fd], timeout):
            return 0
        mcu = read_line(self.mcu_port.read, self.mcu.receive_data)
        return mcu + read_line(self.gps_port.read, self.gps.receive_data)

    def run(
        self, rate_hz: float, stop: threading.Event, clock: Callable[[], float] = time.monotonic
    ) -> None:
        """Step at `rate_hz` in real time until `stop` is set; the lines are served between."""
        run_real_time(rate_hz, stop, clock, self.step, self.service)

    def close(self) -> None:
        """Close the devices this opened (descriptors given stay open)."""
        self.mcu_port.close()
        self.gps_port.close()


__all__ = ["SimHuskyPorts"]
