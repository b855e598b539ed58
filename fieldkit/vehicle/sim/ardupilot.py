"""A simulated ArduPilot vehicle's protocol and flight, without I/O: bytes and time in, frames out.

    sim = SimArduPilot(load_profile("solo"), home=(45.5017, -73.5673))
    sim.receive_data(bytes_from_the_gcs)           # COMMAND_LONG, SET_POSITION_TARGET...
    sim.step(0.1)                                  # physics by 0.1 s, telemetry when due
    write(sim.data_to_send())                      # HEARTBEAT, streams, ACKs

Real ArduPilot SITL cannot be built or downloaded here
(docs/third-party.md#no-autopilot-sitl), so this stands in for it, for everything the field
node's link uses. `fieldkit.vehicle.sim.vehicle.SimVehicle` puts it on a pty, a serial port
or a pymavlink URL. UAV profiles behave like ArduCopter, ground profiles like ArduPilot
Rover:

- HEARTBEAT every second: MAV_TYPE_QUADROTOR or MAV_TYPE_GROUND_ROVER, MAV_AUTOPILOT_
  ARDUPILOTMEGA, the armed flag in base_mode and ArduPilot's custom mode numbers (pymavlink's
  `mode_mapping_acm` / `mode_mapping_rover`: copter GUIDED 4, LOITER 5, RTL 6, LAND 9; rover
  HOLD 4, RTL 11, GUIDED 15).
- Telemetry streams, none until asked (REQUEST_DATA_STREAM groups as ArduPilot maps them, or
  SET_MESSAGE_INTERVAL per message): SYS_STATUS, GPS_RAW_INT, EXTENDED_SYS_STATE,
  GLOBAL_POSITION_INT, ATTITUDE, VFR_HUD, BATTERY_STATUS, RC_CHANNELS, HOME_POSITION.
- A GPS fix (3D, 10 satellites) `gps_fix_delay_s` after boot; before it, fix type 1 and 3
  satellites, zero positions, and ArduPilot's refusals: arming fails with
  "PreArm: Need 3D Fix", GPS modes with "Mode change to GUIDED failed: requires position".
- A COMMAND_ACK for every COMMAND_LONG: ACCEPTED, FAILED (checks refused, as ArduPilot
  answers them) or UNSUPPORTED (unknown commands; takeoff and land on a rover). Takeoff only in
  GUIDED, armed and on the ground; disarming in the air refused unless forced; no arming in
  RTL or LAND; an armed copter that does not take off disarms itself after `auto_disarm_s`.
- SET_POSITION_TARGET_GLOBAL_INT in GUIDED, followed with the profile's kinematics
  (`fieldkit.vehicle.kinematics.Vehicle` in a `geo.LocalFrame` at home); LAND descends and disarms
  on touchdown; RTL climbs to `rtl_alt_m`, flies home and lands (a rover drives home and stops).

Stepping is deterministic: `step(dt)` moves the physics by `dt` and sends what is due on the
simulated clock; the same inputs give the same bytes. The flight itself is the profile's
kinematics (`fieldkit.vehicle.kinematics.Vehicle`, in `self.vehicle`), which the protocol drives.

Failure injection (`faults`, `pilot_switch`, `set_battery`) covers what the node must survive:
lost heartbeats, a silent autopilot, line noise between frames, corrupt CRCs, lost ACKs, the
pilot taking over with the mode switch, a low battery.
"""

from __future__ import annotations

import logging
import math
import random
from collections import Counter
from dataclasses import dataclass
from typing import Any, TypedDict

from pymavlink import mavutil
from pymavlink.dialects.v20 import all as mavlink2

from fieldkit.errors import FieldkitError
from fieldkit.robot.geo import DEFAULT_HOME as DEFAULT_HOME
from fieldkit.robot.geo import LocalFrame
from fieldkit.robot.profiles import Profile
from fieldkit.robot.script_api import IN_AIR, LANDING, ON_GROUND, TAKING_OFF
from fieldkit.vehicle.kinematics import Vehicle
from fieldkit.vehicle.mavlink import FrameReader, new_codec

