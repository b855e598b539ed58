"""The DJI Onboard SDK core: the host's side of the M100's OPEN protocol, without I/O.

`DjiCore` is the M100 backend of `fieldkit.vehicle.core.VehicleCore`, in the manner of the
MAVLink `AutopilotCore`: bytes from the flight controller go in (`receive_data`), time moves
on (`tick`, with the injected `clock`), and the frames to send come out (`data_to_send`).

    core = DjiCore(app_id=1234567, app_key=KEY_HEX, profile=load_profile("m100"))
    core.receive_data(line_bytes)        # broadcast telemetry, ACKs, lost-control pushes
    core.tick()                          # retries, timeouts, the movement-control stream
    write(core.data_to_send())
    takeoff = core.takeoff(5.0)          # returns at once: a DjiCommand

What it does, in the order of a flight (facts: the spec, summarised in docs/vehicles.md):

- **Connection**: get version (the hardware must be an M100), activation with the app id
  and the firmware word read, then the broadcast frequencies the profile asks for. Each is a
  reliable command on a session >= 2, retransmitted byte for byte on its timeout. A refused
  activation is an `activation` event and `activation_error` naming DJI's return code;
  "new device / DJI GO offline" codes are retried, the others are final.
- **Control authority**: obtained before the first order that needs it (re-sent while the
  flight controller answers "in progress"), refused with the RC mode switch out of F. The
  pilot always wins: a lost-control push, the control device leaving "onboard" or the mode
  switch leaving F makes `pilot_override` true, stops every stream and fails what is
  pending; nothing is sent to take the aircraft back. The switch back in F hands the robot
  back to the node (authority is asked for again at its next order).
- **Telemetry**: broadcast items decoded into `AutopilotState` (position and heights,
  quaternion to yaw, velocity, battery, flight status, RC, GPS health, control device).
- **Tasks**: take-off (then the climb to the asked altitude by movement control), landing,
  go home, each acknowledged (M100 codes: 2 started, 1 failed) and followed on the flight
  status as DJI's host does; arm/disarm (0x01/0x05).
- **Movement control**: `goto` streams position offsets toward an absolute point (flag
  0x91: offset, height, yaw angle, ground frame, stable), `hold` zero velocities (0x49), at
  the profile's control rate (DJI: 50 Hz, its maximum) on session 0, without ACK, only while
  the host has authority and the aircraft is in the air.
- **Encryption** (profile `dji.encrypt`): control, task, movement and arm frames AES-256
  with the app key once activated; the first of them checks the key (0xFF00 KEY_ERROR).
"""

from __future__ import annotations

import hashlib
import math
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING

from fieldkit.robot import geo
from fieldkit.robot.profiles import DjiSettings, Profile
from fieldkit.robot.script_api import IN_AIR, LANDING, ON_GROUND, TAKING_OFF
from fieldkit.vehicle.autopilot import (
    AutopilotError,
    AutopilotState,
    CommandStatus,
    CoreRecords,
    Event,
    clock_reading,
    describe_error,
)
from fieldkit.vehicle.dji import messages as M
from fieldkit.vehicle.dji.crypto import FrameCipher, parse_app_key
from fieldkit.vehicle.dji.frame import Frame, FrameReader, ack_frame, command_frame

if TYPE_CHECKING:
    from fieldkit.vehicle.core import VehicleCore

MAX_CONTROL_RATE_HZ = 50.0
"""Movement-control frames per second at most: DJI's recommended rate, the most the FC reads."""
RECONNECT_S = 1.0
"""Pause before the connection sequence starts over after a silent or refusing FC."""
ACTIVATION_ATTEMPTS = 3
"""Activations tried when DJI answers "new device" or "DJI GO offline" (users report two)."""
OBTAIN_IN_PROGRESS_MAX = 6
"""Re-sends of an obtain/release answered "in progress" before giving up."""
TAKEOFF_START_S = 3.0
"""After the take-off ACK: seconds for the motors to start (status >= taking off)."""
TAKEOFF_LEAVE_S = 15.0
"""After the motors start: seconds to leave the ground (status in the air)."""
TAKEOFF_SETTLE_S = 10.0
"""Then: seconds for the auto take-off (about 1.2 m) to settle before the climb is ordered."""
HOVER_VZ_MPS = 0.1
"""Vertical speed below which the aircraft counts as hovering."""
CLIMBING_VZ_MPS = 0.3
"""Vertical speed above which it counts as climbing."""
LANDING_START_S = 3.0
"""After the landing ACK: seconds for the status to leave "in the air"."""
RC_F_THRESHOLD = 4000
"""RC mode channel above this reads as F (F is 8000, A 0, P -8000)."""


@dataclass(frozen=True)
class _Timing:
    """Per-command ACK timeout and sends (spec §4.4, with retransmission as intended)."""

    timeout_s: float
    sends: int


_VERSION = _Timing(0.1, 3)
_ACTIVATE = _Timing(1.0, 3)
_BROADCAST = _Timing(0.1, 3)
_CONTROL = _Timing(0.5, 3)
_TASK = _Timing(0.5, 3)
_ARM = _Timing(0.1, 10)


class DjiError(AutopilotError):
    """The DJI link cannot do what was asked; the message says what and why."""


class _Verdict(Enum):
    """What an ACK handler decided besides success and failure."""

    RESEND = "resend"  # "in progress": send the same request again now


# An ACK handler: (return code or None, ACK value) -> None (accepted), a failure text, or
# RESEND.
_OnAck = Callable[[int | None, bytes], "str | _Verdict | None"]


@dataclass(eq=False)
class _Step:
    """One part of a command: a reliable frame and its ACK, a wait on the status, or an action."""

    label: str
    kind: str  # "send", "watch", "do"
    # send: the request (built when the step starts; retransmitted byte for byte)
    request: Callable[[], tuple[tuple[int, int], bytes]] | None = None
    on_ack: _OnAck | None = None
    timing: _Timing = _TASK
    skip: Callable[[], bool] | None = None  # evaluated when the step starts
    optional: bool = False  # a failure is a warning, not the command's failure
    # watch: wait until `until()` holds, or fail with `fail_text` after `timeout_s`
    until: Callable[[], bool] | None = None
    timeout_s: float = 0.0
    fail_text: str = ""
    # do: a local action; a text is a failure
    action: Callable[[], str | None] | None = None


