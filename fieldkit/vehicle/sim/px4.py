"""A simulated PX4 multicopter, without I/O: PX4's MAVLink rules over the shared kinematics.

    sim = SimPx4(load_profile("spiri"), home=(45.5017, -73.5673))
    sim.receive_data(bytes_from_the_companion)     # COMMAND_LONG, SET_POSITION_TARGET_*...
    sim.step(0.1)                                  # physics by 0.1 s, telemetry when due
    write(sim.data_to_send())                      # HEARTBEAT, streams, ACKs, STATUSTEXT

No PX4 build runs here (docs/third-party.md#no-autopilot-sitl), so this stands in for PX4
SITL for everything fieldkit's PX4 link does, by the rules of the project's PX4 offboard spec
(docs/vehicles.md#px4-spiri). It is `SimArduPilot` (streams, faults, battery, GPS fix, the
profile's kinematics) with PX4's side of the conversation:

- HEARTBEAT as PX4 sends it: MAV_AUTOPILOT_PX4, `custom_mode = sub << 24 | main << 16`,
  base_mode CUSTOM_MODE_ENABLED plus ARMED, MANUAL_INPUT (stick modes), STABILIZE, and
  AUTO | GUIDED in AUTO modes; system_status STANDBY, ACTIVE, or CRITICAL while a failsafe
  is active. It boots in POSCTL.
- Commands only for system 1 component 1 (or 0), else COMMAND_ACK FAILED; a command from
  PX4's own ids is ignored. Refusals are TEMPORARILY_REJECTED with a STATUSTEXT ("Arming
  denied: GPS fix too low", "Disarming denied: not landed"; DO_SET_MODE refusals are only
  explained to component 190, as PX4 does).
- DO_SET_MODE by main/sub mode (or by the base-mode flags), NAV_TAKEOFF (AUTO.TAKEOFF to
  param7 AMSL or MIS_TAKEOFF_ALT, then AUTO.LOITER), NAV_LAND, NAV_RETURN_TO_LAUNCH,
  DO_REPOSITION (hold at a point), COMPONENT_ARM_DISARM (21196 forces a disarm; arming
  checks run anyway), SET_MESSAGE_INTERVAL, REQUEST_MESSAGE; PARAM_REQUEST_READ/LIST and
  PARAM_SET over `params` (integers bytewise, as PX4).
- OFFBOARD: SET_POSITION_TARGET_LOCAL_NED (frames 1, 8) and _GLOBAL_INT (frames 5, 6, 11)
  with PX4's type_mask rules; each valid one is the offboard signal. The switch (and arming
  in OFFBOARD) is refused unless a setpoint came within COM_OF_LOSS_T and the signal has been
  present `offboard_warmup_s`. Setpoints move the vehicle only in OFFBOARD (velocity and
  acceleration setpoints count as the signal but are not flown: it holds).
- Offboard loss: armed in OFFBOARD with no setpoint for more than COM_OF_LOSS_T, it leaves
  for COM_OBL_RC_ACT's mode (0 Position, 1 Altitude, 2 Stabilized, 3 Return, 4 Land, 5 Hold,
  6 Terminate, 7 Disarm; the first three need an RC, and without one NAV_RCL_ACT decides:
  the spec leaves that end state unverified, this is a model), says so, and reports CRITICAL
  until a new mode is chosen or the signal returns.
- Landing: the land detector disarms COM_DISARM_LAND after touchdown; an armed vehicle that
  does not take off disarms after COM_DISARM_PRFLT.

`fieldkit.vehicle.sim.vehicle.SimPx4Vehicle` puts it on a pty or a URL.
"""

from __future__ import annotations

import math
import struct
from typing import Any, Unpack

from pymavlink.dialects.v20 import all as mavlink2

from fieldkit.robot.profiles import Profile
from fieldkit.robot.script_api import IN_AIR, LANDING, ON_GROUND, TAKING_OFF
from fieldkit.vehicle.px4 import (
    FORCE,
    MAIN_ACRO,
    MAIN_ALTCTL,
    MAIN_AUTO,
    MAIN_MANUAL,
    MAIN_POSCTL,
    MAIN_STABILIZED,
    MODES,
    OFFBOARD,
    custom_mode,
    split_custom_mode,
)
from fieldkit.vehicle.sim.ardupilot import (
    ACCEPTED,
    FAILED,
    UNSUPPORTED,
    SimArduPilot,
    SimOptions,
)

