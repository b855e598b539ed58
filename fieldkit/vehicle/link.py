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

A serial device that goes away (a USB cable worked loose: reads fail with EIO, the node file
vanishes) never raises into the loop: the port is closed, a "link" event says
`/dev/autopilot lost (read failed: Input/output error); reopening` once, frames written while
down are dropped (`bytes_dropped`), and each `poll()` tries the same path again when
`ReopenPolicy` says so (once a second of the link's clock; one open() each). Meanwhile no
heartbeat comes, so the supervisor's heartbeat-loss failsafe fires as for any silent
autopilot. When the path opens again (the udev symlink pointing at the device's new
ttyUSBn), a "reopened" event says `/dev/autopilot back after N s` and the core starts afresh
on it (`AutopilotCore.connection_made`: no half frame, streams asked again). Network
transports keep their own ways: an error there is counted as a line error.

Everything the protocol decides (telemetry, the command machine, heartbeats) is the core's,
`fieldkit.vehicle.autopilot.AutopilotCore`. `Autopilot` extends it with the port only, so
the node keeps one object with the core's whole command API: it opens the connection, reads
it into `receive_data`, writes each frame the moment the codec encodes it (a command issued
between polls leaves at once), and adds the bounded blocking waits used at start-up.
"""

from __future__ import annotations

import select
import time
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
from fieldkit.vehicle.links import command_outcome, poll_until
from fieldkit.vehicle.mavlink import adopt_codec
from fieldkit.vehicle.px4 import Px4Core
from fieldkit.vehicle.reopen import DEFAULT_INTERVAL_S, ReopenPolicy
from fieldkit.vehicle.serial_port import close_quietly, port_reason

# A single poll reads at most this much, so that a flooded line cannot starve the loop.
_MAX_READ_PER_POLL = 1 << 16
_READ_CHUNK = 4096


class Autopilot(AutopilotCore):
    """The node's MAVLink link to one autopilot: the protocol core on a pymavlink connection."""

    def __init__(
        self,
        url: str,
        *,
        baud: int = 57600,
        reopen_interval_s: float = DEFAULT_INTERVAL_S,
        **options: Unpack[CoreOptions],
    ) -> None:
        """Open `url` (any pymavlink connection string); raises AutopilotError if it fails.

        The other options are `AutopilotCore`'s: `profile` gives the mode names, the
        heartbeat timeout and whether the robot is a ground robot (no takeoff);
        `heartbeat_interval_s` is how often `poll()` sends our own heartbeat (None: only
        `send_heartbeat()`); RC channel `override_channel` at or above `override_pwm`
        microseconds reads as the pilot taking over; `target_system` pins the autopilot's
        system id (by default the first autopilot heartbeat decides). A serial device lost
        later is tried again every `reopen_interval_s` seconds of the link's clock.
        """
        super().__init__(url=url, **options)
        self.baud = baud
        try:
            conn = self._connect()
        except Exception as e:  # serial, socket and value errors alike
            raise AutopilotError(
                f"cannot open the autopilot link {url}: {describe_error(e)}"
            ) from e
        self._conn: Any | None = conn
        # Only a serial device comes back by being opened again; sockets have their own ways.
        self.serial = isinstance(conn, mavutil.mavserial)
        self.reopen = ReopenPolicy(reopen_interval_s)
        self.bytes_dropped = 0  # written while the device was gone
        self._closed = False
        #: Taps on the bytes as they cross the port (a recorder): read, and written.
        self.on_rx: Callable[[bytes], None] | None = None
        self.on_tx: Callable[[bytes], None] | None = None

    def _connect(self) -> Any:
        """A pymavlink connection to `url` that encodes and decodes with our codec."""
        conn = mavutil.mavlink_connection(
            self.url,
            baud=self.baud,
            source_system=self.source_system,
            source_component=self.source_component,
        )
        adopt_codec(conn, self._mav)
        return conn

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
        """Close the port; pending commands are cancelled, and a lost device stays closed."""
        self._closed = True
        self.cancel_all("link closed")
        conn, self._conn = self._conn, None
        if conn is not None:
            close_quietly(conn)

    def __enter__(self) -> Autopilot:
        """Use as a context manager: closed on exit."""
        return self

    def __exit__(self, *exc: object) -> None:
        """Close the link."""
        self.close()

    @property
    def link_down(self) -> bool:
        """Whether the serial device is lost and not reopened yet."""
        return self.reopen.down

    def fileno(self) -> int | None:
        """The descriptor to select() on (None for transports without one, or while down)."""
        fd = getattr(self._conn, "fd", None)
        return fd if isinstance(fd, int) and fd >= 0 else None

    def write(self, buf: bytes | bytearray) -> None:
        """Send the codec's frame on the link now; errors are counted, not raised."""
        conn = self._conn
        if conn is None:
            # Nothing to write to: by the time the device is back, the frame is stale (our
            # heartbeat, a retry the command machine will make again anyway).
            self.bytes_dropped += len(buf)
            return
        try:
            if self.serial:
                # pymavlink's serial write swallows the error (and prints to stdout): write
                # to its pyserial port so that a vanished device is seen here.
                conn.port.write(bytes(buf))
            else:
                conn.write(bytes(buf))
        except Exception as e:  # a dead port costs a counter, not the loop
            if self.serial:
                self._lost(port_reason("write failed", e))
            else:
                self._link_error(f"write failed: {describe_error(e)}")
            return
        self.bytes_sent += len(buf)
        if self.on_tx is not None:
            self.on_tx(bytes(buf))

    def _lost(self, reason: str) -> None:
        """The serial device failed: close it, say so once, try it again at the policy's pace."""
        self.link_errors += 1
        conn, self._conn = self._conn, None
        if conn is not None:
            close_quietly(conn)
        if self.reopen.lost(self._clock(), reason):
            self._event("link", f"{self.url} lost ({reason}); reopening")

    def _reopen(self) -> Any | None:
        """Try the lost device's path again if an attempt is due; the connection, or None."""
        now = self._clock()
        if self._closed or not self.reopen.due(now):
            return None
        try:
            conn = self._connect()
        except Exception:  # still gone (ENOENT), not ready, not permitted: the next second
            self.reopen.failed(now)
            return None
        self._conn = conn
        down = self.reopen.back(now)
        self._event("reopened", f"{self.url} back after {round(down, 1):g} s")
        self.connection_made()
        return self._conn  # None again if its first writes failed: a device still flapping

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
        if conn is None:
            conn = self._reopen()
            if conn is None:
                if timeout > 0 and not self._closed:
                    time.sleep(timeout)  # nothing to select() on: wait as select() would
                return 0
        fd = self.fileno()
        if timeout > 0 and fd is not None:
            try:
                select.select([fd], [], [], timeout)
            except (OSError, ValueError) as e:
                if self.serial:
                    self._lost(port_reason("select failed", e))
                else:
                    self._link_error(f"select failed: {describe_error(e)}")
                return 0
        handled = 0
        total = 0
        while total < _MAX_READ_PER_POLL:
            try:
                data = conn.recv(_READ_CHUNK)
            except Exception as e:  # pyserial and socket errors alike: the link failed
                if self.serial:
                    self._lost(port_reason("read failed", e))
                else:
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
        return command_outcome(command, ok, timeout, AutopilotError)

    def _wait(
        self,
        cond: Callable[[], bool],
        timeout: float,
        idle: Callable[[], None] | None,
        poll_interval: float,
    ) -> bool:
        deadline = self._clock() + timeout
        return poll_until(self.poll, self._clock, cond, deadline, idle, poll_interval)


class Px4Autopilot(Autopilot, Px4Core):
    """The node's MAVLink link to PX4: `Px4Core` (OFFBOARD setpoint stream, PX4 modes) on a
    pymavlink connection; the port is `Autopilot`'s, the conversation `Px4Core`'s."""
