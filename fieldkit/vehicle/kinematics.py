"""A kinematic vehicle: point mass with speed and acceleration limits, stepped at a fixed dt.

    v = Vehicle.from_profile(load_profile("solo"))
    v.arm(); v.takeoff(5.0)
    for _ in range(60):
        v.step()                       # 0.1 s, no wall clock
    v.goto(20.0, 10.0, 5.0)

Position is in the local ENU frame (x east, y north, z up, metres); `status` uses the
codes ROSBuzz pushes as `flight.status` (`fieldkit.robot.script_api`): 1 on ground, 2 in
air, 3 taking off, 4 landing.

Motion model. Horizontal and vertical motion are controlled separately, as autopilot
position controllers do: each gets at most `max_accel_mps2` of acceleration; horizontal
speed is capped at `max_speed_mps`, vertical speed at `max_climb_mps` up and
`max_descent_mps` down. Toward a target, the commanded speed is the largest one from which
the vehicle can still brake to a stop *exactly* at the target under the same discrete
update (velocity first, then position += velocity·dt), so it arrives without overshoot
and without chattering. `hold()` brakes at full deceleration and stays where it stopped.

The integration is plain float arithmetic in a fixed order, so the same commands give
bit-identical states. `step` is meant to run for thousands of vehicles per tick: an idle
vehicle costs a few attribute reads, a moving one a couple of square roots.
"""

from __future__ import annotations

import math

from fieldkit.robot.profiles import Battery, Kinematics, Profile
from fieldkit.robot.script_api import IN_AIR, LANDING, ON_GROUND, TAKING_OFF, FlightStatus

DT = 0.1
"""The simulator's step, seconds: the field node's 10 Hz loop."""

# Control state of one axis group (horizontal, vertical).
_IDLE = 0  # stopped, holding position exactly
_GOTO = 1  # steering toward the target
_BRAKE = 2  # decelerating to a stop wherever that is

# Phases of a return to launch: climbing where it is, then flying home (then it lands).
_RTL_CLIMB = 0
_RTL_RETURN = 1

# Arrival: within this distance, and slow enough to stop in one step, snap onto the target.
# Far below any hover accuracy, far above the rounding of coordinates of a few km.
_SNAP_M = 1e-6


def _brake_speed(d: float, a: float, dt: float) -> float:
    """Largest speed from which braking by a·dt per step stops within distance `d`, exactly.

    With v = (n + f)·a·dt (0 <= f < 1) the steps travel v·dt, (v − a·dt)·dt, ..., f·a·dt²:
    a total of a·dt²·(n + 1)(n + 2f)/2. This inverts that, so that moving at the returned
    speed and then decelerating at the limit ends on the target, not past it.
    """
    adt2 = a * dt * dt
    q = d / adt2
    n = math.floor((math.sqrt(8.0 * q + 1.0) - 1.0) * 0.5)
    f = (2.0 * q / (n + 1) - n) * 0.5
    # Rounding at the boundaries between n and n + 1 can push f a hair outside [0, 1].
    if f < 0.0:
        f = 0.0
    elif f > 1.0:
        f = 1.0
    return (n + f) * a * dt


