"""The autopilot protocol core: MAVLink to an ArduPilot autopilot, without I/O.

PX4 flies otherwise (its own mode numbers, OFFBOARD's setpoint stream): `fieldkit.vehicle.
px4.Px4Core` is this core with PX4's conversation on top, through a few hooks here (mode
names, the override text, steps held back until `ready`).

`AutopilotCore` is the node's side of the conversation in the manner of h11: bytes from the
autopilot go in (`receive_data`), time moves on (`tick`, with the injected `clock`), and the
MAVLink frames to send come out (`data_to_send`); it never opens, reads or writes a port.
`fieldkit.vehicle.link.Autopilot` is the same core on a pymavlink connection.

    core = AutopilotCore(profile=load_profile("solo"), clock=clock)
    core.receive_data(line_bytes)                   # telemetry, ACKs, heartbeats...
    takeoff = core.takeoff(5.0)                     # returns at once: a MavCommand
    core.tick()                                     # retries, timeouts, our heartbeat
    write(core.data_to_send())

Every command is a small state machine that `tick()` moves on: send, await the COMMAND_ACK
until a deadline, resend up to `max_attempts` times, then report. Only one COMMAND_LONG is in
flight at a time because a COMMAND_ACK names only the command id, so two in flight could not
be told apart; the rest wait in a FIFO queue. Safety commands (`land`, `rtl`, `hold`) go to
the front of the queue. Setpoints (`goto`) have no ACK in MAVLink and are sent at once.

Time comes from the injected `clock` (default `time.monotonic`), so tests drive deadlines,
retries and heartbeat ages without sleeping. A transport that reopens a lost line calls
`connection_made()`: the parser forgets any half frame and the streams are asked again.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, TypedDict

from pymavlink import mavutil
from pymavlink.dialects.v20 import all as mavlink2

from fieldkit.errors import FieldkitError
from fieldkit.robot.profiles import Profile
from fieldkit.vehicle.mavlink import FrameReader, new_codec

COMPANION_COMPONENT = mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER
"""Our MAVLink component id: an onboard (companion) computer."""
GCS_SYSTEM = 255
"""Our MAVLink system id: ArduPilot's default SYSID_MYGCS, so its GCS failsafe watches us."""
FORCE_ARM = 2989
"""COMPONENT_ARM_DISARM param2 that skips ArduPilot's pre-arm checks."""
FORCE_DISARM = 21196
"""COMPONENT_ARM_DISARM param2 that disarms an ArduPilot vehicle even in the air."""
RC_UNUSED = (0, 65535)
"""RC channel values that mean "no such channel" in RC_CHANNELS."""
MAX_ALTITUDE_M = 100_000.0
"""Setpoint altitudes beyond this many metres from home are refused (not an altitude)."""
_FLOAT32_MAX = 3.4028234663852886e38

# SET_POSITION_TARGET type_mask: use the position only (ignore velocity, acceleration, yaw
# rate, and yaw unless given). Bits: 0-2 position, 3-5 velocity, 6-8 acceleration, 10 yaw,
# 11 yaw rate.
_MASK_POSITION_ONLY = 0b1101_1111_1000
_MASK_POSITION_YAW = 0b1001_1111_1000

# The messages `request_streams` asks for by SET_MESSAGE_INTERVAL: everything AutopilotState holds.
_STREAMED = (
    mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT,
    mavlink2.MAVLINK_MSG_ID_ATTITUDE,
    mavlink2.MAVLINK_MSG_ID_SYS_STATUS,
    mavlink2.MAVLINK_MSG_ID_BATTERY_STATUS,
    mavlink2.MAVLINK_MSG_ID_RC_CHANNELS,
    mavlink2.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
)
# Home changes rarely (at arming): a slow stream is enough to learn it and notice a change.
_HOME_RATE_HZ = 0.5
# STATUSTEXT this recent is quoted in a command failure ("PreArm: Need 3D Fix").
_STATUSTEXT_WINDOW_S = 2.0


class AutopilotError(FieldkitError):
    """The autopilot link cannot do what was asked; the message says what and why."""


@dataclass
class AutopilotState:
    """The autopilot's latest state as the link has seen it; None until reported."""

    lat: float | None = None  # degrees, GLOBAL_POSITION_INT (the autopilot's fused estimate)
    lon: float | None = None
    alt_rel_m: float | None = None  # above home
    alt_msl_m: float | None = None
    heading_deg: float | None = None  # 0..360 from north, clockwise
    yaw_rad: float | None = None  # ATTITUDE yaw: 0 north, positive toward east
    vel_north_mps: float | None = None
    vel_east_mps: float | None = None
    vel_down_mps: float | None = None
    ground_speed_mps: float | None = None
    battery_voltage_v: float | None = None
    battery_current_a: float | None = None
    battery_percent: float | None = None
    armed: bool = False
    mode: str = "UNKNOWN"  # pymavlink's name for the custom mode, e.g. "GUIDED"
    custom_mode: int | None = None
    mav_type: int | None = None  # HEARTBEAT.type: 2 quadrotor, 10 ground rover...
    autopilot_type: int | None = None  # HEARTBEAT.autopilot: 3 ArduPilot, 12 PX4
    system_status: int | None = None  # MAV_STATE
    landed_state: int | None = None  # 1 on ground, 2 in air, 3 taking off, 4 landing
    gps_fix_type: int = 0  # 0-1 no fix, 2 2D, 3 3D, 4+ DGPS/RTK
    satellites: int | None = None
    gps_lat: float | None = None  # the raw GPS fix (GPS_RAW_INT), degrees
    gps_lon: float | None = None
    rc_channels: tuple[int, ...] = ()  # PWM in microseconds, channel 1 first
    rc_rssi: int | None = None
    rc_override: bool = False  # the override channel is at or above the override PWM
    home: tuple[float, float, float] | None = None  # lat, lon (degrees), alt MSL (m)
    last_heartbeat: float | None = None  # link clock time of the last vehicle heartbeat
    last_message: float | None = None  # link clock time of the last message from the vehicle
    statustext: str | None = None  # the last STATUSTEXT

    def copy(self) -> AutopilotState:
        """An independent snapshot (the link keeps updating its own object)."""
        return dataclasses.replace(self)


