"""The node's link to an M100: `DjiCore` on a serial port (pyserial), non-blocking.

    link = DjiLink.from_profile(load_profile("m100"), app_id=ID, app_key=KEY)
    link.wait_connected(30.0)            # start-up only: activated, control authority held
    link.wait_gps_fix(link.gps_fix_timeout_s)
    takeoff = link.takeoff(5.0)          # returns at once: a DjiCommand
    while running:                       # the node's loop
        link.poll()                      # read, ACKs, retries, the movement stream
        t = link.telemetry
        for event in link.drain_events():
            log(event)

Everything the protocol decides is the core's (`fieldkit.vehicle.dji.core.DjiCore`, in
`link.core`); this adds the port: it opens it, reads it into `receive_data`, writes what the
core queues the moment a call returns (nothing waits for the next poll), taps both ways for
the flight recorder (`on_rx`, `on_tx`), and offers the bounded blocking waits used at
start-up. Writes never block: what the line cannot take now waits for the next poll.

DJI wants movement-control frames at 50 Hz; the node's loop runs at its profile's rate (10
Hz). With `stream_thread` a small thread sends the stream's frames between polls, under the
same lock as everything else, so the rate holds whatever the loop's. `stream_paused` (the
node's "a tick is running") holds the thread back during a tick, so that its sends fall
between ticks, never among a tick's own writes; `on_stream` tells a recorder the clock time
of each, and a replay (no thread) sends them again at those times with `stream_at`.

A serial device that goes away (a loose cable: reads fail with EIO, the tty reads end of
file) never raises into the loop (`fieldkit.vehicle.serial_port.ReopeningSerial`): the port
is closed, a "link" event says `/dev/m100 lost (read failed: Input/output error); reopening`
once, what would be written meanwhile is dropped (`bytes_dropped`), and each poll tries the
path again at `ReopenPolicy`'s pace (`reopen`). The silence is a heartbeat loss to the
supervisor. When the path opens again, a "reopened" event says `/dev/m100 back after N s`
and the session starts over as at start-up (`DjiCore.connection_made`: activation, the
broadcast rate, control authority if the node held it and the pilot has not taken over).
"""

from __future__ import annotations

import select
import threading
import time
from collections.abc import Callable
from typing import Any

from fieldkit.robot.profiles import Profile
from fieldkit.vehicle.autopilot import AutopilotState, Event, describe_error
from fieldkit.vehicle.dji.core import DjiCommand, DjiCore, DjiError
from fieldkit.vehicle.links import command_outcome, poll_until
from fieldkit.vehicle.reopen import DEFAULT_INTERVAL_S, ReopenPolicy
from fieldkit.vehicle.serial_port import PORT_ERRORS, ReopeningSerial

_READ_CHUNK = 4096
_MAX_READ_PER_POLL = 1 << 16
#: Bytes the line may owe before they are dropped: a flight controller that reads nothing.
MAX_TX_BACKLOG = 16384
#: Seconds `close()` waits for the release of control authority to be acknowledged.
RELEASE_WAIT_S = 1.0


