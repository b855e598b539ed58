"""The field node's link to a Husky: `HuskyCore` on two serial ports, the MCU's and the GPS's.

    husky = Husky.from_profile(load_profile("husky"))      # autopilot.url and [gps] port
    husky.wait_heartbeat(10.0)                              # start-up only: bounded waits
    husky.wait_command(husky.request_streams(10.0), 5.0)
    husky.wait_gps_fix(husky.gps_fix_timeout_s)
    husky.wait_command(husky.arm(), 5.0)
    while running:                                          # the node's 10 Hz loop
        husky.poll()                                        # read both ports, the cycle
        husky.goto(lat, lon, 0.0)                           # a setpoint for the controller
    husky.hold()                                            # zero speeds written now

Everything the protocol decides is the core's (`fieldkit.vehicle.clearpath.core.HuskyCore`);
`Husky` extends it with the ports only, the way `fieldkit.vehicle.link.Autopilot` does for
MAVLink, so the node keeps one object with the whole command API and the same start-up waits.
Every frame is written to the MCU's port the moment the core makes it (a stop order's zero
speeds leave at once). `poll()` reads what both ports hold and ticks the core; nothing blocks
the loop. Taps for a recorder: `on_rx` / `on_tx` see the MCU's bytes, `on_gps_rx` the GPS's
(the receiver is never written to).

A serial device that goes away (a USB adapter unplugged: reads fail, the tty reads end of
file) never raises into the loop: each port is a `fieldkit.vehicle.serial_port.ReopeningSerial`
of its own. It is closed, a "link" event says so once, frames written meanwhile are dropped
(`bytes_dropped`), and each poll tries the path again every `reopen_interval_s` of the core's
clock (`reopen`, `gps_reopen`), with a "reopened" event when it is back. The MCU gone: nothing
the node sends reaches the base, whose MCU's own watchdog stops the wheels when commands stop
(the event says so); the silence is a lost heartbeat, the supervisor's failsafe. The GPS gone:
its fix is lost at once (the base stops driving), and comes back with its sentences.
"""

from __future__ import annotations

import select
import time
from collections.abc import Callable
from typing import Any

from fieldkit.robot.profiles import Profile
from fieldkit.vehicle.autopilot import AutopilotError, AutopilotState, describe_error
from fieldkit.vehicle.clearpath.core import HuskyCommand, HuskyCore
from fieldkit.vehicle.links import command_outcome, poll_until
from fieldkit.vehicle.reopen import DEFAULT_INTERVAL_S, ReopenPolicy
from fieldkit.vehicle.serial_port import PORT_ERRORS, ReopeningSerial

_READ_CHUNK = 4096
# A single poll reads at most this much per port: a flooded line cannot starve the loop.
_MAX_READ_PER_POLL = 1 << 16


class HuskyError(AutopilotError):
    """The Husky link cannot do what was asked (a port that will not open, a wait that ran
    out); the message says what and why."""