class CommandStatus(StrEnum):
    """Where a command stands."""

    QUEUED = "queued"  # waiting for the one in flight, or for a first heartbeat
    ACTIVE = "active"  # sent, waiting for its COMMAND_ACK
    DONE = "done"  # accepted (every step of it)
    FAILED = "failed"  # refused, or no ACK after every attempt; see `error`
    CANCELLED = "cancelled"


_FINISHED = (CommandStatus.DONE, CommandStatus.FAILED, CommandStatus.CANCELLED)


@dataclass(eq=False)
class _Step:
    """One message of a command: sent, and unless `ack` is None, acknowledged."""

    label: str  # what failed, in messages: "MAV_CMD_COMPONENT_ARM_DISARM"
    send: Callable[[int], None]  # sends it; argument: the confirmation (0, then retries)
    ack: int | None  # the MAV_CMD id to await in COMMAND_ACK; None for fire and forget
    on_accept: Callable[[], None] | None = None
    optional: bool = False  # a refusal is a warning, not a failure of the command
    # Held back (not sent, no attempt counted) until `ready(now)` holds, for at most
    # `ready_timeout_s`: PX4's OFFBOARD switch waits for its setpoint stream to settle.
    ready: Callable[[float], bool] | None = None
    waiting_for: str = ""  # what `ready` waits for, in the failure text
    ready_timeout_s: float = 10.0


class MavCommand:
    """One request to the autopilot: returned at once, moved on by the link's `tick()`."""

    def __init__(
        self,
        cid: int,
        name: str,
        steps: Sequence[_Step],
        created: float,
        on_done: Callable[[MavCommand], None] | None = None,
    ) -> None:
        """A queued command; the link builds these."""
        self.id = cid
        self.name = name
        self.status = CommandStatus.QUEUED
        self.attempts = 0  # sends of the current (or last) step
        self.result: int | None = None  # the last MAV_RESULT received
        self.error: str | None = None
        self.warnings: list[str] = []  # refusals of optional steps
        self.created = created
        self.finished: float | None = None
        self.on_done = on_done
        self._steps = list(steps)
        self._index = 0
        self._deadline = 0.0
        self._waiting_since = 0.0  # when the current step began waiting for `ready`

    @property
    def done(self) -> bool:
        """Whether it is over, whatever the outcome."""
        return self.status in _FINISHED

    @property
    def ok(self) -> bool:
        """Whether it was accepted."""
        return self.status is CommandStatus.DONE

    @property
    def result_name(self) -> str | None:
        """The last MAV_RESULT by name, e.g. "MAV_RESULT_DENIED"."""
        return None if self.result is None else _result_name(self.result)

    def __repr__(self) -> str:
        """E.g. `<MavCommand 3 arm: failed (arm refused: MAV_RESULT_FAILED)>`."""
        tail = f" ({self.error})" if self.error else ""
        return f"<MavCommand {self.id} {self.name}: {self.status.value}{tail}>"


@dataclass(frozen=True)
class Event:
    """Something the node should know (and log): see `AutopilotCore.drain_events`."""

    time: float  # link clock
    # "command", "heartbeat", "mode", "armed", "override", "statustext", "link" (a line
    # error, the device lost), "reopened" (the device back)
    kind: str
    text: str
    command: MavCommand | None = None


def _result_name(result: int) -> str:
    """MAV_RESULT number to name."""
    entry = mavlink2.enums["MAV_RESULT"].get(result)
    return entry.name if entry is not None else f"MAV_RESULT({result})"


def _cmd_name(cmd: int) -> str:
    """MAV_CMD number to name."""
    entry = mavlink2.enums["MAV_CMD"].get(cmd)
    return entry.name if entry is not None else f"MAV_CMD({cmd})"


def _is_vehicle_heartbeat(msg: Any) -> bool:
    """A heartbeat from an autopilot, not from a GCS, gimbal, camera or radio."""
    if msg.autopilot == mavlink2.MAV_AUTOPILOT_INVALID:
        return False
    return msg.type not in (
        mavlink2.MAV_TYPE_GCS,
        mavlink2.MAV_TYPE_GIMBAL,
        mavlink2.MAV_TYPE_ADSB,
        mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
        mavlink2.MAV_TYPE_CAMERA,
    )


class CoreOptions(TypedDict, total=False):
    """`AutopilotCore`'s keyword options, as a transport passes them on unchanged."""

    profile: Profile | None
    clock: Callable[[], float]
    source_system: int
    source_component: int
    ack_timeout_s: float
    max_attempts: int
    queue_timeout_s: float
    heartbeat_interval_s: float | None
    heartbeat_timeout_s: float | None
    override_channel: int
    override_pwm: int
    target_system: int | None


def clock_reading(state: dict[str, object], key: str) -> float | None:
    """The clock reading `key` of a core's `time_state()` (None when missing or not a number)."""
    v = state.get(key)
    return float(v) if isinstance(v, int | float) else None


