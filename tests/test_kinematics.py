"""fieldkit.vehicle.kinematics: limits checked on every step, arrival without overshoot, status."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fieldkit.robot.profiles import Battery, Kinematics, Profile, load_profile
from fieldkit.robot.script_api import IN_AIR, LANDING, ON_GROUND, TAKING_OFF
from fieldkit.vehicle.kinematics import DT, Vehicle

SOLO = load_profile("solo")
HUSKY = load_profile("husky")
PROFILES = [load_profile(n) for n in ("m100", "solo", "spiri", "husky")]
UAVS = [p for p in PROFILES if not p.is_ground]

TOL = 1e-9


class Recorder:
    """Steps a vehicle and checks the profile's limits between every two steps."""

    def __init__(self, v: Vehicle) -> None:
        self.v = v
        self.steps = 0
        self.max_speed = 0.0
        self.max_accel = 0.0

    def step(self, n: int = 1) -> None:
        """Step `n` times, asserting the limits after each step."""
        v = self.v
        k = v.kinematics
        for _ in range(n):
            before = (v.x, v.y, v.z, v.vx, v.vy, v.vz)
            v.step(DT)
            self.steps += 1
            x0, y0, z0, vx0, vy0, vz0 = before
            speed = math.hypot(v.vx, v.vy)
            self.max_speed = max(self.max_speed, speed)
            assert speed <= k.max_speed_mps + TOL
            # What the position did must match the velocity: no teleporting around the limit
            # (arrival snaps by at most a micrometre).
            assert math.hypot(v.x - x0, v.y - y0) <= k.max_speed_mps * DT + 2e-6
            acc = math.hypot(v.vx - vx0, v.vy - vy0) / DT
            self.max_accel = max(self.max_accel, acc)
            assert acc <= k.max_accel_mps2 + TOL
            assert abs(v.vz - vz0) / DT <= k.max_accel_mps2 + TOL
            assert v.z >= 0.0
            if v.ground:
                assert v.z == 0.0 and v.vz == 0.0 and v.status == ON_GROUND
            else:
                assert -k.max_descent_mps - TOL <= v.vz <= k.max_climb_mps + TOL
                assert v.z - z0 <= k.max_climb_mps * DT + 2e-6
                assert z0 - v.z <= k.max_descent_mps * DT + 2e-6
                if v.status == ON_GROUND:
                    assert v.z == 0.0
                if not v.armed:
                    assert v.status == ON_GROUND

    def until(self, done: Callable[[Vehicle], bool], limit: int) -> int:
        """Step until `done(vehicle)`; the number of steps taken (fails after `limit`)."""
        start = self.steps
        while not done(self.v):
            assert self.steps - start < limit, "did not get there in time"
            self.step()
        return self.steps - start


def airborne(profile: Profile = SOLO, alt: float | None = None) -> Recorder:
    """A UAV hovering at `alt` (default: the profile's takeoff altitude) above the origin."""
    r = Recorder(Vehicle.from_profile(profile))
    assert r.v.arm()
    assert r.v.takeoff(alt if alt is not None else profile.kinematics.takeoff_altitude_m)
    r.until(lambda v: v.status == IN_AIR, 10_000)
    return r


# ------------------------------------------------------------------ takeoff and land


@pytest.mark.parametrize("profile", UAVS, ids=lambda p: p.name)
def test_takeoff_time_and_status(profile: Profile) -> None:
    k = profile.kinematics
    alt = k.takeoff_altitude_m
    r = Recorder(Vehicle.from_profile(profile))
    v = r.v
    assert v.status == ON_GROUND and not v.armed
    assert not v.takeoff(alt), "takeoff must need arming"
    assert v.arm() and v.armed
    assert v.takeoff(alt)
    assert v.status == TAKING_OFF
    r.step()
    assert v.status == TAKING_OFF and v.z > 0.0
    n = r.until(lambda v: v.status == IN_AIR, 10_000)
    t = (n + 1) * DT
    # Constant climb at max_climb, plus the time to reach that rate and to slow down again.
    assert (
        alt / k.max_climb_mps
        <= t
        <= alt / k.max_climb_mps + k.max_climb_mps / k.max_accel_mps2 + 2 * DT
    )
    assert v.z == alt and v.vz == 0.0
    assert (v.x, v.y) == (0.0, 0.0)
    assert r.max_speed == 0.0