class DjiCommand:
    """One order to the flight controller: returned at once, moved on by the core's `tick()`."""

    def __init__(
        self,
        cid: int,
        name: str,
        steps: list[_Step],
        created: float,
        *,
        needs_activation: bool = True,
        on_done: Callable[[DjiCommand], None] | None = None,
    ) -> None:
        """A queued command; the core builds these."""
        self.id = cid
        self.name = name
        self.status = CommandStatus.QUEUED
        self.error: str | None = None
        self.code: int | None = None  # the last return code received
        self.attempts = 0  # sends of the current (or last) step
        self.warnings: list[str] = []
        self.created = created
        self.finished: float | None = None
        self.on_done = on_done
        self.needs_activation = needs_activation
        self._steps = steps
        self._index = 0
        self._deadline = 0.0
        self._frame = b""
        self._session = 0
        self._seq = 0
        self._in_progress = 0

    @property
    def done(self) -> bool:
        """Whether it is over, whatever the outcome."""
        return self.status in (CommandStatus.DONE, CommandStatus.FAILED, CommandStatus.CANCELLED)

    @property
    def ok(self) -> bool:
        """Whether the flight controller accepted every part of it."""
        return self.status is CommandStatus.DONE

    def __repr__(self) -> str:
        """E.g. `<DjiCommand 3 takeoff 5: failed (takeoff 5 failed: ...)>`."""
        tail = f" ({self.error})" if self.error else ""
        return f"<DjiCommand {self.id} {self.name}: {self.status.value}{tail}>"


@dataclass
class _Setpoint:
    """What the movement-control stream sends: a point to fly to, or a hover."""

    kind: str  # "goto" or "hover"
    lat: float = 0.0
    lon: float = 0.0
    alt: float = 0.0
    yaw_deg: float = 0.0
    serial: int = 0