class CoreRecords:
    """What every protocol core keeps the same way (MAVLink, DJI, Clearpath): its event log,
    its link-error streaks, the heartbeat's age and the clock readings a replay restores.

    The core sets the attributes below in its `__init__`; this only reads and updates them.
    """

    url: str
    telemetry: AutopilotState
    events: deque[Event]
    link_errors: int
    heartbeat_timeout_s: float
    _clock: Callable[[], float]
    _link_failing: bool
    _t0: float

    def heartbeat_age(self) -> float:
        """Seconds since the vehicle was last heard (infinity before the first time)."""
        last = self.telemetry.last_heartbeat
        return math.inf if last is None else max(0.0, self._clock() - last)

    @property
    def heartbeat_lost(self) -> bool:
        """Whether the vehicle has been silent longer than the profile allows (or never spoke)."""
        return self.heartbeat_age() > self.heartbeat_timeout_s

    def drain_events(self) -> list[Event]:
        """The events since the last call, oldest first."""
        out = list(self.events)
        self.events.clear()
        return out

    def _event(self, kind: str, text: str, command: object = None) -> None:
        # Event.command is typed for MAVLink commands; the other cores' ride along unchanged.
        self.events.append(Event(self._clock(), kind, text, command))  # type: ignore[arg-type]

    def _link_error(self, text: str) -> None:
        self.link_errors += 1
        if not self._link_failing:
            # Log the first error of a streak only: a dead port fails on every poll.
            self._link_failing = True
            self._event("link", f"{self.url}: {text}")

    def _restore_clock(self, state: dict[str, object]) -> None:
        """Restore the readings every core's `time_state()` has: t0 and when last heard."""
        t0 = clock_reading(state, "t0")
        if t0 is not None:
            self._t0 = t0
        self.telemetry.last_heartbeat = clock_reading(state, "last_heartbeat")
        self.telemetry.last_message = clock_reading(state, "last_message")


