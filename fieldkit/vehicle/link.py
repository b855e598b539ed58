"""The field node's link to its autopilot: `AutopilotCore` on a pymavlink connection.

    ap = Autopilot.from_profile(load_profile("solo"))      # opens profile.autopilot.url
    ap.wait_heartbeat(10.0)                                 # start-up only: bounded waits
    ap.request_streams(10.0)
    ap.wait_gps_fix(ap.gps_fix_timeout_s)
    takeoff = ap.takeoff(5.0)                               # returns at once: a MavCommand
    while running:                                          # the node's 10 Hz loop
        ap.poll()                                           # read, ACKs, retries, heartbeat
        t = ap.telemetry                                    # lat, lon, alt_rel_m, armed, mode...
        for event in ap.drain_events():                     # command results, heartbeat loss,
            log(event)                                      # mode changes, pilot override
        ap.goto(lat, lon, alt)                              # a setpoint: sent now, no ACK

Any pymavlink connection string works: a serial device (`/dev/ttyUSB0` with `baud`), a pty,
`tcp:HOST:PORT` (ArduPilot SITL's 5760), `udpin:0.0.0.0:14550`. Nothing here blocks the loop:
`poll()` reads what the line holds (it waits at most its `timeout`, 0 by default).

Everything the protocol decides (telemetry, the command machine, heartbeats) is the core's,
`fieldkit.vehicle.autopilot.AutopilotCore`. `Autopilot` extends it with the port only, so
the node keeps one object with the core's whole command API: it opens the connection, reads
it into `receive_data`, writes each frame the moment the codec encodes it (a command issued
between polls leaves at once), and adds the bounded blocking waits used at start-up.
"""

from __future__ import annotations

import select
from collections.abc import Callable
from typing import Any, Unpack

from pymavlink import mavutil

from fieldkit.robot.profiles import Profile
from fieldkit.vehicle.autopilot import (
    AutopilotCore,
    AutopilotError,
    AutopilotState,
    CoreOptions,
    MavCommand,
    describe_error,
)
from fieldkit.vehicle.mavlink import adopt_codec
from fieldkit.vehicle.px4 import Px4Core

# A single poll reads at most this much, so that a flooded line cannot starve the loop.
_MAX_READ_PER_POLL = 1 << 16
_READ_CHUNK = 4096


