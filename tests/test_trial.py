"""A new version's trial: the real simulator, a small swarm per profile, its script errors."""

from __future__ import annotations

from pathlib import Path

import pytest

import bvm
from fieldkit.errors import ConfigError
from fieldkit.robot.profiles import load_profile
from fieldkit.sim.simulator import SimConfig, Simulation, StartPose
from fieldkit.sim.trial import StartState, trial
from fieldkit.vehicle.kinematics import Vehicle

# Takes off, moves, talks to its neighbours and shares a stigmergy: the closures a field
# script uses, on a UAV and on a ground robot alike.
GOOD = """
s = swarm.create(1)
v = stigmergy.create(1)
function init() { s.join()  t = 0 }
neighbors.listen("hello", function(topic, value, sender) { last = value })
function step() {
  t = t + 1
  if (t == 3) uav_takeoff(5.0)
  if (t > 25) goto_abs(0.1, 0.0, 0.0)
  neighbors.broadcast("hello", id)
  v.put(id, neighbors.count())
}
"""

# Robot 2 divides by zero in its step at simulated second 2 (tick 20).
AT_SECOND_2 = """
function init() { t = 0 }
function step() {
  if (t == 20 and id == 2) { var x = 1 / 0 }
  t = t + 1
}
"""


def program(tmp_path: Path, source: str, name: str = "s.bzz") -> bvm.Program:
    path = tmp_path / name
    path.write_text(source)
    return bvm.compile_file(path)


def test_a_good_script_passes_on_two_profiles(tmp_path: Path) -> None:
    assert trial(program(tmp_path, GOOD), ["solo", "husky"]) == []


def test_an_error_at_second_2_is_named_with_its_place_robot_and_time(tmp_path: Path) -> None:
    errors = trial(program(tmp_path, AT_SECOND_2), ["solo", "husky"], seconds=3.0)
    col = AT_SECOND_2.splitlines()[3].index("/") + 1
    where = f"{tmp_path / 's.bzz'}:4:{col}: division by zero"
    assert errors == [
        f"{where} (robot 2 of the solo swarm, at 2.0 s simulated)\n  in step, called by the host",
        f"{where} (robot 2 of the husky swarm, at 2.0 s simulated)\n  in step, called by the host",
    ]
    # Before second 2 nothing went wrong: a shorter trial passes (the error is in step 20).
    assert trial(program(tmp_path, AT_SECOND_2), ["solo"], seconds=2.0) == []


def test_the_same_error_on_every_robot_is_one_entry_naming_them(tmp_path: Path) -> None:
    errors = trial(program(tmp_path, "function step() { x = nil + 1 }\n"), ["solo"], robots=4)
    assert len(errors) == 1
    assert "s.bzz:1:" in errors[0] and "(robots 1, 2, 3, 4 of the solo swarm, first at" in errors[0]


def test_errors_in_the_global_code_and_init_refuse_too(tmp_path: Path) -> None:
    errors = trial(program(tmp_path, "x = 1 / 0\nfunction step() {}\n"), ["solo"], robots=1)
    assert len(errors) == 1 and "s.bzz:1:" in errors[0] and "at 0.0 s" in errors[0]
    no_step = trial(program(tmp_path, "function init() {}\n"), ["solo"], robots=1)
    assert len(no_step) == 1 and "robot 1 of the solo swarm" in no_step[0]


# Fails unless the robot starts where the swarm's state says: flying at 8 m over (10, 5).
CHECKS_START = """
function init() {
  if (flight.status != 2 or pose.position.altitude < 7.9) { var x = 1 / 0 }
}
function step() {}
"""


def test_a_trial_starts_from_the_swarm_state_when_known(tmp_path: Path) -> None:
    prog = program(tmp_path, CHECKS_START)
    flying = StartState({4: StartPose(10.0, 5.0, 8.0, True), 7: StartPose(-3.0, 2.0, 8.0, True)})
    assert trial(prog, ["solo"], start=flying) == []
    landed = StartState({4: StartPose(10.0, 5.0, 8.0, True), 7: StartPose(-3.0, 2.0)})
    errors = trial(prog, ["solo"], start=landed)
    assert len(errors) == 1 and "(robot 7 of the solo swarm, at 0.0 s simulated)" in errors[0]


def test_a_simulation_places_the_start_state_s_robots(tmp_path: Path) -> None:
    poses = {4: StartPose(10.0, 5.0, 8.0, True), 9: StartPose(-3.0, 2.0)}
    cfg = SimConfig(
        script=Path("s.bzz"),
        robots=2,
        seconds=0.1,
        program=bvm.compile_source("function step() {}\n", "s.bzz"),
        start=poses,
    )
    sim = Simulation(cfg)
    assert list(sim.robots) == [4, 9]
    assert sim.robots[4].vehicle.position == (10.0, 5.0, 8.0) and sim.robots[4].vehicle.armed
    assert sim.robots[9].vehicle.position == (-3.0, 2.0, 0.0) and not sim.robots[9].vehicle.armed
    sim.run()
    assert sim.robots[4].vehicle.position == (10.0, 5.0, 8.0)  # hovering, not falling


@pytest.mark.parametrize(
    ("start", "words"),
    [
        ({1: StartPose(0.0, 0.0)}, "start state of 1 robots for a swarm of 2"),
        ({1: StartPose(0.0, 0.0), 70000: StartPose(0.0, 0.0)}, "robot id 70000"),
        ({1: StartPose(0.0, 0.0), 2: StartPose(0.0, 0.0, 0.0, True)}, "not above ground"),
        ({1: StartPose(0.0, 0.0), 2: StartPose(float("nan"), 0.0)}, "not finite"),
    ],
)
def test_a_start_state_that_cannot_be_simulated_is_a_clear_error(
    start: dict[int, StartPose], words: str
) -> None:
    with pytest.raises(ConfigError, match=words):
        SimConfig(script=Path("s.bzz"), robots=2, start=start).validate()


def test_a_ground_robot_started_under_way_stays_on_the_ground() -> None:
    husky = Vehicle.from_profile(load_profile("husky"), x=1.0, y=2.0)
    husky.start_flying(8.0)
    assert husky.armed and husky.position == (1.0, 2.0, 0.0)
    solo = Vehicle.from_profile(load_profile("solo"))
    with pytest.raises(ValueError, match="above the ground"):
        solo.start_flying(0.0)


def test_a_trial_without_a_profile_or_with_an_unknown_one_is_refused(tmp_path: Path) -> None:
    prog = program(tmp_path, GOOD)
    with pytest.raises(ConfigError, match="at least one device profile"):
        trial(prog, [])
    with pytest.raises(ConfigError, match="--profile 'nosuch'"):
        trial(prog, ["nosuch"])


def test_the_same_trial_gives_the_same_errors(tmp_path: Path) -> None:
    src = "function step() { if (math.rng.uniform(1.0) < 0.05) { var x = 1 / 0 } }\n"
    prog = program(tmp_path, src)
    first = trial(prog, ["solo"], seed=3)
    assert first and trial(prog, ["solo"], seed=3) == first
    assert trial(prog, ["solo"], seed=4) != first  # the seed is what decides