TEMPORARILY_REJECTED = mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
"""COMMAND_ACK result: PX4's "not now" (checks failed, a mode that cannot run)."""

DEFAULT_PARAMS: dict[str, float] = {
    "COM_OF_LOSS_T": 1.0,
    "COM_OBL_RC_ACT": 0,
    "COM_DISARM_PRFLT": 10.0,
    "COM_DISARM_LAND": 2.0,
    "MIS_TAKEOFF_ALT": 2.5,
    "NAV_RCL_ACT": 2,
    "COM_RC_IN_MODE": 0,
}
"""The parameters the simulator has, at PX4's current defaults."""
INT_PARAMS = frozenset({"COM_OBL_RC_ACT", "NAV_RCL_ACT", "COM_RC_IN_MODE"})
"""Those that are INT32 (sent bytewise in PARAM_VALUE's float, as PX4 does)."""

# Modes that take stick input: base_mode MANUAL_INPUT, and they need an RC.
_STICK_MODES = frozenset({"MANUAL", "ALTCTL", "POSCTL", "ACRO", "STABILIZED", "RATTITUDE"})
# Modes that need a position estimate (refused without a GPS fix).
_POSITION_MODES = frozenset(
    {"POSCTL", "OFFBOARD", "TAKEOFF", "LOITER", "MISSION", "RTL", "FOLLOWME", "PRECLAND"}
)
# DO_SET_MODE: custom main modes selected directly, and AUTO's sub modes.
_MAIN_SELECT = {
    MAIN_MANUAL: "MANUAL",
    MAIN_ALTCTL: "ALTCTL",
    MAIN_POSCTL: "POSCTL",
    MAIN_ACRO: "ACRO",
    6: OFFBOARD,
    MAIN_STABILIZED: "STABILIZED",
}
_AUTO_SELECT = {
    0: "MISSION",
    2: "TAKEOFF",
    3: "LOITER",
    4: "MISSION",
    5: "RTL",
    6: "LAND",
    8: "FOLLOWME",
    9: "PRECLAND",
}
# COM_OBL_RC_ACT -> the mode the offboard-loss failsafe selects ("" : kill the motors).
_OBL_MODES = {0: "POSCTL", 1: "ALTCTL", 2: "STABILIZED", 3: "RTL", 4: "LAND", 5: "LOITER"}
_OBL_KILL = (6, 7)
# NAV_RCL_ACT, where an RC-only fallback cannot run: 1 Hold, 2 Return, 3 Land, 5/6 kill.
_RCL_MODES = {0: "LOITER", 1: "LOITER", 2: "RTL", 3: "LAND"}
_MIN_CLIMB_M = 0.1  # an OFFBOARD setpoint this far up lifts an armed vehicle off
_EPS = 1e-9