def test_takeoff_climbs_at_max_climb_rate() -> None:
    r = Recorder(Vehicle.from_profile(SOLO))
    r.v.arm()
    r.v.takeoff(20.0)
    rates = []
    while r.v.status == TAKING_OFF:
        r.step()
        rates.append(r.v.vz)
    assert max(rates) == pytest.approx(SOLO.kinematics.max_climb_mps, abs=1e-12)


def test_takeoff_refusals() -> None:
    v = Vehicle.from_profile(SOLO)
    v.arm()
    assert not v.takeoff(0.0)
    assert not v.takeoff(-3.0)
    assert not v.takeoff(math.nan)
    assert v.status == ON_GROUND
    r = airborne()
    assert not r.v.takeoff(10.0), "already flying"


@pytest.mark.parametrize("profile", UAVS, ids=lambda p: p.name)
def test_land_disarms_on_touchdown(profile: Profile) -> None:
    r = airborne(profile, alt=10.0)
    v = r.v
    assert not v.disarm(), "no disarming in the air"
    assert v.armed
    assert v.land()
    assert v.status == LANDING
    r.step()
    assert v.armed and v.vz < 0.0
    k = profile.kinematics
    n = r.until(lambda v: v.status == ON_GROUND, 10_000)
    assert 10.0 / k.max_descent_mps <= (n + 1) * DT
    assert (n + 1) * DT <= 10.0 / k.max_descent_mps + k.max_descent_mps / k.max_accel_mps2 + 2 * DT
    assert v.z == 0.0 and v.vz == 0.0
    assert not v.armed
    assert not v.land(), "already on the ground"
    assert not v.takeoff(5.0), "disarmed on touchdown"


def test_land_while_moving_brakes_then_descends() -> None:
    r = airborne(alt=3.0)
    v = r.v
    v.goto(100.0, 0.0, 3.0)
    r.step(60)
    assert math.hypot(v.vx, v.vy) == pytest.approx(SOLO.kinematics.max_speed_mps)
    x_at_land = v.x
    assert v.land()
    assert not v.goto(0.0, 0.0, 3.0), "no goto while landing"
    r.until(lambda v: v.status == ON_GROUND, 10_000)
    k = SOLO.kinematics
    # It stops within its braking distance v²/2a (plus one step), it does not go back.
    assert x_at_land < v.x <= x_at_land + k.max_speed_mps**2 / (2 * k.max_accel_mps2) + 0.6
    assert (v.vx, v.vy, v.vz) == (0.0, 0.0, 0.0)


def test_land_during_takeoff_and_disarm_on_ground() -> None:
    r = Recorder(Vehicle.from_profile(SOLO))
    v = r.v
    v.arm()
    v.takeoff(10.0)
    r.step(15)
    assert v.status == TAKING_OFF
    assert v.land() and v.status == LANDING
    r.until(lambda v: v.status == ON_GROUND, 10_000)
    assert not v.armed
    v.arm()
    assert v.disarm() and not v.armed


def test_hold_aborts_takeoff_and_hovers() -> None:
    r = Recorder(Vehicle.from_profile(SOLO))
    v = r.v
    v.arm()
    v.takeoff(20.0)
    r.step(30)
    assert v.hold()
    assert v.status == IN_AIR
    r.until(lambda v: v.settled, 100)
    z = v.z
    r.step(50)
    assert v.z == z and v.status == IN_AIR and v.armed


# ------------------------------------------------------------------ goto