class AutopilotCore(CoreRecords):
    """The node's MAVLink conversation with one autopilot: telemetry in, checked commands out."""

    def __init__(
        self,
        *,
        url: str = "autopilot",
        profile: Profile | None = None,
        clock: Callable[[], float] = time.monotonic,
        source_system: int = GCS_SYSTEM,
        source_component: int = COMPANION_COMPONENT,
        ack_timeout_s: float = 1.0,
        max_attempts: int = 3,
        queue_timeout_s: float = 10.0,
        heartbeat_interval_s: float | None = 1.0,
        heartbeat_timeout_s: float | None = None,
        override_channel: int = 5,
        override_pwm: int = 1800,
        target_system: int | None = None,
    ) -> None:
        """A link that has heard nothing yet; `url` only names it in event texts.

        `profile` gives the mode names, the heartbeat timeout and whether the robot is a
        ground robot (no takeoff). `heartbeat_interval_s`: how often `tick()` sends our own
        heartbeat (None: only `send_heartbeat()`). RC channel `override_channel` at or
        above `override_pwm` microseconds reads as the pilot taking over. `target_system`
        pins the autopilot's system id; by default the first autopilot heartbeat decides.
        """
        if max_attempts < 1:
            raise ValueError("max_attempts must be >= 1")
        self.url = url  # names the link in event texts
        self.profile = profile
        self._clock = clock
        self.ack_timeout_s = ack_timeout_s
        self.max_attempts = max_attempts
        self.queue_timeout_s = queue_timeout_s
        self.heartbeat_interval_s = heartbeat_interval_s
        ap = profile.autopilot if profile is not None else None
        if heartbeat_timeout_s is None:
            heartbeat_timeout_s = ap.heartbeat_timeout_s if ap is not None else 3.0
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.gps_fix_timeout_s = ap.gps_fix_timeout_s if ap is not None else 120.0
        self.ground = profile.is_ground if profile is not None else False
        self.flavour = ap.flavour if ap is not None else "ardupilot"
        if ap is not None:
            self.guided_mode, self.loiter_mode = ap.guided_mode, ap.loiter_mode
            self.land_mode, self.rtl_mode = ap.land_mode, ap.rtl_mode
        elif self.ground:
            self.guided_mode, self.loiter_mode, self.land_mode, self.rtl_mode = (
                "GUIDED",
                "HOLD",
                "HOLD",
                "RTL",
            )
        else:
            self.guided_mode, self.loiter_mode, self.land_mode, self.rtl_mode = (
                "GUIDED",
                "LOITER",
                "LAND",
                "RTL",
            )
        self.override_channel = override_channel
        self.override_pwm = override_pwm
        self.source_system = source_system
        self.source_component = source_component

        # Every frame the codec encodes goes through `write`: queued here, written at once by
        # a transport that overrides it.
        self._mav = new_codec(self, source_system, source_component)
        self._reader = FrameReader(self._mav)
        self._outbox = bytearray()

        self.telemetry = AutopilotState()
        self.target_system: int | None = None
        self._pinned = target_system
        self.target_component: int | None = None
        self.message_counts: Counter[str] = Counter()
        self.bytes_received = 0
        self.bytes_sent = 0
        self.link_errors = 0
        self.events: deque[Event] = deque(maxlen=1000)
        self.mode_override = False  # the mode changed without the node asking
        self.last_target: tuple[float, float, float] | None = None  # last goto (lat, lon, alt)
        self._queue: deque[MavCommand] = deque()
        self._active: MavCommand | None = None
        self._next_id = 1
        self._commanded_mode: str | None = None
        self._hb_lost = False
        self._last_hb_sent: float | None = None
        self._statustexts: deque[tuple[float, str]] = deque(maxlen=8)
        self._link_failing = False
        self.stream_rate_hz: float | None = None  # the last `request_streams` rate
        self._rc_seen_full = False  # RC_CHANNELS seen: ignore the older RC_CHANNELS_RAW
        self._t0 = clock()

    # ------------------------------------------------------------------ bytes in and out

    def receive_data(self, data: bytes) -> int:
        """Handle bytes from the autopilot (any split of the stream); good messages handled.

        Never raises on what the line holds: a message that cannot be used costs a link error.
        """
        self._link_failing = False
        self.bytes_received += len(data)
        now = self._clock()
        handled = 0
        for msg in self._reader.feed(data):
            try:
                self._handle(msg, now)
            except Exception as e:  # a hostile message must not stop the node's loop
                self._link_error(f"cannot use {msg.get_type()}: {describe_error(e)}")
                continue
            handled += 1
        return handled

    def connection_made(self) -> None:
        """The line was reopened after a loss: start afresh on it.

        No half frame from before (its rest never comes), no line-error streak, and the
        streams asked again at the last `request_streams` rate: the autopilot may have
        rebooted (a brown-out on the same cable), and one that did streams nothing until
        asked. The command machine and the telemetry carry on: the heartbeat's age tells
        the supervisor how long the link was gone.
        """
        self._reader.reset()
        self._link_failing = False
        if self.stream_rate_hz is not None:
            self.request_streams(self.stream_rate_hz)

    def tick(self) -> None:
        """Move time on: our heartbeat when due, heartbeat-loss events, command deadlines."""
        self._tick(self._clock())

    def write(self, buf: bytes | bytearray) -> None:
        """Where the codec puts each encoded frame: queued for `data_to_send`."""
        self._outbox += buf
        self.bytes_sent += len(buf)

    def data_to_send(self) -> bytes:
        """The frames encoded since the last call, to be written to the autopilot."""
        out = bytes(self._outbox)
        self._outbox.clear()
        return out

    # ------------------------------------------------------------------ state views

    @property
    def messages(self) -> int:
        """Good messages decoded so far (from every system on the link)."""
        return self._reader.messages

    @property
    def bad_frames(self) -> int:
        """Rejected frames and runs of garbage bytes (bad CRC, bad length, noise)."""
        return self._reader.bad_frames

    @property
    def unknown_frames(self) -> int:
        """Frames with message ids our dialect does not know."""
        return self._reader.unknown_frames

    @property
    def pending(self) -> tuple[MavCommand, ...]:
        """Commands not finished yet: the one in flight first, then the queue."""
        head = (self._active,) if self._active is not None else ()
        return head + tuple(self._queue)

    def time_state(self) -> dict[str, object]:
        """Every clock reading the core keeps (and the commands still pending): what a replay
        restores after feeding the start-up bytes, so its ticks run on the same times."""
        t = self.telemetry
        return {
            "t0": self._t0,
            "last_hb_sent": self._last_hb_sent,
            "last_heartbeat": t.last_heartbeat,
            "last_message": t.last_message,
            "statustexts": [[at, text] for at, text in self._statustexts],
            "pending_commands": len(self._queue) + (self._active is not None),
        }

    def set_time_state(self, state: dict[str, object]) -> None:
        """Restore the clock readings of `time_state` (pending commands are not restored)."""
        self._restore_clock(state)
        self._last_hb_sent = clock_reading(state, "last_hb_sent")
        texts = state.get("statustexts")
        if isinstance(texts, list):
            self._statustexts.clear()
            for at, text in texts:
                self._statustexts.append((float(at), str(text)))

    @property
    def pilot_override(self) -> bool:
        """Whether someone else has the vehicle: RC override channel high, or a mode change
        the node did not ask for (pilot's mode switch, the autopilot's own failsafe)."""
        return self.telemetry.rc_override or self.mode_override

    def _tick(self, now: float) -> None:
        if self.heartbeat_interval_s is not None and (
            self._last_hb_sent is None or now - self._last_hb_sent >= self.heartbeat_interval_s
        ):
            self.send_heartbeat()
        last = self.telemetry.last_heartbeat
        if last is not None:
            age = now - last
            if age > self.heartbeat_timeout_s and not self._hb_lost:
                self._hb_lost = True
                self._event("heartbeat", f"autopilot heartbeat lost: none for {age:.1f} s")
            elif age <= self.heartbeat_timeout_s and self._hb_lost:
                self._hb_lost = False
                self._event("heartbeat", "autopilot heartbeat back")
        self._advance(now)

    def send_heartbeat(self) -> None:
        """Send our heartbeat now (a GCS/companion one; `tick()` does it every second)."""
        self._last_hb_sent = self._clock()
        self._mav.heartbeat_send(
            mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE
        )

    # ------------------------------------------------------------------ incoming

    def _handle(self, msg: Any, now: float) -> None:
        name = msg.get_type()
        self.message_counts[name] += 1
        src = msg.get_srcSystem()
        if name == "HEARTBEAT":
            pinned = self._pinned
            if (
                self.target_system is None
                and _is_vehicle_heartbeat(msg)
                and (pinned is None or src == pinned)
            ):
                self.target_system, self.target_component = src, msg.get_srcComponent()
                self._event("heartbeat", f"autopilot found: system {src}, {_describe_hb(msg)}")
            if (src, msg.get_srcComponent()) == (self.target_system, self.target_component):
                self._on_heartbeat(msg, now)
            return
        if src != self.target_system:
            return  # another system on the same line: a radio, a second GCS
        t = self.telemetry
        t.last_message = now
        handler = _HANDLERS.get(name)
        if handler is not None:
            handler(self, msg, now)

    def _on_heartbeat(self, m: Any, now: float) -> None:
        t = self.telemetry
        t.last_heartbeat = now
        t.last_message = now
        armed = bool(m.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)
        mode = self._mode_name(m)
        t.mav_type, t.autopilot_type = m.type, m.autopilot
        t.custom_mode, t.system_status = m.custom_mode, m.system_status
        if armed != t.armed:
            t.armed = armed
            self._event("armed", "armed" if armed else "disarmed")
        if mode != t.mode:
            old, t.mode = t.mode, mode
            self._event("mode", f"mode {old} -> {mode}")
        taken = self._commanded_mode is not None and mode != self._commanded_mode
        # A heartbeat that overtakes the ACK of the node's own mode change is not a takeover.
        taken = taken and not self._mode_in_flight(mode)
        if taken and not self.mode_override:
            self._event("override", self._mode_taken(mode, now))
        self.mode_override = taken

    def _mode_name(self, m: Any) -> str:
        """The flight mode a HEARTBEAT reports, by pymavlink's name."""
        return str(mavutil.mode_string_v10(m))

    def _mode_taken(self, mode: str, now: float) -> str:
        """The mode changed to `mode` without the node: the override event's text (a
        subclass may also react, e.g. stop a setpoint stream)."""
        return (
            f"mode changed to {mode} without the node (it asked for "
            f"{self._commanded_mode}): pilot or autopilot failsafe"
        )

    def _mode_in_flight(self, mode: str) -> bool:
        """Whether the command being sent now is the node's own change to `mode`."""
        cmd = self._active
        if cmd is None or cmd._index >= len(cmd._steps):
            return False
        return cmd._steps[cmd._index].label == f"mode {mode}"

    def _on_global_position(self, m: Any, now: float) -> None:
        t = self.telemetry
        if (m.lat == 0 and m.lon == 0) or not _on_earth(m.lat, m.lon):
            return  # ArduPilot reports 0, 0 until it has a position
        t.lat, t.lon = m.lat * 1e-7, m.lon * 1e-7
        t.alt_msl_m, t.alt_rel_m = m.alt * 1e-3, m.relative_alt * 1e-3
        t.vel_north_mps, t.vel_east_mps, t.vel_down_mps = m.vx * 0.01, m.vy * 0.01, m.vz * 0.01
        t.ground_speed_mps = math.hypot(m.vx, m.vy) * 0.01
        t.heading_deg = None if m.hdg == 65535 else m.hdg * 0.01

    def _on_gps_raw(self, m: Any, now: float) -> None:
        t = self.telemetry
        t.gps_fix_type = m.fix_type
        t.satellites = None if m.satellites_visible == 255 else m.satellites_visible
        if m.fix_type >= 2 and _on_earth(m.lat, m.lon):
            t.gps_lat, t.gps_lon = m.lat * 1e-7, m.lon * 1e-7

    def _on_attitude(self, m: Any, now: float) -> None:
        self.telemetry.yaw_rad = m.yaw if math.isfinite(m.yaw) else None

    def _on_vfr_hud(self, m: Any, now: float) -> None:
        if math.isfinite(m.groundspeed):
            self.telemetry.ground_speed_mps = m.groundspeed

    def _on_sys_status(self, m: Any, now: float) -> None:
        t = self.telemetry
        if m.voltage_battery != 65535:
            t.battery_voltage_v = m.voltage_battery * 1e-3
        t.battery_current_a = None if m.current_battery == -1 else m.current_battery * 0.01
        t.battery_percent = _percent(m.battery_remaining)

    def _on_battery_status(self, m: Any, now: float) -> None:
        if m.id != 0:
            return  # the first battery is the one SYS_STATUS reports too
        t = self.telemetry
        cells = [v for v in m.voltages if v != 65535]
        if cells:
            # One entry is the whole pack for most ArduPilot monitors; cells add up otherwise.
            t.battery_voltage_v = sum(cells) * 1e-3
        if m.current_battery != -1:
            t.battery_current_a = m.current_battery * 0.01
        if m.battery_remaining != -1:
            t.battery_percent = _percent(m.battery_remaining)

    def _on_home(self, m: Any, now: float) -> None:
        if _on_earth(m.latitude, m.longitude):
            self.telemetry.home = (m.latitude * 1e-7, m.longitude * 1e-7, m.altitude * 1e-3)

    def _on_extended_state(self, m: Any, now: float) -> None:
        self.telemetry.landed_state = m.landed_state or None

    def _on_rc_channels(self, m: Any, now: float) -> None:
        self._rc_seen_full = True
        n = min(m.chancount, 18)
        self._set_rc(tuple(getattr(m, f"chan{i}_raw") for i in range(1, n + 1)), m.rssi)

    def _on_rc_channels_raw(self, m: Any, now: float) -> None:
        if self._rc_seen_full or m.port != 0:
            return
        raw = [getattr(m, f"chan{i}_raw") for i in range(1, 9)]
        while raw and raw[-1] in RC_UNUSED:
            raw.pop()
        self._set_rc(tuple(raw), m.rssi)

    def _set_rc(self, channels: tuple[int, ...], rssi: int) -> None:
        t = self.telemetry
        t.rc_channels = channels
        t.rc_rssi = None if rssi == 255 else rssi
        i = self.override_channel - 1
        high = 0 <= i < len(channels) and channels[i] not in RC_UNUSED
        high = high and channels[i] >= self.override_pwm
        if high and not t.rc_override:
            self._event(
                "override",
                f"RC channel {self.override_channel} at {channels[i]} us: the pilot has control",
            )
        elif t.rc_override and not high:
            self._event("override", f"RC channel {self.override_channel} released")
        t.rc_override = high

    def _on_statustext(self, m: Any, now: float) -> None:
        text = m.text if isinstance(m.text, str) else bytes(m.text).decode("ascii", "replace")
        text = text.rstrip("\x00").strip()
        self.telemetry.statustext = text
        self._statustexts.append((now, text))
        self._event("statustext", text)

    def _on_ack(self, m: Any, now: float) -> None:
        cmd = self._active
        if cmd is None or cmd.status is not CommandStatus.ACTIVE:
            return
        ts = getattr(m, "target_system", 0)
        if ts not in (0, self.source_system):
            return  # the answer to another GCS's command
        step = cmd._steps[cmd._index]
        if step.ack is None or m.command != step.ack or cmd.attempts == 0:
            return  # not ours, or a step still held back (an ACK of an earlier command)
        cmd.result = m.result
        if m.result == mavlink2.MAV_RESULT_ACCEPTED:
            if step.on_accept is not None:
                step.on_accept()
            self._next_step(cmd, now)
        elif m.result == mavlink2.MAV_RESULT_IN_PROGRESS:
            cmd._deadline = now + self.ack_timeout_s  # still working: keep waiting
        else:
            reason = f"{step.label} refused: {_result_name(m.result)}"
            recent = [txt for at, txt in self._statustexts if now - at <= _STATUSTEXT_WINDOW_S]
            if recent:
                reason += f" ({recent[-1]})"
            self._step_failed(cmd, reason, now)

    # ------------------------------------------------------------------ command machine

    def _new(
        self,
        name: str,
        steps: Sequence[_Step],
        on_done: Callable[[MavCommand], None] | None,
        urgent: bool = False,
    ) -> MavCommand:
        cmd = MavCommand(self._next_id, name, steps, self._clock(), on_done)
        self._next_id += 1
        if urgent:
            self._queue.appendleft(cmd)
        else:
            self._queue.append(cmd)
        # Start it now if the line is free: a command issued after poll() leaves this tick.
        self._advance(self._clock())
        return cmd

    def _refused(
        self, name: str, reason: str, on_done: Callable[[MavCommand], None] | None
    ) -> MavCommand:
        cmd = MavCommand(self._next_id, name, (), self._clock(), on_done)
        self._next_id += 1
        self._finish(cmd, CommandStatus.FAILED, f"{name} refused: {reason}")
        return cmd

    def _advance(self, now: float) -> None:
        while True:
            cmd = self._active
            if cmd is None:
                if not self._queue:
                    return
                head = self._queue[0]
                if self.target_system is None:
                    if now - head.created >= self.queue_timeout_s:
                        self._queue.popleft()
                        self._finish(
                            head,
                            CommandStatus.FAILED,
                            f"{head.name}: not sent, no heartbeat from the autopilot "
                            f"after {self.queue_timeout_s:g} s",
                        )
                        continue
                    return
                self._queue.popleft()
                self._active = cmd = head
                cmd.status = CommandStatus.ACTIVE
                cmd._index = 0
                if not self._start_step(cmd, now):
                    continue
            step = cmd._steps[cmd._index]
            if cmd.attempts == 0:  # held back until the step is ready
                if step.ready is None or step.ready(now):
                    self._send_step(cmd, step, now)
                    if step.ack is None:
                        self._next_step(cmd, now)
                        continue
                    return
                waited = now - cmd._waiting_since
                if waited < step.ready_timeout_s:
                    return
                self._step_failed(
                    cmd, f"{step.label}: {step.waiting_for} not ready after {waited:.1f} s", now
                )
                continue
            if now < cmd._deadline:
                return
            if cmd.attempts < self.max_attempts:
                self._send_step(cmd, step, now)
                return
            self._step_failed(
                cmd,
                f"{step.label}: no COMMAND_ACK after {cmd.attempts} "
                f"{'try' if cmd.attempts == 1 else 'tries'}",
                now,
            )
            # _step_failed moved on to the next step or command: look at it again.

    def _start_step(self, cmd: MavCommand, now: float) -> bool:
        """Send the current step (and finish the fire-and-forget ones); False when over."""
        while cmd._index < len(cmd._steps):
            step = cmd._steps[cmd._index]
            cmd.attempts = 0
            if step.ready is not None and not step.ready(now):
                cmd._waiting_since = now  # `_advance` sends it once ready
                return True
            self._send_step(cmd, step, now)
            if step.ack is not None:
                return True
            cmd._index += 1
        self._finish(cmd, CommandStatus.DONE)
        return False

    def _send_step(self, cmd: MavCommand, step: _Step, now: float) -> None:
        step.send(cmd.attempts)
        cmd.attempts += 1
        cmd._deadline = now + self.ack_timeout_s

    def _next_step(self, cmd: MavCommand, now: float) -> None:
        cmd._index += 1
        if self._start_step(cmd, now):
            return
        self._advance(now)

    def _step_failed(self, cmd: MavCommand, reason: str, now: float) -> None:
        step = cmd._steps[cmd._index]
        if step.optional:
            cmd.warnings.append(reason)
            self._next_step(cmd, now)
            return
        self._finish(cmd, CommandStatus.FAILED, f"{cmd.name} failed: {reason}")
        self._advance(now)

    def _finish(self, cmd: MavCommand, status: CommandStatus, error: str | None = None) -> None:
        cmd.status = status
        cmd.error = error
        cmd.finished = self._clock()
        if self._active is cmd:
            self._active = None
        if status is CommandStatus.DONE:
            text = f"{cmd.name}: done"
            if cmd.warnings:
                text += f" ({len(cmd.warnings)} optional part(s) refused: {cmd.warnings[0]})"
        else:
            text = error or f"{cmd.name}: {status.value}"
        self._event("command", text, cmd)
        if cmd.on_done is not None:
            cmd.on_done(cmd)

    def cancel(self, command: MavCommand, reason: str = "cancelled") -> None:
        """Stop waiting for `command` (an ACK that comes later is ignored)."""
        if command.done:
            return
        if command in self._queue:
            self._queue.remove(command)
        self._finish(command, CommandStatus.CANCELLED, f"{command.name}: {reason}")
        self._advance(self._clock())

    def cancel_all(self, reason: str = "cancelled") -> None:
        """Cancel every pending command."""
        for cmd in self.pending:
            self.cancel(cmd, reason)

    # ------------------------------------------------------------------ commands

    def _long_step(
        self,
        cmd_id: int,
        params: Sequence[float] = (),
        *,
        on_accept: Callable[[], None] | None = None,
        optional: bool = False,
    ) -> _Step:
        # MAVLink params are float32: a finite value beyond its range saturates to infinity
        # (which autopilots refuse) rather than fail to pack at send time.
        p = [_float32(float(x)) for x in params][:7]
        p += [0.0] * (7 - len(p))

        def send(confirmation: int) -> None:
            self._mav.command_long_send(
                self.target_system or 0,
                self.target_component or 0,
                cmd_id,
                min(confirmation, 255),
                *p,
            )

        return _Step(_cmd_name(cmd_id), send, cmd_id, on_accept, optional)

    def command(
        self,
        cmd_id: int,
        params: Sequence[float] = (),
        *,
        name: str | None = None,
        on_done: Callable[[MavCommand], None] | None = None,
    ) -> MavCommand:
        """Any COMMAND_LONG (up to 7 params), acknowledged and retried like the others."""
        return self._new(name or _cmd_name(cmd_id), [self._long_step(cmd_id, params)], on_done)

    def arm(
        self, *, force: bool = False, on_done: Callable[[MavCommand], None] | None = None
    ) -> MavCommand:
        """Arm the motors (`force` skips ArduPilot's pre-arm checks)."""
        step = self._long_step(
            mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, (1, FORCE_ARM if force else 0)
        )
        return self._new("arm", [step], on_done)

    def disarm(
        self, *, force: bool = False, on_done: Callable[[MavCommand], None] | None = None
    ) -> MavCommand:
        """Disarm; the autopilot refuses in the air unless `force` (motors stop: it falls)."""
        step = self._long_step(
            mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, (0, FORCE_DISARM if force else 0)
        )
        return self._new("disarm", [step], on_done)

    def set_mode(
        self, name: str, *, on_done: Callable[[MavCommand], None] | None = None
    ) -> MavCommand:
        """Switch to the flight mode `name` (e.g. "GUIDED"), as pymavlink names modes."""
        step = self._mode_step(name)
        if isinstance(step, str):
            return self._refused(f"set_mode {name}", step, on_done)
        return self._new(f"set_mode {name}", [step], on_done)

    def _mode_step(self, name: str) -> _Step | str:
        """The DO_SET_MODE step for an ArduPilot mode name, or why there is none.

        PX4 numbers its modes otherwise and needs a setpoint stream for OFFBOARD: that is
        `fieldkit.vehicle.px4.Px4Core` (the profile's `autopilot.flavour = "px4"`).
        """
        if self.telemetry.autopilot_type == mavlink2.MAV_AUTOPILOT_PX4:
            return (
                "the autopilot is PX4 (HEARTBEAT autopilot 12) but this link speaks ArduPilot: "
                'set autopilot.flavour = "px4" in the profile'
            )
        mav_type = self.telemetry.mav_type
        if mav_type is None:
            ground = mavlink2.MAV_TYPE_GROUND_ROVER
            mav_type = ground if self.ground else mavlink2.MAV_TYPE_QUADROTOR
        mapping = mavutil.mode_mapping_byname(mav_type)
        if mapping is None:
            return f"no ArduPilot mode table for vehicle type {mav_type}"
        if name not in mapping:
            return f"unknown mode {name!r} (known: {', '.join(sorted(mapping))})"
        params = (mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mapping[name])

        def accepted() -> None:
            # From now on a different mode in the heartbeat means someone else switched.
            self._commanded_mode = name
            self.mode_override = False

        step = self._long_step(mavlink2.MAV_CMD_DO_SET_MODE, params, on_accept=accepted)
        step.label = f"mode {name}"
        return step

    def takeoff(
        self, alt: float, *, on_done: Callable[[MavCommand], None] | None = None
    ) -> MavCommand:
        """Climb to `alt` metres above home: the guided mode, arm, then MAV_CMD_NAV_TAKEOFF."""
        name = f"takeoff {alt:g}"
        if self.ground:
            who = self.profile.name if self.profile is not None else "this vehicle"
            return self._refused(name, f"{who} is a ground robot: it does not fly", on_done)
        if not (math.isfinite(alt) and 0.0 < alt <= MAX_ALTITUDE_M):
            return self._refused(name, f"altitude must be > 0 m, got {alt}", on_done)
        mode = self._mode_step(self.guided_mode)
        if isinstance(mode, str):
            return self._refused(name, mode, on_done)
        steps = [
            mode,
            self._long_step(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, (1, 0)),
            self._long_step(mavlink2.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, math.nan, 0, 0, alt)),
        ]
        return self._new(name, steps, on_done)

    def land(self, *, on_done: Callable[[MavCommand], None] | None = None) -> MavCommand:
        """Land where it is (the profile's land mode; a ground robot holds). Goes first."""
        return self._mode_command("land", self.land_mode, on_done)

    def rtl(self, *, on_done: Callable[[MavCommand], None] | None = None) -> MavCommand:
        """Return to launch (and land, for a UAV). Goes first in the queue."""
        return self._mode_command("rtl", self.rtl_mode, on_done)

    def hold(
        self, *, keep_guided: bool = False, on_done: Callable[[MavCommand], None] | None = None
    ) -> MavCommand:
        """Stop and keep position: the loiter/hold mode, or with `keep_guided` a position
        target at the current position (the node keeps control). Goes first in the queue."""
        if not keep_guided:
            return self._mode_command("hold", self.loiter_mode, on_done)
        t = self.telemetry
        if t.lat is None or t.lon is None:
            return self._refused("hold", "position unknown", on_done)
        return self.goto(t.lat, t.lon, t.alt_rel_m or 0.0, on_done=on_done)

    def _mode_command(
        self, name: str, mode: str, on_done: Callable[[MavCommand], None] | None
    ) -> MavCommand:
        step = self._mode_step(mode)
        if isinstance(step, str):
            return self._refused(name, step, on_done)
        return self._new(f"{name} ({mode})", [step], on_done, urgent=True)

    def goto(
        self,
        lat: float,
        lon: float,
        alt: float,
        *,
        yaw_deg: float | None = None,
        on_done: Callable[[MavCommand], None] | None = None,
    ) -> MavCommand:
        """Fly (drive) to an absolute point: SET_POSITION_TARGET_GLOBAL_INT, sent at once.

        `alt` is metres above home (relative-altitude frame); ground robots send 0. MAVLink
        has no ACK for setpoints: the command is done once sent, and the autopilot holds
        that absolute target (in its guided mode) until told otherwise. `yaw_deg`, if given,
        is the heading to face (0 north, clockwise); otherwise the heading is left alone.
        """
        name = f"goto {lat:.7f},{lon:.7f},{alt:g}"
        if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)):
            return self._refused(name, "non-finite coordinates", on_done)
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return self._refused(name, "latitude or longitude out of range", on_done)
        if abs(alt) > MAX_ALTITUDE_M:
            return self._refused(name, f"altitude beyond {MAX_ALTITUDE_M:g} m", on_done)
        if self.target_system is None:
            return self._refused(name, "no heartbeat from the autopilot yet", on_done)
        if self.ground:
            alt = 0.0
        mask = _MASK_POSITION_ONLY if yaw_deg is None else _MASK_POSITION_YAW
        yaw = 0.0 if yaw_deg is None else math.radians(yaw_deg)
        boot_ms = int((self._clock() - self._t0) * 1000) & 0xFFFFFFFF
        self._mav.set_position_target_global_int_send(
            boot_ms,
            self.target_system,
            self.target_component or 0,
            mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            mask,
            int(round(lat * 1e7)),
            int(round(lon * 1e7)),
            float(alt),
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            yaw,
            0.0,
        )
        self.last_target = (lat, lon, alt)
        # Setpoints stream at the loop rate: finish quietly, no event per setpoint.
        return self._over_at_once(name, on_done)

    def _over_at_once(
        self,
        name: str,
        on_done: Callable[[MavCommand], None] | None,
        error: str | None = None,
    ) -> MavCommand:
        """A command finished as it is made, without an event: a setpoint sent (done), or,
        with `error`, one refused again and again at the loop rate (failed)."""
        cmd = MavCommand(self._next_id, name, (), self._clock(), on_done)
        self._next_id += 1
        cmd.status = CommandStatus.DONE if error is None else CommandStatus.FAILED
        cmd.error = error
        cmd.attempts = 1 if error is None else 0
        cmd.finished = cmd.created
        if on_done is not None:
            on_done(cmd)
        return cmd

    def request_streams(
        self, rate_hz: float, *, on_done: Callable[[MavCommand], None] | None = None
    ) -> MavCommand:
        """Ask for the telemetry at `rate_hz`: REQUEST_DATA_STREAM (all streams, ArduPilot)
        then SET_MESSAGE_INTERVAL for each message used (ArduPilot and PX4; a refusal of
        one of these is only a warning on the command)."""
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            return self._refused("request_streams", f"rate must be > 0 Hz, got {rate_hz}", on_done)
        self.stream_rate_hz = rate_hz

        def legacy(confirmation: int) -> None:
            self._mav.request_data_stream_send(
                self.target_system or 0,
                self.target_component or 0,
                mavlink2.MAV_DATA_STREAM_ALL,
                max(1, int(round(rate_hz))),
                1,
            )

        steps = [_Step("REQUEST_DATA_STREAM", legacy, None), *self._interval_steps(rate_hz)]
        return self._new(f"request_streams {rate_hz:g} Hz", steps, on_done)

    def _interval_steps(self, rate_hz: float) -> list[_Step]:
        """SET_MESSAGE_INTERVAL for every message used, at `rate_hz` (home slower); optional."""
        interval_us = 1e6 / rate_hz
        steps = [
            self._long_step(
                mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, (msg_id, interval_us), optional=True
            )
            for msg_id in _STREAMED
        ]
        home_us = 1e6 / min(rate_hz, _HOME_RATE_HZ)
        steps.append(
            self._long_step(
                mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL,
                (mavlink2.MAVLINK_MSG_ID_HOME_POSITION, home_us),
                optional=True,
            )
        )
        return steps


