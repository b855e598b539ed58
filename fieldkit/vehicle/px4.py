"""PX4 from a companion computer: its custom modes, and `Px4Core`, OFFBOARD flight without I/O.

PX4 speaks the same MAVLink as ArduPilot but flies otherwise, so `Px4Core` is the MAVLink core
(`fieldkit.vehicle.autopilot.AutopilotCore`: telemetry, ACK-checked and retried commands,
events) with PX4's own conversation on top (docs/vehicles.md#px4-spiri; the facts are
PX4's, gathered in the project's PX4 offboard spec):

- **Modes** are a main mode and, for AUTO, a sub mode: `custom_mode = sub << 24 | main << 16`
  in the HEARTBEAT, and DO_SET_MODE with param1 1 (custom), param2 main, param3 sub
  (`MODES`, `custom_mode`, `mode_name`). Hold, land and return are PX4's own AUTO.LOITER,
  AUTO.LAND and AUTO.RTL.
- **OFFBOARD** only starts, and only stays, while position setpoints keep coming. The core
  streams SET_POSITION_TARGET_GLOBAL_INT (MAV_FRAME_GLOBAL_INT: AMSL altitude, the frame the
  spec recommends) from `tick()`, every `setpoint_interval_s` of the link clock, whatever
  rate the node gives orders at; `goto` only changes the setpoint (and sends it at once).
  The switch to OFFBOARD is held back until the stream has run `offboard_warmup_s`.
- **Take-off** is PX4's offboard take-off: stream "here, `alt` above home", switch to
  OFFBOARD, arm; PX4 climbs to the setpoint and the node stays in control.
- **Refusals**: PX4 answers TEMPORARILY_REJECTED and says why in a STATUSTEXT ("Arming
  denied: ..."); the failed command carries both.
- **Leaving OFFBOARD by itself** (the stream stopped past COM_OF_LOSS_T, the pilot's switch,
  a failsafe) is an `override` event that says why, and the node never switches back behind
  the pilot's back: the stream stops, `goto` is refused (quietly, it comes every tick) until
  the node asks again with `takeoff` or `set_mode("OFFBOARD")`.

    core = Px4Core(profile=load_profile("spiri"), clock=clock)
    core.receive_data(line_bytes)
    core.takeoff(3.0)                # stream, OFFBOARD after the warm-up, arm
    core.goto(lat, lon, 3.0)         # the streamed setpoint moves
    core.tick()                      # the stream, retries, our heartbeat
    write(core.data_to_send())
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Unpack

from pymavlink.dialects.v20 import all as mavlink2

from fieldkit.vehicle.autopilot import (
    MAX_ALTITUDE_M,
    AutopilotCore,
    CoreOptions,
    MavCommand,
    _Step,
    clock_reading,
)

if TYPE_CHECKING:
    from fieldkit.vehicle.core import VehicleCore

COMPANION_SYSTEM = 1
"""Our system id toward PX4: the vehicle's own (MAVSDK's companion default)."""
COMPANION_COMPONENT = mavlink2.MAV_COMP_ID_PATHPLANNER
"""Our component id (195): MAVSDK's companion default; never PX4's own 1, which PX4 ignores."""
FORCE = 21196
"""COMPONENT_ARM_DISARM param2 that forces (PX4 still runs its arming checks over MAVLink)."""
TEMPORARILY_REJECTED = mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
"""PX4's COMMAND_ACK result for "not now": arming checks, a mode that cannot run."""

#: PX4 main modes (HEARTBEAT custom_mode byte 2).
MAIN_MANUAL, MAIN_ALTCTL, MAIN_POSCTL, MAIN_AUTO, MAIN_ACRO, MAIN_OFFBOARD = 1, 2, 3, 4, 5, 6
MAIN_STABILIZED, MAIN_RATTITUDE = 7, 8