@pytest.mark.parametrize("profile", PROFILES, ids=lambda p: p.name)
@pytest.mark.parametrize("dest", [(30.0, 40.0), (-7.5, 2.0), (0.3, -0.1), (-200.0, -150.0)])
def test_goto_converges_without_overshoot(profile: Profile, dest: tuple[float, float]) -> None:
    k = profile.kinematics
    if profile.is_ground:
        r = Recorder(Vehicle.from_profile(profile))
        r.v.arm()
        z = 0.0
    else:
        r = airborne(profile)
        z = k.takeoff_altitude_m + 2.0
    v = r.v
    tx, ty = dest
    assert v.goto(tx, ty, z)
    dist0 = math.hypot(tx - v.x, ty - v.y)
    limit = int((dist0 / k.max_speed_mps + 2 * k.max_speed_mps / k.max_accel_mps2 + 5) / DT)
    last = dist0
    while not v.settled:
        assert r.steps < 10_000 + limit
        r.step()
        d = math.hypot(tx - v.x, ty - v.y)
        # A straight approach from rest: the distance never grows, so nothing overshoots.
        assert d <= last + TOL
        last = d
        # And never past the target along the line of travel.
        assert (v.x * tx + v.y * ty) / dist0 <= dist0 + k.hover_accuracy_m
    assert math.hypot(tx - v.x, ty - v.y) <= k.hover_accuracy_m
    assert (v.x, v.y) == (tx, ty)  # in fact exactly on it
    assert (v.vx, v.vy, v.vz) == (0.0, 0.0, 0.0)
    assert v.z == z
    if dist0 > 50:
        assert r.max_speed == pytest.approx(k.max_speed_mps)
        assert r.max_accel == pytest.approx(k.max_accel_mps2)
    # It stays there.
    pos = v.position
    r.step(20)
    assert v.position == pos


def test_goto_time_is_near_optimal() -> None:
    r = airborne()
    k = SOLO.kinematics
    r.v.goto(100.0, 0.0, k.takeoff_altitude_m)
    n = r.until(lambda v: v.settled, 10_000)
    ideal = 100.0 / k.max_speed_mps + k.max_speed_mps / k.max_accel_mps2
    assert ideal <= n * DT + DT <= ideal + 3 * DT


def test_goto_changes_altitude_within_limits() -> None:
    r = airborne(alt=5.0)
    v = r.v
    assert v.goto(10.0, 0.0, 25.0)
    r.until(lambda v: v.settled, 10_000)
    assert v.position == (10.0, 0.0, 25.0)
    assert v.goto(10.0, 0.0, 2.0)
    r.until(lambda v: v.settled, 10_000)
    assert v.position == (10.0, 0.0, 2.0)
    assert v.status == IN_AIR


def test_uav_not_flying_ignores_goto() -> None:
    v = Vehicle.from_profile(SOLO)
    assert not v.goto(10.0, 10.0, 5.0)
    v.arm()
    assert not v.goto(10.0, 10.0, 5.0)
    v.takeoff(5.0)
    assert not v.goto(10.0, 10.0, 5.0), "still taking off"
    for _ in range(100):
        v.step()
    assert (v.x, v.y) == (0.0, 0.0)
    assert not v.goto(10.0, 10.0, 0.0), "z = 0 is what land() is for"
    assert not v.goto(math.nan, 10.0, 5.0)
    assert v.goto(10.0, 10.0, 5.0)


def test_goto_sets_yaw_only_when_asked() -> None:
    r = airborne()
    r.v.goto(10.0, 10.0, 5.0)
    r.step(20)
    assert r.v.yaw == 0.0
    r.v.goto(10.0, 10.0, 5.0, yaw=1.25)
    assert r.v.yaw == 1.25