class DjiLink:
    """The node's OPEN protocol link to one M100: the core on a serial port."""

    def __init__(
        self,
        url: str,
        *,
        app_id: int,
        app_key: str,
        baud: int = 230400,
        profile: Profile | None = None,
        clock: Callable[[], float] = time.monotonic,
        stream_thread: bool = False,
        stream_paused: Callable[[], bool] | None = None,
        release_on_close: bool = True,
        reopen_interval_s: float = DEFAULT_INTERVAL_S,
        **options: Any,
    ) -> None:
        """Open `url` (a serial device or pyserial URL) at `baud`; raises DjiError if it fails.

        `app_id` and `app_key` are the developer's (from the node's config); `profile` and
        the other options are `DjiCore`'s. `stream_thread` sends the movement stream from a
        thread at the control rate, except while `stream_paused()` is true;
        `release_on_close` gives control authority back when the link is closed. A device
        lost later is tried again every `reopen_interval_s` seconds of `clock`.
        """
        self.core = DjiCore(
            app_id=app_id, app_key=app_key, url=url, profile=profile, clock=clock, **options
        )
        self.url = url
        self._clock = clock
        try:
            self._line = ReopeningSerial(
                url, baud, clock=clock, reopen_interval_s=reopen_interval_s, write_timeout=None
            )
        except PORT_ERRORS as e:
            raise DjiError(f"cannot open the DJI link {url}: {describe_error(e)}") from e
        self._line.on_lost = self.core.connection_lost
        self._line.on_back = self.core.connection_made
        self._line.on_error = self.core.link_error
        #: Taps on the bytes as they cross the port (a recorder): read, and written.
        self.on_rx: Callable[[bytes], None] | None = None
        self.on_tx: Callable[[bytes], None] | None = None
        #: Told the clock time of each movement frame the thread sends (a recorder).
        self.on_stream: Callable[[float], None] | None = None
        self.stream_paused = stream_paused
        self.bytes_written = 0
        self._backlog_dropped = 0  # unwritten past MAX_TX_BACKLOG
        self.release_on_close = release_on_close
        self._tx = bytearray()
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        if stream_thread:
            self._thread = threading.Thread(target=self._pump, name="dji-stream", daemon=True)
            self._thread.start()

    @classmethod
    def from_profile(
        cls, profile: Profile, url: str | None = None, *, app_id: int, app_key: str, **kwargs: Any
    ) -> DjiLink:
        """A link as the profile says (`autopilot.url`, `autopilot.baud`, `[dji]`), or to `url`."""
        return cls(
            url if url is not None else profile.autopilot.url,
            app_id=app_id,
            app_key=app_key,
            baud=profile.autopilot.baud,
            profile=profile,
            **kwargs,
        )

    # ------------------------------------------------------------------ views

    @property
    def telemetry(self) -> AutopilotState:
        """The latest telemetry (the core's object, updated in place)."""
        return self.core.telemetry

    @property
    def pilot_override(self) -> bool:
        """Whether the pilot has the aircraft (see `DjiCore.pilot_override`)."""
        return self.core.pilot_override

    @property
    def messages(self) -> int:
        """Good frames received."""
        return self.core.messages

    @property
    def bad_frames(self) -> int:
        """Noise runs, broken and unreadable frames received."""
        return self.core.bad_frames

    @property
    def gps_fix_timeout_s(self) -> float:
        """The profile's wait for a GPS fix."""
        return self.core.gps_fix_timeout_s

    def heartbeat_age(self) -> float:
        """Seconds since the flight controller was last heard."""
        return self.core.heartbeat_age()

    def drain_events(self) -> list[Event]:
        """The core's events since the last call."""
        with self._lock:
            return self.core.drain_events()

    def time_state(self) -> dict[str, object]:
        """The core's clock readings."""
        return self.core.time_state()

    def set_time_state(self, state: dict[str, object]) -> None:
        """Restore the core's clock readings."""
        with self._lock:
            self.core.set_time_state(state)

    def fileno(self) -> int | None:
        """The descriptor to select() on (None for a port without one, or while down)."""
        return self._line.fileno()

    @property
    def reopen(self) -> ReopenPolicy:
        """The serial device's outages: down now, how many, seconds down (the node reads it)."""
        return self._line.reopen

    @property
    def link_down(self) -> bool:
        """Whether the serial device is lost and not reopened yet."""
        return self._line.down

    @property
    def bytes_dropped(self) -> int:
        """Bytes never written: the device was gone, or the backlog overflowed."""
        return self._line.bytes_dropped + self._backlog_dropped

    # ------------------------------------------------------------------ the loop

    def poll(self, timeout: float = 0.0) -> int:
        """Read and handle everything available, then move commands and the stream on.

        Waits up to `timeout` seconds for the first byte (0: not at all). Returns the good
        frames handled.
        """
        fd = self._line.fileno()
        if timeout > 0 and fd is not None:
            try:
                select.select([fd], [], [], timeout)
            except (OSError, ValueError) as e:
                with self._lock:
                    self._line.failed("select failed", e)
        elif timeout > 0 and self._line.down:
            time.sleep(timeout)  # nothing to select() on: wait as select() would
        with self._lock:
            if self._line.try_reopen():
                self._tx.clear()  # the rest of a frame the old line did not take: garbage now
            n = self._read()
            self.core.tick()
            self._flush()
            return n

    def _read(self) -> int:
        handled = 0
        total = 0
        while total < _MAX_READ_PER_POLL:
            data = self._line.read(_READ_CHUNK)  # a failure takes the line down: b""
            if not data:
                break
            total += len(data)
            if self.on_rx is not None:
                self.on_rx(data)
            handled += self.core.receive_data(data)
        return handled

    def _flush(self) -> None:
        """Write what the core queued (and what the line could not take before)."""
        data = self.core.data_to_send()
        if data:
            if self.on_tx is not None:
                self.on_tx(data)
            self._tx += data
        if not self._tx:
            return
        n = self._line.write_some(self._tx)  # a dead port costs a counter, not the loop
        if self._line.port is None:
            self._tx.clear()  # gone (dropped and counted by the line): a cut frame is garbage
            return
        self.bytes_written += n
        del self._tx[:n]
        if len(self._tx) > MAX_TX_BACKLOG:
            self._backlog_dropped += len(self._tx)
            self._tx.clear()
            self.core.link_error(
                f"{MAX_TX_BACKLOG} bytes unwritten: the flight controller is not reading "
                "(backlog dropped)"
            )

    def _pump(self) -> None:
        """The stream thread: a movement frame whenever one is due, between polls."""
        period = 1.0 / self.core.control_rate_hz
        while not self._stop.wait(period / 2):
            with self._lock:
                # Checked under the lock: a tick's poll cannot have run since, so a send
                # here comes before everything the tick reads and writes.
                paused = self.stream_paused
                if paused is not None and paused():
                    continue
                try:
                    self._stream(self._clock())
                except Exception as e:  # the loop's link must outlive a bad moment
                    self.core.link_error(f"stream failed: {describe_error(e)}")

    def _stream(self, now: float) -> bool:
        if not self.core.stream(now):
            return False
        if self.on_stream is not None:
            self.on_stream(now)
        self._flush()
        return True

    def stream_at(self, now: float) -> bool:
        """Send the movement frame due at clock time `now`, as the thread would have (a
        replay's recorded sends); whether one was due."""
        with self._lock:
            return self._stream(now)

    # ------------------------------------------------------------------ orders

    def _do(self, call: Callable[[], DjiCommand]) -> DjiCommand:
        with self._lock:
            cmd = call()
            self._flush()
            return cmd

    def arm(self) -> DjiCommand:
        """Start the motors (see `DjiCore.arm`)."""
        return self._do(self.core.arm)

    def disarm(self) -> DjiCommand:
        """Stop the motors (see `DjiCore.disarm`)."""
        return self._do(self.core.disarm)

    def takeoff(self, altitude_m: float) -> DjiCommand:
        """Take off, then climb to `altitude_m` (see `DjiCore.takeoff`)."""
        return self._do(lambda: self.core.takeoff(altitude_m))

    def goto(
        self, lat: float, lon: float, alt_m: float, *, yaw_deg: float | None = None
    ) -> DjiCommand:
        """Fly to an absolute point (see `DjiCore.goto`)."""
        return self._do(lambda: self.core.goto(lat, lon, alt_m, yaw_deg=yaw_deg))

    def hold(self) -> DjiCommand:
        """Brake and hover (see `DjiCore.hold`)."""
        return self._do(self.core.hold)

    def land(self) -> DjiCommand:
        """Land where it is (see `DjiCore.land`)."""
        return self._do(self.core.land)

    def rtl(self) -> DjiCommand:
        """Go home (see `DjiCore.rtl`)."""
        return self._do(self.core.rtl)

    def obtain_control(self) -> DjiCommand:
        """Ask for control authority (see `DjiCore.obtain_control`)."""
        return self._do(self.core.obtain_control)

    def release_control(self) -> DjiCommand:
        """Give control authority back (see `DjiCore.release_control`)."""
        return self._do(self.core.release_control)

    def request_streams(self, rate_hz: float) -> DjiCommand:
        """Broadcast at least at `rate_hz` (see `DjiCore.request_streams`)."""
        return self._do(lambda: self.core.request_streams(rate_hz))

    def cancel_all(self, reason: str = "cancelled") -> None:
        """Cancel every pending order."""
        with self._lock:
            self.core.cancel_all(reason)
            self._flush()

    # ------------------------------------------------------------------ blocking helpers

    def wait_connected(
        self,
        timeout: float,
        *,
        idle: Callable[[], None] | None = None,
        poll_interval: float = 0.05,
    ) -> AutopilotState:
        """Poll until activated and holding control authority; DjiError after `timeout`
        seconds, or at once when activation or authority is refused (naming DJI's code).

        For start-up, not for the loop. `idle` is called between polls (a test steps its
        simulated flight controller there).
        """
        core = self.core
        deadline = self._clock() + timeout

        def activated() -> bool:
            return core.activated or core.activation_error is not None

        if not self._wait(activated, deadline, idle, poll_interval):
            raise DjiError(self._silence(timeout))
        if core.activation_error is not None:
            raise DjiError(core.activation_error)
        if not core.authority:
            cmd = self.obtain_control()
            self._wait(lambda: cmd.done, deadline, idle, poll_interval)
            if not cmd.done:
                raise DjiError(f"control authority: no answer after {timeout:g} s on {self.url}")
            if not cmd.ok:
                raise DjiError(cmd.error or "control authority refused")
        return self.telemetry

    def wait_heartbeat(
        self,
        timeout: float,
        *,
        idle: Callable[[], None] | None = None,
        poll_interval: float = 0.05,
    ) -> AutopilotState:
        """The node's start-up wait: the M100 has no heartbeat, so `wait_connected`."""
        return self.wait_connected(timeout, idle=idle, poll_interval=poll_interval)

    def _silence(self, timeout: float) -> str:
        core = self.core
        if core.messages == 0:
            detail = (
                f"nothing received ({core.bytes_received} bytes, {core.bad_frames} bad frames): "
                "check the wiring, the UART, that API control is enabled in DJI Assistant, and "
                f"the baud rate"
            )
        elif core.version is None:
            detail = "broadcast heard but no answer to get-version"
        else:
            detail = "no answer to activation"
        return f"M100 not activated after {timeout:g} s on {self.url}: {detail}"

    def wait_gps_fix(
        self,
        timeout: float,
        *,
        min_fix: int = 3,
        idle: Callable[[], None] | None = None,
        poll_interval: float = 0.05,
    ) -> AutopilotState:
        """Poll until the GPS health allows position control (fix type 3: health >= 3)."""
        deadline = self._clock() + timeout
        ok = self._wait(
            lambda: self.telemetry.gps_fix_type >= min_fix, deadline, idle, poll_interval
        )
        if not ok:
            health = self.core.gps_health
            detail = "no position item received" if health is None else f"GPS health {health}"
            raise DjiError(
                f"no usable GPS after {timeout:g} s ({detail}; position control needs 3)"
            )
        return self.telemetry

    def wait_position(
        self,
        timeout: float,
        *,
        idle: Callable[[], None] | None = None,
        poll_interval: float = 0.05,
    ) -> AutopilotState:
        """Poll until a position has been received; DjiError after `timeout` seconds."""
        deadline = self._clock() + timeout
        if not self._wait(lambda: self.telemetry.lat is not None, deadline, idle, poll_interval):
            raise DjiError(f"no position from the M100 after {timeout:g} s")
        return self.telemetry

    def wait_command(
        self,
        command: DjiCommand,
        timeout: float,
        *,
        idle: Callable[[], None] | None = None,
        poll_interval: float = 0.05,
    ) -> DjiCommand:
        """Poll until `command` is over; DjiError if it failed or is still pending."""
        deadline = self._clock() + timeout
        ok = self._wait(lambda: command.done, deadline, idle, poll_interval)
        return command_outcome(command, ok, timeout, DjiError)

    def _wait(
        self,
        cond: Callable[[], bool],
        deadline: float,
        idle: Callable[[], None] | None,
        poll_interval: float,
    ) -> bool:
        return poll_until(self.poll, self._clock, cond, deadline, idle, poll_interval)

    # ------------------------------------------------------------------ lifecycle

    def close(self) -> None:
        """Stop the stream, give control authority back (briefly awaited), close the port."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        if self.release_on_close and self.core.authority:
            cmd = self.release_control()
            end = time.monotonic() + RELEASE_WAIT_S
            while not cmd.done and time.monotonic() < end:
                self.poll(0.05)
        with self._lock:
            self.core.cancel_all("link closed")
            self._line.close()  # a dead port's close does not fail; a lost one stays closed

    def __enter__(self) -> DjiLink:
        """Use as a context manager: closed on exit."""
        return self

    def __exit__(self, *exc: object) -> None:
        """Close the link."""
        self.close()


__all__ = ["DjiLink", "MAX_TX_BACKLOG"]