# The logger keeps its old name: `fieldkit vehicle-sim` shows this logger's lines.
_log = logging.getLogger("fieldkit.vehicle_sim")

ACCEPTED = mavlink2.MAV_RESULT_ACCEPTED
"""COMMAND_ACK result: done."""
FAILED = mavlink2.MAV_RESULT_FAILED
"""COMMAND_ACK result: refused by a check (ArduPilot's usual refusal)."""
DENIED = mavlink2.MAV_RESULT_DENIED
"""COMMAND_ACK result: parameters not acceptable."""
UNSUPPORTED = mavlink2.MAV_RESULT_UNSUPPORTED
"""COMMAND_ACK result: a command this vehicle does not know."""

# Modes that need a position estimate (ArduPilot refuses them without a GPS fix).
_COPTER_GPS_MODES = frozenset(
    {"GUIDED", "LOITER", "RTL", "AUTO", "POSHOLD", "CIRCLE", "DRIFT", "BRAKE", "SMART_RTL"}
    | {"FOLLOW", "ZIGZAG", "AUTO_RTL"}
)
_ROVER_GPS_MODES = frozenset(
    {"GUIDED", "RTL", "AUTO", "LOITER", "SMART_RTL", "FOLLOW", "CIRCLE", "DOCK"}
)
# ArduCopter refuses to arm in these modes.
_COPTER_NO_ARM_MODES = frozenset({"RTL", "LAND", "SMART_RTL", "AUTO_RTL"})
# base_mode gets GUIDED_ENABLED in these, as ArduPilot reports it.
_GUIDED_FLAG_MODES = frozenset({"GUIDED", "AUTO", "RTL", "SMART_RTL", "AUTO_RTL", "LAND"})

# REQUEST_DATA_STREAM groups, as ArduPilot's SRn_ parameters group these messages.
_STREAM_GROUPS: dict[int, tuple[str, ...]] = {
    mavlink2.MAV_DATA_STREAM_EXTENDED_STATUS: ("SYS_STATUS", "GPS_RAW_INT", "EXTENDED_SYS_STATE"),
    mavlink2.MAV_DATA_STREAM_RC_CHANNELS: ("RC_CHANNELS",),
    mavlink2.MAV_DATA_STREAM_POSITION: ("GLOBAL_POSITION_INT",),
    mavlink2.MAV_DATA_STREAM_EXTRA1: ("ATTITUDE",),
    mavlink2.MAV_DATA_STREAM_EXTRA2: ("VFR_HUD",),
    mavlink2.MAV_DATA_STREAM_EXTRA3: ("BATTERY_STATUS",),
}
# Everything that can stream, in the order it is sent within a step (deterministic output).
STREAMS: tuple[str, ...] = (
    "SYS_STATUS",
    "GPS_RAW_INT",
    "EXTENDED_SYS_STATE",
    "GLOBAL_POSITION_INT",
    "ATTITUDE",
    "VFR_HUD",
    "BATTERY_STATUS",
    "RC_CHANNELS",
    "HOME_POSITION",
)
"""Messages the simulator streams on request, in the order it sends them within a step."""
_STREAM_IDS = {getattr(mavlink2, f"MAVLINK_MSG_ID_{name}"): name for name in STREAMS}

_SENSORS = (
    mavlink2.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mavlink2.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mavlink2.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mavlink2.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mavlink2.MAV_SYS_STATUS_SENSOR_GPS
    | mavlink2.MAV_SYS_STATUS_SENSOR_BATTERY
)
RC_MODE_CHANNEL = 5
"""ArduPilot's default flight-mode channel (FLTMODE_CH / MODE_CH)."""
_RC_LOW = 1100
_RC_MID = 1500
_UINT16_MAX = 65535
# Above this, a ground speed reads as driving (for the battery current and the course).
_MOVING_MPS = 0.05


class VehicleSimError(FieldkitError):
    """The simulated vehicle cannot start (a port it cannot open, a bad home)."""