def test_hold_brakes_at_full_deceleration_and_keeps_position() -> None:
    r = airborne()
    v = r.v
    k = SOLO.kinematics
    v.goto(500.0, 0.0, 5.0)
    r.step(50)
    assert v.vx == pytest.approx(k.max_speed_mps)
    x0 = v.x
    assert v.hold()
    n = r.until(lambda v: v.settled, 1000)
    assert n * DT <= k.max_speed_mps / k.max_accel_mps2 + DT
    assert v.x - x0 <= k.max_speed_mps**2 / (2 * k.max_accel_mps2) + k.max_speed_mps * DT
    assert v.target == v.position
    pos = v.position
    r.step(30)
    assert v.position == pos and v.status == IN_AIR


def test_target_change_mid_flight_converges() -> None:
    r = airborne()
    v = r.v
    v.goto(50.0, 0.0, 5.0)
    r.step(40)
    v.goto(0.0, 30.0, 8.0)  # sharp turn at full speed
    r.until(lambda v: v.settled, 1000)
    assert v.position == (0.0, 30.0, 8.0)


# ------------------------------------------------------------------ ground robots


def test_ground_robot_never_leaves_the_ground() -> None:
    r = Recorder(Vehicle.from_profile(HUSKY))
    v = r.v
    assert v.ground
    assert not v.goto(5.0, 5.0), "disarmed"
    assert v.arm()
    assert not v.takeoff(10.0)
    assert v.status == ON_GROUND
    assert v.goto(10.0, -5.0, 30.0)  # z ignored
    r.until(lambda v: v.settled, 10_000)
    assert v.position == (10.0, -5.0, 0.0)
    assert not v.land()
    assert r.max_speed == pytest.approx(1.0)


def test_ground_robot_faces_where_it_drives() -> None:
    r = Recorder(Vehicle.from_profile(HUSKY))
    r.v.arm()
    r.v.goto(0.0, 10.0)
    r.step(5)
    assert r.v.yaw == pytest.approx(math.pi / 2)


def test_ground_robot_disarm_brakes() -> None:
    r = Recorder(Vehicle.from_profile(HUSKY))
    v = r.v
    v.arm()
    v.goto(100.0, 0.0)
    r.step(30)
    assert v.disarm() and not v.armed
    r.until(lambda v: v.settled, 10)
    x = v.x
    r.step(10)
    assert v.x == x < 100.0


commands = st.lists(
    st.one_of(
        st.tuples(st.just("goto"), st.floats(-50, 50), st.floats(-50, 50), st.floats(-5, 40)),
        st.tuples(st.sampled_from(["arm", "disarm", "land", "hold"])),
        st.tuples(st.just("takeoff"), st.floats(-2, 30)),
        st.tuples(st.just("wait"), st.integers(1, 80)),
    ),
    max_size=25,
)


def run(r: Recorder, cmds: list[tuple[Any, ...]]) -> None:
    """Apply `cmds` to the recorder's vehicle, stepping for each 'wait'."""
    v = r.v
    for c in cmds:
        if c[0] == "goto":
            v.goto(c[1], c[2], c[3])
        elif c[0] == "takeoff":
            v.takeoff(c[1])
        elif c[0] == "wait":
            r.step(c[1])
        else:
            getattr(v, c[0])()


@settings(max_examples=150, deadline=None)
@given(commands)
def test_ground_robot_z_stays_zero_whatever_it_is_told(cmds: list[tuple[Any, ...]]) -> None:
    r = Recorder(Vehicle.from_profile(HUSKY))
    run(r, cmds)  # the Recorder asserts z == 0, vz == 0 and status 1 on every step
    r.step(5)
    assert r.v.z == 0.0


@settings(max_examples=150, deadline=None)
@given(commands)
def test_uav_limits_hold_under_any_command_sequence(cmds: list[tuple[Any, ...]]) -> None:
    r = Recorder(Vehicle.from_profile(SOLO))
    run(r, cmds)  # limits checked on every step
    # Whatever happened, a final command settles.
    r.v.hold()
    r.until(lambda v: v.settled, 200)
    if r.v.status == IN_AIR:
        assert r.v.goto(1.0, 2.0, 3.0)
        r.until(lambda v: v.settled, 2000)
        assert r.v.position == (1.0, 2.0, 3.0)


