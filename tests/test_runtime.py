"""The robot runtime: one tick for every host.

The same script with the same inputs runs through the simulator's host and through the
field node's host (against the simulated ArduPilot on a pty, over MAVLink) and must go
through the same script states; and the behaviours that used to differ between the copies
of the tick are pinned here once.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import pytest
from rigs import RIG_HOME, SimRig

import bvm
from fieldkit.errors import ConfigError
from fieldkit.node.autopilot_port import MavlinkAutopilot
from fieldkit.node.node import Node
from fieldkit.robot import (
    Command,
    RcCommand,
    RobotRuntime,
    ScriptStatus,
    Sensors,
    TickRecord,
    geo,
)
from fieldkit.robot import bundle as wirebundle
from fieldkit.robot.profiles import load_profile
from fieldkit.sim.simulator import SimConfig, Simulation

HOME = RIG_HOME

FLY = """
function init() { BVMSTATE = "TURNEDOFF" }
function step() {
  if (flight.rc_cmd == 22) BVMSTATE = "TAKEOFF"
  if (BVMSTATE == "TAKEOFF") {
    uav_takeoff(TARGET_ALTITUDE)
    if (pose.position.altitude > TARGET_ALTITUDE * 0.9) {
      BVMSTATE = "GO"
      goto_abs(20.0, 0.0, 0.0, 0.0)
      north0 = pose.position.x
    }
  } else if (BVMSTATE == "GO") {
    if (pose.position.x - north0 > 19.0) BVMSTATE = "THERE"
  }
}
"""


def states_of(runtime: RobotRuntime) -> list[str | None]:
    """The script state after each tick, as an observer of the runtime sees it."""
    seen: list[str | None] = []

    def watch(record: TickRecord) -> None:
        seen.append(record.state)

    runtime.observer = watch
    return seen


def transitions(states: list[str | None]) -> list[tuple[int, str | None]]:
    """(tick, new state) of every change."""
    out = []
    for k, s in enumerate(states):
        if k == 0 or s != states[k - 1]:
            out.append((k, s))
    return out


def test_the_simulator_and_the_node_go_through_the_same_states(rig: SimRig, tmp_path: Path) -> None:
    ticks = 300
    script = tmp_path / "fly.bzz"
    script.write_text(FLY)
    command = RcCommand(0.5, 1, 22)
    # The simulator's host: one robot at the rig's home.
    sim = Simulation(
        SimConfig(
            script=script, robots=1, seconds=ticks / 10, commands=[command], origin=(*HOME, 0.0)
        )
    )
    sim_states = states_of(sim.robots[1].runtime)
    sim.run()
    # The node's host: the same runtime against a simulated ArduPilot over MAVLink.
    t = rig.link.telemetry
    home = (t.lat, t.lon, 0.0)
    node = Node(
        rig.profile,
        bvm.compile_file(script),
        1,
        MavlinkAutopilot(rig.link, home),
        None,
        home=home,
        commands=[command],
        clock=rig.clock,
        out=lambda _text: None,
    )
    node_states = states_of(node.runtime)
    for _ in range(ticks):
        node.tick()
        rig.tick()
    assert len(sim_states) == len(node_states) == ticks
    sim_path, node_path = transitions(sim_states), transitions(node_states)
    # Same states in the same order...
    assert (
        [s for _, s in sim_path]
        == [s for _, s in node_path]
        == ["TURNEDOFF", "TAKEOFF", "GO", "THERE"]
    )
    # ...at the same ticks, but for the autopilot's handshakes (mode, arming, ACKs over
    # MAVLink take a few ticks a real robot also takes): within 1.5 s.
    for (k_sim, _), (k_node, _) in zip(sim_path, node_path, strict=True):
        assert abs(k_sim - k_node) <= 15, (sim_path, node_path)
    # And tick for tick the states agree nearly everywhere.
    same = sum(a == b for a, b in zip(sim_states, node_states, strict=True))
    assert same >= ticks - 3 * 15


# ---------------------------------------------------------------- the runtime alone


def sensors(**kw: float) -> Sensors:
    base = {"lat": HOME[0], "lon": HOME[1], "alt": 0.0, "north": 0.0, "east": 0.0}
    base.update(kw)
    return Sensors(**base)  # type: ignore[arg-type]


def runtime(src: str, profile: str = "solo", robot_id: int = 1, seed: int = 0) -> RobotRuntime:
    r = RobotRuntime(robot_id, load_profile(profile), geo.LocalFrame(*HOME), seed=seed)
    r.start(bvm.compile_source(src), sensors())
    return r


def test_each_robot_draws_its_own_random_numbers() -> None:
    """The node used to seed every robot's script API with 0: same "random" goals."""
    src = "function init() { r = math.rng.uniform(1000.0) }\nfunction step() {}"
    draws = {runtime(src, robot_id=rid).vm["r"] for rid in (1, 2, 3)}
    assert len(draws) == 3
    assert runtime(src, robot_id=2).vm["r"] == runtime(src, robot_id=2).vm["r"]