class DjiCore(CoreRecords):
    """The host's OPEN protocol conversation with one M100 flight controller."""

    def __init__(
        self,
        *,
        app_id: int,
        app_key: str,
        url: str = "dji",
        profile: Profile | None = None,
        clock: Callable[[], float] = time.monotonic,
        encrypt: bool | None = None,
        broadcast_hz: int | None = None,
        control_rate_hz: float | None = None,
        queue_timeout_s: float = 10.0,
        heartbeat_timeout_s: float | None = None,
    ) -> None:
        """A core that has heard nothing yet; the connection sequence starts at the first tick.

        `app_id` and `app_key` (64 hex digits) are the developer's, from the node's config:
        never from a profile. `profile` gives the heartbeat (silence) timeout, whether it
        is a ground robot, and its `[dji]` settings (broadcast rate, control rate,
        encryption), which `encrypt`, `broadcast_hz` and `control_rate_hz` override.
        Raises `DjiError` for an app key that is not 64 hex digits.
        """
        s = profile.dji if profile is not None else DjiSettings()
        try:
            self._cipher = FrameCipher.from_app_key(app_key)
            #: The key's fingerprint (`app_key_fingerprint`), never the key: for a recording.
            self.key_fingerprint = app_key_fingerprint(app_key)
        except ValueError as e:
            raise DjiError(str(e)) from None
        if not 0 < app_id <= 0xFFFFFFFF:
            raise DjiError(f"the DJI app id must be a positive 32-bit number, got {app_id}")
        rate = s.broadcast_hz if broadcast_hz is None else broadcast_hz
        if rate not in M.RATE_CODES or rate == 0:
            raise DjiError(f"broadcast rate must be one of 1, 10, 50, 100 Hz, got {rate}")
        control = s.control_rate_hz if control_rate_hz is None else control_rate_hz
        if not (math.isfinite(control) and 0 < control <= MAX_CONTROL_RATE_HZ):
            raise DjiError(f"control rate must be in (0, 50] Hz (DJI's maximum), got {control}")
        self.url = url
        self.profile = profile
        self.app_id = app_id
        self.encrypt = s.encrypt if encrypt is None else encrypt
        self.broadcast_hz = rate
        self.control_rate_hz = control
        self.queue_timeout_s = queue_timeout_s
        ap = profile.autopilot if profile is not None else None
        if heartbeat_timeout_s is None:
            heartbeat_timeout_s = ap.heartbeat_timeout_s if ap is not None else 3.0
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.gps_fix_timeout_s = ap.gps_fix_timeout_s if ap is not None else 120.0
        self.ground = profile.is_ground if profile is not None else False
        if ap is not None:
            self.guided_mode, self.loiter_mode = ap.guided_mode, ap.loiter_mode
            self.land_mode, self.rtl_mode = ap.land_mode, ap.rtl_mode
        else:
            self.guided_mode, self.loiter_mode = "SDK_CONTROL", "HOVER"
            self.land_mode, self.rtl_mode = "LANDING", "GO_HOME"
        self._clock = clock

        self._reader = FrameReader(self._cipher)
        self._outbox = bytearray()
        self.telemetry = AutopilotState()
        self.events: deque[Event] = deque(maxlen=1000)
        self.bytes_received = 0
        self.bytes_sent = 0
        self.link_errors = 0
        self.frames_sent = 0
        self.stream_frames = 0  # movement-control frames sent
        self.unhandled_frames = 0  # good frames of no use here (other pushes, stray ACKs)
        self.malformed = 0  # good frames whose value does not hold what it says

        # Sequence numbers: one counter for every command frame (spec §4.3).
        self._seq = 0
        self._last_seq = dict.fromkeys(range(32), 0)

        # Connection.
        self.version: M.VersionInfo | None = None
        self.activated = False
        self.activation_error: str | None = None
        self.key_rejected = False  # the FC answered KEY_ERROR: the app key is wrong
        self._activation_refusals = 0
        self._version_retry = False
        self._connect_at: float | None = clock()
        self._connect_failing: str | None = None

        # Control authority and the pilot.
        self.authority = False
        self._pilot_took = False
        self._releasing = False
        self.rc_mode: int | None = None  # the RC mode channel, -10000..10000
        self.device: int | None = None  # control info: 0 RC, 1 app, 2 onboard
        self.control_mode: int | None = None
        self.flight_status: int | None = None  # M100 status 1..5
        self.gps_health: int | None = None
        self._motors = False  # armed by our command, still on the ground
        self._go_home = False  # a go-home is under way

        # Movement control.
        self._setpoint: _Setpoint | None = None
        self._setpoint_serial = 0
        self._last_stream: float | None = None

        # Commands.
        self._queue: deque[DjiCommand] = deque()
        self._active: DjiCommand | None = None
        self._next_id = 1
        self._task_seq = 0
        self._hb_lost = False
        self._link_failing = False
        self._t0 = clock()
        self._connect: DjiCommand | None = None

    # ------------------------------------------------------------------ bytes in and out

    def receive_data(self, data: bytes) -> int:
        """Handle bytes from the flight controller (any split); good frames handled.

        Never raises on what the line holds: a frame that cannot be used costs a counter.
        """
        self._link_failing = False
        self.bytes_received += len(data)
        now = self._clock()
        handled = 0
        for frame in self._reader.feed(data):
            t = self.telemetry
            t.last_message = now
            t.last_heartbeat = now
            try:
                self._handle(frame, now)
            except Exception as e:  # a hostile frame must not stop the node's loop
                self.link_error(f"cannot use a frame: {describe_error(e)}")
                continue
            handled += 1
        return handled

    def data_to_send(self) -> bytes:
        """The frames queued since the last call, to be written to the flight controller."""
        out = bytes(self._outbox)
        self._outbox.clear()
        return out

    def write(self, buf: bytes | bytearray) -> None:
        """Where every frame goes: queued for `data_to_send` (a transport writes at once)."""
        self._outbox += buf
        self.bytes_sent += len(buf)

    def tick(self) -> None:
        """Move time on: the connection sequence, command deadlines, the stream, silence."""
        now = self._clock()
        if self._connect_at is not None and now >= self._connect_at and self._connect is None:
            self._start_connect(now)
        last = self.telemetry.last_heartbeat
        if last is not None:
            age = now - last
            if age > self.heartbeat_timeout_s and not self._hb_lost:
                self._hb_lost = True
                self._event("heartbeat", f"flight controller silent: no frame for {age:.1f} s")
            elif age <= self.heartbeat_timeout_s and self._hb_lost:
                self._hb_lost = False
                self._event("heartbeat", "flight controller heard again")
                # It may have restarted meanwhile: the version's code says whether it is
                # still activated, and activating again is harmless.
                self._reconnect()
        self._advance(now)
        self.stream(now)

    # ------------------------------------------------------------------ views

    @property
    def messages(self) -> int:
        """Good frames received."""
        return self._reader.frames

    @property
    def bad_frames(self) -> int:
        """Runs of noise, broken frames and unreadable ones (see `FrameReader`)."""
        return self._reader.bad_frames

    @property
    def reader(self) -> FrameReader:
        """The de-framer, with its counters (garbage bytes, CRC errors...)."""
        return self._reader

    @property
    def pending(self) -> tuple[DjiCommand, ...]:
        """Commands not finished yet: the one in flight first, then the queue."""
        head = (self._active,) if self._active is not None else ()
        return head + tuple(self._queue)

    @property
    def connected(self) -> bool:
        """Activated and holding control authority: ready to fly."""
        return self.activated and self.authority

    @property
    def pilot_override(self) -> bool:
        """Whether the pilot has the aircraft: authority taken back (until the mode switch
        is back in F), or the mode switch out of F."""
        return self._pilot_took or self._switch_off_f

    @property
    def _switch_off_f(self) -> bool:
        return self.rc_mode is not None and self.rc_mode <= RC_F_THRESHOLD

    def time_state(self) -> dict[str, object]:
        """The core's clock readings, for a replay to restore after the start-up bytes."""
        t = self.telemetry
        return {
            "t0": self._t0,
            "last_heartbeat": t.last_heartbeat,
            "last_message": t.last_message,
            "last_stream": self._last_stream,
            "pending_commands": len(self.pending),
            # The frame counters: a replay's start-up may send fewer frames than the flight's
            # (no retries on a frozen clock), and every later frame carries them.
            "seq": self._seq,
            "last_seq": {str(k): v for k, v in self._last_seq.items() if v},
            "task_seq": self._task_seq,
        }

    def set_time_state(self, state: dict[str, object]) -> None:
        """Restore the readings of `time_state` (pending commands are not restored)."""
        self._restore_clock(state)
        self._last_stream = clock_reading(state, "last_stream")
        seq, task_seq, last_seq = state.get("seq"), state.get("task_seq"), state.get("last_seq")
        if isinstance(seq, int):
            self._seq = seq & 0xFFFF
        if isinstance(task_seq, int):
            self._task_seq = task_seq & 0xFF
        if isinstance(last_seq, dict):
            self._last_seq = dict.fromkeys(range(32), 0)
            for k, v in last_seq.items():
                if str(k).isdigit() and int(k) < 32 and isinstance(v, int):
                    self._last_seq[int(k)] = v & 0xFFFF

    # ------------------------------------------------------------------ incoming

    def _handle(self, frame: Frame, now: float) -> None:
        if frame.ack:
            self._on_ack(frame, now)
            return
        key = (frame.cmd_set, frame.cmd_id)
        if key == M.PUSH_BROADCAST:
            try:
                broadcast = M.parse_broadcast(frame.value)
            except ValueError:
                self.malformed += 1  # its flag promises items the frame does not hold
                return
            self._on_broadcast(broadcast, now)
        elif key == M.PUSH_LOST_CONTROL:
            if frame.session >= 1:
                cipher = self._cipher if frame.enc else None
                self.write(ack_frame(frame.session, frame.seq, b"\x00\x00", cipher=cipher))
            self._authority_lost("the flight controller's lost-control push")
        else:
            self.unhandled_frames += 1

    def _on_ack(self, frame: Frame, now: float) -> None:
        cmd = self._active
        if (
            cmd is None
            or cmd.status is not CommandStatus.ACTIVE
            or not cmd._frame
            or (frame.session, frame.seq) != (cmd._session, cmd._seq)
        ):
            self.unhandled_frames += 1  # late, duplicate, or for nobody
            return
        step = cmd._steps[cmd._index]
        assert step.on_ack is not None  # only send steps hold a frame
        code = M.return_code(frame.value)
        cmd.code = code
        verdict = step.on_ack(code, frame.value)
        if verdict is None:
            cmd._frame = b""
            self._next_step(cmd, now)
        elif verdict is _Verdict.RESEND:
            cmd._in_progress += 1
            if cmd._in_progress > OBTAIN_IN_PROGRESS_MAX:
                self._step_failed(cmd, f"{step.label}: still in progress after "
                                  f"{cmd._in_progress} answers", now)  # fmt: skip
                return
            # A new command, not a retransmission: the same SEQ would get the cached
            # "in progress" answer back (spec §4.2).
            cmd.attempts = 0
            self._build(cmd, step)
            self._send(cmd, now)
        else:
            self._step_failed(cmd, verdict, now)

    def _on_broadcast(self, b: M.Broadcast, now: float) -> None:
        t = self.telemetry
        if b.quaternion is not None:
            yaw = M.quaternion_yaw(*b.quaternion)
            if math.isfinite(yaw):
                t.yaw_rad = yaw
                t.heading_deg = math.degrees(yaw) % 360.0
        if b.velocity is not None:
            vx, vy, vz, status = b.velocity
            if status & 1 and all(map(math.isfinite, (vx, vy, vz))):
                t.vel_north_mps, t.vel_east_mps = vx, vy
                t.vel_down_mps = -vz if M.VELOCITY_Z_UP else vz
                t.ground_speed_mps = math.hypot(vx, vy)
            else:
                t.vel_north_mps = t.vel_east_mps = t.vel_down_mps = t.ground_speed_mps = None
        if b.position is not None:
            self._on_position(*b.position)
        if b.rc is not None:
            self._on_rc(b.rc)
        if b.battery is not None:
            pct = b.battery[0]
            t.battery_percent = float(pct) if pct <= 100 else None
        if b.control is not None:
            self.control_mode = b.control[0]
            self._on_device(b.control[1] & M.DEVICE_MASK)
        if b.flight_status is not None:
            self._on_status(b.flight_status[0])
        t.rc_override = self.pilot_override
        self._update_mode()

    def _on_position(self, lat: float, lon: float, alt: float, height: float, health: int) -> None:
        t = self.telemetry
        self.gps_health = health
        t.gps_fix_type = 3 if health >= 3 else 1
        if all(map(math.isfinite, (lat, lon))) and (lat, lon) != (0.0, 0.0):
            lat_d, lon_d = math.degrees(lat), math.degrees(lon)
            if -90.0 <= lat_d <= 90.0 and -180.0 <= lon_d <= 180.0:
                t.lat, t.lon = lat_d, lon_d
        if math.isfinite(alt):
            t.alt_msl_m = alt
        if math.isfinite(height):
            t.alt_rel_m = height

    def _on_rc(self, rc: tuple[int, int, int, int, int, int]) -> None:
        t = self.telemetry
        # As microseconds (1000..2000), the unit AutopilotState's channels use: F reads 1900.
        t.rc_channels = tuple(min(2000, max(1000, 1500 + v // 20)) for v in rc)
        old = self.rc_mode
        self.rc_mode = mode = rc[4]
        was_f = old is not None and old > RC_F_THRESHOLD
        now_f = mode > RC_F_THRESHOLD
        if old is not None and was_f == now_f:
            return
        where = _switch_name(mode)
        if not now_f:
            if old is None:
                self._event("override", f"RC mode switch in {where}, not F: the pilot has the M100")
            else:
                self._event("override", f"RC mode switch F -> {where}: the pilot has the M100")
            self._authority_lost(f"RC mode switch in {where}")
        elif old is not None:
            self._pilot_took = False
            self._event(
                "override",
                "RC mode switch back in F: the node may fly the M100 again (control "
                "authority is asked for at its next order)",
            )

    def _on_device(self, device: int) -> None:
        old, self.device = self.device, device
        if device == old:
            return
        # Only a change away from "onboard" counts: the broadcast lags the obtain ACK.
        if (
            self.authority
            and old == M.DEVICE_ONBOARD
            and device != M.DEVICE_ONBOARD
            and not self._releasing
        ):
            who = {M.DEVICE_RC: "the remote controller", M.DEVICE_APP: "the mobile app"}
            self._authority_lost(f"control passed to {who.get(device, f'device {device}')}")

    def _on_status(self, status: int) -> None:
        old, self.flight_status = self.flight_status, status
        t = self.telemetry
        t.landed_state = {
            M.STATUS_STANDBY: ON_GROUND,
            M.STATUS_TAKING_OFF: TAKING_OFF,
            M.STATUS_IN_AIR: IN_AIR,
            M.STATUS_LANDING: LANDING,
            M.STATUS_LANDED: ON_GROUND,
        }.get(status)
        if status in (M.STATUS_LANDED, M.STATUS_STANDBY):
            if old in (M.STATUS_IN_AIR, M.STATUS_LANDING, M.STATUS_TAKING_OFF):
                self._motors = False  # the M100 stops its motors on touchdown
                self._go_home = False
        if (
            status in (M.STATUS_TAKING_OFF, M.STATUS_IN_AIR)
            and old == M.STATUS_STANDBY
            and t.lat is not None
            and t.lon is not None
        ):
            # The M100 records its home point where it takes off (GPS permitting).
            t.home = (t.lat, t.lon, t.alt_msl_m if t.alt_msl_m is not None else 0.0)
        armed = status in (M.STATUS_TAKING_OFF, M.STATUS_IN_AIR, M.STATUS_LANDING) or self._motors
        if armed != t.armed:
            t.armed = armed
            self._event("armed", "armed" if armed else "disarmed")
        if old is not None and old != status:
            self._event(
                "flight",
                f"flight status {M.STATUS_NAMES.get(old, old)} -> "
                f"{M.STATUS_NAMES.get(status, status)}",
            )

    def _update_mode(self) -> None:
        t = self.telemetry
        if self._switch_off_f:
            mode = f"RC_{_switch_name(self.rc_mode or 0)}"
        elif self.authority:
            if self.flight_status == M.STATUS_LANDING:
                mode = self.land_mode
            elif self._go_home:
                mode = self.rtl_mode
            elif self._setpoint is not None and self._setpoint.kind == "hover":
                mode = self.loiter_mode
            else:
                mode = self.guided_mode
        elif self.device == M.DEVICE_APP:
            mode = "APP"
        elif self.rc_mode is not None:
            mode = "RC_F"
        else:
            mode = "UNKNOWN"
        if mode != t.mode:
            old, t.mode = t.mode, mode
            self._event("mode", f"mode {old} -> {mode}")

    def _authority_lost(self, reason: str) -> None:
        """The pilot (or the app) has the aircraft: stop everything, never take it back."""
        self._setpoint = None
        had = self.authority
        self.authority = False
        if had and self._hb_lost and not self._switch_off_f:
            # Heard again after a silence, with the switch in F: the flight controller
            # restarted (or the line was cut), not the pilot. Asked for again at the next order.
            self._event(
                "authority",
                f"control authority lost while the flight controller was silent ({reason})",
            )
        elif had:
            self._pilot_took = True
            self._event(
                "override",
                f"control authority taken back ({reason}): the pilot has the M100; the node "
                "sends nothing until the RC mode switch is back in F",
            )
        if had or self._switch_off_f:
            for cmd in self.pending:
                if cmd.needs_activation:
                    self.cancel(cmd, f"the pilot took control ({reason})")
        self.telemetry.rc_override = self.pilot_override
        self._update_mode()

    # ------------------------------------------------------------------ outgoing

    def _next_seq(self, session: int) -> int:
        seq = self._seq
        if session >= 1 and seq == self._last_seq[session]:
            seq = (seq + 1) & 0xFFFF  # never two commands in a row with one SEQ on a session
        self._seq = (seq + 1) & 0xFFFF
        self._last_seq[session] = seq
        return seq

    def _cipher_for(self, cmd_set: int) -> FrameCipher | None:
        if self.encrypt and self.activated and cmd_set in M.ENCRYPTABLE_SETS:
            return self._cipher
        return None

    def _transmit(self, frame: bytes) -> None:
        self.frames_sent += 1
        self.write(frame)

    def stream(self, now: float | None = None) -> bool:
        """Send the movement-control setpoint if one is due; True if a frame left.

        `tick()` calls it; a transport may call it more often to reach the control rate
        when its owner ticks slower (the node's loop runs at 10 Hz, DJI asks for 50).
        """
        if now is None:
            now = self._clock()
        sp = self._setpoint
        if sp is None or not self.authority or self.flight_status != M.STATUS_IN_AIR:
            return False
        period = 1.0 / self.control_rate_hz
        if self._last_stream is not None and now - self._last_stream < period * 0.999:
            return False
        movement = self._movement(sp)
        if movement is None:
            return False
        self._last_stream = now
        cmd_set, cmd_id = M.CMD_MOVEMENT
        seq = self._next_seq(0)
        frame = command_frame(
            0, seq, cmd_set, cmd_id, movement.encode(), cipher=self._cipher_for(cmd_set)
        )
        self._transmit(frame)
        self.stream_frames += 1
        return True

    def _movement(self, sp: _Setpoint) -> M.Movement | None:
        if sp.kind == "hover":
            return M.Movement(M.FLAG_HOVER, 0.0, 0.0, 0.0, 0.0)
        t = self.telemetry
        if t.lat is None or t.lon is None:
            return None
        north, east = geo.ned_offset(t.lat, t.lon, sp.lat, sp.lon)
        return M.Movement(M.FLAG_POSITION, north, east, sp.alt, sp.yaw_deg)

    # ------------------------------------------------------------------ connection

    def _start_connect(self, now: float) -> None:
        self._connect_at = None
        steps = [
            _Step(
                "get version",
                "send",
                request=lambda: (M.CMD_GET_VERSION, b"\x00"),
                on_ack=self._on_version,
                timing=_VERSION,
            ),
            _Step(
                "activation",
                "send",
                request=self._activation_request,
                on_ack=self._on_activation,
                timing=_ACTIVATE,
            ),
            _Step(
                "set broadcast frequencies",
                "send",
                request=self._frequency_request,
                on_ack=_code_is(M.SUCCESS, M.BROADCAST_CODES, "set broadcast frequencies"),
                timing=_BROADCAST,
                optional=True,
            ),
        ]
        cmd = DjiCommand(
            self._next_id,
            "connect",
            steps,
            now,
            needs_activation=False,
            on_done=self._connected,
        )
        self._next_id += 1
        self._connect = cmd
        self._queue.appendleft(cmd)

    def _reconnect(self) -> None:
        """Run the connection sequence again (unless it is running or activation was refused)."""
        if self._connect is None and self.activation_error is None:
            self._connect_at = self._clock()

    def _activation_request(self) -> tuple[tuple[int, int], bytes]:
        word = self.version.firmware_word if self.version is not None else M.M100_FIRMWARE
        return M.CMD_ACTIVATE, M.activation_value(self.app_id, word)

    def _frequency_request(self) -> tuple[tuple[int, int], bytes]:
        return M.CMD_SET_BROADCAST, M.frequency_value(self.frequencies(self.broadcast_hz))

    @staticmethod
    def frequencies(rate_hz: int) -> list[int]:
        """The 12 frequency codes asked for: what the core reads at `rate_hz`, the time
        stamp at 1 Hz, the rest (acceleration, rates, magnetometer, gimbal) off."""
        code = M.RATE_CODES[rate_hz]
        used = {"quaternion", "velocity", "position", "rc", "flight_status", "battery", "control"}
        return [code if name in used else (1 if name == "timestamp" else 0) for name in M.ITEMS]

    def _on_version(self, code: int | None, value: bytes) -> str | None:
        try:
            info = M.parse_version_ack(value)
        except ValueError as e:
            return f"unreadable version answer: {e}"
        if not info.hardware.startswith("M100"):
            # Final: the other DJI controllers speak another dialect (spec §12).
            self.activation_error = (
                f"the flight controller is {info.hardware or 'unnamed'} firmware "
                f"{info.firmware_text}, not an M100: fieldkit's DJI backend speaks the "
                "M100's OPEN protocol only"
            )
            return self.activation_error
        first = self.version is None
        self.version = info
        if first:
            self._event(
                "activation",
                f"flight controller: {info.hardware} firmware {info.firmware_text}, "
                f"serial {info.serial or '?'}",
            )
        return None

    def _on_activation(self, code: int | None, value: bytes) -> str | None:
        if code is None:
            return "activation: answer without a return code"
        if code == M.SUCCESS:
            self.activated = True
            self.activation_error = None
            return None
        text = f"activation refused: {M.code_text(code, M.ACTIVATION_CODES)} (app id {self.app_id})"
        if code == M.ACTIVATION_VERSION_MISMATCH and not self._version_retry:
            self._version_retry = True  # query the version again and resend, once
            return text
        if code in M.ACTIVATION_RETRY:
            self._activation_refusals += 1
            if self._activation_refusals < ACTIVATION_ATTEMPTS:
                return text
        self.activation_error = text
        return text

    def _connected(self, cmd: DjiCommand) -> None:
        self._connect = None
        now = self._clock()
        if cmd.ok:
            if cmd.warnings:
                self._event("link", f"broadcast frequencies not confirmed: {cmd.warnings[0]}")
            self._connect_failing = None
            self._event(
                "activation",
                f"activated: app id {self.app_id}, broadcast at {self.broadcast_hz} Hz, "
                f"frames {'AES-256 encrypted' if self.encrypt else 'in clear'}",
            )
            self._advance(now)
            return
        if cmd.status is CommandStatus.CANCELLED:
            return
        if self.activation_error is not None:
            self._event("activation", self.activation_error)
            for pending in self.pending:
                self._queue.remove(pending)
                self._finish(
                    pending,
                    CommandStatus.FAILED,
                    f"{pending.name}: not sent, not activated: {self.activation_error}",
                )
            return
        if cmd.error != self._connect_failing:
            # The first failure of a streak: a silent FC would otherwise fill the log.
            self._event("activation", f"{cmd.error}; trying again every {RECONNECT_S:g} s")
        self._connect_failing = cmd.error
        self._connect_at = now + RECONNECT_S

    # ------------------------------------------------------------------ command machine

    def _new(
        self,
        name: str,
        steps: list[_Step],
        on_done: Callable[[DjiCommand], None] | None,
        *,
        urgent: bool = False,
    ) -> DjiCommand:
        cmd = DjiCommand(self._next_id, name, steps, self._clock(), on_done=on_done)
        self._next_id += 1
        if urgent:
            # Behind the connection sequence, which everything else waits for anyway.
            at = 1 if self._queue and self._queue[0] is self._connect else 0
            self._queue.insert(at, cmd)
            active = self._active
            if active is not None and active._steps[active._index].kind == "watch":
                # A take-off watching the status must not hold a landing back for seconds.
                self.cancel(active, f"superseded by {name}")
        else:
            self._queue.append(cmd)
        self._advance(self._clock())
        return cmd

    def _refused(
        self, name: str, reason: str, on_done: Callable[[DjiCommand], None] | None
    ) -> DjiCommand:
        cmd = DjiCommand(self._next_id, name, [], self._clock(), on_done=on_done)
        self._next_id += 1
        self._finish(cmd, CommandStatus.FAILED, f"{name} refused: {reason}")
        return cmd

    def _quiet_done(self, name: str, on_done: Callable[[DjiCommand], None] | None) -> DjiCommand:
        """A command that is over at once (a setpoint): no event, as setpoints stream."""
        cmd = DjiCommand(self._next_id, name, [], self._clock(), on_done=on_done)
        self._next_id += 1
        cmd.status = CommandStatus.DONE
        cmd.finished = cmd.created
        if on_done is not None:
            on_done(cmd)
        return cmd

    def _advance(self, now: float) -> None:
        while True:
            cmd = self._active
            if cmd is None:
                if not self._queue:
                    return
                head = self._queue[0]
                if head.needs_activation and not self.activated:
                    if self.activation_error is not None:
                        self._queue.popleft()
                        self._finish(
                            head, CommandStatus.FAILED,
                            f"{head.name}: not sent, not activated: {self.activation_error}",
                        )  # fmt: skip
                        continue
                    if now - head.created >= self.queue_timeout_s:
                        self._queue.popleft()
                        self._finish(
                            head, CommandStatus.FAILED,
                            f"{head.name}: not sent, the flight controller is not activated "
                            f"after {self.queue_timeout_s:g} s",
                        )  # fmt: skip
                        continue
                    return
                self._queue.popleft()
                self._active = cmd = head
                cmd.status = CommandStatus.ACTIVE
                cmd._index = 0
                if not self._start_step(cmd, now):
                    continue
            step = cmd._steps[cmd._index]
            if step.kind == "watch":
                assert step.until is not None
                if step.until():
                    cmd._index += 1
                    if self._start_step(cmd, now):
                        return
                    continue
                if now >= cmd._deadline:
                    self._step_failed(cmd, step.fail_text, now)
                    continue
                return
            if now < cmd._deadline:
                return
            if cmd.attempts < step.timing.sends:
                self._send(cmd, now)
                return
            self._step_failed(
                cmd,
                f"{step.label}: no answer after {cmd.attempts} "
                f"{'try' if cmd.attempts == 1 else 'tries'}",
                now,
            )

    def _start_step(self, cmd: DjiCommand, now: float) -> bool:
        """Start the current step, running through skipped and instant ones; False when the
        command is over (finished or failed)."""
        while cmd._index < len(cmd._steps):
            step = cmd._steps[cmd._index]
            cmd.attempts = 0
            cmd._in_progress = 0
            if step.skip is not None and step.skip():
                cmd._index += 1
                continue
            if step.kind == "do":
                assert step.action is not None
                failure = step.action()
                if failure is not None:
                    self._finish(cmd, CommandStatus.FAILED, f"{cmd.name} failed: {failure}")
                    return False
                cmd._index += 1
                continue
            if step.kind == "watch":
                assert step.until is not None
                if step.until():
                    cmd._index += 1
                    continue
                cmd._deadline = now + step.timeout_s
                return True
            self._build(cmd, step)
            self._send(cmd, now)
            return True
        self._finish(cmd, CommandStatus.DONE)
        return False

    def _build(self, cmd: DjiCommand, step: _Step) -> None:
        """The frame of a send step, kept for its retransmissions."""
        assert step.request is not None
        (cmd_set, cmd_id), value = step.request()
        session = 2  # one command in flight: the lowest reliable session is always free
        cmd._session = session
        cmd._seq = self._next_seq(session)
        cmd._frame = command_frame(
            session, cmd._seq, cmd_set, cmd_id, value, cipher=self._cipher_for(cmd_set)
        )

    def _send(self, cmd: DjiCommand, now: float) -> None:
        step = cmd._steps[cmd._index]
        self._transmit(cmd._frame)  # byte for byte the same on every retransmission
        cmd.attempts += 1
        cmd._deadline = now + step.timing.timeout_s

    def _next_step(self, cmd: DjiCommand, now: float) -> None:
        """Go on to the next step (and to the next command when this one is over)."""
        cmd._index += 1
        cmd._frame = b""
        if not self._start_step(cmd, now):
            self._advance(now)

    def _step_failed(self, cmd: DjiCommand, reason: str, now: float) -> None:
        step = cmd._steps[cmd._index]
        cmd._frame = b""
        if step.optional:
            cmd.warnings.append(reason)
            self._next_step(cmd, now)
            return
        self._finish(cmd, CommandStatus.FAILED, f"{cmd.name} failed: {reason}")
        self._advance(now)

    def _finish(self, cmd: DjiCommand, status: CommandStatus, error: str | None = None) -> None:
        cmd.status = status
        cmd.error = error
        cmd.finished = self._clock()
        cmd._frame = b""
        if self._active is cmd:
            self._active = None
        if cmd is not self._connect:
            text = f"{cmd.name}: done" if status is CommandStatus.DONE else (error or cmd.name)
            if status is CommandStatus.DONE and cmd.warnings:
                text += f" ({cmd.warnings[0]})"
            self._event("command", text, cmd)
        if cmd.on_done is not None:
            cmd.on_done(cmd)

    def cancel(self, command: DjiCommand, reason: str = "cancelled") -> None:
        """Stop waiting for `command` (an ACK that comes later is ignored)."""
        if command.done:
            return
        if command in self._queue:
            self._queue.remove(command)
        self._finish(command, CommandStatus.CANCELLED, f"{command.name}: {reason}")
        self._advance(self._clock())

    def cancel_all(self, reason: str = "cancelled") -> None:
        """Cancel every pending order (the connection sequence goes on)."""
        for cmd in self.pending:
            if cmd is not self._connect:
                self.cancel(cmd, reason)

    def link_error(self, text: str) -> None:
        """Count a failure of the line (the transport's too); the first of a streak is an event."""
        self._link_error(text)

    def connection_lost(self, reason: str) -> None:
        """The transport's device vanished (a loose cable): a "link" event, once per outage.

        Nothing else changes here: the silence that follows is the heartbeat loss the
        supervisor acts on, and what is sent meanwhile never arrives.
        """
        self.link_errors += 1
        self._event("link", f"{self.url} lost ({reason}); reopening")

    def connection_made(self, down_s: float) -> None:
        """The device is back after `down_s` seconds: the session starts over, as at start-up.

        The flight controller may have restarted, or dropped what it had of us: no half
        frame from before, then get version, activation and the broadcast frequencies at the
        last rate, and control authority asked for again if the node held it when the line
        went (never when the pilot has the aircraft: the override rules stand). Orders that
        need activation wait for it, as at start-up.
        """
        self._event("reopened", f"{self.url} back after {down_s:g} s")
        self._reader.reset()
        self._link_failing = False
        regain = self.authority and not self.pilot_override
        self.activated = False
        self.authority = False
        self._update_mode()
        if self._connect is None and self.activation_error is None:
            self._start_connect(self._clock())
        if regain:
            self.obtain_control()

    # ------------------------------------------------------------------ steps

    def _obtain_step(self, *, skip_if_held: bool = True) -> _Step:
        return _Step(
            "obtain control authority",
            "send",
            request=lambda: (M.CMD_CONTROL, b"\x01"),
            on_ack=self._on_obtain,
            timing=_CONTROL,
            skip=(lambda: self.authority) if skip_if_held else None,
        )

    def _on_obtain(self, code: int | None, value: bytes) -> str | _Verdict | None:
        if code == M.CONTROL_OBTAINED:
            had = self.authority
            self.authority = True
            self._pilot_took = False
            if not had:
                self._event("authority", "control authority obtained")
            self._update_mode()
            return None
        if code == M.CONTROL_OBTAINING:
            return _Verdict.RESEND
        return self._refusal("control authority refused", code, M.CONTROL_CODES)

    def _on_release(self, code: int | None, value: bytes) -> str | _Verdict | None:
        if code == M.CONTROL_RELEASED:
            self._releasing = False
            if self.authority:
                self.authority = False
                self._event("authority", "control authority released")
            self._setpoint = None
            self._update_mode()
            return None
        if code == M.CONTROL_RELEASING:
            return _Verdict.RESEND
        self._releasing = False
        return self._refusal("release refused", code, M.CONTROL_CODES)

    def _refusal(self, what: str, code: int | None, table: Mapping[int, str]) -> str:
        if code is None:
            return f"{what}: answer without a return code"
        if code == M.NO_AUTHORIZATION and self.activated:
            self._event(
                "activation",
                "the flight controller says it is not activated (restarted?): activating again",
            )
            self.activated = False
            self.authority = False
            self._reconnect()
        if code == M.KEY_ERROR:
            self.key_rejected = True
            self._event(
                "activation",
                f"the flight controller rejected our encryption: {M.code_text(code, {})} "
                "(the app key in the node config is not this app id's)",
            )
        return f"{what}: {M.code_text(code, table)}"

    def _task_step(self, task: int) -> _Step:
        label = M.TASK_NAMES[task]

        def request() -> tuple[tuple[int, int], bytes]:
            self._task_seq = (self._task_seq + 1) & 0xFF
            return M.CMD_TASK, bytes((self._task_seq, task))

        def on_ack(code: int | None, value: bytes) -> str | None:
            if code == M.TASK_STARTED:
                if task == M.TASK_GO_HOME:
                    self._go_home = True
                    self._update_mode()
                return None
            return self._refusal(f"{label} refused", code, M.TASK_CODES)

        return _Step(label, "send", request=request, on_ack=on_ack, timing=_TASK)

    def _watch(self, label: str, until: Callable[[], bool], timeout_s: float, fail: str) -> _Step:
        return _Step(label, "watch", until=until, timeout_s=timeout_s, fail_text=fail)

    # ------------------------------------------------------------------ orders

    def _pilot_refusal(self) -> str | None:
        if not self.pilot_override:
            return None
        if self._switch_off_f:
            where = _switch_name(self.rc_mode or 0)
            return f"the pilot has control (RC mode switch in {where}, not F)"
        return "the pilot took control back: put the RC mode switch out of F and back to hand over"

    def obtain_control(self, *, on_done: Callable[[DjiCommand], None] | None = None) -> DjiCommand:
        """Ask for control authority (even after a pilot override: an explicit hand-back)."""
        return self._new("obtain control", [self._obtain_step(skip_if_held=False)], on_done)

    def release_control(self, *, on_done: Callable[[DjiCommand], None] | None = None) -> DjiCommand:
        """Give control authority back to the remote controller (before exiting)."""

        def start() -> str | None:
            self._releasing = True
            self._setpoint = None
            return None

        steps = [
            _Step("stop streaming", "do", action=start),
            _Step(
                "release control authority",
                "send",
                request=lambda: (M.CMD_CONTROL, b"\x00"),
                on_ack=self._on_release,
                timing=_CONTROL,
            ),
        ]
        return self._new("release control", steps, on_done)

    def request_streams(
        self, rate_hz: float, *, on_done: Callable[[DjiCommand], None] | None = None
    ) -> DjiCommand:
        """Broadcast at least at `rate_hz` (never below the profile's rate): the smallest of
        DJI's rates (1, 10, 50, 100 Hz) that covers it."""
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            return self._refused("request_streams", f"rate must be > 0 Hz, got {rate_hz}", on_done)
        want = max(rate_hz, self.broadcast_hz)
        rate = next((r for r in (1, 10, 50, 100) if r >= want), 100)
        self.broadcast_hz = rate
        step = _Step(
            "set broadcast frequencies",
            "send",
            request=self._frequency_request,
            on_ack=_code_is(M.SUCCESS, M.BROADCAST_CODES, "set broadcast frequencies"),
            timing=_BROADCAST,
        )
        return self._new(f"request_streams {rate} Hz", [step], on_done)

    def arm(self, *, on_done: Callable[[DjiCommand], None] | None = None) -> DjiCommand:
        """Start the motors (0x01/0x05), obtaining control first if needed."""
        return self._arm(True, on_done)

    def disarm(self, *, on_done: Callable[[DjiCommand], None] | None = None) -> DjiCommand:
        """Stop the motors; the M100 refuses in the air."""
        return self._arm(False, on_done)

    def _arm(self, on: bool, on_done: Callable[[DjiCommand], None] | None) -> DjiCommand:
        name = "arm" if on else "disarm"
        why = self._pilot_refusal()
        if why is not None:
            return self._refused(name, why, on_done)

        def on_ack(code: int | None, value: bytes) -> str | None:
            if code in (M.ARM_SUCCESS, M.ARM_ALREADY):
                self._motors = on
                if self.flight_status in (None, M.STATUS_STANDBY, M.STATUS_LANDED):
                    t = self.telemetry
                    if t.armed != on:
                        t.armed = on
                        self._event("armed", "armed" if on else "disarmed")
                return None
            return self._refusal(f"{name} refused", code, M.ARM_CODES)

        step = _Step(
            name,
            "send",
            request=lambda: (M.CMD_ARM, b"\x01" if on else b"\x00"),
            on_ack=on_ack,
            timing=_ARM,
        )
        return self._new(name, [self._obtain_step(), step], on_done)

    def takeoff(
        self, altitude_m: float, *, on_done: Callable[[DjiCommand], None] | None = None
    ) -> DjiCommand:
        """Take off (DJI's auto take-off, about 1.2 m), then climb to `altitude_m` above the
        take-off point by movement control; done once in the air."""
        name = f"takeoff {altitude_m:g}"
        if self.ground:
            return self._refused(name, "a ground robot does not fly", on_done)
        if not (math.isfinite(altitude_m) and altitude_m > 0.0):
            return self._refused(name, f"altitude must be > 0 m, got {altitude_m}", on_done)
        why = self._pilot_refusal()
        if why is not None:
            return self._refused(name, why, on_done)
        serial = self._setpoint_serial

        def climb() -> str | None:
            t = self.telemetry
            if self._setpoint_serial != serial or t.lat is None or t.lon is None:
                return None  # a newer order decides where to go
            self._set_setpoint(_Setpoint("goto", t.lat, t.lon, altitude_m, self._yaw_deg()))
            return None

        steps = [
            self._obtain_step(),
            self._task_step(M.TASK_TAKEOFF),
            self._watch(
                "motors start",
                lambda: (self.flight_status or 0) >= M.STATUS_TAKING_OFF,
                TAKEOFF_START_S,
                f"motors did not start within {TAKEOFF_START_S:g} s of the take-off ACK "
                "(flight status still standby)",
            ),
            self._watch(
                "leave the ground",
                lambda: self.flight_status in (M.STATUS_IN_AIR, M.STATUS_LANDING),
                TAKEOFF_LEAVE_S,
                f"still on the ground {TAKEOFF_LEAVE_S:g} s after the motors started",
            ),
            _Step(
                "auto take-off climb",
                "watch",
                until=self._climb_settled(),
                timeout_s=TAKEOFF_SETTLE_S,
                fail_text="the auto take-off climb did not settle",
                optional=True,
            ),
            _Step("climb", "do", action=climb),
        ]
        return self._new(name, steps, on_done)

    def land(self, *, on_done: Callable[[DjiCommand], None] | None = None) -> DjiCommand:
        """Land where it is (DJI's auto landing). Goes first in the queue."""
        why = self._pilot_refusal()
        if why is not None:
            return self._refused("land", why, on_done)
        self._set_setpoint(None)
        steps = [
            self._obtain_step(),
            self._task_step(M.TASK_LAND),
            self._watch(
                "landing starts",
                lambda: self.flight_status != M.STATUS_IN_AIR,
                LANDING_START_S,
                f"still flying {LANDING_START_S:g} s after the landing ACK",
            ),
        ]
        return self._new("land", steps, on_done, urgent=True)

    def rtl(self, *, on_done: Callable[[DjiCommand], None] | None = None) -> DjiCommand:
        """Go home (DJI's return-to-home task: climb, fly home, land). Goes first."""
        why = self._pilot_refusal()
        if why is not None:
            return self._refused("rtl", why, on_done)
        self._set_setpoint(None)
        steps = [self._obtain_step(), self._task_step(M.TASK_GO_HOME)]
        return self._new("rtl", steps, on_done, urgent=True)

    def hold(self, *, on_done: Callable[[DjiCommand], None] | None = None) -> DjiCommand:
        """Brake and hover where it is: zero velocities streamed. Goes first."""
        why = self._pilot_refusal()
        if why is not None:
            return self._refused("hold", why, on_done)
        self._go_home = False
        self._set_setpoint(_Setpoint("hover"))
        if self.authority:
            return self._quiet_done("hold", on_done)
        return self._new("hold", [self._obtain_step()], on_done, urgent=True)

    def goto(
        self,
        lat: float,
        lon: float,
        alt_m: float,
        *,
        yaw_deg: float | None = None,
        on_done: Callable[[DjiCommand], None] | None = None,
    ) -> DjiCommand:
        """Fly to an absolute point (`alt_m` above the take-off point), by position offsets
        streamed at the control rate; superseded by the next setpoint.

        Done at once when the host has control authority (setpoints have no ACK in the
        OPEN protocol); otherwise once authority is obtained. `yaw_deg` (0 north,
        clockwise) is the heading to face; by default the heading is kept.
        """
        name = f"goto {lat:.7f},{lon:.7f},{alt_m:g}"
        if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt_m)):
            return self._refused(name, "non-finite coordinates", on_done)
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return self._refused(name, "latitude or longitude out of range", on_done)
        why = self._pilot_refusal()
        if why is not None:
            return self._refused(name, why, on_done)
        if self.gps_health is not None and self.gps_health < 3:
            return self._refused(
                name, f"GPS health {self.gps_health}: position control needs 3 or more", on_done
            )
        heading = self._yaw_deg() if yaw_deg is None else math.remainder(yaw_deg, 360.0)
        self._go_home = False
        self._set_setpoint(_Setpoint("goto", lat, lon, max(alt_m, 0.0), heading))
        if self.authority:
            return self._quiet_done(name, on_done)
        if any(s.label == "obtain control authority" for c in self.pending for s in c._steps):
            return self._quiet_done(name, on_done)  # on its way: the stream starts with it
        return self._new(name, [self._obtain_step()], on_done)

    def _climb_settled(self) -> Callable[[], bool]:
        """A test for the end of DJI's auto take-off climb: it climbed, and has stopped."""
        climbed = False

        def settled() -> bool:
            nonlocal climbed
            vd = self.telemetry.vel_down_mps
            if vd is None:
                return False
            if -vd > CLIMBING_VZ_MPS:
                climbed = True
            return climbed and abs(vd) < HOVER_VZ_MPS

        return settled

    def _set_setpoint(self, sp: _Setpoint | None) -> None:
        self._setpoint_serial += 1
        if sp is not None:
            sp.serial = self._setpoint_serial
        self._setpoint = sp
        self._update_mode()

    def _yaw_deg(self) -> float:
        yaw = self.telemetry.yaw_rad
        return math.degrees(math.remainder(yaw, 2 * math.pi)) if yaw is not None else 0.0

    @property
    def setpoint(self) -> tuple[str, float, float, float, float] | None:
        """What the movement stream sends: ("goto", lat, lon, alt, yaw°), ("hover", ...)."""
        sp = self._setpoint
        return None if sp is None else (sp.kind, sp.lat, sp.lon, sp.alt, sp.yaw_deg)


def _switch_name(mode: int) -> str:
    """The RC mode switch position of a mode channel value: P, A or F."""
    if mode > RC_F_THRESHOLD:
        return "F"
    if mode < -RC_F_THRESHOLD:
        return "P"
    return "A"


def _code_is(
    wanted: int, table: Mapping[int, str], what: str
) -> Callable[[int | None, bytes], str | None]:
    """An ACK handler that accepts one return code."""

    def check(code: int | None, value: bytes) -> str | None:
        if code == wanted:
            return None
        shown = "no return code" if code is None else M.code_text(code, table)
        return f"{what} refused: {shown}"

    return check


if TYPE_CHECKING:

    def _is_a_vehicle_core(core: DjiCore) -> VehicleCore:
        """mypy checks here that DjiCore serves the one vehicle interface."""
        return core


def app_key_fingerprint(app_key: str) -> str:
    """16 hex digits naming an app key without revealing it (what a recording keeps): a
    replay given another key says so before it decodes nothing."""
    key = parse_app_key(app_key)
    return hashlib.sha256(b"fieldkit dji app key v1\0" + key).hexdigest()[:16]


__all__ = ["DjiCommand", "DjiCore", "DjiError", "app_key_fingerprint"]
