"""The simulator: tick order, determinism, safe state on script errors, radio accounting."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fieldkit.robot.neighbors import NEIGHBOR_TIMEOUT_S
from fieldkit.sim.simulator import (
    TICK_S,
    ConfigError,
    RcCommand,
    SimConfig,
    Simulation,
)

TAKEOFF = """
s = swarm.create(1)
v = stigmergy.create(1)
function init() { s.join()  BVMSTATE = "TURNEDOFF" }
neighbors.listen("cmd", function(t, val, sender) {
  if (BVMSTATE == "TURNEDOFF") BVMSTATE = "TAKEOFF"
})
function step() {
  if (flight.rc_cmd == 22) BVMSTATE = "TAKEOFF"
  if (BVMSTATE == "TAKEOFF") {
    neighbors.broadcast("cmd", 22)
    uav_takeoff(TARGET_ALTITUDE)
    if (pose.position.altitude >= TARGET_ALTITUDE * 0.95) BVMSTATE = "FLYING"
  }
  v.put(id, neighbors.count())
  if (id == 3 and BVMSTATE == "FLYING" and BROKEN == 1) { var x = 1 / 0 }
}
"""


def script(tmp_path: Path, src: str = TAKEOFF) -> Path:
    p = tmp_path / "behavior.bzz"
    p.write_text(src)
    return p


def run(tmp_path: Path, **kw: object) -> Simulation:
    cfg = SimConfig(
        script=script(tmp_path),
        robots=kw.pop("robots", 5),  # type: ignore[arg-type]
        seconds=kw.pop("seconds", 20.0),  # type: ignore[arg-type]
        commands=[RcCommand(1.0, 1, 22)],
        **kw,  # type: ignore[arg-type]
    )
    sim = Simulation(cfg)
    sim.run()
    return sim


def test_a_command_spreads_and_everyone_takes_off(tmp_path: Path) -> None:
    sim = run(tmp_path, drop=0.3, seed=2)
    summary = sim.summary()
    assert summary["final_states"] == {str(i): "FLYING" for i in range(1, 6)}
    assert summary["errors"] == []
    for r in sim.robots.values():
        assert r.vehicle.z == pytest.approx(sim.profile.kinematics.takeoff_altitude_m, abs=0.5)
    assert 0 < summary["max_bundle_bytes"] <= 190
    assert summary["seconds_simulated"] == 20.0


def test_same_seed_same_run_bit_for_bit(tmp_path: Path) -> None:
    first, again, other = (run(tmp_path, drop=0.5, seed=s) for s in (7, 7, 8))
    parsed = run(tmp_path, drop=0.5, seed=7, decode_bundles=True)  # the bytes say the same
    assert json.dumps(parsed.summary()) == json.dumps(first.summary())
    assert json.dumps(first.summary()) == json.dumps(again.summary())
    assert [r.vehicle.position for r in first.robots.values()] == [
        r.vehicle.position for r in again.robots.values()
    ]
    assert first.radio.dropped == again.radio.dropped != other.radio.dropped


def test_a_script_error_holds_that_robot_and_the_rest_go_on(tmp_path: Path) -> None:
    cfg = SimConfig(
        script=script(tmp_path),
        robots=5,
        seconds=25.0,
        commands=[RcCommand(1.0, 1, 22)],
        globals={"BROKEN": 1},
    )
    sim = Simulation(cfg)
    sim.run()
    errors = sim.summary()["errors"]
    assert len(errors) == 1 and errors[0]["robot"] == 3
    assert "behavior.bzz:16:" in errors[0]["error"] and "division by zero" in errors[0]["error"]
    # At the `/` itself (1-based column), with the Buzz call stack under it.
    col = TAKEOFF.splitlines()[15].index("/") + 1
    assert errors[0]["error"].splitlines() == [
        f"{cfg.script}:16:{col}: division by zero",
        "  in step, called by the host",
    ]
    held = sim.robots[3].vehicle
    assert held.z >= 4.5 and held.velocity == (0.0, 0.0, 0.0)  # hovering, not falling
    assert all(sim.robots[i].state == "FLYING" for i in (1, 2, 4, 5))


def test_ground_robots_never_fly(tmp_path: Path) -> None:
    sim = run(tmp_path, profile="husky", robots=3, seconds=10.0)
    assert all(r.vehicle.z == 0.0 for r in sim.robots.values())
    assert sim.summary()["errors"] == []


@pytest.mark.parametrize(
    "kw,words",
    [
        ({"robots": 0}, "--robots"),
        ({"drop": 1.5}, "--drop"),
        ({"latency": 0}, "--latency"),
        ({"range_m": -1.0}, "--range"),
        ({"seconds": 0.0}, "--seconds"),
        ({"commands": [RcCommand(1.0, 9, 22)]}, "robots are 1..2"),
        ({"profile": "nosuch"}, "--profile"),
    ],
)
def test_invalid_parameters_are_clear_errors(tmp_path: Path, kw: dict, words: str) -> None:
    base = {"script": script(tmp_path), "robots": 2}
    base.update(kw)
    with pytest.raises(ConfigError, match=words):
        Simulation(SimConfig(**base))  # type: ignore[arg-type]


@pytest.mark.parametrize("text", ["1:2", "x:1:22", "1:1:16:50", "-1:1:22"])
def test_bad_command_syntax(text: str) -> None:
    with pytest.raises(ConfigError, match="--command"):
        RcCommand.parse(text)


def test_command_with_waypoint_params() -> None:
    c = RcCommand.parse("12.5:1:16:50:45.5:-73.6:10")
    assert c == RcCommand(12.5, 1, 16, (50.0, 45.5, -73.6, 10.0))


def test_bursty_losses(tmp_path: Path) -> None:
    sim = run(tmp_path, drop=0.3, burst=4.0, seed=3)
    assert sim.radio.model.bursts is not None
    assert sim.summary()["final_states"] == {str(i): "FLYING" for i in range(1, 6)}
    with pytest.raises(ConfigError, match="--burst"):
        Simulation(SimConfig(script=script(tmp_path), robots=2, drop=0.9, burst=1.0))


def test_a_robot_not_heard_for_the_timeout_leaves_its_neighbours(tmp_path: Path) -> None:
    """A robot that goes silent stays a neighbour where it was last heard, for
    NEIGHBOR_TIMEOUT_S, and is gone after; the others are unaffected."""
    src = "function init() {}\nfunction step() {}\n"
    cfg = SimConfig(script=script(tmp_path, src), robots=4, seconds=60.0, range_m=50.0)
    sim = Simulation(cfg)
    for _ in range(5):
        sim.step()

    def poses(rid: int) -> dict:
        return dict(sim.robots[rid].vm.neighbors.poses() or {})

    assert sorted(poses(1)) == [2, 3, 4]
    where = poses(1)[4]["distance"]
    sim.robots[4].vehicle.x += 1000.0  # out of everyone's range: silent from now on
    # Its last bundle, sent before it moved, is heard one tick later (latency 1).
    timeout = round(NEIGHBOR_TIMEOUT_S / TICK_S)
    for _ in range(timeout + 1):
        sim.step()
        assert sorted(poses(1)) == [2, 3, 4] and poses(1)[4]["distance"] == where
    sim.step()
    assert sorted(poses(1)) == [2, 3] and sorted(poses(2)) == [1, 3] and poses(4) == {}