class Autopilot(AutopilotCore):
    """The node's MAVLink link to one autopilot: the protocol core on a pymavlink connection."""

    def __init__(self, url: str, *, baud: int = 57600, **options: Unpack[CoreOptions]) -> None:
        """Open `url` (any pymavlink connection string); raises AutopilotError if it fails.

        The other options are `AutopilotCore`'s: `profile` gives the mode names, the
        heartbeat timeout and whether the robot is a ground robot (no takeoff);
        `heartbeat_interval_s` is how often `poll()` sends our own heartbeat (None: only
        `send_heartbeat()`); RC channel `override_channel` at or above `override_pwm`
        microseconds reads as the pilot taking over; `target_system` pins the autopilot's
        system id (by default the first autopilot heartbeat decides).
        """
        super().__init__(url=url, **options)
        try:
            self._conn = mavutil.mavlink_connection(
                url,
                baud=baud,
                source_system=self.source_system,
                source_component=self.source_component,
            )
        except Exception as e:  # serial, socket and value errors alike
            raise AutopilotError(
                f"cannot open the autopilot link {url}: {describe_error(e)}"
            ) from e
        adopt_codec(self._conn, self._mav)
        #: Taps on the bytes as they cross the port (a recorder): read, and written.
        self.on_rx: Callable[[bytes], None] | None = None
        self.on_tx: Callable[[bytes], None] | None = None

    @classmethod
    def from_profile(cls, profile: Profile, url: str | None = None, **kwargs: Any) -> Autopilot:
        """A link as the profile says (`autopilot.url`, `autopilot.baud`), or to `url`; the
        core by `autopilot.flavour` (px4: `Px4Autopilot`, PX4's OFFBOARD conversation)."""
        if profile.autopilot.flavour == "dji":
            raise AutopilotError(
                f"{profile.name}: the DJI Onboard SDK does not speak MAVLink (flavour dji)"
            )
        if profile.autopilot.flavour == "px4" and cls is Autopilot:
            cls = Px4Autopilot
        return cls(
            url if url is not None else profile.autopilot.url,
            baud=profile.autopilot.baud,
            profile=profile,
            **kwargs,
        )

    # ------------------------------------------------------------------ lifecycle

    def close(self) -> None:
        """Close the port; pending commands are cancelled."""
        self.cancel_all("link closed")
        try:
            self._conn.close()
        except Exception:  # closing a dead port must not fail
            pass

    def __enter__(self) -> Autopilot:
        """Use as a context manager: closed on exit."""
        return self

    def __exit__(self, *exc: object) -> None:
        """Close the link."""
        self.close()

    def fileno(self) -> int | None:
        """The descriptor to select() on (None for transports without one)."""
        fd = getattr(self._conn, "fd", None)
        return fd if isinstance(fd, int) and fd >= 0 else None

    def write(self, buf: bytes | bytearray) -> None:
        """Send the codec's frame on the link now; errors are counted, not raised."""
        try:
            self._conn.write(bytes(buf))
        except Exception as e:  # a dead port costs a counter, not the loop
            self._link_error(f"write failed: {describe_error(e)}")
            return
        self.bytes_sent += len(buf)
        if self.on_tx is not None:
            self.on_tx(bytes(buf))

    # ------------------------------------------------------------------ the loop

    def poll(self, timeout: float = 0.0) -> int:
        """Read and handle everything available, then move commands and heartbeats on.

        Waits up to `timeout` seconds for the first byte when nothing is there yet (0: not
        at all). Returns the number of good messages handled.
        """
        n = self._read(timeout)
        self.tick()
        return n

    def _read(self, timeout: float) -> int:
        conn = self._conn
        fd = self.fileno()
        if timeout > 0 and fd is not None:
            try:
                select.select([fd], [], [], timeout)
            except (OSError, ValueError) as e:
                self._link_error(f"select failed: {describe_error(e)}")
                return 0
        handled = 0
        total = 0
        while total < _MAX_READ_PER_POLL:
            try:
                data = conn.recv(_READ_CHUNK)
            except Exception as e:  # pyserial and socket errors alike: the link failed
                self._link_error(f"read failed: {describe_error(e)}")
                break
            if not data:
                break
            if isinstance(data, str):  # some pymavlink transports return "" or str
                data = data.encode("latin-1")
            total += len(data)
            if self.on_rx is not None:
                self.on_rx(data)
            handled += self.receive_data(data)
            if fd is None:
                break  # no descriptor: cannot tell "more" from "no more"; next poll reads on
        return handled

    # ------------------------------------------------------------------ blocking helpers

    def wait_heartbeat(
        self,
        timeout: float,
        *,
        idle: Callable[[], None] | None = None,
        poll_interval: float = 0.05,
    ) -> AutopilotState:
        """Poll until a vehicle heartbeat arrives; AutopilotError after `timeout` seconds.

        For start-up, not for the loop. `idle` is called between polls (a test steps its
        simulated vehicle there); each poll waits up to `poll_interval` for data.
        """
        ok = self._wait(
            lambda: self.telemetry.last_heartbeat is not None, timeout, idle, poll_interval
        )
        if not ok:
            raise AutopilotError(
                f"no heartbeat from the autopilot after {timeout:g} s on {self.url} "
                f"({self.bytes_received} bytes received, {self.bad_frames} bad frames)"
            )
        return self.telemetry

    def wait_gps_fix(
        self,
        timeout: float,
        *,
        min_fix: int = 3,
        idle: Callable[[], None] | None = None,
        poll_interval: float = 0.05,
    ) -> AutopilotState:
        """Poll until the GPS fix type reaches `min_fix` (3: 3D); AutopilotError on timeout."""
        ok = self._wait(
            lambda: self.telemetry.gps_fix_type >= min_fix, timeout, idle, poll_interval
        )
        if not ok:
            t = self.telemetry
            if t.satellites is None:
                detail = "no GPS_RAW_INT received"
            else:
                detail = f"fix type {t.gps_fix_type}, {t.satellites} satellites"
            raise AutopilotError(f"no GPS fix after {timeout:g} s ({detail})")
        return self.telemetry

    def wait_position(
        self,
        timeout: float,
        *,
        idle: Callable[[], None] | None = None,
        poll_interval: float = 0.05,
    ) -> AutopilotState:
        """Poll until the autopilot has sent a position (GLOBAL_POSITION_INT): a fix can
        come first, and a node must not take 0,0 for its home; AutopilotError on timeout."""
        if not self._wait(lambda: self.telemetry.lat is not None, timeout, idle, poll_interval):
            raise AutopilotError(
                f"GPS fix but no position (GLOBAL_POSITION_INT) after {timeout:g} s"
            )
        return self.telemetry

    def wait_command(
        self,
        command: MavCommand,
        timeout: float,
        *,
        idle: Callable[[], None] | None = None,
        poll_interval: float = 0.05,
    ) -> MavCommand:
        """Poll until `command` is over; AutopilotError if it failed or is still pending."""
        ok = self._wait(lambda: command.done, timeout, idle, poll_interval)
        if not ok:
            raise AutopilotError(f"{command.name}: not finished after {timeout:g} s")
        if not command.ok:
            raise AutopilotError(command.error or f"{command.name}: {command.status.value}")
        return command

    def _wait(
        self,
        cond: Callable[[], bool],
        timeout: float,
        idle: Callable[[], None] | None,
        poll_interval: float,
    ) -> bool:
        deadline = self._clock() + timeout
        while True:
            self.poll(poll_interval)
            if cond():
                return True
            if self._clock() >= deadline:
                return False
            if idle is not None:
                idle()


class Px4Autopilot(Autopilot, Px4Core):
    """The node's MAVLink link to PX4: `Px4Core` (OFFBOARD setpoint stream, PX4 modes) on a
    pymavlink connection; the port is `Autopilot`'s, the conversation `Px4Core`'s."""