class SimPx4(SimArduPilot):
    """One simulated PX4 multicopter (a ground profile: a PX4 rover that only drives)."""

    def __init__(
        self,
        profile: Profile,
        *,
        rc: bool = True,
        offboard_warmup_s: float = 1.0,
        **options: Unpack[SimOptions],
    ) -> None:
        """A disarmed PX4 in POSCTL at `home` (options as `SimArduPilot`'s).

        `rc`: whether an RC receiver is present (the stick modes and the offboard-loss
        fallbacks to them need one). OFFBOARD is refused until setpoints have come for
        `offboard_warmup_s` without a gap longer than COM_OF_LOSS_T.
        """
        super().__init__(profile, **options)
        self.mode_numbers = {name: custom_mode(*nums) for name, nums in MODES.items()}
        self.mode = "POSCTL"
        self.rc_present = rc
        self.offboard_warmup_s = offboard_warmup_s
        self.params: dict[str, float] = dict(DEFAULT_PARAMS)
        self.failsafe: str | None = None  # the active failsafe's reason
        self.setpoints = 0  # valid setpoints received
        self.setpoints_dropped = 0  # setpoints PX4 would reject (frame, mask, no position)
        #: The last valid OFFBOARD setpoint: (x east, y north, z up, yaw ENU or None); None
        #: for a velocity or acceleration setpoint (held where the vehicle is).
        self.offboard_target: tuple[float, float, float, float | None] | None = None
        self.last_setpoint: float | None = None  # sim time of the last valid setpoint
        self._signal_since: float | None = None  # start of the unbroken offboard signal
        self._applied: tuple[float, float, float, float | None] | None = None
        self._takeoff_z: float | None = None  # AUTO.TAKEOFF's target, above home
        self._land_disarm_at: float | None = None

    # ------------------------------------------------------------------ views

    @property
    def kind(self) -> str:
        """What it simulates, for a log line."""
        return "PX4 rover" if self.ground else "PX4 multicopter"

    @property
    def custom_mode(self) -> int:
        """PX4's custom_mode of the current mode."""
        return self.mode_numbers[self.mode]

    @property
    def offboard_signal(self) -> bool:
        """Whether PX4 would take OFFBOARD now: a setpoint within COM_OF_LOSS_T, for long
        enough."""
        if self.last_setpoint is None or self._signal_since is None:
            return False
        fresh = self.time - self.last_setpoint <= self._loss_t() + _EPS
        return fresh and self.time - self._signal_since >= self.offboard_warmup_s - _EPS

    def _loss_t(self) -> float:
        value = self.params["COM_OF_LOSS_T"]
        return value if math.isfinite(value) and value >= 0 else 1.0

    # ------------------------------------------------------------------ input

    def _handle(self, msg: Any) -> None:
        name = msg.get_type()
        self.received[name] += 1
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if name == "HEARTBEAT":
            if src != (self.sysid, self.compid):
                self.gcs_heartbeats += 1
                self.last_gcs_heartbeat = self.time
            return
        if src == (self.sysid, self.compid):
            return  # PX4 ignores what claims to come from itself
        if name == "COMMAND_LONG":
            self.commands[msg.command] += 1
            if msg.target_system != self.sysid or msg.target_component not in (0, self.compid):
                self._ack(msg, msg.command, FAILED)  # PX4 answers a wrong target FAILED
                return
            self._ack(msg, msg.command, self._command_long(msg))
        elif name == "COMMAND_INT":
            if msg.target_system == self.sysid:
                self._ack(msg, msg.command, UNSUPPORTED)
        elif name in ("SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT"):
            if msg.target_system in (0, self.sysid) and msg.target_component in (0, self.compid):
                self._setpoint(msg, local=name.endswith("LOCAL_NED"))
        elif name == "SET_MODE":
            if msg.target_system == self.sysid:
                self._ack(msg, mavlink2.MAVLINK_MSG_ID_SET_MODE, self._set_mode_number(
                    msg.custom_mode if msg.base_mode & 1 else -1))  # fmt: skip
        elif name in ("PARAM_REQUEST_READ", "PARAM_REQUEST_LIST", "PARAM_SET"):
            if msg.target_system == self.sysid:
                self._param_message(name, msg)

    def _command_long(self, m: Any) -> int:
        c = m.command
        if c == mavlink2.MAV_CMD_COMPONENT_ARM_DISARM:
            if not (math.isfinite(m.param1) and round(m.param1) in (0, 1)):
                self._text("Unsupported ARM_DISARM param")
                return UNSUPPORTED
            forced = math.isfinite(m.param2) and round(m.param2) == FORCE
            return self._arm(force=forced) if round(m.param1) == 1 else self._disarm(forced)
        if c == mavlink2.MAV_CMD_DO_SET_MODE:
            return self._do_set_mode(m)
        if c == mavlink2.MAV_CMD_NAV_TAKEOFF:
            if self.ground:
                return UNSUPPORTED
            if math.isfinite(m.param7):
                z = m.param7 - self.frame.alt  # AMSL
            else:
                z = self.params["MIS_TAKEOFF_ALT"]
            if not (z > 0.0 and math.isfinite(z)):
                self._text("Takeoff denied: altitude below home")
                return TEMPORARILY_REJECTED
            return self._px4_mode("TAKEOFF", "NAV_TAKEOFF", tell=True, takeoff_z=z)
        if c == mavlink2.MAV_CMD_NAV_LAND:
            return self._px4_mode("LAND", "NAV_LAND", tell=True)
        if c == mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return self._px4_mode("RTL", "NAV_RETURN_TO_LAUNCH", tell=True)
        if c == mavlink2.MAV_CMD_DO_REPOSITION:
            return self._reposition(m)
        if c in (
            mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL,
            mavlink2.MAV_CMD_REQUEST_MESSAGE,
            mavlink2.MAV_CMD_GET_HOME_POSITION,
        ):
            return super()._command_long(m)
        return UNSUPPORTED

    def _do_set_mode(self, m: Any) -> int:
        # PX4 casts params 1-3 to uint8: NaN and the like are garbage, read as 0.
        base, main, sub = (
            int(p) & 0xFF if math.isfinite(p) else 0 for p in (m.param1, m.param2, m.param3)
        )
        tell = m.get_srcComponent() == mavlink2.MAV_COMP_ID_MISSIONPLANNER
        if base & mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            name = _MAIN_SELECT.get(main) if main != MAIN_AUTO else _AUTO_SELECT.get(sub)
            if name is None:
                if tell:
                    self._text("Unsupported auto mode" if main == MAIN_AUTO else "Unknown mode")
                return TEMPORARILY_REJECTED
        elif base & mavlink2.MAV_MODE_FLAG_AUTO_ENABLED:
            name = "MISSION"
        elif base & mavlink2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED:
            if base & mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED:
                name = "POSCTL"
            elif base & mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED:
                name = "STABILIZED"
            else:
                name = "MANUAL"
        else:
            return TEMPORARILY_REJECTED
        return self._px4_mode(name, "GCS", tell=tell)

    def _reposition(self, m: Any) -> int:
        if not (math.isfinite(m.param2) and int(m.param2) & 1):
            return UNSUPPORTED  # PX4 wants MAV_DO_REPOSITION_FLAGS_CHANGE_MODE
        result = self._px4_mode("LOITER", "DO_REPOSITION", tell=True)
        v = self.vehicle
        if result != ACCEPTED or v.status != IN_AIR:
            return result
        if math.isfinite(m.param5) and math.isfinite(m.param6):
            try:
                x, y, _ = self.frame.from_gps(m.param5, m.param6)
            except ValueError:
                return result
            z = m.param7 - self.frame.alt if math.isfinite(m.param7) else v.z
            v.goto(x, y, z if z > 0 else v.z)
        return result

    def _set_mode_number(self, number: int) -> int:
        main, sub = split_custom_mode(number) if number >= 0 else (0, 0)
        name = _MAIN_SELECT.get(main) if main != MAIN_AUTO else _AUTO_SELECT.get(sub)
        if name is None:
            return TEMPORARILY_REJECTED
        return self._px4_mode(name, "GCS", tell=False)

    def _set_mode(self, name: str, by: str) -> int:
        return self._px4_mode(name, by, tell=True)

    def _px4_mode(self, name: str, by: str, *, tell: bool, takeoff_z: float | None = None) -> int:
        """Switch to `name` if it can run now (else TEMPORARILY_REJECTED, said if `tell`);
        `takeoff_z`: AUTO.TAKEOFF's height above home (None: MIS_TAKEOFF_ALT)."""
        if name not in self.mode_numbers:
            return FAILED
        why = self._cannot_run(name)
        if why is not None:
            if tell:
                self._text(f"Mode change to {name} denied: {why}"[:50])
            return TEMPORARILY_REJECTED
        self._takeoff_z = takeoff_z
        if self.failsafe is not None:
            self._note(f"failsafe cleared by a mode change ({by})")
            self.failsafe = None
        if name == self.mode:
            return ACCEPTED
        self._note(f"mode {self.mode} -> {name} ({by})")
        self.mode = name
        self._enter_mode()
        return ACCEPTED

    def _cannot_run(self, name: str) -> str | None:
        """Why mode `name` cannot run now (PX4's mode requirements), or None."""
        if name in _POSITION_MODES and self.gps_fix_type < 3:
            return "no position"
        if name in _STICK_MODES and not self.rc_present:
            return "no RC"
        if name == OFFBOARD and not self.offboard_signal:
            return "no offboard signal"
        if name == "MISSION":
            return "no valid mission"
        if name in ("FOLLOWME", "PRECLAND"):
            return "not available"
        return None

    def _arm(self, force: bool) -> int:
        v = self.vehicle
        if v.armed:
            return ACCEPTED
        # Over MAVLink PX4 runs its checks even when forced.
        if self.gps_fix_type < 3 and self.mode in _POSITION_MODES | {"LAND"}:
            self._text("Arming denied: GPS fix too low")
            return TEMPORARILY_REJECTED
        why = self._cannot_run(self.mode)
        if why is not None:
            self._text(f"Arming denied: {why}")
            return TEMPORARILY_REJECTED
        if self.mode in ("RTL", "LAND"):
            self._text(f"Arming denied: mode {self.mode} cannot arm")
            return TEMPORARILY_REJECTED
        if not v.arm():
            self._text("Arming denied: battery too low")
            return TEMPORARILY_REJECTED
        self._landed_armed_s = 0.0
        self._land_disarm_at = None
        if self.gps_fix_type >= 3:
            self._set_home()  # PX4 sets home where it arms
        self._note(f"armed in {self.mode}")
        if self.mode == "TAKEOFF":
            self._enter_mode()
        elif self.mode == OFFBOARD:
            self._applied = None
            self._apply_offboard()
        return ACCEPTED

    def _disarm(self, force: bool) -> int:
        v = self.vehicle
        if not v.armed:
            return ACCEPTED
        if not self.ground and v.status != ON_GROUND and not force:
            self._text("Disarming denied: not landed")
            return TEMPORARILY_REJECTED
        return super()._disarm(force)

    # ------------------------------------------------------------------ setpoints

    def _setpoint(self, m: Any, *, local: bool) -> None:
        """A SET_POSITION_TARGET_*: PX4's rules decide whether it is a valid offboard signal."""
        mask, frame = m.type_mask, m.coordinate_frame
        vel = any(not mask & bit for bit in (8, 16, 32))
        acc = any(not mask & bit for bit in (64, 128, 256))
        if acc and mask & 512:
            return self._drop("force setpoint not supported")
        x, y, z = self._target_or_here()
        if local:
            if frame not in (mavlink2.MAV_FRAME_LOCAL_NED, mavlink2.MAV_FRAME_BODY_NED):
                return self._drop("SET_POSITION_TARGET_LOCAL_NED: unsupported frame")
            uses = [not mask & 1, not mask & 2, not mask & 4]
            if frame == mavlink2.MAV_FRAME_BODY_NED:
                uses = [False, False, False]  # positions are ignored in the body frame
            values = (m.x, m.y, m.z)
            if any(u and not math.isfinite(val) for u, val in zip(uses, values, strict=True)):
                return self._drop(None)
            if uses[0]:
                y = m.x  # north
            if uses[1]:
                x = m.y  # east
            if uses[2]:
                z = -m.z  # down from the origin: home's altitude
            position = any(uses)
        else:
            if frame not in (
                mavlink2.MAV_FRAME_GLOBAL_INT,
                mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
            ):
                return self._drop("SET_POSITION_TARGET_GLOBAL_INT: unsupported frame")
            position = not mask & 7  # all of x, y and z, or no position
            if position:
                if self.gps_fix_type < 3 or not math.isfinite(m.alt):
                    return self._drop(None)  # no global reference: silently dropped
                try:
                    x, y, _ = self.frame.from_gps(m.lat_int * 1e-7, m.lon_int * 1e-7)
                except ValueError:
                    return self._drop(None)
                z = m.alt - self.frame.alt if frame == mavlink2.MAV_FRAME_GLOBAL_INT else m.alt
        if not (position or vel or acc):
            return self._drop("offboard setpoint invalid")
        yaw = None if mask & 1024 or not math.isfinite(m.yaw) else math.pi / 2 - m.yaw
        self.setpoints += 1
        if self.last_setpoint is None or self.time - self.last_setpoint > self._loss_t() + _EPS:
            self._signal_since = self.time
        self.last_setpoint = self.time
        if self.failsafe == "offboard signal lost":
            self._note("offboard signal back: failsafe over (the mode stays)")
            self.failsafe = None
        if self.ground:
            z = 0.0
        self.offboard_target = (x, y, z, yaw) if position else None
        if self.mode == OFFBOARD:
            self._apply_offboard()

    def _target_or_here(self) -> tuple[float, float, float]:
        """Where an offboard setpoint's unused axes stay: the last target, else here."""
        if self.offboard_target is not None:
            return self.offboard_target[:3]
        v = self.vehicle
        return v.x, v.y, v.z

    def _drop(self, text: str | None) -> None:
        self.setpoints_dropped += 1
        if text is not None:
            self._text(text)

    def _apply_offboard(self) -> None:
        """Fly the OFFBOARD setpoint (armed, in OFFBOARD), once per new setpoint."""
        v = self.vehicle
        if self.mode != OFFBOARD or not v.armed:
            return
        target = self.offboard_target
        if target is None:
            if self._applied is not None or v.status == IN_AIR:
                v.hold()
            self._applied = None
            return
        if target == self._applied and v.status != ON_GROUND:
            return
        self._applied = target
        x, y, z, yaw = target
        if self.ground:
            v.goto(x, y)
        elif v.status == ON_GROUND:
            if z >= _MIN_CLIMB_M and v.takeoff(z):
                self._pending_target = (x, y, z, yaw)
                self._note(f"offboard climb to {z:.1f} m")
        elif v.status == TAKING_OFF:
            self._pending_target = (x, y, z, yaw)
        elif z < _MIN_CLIMB_M:
            v.land()
        else:
            if v.status == LANDING:
                v.hold()
            v.goto(x, y, z, yaw)

    # ------------------------------------------------------------------ parameters

    def _param_message(self, name: str, m: Any) -> None:
        if name == "PARAM_REQUEST_LIST":
            for index in range(len(self.params)):
                self._send_param(index)
            return
        pid = m.param_id if isinstance(m.param_id, str) else bytes(m.param_id).decode("latin-1")
        pid = pid.split("\x00", 1)[0]
        names = list(self.params)
        if name == "PARAM_REQUEST_READ":
            if pid in self.params:
                self._send_param(names.index(pid))
            elif 0 <= m.param_index < len(names) and not pid:
                self._send_param(m.param_index)
            return
        if pid not in self.params:
            return  # PX4 ignores a PARAM_SET of an unknown parameter
        value = m.param_value
        if pid in INT_PARAMS:
            value = struct.unpack("<i", struct.pack("<f", value))[0]
        elif not math.isfinite(value):
            return
        self.params[pid] = value
        self._note(f"param {pid} = {value:g}")
        self._send_param(names.index(pid))

    def _send_param(self, index: int) -> None:
        name = list(self.params)[index]
        value = self.params[name]
        if name in INT_PARAMS:
            wire = struct.unpack("<f", struct.pack("<i", int(value)))[0]
            kind = mavlink2.MAV_PARAM_TYPE_INT32
        else:
            wire, kind = float(value), mavlink2.MAV_PARAM_TYPE_REAL32
        self._mav.param_value_send(name.encode("ascii"), wire, kind, len(self.params), index)

    # ------------------------------------------------------------------ physics and modes

    def _enter_mode(self) -> None:
        """What a new mode does at once to the motion."""
        v = self.vehicle
        self._pending_target = None
        self._applied = None
        if self.mode == "TAKEOFF":
            if v.armed and v.status == ON_GROUND and not self.ground:
                z = self._takeoff_z if self._takeoff_z is not None else self.params[
                    "MIS_TAKEOFF_ALT"]  # fmt: skip
                if v.takeoff(z):
                    self._note(f"takeoff to {z:g} m")
            elif v.status == IN_AIR:
                v.hold()
            return
        flying = v.flying if not self.ground else v.armed
        if not flying:
            return
        if self.mode == "LAND" and not self.ground:
            v.land()
        elif self.mode == "RTL":
            hx, hy, _ = self.frame.from_gps(*self.home[:2]) if self.home else (0.0, 0.0, 0.0)
            v.return_home(hx, hy, self.rtl_alt_m)
        elif self.mode == OFFBOARD:
            self._apply_offboard()
        else:
            v.hold()  # Hold, and the stick modes with the sticks centred

    def _control(self, dt: float) -> None:
        prflt = self.params["COM_DISARM_PRFLT"]
        self.auto_disarm_s = prflt if math.isfinite(prflt) and prflt > 0 else None
        v = self.vehicle
        super()._control(dt)
        if self.mode == "TAKEOFF" and v.status == IN_AIR and v.settled:
            self._note("takeoff done: mode TAKEOFF -> LOITER (auto)")
            self.mode = "LOITER"
            v.hold()
        if self._land_disarm_at is not None and self.time + _EPS >= self._land_disarm_at:
            self._land_disarm_at = None
            if v.armed and v.status == ON_GROUND:
                v.disarm()
                self._note("landed: disarmed (COM_DISARM_LAND)")
        if (
            self.mode == OFFBOARD
            and v.armed
            and self.failsafe is None
            and (self.last_setpoint is None or self.time - self.last_setpoint > self._loss_t())
        ):
            self._offboard_lost()

    def _offboard_lost(self) -> None:
        """PX4's offboard-loss failsafe: COM_OBL_RC_ACT's mode, or NAV_RCL_ACT's without RC."""
        action = int(self.params["COM_OBL_RC_ACT"])
        mode = _OBL_MODES.get(action)
        kill = action in _OBL_KILL
        if mode is not None and mode in _STICK_MODES and not self.rc_present:
            rcl = int(self.params["NAV_RCL_ACT"])
            mode, kill = _RCL_MODES.get(rcl), rcl in (5, 6)
        self.failsafe = "offboard signal lost"
        if kill or mode is None:
            self._text("Failsafe: no offboard signal, terminating")
            self._disarm(True)
            return
        if self._cannot_run(mode) is not None:
            mode = "LAND"  # PX4's last fallback: land where it is
        self._text(f"Failsafe: no offboard signal, {mode}")
        self._note(f"mode {self.mode} -> {mode} (failsafe)")
        self.mode = mode
        self._enter_mode()

    def _touchdown(self) -> None:
        """The land detector saw the ground: motors idle, disarmed after COM_DISARM_LAND."""
        v = self.vehicle
        v.armed = True  # the kinematics disarm at touchdown; PX4 waits
        delay = self.params["COM_DISARM_LAND"]
        self._land_disarm_at = self.time + (delay if math.isfinite(delay) and delay > 0 else 0)
        self._note("touchdown")

    # ------------------------------------------------------------------ telemetry

    def _send_heartbeat(self) -> None:
        v = self.vehicle
        main, _ = MODES[self.mode]
        base = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if v.armed:
            base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        if self.mode in _STICK_MODES:
            base |= mavlink2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        if main == MAIN_AUTO:
            base |= (
                mavlink2.MAV_MODE_FLAG_AUTO_ENABLED
                | mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
                | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
            )
        elif self.mode != "ACRO":
            base |= mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
        if not v.armed:
            state = mavlink2.MAV_STATE_STANDBY
        elif self.failsafe is not None:
            state = mavlink2.MAV_STATE_CRITICAL
        else:
            state = mavlink2.MAV_STATE_ACTIVE
        self._mav.heartbeat_send(
            self.mav_type, mavlink2.MAV_AUTOPILOT_PX4, base, self.custom_mode, state
        )

    def _send_extended_sys_state(self) -> None:
        v = self.vehicle
        status = mavlink2.MAV_LANDED_STATE_ON_GROUND if self.ground else v.status
        if status == TAKING_OFF and self.mode != "TAKEOFF":
            status = IN_AIR  # PX4 says TAKEOFF/LANDING only for AUTO's own setpoints
        elif status == LANDING and self.mode not in ("LAND", "RTL"):
            status = IN_AIR
        self._mav.extended_sys_state_send(mavlink2.MAV_VTOL_STATE_UNDEFINED, status)

    def _send_rc_channels(self) -> None:
        if self.rc_present:
            super()._send_rc_channels()
