"""The safety supervisor: fence, ceiling, speed carrot, failsafes and the pilot's override."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest

from fieldkit.robot import geo
from fieldkit.robot.profiles import Geofence, load_profile
from fieldkit.robot.safety import Order, Supervisor
from fieldkit.robot.script_api import IN_AIR, ON_GROUND, Command, Sensors

FRAME = geo.LocalFrame(45.5, -73.6, 0.0)


def fenced_solo(half: float = 50.0) -> Supervisor:
    solo = load_profile("solo")
    corners = []
    for north, east in ((-half, -half), (-half, half), (half, half), (half, -half)):
        lat, lon, _ = FRAME.to_gps(east, north, 0.0)
        corners.append((lat, lon))
    profile = dataclasses.replace(solo, geofence=Geofence(tuple(corners), 30.0))
    return Supervisor(profile, FRAME)


def flying(flying: bool = True, **kw: float) -> Sensors:
    """What the supervisor sees of a vehicle: in the air at 10 m unless told otherwise."""
    base: dict[str, Any] = {"lat": 0.0, "lon": 0.0, "north": 0.0, "east": 0.0, "alt": 10.0}
    base["battery_percent"] = 90.0
    base["status"] = IN_AIR if flying else ON_GROUND
    base.update(kw)
    return Sensors(**base)


def test_goto_is_followed_with_a_speed_limited_carrot() -> None:
    sup = fenced_solo()
    sup.submit([Command("goto", (30.0, 40.0, 10.0))])
    order = sup.tick(flying())
    step = sup.max_speed * 1.0
    assert order is not None and order.kind == "goto"
    assert order.args[0] == pytest.approx(30.0 / 50.0 * step)
    assert order.args[1] == pytest.approx(40.0 / 50.0 * step)
    # Near the target, the target itself.
    assert sup.tick(flying(north=29.5, east=39.5)) == Order("goto", (30.0, 40.0, 10.0))


def test_targets_outside_the_fence_or_above_the_ceiling_are_clamped() -> None:
    sup = fenced_solo(half=50.0)
    sup.submit([Command("goto", (0.0, 200.0, 80.0))])
    sup.max_speed = 1e6  # look at the clamped target itself, not the carrot
    order = sup.tick(flying())
    assert order == Order("goto", (0.0, pytest.approx(50.0), 30.0))
    assert sup.clamped == 2


def test_outside_the_fence_already_means_stay() -> None:
    sup = fenced_solo(half=50.0)
    sup.max_speed = 1e6
    sup.submit([Command("goto", (0.0, 300.0, 10.0))])
    assert sup.tick(flying(east=100.0)) == Order("goto", (0.0, 100.0, 10.0))


def test_commands_go_in_order_one_per_tick() -> None:
    sup = fenced_solo()
    sup.submit([Command("arm"), Command("takeoff", (50.0,)), Command("goto", (1.0, 1.0, 5.0))])
    ground = flying(flying=False, alt=0.0)
    assert sup.tick(ground) == Order("arm")
    assert sup.tick(ground) == Order("takeoff", (30.0,))  # capped at the ceiling
    assert sup.tick(flying()).kind == "goto"


def test_ground_robots_never_take_off_and_stay_at_zero() -> None:
    sup = Supervisor(load_profile("husky"), FRAME)
    sup.submit([Command("takeoff", (10.0,)), Command("goto", (3.0, 4.0, 20.0))])
    order = sup.tick(flying(flying=False, alt=0.0))
    assert order is not None and order.kind == "goto" and order.args[2] == 0.0
    assert "takeoff refused: ground robot" in sup.events


def test_script_error_goes_to_the_safe_state_once_and_latches() -> None:
    sup = fenced_solo()
    sup.script_error("robot.bzz:3:4: division by zero")
    assert sup.tick(flying()) == Order("hold")  # solo: on_script_error = "hold"
    sup.submit([Command("goto", (10.0, 0.0, 10.0))])
    assert sup.tick(flying()) is None and sup.tick(flying()) is None
    assert any("robot.bzz:3:4" in e for e in sup.events)


def test_heartbeat_loss_then_recovery() -> None:
    sup = fenced_solo()  # solo: on_heartbeat_loss = "land"
    sup.submit([Command("goto", (10.0, 0.0, 10.0))])
    assert sup.tick(flying(heartbeat_age_s=5.0)) is None  # nothing reaches it now
    assert sup.tick(flying(heartbeat_age_s=9.0)) is None
    assert sup.tick(flying()) == Order("land")  # the link is back: the action goes out
    for _ in range(100):
        assert sup.tick(flying()) is None  # landing is never undone


def test_heartbeat_loss_with_hold_gives_the_robot_back() -> None:
    sup = Supervisor(load_profile("husky"), FRAME)  # husky: on_heartbeat_loss = "stop"
    assert sup.tick(flying(flying=False, heartbeat_age_s=10.0)) is None
    assert sup.tick(flying(flying=False)) == Order("hold")
    for _ in range(sup.recovery_ticks - 1):
        assert sup.tick(flying(flying=False)) is None
    sup.tick(flying(flying=False))
    assert sup.failsafe is None
    sup.submit([Command("goto", (1.0, 0.0, 0.0))])
    assert sup.tick(flying(flying=False)).kind == "goto"  # type: ignore[union-attr]


def test_low_battery_triggers_the_profile_action() -> None:
    sup = fenced_solo()  # solo: on_low_battery = "rtl" below 25 %
    sup.submit([Command("goto", (10.0, 0.0, 10.0))])
    assert sup.tick(flying(battery_percent=30.0)).kind == "goto"  # type: ignore[union-attr]
    assert sup.tick(flying(battery_percent=20.0)) == Order("rtl")
    assert sup.tick(flying(battery_percent=20.0)) is None


def test_the_pilot_always_wins() -> None:
    sup = fenced_solo()
    sup.submit([Command("goto", (10.0, 0.0, 10.0))])
    assert sup.tick(flying(rc_override=True)) is None
    sup.script_error("x")
    assert sup.tick(flying(rc_override=True)) is None
    assert sup.tick(flying()) == Order("hold")


def test_a_command_repeated_every_step_goes_out_once_then_after_the_resend_delay() -> None:
    sup = fenced_solo()
    ground = flying(flying=False, alt=0.0)
    sent = []
    for _ in range(sup.resend_ticks + 5):
        sup.submit([Command("takeoff", (10.0,))])
        sent.append(sup.tick(ground))
    assert sent[0] == Order("takeoff", (10.0,))
    assert sent[1 : sup.resend_ticks] == [None] * (sup.resend_ticks - 1)
    assert sent[sup.resend_ticks] == Order("takeoff", (10.0,))
    sup.submit([Command("land")])
    assert sup.tick(flying()) == Order("land")  # another command goes at once
