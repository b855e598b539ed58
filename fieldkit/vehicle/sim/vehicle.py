"""`SimVehicle`: the simulated ArduPilot (`SimArduPilot`) on a pty, a serial port or a URL.

    pty = open_pty()                                   # or any pymavlink URL: "tcpin:0.0.0.0:5760"
    sim = SimVehicle(load_profile("solo"), pty.master, home=(45.5017, -73.5673))
    ap = Autopilot(pty.slave_path, profile=...)        # the node's link, on the other end
    sim.step(0.1)                                      # link serviced, physics by 0.1 s

Everything the vehicle does is `fieldkit.vehicle.sim.ardupilot.SimArduPilot`'s; `SimVehicle`
extends it with the port only (so callers keep one object with the whole simulator's state):
`service()` reads the line into `receive_data`, each frame is written the moment it is encoded
(a full pty drops it, as a UART would), and `run(rate_hz, stop)` paces the steps in real time
for `fieldkit vehicle-sim`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Unpack

from pymavlink import mavutil

from fieldkit.robot.profiles import Profile
from fieldkit.vehicle.autopilot import describe_error
from fieldkit.vehicle.mavlink import adopt_codec
from fieldkit.vehicle.sim.ardupilot import SimArduPilot, SimOptions, VehicleSimError
from fieldkit.vehicle.sim.lines import (
    READ_CHUNK,
    FdLine,
    read_line,
    run_real_time,
    wait_readable,
)
from fieldkit.vehicle.sim.px4 import SimPx4


class _UrlPort:
    """Any pymavlink connection: a serial device, tcpin:, udpout:..."""

    def __init__(self, url: str, baud: int, sysid: int, compid: int) -> None:
        self.conn = mavutil.mavlink_connection(
            url, baud=baud, source_system=sysid, source_component=compid
        )

    def fileno(self) -> int | None:
        """The connection's descriptor, if it has one."""
        fd = getattr(self.conn, "fd", None)
        return fd if isinstance(fd, int) and fd >= 0 else None

    def read(self) -> bytes:
        """What the connection holds."""
        try:
            data = self.conn.recv(READ_CHUNK)
        except Exception:  # a closed socket or serial port reads as silence
            return b""
        if isinstance(data, str):
            data = data.encode("latin-1")
        return data or b""

    def write(self, data: bytes) -> int:
        """Bytes written (0 if nobody is listening)."""
        try:
            self.conn.write(data)
        except Exception:  # nobody listening: the bytes are lost, as on a real line
            return 0
        return len(data)

    def close(self) -> None:
        """Close the connection."""
        try:
            self.conn.close()
        except Exception:  # closing a dead port must not fail
            pass


class SimVehicle(SimArduPilot):
    """A simulated ArduPilot vehicle on a line: a pty master or a pymavlink connection."""

    def __init__(
        self,
        profile: Profile,
        device: str | int,
        *,
        baud: int = 57600,
        **options: Unpack[SimOptions],
    ) -> None:
        """A disarmed vehicle at `home`, talking on `device`.

        `device` is a pty master descriptor (see `fieldkit.vehicle.pty.open_pty`; not closed by
        `close()`), or a pymavlink connection string: a serial device path,
        "tcpin:0.0.0.0:5760", "udpout:127.0.0.1:14550"... The other options are
        `SimArduPilot`'s.
        """
        super().__init__(profile, **options)
        self.port: FdLine | _UrlPort = self._open(device, baud)
        self.device = device if isinstance(device, str) else f"fd {device}"

    def _open(self, device: str | int, baud: int) -> FdLine | _UrlPort:
        if isinstance(device, int):
            return FdLine(device)
        try:
            url_port = _UrlPort(device, baud, self.sysid, self.compid)
        except Exception as e:  # serial, socket and value errors alike
            raise VehicleSimError(f"cannot open port {device}: {describe_error(e)}") from e
        adopt_codec(url_port.conn, self._mav)
        return url_port

    def attach(self, device: str | int, *, baud: int = 57600) -> None:
        """Move to another line, as `device` in the constructor: the same machine (flying,
        armed, in its mode) on a new cable. The old port is closed as `close()` closes it."""
        port = self._open(device, baud)
        self.port.close()
        self.port = port
        self._reader.reset()  # the rest of a frame cut by the pull never comes
        self.device = device if isinstance(device, str) else f"fd {device}"

    def step(self, dt: float) -> None:
        """Service the link (no waiting), advance the physics by `dt`, send what is due."""
        self.service()
        super().step(dt)

    def run(
        self, rate_hz: float, stop: threading.Event, clock: Callable[[], float] = time.monotonic
    ) -> None:
        """Step at `rate_hz` in real time until `stop` is set; the link is served in between."""
        # A URL port without a descriptor cannot be select()ed on: wait on `stop` instead.
        run_real_time(
            rate_hz,
            stop,
            clock,
            self.step,
            self.service,
            can_wait=lambda: self.port.fileno() is not None,
        )

    def service(self, timeout: float = 0.0) -> int:
        """Read and handle what the link holds, waiting up to `timeout` for the first byte."""
        fd = self.port.fileno()
        if not wait_readable([] if fd is None else [fd], timeout):
            return 0
        return read_line(self.port.read, self.receive_data)

    def close(self) -> None:
        """Close the port this vehicle opened (a pty master given as a descriptor stays open)."""
        self.port.close()

    def _transmit(self, frame: bytes) -> None:
        sent = self.port.write(frame)
        self.bytes_sent += sent
        self.bytes_dropped += len(frame) - sent


class SimPx4Vehicle(SimVehicle, SimPx4):
    """A simulated PX4 (`SimPx4`) on a line: the port is `SimVehicle`'s, the rest PX4's."""


def open_sim_vehicle(
    profile: Profile, device: str | int, *, baud: int = 57600, **options: Unpack[SimOptions]
) -> SimVehicle:
    """The simulated machine the profile's `autopilot.flavour` names, talking on `device`:
    PX4 for "px4", ArduPilot (Copter, or Rover for a ground profile) otherwise."""
    cls = SimPx4Vehicle if profile.autopilot.flavour == "px4" else SimVehicle
    return cls(profile, device, baud=baud, **options)