class Vehicle:
    """One simulated robot: a UAV (takes off, flies, lands) or a ground robot (stays at z = 0)."""

    __slots__ = (
        "x",
        "y",
        "z",
        "vx",
        "vy",
        "vz",
        "yaw",
        "armed",
        "status",
        "battery_percent",
        "voltage",
        "ground",
        "kinematics",
        "battery",
        "_tx",
        "_ty",
        "_tz",
        "_hmode",
        "_vmode",
        "_vmax",
        "_accel",
        "_climb",
        "_descent",
        "_drain",
        "_rtl",
    )

    def __init__(
        self,
        kinematics: Kinematics,
        *,
        ground: bool = False,
        battery: Battery | None = None,
        x: float = 0.0,
        y: float = 0.0,
        yaw: float = 0.0,
    ) -> None:
        """A disarmed vehicle on the ground at (x, y); no `battery` means it never drains."""
        k = kinematics
        if not (k.max_speed_mps > 0 and k.max_accel_mps2 > 0):
            raise ValueError("max_speed_mps and max_accel_mps2 must be > 0")
        if not ground and not (k.max_climb_mps > 0 and k.max_descent_mps > 0):
            raise ValueError("a UAV needs max_climb_mps and max_descent_mps > 0")
        self.kinematics = kinematics
        self.battery = battery
        self.ground = ground
        self.x = float(x)
        self.y = float(y)
        self.z = 0.0
        self.vx = 0.0
        self.vy = 0.0
        self.vz = 0.0
        self.yaw = float(yaw)
        self.armed = False
        self.status: FlightStatus = ON_GROUND
        self.battery_percent = 100.0
        self.voltage = battery.full_voltage if battery is not None else 0.0
        self._tx = self.x
        self._ty = self.y
        self._tz = 0.0
        self._hmode = _IDLE
        self._vmode = _IDLE
        self._vmax = k.max_speed_mps
        self._accel = k.max_accel_mps2
        self._climb = k.max_climb_mps
        self._descent = k.max_descent_mps
        # Percent per second while armed: linear from full to empty over the endurance.
        self._drain = 100.0 / battery.endurance_s if battery is not None else 0.0
        # Return to launch under way: (phase, home x, home y, altitude), else None.
        self._rtl: tuple[int, float, float, float] | None = None

    @classmethod
    def from_profile(
        cls, profile: Profile, *, x: float = 0.0, y: float = 0.0, yaw: float = 0.0
    ) -> Vehicle:
        """A vehicle with a device profile's kinematics, vehicle type and battery."""
        return cls(
            profile.kinematics, ground=profile.is_ground, battery=profile.battery, x=x, y=y, yaw=yaw
        )

    # ------------------------------------------------------------------ state views

    @property
    def position(self) -> tuple[float, float, float]:
        """(x east, y north, z up), metres in the local frame."""
        return self.x, self.y, self.z

    @property
    def velocity(self) -> tuple[float, float, float]:
        """(east, north, up) velocity, m/s."""
        return self.vx, self.vy, self.vz

    @property
    def target(self) -> tuple[float, float, float]:
        """Where the vehicle is going, or holds."""
        return self._tx, self._ty, self._tz

    @property
    def flying(self) -> bool:
        """Whether a UAV is off the ground (taking off, in the air, or landing)."""
        return self.status != ON_GROUND

    @property
    def settled(self) -> bool:
        """Whether the vehicle has finished its last command and is standing still."""
        return self._hmode == _IDLE and self._vmode == _IDLE

    def start_flying(self, alt: float) -> None:
        """Begin already under way, as a run from a known swarm state does: a UAV armed and
        hovering at `alt` metres where it stands (status 2), a ground robot armed."""
        self.armed = True
        if self.ground:
            return
        if not (alt > 0.0 and math.isfinite(alt)):
            raise ValueError(f"a UAV flies above the ground: altitude {alt} m")
        self.z = self._tz = float(alt)
        self.status = IN_AIR

    def set_battery(self, percent: float) -> None:
        """Jump the charge to `percent` (clamped to 0..100); the voltage follows the battery's
        linear model (a vehicle without a battery keeps its voltage)."""
        p = min(100.0, max(0.0, percent))
        self.battery_percent = p
        b = self.battery
        if b is not None:
            self.voltage = b.empty_voltage + (b.full_voltage - b.empty_voltage) * p * 0.01

    # ------------------------------------------------------------------ commands

    def arm(self) -> bool:
        """Arm the motors; refused with an empty battery. True if armed afterwards."""
        if self.armed:
            return True
        if self.battery is not None and self.battery_percent <= 0.0:
            return False
        self.armed = True
        return True

    def disarm(self) -> bool:
        """Disarm; a UAV refuses unless it is on the ground. A ground robot brakes to a stop."""
        if not self.ground and self.status != ON_GROUND:
            return False
        self.armed = False
        if self._hmode != _IDLE:
            self._hmode = _BRAKE
        return True

    def takeoff(self, alt: float) -> bool:
        """Climb straight up to `alt` metres (UAV, armed, on the ground); status 3, then 2."""
        self._rtl = None
        if self.ground or not self.armed or self.status != ON_GROUND:
            return False
        if not (alt > 0.0 and math.isfinite(alt)):
            return False
        self._tx, self._ty, self._tz = self.x, self.y, float(alt)
        self._hmode = _GOTO
        self._vmode = _GOTO
        self.status = TAKING_OFF
        return True

    def land(self) -> bool:
        """Brake and descend to the ground; status 4, then 1 and disarmed on touchdown (UAV)."""
        self._rtl = None
        if self.ground or self.status == ON_GROUND:
            return False
        if self.status != LANDING:
            self._brake_horizontal()
            self._tz = 0.0
            self._vmode = _GOTO
            self.status = LANDING
        return True

    def goto(self, x: float, y: float, z: float = 0.0, yaw: float | None = None) -> bool:
        """Go to the absolute local point (x, y, z) and stop there; ground robots ignore z.

        Refused (False) by a UAV that is not in the air (status 2) or given z <= 0 (that is
        what `land` is for), by a disarmed ground robot, and for non-finite coordinates.
        `yaw`, if given, is the new heading (ENU radians); otherwise the heading is kept.
        """
        self._rtl = None
        if not (math.isfinite(x) and math.isfinite(y)):
            return False
        if self.ground:
            if not self.armed:
                return False
            self._tx, self._ty = float(x), float(y)
            self._hmode = _GOTO
        else:
            if self.status != IN_AIR or not (z > 0.0 and math.isfinite(z)):
                return False
            self._tx, self._ty, self._tz = float(x), float(y), float(z)
            self._hmode = _GOTO
            self._vmode = _GOTO
            if yaw is not None and math.isfinite(yaw):
                self.yaw = float(yaw)
        return True

    def hold(self) -> bool:
        """Brake to a stop at full deceleration and keep that position; aborts takeoff/landing."""
        self._rtl = None
        self._brake_horizontal()
        if self._vmode != _IDLE:
            self._vmode = _BRAKE
        if self.status in (TAKING_OFF, LANDING):
            self.status = IN_AIR if self.z > 0.0 else ON_GROUND
        return True

    def return_home(self, x: float, y: float, alt: float) -> bool:
        """Return to launch as ArduPilot's RTL does: climb to at least `alt`, fly to (x, y),
        land. A ground robot drives to (x, y) and stops. False if not under way."""
        if self.ground:
            if not self.armed or not self.goto(x, y):
                return False
            self._rtl = (_RTL_RETURN, x, y, 0.0)
            return True
        if self.status == ON_GROUND:
            return False
        self.hold()  # out of a takeoff or a landing: in the air, braking
        if self.status != IN_AIR:
            return False  # it had not left the ground yet
        climb = max(self.z, alt)
        self.goto(self.x, self.y, climb)
        self._rtl = (_RTL_CLIMB, x, y, climb)
        return True

    def _rtl_next(self) -> None:
        """The RTL phase just finished (both axes stopped): start the next one."""
        phase, x, y, alt = self._rtl  # type: ignore[misc]  # only called while one runs
        if phase == _RTL_CLIMB:
            self.goto(x, y, alt)
            self._rtl = (_RTL_RETURN, x, y, alt)
        elif self.ground:
            self._rtl = None
        else:
            self.land()

    def _brake_horizontal(self) -> None:
        """Stop steering horizontally; decelerate if moving."""
        if self._hmode != _IDLE:
            self._hmode = _BRAKE

    # ------------------------------------------------------------------ time

    def step(self, dt: float = DT) -> None:
        """Advance the simulation by `dt` seconds."""
        if self.armed and self._drain:
            p = self.battery_percent - self._drain * dt
            if p < 0.0:
                p = 0.0
            self.battery_percent = p
            b = self.battery
            if b is not None:  # always, when it drains
                self.voltage = b.empty_voltage + (b.full_voltage - b.empty_voltage) * p * 0.01
        hmode = self._hmode
        vmode = self._vmode
        if hmode == _IDLE and vmode == _IDLE:
            return
        adt = self._accel * dt

        if hmode != _IDLE:
            vx = self.vx
            vy = self.vy
            if hmode == _GOTO:
                ex = self._tx - self.x
                ey = self._ty - self.y
                d = math.sqrt(ex * ex + ey * ey)
                if d <= _SNAP_M and vx * vx + vy * vy <= adt * adt:
                    self.x = self._tx
                    self.y = self._ty
                    self.vx = self.vy = 0.0
                    self._hmode = hmode = _IDLE
                else:
                    s = _brake_speed(d, self._accel, dt)
                    if s > self._vmax:
                        s = self._vmax
                    s = s / d if d > 0.0 else 0.0
                    dvx = ex * s - vx
                    dvy = ey * s - vy
            else:  # _BRAKE
                if vx * vx + vy * vy <= adt * adt:
                    self._tx = self.x
                    self._ty = self.y
                    self.vx = self.vy = 0.0
                    self._hmode = hmode = _IDLE
                else:
                    dvx = -vx
                    dvy = -vy
            if hmode != _IDLE:
                dv = math.sqrt(dvx * dvx + dvy * dvy)
                if dv > adt:
                    # The new velocity is a convex mix of the old and the desired one, so
                    # neither the speed cap nor the acceleration limit can be exceeded.
                    k = adt / dv
                    dvx *= k
                    dvy *= k
                vx += dvx
                vy += dvy
                self.vx = vx
                self.vy = vy
                self.x += vx * dt
                self.y += vy * dt
                if self.ground:
                    # A wheeled robot faces where it drives.
                    self.yaw = math.atan2(vy, vx)

        if vmode != _IDLE:
            vz = self.vz
            if vmode == _GOTO:
                ez = self._tz - self.z
                d = ez if ez >= 0.0 else -ez
                if d <= _SNAP_M and -adt <= vz <= adt:
                    self.z = self._tz
                    self.vz = 0.0
                    self._vmode = vmode = _IDLE
                else:
                    s = _brake_speed(d, self._accel, dt)
                    if ez >= 0.0:
                        dvz = (s if s < self._climb else self._climb) - vz
                    else:
                        dvz = -(s if s < self._descent else self._descent) - vz
            else:  # _BRAKE
                if -adt <= vz <= adt:
                    self._tz = self.z
                    self.vz = 0.0
                    self._vmode = vmode = _IDLE
                else:
                    dvz = -vz
            if vmode != _IDLE:
                if dvz > adt:
                    dvz = adt
                elif dvz < -adt:
                    dvz = -adt
                vz += dvz
                self.vz = vz
                z = self.z + vz * dt
                if z < 0.0:
                    # The ground is solid: braking so late cannot happen toward a target
                    # above 0, but rounding on the last landing step could dip below.
                    z = 0.0
                self.z = z

        if hmode == _IDLE and vmode == _IDLE:
            self._arrived()
            if self._rtl is not None:
                self._rtl_next()

    def _arrived(self) -> None:
        """Both axes stopped: finish a takeoff or a landing."""
        if self.status == TAKING_OFF:
            self.status = IN_AIR
        elif self.status == LANDING:
            self.status = ON_GROUND
            self.armed = False
