"""The Husky core: the Clearpath MCU and a GPS receiver as one vehicle, without I/O.

    core = HuskyCore(profile=load_profile("husky"), clock=clock)
    core.receive_data(mcu_bytes)                  # acknowledgements, encoders, status...
    core.receive_gps(gps_bytes)                   # NMEA sentences or UBX frames
    core.tick()                                   # the control cycle: speeds, requests
    write_mcu(core.data_to_send())
    core.telemetry                                # an AutopilotState, as every backend's
    cmd = core.goto(lat, lon, 0.0)                # returns at once; cmd.done / cmd.ok

It satisfies `fieldkit.vehicle.core.VehicleCore`, so the node, the supervisor and the
recording see a Husky as they see an ArduPilot. What each part of the interface means here:

- **heartbeat**: the MCU answering. The MCU sends nothing unasked, so every control cycle
  asks (encoders and safety flags each cycle, system status and power every
  `diagnostics_interval_s`, as husky_base does); any valid frame from it is a heartbeat.
  Silent past the profile's `heartbeat_timeout_s`: a "heartbeat" event, `heartbeat_lost`,
  and the supervisor applies the profile's failsafe. The zero-speed stream goes on meanwhile.
- **the command stream** (the MCU's watchdog stops the base when commands stop): a set
  differential speed frame every `control_interval_s` (0.1 s) whatever happens, zeros when
  there is nothing to do. A stop order (`hold`, `land`, `disarm`) writes its zero-speed frame
  at once, not at the next cycle, and is done when the MCU acknowledges it (resent each
  `ack_timeout_s`, up to `max_attempts` sends).
- **armed**: the drive enabled by `arm()` (the MCU's speed and acceleration limits set to the
  profile's, both acknowledged) and not stopped by the e-stop or a lockout. `disarm()` stops.
  `pilot_override`: the e-stop, or the MCU's pause ("ros_pause"), is on: a person has it.
- **position and fix**: the GPS (`fieldkit.vehicle.clearpath.gps.GpsCore`), its fix type on
  MAVLink's scale. Between fixes the position is carried on by wheel odometry; each fix resets
  it. GPS losing its fix, or silent: a "gps" event, and the base stops (no position, no
  driving); it goes on to its target when the fix is back.
- **heading**: a dual-antenna receiver's HDT, else an IMU's orientation (if the MCU answers
  the orientation request at start-up), else the GPS course over ground while driving faster
  than `track_min_speed_mps` (reversed when backing up), blended into the odometry's estimate
  (the wheel-speed difference over the profile's wheel separation). Standing still, the last
  estimate is kept, and turning in place moves it by odometry. Before the base has ever
  driven (no IMU), the heading is unknown (None), and a goto drives straight ahead slowly
  until the course gives one.
- **battery**: the power message's charge (percent), the system status's first voltage and
  current.
- **orders**: `goto` is a setpoint for the go-to controller (`controller.GotoController`:
  within the profile's speed and acceleration, stopping inside `hover_accuracy_m`); `rtl`
  goes to home (the first fix, moved to where `arm()` happened); `takeoff` is done at once
  (a ground robot does not fly) and `land` stops, as `hold` does.

Every frame to the MCU asks for an acknowledgement (FLAGS 0, as husky_base), matched to the
oldest outstanding frame of its type (the reference does not even check the type); the
stream's missing acknowledgements are counted (`missed_acks`), a command's are retried. A
refusal ends a command with the MCU's reason ("value out of range").
"""

from __future__ import annotations

import math
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from fieldkit.robot import geo
from fieldkit.robot.profiles import DriveSettings, Profile
from fieldkit.vehicle.autopilot import (
    AutopilotState,
    CommandStatus,
    CoreRecords,
    Event,
    clock_reading,
)
from fieldkit.vehicle.clearpath import messages as M
from fieldkit.vehicle.clearpath.controller import GotoController
from fieldkit.vehicle.clearpath.frame import Frame, FrameReader
from fieldkit.vehicle.clearpath.gps import GpsCore
from fieldkit.vehicle.core import VehicleCore

#: Below this ground speed (m/s) the GPS course says nothing about the heading.
TRACK_MIN_SPEED_MPS = 0.3
#: Weight of a GPS course in the heading estimate (the rest is the odometry's).
TRACK_GAIN = 0.5
#: An encoder step longer than this (m) between two readings is a glitch or a rollover: the
#: reading is dropped and its offset kept, as husky_base does with its 1-radian check.
ENCODER_GLITCH_M = 0.5
#: Outstanding acknowledgements kept at the most (a silent MCU must not grow the list).
MAX_PENDING = 256