MODES: dict[str, tuple[int, int]] = {
    "MANUAL": (MAIN_MANUAL, 0),
    "ALTCTL": (MAIN_ALTCTL, 0),
    "POSCTL": (MAIN_POSCTL, 0),
    "ORBIT": (MAIN_POSCTL, 1),
    "READY": (MAIN_AUTO, 1),
    "TAKEOFF": (MAIN_AUTO, 2),
    "LOITER": (MAIN_AUTO, 3),
    "MISSION": (MAIN_AUTO, 4),
    "RTL": (MAIN_AUTO, 5),
    "LAND": (MAIN_AUTO, 6),
    "FOLLOWME": (MAIN_AUTO, 8),
    "PRECLAND": (MAIN_AUTO, 9),
    "VTOL_TAKEOFF": (MAIN_AUTO, 10),
    **{f"EXTERNAL{k}": (MAIN_AUTO, 10 + k) for k in range(1, 9)},
    "ACRO": (MAIN_ACRO, 0),
    "OFFBOARD": (MAIN_OFFBOARD, 0),
    "STABILIZED": (MAIN_STABILIZED, 0),
    "RATTITUDE": (MAIN_RATTITUDE, 0),
}
"""PX4's flight modes by pymavlink's names (the profiles' `*_mode`): (main, sub)."""

SETTABLE: frozenset[str] = frozenset(
    {"MANUAL", "ALTCTL", "POSCTL", "ACRO", "OFFBOARD", "STABILIZED"}
    | {"TAKEOFF", "LOITER", "MISSION", "RTL", "LAND", "FOLLOWME", "PRECLAND"}
)
"""The modes PX4's DO_SET_MODE selects (READY, ORBIT, VTOL_TAKEOFF come otherwise)."""

_BY_NUMBERS = {numbers: name for name, numbers in MODES.items()}
# Only AUTO and POSCTL have sub modes: PX4 leaves the sub byte 0 elsewhere, ignore it there.
_WITH_SUB = (MAIN_AUTO, MAIN_POSCTL)

OFFBOARD = "OFFBOARD"
"""The mode the node flies PX4 in."""

#: Parameters read at start-up (PARAM_REQUEST_READ), to explain and respect PX4's rules.
PARAMS = (
    "COM_OF_LOSS_T",
    "COM_OBL_RC_ACT",
    "COM_DISARM_PRFLT",
    "MIS_TAKEOFF_ALT",
    "COM_RC_IN_MODE",
)
#: COM_OF_LOSS_T's default (v1.12 on): seconds without a setpoint before PX4 leaves OFFBOARD.
DEFAULT_OF_LOSS_T = 1.0
#: What COM_OBL_RC_ACT makes PX4 do when the offboard signal is lost (v1.14+).
OBL_ACTIONS = {
    0: "Position mode",
    1: "Altitude mode",
    2: "Stabilized mode",
    3: "Return",
    4: "Land",
    5: "Hold",
    6: "Terminate",
    7: "Disarm",
}

# SET_POSITION_TARGET type_mask (1 = ignore): position only, and position + yaw.
MASK_POSITION = 0x0DF8
MASK_POSITION_YAW = 0x09F8
# Seconds a recorded break in our stream still explains PX4 leaving OFFBOARD.
_GAP_MEMORY_S = 5.0
_STATUSTEXT_WINDOW_S = 2.0
# An AMSL altitude beyond this is no reference (a hostile GLOBAL_POSITION_INT made it).
_MAX_AMSL_M = 1e6


def custom_mode(main: int, sub: int = 0) -> int:
    """The HEARTBEAT custom_mode of a PX4 main and sub mode."""
    return (sub & 0xFF) << 24 | (main & 0xFF) << 16


def split_custom_mode(value: int) -> tuple[int, int]:
    """(main, sub) of a HEARTBEAT custom_mode."""
    return (value >> 16) & 0xFF, (value >> 24) & 0xFF


def mode_name(value: int) -> str:
    """A custom_mode's name ("OFFBOARD", "LOITER"...), or e.g. "PX4(4.7)" for an unknown one."""
    main, sub = split_custom_mode(value)
    name = _BY_NUMBERS.get((main, sub if main in _WITH_SUB else 0))
    return name if name is not None else f"PX4({main}.{sub})"


def set_mode_params(name: str) -> tuple[float, float, float] | None:
    """DO_SET_MODE's params 1-3 for a mode PX4 lets a command select, or None."""
    if name not in SETTABLE:
        return None
    main, sub = MODES[name]
    return float(mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub)