def _float32(x: float) -> float:
    """`x` as MAVLink's float32 can carry it: beyond its range, infinity of the same sign."""
    return math.copysign(math.inf, x) if math.isfinite(x) and abs(x) > _FLOAT32_MAX else x


def _on_earth(lat_e7: int, lon_e7: int) -> bool:
    """Whether 1e-7-degree coordinates are a place (a corrupt-but-valid frame may not be)."""
    return -900_000_000 <= lat_e7 <= 900_000_000 and -1_800_000_000 <= lon_e7 <= 1_800_000_000


def describe_error(e: BaseException) -> str:
    """An exception as a short reason: the OS error text when there is one."""
    if isinstance(e, OSError):
        # pyserial wraps the OS error in its own text ("could not open port ...: [Errno 2]
        # ..."); the bare OS reason reads better after our own "cannot open PATH:".
        if isinstance(e.errno, int) and e.errno > 0:
            return os.strerror(e.errno)
        if e.strerror:
            return e.strerror
    return str(e) or type(e).__name__


def _percent(remaining: int) -> float | None:
    """battery_remaining: -1 (unknown) and anything outside 0..100 read as unknown."""
    return float(remaining) if 0 <= remaining <= 100 else None


def _describe_hb(m: Any) -> str:
    """Who sent a heartbeat, e.g. "ARDUPILOTMEGA, MAV_TYPE_QUADROTOR"."""
    ap = mavlink2.enums["MAV_AUTOPILOT"].get(m.autopilot)
    ty = mavlink2.enums["MAV_TYPE"].get(m.type)
    return f"{ap.name if ap else m.autopilot}, {ty.name if ty else m.type}"


_HANDLERS: dict[str, Callable[[AutopilotCore, Any, float], None]] = {
    "GLOBAL_POSITION_INT": AutopilotCore._on_global_position,
    "GPS_RAW_INT": AutopilotCore._on_gps_raw,
    "ATTITUDE": AutopilotCore._on_attitude,
    "VFR_HUD": AutopilotCore._on_vfr_hud,
    "SYS_STATUS": AutopilotCore._on_sys_status,
    "BATTERY_STATUS": AutopilotCore._on_battery_status,
    "HOME_POSITION": AutopilotCore._on_home,
    "EXTENDED_SYS_STATE": AutopilotCore._on_extended_state,
    "RC_CHANNELS": AutopilotCore._on_rc_channels,
    "RC_CHANNELS_RAW": AutopilotCore._on_rc_channels_raw,
    "STATUSTEXT": AutopilotCore._on_statustext,
    "COMMAND_ACK": AutopilotCore._on_ack,
}