_FINISHED = (CommandStatus.DONE, CommandStatus.FAILED, CommandStatus.CANCELLED)
_NO_DRIVE = M.SAFETY_ESTOP | M.SAFETY_LOCKOUT


class HuskyCommand:
    """One order to the Husky: returned at once, moved on by the core's `tick()`."""

    def __init__(
        self,
        cid: int,
        name: str,
        frames: Sequence[Frame],
        created: float,
        on_done: Callable[[HuskyCommand], None] | None = None,
    ) -> None:
        """A command sending `frames` in turn, each acknowledged; the core builds these."""
        self.id = cid
        self.name = name
        self.status = CommandStatus.QUEUED
        self.attempts = 0  # sends of the current frame
        self.result: int | None = None  # the last acknowledgement's result
        self.error: str | None = None
        self.warnings: list[str] = []
        self.created = created
        self.finished: float | None = None
        self.on_done = on_done
        self.frames = list(frames)
        self.index = 0
        self.optional: set[int] = set()  # frame indexes whose refusal is only a warning
        self.on_accept: Callable[[], str | None] | None = None  # last check; a reason fails

    @property
    def done(self) -> bool:
        """Whether it is over, whatever the outcome."""
        return self.status in _FINISHED

    @property
    def ok(self) -> bool:
        """Whether the MCU accepted it (every frame of it)."""
        return self.status is CommandStatus.DONE

    def __repr__(self) -> str:
        """E.g. `<HuskyCommand 3 arm: failed (arm refused: e_stop)>`."""
        tail = f" ({self.error})" if self.error else ""
        return f"<HuskyCommand {self.id} {self.name}: {self.status.value}{tail}>"


@dataclass(eq=False)
class _Pending:
    """A frame sent, its acknowledgement awaited."""

    frame: Frame
    deadline: float
    command: HuskyCommand | None = None