# ------------------------------------------------------------------ battery


def test_battery_drains_linearly_while_armed() -> None:
    b = Battery(full_voltage=16.8, empty_voltage=14.0, endurance_s=100.0)
    v = Vehicle(SOLO.kinematics, battery=b)
    assert (v.battery_percent, v.voltage) == (100.0, 16.8)
    for _ in range(50):
        v.step()
    assert v.battery_percent == 100.0, "no drain while disarmed"
    v.arm()
    for _ in range(500):  # 50 s of 100 s
        v.step()
    assert v.battery_percent == pytest.approx(50.0)
    assert v.voltage == pytest.approx(15.4)
    for _ in range(600):
        v.step()
    assert v.battery_percent == 0.0
    assert v.voltage == pytest.approx(14.0)
    v.disarm()
    assert not v.arm(), "an empty battery cannot arm"


def test_profile_battery_endurance() -> None:
    v = Vehicle.from_profile(SOLO)
    v.arm()
    for _ in range(int(SOLO.battery.endurance_s / DT / 2)):
        v.step()
    assert v.battery_percent == pytest.approx(50.0, abs=1e-6)


def test_set_battery_clamps_and_moves_the_voltage() -> None:
    b = Battery(full_voltage=16.8, empty_voltage=14.0, endurance_s=100.0)
    v = Vehicle(SOLO.kinematics, battery=b)
    v.set_battery(25.0)
    assert (v.battery_percent, v.voltage) == (25.0, pytest.approx(14.7))
    v.set_battery(-5.0)
    assert (v.battery_percent, v.voltage) == (0.0, pytest.approx(14.0))
    v.set_battery(140.0)
    assert (v.battery_percent, v.voltage) == (100.0, pytest.approx(16.8))
    bare = Vehicle(SOLO.kinematics)
    bare.set_battery(30.0)
    assert (bare.battery_percent, bare.voltage) == (30.0, 0.0), "no model: the voltage stays"


def test_no_battery_model_never_drains() -> None:
    v = Vehicle(SOLO.kinematics)
    v.arm()
    for _ in range(1000):
        v.step()
    assert v.battery_percent == 100.0


# ------------------------------------------------------------------ determinism, cost


def trace(cmds: list[tuple[Any, ...]]) -> list[tuple[Any, ...]]:
    """Every state of a solo running `cmds`, as exact floats."""
    v = Vehicle.from_profile(SOLO, x=3.0, y=-4.0)
    out = []
    for c in cmds:
        if c[0] == "wait":
            for _ in range(c[1]):
                v.step()
                out.append((v.x, v.y, v.z, v.vx, v.vy, v.vz, v.status, v.battery_percent))
        elif c[0] == "goto":
            v.goto(*c[1:])
        else:
            getattr(v, c[0])(*c[1:])
    return out


def test_deterministic() -> None:
    cmds = [
        ("arm",),
        ("takeoff", 4.0),
        ("wait", 40),
        ("goto", 17.3, -8.1, 6.0),
        ("wait", 33),
        ("goto", -5.0, 12.0, 3.0),
        ("wait", 25),
        ("hold",),
        ("wait", 10),
        ("land",),
        ("wait", 100),
    ]
    a = trace(cmds)
    b = trace(cmds)
    assert a == b
    assert len(set(a)) > 100  # it did move


def test_vehicle_has_slots() -> None:
    v = Vehicle(SOLO.kinematics)
    with pytest.raises(AttributeError):
        v.colour = "red"  # type: ignore[attr-defined]


def test_invalid_kinematics_rejected() -> None:
    bad = Kinematics(1.0, 1.0, 0.0, 1.0, 5.0, 0.5)
    with pytest.raises(ValueError):
        Vehicle(bad)
    Vehicle(bad, ground=True)  # vertical limits do not matter on wheels