def param_value(msg: Any) -> float | None:
    """A PARAM_VALUE's number: PX4 sends integers bytewise (the int32's bytes in the float)."""
    value = msg.param_value
    if msg.param_type in (mavlink2.MAV_PARAM_TYPE_INT32, mavlink2.MAV_PARAM_TYPE_UINT32):
        fmt = "<i" if msg.param_type == mavlink2.MAV_PARAM_TYPE_INT32 else "<I"
        return float(struct.unpack(fmt, struct.pack("<f", value))[0])
    return float(value) if math.isfinite(value) else None  # PX4 has REAL32 besides INT32


def param_name(msg: Any) -> str:
    """A PARAM_VALUE's parameter id as text."""
    raw = msg.param_id
    text = raw if isinstance(raw, str) else bytes(raw).decode("ascii", "replace")
    return text.split("\x00", 1)[0]


class Px4Core(AutopilotCore):
    """The node's MAVLink conversation with PX4: OFFBOARD setpoints streamed from `tick()`."""

    def __init__(
        self,
        *,
        url: str = "autopilot",
        setpoint_interval_s: float = 0.05,
        offboard_warmup_s: float = 1.2,
        **options: Unpack[CoreOptions],
    ) -> None:
        """A PX4 link that has heard nothing yet (options as `AutopilotCore`'s).

        The stream sends a setpoint every `setpoint_interval_s` (20 Hz, as MAVSDK; at most
        once per `tick()`, so the poll rate bounds it: the node polls at its loop rate, and PX4
        needs more than 2 Hz). OFFBOARD is asked for once the stream has run
        `offboard_warmup_s` (PX4 wants the signal for more than 1 s; the rest is margin for
        the line). Our identity is MAVSDK's companion, system 1 component 195, unless given.
        """
        options.setdefault("source_system", COMPANION_SYSTEM)
        options.setdefault("source_component", COMPANION_COMPONENT)
        super().__init__(url=url, **options)
        self.setpoint_interval_s = setpoint_interval_s
        self.offboard_warmup_s = offboard_warmup_s
        self.params: dict[str, float] = {}  # PX4 parameters read back (PARAMS)
        #: The streamed setpoint: (lat, lon, metres above home, yaw in degrees or None).
        self.setpoint: tuple[float, float, float, float | None] | None = None
        #: Why PX4 left OFFBOARD without the node; while set, `goto` does not take it back.
        self.offboard_lost: str | None = None
        self.setpoints_sent = 0
        self._stream_since: float | None = None  # start of the unbroken stream
        self._last_setpoint: float | None = None  # link clock of the last setpoint sent
        self._stream_gap: tuple[float, float] | None = None  # (when, seconds) of a break
        self._no_reference_told = False

    # ------------------------------------------------------------------ views

    @property
    def offboard_loss_s(self) -> float:
        """COM_OF_LOSS_T as read from PX4 (its default until then)."""
        value = self.params.get("COM_OF_LOSS_T", DEFAULT_OF_LOSS_T)
        return value if math.isfinite(value) and value > 0 else DEFAULT_OF_LOSS_T

    @property
    def streaming(self) -> bool:
        """Whether a setpoint is being streamed."""
        return self.setpoint is not None

    def stream_age(self, now: float | None = None) -> float:
        """Seconds the current setpoint stream has run unbroken (0 when none)."""
        if self._stream_since is None or self.setpoint is None:
            return 0.0
        return max(0.0, (self._clock() if now is None else now) - self._stream_since)

    def time_state(self) -> dict[str, object]:
        """`AutopilotCore.time_state` plus the setpoint stream's clock readings."""
        state = super().time_state()
        state["last_setpoint"] = self._last_setpoint
        state["stream_since"] = self._stream_since
        return state

    def set_time_state(self, state: dict[str, object]) -> None:
        """Restore `time_state()`'s readings."""
        super().set_time_state(state)
        self._last_setpoint = clock_reading(state, "last_setpoint")
        self._stream_since = clock_reading(state, "stream_since")

    # ------------------------------------------------------------------ time and bytes

    def _tick(self, now: float) -> None:
        # The stream first: an OFFBOARD switch waiting on it sees this tick's setpoint.
        if self.setpoint is not None and (
            self._last_setpoint is None
            or now - self._last_setpoint >= self.setpoint_interval_s - 1e-9
        ):
            self._send_setpoint(now)
        super()._tick(now)

    def send_heartbeat(self) -> None:
        """Our heartbeat now: an onboard controller (MAV_TYPE 18), as PX4's companion."""
        self._last_hb_sent = self._clock()
        self._mav.heartbeat_send(
            mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
            mavlink2.MAV_AUTOPILOT_INVALID,
            0,
            0,
            mavlink2.MAV_STATE_ACTIVE,
        )

    def _home_amsl(self) -> float | None:
        """Home's altitude above mean sea level: what turns "above home" into frame 5's AMSL."""
        t = self.telemetry
        if t.alt_msl_m is not None and t.alt_rel_m is not None:
            return t.alt_msl_m - t.alt_rel_m
        return t.home[2] if t.home is not None else None

    def _setpoint_amsl(self) -> float | None:
        """The setpoint's altitude above mean sea level, or None without a usable reference."""
        home = self._home_amsl()
        if self.setpoint is None or home is None:
            return None
        amsl = home + self.setpoint[2]
        return amsl if abs(amsl) <= _MAX_AMSL_M else None

    def _send_setpoint(self, now: float) -> bool:
        """Send the setpoint now (False, and an event once, without an altitude reference)."""
        assert self.setpoint is not None
        lat, lon, alt, yaw_deg = self.setpoint
        amsl = self._setpoint_amsl()
        if amsl is None or self.target_system is None:
            if not self._no_reference_told:
                self._no_reference_told = True
                self._event("link", f"{self.url}: setpoint not sent: no altitude reference yet")
            return False
        self._no_reference_told = False
        last = self._last_setpoint
        if last is not None:
            gap = now - last
            loss = self.offboard_loss_s
            if gap > loss:
                self._stream_gap = (now, gap)
                self._stream_since = now  # a broken stream starts again: so does the warm-up
            if gap > loss * 0.5 and self.telemetry.mode == OFFBOARD and self.telemetry.armed:
                self._event(
                    "link",
                    f"{self.url}: setpoint stream paused {gap:.1f} s in OFFBOARD (PX4 leaves "
                    f"OFFBOARD after COM_OF_LOSS_T = {loss:g} s)",
                )
        else:
            self._stream_since = now
        boot_ms = int((now - self._t0) * 1000) & 0xFFFFFFFF
        self._mav.set_position_target_global_int_send(
            boot_ms,
            self.target_system,
            self.target_component or 0,
            mavlink2.MAV_FRAME_GLOBAL_INT,
            MASK_POSITION if yaw_deg is None else MASK_POSITION_YAW,
            int(round(lat * 1e7)),
            int(round(lon * 1e7)),
            float(amsl),
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0 if yaw_deg is None or not math.isfinite(yaw_deg) else math.radians(yaw_deg),
            0.0,
        )
        self._last_setpoint = now
        self.setpoints_sent += 1
        return True

    def _start_stream(self, lat: float, lon: float, alt: float, yaw_deg: float | None) -> bool:
        """Stream this setpoint from now on (sent at once); False without a reference."""
        self.setpoint = (lat, lon, alt, yaw_deg)
        return self._send_setpoint(self._clock())

    def _stop_stream(self) -> None:
        """No more setpoints (PX4 has its own mode now, or the pilot has the vehicle)."""
        self.setpoint = None
        self._stream_since = None
        self._last_setpoint = None

    def _stream_ready(self, now: float) -> bool:
        """Whether the stream has run long enough for PX4 to accept OFFBOARD."""
        return (
            self.setpoint is not None
            and self._last_setpoint is not None
            and now - self._last_setpoint <= self.offboard_loss_s
            and self.stream_age(now) >= self.offboard_warmup_s - 1e-9
        )

    # ------------------------------------------------------------------ incoming

    def _handle(self, msg: Any, now: float) -> None:
        super()._handle(msg, now)
        if msg.get_type() == "PARAM_VALUE" and msg.get_srcSystem() == self.target_system:
            name = param_name(msg)
            if name in PARAMS:
                value = param_value(msg)
                if value is not None:
                    self.params[name] = value

    def _mode_name(self, m: Any) -> str:
        return mode_name(m.custom_mode)

    def _mode_taken(self, mode: str, now: float) -> str:
        if self._commanded_mode != OFFBOARD:
            return super()._mode_taken(mode, now)
        reason = self._offboard_loss_reason(now)
        self.offboard_lost = f"now in {mode}: {reason}"
        self._stop_stream()
        # A switch to OFFBOARD still on its way (a retry, a take-off's) would fight the
        # pilot: it is given up.
        label = f"mode {OFFBOARD}"
        for cmd in self.pending:
            if any(step.label == label for step in cmd._steps[cmd._index :]):
                self.cancel(cmd, f"PX4 left OFFBOARD for {mode}: not switching back")
        return (
            f"PX4 left OFFBOARD for {mode} without the node: {reason}; the node will not "
            "switch back (the pilot has it, or a new takeoff/set_mode OFFBOARD)"
        )

    def _offboard_loss_reason(self, now: float) -> str:
        """Why PX4 most likely left OFFBOARD, from what the link saw."""
        t = self.telemetry
        why: list[str] = []
        loss = self.offboard_loss_s
        gap = None
        if self._last_setpoint is not None and now - self._last_setpoint > loss:
            gap = now - self._last_setpoint
        elif self._stream_gap is not None and now - self._stream_gap[0] <= _GAP_MEMORY_S:
            gap = self._stream_gap[1]
        if gap is not None:
            action = self.params.get("COM_OBL_RC_ACT")
            then = "" if action is None else f", COM_OBL_RC_ACT {action:g}: "
            then += OBL_ACTIONS.get(int(action), "") if action is not None else ""
            why.append(
                f"offboard signal lost: no setpoint for {gap:.1f} s > COM_OF_LOSS_T "
                f"{loss:g} s{then}"
            )
        if t.rc_override:
            i = self.override_channel - 1
            pwm = t.rc_channels[i] if 0 <= i < len(t.rc_channels) else "?"
            why.append(f"the pilot's switch (RC channel {self.override_channel} at {pwm} us)")
        if t.system_status == mavlink2.MAV_STATE_CRITICAL:
            why.append("PX4 reports a failsafe (system status CRITICAL)")
        texts = [txt for at, txt in self._statustexts if now - at <= _STATUSTEXT_WINDOW_S]
        if texts:
            why.append(f'PX4 says "{texts[-1]}"')
        return "; ".join(why) if why else "the pilot's mode switch or a PX4 failsafe"

    # ------------------------------------------------------------------ commands

    def _mode_step(self, name: str) -> _Step | str:
        params = set_mode_params(name)
        if params is None:
            known = ", ".join(sorted(SETTABLE))
            return f"unknown PX4 mode {name!r} (DO_SET_MODE selects: {known})"
        if name == OFFBOARD and self.setpoint is None:
            return "PX4 refuses OFFBOARD without a setpoint stream: goto() or takeoff() first"

        def accepted() -> None:
            self._commanded_mode = name
            self.mode_override = False
            if name == OFFBOARD:
                self.offboard_lost = None
            else:
                self._stop_stream()  # PX4 flies its own mode now: only after its ACK

        step = self._long_step(mavlink2.MAV_CMD_DO_SET_MODE, params, on_accept=accepted)
        step.label = f"mode {name}"
        if name == OFFBOARD:
            step.ready = self._stream_ready
            step.waiting_for = f"a setpoint stream of {self.offboard_warmup_s:g} s"
        return step

    def arm(
        self, *, force: bool = False, on_done: Callable[[MavCommand], None] | None = None
    ) -> MavCommand:
        """Arm the motors (`force`: PX4's 21196, though its checks still run over MAVLink)."""
        step = self._long_step(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, (1, FORCE if force else 0))
        return self._new("arm", [step], on_done)

    def takeoff(
        self, alt: float, *, on_done: Callable[[MavCommand], None] | None = None
    ) -> MavCommand:
        """Offboard take-off to `alt` metres above home: stream "here at `alt`", switch to
        OFFBOARD once the stream has run `offboard_warmup_s`, arm; PX4 climbs to the setpoint."""
        name = f"takeoff {alt:g}"
        t = self.telemetry
        if self.ground:
            who = self.profile.name if self.profile is not None else "this vehicle"
            return self._refused(name, f"{who} is a ground robot: it does not fly", on_done)
        if not (math.isfinite(alt) and 0.0 < alt <= MAX_ALTITUDE_M):
            return self._refused(name, f"altitude must be > 0 m, got {alt}", on_done)
        if self.target_system is None:
            return self._refused(name, "no heartbeat from the autopilot yet", on_done)
        if t.lat is None or t.lon is None or self._home_amsl() is None:
            return self._refused(name, "position unknown (no GLOBAL_POSITION_INT yet)", on_done)
        if t.armed and t.landed_state not in (None, mavlink2.MAV_LANDED_STATE_ON_GROUND):
            return self._refused(name, "already in the air", on_done)
        self.offboard_lost = None  # the node asks again: OFFBOARD is its to take
        self._start_stream(t.lat, t.lon, alt, None)
        mode = self._mode_step(OFFBOARD)
        assert not isinstance(mode, str)  # the stream is there
        arm = self._long_step(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, (1, 0))

        def finished(cmd: MavCommand) -> None:
            if not cmd.ok and not self.telemetry.armed and self._commanded_mode != OFFBOARD:
                self._stop_stream()  # nothing flies it: no stream on the ground
            if on_done is not None:
                on_done(cmd)

        return self._new(name, [mode, arm], finished)

    def goto(
        self,
        lat: float,
        lon: float,
        alt: float,
        *,
        yaw_deg: float | None = None,
        on_done: Callable[[MavCommand], None] | None = None,
    ) -> MavCommand:
        """Move the streamed setpoint to an absolute point (`alt` above home), sent at once.

        In the air but out of OFFBOARD by the node's own doing (a hold), the switch back is
        queued behind the stream's warm-up. After PX4 left OFFBOARD by itself, refused
        (without an event: the node sends one every tick) until the node asks again.
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
        if self.offboard_lost is not None:
            return self._over_at_once(
                name, on_done, f"{name} refused: PX4 left OFFBOARD ({self.offboard_lost})"
            )
        if self.ground:
            alt = 0.0
        if not self._start_stream(lat, lon, alt, yaw_deg):
            self.setpoint = None
            return self._refused(name, "no altitude reference yet (no position)", on_done)
        self.last_target = (lat, lon, alt)
        if self._should_engage():
            step = self._mode_step(OFFBOARD)
            assert not isinstance(step, str)  # the stream is there
            self._new("offboard", [step], None)
        return self._over_at_once(name, on_done)

    def _should_engage(self) -> bool:
        """Whether a goto should take the vehicle (back) into OFFBOARD: it flies (a ground
        robot: it is armed), in a mode the node chose, and no OFFBOARD switch is on its way."""
        t = self.telemetry
        if t.mode == OFFBOARD or self._commanded_mode == OFFBOARD:
            return False  # there, or asked for and accepted (the heartbeat comes at 1 Hz)
        if not t.armed or self._commanded_mode is None or self.mode_override or t.rc_override:
            return False  # not flying, or in a mode the node never chose: the pilot's
        if not self.ground and t.landed_state != mavlink2.MAV_LANDED_STATE_IN_AIR:
            return False  # on the ground, taking off or landing: takeoff() is for that
        label = f"mode {OFFBOARD}"
        return not any(
            step.label == label for cmd in self.pending for step in cmd._steps[cmd._index :]
        )

    def request_streams(
        self, rate_hz: float, *, on_done: Callable[[MavCommand], None] | None = None
    ) -> MavCommand:
        """Read PX4's offboard parameters (PARAM_REQUEST_READ, answered by PARAM_VALUE), then
        ask for the telemetry at `rate_hz` by SET_MESSAGE_INTERVAL (PX4 has no data streams;
        a refusal of one of these is only a warning on the command)."""
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            return self._refused("request_streams", f"rate must be > 0 Hz, got {rate_hz}", on_done)
        steps = [self._param_step(p) for p in PARAMS] + self._interval_steps(rate_hz)
        return self._new(f"request_streams {rate_hz:g} Hz", steps, on_done)

    def _param_step(self, name: str) -> _Step:
        def send(confirmation: int) -> None:
            self._mav.param_request_read_send(
                self.target_system or 0, self.target_component or 0, name.encode("ascii"), -1
            )

        return _Step(f"PARAM_REQUEST_READ {name}", send, None)


if TYPE_CHECKING:

    def _conforms(core: Px4Core) -> VehicleCore:
        """mypy proves here that `Px4Core` offers the vehicle interface."""
        return core


__all__ = [
    "COMPANION_COMPONENT",
    "COMPANION_SYSTEM",
    "MODES",
    "OFFBOARD",
    "PARAMS",
    "Px4Core",
    "SETTABLE",
    "custom_mode",
    "mode_name",
    "param_value",
    "set_mode_params",
    "split_custom_mode",
]