class HuskyCore(CoreRecords):
    """The node's conversation with one Husky base and its GPS: telemetry in, orders out."""

    def __init__(
        self,
        *,
        url: str = "husky",
        gps_url: str = "gps",
        profile: Profile | None = None,
        clock: Callable[[], float] = time.monotonic,
        control_interval_s: float = 0.1,
        diagnostics_interval_s: float = 1.0,
        ack_timeout_s: float = 0.25,
        max_attempts: int = 4,
        heartbeat_timeout_s: float | None = None,
        gps_timeout_s: float | None = None,
    ) -> None:
        """A core that has heard nothing yet; `url` and `gps_url` name the ports in events.

        `profile` gives the speed, acceleration and accuracy, the wheel separation, the
        heartbeat and GPS timeouts; `max_attempts` sends of a command's frame (husky_base:
        1 + 3 retries) before it fails.
        """
        if max_attempts < 1:
            raise ValueError("max_attempts must be >= 1")
        self.url = url
        self.profile = profile
        self._clock = clock
        self.control_interval_s = control_interval_s
        self.diagnostics_interval_s = diagnostics_interval_s
        self.ack_timeout_s = ack_timeout_s
        self.max_attempts = max_attempts
        ap = profile.autopilot if profile is not None else None
        kin = profile.kinematics if profile is not None else None
        drive = (profile.drive if profile is not None else None) or DriveSettings()
        gps = profile.gps if profile is not None else None
        if heartbeat_timeout_s is None:
            heartbeat_timeout_s = ap.heartbeat_timeout_s if ap is not None else 3.0
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.gps_fix_timeout_s = ap.gps_fix_timeout_s if ap is not None else 120.0
        self.max_speed = kin.max_speed_mps if kin is not None else 1.0
        self.max_accel = kin.max_accel_mps2 if kin is not None else 3.0
        self.accuracy = kin.hover_accuracy_m if kin is not None else 0.5
        self.separation = drive.wheel_separation_m
        self.guided_mode = ap.guided_mode if ap is not None else "GUIDED"
        self.hold_mode = ap.loiter_mode if ap is not None else "HOLD"
        self.rtl_mode = ap.rtl_mode if ap is not None else "RTL"
        if gps_timeout_s is None:
            gps_timeout_s = gps.timeout_s if gps is not None else 2.0
        self.gps = GpsCore(url=gps_url, clock=clock, timeout_s=gps_timeout_s)
        self.controller = GotoController(
            max_speed_mps=self.max_speed,
            max_accel_mps2=self.max_accel,
            accuracy_m=self.accuracy,
            wheel_separation_m=self.separation,
            max_turn_rate_rps=drive.max_turn_rate_rps,
        )

        self.telemetry = AutopilotState(mode=self.hold_mode, landed_state=1)
        self.events: deque[Event] = deque(maxlen=1000)
        self.received: Counter[str] = Counter()  # MCU frames by type name
        self.bytes_received = 0
        self.bytes_sent = 0
        self.link_errors = 0
        self.payload_errors = 0  # frames whose payload did not fit their type
        self.unmatched_acks = 0  # acknowledgements of nothing we sent
        self.missed_acks = 0  # stream frames never acknowledged
        self.refused = 0  # acknowledgements with a non-zero result
        self.speed_frames = 0  # set differential speed frames sent
        self.safety_flags = 0
        self.platform: M.PlatformInfo | None = None
        self.imu = False  # the MCU answers orientation requests
        self.enabled = False  # arm() done and no disarm since
        self.target: tuple[float, float] | None = None  # where goto/rtl drives
        self.wheel_command = (0.0, 0.0)  # the last speeds sent (left, right), m/s
        self.last_target: tuple[float, float, float] | None = None
        self._reader = FrameReader()
        self._outbox = bytearray()
        self._pending: deque[_Pending] = deque()
        self._commands: deque[HuskyCommand] = deque()  # config commands, one at a time
        self._stops: list[HuskyCommand] = []  # stop orders awaiting their zero's ack
        self._next_id = 1
        self._hb_lost = False
        self._link_failing = False
        self._last_cycle: float | None = None
        # When the host last began asking again after a pause of its own (a slow start-up):
        # the MCU answers only when asked, so its silence counts from then, not from before.
        self._asking_since: float | None = None
        self._last_diag: float | None = None
        self._yaw: float | None = None  # NED radians: 0 north, clockwise
        self._yaw_source = "none"
        self._enc: tuple[float, float] | None = None  # last encoder travel (left, right)
        self._enc_speed = 0.0
        self._odo = (0.0, 0.0)  # (north, east) driven since the last GPS fix, m
        self._fix_pos: tuple[float, float] | None = None  # the last GPS fix's lat, lon
        self._fix_seen: float | None = None  # its GPS last_fix time
        self._t0 = clock()

    # ------------------------------------------------------------------ bytes in and out

    def receive_data(self, data: bytes) -> int:
        """Bytes from the MCU (any split): the number of good frames handled. Never raises."""
        self._link_failing = False
        self.bytes_received += len(data)
        now = self._clock()
        frames = self._reader.feed(data)
        for frame in frames:
            self._on_frame(frame, now)
        return len(frames)

    def receive_gps(self, data: bytes) -> int:
        """Bytes from the GPS receiver (any split): good sentences and frames. Never raises."""
        f = self.gps.fix
        before = (f.last_fix, f.track_deg, f.speed_mps, f.heading_deg)
        handled = self.gps.receive_data(data)
        if f.last_fix != before[0]:
            self._on_fix()
        if (f.track_deg, f.speed_mps, f.heading_deg) != before[1:]:
            self._on_course()
        self._update_position()
        return handled

    def write(self, buf: bytes | bytearray) -> None:
        """Where every encoded frame goes: queued for `data_to_send` (a transport writes it
        to the port at once instead)."""
        self._outbox += buf
        self.bytes_sent += len(buf)

    def data_to_send(self) -> bytes:
        """The frames for the MCU since the last call."""
        out = bytes(self._outbox)
        self._outbox.clear()
        return out

    def _send(self, frame: Frame, command: HuskyCommand | None = None) -> None:
        if len(self._pending) >= MAX_PENDING:
            self._pending.popleft()
            self.missed_acks += 1
        self._pending.append(_Pending(frame, self._clock() + self.ack_timeout_s, command))
        if frame.type == M.MsgType.SET_DIFF_SPEED:
            self.speed_frames += 1
        self.write(frame.encode())

    # ------------------------------------------------------------------ state views

    @property
    def messages(self) -> int:
        """Good frames from the MCU and good sentences (or UBX frames) from the GPS."""
        return self._reader.frames + self.gps.messages

    @property
    def bad_frames(self) -> int:
        """MCU frames dropped (CRC, layout, payload) and GPS input the parsers refused."""
        return self._reader.bad_frames + self.payload_errors + self.gps.bad_sentences

    @property
    def mcu_stats(self) -> Counter[str]:
        """The MCU de-framer's counters (frames, garbage_bytes, bad_crc...)."""
        return self._reader.stats

    @property
    def heading_source(self) -> str:
        """Where the heading comes from now: "none", "odometry", "gps", "imu", "gps_hdt"."""
        return self._yaw_source

    @property
    def pending(self) -> tuple[HuskyCommand, ...]:
        """Commands not finished yet."""
        return tuple(self._commands) + tuple(self._stops)

    def heartbeat_age(self) -> float:
        """Seconds the MCU has left the host's requests unanswered: since its last answer, or
        since the host began asking again after a pause (inf before the first answer)."""
        last = self.telemetry.last_heartbeat
        if last is None:
            return math.inf
        if self._asking_since is not None:
            last = max(last, self._asking_since)
        return max(0.0, self._clock() - last)

    @property
    def pilot_override(self) -> bool:
        """Whether a person has the base: its e-stop, or the MCU's pause, is on."""
        return bool(self.safety_flags & (M.SAFETY_ESTOP | M.SAFETY_ROS_PAUSE))

    def drain_events(self) -> list[Event]:
        """What happened since the last call (the GPS's events too), oldest first."""
        out = super().drain_events() + self.gps.drain_events()
        out.sort(key=lambda e: e.time)
        return out

    def time_state(self) -> dict[str, object]:
        """The core's clock readings, for a replay to restore after the start-up bytes."""
        t = self.telemetry
        return {
            "t0": self._t0,
            "last_heartbeat": t.last_heartbeat,
            "last_message": t.last_message,
            "last_cycle": self._last_cycle,
            "asking_since": self._asking_since,
            "last_diag": self._last_diag,
            "gps_last_fix": self.gps.fix.last_fix,
            "gps_last_heard": self.gps.fix.last_heard,
            "pending_commands": len(self.pending),
        }

    def set_time_state(self, state: dict[str, object]) -> None:
        """Restore `time_state()`'s readings (pending commands are not restored)."""
        self._restore_clock(state)
        self._last_cycle = clock_reading(state, "last_cycle")
        self._asking_since = clock_reading(state, "asking_since")
        self._last_diag = clock_reading(state, "last_diag")
        self.gps.fix.last_fix = clock_reading(state, "gps_last_fix")
        self.gps.fix.last_heard = clock_reading(state, "gps_last_heard")

    # ------------------------------------------------------------------ incoming

    def _on_frame(self, frame: Frame, now: float) -> None:
        t = self.telemetry
        t.last_heartbeat = t.last_message = now
        self.received[M.name_of(frame.type)] += 1
        try:
            value = M.decode(frame)
        except M.PayloadError as e:
            self.payload_errors += 1
            self._link_error(f"MCU frame {M.name_of(frame.type)} unusable: {e}")
            return
        if isinstance(value, M.Ack):
            self._on_ack(value, now)
        elif isinstance(value, M.Encoders):
            self._on_encoders(value)
        elif isinstance(value, M.SafetyStatus):
            self._on_safety(value.flags)
        elif isinstance(value, M.SystemStatus):
            if value.voltages:
                t.battery_voltage_v = value.voltages[0]
            if value.currents:
                t.battery_current_a = value.currents[0]
        elif isinstance(value, M.PowerSystem):
            if value.charges:
                t.battery_percent = min(100.0, max(0.0, value.charges[0] * 100.0))
        elif isinstance(value, M.PlatformInfo):
            if self.platform is None:
                self._event("heartbeat", f"MCU found: Husky {value.model}-{value.serial}")
            self.platform = value
        elif isinstance(value, M.Triple) and frame.type == M.MsgType.ORIENTATION:
            if self._yaw_source != "gps_hdt":
                self._set_yaw(value.c, "imu")

    def _on_ack(self, a: M.Ack, now: float) -> None:
        for p in self._pending:
            if p.frame.type == a.type:
                break
        else:
            self.unmatched_acks += 1
            return
        self._pending.remove(p)
        cmd = p.command
        if a.result:
            self.refused += 1
        if cmd is None or cmd.done:
            return
        cmd.result = a.result
        if not a.result:
            if cmd in self._stops:
                self._finish(cmd, CommandStatus.DONE)
            else:
                self._next_frame(cmd, now)
            return
        if a.result == M.ACK_BAD_CHECKSUM and cmd.attempts < min(3, self.max_attempts):
            self._resend(cmd)  # the line garbled it: send again (the reference does)
            return
        reason = f"{M.name_of(a.type)} refused by the MCU: {a.reason()}"
        if cmd.index in cmd.optional:
            cmd.warnings.append(reason)
            self._next_frame(cmd, now)
            return
        self._finish(cmd, CommandStatus.FAILED, f"{cmd.name} failed: {reason}")

    def _on_encoders(self, e: M.Encoders) -> None:
        if len(e.travel) < 2:
            return
        left, right = e.travel[0], e.travel[1]
        self._enc_speed = (e.speed[0] + e.speed[1]) * 0.5
        prev = self._enc
        self._enc = (left, right)
        if prev is None:
            return
        dl, dr = left - prev[0], right - prev[1]
        if abs(dl) > ENCODER_GLITCH_M or abs(dr) > ENCODER_GLITCH_M:
            return  # a rollover or a glitch: the new reading becomes the reference
        ds = (dl + dr) * 0.5
        # Right wheel farther: a left (counter-clockwise) turn, a smaller NED yaw.
        dyaw = -(dr - dl) / self.separation
        yaw = self._yaw
        if yaw is not None:
            mid = yaw + dyaw * 0.5
            n, e_ = self._odo
            self._odo = (n + ds * math.cos(mid), e_ + ds * math.sin(mid))
            if self._yaw_source not in ("imu", "gps_hdt"):
                self._set_yaw(yaw + dyaw, "odometry" if self._yaw_source == "none" else None)
        self._update_velocity()
        self._update_position()

    def _on_safety(self, flags: int) -> None:
        old = self.safety_flags
        self.safety_flags = flags
        if flags == old:
            return
        on = M.flag_names(flags & ~old, M.SAFETY_FLAGS)
        off = M.flag_names(old & ~flags, M.SAFETY_FLAGS)
        parts = [f"{n} on" for n in on] + [f"{n} off" for n in off]
        self._event("safety", f"MCU safety: {', '.join(parts)}")
        if flags & ~old & (_NO_DRIVE | M.SAFETY_ROS_PAUSE) and self.target is not None:
            # Someone stopped the base: its target is forgotten, so that releasing the
            # e-stop does not send it off again on its own.
            self.target = None
            self.controller.stop()
            self._set_mode(self.hold_mode)
        self._update_armed()

    def _update_armed(self) -> None:
        t = self.telemetry
        armed = self.enabled and not self.safety_flags & _NO_DRIVE
        if armed != t.armed:
            t.armed = armed
            self._event("armed", "armed (drive enabled)" if armed else "disarmed (drive stopped)")

    def _on_fix(self) -> None:
        """A new GPS position with a fix: the position starts again from it."""
        f = self.gps.fix
        t = self.telemetry
        if f.lat is None or f.lon is None:
            return
        self._fix_pos = (f.lat, f.lon)
        self._odo = (0.0, 0.0)
        t.gps_lat, t.gps_lon = f.lat, f.lon
        t.alt_msl_m = f.alt_msl_m
        if t.home is None:
            t.home = (f.lat, f.lon, f.alt_msl_m or 0.0)

    def _on_course(self) -> None:
        """A new course or heading from the GPS: a true heading (HDT) is taken as it is; a
        course, when driving fast enough, pulls the estimate halfway toward it."""
        f = self.gps.fix
        if f.heading_deg is not None:
            self._set_yaw(math.radians(f.heading_deg), "gps_hdt")
            return
        if (
            f.track_deg is None
            or f.speed_mps is None
            or f.speed_mps < TRACK_MIN_SPEED_MPS
            or self._yaw_source in ("imu", "gps_hdt")
            or not self.gps.has_fix
        ):
            return
        course = math.radians(f.track_deg)
        if self._enc_speed < 0:
            course += math.pi  # backing up: the course is behind the base
        yaw = self._yaw
        if yaw is None or self._yaw_source == "none":
            self._set_yaw(course, "gps")
        else:
            self._set_yaw(yaw + TRACK_GAIN * math.remainder(course - yaw, 2 * math.pi), "gps")

    def _set_yaw(self, yaw: float, source: str | None) -> None:
        self._yaw = math.remainder(yaw, 2.0 * math.pi)
        if source is not None:
            self._yaw_source = source
        t = self.telemetry
        t.yaw_rad = self._yaw
        t.heading_deg = math.degrees(self._yaw) % 360.0

    def _update_velocity(self) -> None:
        t = self.telemetry
        v = self._enc_speed
        t.ground_speed_mps = abs(v)
        yaw = self._yaw
        if yaw is None:
            t.vel_north_mps = t.vel_east_mps = None
        else:
            t.vel_north_mps, t.vel_east_mps = v * math.cos(yaw), v * math.sin(yaw)
        t.vel_down_mps = 0.0

    def _update_position(self) -> None:
        """The telemetry's position: the last fix plus the odometry since, with its fix type."""
        t = self.telemetry
        f = self.gps.fix
        t.gps_fix_type = f.fix_type if self.gps.has_fix else min(f.fix_type, 1)
        t.satellites = f.satellites
        pos = self._fix_pos
        if pos is None:
            return
        n, e = self._odo
        try:
            t.lat, t.lon = geo.offset_gps(pos[0], pos[1], n, e) if (n or e) else pos
        except ValueError:
            t.lat, t.lon = pos
        t.alt_rel_m = 0.0

    # ------------------------------------------------------------------ time

    def tick(self) -> None:
        """The control cycle when due (speeds, requests), retries, heartbeat and GPS checks."""
        now = self._clock()
        had_fix = self.gps.has_fix
        self.gps.tick()
        if had_fix and not self.gps.has_fix:
            self._update_position()
        self._expire(now)
        if self._last_cycle is not None and now - self._last_cycle > self.heartbeat_timeout_s / 2:
            # The host asked nothing for a while (its loop was held up): not the MCU's silence.
            self._asking_since = now
        if self.telemetry.last_heartbeat is not None:
            age = self.heartbeat_age()
            if age > self.heartbeat_timeout_s and not self._hb_lost:
                self._hb_lost = True
                self._event("heartbeat", f"MCU silent: no answer for {age:.1f} s")
            elif age <= self.heartbeat_timeout_s and self._hb_lost:
                self._hb_lost = False
                self._event("heartbeat", "MCU answering again")
        # Just under the interval: a loop ticking at exactly the control rate sends every tick.
        due = self._last_cycle is None or now - self._last_cycle >= self.control_interval_s * 0.95
        if due:
            self._cycle(now)

    def gps_lost(self, reason: str) -> None:
        """The GPS receiver's device went away: no fix from now on (the base stops driving),
        until its sentences give one again."""
        had_fix = self.gps.has_fix
        self.gps.device_lost(reason)
        if had_fix:
            self._update_position()

    def _cycle(self, now: float) -> None:
        dt = self.control_interval_s if self._last_cycle is None else now - self._last_cycle
        self._last_cycle = now
        left, right = self._drive(min(max(dt, 0.0), 1.0))
        self._send_speed(left, right)
        self._send(M.request(M.MsgType.ENCODERS))
        self._send(M.request(M.MsgType.SAFETY_SYSTEM))
        if self.imu:
            self._send(M.request(M.MsgType.ORIENTATION))
        if self._last_diag is None or now - self._last_diag >= self.diagnostics_interval_s * 0.95:
            self._last_diag = now
            self._send(M.request(M.MsgType.SYSTEM_STATUS))
            self._send(M.request(M.MsgType.POWER_SYSTEM))

    def _send_speed(self, left: float, right: float, command: HuskyCommand | None = None) -> None:
        self.wheel_command = (left, right)
        a = self.max_accel
        self._send(M.set_diff_speed(left, right, a, a), command)

    def _drive(self, dt: float) -> tuple[float, float]:
        """This cycle's wheel speeds: toward the target, or zeros."""
        ctl = self.controller
        target = self.target
        t = self.telemetry
        if (
            target is None
            or not self.telemetry.armed
            or not self.gps.has_fix
            or t.lat is None
            or t.lon is None
        ):
            return ctl.stop()
        dist, bearing = geo.range_bearing(t.lat, t.lon, target[0], target[1])
        speeds = ctl.step(dist, bearing, self._yaw, dt)
        if ctl.arrived and t.mode == self.rtl_mode:
            self._event("mode", f"home reached: mode {self.rtl_mode} -> {self.hold_mode}")
            t.mode = self.hold_mode
            self.target = None
        return speeds

    def _expire(self, now: float) -> None:
        """Acknowledgements overdue: a command's frame is sent again or the command fails;
        the stream's are counted."""
        while self._pending and self._pending[0].deadline <= now:
            p = self._pending.popleft()
            cmd = p.command
            if cmd is None or cmd.done:
                self.missed_acks += 1
                continue
            if cmd.attempts < self.max_attempts:
                self._resend(cmd)
                continue
            self._finish(
                cmd,
                CommandStatus.FAILED,
                f"{cmd.name} failed: {M.name_of(p.frame.type)} not acknowledged after "
                f"{cmd.attempts} {'try' if cmd.attempts == 1 else 'tries'}",
            )

    # ------------------------------------------------------------------ commands

    def _new(
        self,
        name: str,
        frames: Sequence[Frame],
        on_done: Callable[[HuskyCommand], None] | None,
    ) -> HuskyCommand:
        cmd = HuskyCommand(self._next_id, name, frames, self._clock(), on_done)
        self._next_id += 1
        return cmd

    def _refused(
        self, name: str, reason: str, on_done: Callable[[HuskyCommand], None] | None = None
    ) -> HuskyCommand:
        cmd = self._new(name, (), on_done)
        self._finish(cmd, CommandStatus.FAILED, f"{name} refused: {reason}")
        return cmd

    def _done_now(
        self, name: str, on_done: Callable[[HuskyCommand], None] | None, quiet: bool = False
    ) -> HuskyCommand:
        cmd = self._new(name, (), on_done)
        self._finish(cmd, CommandStatus.DONE, quiet=quiet)
        return cmd

    def _finish(
        self,
        cmd: HuskyCommand,
        status: CommandStatus,
        error: str | None = None,
        quiet: bool = False,
    ) -> None:
        cmd.status = status
        cmd.error = error
        cmd.finished = self._clock()
        if cmd in self._stops:
            self._stops.remove(cmd)
        if cmd in self._commands:
            self._commands.remove(cmd)
            self._start_next()
        if not quiet:
            text = error or f"{cmd.name}: {status.value}"
            if status is CommandStatus.DONE and cmd.warnings:
                text += f" ({len(cmd.warnings)} optional part(s) refused: {cmd.warnings[0]})"
            self._event("command", text, cmd)
        if cmd.on_done is not None:
            cmd.on_done(cmd)

    def _queue(self, cmd: HuskyCommand) -> HuskyCommand:
        """Send a configuration command's frames one at a time, after those before it."""
        self._commands.append(cmd)
        if len(self._commands) == 1:
            self._start_next()
        return cmd

    def _start_next(self) -> None:
        if not self._commands:
            return
        cmd = self._commands[0]
        if cmd.status is CommandStatus.QUEUED:
            cmd.status = CommandStatus.ACTIVE
            cmd.index = 0
            self._send_frame(cmd)

    def _send_frame(self, cmd: HuskyCommand) -> None:
        if cmd.index >= len(cmd.frames):
            reason = cmd.on_accept() if cmd.on_accept is not None else None
            if reason is None:
                self._finish(cmd, CommandStatus.DONE)
            else:
                self._finish(cmd, CommandStatus.FAILED, f"{cmd.name} refused: {reason}")
            return
        cmd.attempts = 0
        self._resend(cmd)

    def _resend(self, cmd: HuskyCommand) -> None:
        cmd.attempts += 1
        if cmd in self._stops:
            self._send_speed(0.0, 0.0, cmd)
        else:
            self._send(cmd.frames[cmd.index], cmd)

    def _next_frame(self, cmd: HuskyCommand, now: float) -> None:
        cmd.index += 1
        self._send_frame(cmd)

    def cancel(self, command: HuskyCommand, reason: str = "cancelled") -> None:
        """Stop waiting for `command` (an acknowledgement that comes later is ignored)."""
        if not command.done:
            self._finish(command, CommandStatus.CANCELLED, f"{command.name}: {reason}")

    def cancel_all(self, reason: str = "cancelled") -> None:
        """Give up every command in progress."""
        for cmd in self.pending:
            self.cancel(cmd, reason)

    def _stop_now(self, name: str, on_done: Callable[[HuskyCommand], None] | None) -> HuskyCommand:
        """Zero speeds on the wire now; done when the MCU acknowledges them."""
        self.target = None
        self.controller.stop()
        self.controller.reset()
        cmd = self._new(name, (), on_done)
        cmd.status = CommandStatus.ACTIVE
        self._stops.append(cmd)
        self._resend(cmd)
        return cmd

    def _set_mode(self, mode: str) -> None:
        t = self.telemetry
        if t.mode != mode:
            self._event("mode", f"mode {t.mode} -> {mode}")
            t.mode = mode

    def arm(self, *, on_done: Callable[[HuskyCommand], None] | None = None) -> HuskyCommand:
        """Enable the drive: the MCU's max acceleration and max speed set to the profile's
        (acknowledged); refused under the e-stop or a lockout."""
        if self.telemetry.last_heartbeat is None:
            return self._refused("arm", "no answer from the MCU yet", on_done)
        frames = (
            M.set_max_accel(self.max_accel, self.max_accel),
            M.set_max_speed(self.max_speed, self.max_speed),
        )
        cmd = self._new("arm", frames, on_done)

        def check() -> str | None:
            blocked = M.flag_names(self.safety_flags & _NO_DRIVE, M.SAFETY_FLAGS)
            if blocked:
                return f"the base will not move: {', '.join(blocked)}"
            self.enabled = True
            t = self.telemetry
            if self.gps.has_fix and t.lat is not None and t.lon is not None:
                t.home = (t.lat, t.lon, t.alt_msl_m or 0.0)  # home is where it arms
            self._update_armed()
            return None

        cmd.on_accept = check
        return self._queue(cmd)

    def disarm(self, *, on_done: Callable[[HuskyCommand], None] | None = None) -> HuskyCommand:
        """Stop now and disable the drive (the zero-speed stream goes on)."""
        self.enabled = False
        self._update_armed()
        self._set_mode(self.hold_mode)
        return self._stop_now("disarm", on_done)

    def takeoff(
        self, altitude_m: float, *, on_done: Callable[[HuskyCommand], None] | None = None
    ) -> HuskyCommand:
        """Done at once: a ground robot does not fly (nothing moves)."""
        return self._done_now(f"takeoff {altitude_m:g} (ground robot: nothing to do)", on_done)

    def goto(
        self,
        lat: float,
        lon: float,
        alt_m: float = 0.0,
        *,
        on_done: Callable[[HuskyCommand], None] | None = None,
    ) -> HuskyCommand:
        """Drive to (lat, lon) and stop within the accuracy radius; `alt_m` is ignored. A
        setpoint (done at once, superseded by the next one), refused when the drive is not
        enabled, and ignored (the base stops) while the GPS has no fix."""
        name = f"goto {lat:.7f},{lon:.7f}"
        if not (math.isfinite(lat) and math.isfinite(lon)):
            return self._refused(name, "non-finite coordinates", on_done)
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return self._refused(name, "latitude or longitude out of range", on_done)
        if self.telemetry.last_heartbeat is None:
            return self._refused(name, "no answer from the MCU yet", on_done)
        if not self.telemetry.armed:
            return self._refused(name, "the drive is not enabled (arm first)", on_done)
        for stop in list(self._stops):
            self.cancel(stop, "superseded by a goto")
        if self.target != (lat, lon):
            self.controller.reset()
        self.target = (lat, lon)
        self.last_target = (lat, lon, 0.0)
        self._set_mode(self.guided_mode)
        # Setpoints come every tick: finished quietly, no event each.
        return self._done_now(name, on_done, quiet=True)

    def hold(self, *, on_done: Callable[[HuskyCommand], None] | None = None) -> HuskyCommand:
        """Stop the wheels now (zero speeds written at once, acknowledged) and stay."""
        self._set_mode(self.hold_mode)
        return self._stop_now("hold", on_done)

    def land(self, *, on_done: Callable[[HuskyCommand], None] | None = None) -> HuskyCommand:
        """A ground robot's land: stop, as `hold`."""
        self._set_mode(self.hold_mode)
        return self._stop_now("land (stop)", on_done)

    def rtl(self, *, on_done: Callable[[HuskyCommand], None] | None = None) -> HuskyCommand:
        """Drive home (where it armed, or the first fix) and stop there."""
        home = self.telemetry.home
        if home is None:
            return self._refused("rtl", "no home yet (no GPS fix so far)", on_done)
        cmd = self.goto(home[0], home[1], 0.0)
        if not cmd.ok:
            return self._refused("rtl", (cmd.error or "").split("refused: ")[-1], on_done)
        self._set_mode(self.rtl_mode)
        return self._done_now("rtl", on_done)

    def request_streams(
        self, rate_hz: float, *, on_done: Callable[[HuskyCommand], None] | None = None
    ) -> HuskyCommand:
        """Start-up: poll the MCU at `rate_hz` (its control cycle), ask for its platform
        info and probe for an IMU (an orientation request the MCU may refuse: a warning)."""
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            return self._refused("request_streams", f"rate must be > 0 Hz, got {rate_hz}", on_done)
        self.control_interval_s = 1.0 / rate_hz
        frames = (M.request(M.MsgType.PLATFORM_INFO), M.request(M.MsgType.ORIENTATION))
        cmd = self._new(f"request_streams {rate_hz:g} Hz", frames, on_done)
        cmd.optional.add(1)

        def check() -> str | None:
            self.imu = not cmd.warnings  # the MCU answered the orientation probe
            return None

        cmd.on_accept = check
        return self._queue(cmd)


__all__ = ["HuskyCommand", "HuskyCore"]


def _is_a_vehicle_core(core: HuskyCore) -> VehicleCore:
    """Never called: mypy checks here that `HuskyCore` offers the `VehicleCore` interface."""
    return core