def test_supervisor_events_are_drained_and_a_repeat_logged_rarely(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A ground robot's script asking to take off every tick: one event per tick, counted,
    logged the first time and every EVENT_LOG_EVERY times, never piling up."""
    r = runtime("function step() { uav_takeoff(5.0) }", profile="husky")
    with caplog.at_level(logging.WARNING, logger="fieldkit.robot"):
        for _ in range(250):
            r.tick(sensors())
    assert r.supervisor.events == []
    assert r.event_counts["takeoff refused: ground robot"] == 250
    logged = [m for m in caplog.messages if "takeoff refused" in m]
    assert len(logged) == 3  # 1st, 100th, 200th


def test_the_heartbeat_failsafe_fires_wherever_the_runtime_runs() -> None:
    """The simulator never passed heartbeat age to the supervisor; the runtime always does."""
    r = runtime("function step() { goto_abs(5.0, 0.0, 0.0) }")
    flying = sensors(alt=10.0, status=2)
    assert r.tick(flying).order is not None
    flying.heartbeat_age_s = 60.0
    assert r.tick(flying).order is None
    assert r.supervisor.failsafe == "autopilot heartbeat lost"


def test_a_waypoint_command_carries_its_parameters() -> None:
    r = runtime("function step() { got = rc_goto.id  lat = rc_goto.latitude }")
    c = RcCommand.parse("1:1:16:7:45.6:-73.5:12")
    r.tick(sensors(), c)
    assert r.vm["got"] == 7 and r.vm["lat"] == pytest.approx(45.6, abs=1e-5)
    # SITL hands it on to a node in the same T:ROBOT:CODE form, parameters included.
    assert RcCommand.parse(c.text()) == c


def test_another_codes_first_param_reaches_the_script_for_one_tick() -> None:
    r = runtime("function step() { p = flight.rc_param  q = isnil(rc_goto) }")
    r.tick(sensors(), RcCommand.parse("1:1:900:4"))
    assert r.vm["p"] == 4 and isinstance(r.vm["p"], int)  # an id stays an integer
    r.tick(sensors())
    assert r.vm["p"] is None  # like rc_cmd, visible for the command's tick only
    r.tick(sensors(), RcCommand.parse("1:1:904:0.1"))
    assert r.vm["p"] == pytest.approx(0.1) and r.vm["p"] != 0.1  # a Buzz float: binary32
    r.tick(sensors(), RcCommand.parse("1:1:16:7:45.6:-73.5:12"))
    assert r.vm["p"] is None  # a waypoint's params are rc_goto's
    with pytest.raises(ConfigError, match="finite"):
        RcCommand.parse("1:1:900:nan")


def test_the_bundle_budget_is_the_profiles() -> None:
    solo = load_profile("solo")
    small = dataclasses.replace(
        solo, radio=dataclasses.replace(solo.radio, per_step_budget_bytes=64)
    )
    src = 'function step() { var i = 0  while (i < 40) { neighbors.broadcast("k", i)  i = i + 1 } }'
    sizes = []
    for profile in (solo, small):
        r = RobotRuntime(1, profile, geo.LocalFrame(*HOME))
        r.start(bvm.compile_source(src), sensors())
        out = r.tick(sensors())
        assert wirebundle.decode(out.bundle).messages == out.messages
        sizes.append(wirebundle.block_size(out.messages))
    assert sizes[0] > 64 >= sizes[1] > 64 - 12  # 12: one more message would not fit
    assert sizes[0] <= wirebundle.MAX_MSG_SIZE


def test_a_failed_script_keeps_the_robot_visible() -> None:
    r = runtime("function step() { var x = 1 / 0 }")
    out = r.tick(sensors(alt=10.0, status=2))
    assert r.status is ScriptStatus.FAILED and "division by zero" in (r.error or "")
    assert out.order is not None and out.order.kind == "hold"  # solo: on_script_error
    later = r.tick(sensors(alt=10.0, status=2))
    b = wirebundle.decode(later.bundle)
    assert b.robot == 1 and b.messages == () and b.lat == pytest.approx(HOME[0])


def test_start_again_switches_the_program_and_keeps_what_the_robot_knows() -> None:
    r = runtime("function step() { v = 1 }")
    r.hear(7, (3.0, 4.0, 0), ())
    r.tick(sensors())
    assert r.start(bvm.compile_source("function step() { v = 2 }"), sensors())
    r.tick(sensors())
    assert r.vm["v"] == 2 and 7 in r.heard and r.ticks == 2


def test_neighbours_time_out_in_ticks() -> None:
    r = runtime("function step() { n = neighbors.count() }")
    r.receive_bundle(wirebundle.encode(wirebundle.Bundle(9, (), HOME[0] + 1e-4, HOME[1], 0.0)))
    r.receive_bundle(b"garbage")
    assert r.counters["bundle_errors"] == 1
    for _ in range(r.timeout + 1):
        r.tick(sensors())
        assert r.vm["n"] == 1
    r.tick(sensors())
    assert r.vm["n"] == 0 and r.heard == {}


def test_rtl_is_the_autopilots_return_in_the_simulator_too(tmp_path: Path) -> None:
    """rtl used to be a goto-home at the current altitude in the simulator and a mode
    change on the node; the simulated vehicle now flies ArduPilot's RTL: climb to at
    least RTL_ALT_M, fly home, land."""
    from fieldkit.sim.simulator import RTL_ALT_M

    script = tmp_path / "rtl.bzz"
    script.write_text(
        """
function init() { BVMSTATE = "UP" }
function step() {
  if (BVMSTATE == "UP") {
    uav_takeoff(TARGET_ALTITUDE)
    if (pose.position.altitude > TARGET_ALTITUDE * 0.95) { BVMSTATE = "OUT" }
  } else if (BVMSTATE == "OUT") {
    goto_abs(30.0, 0.0, 0.0, 0.0)
    BVMSTATE = "GOING"
  } else if (BVMSTATE == "GOING" and pose.position.x > 25.0) {
    gohome()
    BVMSTATE = "HOME"
  }
}
"""
    )
    sim = Simulation(SimConfig(script=script, robots=1, seconds=60.0))
    v = sim.robots[1].vehicle
    home = (v.x, v.y)
    top = 0.0
    while sim.tick < 600:
        sim.step()
        if sim.robots[1].state == "HOME":
            top = max(top, v.z)
    assert sim.robots[1].state == "HOME"
    assert top == pytest.approx(RTL_ALT_M)  # it climbed first
    assert (v.x, v.y, v.z) == pytest.approx((*home, 0.0), abs=1e-6)
    assert v.status == 1 and not v.armed  # landed and disarmed


def test_a_goto_target_is_reached_within_the_profiles_hover_accuracy() -> None:
    """hover_accuracy_m was parsed and never used; the supervisor answers with it."""
    r = runtime("function step() {}")
    sup = r.supervisor
    accuracy = r.profile.kinematics.hover_accuracy_m
    assert not sup.arrived(sensors(alt=10.0, status=2))  # no target yet
    sup.submit([Command("goto", (30.0, 40.0, 10.0))])
    sup.tick(sensors(alt=10.0, status=2))
    near = 0.9 * accuracy
    assert sup.arrived(sensors(north=30.0 - near, east=40.0, alt=10.0, status=2))
    assert not sup.arrived(sensors(north=30.0 - 1.5 * accuracy, east=40.0, alt=10.0, status=2))
    assert not sup.arrived(sensors(north=30.0, east=40.0, alt=10.0 + 1.5 * accuracy, status=2))


def test_set_globals_reach_the_global_code_and_win_over_its_defaults() -> None:
    """`--set`: the global code sees the value (`isnil` defaults) and a plain assignment
    does not override it, so `init()` always reads what the operator gave."""
    src = """
if (isnil(SHAPE)) { SHAPE = "P" }
MARGIN = 20
seen_in_global_code = MARGIN
function init() { at_init = string.concat(SHAPE, ":", string.tostring(MARGIN)) }
function step() {}
"""
    r = RobotRuntime(1, load_profile("solo"), geo.LocalFrame(*HOME))
    assert r.start(bvm.compile_source(src), sensors(), {"SHAPE": "Y", "MARGIN": 5})
    assert r.vm["at_init"] == "Y:5" and r.vm["seen_in_global_code"] == 20