@dataclass
class SimFaults:
    """What goes wrong, switched on and off by tests at any step."""

    heartbeats: bool = True  # False: no HEARTBEAT, everything else still flows
    silent: bool = False  # True: nothing at all leaves the vehicle (a dead autopilot)
    garbage_every: int = 0  # after every Nth frame, `garbage_len` random bytes (0: never)
    garbage_len: int = 8
    corrupt_every: int = 0  # every Nth frame leaves with a broken CRC (0: never)
    drop_acks: int = 0  # the next N COMMAND_ACKs are lost on the way (the command still acts)


class SimOptions(TypedDict, total=False):
    """`SimArduPilot`'s keyword options, as a transport passes them on unchanged."""

    home: tuple[float, float]
    home_alt_m: float
    sysid: int
    compid: int
    gps_fix_delay_s: float
    default_rate_hz: float
    auto_disarm_s: float | None
    rtl_alt_m: float
    seed: int


class SimArduPilot:
    """One simulated ArduPilot vehicle (Copter for UAV profiles, Rover for ground ones)."""

    def __init__(
        self,
        profile: Profile,
        *,
        home: tuple[float, float] = DEFAULT_HOME,
        home_alt_m: float = 50.0,
        sysid: int = 1,
        compid: int = 1,
        gps_fix_delay_s: float = 0.0,
        default_rate_hz: float = 0.0,
        auto_disarm_s: float | None = 10.0,
        rtl_alt_m: float = 15.0,
        seed: int = 0,
    ) -> None:
        """A disarmed vehicle at `home` that has heard nothing yet.

        `default_rate_hz` streams everything before anyone asks
        (0: only heartbeats, like an ArduPilot port whose SRn_ rates are 0). `seed` drives
        the garbage bytes of `faults.garbage_every`.
        """
        try:
            self.frame = LocalFrame(float(home[0]), float(home[1]), float(home_alt_m))
        except (ValueError, TypeError, IndexError) as e:
            raise VehicleSimError(f"bad home {home!r}: {e}") from e
        self.profile = profile
        self.ground = profile.is_ground
        self.sysid = sysid
        self.compid = compid
        self.gps_fix_delay_s = gps_fix_delay_s
        self.auto_disarm_s = auto_disarm_s
        self.rtl_alt_m = rtl_alt_m
        self.vehicle = Vehicle.from_profile(profile)
        self.mav_type = (
            mavlink2.MAV_TYPE_GROUND_ROVER if self.ground else mavlink2.MAV_TYPE_QUADROTOR
        )
        modes = mavutil.mode_mapping_rover if self.ground else mavutil.mode_mapping_acm
        self.mode_numbers: dict[str, int] = {name: num for num, name in modes.items()}
        self.mode = "MANUAL" if self.ground else "STABILIZE"
        self.time = 0.0
        self.faults = SimFaults()
        self.rc: list[int] = [_RC_MID] * 16
        self.rc[2] = 1000 if not self.ground else _RC_MID  # throttle low
        self.rc[RC_MODE_CHANNEL - 1] = _RC_LOW
        self.home: tuple[float, float, float] | None = None  # set at GPS fix, moved at arming
        self.guided_target: tuple[float, float, float] | None = None  # last (lat, lon, alt)
        self.received: Counter[str] = Counter()  # messages by type
        self.commands: Counter[int] = Counter()  # COMMAND_LONGs by MAV_CMD id
        self.gcs_heartbeats = 0
        self.last_gcs_heartbeat: float | None = None  # sim time
        self.frames_sent = 0
        self.corrupted_frames = 0
        self.garbage_bytes = 0
        self.bytes_sent = 0
        self.bytes_dropped = 0
        self.bytes_received = 0
        self.acks_sent = 0
        self.acks_dropped = 0
        self.texts: list[str] = []  # STATUSTEXTs sent
        self._rng = random.Random(seed)
        self._consumed_mah = 0.0
        self._landed_armed_s = 0.0
        self._pending_target: tuple[float, float, float, float | None] | None = None
        self._home_dirty = False
        self._intervals: dict[str, float | None] = {}
        self._next_due: dict[str, float] = {}
        for name in STREAMS:
            rate = default_rate_hz if name != "HOME_POSITION" else min(default_rate_hz, 0.5)
            self._set_interval(name, 1.0 / rate if rate > 0 else None)
        self._next_heartbeat = 0.0

        # Every frame the codec encodes goes through `write`: faults, counters, the outbox.
        self._mav = new_codec(self, sysid, compid)
        self._reader = FrameReader(self._mav)
        self._outbox: list[bytes] = []

    # ------------------------------------------------------------------ views

    @property
    def kind(self) -> str:
        """What it simulates, for a log line: "ArduCopter" or "ArduPilot Rover"."""
        return "ArduPilot Rover" if self.ground else "ArduCopter"

    @property
    def armed(self) -> bool:
        """Whether the motors are armed."""
        return self.vehicle.armed

    @property
    def gps_fix_type(self) -> int:
        """3 (3D fix) once `gps_fix_delay_s` has passed, 1 (no fix) before."""
        return 3 if self.time >= self.gps_fix_delay_s else 1

    @property
    def satellites(self) -> int:
        """Satellites in view."""
        return 10 if self.gps_fix_type >= 3 else 3

    @property
    def position(self) -> tuple[float, float, float]:
        """(lat, lon, altitude above home in metres) of the vehicle now."""
        v = self.vehicle
        lat, lon, _ = self.frame.to_gps(v.x, v.y)
        return lat, lon, v.z

    @property
    def custom_mode(self) -> int:
        """ArduPilot's number of the current mode."""
        return self.mode_numbers[self.mode]

    # ------------------------------------------------------------------ test handles

    def pilot_switch(self, mode: str, pwm: int = 1900, channel: int = RC_MODE_CHANNEL) -> bool:
        """The pilot flips the mode switch: RC `channel` goes to `pwm` and the mode changes
        (with ArduPilot's checks); True if the mode changed."""
        self.rc[channel - 1] = pwm
        return self._set_mode(mode, "RC") == ACCEPTED

    def pilot_release(self, channel: int = RC_MODE_CHANNEL) -> None:
        """The pilot puts the switch back low (the mode stays what it is, as ArduPilot)."""
        self.rc[channel - 1] = _RC_LOW

    def set_battery(self, percent: float) -> None:
        """Jump the battery to `percent` (voltage follows the profile's linear model)."""
        self.vehicle.set_battery(percent)  # its battery is the profile's

    # ------------------------------------------------------------------ time

    def step(self, dt: float) -> None:
        """Advance the physics by `dt` and send what is due."""
        self.time += dt
        had_fix = self.home is not None
        if not had_fix and self.gps_fix_type >= 3:
            self._set_home()
        self._control(dt)
        v = self.vehicle
        if v.armed:
            self._consumed_mah += self._current_a() * dt / 3.6
        was = v.status
        v.step(dt)
        if was == LANDING and v.status == ON_GROUND:
            self._touchdown()
        self._emit()

    def _touchdown(self) -> None:
        """A landing just ended on the ground (the kinematics disarmed: ArduPilot's way)."""
        self._note("touchdown: disarmed")

    # ------------------------------------------------------------------ bytes in and out

    def receive_data(self, data: bytes) -> int:
        """Handle bytes from the ground side (any split of the stream); messages handled."""
        self.bytes_received += len(data)
        handled = 0
        for msg in self._reader.feed(data):
            self._handle(msg)
            handled += 1
        return handled

    def data_to_send(self) -> bytes:
        """The bytes sent since the last call (faults applied), for the line."""
        out = b"".join(self._outbox)
        self._outbox.clear()
        return out

    def _transmit(self, frame: bytes) -> None:
        """One frame (or frame and noise) onto the line: here, the outbox.

        A transport overrides this to write each frame at once, as a UART would.
        """
        self._outbox.append(frame)
        self.bytes_sent += len(frame)

    # ------------------------------------------------------------------ output

    def write(self, buf: bytes | bytearray) -> None:
        """Where the codec writes each frame: faults are applied, bytes counted."""
        f = self.faults
        if f.silent:
            return
        frame = bytearray(buf)
        self.frames_sent += 1
        n = self.frames_sent
        if f.corrupt_every and n % f.corrupt_every == 0:
            frame[-1] ^= 0x5A  # the CRC's high byte (frames are unsigned)
            self.corrupted_frames += 1
        if f.garbage_every and n % f.garbage_every == 0:
            noise = bytes(self._rng.randrange(256) for _ in range(f.garbage_len))
            frame += noise
            self.garbage_bytes += len(noise)
        self._transmit(bytes(frame))

    def _text(self, text: str, severity: int = mavlink2.MAV_SEVERITY_CRITICAL) -> None:
        self.texts.append(text)
        self._note(text)
        self._mav.statustext_send(severity, text.encode("ascii", "replace")[:50])

    def _note(self, text: str) -> None:
        _log.info("t=%.1f %s: %s", self.time, self.profile.name, text)

    def _ack(self, msg: Any, command: int, result: int) -> None:
        if self.faults.drop_acks > 0:
            self.faults.drop_acks -= 1
            self.acks_dropped += 1
            return
        self.acks_sent += 1
        self._mav.command_ack_send(
            command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        )

    # ------------------------------------------------------------------ input

    def _handle(self, msg: Any) -> None:
        name = msg.get_type()
        self.received[name] += 1
        if name == "HEARTBEAT":
            if msg.get_srcSystem() != self.sysid:
                self.gcs_heartbeats += 1
                self.last_gcs_heartbeat = self.time
            return
        target = getattr(msg, "target_system", None)
        if target is None or target not in (0, self.sysid):
            return  # not for us (or no target at all: nothing we act on)
        if name == "COMMAND_LONG":
            if msg.target_component in (0, self.compid):
                self.commands[msg.command] += 1
                self._ack(msg, msg.command, self._command_long(msg))
        elif name == "COMMAND_INT":
            self._ack(msg, msg.command, UNSUPPORTED)
        elif name == "SET_MODE":
            result = self._set_mode_number(msg.custom_mode)
            self._ack(msg, mavlink2.MAVLINK_MSG_ID_SET_MODE, result)
        elif name == "SET_POSITION_TARGET_GLOBAL_INT":
            self._position_target(msg)
        elif name == "REQUEST_DATA_STREAM":
            self._request_stream(msg.req_stream_id, msg.req_message_rate, msg.start_stop)

    def _command_long(self, m: Any) -> int:
        c = m.command
        if c == mavlink2.MAV_CMD_COMPONENT_ARM_DISARM:
            if m.param1 == 1.0:
                return self._arm(force=int(m.param2) == 2989)
            if m.param1 == 0.0:
                return self._disarm(force=int(m.param2) == 21196)
            return DENIED
        if c == mavlink2.MAV_CMD_DO_SET_MODE:
            if not int(m.param1) & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return DENIED  # ArduPilot only takes custom modes
            return self._set_mode_number(int(m.param2))
        if c == mavlink2.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff(m.param7)
        if c == mavlink2.MAV_CMD_NAV_LAND:
            return UNSUPPORTED if self.ground else self._set_mode("LAND", "GCS")
        if c == mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._set_mode("RTL", "GCS")
        if c == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            name = _STREAM_IDS.get(int(m.param1))
            if name is None:
                return FAILED
            us = m.param2
            if us < 0:
                self._set_interval(name, None)
            elif us == 0:
                self._set_interval(name, None)  # "default rate": ours is off
            else:
                self._set_interval(name, us * 1e-6)
            return ACCEPTED
        if c == mavlink2.MAV_CMD_REQUEST_MESSAGE:
            name = _STREAM_IDS.get(int(m.param1))
            if name is None or (name == "HOME_POSITION" and self.home is None):
                return FAILED
            self._send(name)
            return ACCEPTED
        if c == mavlink2.MAV_CMD_GET_HOME_POSITION:
            if self.home is None:
                return FAILED
            self._send("HOME_POSITION")
            return ACCEPTED
        return UNSUPPORTED

    def _arm(self, force: bool) -> int:
        v = self.vehicle
        if v.armed:
            return ACCEPTED
        if not force:
            if self.gps_fix_type < 3:
                self._text("PreArm: Need 3D Fix")
                return FAILED
            if not self.ground and self.mode in _COPTER_NO_ARM_MODES:
                self._text("Arm: Mode not armable")
                return FAILED
        if not v.arm():
            self._text("PreArm: Battery below minimum arming capacity")
            return FAILED
        self._landed_armed_s = 0.0
        if self.gps_fix_type >= 3:
            self._set_home()  # ArduPilot moves home to where it arms
        self._note(f"armed in {self.mode}")
        return ACCEPTED

    def _disarm(self, force: bool) -> int:
        v = self.vehicle
        if not v.armed:
            return ACCEPTED
        if not self.ground and v.status != ON_GROUND:
            if not force:
                return FAILED
            # Motors stop in the air: the vehicle falls. Model the crash as an instant drop.
            fallen = Vehicle.from_profile(self.profile, x=v.x, y=v.y, yaw=v.yaw)
            fallen.battery_percent, fallen.voltage = v.battery_percent, v.voltage
            self.vehicle = fallen
            self._text("Disarmed in the air (forced)")
            return ACCEPTED
        v.disarm()
        self._note("disarmed")
        return ACCEPTED

    def _takeoff(self, alt: float) -> int:
        v = self.vehicle
        if self.ground:
            return UNSUPPORTED  # Rover does not know NAV_TAKEOFF
        if self.mode != "GUIDED" or not v.armed or v.status != ON_GROUND:
            return FAILED
        if not (math.isfinite(alt) and alt > 0.0) or not v.takeoff(alt):
            return FAILED
        self._note(f"takeoff to {alt:g} m")
        return ACCEPTED

    def _set_mode_number(self, number: int) -> int:
        names = {n: name for name, n in self.mode_numbers.items()}
        name = names.get(number)
        if name is None:
            return FAILED
        return self._set_mode(name, "GCS")

    def _set_mode(self, name: str, by: str) -> int:
        if name not in self.mode_numbers:
            return FAILED
        gps_modes = _ROVER_GPS_MODES if self.ground else _COPTER_GPS_MODES
        if name in gps_modes and self.gps_fix_type < 3:
            self._text(f"Mode change to {name} failed: requires position")
            return FAILED
        if name == self.mode:
            return ACCEPTED
        self._note(f"mode {self.mode} -> {name} ({by})")
        self.mode = name
        self._enter_mode()
        return ACCEPTED

    def _enter_mode(self) -> None:
        """What a new mode does at once to the motion."""
        v = self.vehicle
        self._pending_target = None
        flying = v.flying if not self.ground else v.armed
        if not flying:
            return
        if self.mode == "LAND" and not self.ground:
            v.land()
        elif self.mode == "RTL":
            # The shared kinematics fly RTL (climb, home, land), as the swarm simulator's do.
            hx, hy, _ = self.frame.from_gps(*self.home[:2]) if self.home else (0.0, 0.0, 0.0)
            v.return_home(hx, hy, self.rtl_alt_m)
        else:
            # GUIDED waits for a target; LOITER, HOLD, BRAKE and the pilot's modes (no
            # sticks here) keep the position.
            v.hold()

    def _position_target(self, m: Any) -> None:
        if self.mode != "GUIDED":
            return  # ArduPilot ignores setpoints outside GUIDED
        if m.type_mask & 0b111:
            return  # velocity or acceleration control: not simulated
        lat, lon = m.lat_int * 1e-7, m.lon_int * 1e-7
        if m.coordinate_frame == mavlink2.MAV_FRAME_GLOBAL_INT:
            z = m.alt - self.frame.alt
        elif m.coordinate_frame in (
            mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,  # flat ground: terrain = home
        ):
            z = m.alt
        else:
            return
        yaw = None if m.type_mask & 1024 else math.pi / 2 - m.yaw  # NED -> ENU
        self.guided_target = (lat, lon, z)
        try:
            x, y, _ = self.frame.from_gps(lat, lon)
        except ValueError:
            return
        v = self.vehicle
        if self.ground:
            v.goto(x, y)
        elif v.status == IN_AIR:
            v.goto(x, y, z, yaw)
        elif v.status == TAKING_OFF:
            self._pending_target = (x, y, z, yaw)  # followed once the climb is done

    def _request_stream(self, stream: int, rate: int, start: int) -> None:
        interval = 1.0 / rate if start and rate > 0 else None
        if stream == mavlink2.MAV_DATA_STREAM_ALL:
            names = [n for group in _STREAM_GROUPS.values() for n in group]
        else:
            names = list(_STREAM_GROUPS.get(stream, ()))
        for name in names:
            self._set_interval(name, interval)

    def _set_interval(self, name: str, interval: float | None) -> None:
        self._intervals[name] = interval
        self._next_due[name] = -1.0  # the first one goes out at the next step

    # ------------------------------------------------------------------ physics and modes

    def _set_home(self) -> None:
        lat, lon, _ = self.position
        self.home = (lat, lon, self.frame.alt)
        self._home_dirty = True

    def _control(self, dt: float) -> None:
        v = self.vehicle
        if self._pending_target is not None and v.status == IN_AIR:
            x, y, z, yaw = self._pending_target
            self._pending_target = None
            v.goto(x, y, z, yaw)
        if not self.ground and self.auto_disarm_s is not None and v.armed and v.status == ON_GROUND:
            self._landed_armed_s += dt
            if self._landed_armed_s >= self.auto_disarm_s:
                v.disarm()
                self._note(f"disarmed: no takeoff for {self.auto_disarm_s:g} s")
        else:
            self._landed_armed_s = 0.0

    def _current_a(self) -> float:
        """Battery current: the profile's endurance at its capacity, less when idle."""
        b = self.profile.battery
        v = self.vehicle
        if not v.armed:
            return 0.3
        nominal = (b.full_voltage + b.empty_voltage) * 0.5
        full = (b.capacity_wh * 3600.0 / b.endurance_s) / nominal if b.capacity_wh else 10.0
        moving = v.flying if not self.ground else math.hypot(v.vx, v.vy) > _MOVING_MPS
        return full if moving else full * 0.2

    # ------------------------------------------------------------------ telemetry

    def _emit(self) -> None:
        t = self.time + 1e-9  # steps of 0.1 s add up to 0.30000000000000004
        if t >= self._next_heartbeat:
            self._next_heartbeat += 1.0
            if self._next_heartbeat <= self.time:
                self._next_heartbeat = self.time + 1.0
            if self.faults.heartbeats:
                self._send("HEARTBEAT")
        if self._home_dirty and self.home is not None:
            self._home_dirty = False
            self._send("HOME_POSITION")  # ArduPilot announces a new home once
        for name in STREAMS:
            interval = self._intervals[name]
            if interval is None or t < self._next_due[name]:
                continue
            due = self._next_due[name]
            # The first one after a request sets the phase; then keep the average rate even
            # when the interval is not a multiple of the step.
            nxt = (self.time if due < 0 else due) + interval
            if nxt <= self.time:
                nxt = self.time + interval
            self._next_due[name] = nxt
            if name == "HOME_POSITION" and self.home is None:
                continue
            self._send(name)

    def _send(self, name: str) -> None:
        getattr(self, f"_send_{name.lower()}")()

    def _boot_ms(self) -> int:
        return int(round(self.time * 1000.0)) & 0xFFFFFFFF

    def _send_heartbeat(self) -> None:
        v = self.vehicle
        base = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
        base |= mavlink2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        if self.mode in _GUIDED_FLAG_MODES:
            base |= mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
        if v.armed:
            base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        state = mavlink2.MAV_STATE_ACTIVE if v.armed else mavlink2.MAV_STATE_STANDBY
        self._mav.heartbeat_send(
            self.mav_type, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, base, self.custom_mode, state
        )

    def _gps_fields(self) -> tuple[int, int, int]:
        """lat, lon (1e-7 degrees) and MSL altitude (mm); zeros without a fix."""
        if self.gps_fix_type < 3:
            return 0, 0, 0
        lat, lon, z = self.position
        return round(lat * 1e7), round(lon * 1e7), round((self.frame.alt + z) * 1000.0)

    def _heading_cdeg(self) -> int:
        """Heading, centidegrees from north clockwise."""
        deg = math.degrees(math.pi / 2 - self.vehicle.yaw) % 360.0
        return round(deg * 100.0) % 36000

    def _send_gps_raw_int(self) -> None:
        v = self.vehicle
        lat, lon, alt = self._gps_fields()
        fix = self.gps_fix_type
        speed = math.hypot(v.vx, v.vy)
        cog = (
            round(math.degrees(math.atan2(v.vx, v.vy)) % 360.0 * 100.0) % 36000
            if speed > _MOVING_MPS
            else _UINT16_MAX
        )
        self._mav.gps_raw_int_send(
            round(self.time * 1e6),
            fix,
            lat,
            lon,
            alt,
            121 if fix >= 3 else _UINT16_MAX,
            200 if fix >= 3 else _UINT16_MAX,
            round(speed * 100.0),
            cog,
            self.satellites,
        )

    def _send_global_position_int(self) -> None:
        v = self.vehicle
        lat, lon, alt = self._gps_fields()
        fix = self.gps_fix_type >= 3
        self._mav.global_position_int_send(
            self._boot_ms(),
            lat,
            lon,
            alt,
            round(v.z * 1000.0) if fix else 0,
            round(v.vy * 100.0),  # north
            round(v.vx * 100.0),  # east
            round(-v.vz * 100.0),  # down
            self._heading_cdeg(),
        )

    def _send_attitude(self) -> None:
        yaw = math.remainder(math.pi / 2 - self.vehicle.yaw, 2 * math.pi)
        self._mav.attitude_send(self._boot_ms(), 0.0, 0.0, yaw, 0.0, 0.0, 0.0)

    def _send_vfr_hud(self) -> None:
        v = self.vehicle
        speed = math.hypot(v.vx, v.vy)
        throttle = 0 if not v.armed else (50 if v.flying else 0)
        self._mav.vfr_hud_send(
            speed, speed, self._heading_cdeg() // 100, throttle, self.frame.alt + v.z, v.vz
        )

    def _send_sys_status(self) -> None:
        v = self.vehicle
        health = _SENSORS
        if self.gps_fix_type < 3:
            health &= ~mavlink2.MAV_SYS_STATUS_SENSOR_GPS
        self._mav.sys_status_send(
            _SENSORS,
            _SENSORS,
            health,
            150,
            round(v.voltage * 1000.0),
            round(self._current_a() * 100.0),
            round(v.battery_percent),
            0,
            0,
            0,
            0,
            0,
            0,
        )

    def _send_battery_status(self) -> None:
        v = self.vehicle
        cells = [round(v.voltage * 1000.0)] + [_UINT16_MAX] * 9
        self._mav.battery_status_send(
            0,
            mavlink2.MAV_BATTERY_FUNCTION_ALL,
            mavlink2.MAV_BATTERY_TYPE_LIPO,
            32767,  # temperature unknown (INT16_MAX)
            cells,
            round(self._current_a() * 100.0),
            round(self._consumed_mah),
            -1,
            round(v.battery_percent),
        )

    def _send_extended_sys_state(self) -> None:
        landed = mavlink2.MAV_LANDED_STATE_ON_GROUND if self.ground else self.vehicle.status
        self._mav.extended_sys_state_send(mavlink2.MAV_VTOL_STATE_UNDEFINED, landed)

    def _send_rc_channels(self) -> None:
        self._mav.rc_channels_send(
            self._boot_ms(), len(self.rc), *self.rc, _UINT16_MAX, _UINT16_MAX, 200
        )

    def _send_home_position(self) -> None:
        if self.home is None:
            return
        lat, lon, alt = self.home
        hx, hy, _ = self.frame.from_gps(lat, lon)
        self._mav.home_position_send(
            round(lat * 1e7),
            round(lon * 1e7),
            round(alt * 1000.0),
            hy,  # local NED from the frame origin: north
            hx,  # east
            0.0,
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            0.0,
            0.0,
            round(self.time * 1e6),
        )