class Husky(HuskyCore):
    """The node's link to one Husky: the core on the MCU's and the GPS's serial ports."""

    def __init__(
        self,
        mcu: str,
        gps: str,
        *,
        baud: int = 115200,
        gps_baud: int = 19200,
        reopen_interval_s: float = DEFAULT_INTERVAL_S,
        **options: Any,
    ) -> None:
        """Open both ports; HuskyError (an AutopilotError) if either will not open.

        The other options are `HuskyCore`'s (`profile`, `clock`, the intervals...).
        """
        super().__init__(url=mcu, gps_url=gps, **options)
        self.reopen_interval_s = reopen_interval_s
        #: Taps on the bytes as they cross the ports (a recorder): MCU in, MCU out, GPS in.
        self.on_rx: Callable[[bytes], None] | None = None
        self.on_tx: Callable[[bytes], None] | None = None
        self.on_gps_rx: Callable[[bytes], None] | None = None
        try:
            self._mcu = self._line(mcu, baud, write_timeout=0.5)
        except PORT_ERRORS as e:
            raise HuskyError(f"cannot open the Husky MCU port {mcu}: {describe_error(e)}") from e
        try:
            self._gps = self._line(gps, gps_baud, write_timeout=0)
        except PORT_ERRORS as e:
            self._mcu.close()
            raise HuskyError(f"cannot open the GPS port {gps}: {describe_error(e)}") from e
        self._mcu.on_lost = self._mcu_lost
        self._mcu.on_back = lambda down: self._event(
            "reopened", f"MCU port {mcu} back after {down:g} s"
        )
        self._gps.on_lost = self._gps_lost
        self._gps.on_back = lambda down: self._event(
            "reopened", f"GPS port {gps} back after {down:g} s"
        )

    def _line(self, path: str, baud: int, *, write_timeout: float) -> ReopeningSerial:
        """One of the two ports, reopened on the core's clock; each failure a line error."""
        line = ReopeningSerial(
            path,
            baud,
            clock=self._clock,
            reopen_interval_s=self.reopen_interval_s,
            write_timeout=write_timeout,
        )
        line.on_error = self._link_error
        return line

    def _mcu_lost(self, reason: str) -> None:
        self.link_errors += 1
        self._event(
            "link",
            f"MCU port {self._mcu.path} lost ({reason}); reopening: nothing reaches the base "
            "meanwhile, its MCU's watchdog stops the wheels",
        )

    def _gps_lost(self, reason: str) -> None:
        self.link_errors += 1
        self._event(
            "link",
            f"GPS port {self._gps.path} lost ({reason}); reopening: no fix meanwhile, the "
            "base stops",
        )
        self.gps_lost(f"port lost: {reason}")

    @classmethod
    def from_profile(
        cls, profile: Profile, url: str | None = None, gps: str | None = None, **kwargs: Any
    ) -> Husky:
        """A link as the profile says (`autopilot.url`, `autopilot.baud`, `[gps]`), or to
        `url` (the MCU) and `gps` (the receiver)."""
        settings = profile.gps
        if gps is None and settings is None:
            raise HuskyError(
                f"{profile.name}: no GPS port: give --gps DEV, or a [gps] table with its port"
            )
        return cls(
            url if url is not None else profile.autopilot.url,
            gps if gps is not None else settings.port,  # type: ignore[union-attr]
            baud=profile.autopilot.baud,
            gps_baud=settings.baud if settings is not None else 19200,
            profile=profile,
            **kwargs,
        )

    # ------------------------------------------------------------------ lifecycle

    def close(self) -> None:
        """Close both ports; pending commands are cancelled."""
        self.cancel_all("link closed")
        self._mcu.close()
        self._gps.close()

    def __enter__(self) -> Husky:
        """Use as a context manager: closed on exit."""
        return self

    def __exit__(self, *exc: object) -> None:
        """Close the link."""
        self.close()

    def fileno(self) -> int | None:
        """The MCU port's descriptor (None while it is down)."""
        return self._mcu.fileno()

    @property
    def link_down(self) -> bool:
        """Whether the MCU's or the GPS's device is lost and not reopened yet."""
        return self._mcu.down or self._gps.down

    @property
    def reopen(self) -> ReopenPolicy:
        """The MCU's device outages: down now, how many, seconds down."""
        return self._mcu.reopen

    @property
    def gps_reopen(self) -> ReopenPolicy:
        """The GPS receiver's device outages."""
        return self._gps.reopen

    @property
    def bytes_dropped(self) -> int:
        """Bytes for the MCU never written: its device was gone."""
        return self._mcu.bytes_dropped

    def write(self, buf: bytes | bytearray) -> None:
        """Send a frame to the MCU now; a dead port costs a counter, not the loop."""
        data = bytes(buf)
        if not self._mcu.write_all(data):
            return  # gone (now or before): dropped and counted by the port
        self.bytes_sent += len(data)
        if self.on_tx is not None:
            self.on_tx(data)

    # ------------------------------------------------------------------ the loop

    def poll(self, timeout: float = 0.0) -> int:
        """Read both ports and handle what they hold, then tick the core; waits up to
        `timeout` for a first byte (0: not at all). Returns the good frames and sentences."""
        for line in (self._mcu, self._gps):
            line.try_reopen()
        fds = [fd for fd in (self._mcu.fileno(), self._gps.fileno()) if fd is not None]
        if timeout > 0:
            if fds:
                try:
                    select.select(fds, [], [], timeout)
                except (OSError, ValueError):
                    pass  # a port died under us: its read below says so
            else:
                time.sleep(timeout)  # nothing to wait on: wait as select() would
        handled = self._read(self._mcu) + self._read(self._gps)
        self.tick()
        return handled

    def _read(self, line: ReopeningSerial) -> int:
        handled = 0
        total = 0
        while total < _MAX_READ_PER_POLL:
            data = line.read(_READ_CHUNK)  # a failure takes the line down: b""
            if not data:
                break
            total += len(data)
            if line is self._mcu:
                if self.on_rx is not None:
                    self.on_rx(data)
                handled += self.receive_data(data)
            else:
                if self.on_gps_rx is not None:
                    self.on_gps_rx(data)
                handled += self.receive_gps(data)
        return handled

    # ------------------------------------------------------------------ blocking helpers

    def wait_heartbeat(
        self,
        timeout: float,
        *,
        idle: Callable[[], None] | None = None,
        poll_interval: float = 0.05,
    ) -> AutopilotState:
        """Poll until the MCU answers; HuskyError after `timeout` seconds. Start-up only."""
        ok = self._wait(
            lambda: self.telemetry.last_heartbeat is not None, timeout, idle, poll_interval
        )
        if not ok:
            raise HuskyError(
                f"no answer from the Husky MCU after {timeout:g} s on {self.url} "
                f"({self.bytes_received} bytes received, {self._reader.bad_frames} bad frames)"
                "\nhint: check the port and that the base is powered (115200 8N1, RS-232)"
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
        """Poll until the GPS fix type reaches `min_fix` (3: 3D); HuskyError on timeout."""
        ok = self._wait(
            lambda: self.gps.has_fix and self.gps.fix.fix_type >= min_fix,
            timeout,
            idle,
            poll_interval,
        )
        if not ok:
            g = self.gps
            if g.messages == 0:
                detail = (
                    f"nothing readable from {g.url} ({g.bytes_received} bytes, "
                    f"{g.bad_sentences} unreadable): check its port and baud"
                )
            else:
                detail = f"fix type {g.fix.fix_type}, {g.fix.satellites} satellites"
            raise HuskyError(f"no GPS fix after {timeout:g} s ({detail})")
        return self.telemetry

    def wait_position(
        self,
        timeout: float,
        *,
        idle: Callable[[], None] | None = None,
        poll_interval: float = 0.05,
    ) -> AutopilotState:
        """Poll until a position is known (a fix with coordinates); HuskyError on timeout."""
        if not self._wait(lambda: self.telemetry.lat is not None, timeout, idle, poll_interval):
            raise HuskyError(f"GPS fix but no position after {timeout:g} s")
        return self.telemetry

    def wait_command(
        self,
        command: HuskyCommand,
        timeout: float,
        *,
        idle: Callable[[], None] | None = None,
        poll_interval: float = 0.05,
    ) -> HuskyCommand:
        """Poll until `command` is over; HuskyError if it failed or is still pending."""
        ok = self._wait(lambda: command.done, timeout, idle, poll_interval)
        return command_outcome(command, ok, timeout, HuskyError)

    def _wait(
        self,
        cond: Callable[[], bool],
        timeout: float,
        idle: Callable[[], None] | None,
        poll_interval: float,
    ) -> bool:
        deadline = self._clock() + timeout
        return poll_until(self.poll, self._clock, cond, deadline, idle, poll_interval)


__all__ = ["Husky", "HuskyError"]
