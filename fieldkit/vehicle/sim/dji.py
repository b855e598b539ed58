"""A simulated DJI Matrice 100 flight controller, without I/O: OPEN protocol bytes and time in,
frames out.

    sim = SimM100(load_profile("m100"), app_id=TEST_APP_ID, app_key=TEST_APP_KEY)
    sim.receive_data(bytes_from_the_host)      # version, activation, authority, tasks...
    sim.step(0.02)                             # physics by 20 ms, broadcast items when due
    write(sim.data_to_send())                  # broadcast pushes, ACKs, lost-control pushes

No M100 (nor DJI's own simulator, which needs the aircraft) is available here, so this
stands in for the N1 flight controller, speaking exactly the frames of
`fieldkit.vehicle.dji` (the spec's §11 contract; what is inferred is marked in
docs/vehicles.md). `fieldkit.vehicle.sim.dji_vehicle.SimM100Vehicle` puts it on a pty or a
serial port; `fieldkit vehicle-sim --profile m100` runs that.

- **Broadcast** from power-on, session 0, its own sequence numbers, each item at its own
  rate (DJI Assistant's defaults until the host sets them, or `broadcast_hz` for all),
  one push per step with the items due.
- **Sessions**: every command on a session >= 1 is acknowledged; on 2..31 the last ACK is
  remembered, and a repeated SEQ gets it again without running the command twice.
- **Get version** at any time (0xFF01 before activation, 0x0000 after); **activation**
  accepts only the configured app id (`unknown_app_code`, 0x0003 by default, for another)
  and the M100 firmware word (0x0008 otherwise). The app key never travels: the FC learns it
  at DJI's online activation; here it is configured, and an encrypted frame that does not
  decrypt to a known command under it is answered 0xFF00 KEY_ERROR.
- **Control authority** only with the simulated RC mode switch in F (`pilot_switch`), else
  0x0000; flipping the switch out of F takes authority back (lost-control push, control
  device back to the RC) and the aircraft hovers, as under a pilot's centred sticks.
- **Tasks** (M100 form, ACK 2 started / 1 failed): take-off with the motors stopped (to
  1.2 m, then hover), landing in the air (status 4, touchdown 5, 2 s later 1), go home.
  Arm/disarm (0x01/0x05) with the M100's codes.
- **Movement control** only with authority and in the air: position offsets, heights and
  yaw angles are flown with the profile's kinematics; velocities are followed as a point one
  second ahead (zero: brake and hold); angle and thrust modes are not simulated (counted).
  When frames stop for `movement_timeout_s`, the aircraft brakes and hovers.

Stepping is deterministic: the same inputs and steps give the same bytes.
"""

from __future__ import annotations

import logging
import math
import random
from collections import Counter
from dataclasses import dataclass
from typing import TypedDict

from fieldkit.errors import FieldkitError
from fieldkit.robot.geo import DEFAULT_HOME as DEFAULT_HOME
from fieldkit.robot.geo import LocalFrame
from fieldkit.robot.profiles import Profile
from fieldkit.robot.script_api import IN_AIR, LANDING, ON_GROUND, TAKING_OFF
from fieldkit.vehicle.dji import messages as M
from fieldkit.vehicle.dji.crypto import FrameCipher
from fieldkit.vehicle.dji.frame import Frame, FrameReader, ack_frame, command_frame
from fieldkit.vehicle.kinematics import Vehicle

_log = logging.getLogger("fieldkit.vehicle_sim")

TEST_APP_ID = 1024768
"""The app id the simulator accepts by default (a test value, not a DJI account's)."""
TEST_APP_KEY = "0123456789abcdef" * 4
"""The app key the simulator decrypts with by default (a test value, never a real key)."""
TAKEOFF_HEIGHT_M = 1.2
"""Where DJI's auto take-off stops and hovers (spec §7.5: "about 1.2 m")."""
LANDED_DWELL_S = 2.0
"""Seconds in "landed" (5) after touchdown before "standby" (1)."""
ASSISTANT_RATES_HZ = (100.0, 100.0, 100.0, 100.0, 100.0, 100.0, 0.0, 50.0, 50.0, 10.0, 1.0, 0.0)
"""Broadcast item rates before the host sets any: DJI Assistant's defaults (spec §7.3)."""
_GEAR_DOWN = -4545


class SimM100Error(FieldkitError):
    """The simulated M100 cannot start (a bad home, a port it cannot open, a bad key)."""


@dataclass
class M100Faults:
    """What goes wrong, switched on and off by tests at any step."""

    silent: bool = False  # nothing leaves the flight controller
    broadcast: bool = True  # False: no broadcast pushes (ACKs still flow)
    garbage_every: int = 0  # after every Nth frame, `garbage_len` random bytes (0: never)
    garbage_len: int = 8
    corrupt_every: int = 0  # every Nth frame leaves with a broken CRC (0: never)
    drop_acks: int = 0  # the next N ACKs are lost on the way (the command still acts)


class SimM100Options(TypedDict, total=False):
    """`SimM100`'s keyword options, as a transport passes them on unchanged."""

    app_id: int
    app_key: str
    home: tuple[float, float]
    home_alt_m: float
    gps_fix_delay_s: float
    rc_mode: str
    broadcast_hz: float | None
    unknown_app_code: int
    obtain_in_progress_first: bool
    encrypt_acks: bool
    movement_timeout_s: float
    go_home_alt_m: float
    seed: int


class SimM100:
    """One simulated M100 N1 flight controller and the aircraft it flies."""

    def __init__(
        self,
        profile: Profile,
        *,
        app_id: int = TEST_APP_ID,
        app_key: str = TEST_APP_KEY,
        home: tuple[float, float] = DEFAULT_HOME,
        home_alt_m: float = 50.0,
        gps_fix_delay_s: float = 0.0,
        rc_mode: str = "F",
        broadcast_hz: float | None = None,
        unknown_app_code: int = 0x0003,
        obtain_in_progress_first: bool = False,
        encrypt_acks: bool = True,
        movement_timeout_s: float = 0.5,
        go_home_alt_m: float = 20.0,
        seed: int = 0,
    ) -> None:
        """A powered-on M100 at `home`, not activated, motors stopped.

        `app_id`/`app_key` are the registered app's (the key as 64 hex digits).
        `broadcast_hz` pushes every item at that rate until the host sets frequencies
        (None: DJI Assistant's defaults). `obtain_in_progress_first` answers the first
        obtain "in progress" (DJI's page says every request is sent twice). `encrypt_acks`
        encrypts the ACK of an encrypted command (undocumented for the real FC).
        `movement_timeout_s`: silence after which movement control stops and it hovers.
        """
        try:
            self.frame = LocalFrame(float(home[0]), float(home[1]), float(home_alt_m))
        except (ValueError, TypeError, IndexError) as e:
            raise SimM100Error(f"bad home {home!r}: {e}") from e
        try:
            self._cipher = FrameCipher.from_app_key(app_key)
        except ValueError as e:
            raise SimM100Error(str(e)) from None
        if rc_mode not in ("P", "A", "F"):
            raise SimM100Error(f"rc_mode must be P, A or F, got {rc_mode!r}")
        self.profile = profile
        self.app_id = app_id
        self.gps_fix_delay_s = gps_fix_delay_s
        self.unknown_app_code = unknown_app_code
        self.obtain_in_progress_first = obtain_in_progress_first
        self.encrypt_acks = encrypt_acks
        self.movement_timeout_s = movement_timeout_s
        self.go_home_alt_m = go_home_alt_m
        self.vehicle = Vehicle.from_profile(profile)
        self.time = 0.0
        self.faults = M100Faults()
        self.rc = [0, 0, 0, 0, _mode_value(rc_mode), _GEAR_DOWN]
        self.activated = False
        self.authority = False
        self.device = M.DEVICE_RC
        self.control_mode = 0
        self.home: tuple[float, float] | None = None  # local (x, y) of the home point
        self.task: str | None = None  # "takeoff", "landing", "go_home" while one runs

        self.received: Counter[tuple[int, int]] = Counter()  # commands run, by (set, id)
        self.refusals: Counter[tuple[int, int]] = Counter()  # ACKs other than success
        self.duplicates = 0  # repeated SEQs answered from the ACK cache
        self.key_errors = 0  # encrypted frames that did not decrypt to a command
        self.unknown_commands = 0
        self.movement_frames = 0  # movement-control frames applied
        self.movement_ignored = 0  # ... ignored (no authority, not in the air, a task)
        self.movement_unsupported = 0  # angle, thrust, rate modes
        self.lost_control_pushes = 0
        self.frames_sent = 0
        self.acks_sent = 0
        self.acks_dropped = 0
        self.corrupted_frames = 0
        self.garbage_bytes = 0
        self.bytes_sent = 0
        self.bytes_dropped = 0
        self.bytes_received = 0

        self._reader = FrameReader(self._cipher)
        self._outbox: list[bytes] = []
        self._rng = random.Random(seed)
        self._seq = 0
        self._acks: dict[int, tuple[int, bytes]] = {}  # session -> (seq, ACK frame)
        self._obtain_asked = False
        self._rates = list(ASSISTANT_RATES_HZ) if broadcast_hz is None else [broadcast_hz] * 12
        self._next_due = [0.0] * len(M.ITEMS)
        self._last_movement: float | None = None
        self._landed_at: float | None = None

    # ------------------------------------------------------------------ views

    @property
    def reader(self) -> FrameReader:
        """The de-framer of what the host sends, with its counters."""
        return self._reader

    @property
    def gps_fix(self) -> bool:
        """Whether the GPS has a fix (after `gps_fix_delay_s`)."""
        return self.time >= self.gps_fix_delay_s

    @property
    def rc_switch(self) -> str:
        """The mode switch: "P", "A" or "F"."""
        return _mode_name(self.rc[4])

    @property
    def flight_status(self) -> int:
        """The M100 flight status, 1 standby ... 5 landed."""
        v = self.vehicle
        if v.status == ON_GROUND:
            if self._landed_at is not None and self.time - self._landed_at < LANDED_DWELL_S:
                return M.STATUS_LANDED
            return M.STATUS_STANDBY
        if v.status == TAKING_OFF:
            return M.STATUS_TAKING_OFF if v.z <= 0.0 else M.STATUS_IN_AIR
        if v.status == LANDING:
            return M.STATUS_LANDING
        return M.STATUS_IN_AIR

    @property
    def position(self) -> tuple[float, float, float]:
        """(lat, lon, height above the take-off point) now."""
        v = self.vehicle
        lat, lon, _ = self.frame.to_gps(v.x, v.y)
        return lat, lon, v.z

    @property
    def broadcast_rates(self) -> tuple[float, ...]:
        """Each item's rate in Hz, in flag-bit order."""
        return tuple(self._rates)

    # ------------------------------------------------------------------ test handles

    def pilot_switch(self, mode: str) -> None:
        """The pilot moves the RC mode switch to "P", "A" or "F": out of F, the host loses
        control authority at once and the aircraft hovers (sticks centred)."""
        if mode not in ("P", "A", "F"):
            raise ValueError(f"the mode switch has P, A and F, not {mode!r}")
        self.rc[4] = _mode_value(mode)
        if mode != "F" and self.authority:
            self._take_back("RC mode switch to " + mode)

    def app_takes_control(self) -> None:
        """The mobile app takes control (the switch stays in F)."""
        if self.authority:
            self._take_back("the mobile app")
        self.device = M.DEVICE_APP

    def set_battery(self, percent: float) -> None:
        """Jump the battery to `percent`."""
        self.vehicle.set_battery(percent)  # its battery is the profile's

    def _take_back(self, by: str) -> None:
        self.authority = False
        self.device = M.DEVICE_RC
        self.task = None
        self._last_movement = None
        v = self.vehicle
        if v.status in (IN_AIR, TAKING_OFF, LANDING):
            v.hold()  # centred sticks: it stops and hovers where it is
        self.lost_control_pushes += 1
        self._push(M.PUSH_LOST_CONTROL, bytes((M.LOST_CONTROL_VALUE,)))
        self._note(f"control authority taken back by {by}")

    # ------------------------------------------------------------------ time

    def step(self, dt: float) -> None:
        """Advance the physics by `dt` and send the broadcast items due."""
        self.time += dt
        v = self.vehicle
        if self.home is None and self.gps_fix:
            self.home = (v.x, v.y)
        if (
            self._last_movement is not None
            and self.time - self._last_movement > self.movement_timeout_s
        ):
            self._last_movement = None
            if v.status == IN_AIR:
                v.hold()  # movement control stopped: brake and hover
        was = v.status
        v.step(dt)
        if was == LANDING and v.status == ON_GROUND:
            self._landed_at = self.time
            self.task = None
            self._note("touchdown: motors stopped")
        elif was == TAKING_OFF and v.status == IN_AIR and self.task == "takeoff":
            self.task = None
        self._broadcast()

    # ------------------------------------------------------------------ bytes in and out

    def receive_data(self, data: bytes) -> int:
        """Handle bytes from the host (any split); frames handled."""
        self.bytes_received += len(data)
        n = 0
        for frame in self._reader.feed(data):
            if not frame.ack:
                self._handle(frame)
            n += 1
        return n

    def data_to_send(self) -> bytes:
        """The bytes sent since the last call (faults applied)."""
        out = b"".join(self._outbox)
        self._outbox.clear()
        return out

    def _transmit(self, frame: bytes) -> None:
        """One frame (and noise) onto the line: the outbox; a transport writes it at once."""
        self._outbox.append(frame)
        self.bytes_sent += len(frame)

    def _write(self, raw: bytes) -> None:
        f = self.faults
        if f.silent:
            return
        buf = bytearray(raw)
        self.frames_sent += 1
        n = self.frames_sent
        if f.corrupt_every and n % f.corrupt_every == 0:
            buf[-1] ^= 0x5A  # the CRC32's top byte (or the CRC16's, for a bare header)
            self.corrupted_frames += 1
        if f.garbage_every and n % f.garbage_every == 0:
            noise = bytes(self._rng.randrange(256) for _ in range(f.garbage_len))
            buf += noise
            self.garbage_bytes += len(noise)
        self._transmit(bytes(buf))

    def _next_seq(self) -> int:
        seq = self._seq
        self._seq = (seq + 1) & 0xFFFF
        return seq

    def _push(self, key: tuple[int, int], value: bytes) -> None:
        self._write(command_frame(0, self._next_seq(), key[0], key[1], value))

    def _note(self, text: str) -> None:
        _log.info("t=%.2f %s: %s", self.time, self.profile.name, text)

    # ------------------------------------------------------------------ commands

    def _handle(self, frame: Frame) -> None:
        cmd_set, cmd_id = frame.cmd_set, frame.cmd_id
        key = (cmd_set or 0, cmd_id or 0)
        want = M.VALUE_LENGTHS.get(key) if cmd_set is not None else None
        if want is None or len(frame.value) != want:
            if frame.enc:
                # It did not decrypt into a command: the host's key is not the app's.
                self.key_errors += 1
                if frame.session >= 1:
                    self._ack(frame, M.KEY_ERROR.to_bytes(2, "little"), plain=True)
            else:
                self.unknown_commands += 1  # unknown commands: silence (spec §15.3)
            return
        if frame.session >= 2:
            cached = self._acks.get(frame.session)
            if cached is not None and cached[0] == frame.seq:
                self.duplicates += 1  # a retransmission: the same answer, not run again
                self._send_ack(cached[1])
                return
        self.received[key] += 1
        if key == M.CMD_MOVEMENT:
            self._movement(M.parse_movement(frame.value))
            return
        answer = self._command(key, frame.value)
        if answer is None or frame.session == 0:
            return
        code = M.return_code(answer)
        if code is not None and key != M.CMD_GET_VERSION and code not in _SUCCESS[key]:
            self.refusals[key] += 1
        self._ack(frame, answer)

    def _ack(self, frame: Frame, value: bytes, *, plain: bool = False) -> None:
        cipher = self._cipher if frame.enc and self.encrypt_acks and not plain else None
        raw = ack_frame(frame.session, frame.seq, value, cipher=cipher)
        if frame.session >= 2:
            self._acks[frame.session] = (frame.seq, raw)
        self._send_ack(raw)

    def _send_ack(self, raw: bytes) -> None:
        if self.faults.drop_acks > 0:
            self.faults.drop_acks -= 1
            self.acks_dropped += 1
            return
        self.acks_sent += 1
        self._write(raw)

    def _command(self, key: tuple[int, int], value: bytes) -> bytes | None:
        """The ACK value of a command (None: no answer)."""
        if key == M.CMD_GET_VERSION:
            return M.version_ack_value(M.SUCCESS if self.activated else M.NO_AUTHORIZATION)
        if key == M.CMD_ACTIVATE:
            return _code(self._activate(value))
        if key == M.CMD_SET_BROADCAST:
            for i, c in enumerate(value[: len(M.ITEMS)]):
                if c in M.CODE_RATES:
                    self._rates[i] = M.CODE_RATES[c]
                    self._next_due[i] = self.time
            return _code(M.SUCCESS)
        if not self.activated:
            return _code(M.NO_AUTHORIZATION)
        if key == M.CMD_CONTROL:
            return _code(self._control(value[0]))
        if key == M.CMD_TASK:
            return _code(self._task(value[1]))
        if key == M.CMD_ARM:
            return _code(self._arm(value[0] == 1))
        if key == M.CMD_TASK_QUERY:
            return _code(0x0005 if self.task is None else 0x0003)
        return None

    def _activate(self, value: bytes) -> int:
        app_id, level, ver = M.parse_activation(value)
        if app_id != self.app_id:
            self._note(f"activation refused: unknown app id {app_id}")
            return self.unknown_app_code
        if ver != M.M100_FIRMWARE:
            return M.ACTIVATION_VERSION_MISMATCH
        if level < M.API_LEVEL:
            return 0x0007
        if not self.activated:
            self._note(f"activated: app id {app_id}")
        self.activated = True
        return M.SUCCESS

    def _control(self, obtain: int) -> int:
        if obtain == 0:
            if self.authority:
                self._note("control authority released")
            self.authority = False
            self.device = M.DEVICE_RC
            self._last_movement = None
            return M.CONTROL_RELEASED
        if self.rc_switch != "F":
            return M.CONTROL_SWITCH_NOT_F
        if self.device == M.DEVICE_APP:
            return M.CONTROL_IOC  # the app holds it (the closest refusal the M100 has)
        if self.obtain_in_progress_first and not self._obtain_asked and not self.authority:
            self._obtain_asked = True
            return M.CONTROL_OBTAINING
        self._obtain_asked = False
        if not self.authority:
            self._note("control authority obtained by the onboard computer")
        self.authority = True
        self.device = M.DEVICE_ONBOARD
        return M.CONTROL_OBTAINED

    def _task(self, task: int) -> int:
        v = self.vehicle
        if not self.authority:
            return M.TASK_FAILED
        if task == M.TASK_TAKEOFF:
            # Auto take-off only with the motors stopped, on the ground (spec §7.5).
            if v.status != ON_GROUND or v.armed or not v.arm():
                return M.TASK_FAILED
            v.takeoff(TAKEOFF_HEIGHT_M)
            self.task = "takeoff"
            self._landed_at = None
            self._note("auto take-off")
            return M.TASK_STARTED
        if task == M.TASK_LAND:
            if v.status not in (IN_AIR, TAKING_OFF) or not v.land():
                return M.TASK_FAILED
            self.task = "landing"
            self._last_movement = None
            self._note("auto landing")
            return M.TASK_STARTED
        if task == M.TASK_GO_HOME:
            if v.status == ON_GROUND or self.home is None:
                return M.TASK_FAILED
            if not v.return_home(self.home[0], self.home[1], self.go_home_alt_m):
                return M.TASK_FAILED
            self.task = "go_home"
            self._last_movement = None
            self._note("go home")
            return M.TASK_STARTED
        return M.TASK_FAILED

    def _arm(self, on: bool) -> int:
        v = self.vehicle
        if not self.authority:
            return M.ARM_NEED_CONTROL
        if on:
            if v.armed:
                return M.ARM_ALREADY
            return M.ARM_SUCCESS if v.arm() else M.ARM_NEED_CONTROL
        if not v.armed:
            return M.ARM_ALREADY
        if v.status != ON_GROUND:
            return M.ARM_IN_AIR
        v.disarm()
        return M.ARM_SUCCESS

    def _movement(self, m: M.Movement) -> None:
        v = self.vehicle
        if v.status == TAKING_OFF and v.z > 0.0 and self.authority:
            # In the air (status 3): movement control ends the auto take-off's climb.
            v.hold()
            self.task = None
        if not self.authority or v.status != IN_AIR or self.task in ("go_home", "landing"):
            self.movement_ignored += 1
            return
        if m.horizontal not in (1, 2) or m.vertical == 2:
            self.movement_unsupported += 1  # angles, rates, thrust: not simulated
            return
        if not all(map(math.isfinite, (m.x, m.y, m.z, m.yaw))):
            self.movement_ignored += 1
            return
        self.movement_frames += 1
        self._last_movement = self.time
        self.control_mode = m.control_mode
        north, east = m.x, m.y
        if m.body:
            # Body frame: x forward, y right, turned by the heading (0 north, clockwise).
            h = math.pi / 2 - v.yaw
            north, east = (
                m.x * math.cos(h) - m.y * math.sin(h),
                m.x * math.sin(h) + m.y * math.cos(h),
            )
        if m.horizontal == 1:  # velocities: a point one second ahead
            still = north == 0.0 and east == 0.0 and (m.vertical == 1 or m.z == 0.0)
            if still:
                v.hold()
                return
        tx, ty = v.x + east, v.y + north
        tz = m.z if m.vertical == 1 else v.z + m.z
        if not tz > 0.0:
            tz = v.z  # a height at or below the ground is a landing: not by movement
        yaw = None if m.yaw_rate else math.pi / 2 - math.radians(m.yaw)
        v.goto(tx, ty, tz, yaw)

    # ------------------------------------------------------------------ broadcast

    def _broadcast(self) -> None:
        t = self.time + 1e-9  # steps of 0.02 s add up to 0.060000000000000005
        due = []
        for i, rate in enumerate(self._rates):
            if rate <= 0 or t < self._next_due[i]:
                continue
            nxt = self._next_due[i] + 1.0 / rate
            self._next_due[i] = nxt if nxt > self.time else self.time + 1.0 / rate
            due.append(M.ITEMS[i])
        if not due or not self.faults.broadcast:
            return
        b = M.Broadcast()
        v = self.vehicle
        for name in due:
            setattr(b, name, self._item(name, v))
        self._push(M.PUSH_BROADCAST, b.encode())

    def _item(self, name: str, v: Vehicle) -> tuple[float | int, ...]:
        if name == "timestamp":
            ticks = int(self.time * 400.0)
            return (ticks & 0xFFFFFFFF, int(self.time % 1.0 * 1e9), 0)
        if name == "quaternion":
            return M.yaw_quaternion(math.pi / 2 - v.yaw)
        if name == "velocity":
            vz = v.vz if M.VELOCITY_Z_UP else -v.vz
            return (v.vy, v.vx, vz, 1)
        if name == "position":
            if not self.gps_fix:
                return (0.0, 0.0, self.frame.alt, v.z, 0)
            lat, lon, _ = self.frame.to_gps(v.x, v.y)
            return (math.radians(lat), math.radians(lon), self.frame.alt + v.z, v.z, 5)
        if name == "magnetometer":
            return (1200, 0, 0)
        if name == "rc":
            return tuple(self.rc)
        if name == "gimbal":
            return (0.0, 0.0, 0.0, 0)
        if name == "flight_status":
            return (self.flight_status,)
        if name == "battery":
            return (max(0, min(100, round(v.battery_percent))),)
        if name == "control":
            bits = self.device | (M.DEVICE_SDK_OPEN if self.authority else 0)
            return (self.control_mode, bits)
        return (0.0, 0.0, 0.0)  # acceleration, angular rate: a steady aircraft


# The codes that mean "done" for each command (for the refusal counter).
_SUCCESS: dict[tuple[int, int], tuple[int, ...]] = {
    M.CMD_ACTIVATE: (M.SUCCESS,),
    M.CMD_SET_BROADCAST: (M.SUCCESS,),
    M.CMD_CONTROL: (M.CONTROL_OBTAINED, M.CONTROL_RELEASED, M.CONTROL_OBTAINING),
    M.CMD_TASK: (M.TASK_STARTED,),
    M.CMD_TASK_QUERY: (0x0003, 0x0005),
    M.CMD_ARM: (M.ARM_SUCCESS,),
}


def _code(code: int) -> bytes:
    return code.to_bytes(2, "little")


def _mode_value(mode: str) -> int:
    return {"P": M.RC_P, "A": M.RC_A, "F": M.RC_F}[mode]


def _mode_name(value: int) -> str:
    return "F" if value > 4000 else "P" if value < -4000 else "A"


__all__ = [
    "DEFAULT_HOME",
    "M100Faults",
    "SimM100",
    "SimM100Error",
    "SimM100Options",
    "TEST_APP_ID",
    "TEST_APP_KEY",
]
