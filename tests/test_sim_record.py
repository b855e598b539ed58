"""`sim run --record`: one bag per simulated robot, each replaying its robot exactly."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from fieldkit.record.flight_bag import read_flight
from fieldkit.sim.experiments import make_plan
from fieldkit.sim.replay import replay_sim
from fieldkit.sim.simulator import Simulation
from fieldkit.update.keys import RobotKeys

SWARM = bytes(range(32))
OPERATOR = Ed25519PrivateKey.from_private_bytes(b"\x05" * 32)
KEYS = RobotKeys(OPERATOR.public_key(), SWARM)


def simulate(out: Path | None, *, drop: float = 0.5, signed: bool = False,
             attacks: tuple[str, ...] = ()) -> Simulation:  # fmt: skip
    plan = make_plan("task-allocation", robots=[6], drops=[drop], runs=1, seed=2, seconds=30)
    config = dataclasses.replace(
        plan.specs()[0].config(),
        security="signed" if signed else "none",
        swarm_key=SWARM,
        operator_pub=OPERATOR.public_key() if signed else None,
        attacks=attacks,
    )
    sim = Simulation(config)
    if out is not None:
        sim.record(out)
    logging.disable(logging.WARNING)
    try:
        sim.run()
    finally:
        logging.disable(logging.NOTSET)
        sim.close_recording()
    return sim


def test_recording_changes_nothing_and_every_robot_replays(tmp_path: Path) -> None:
    plain = simulate(None)
    recorded = simulate(tmp_path / "bags")
    assert recorded.summary() == plain.summary()  # bit for bit, recording or not
    for rid in recorded.robots:
        flight = read_flight(tmp_path / "bags" / f"robot{rid}")
        assert len(flight.ticks) == 300
        report = replay_sim(flight)
        assert report.divergence is None, (rid, report.divergence)
        assert report.digests == 300 and report.frames >= 300


def test_a_signed_attacked_robot_replays_with_its_keys(tmp_path: Path) -> None:
    simulate(tmp_path / "bags", signed=True, attacks=("forge", "command"))
    flight = read_flight(tmp_path / "bags" / "robot3")
    assert any(s == 65535 for t in flight.ticks for s, _ in t.radio_in)  # the attacker's
    report = replay_sim(flight, keys=KEYS)
    assert report.divergence is None, report.divergence
    from fieldkit.record.compare import ReplayError

    with pytest.raises(ReplayError, match="keys"):
        replay_sim(flight)


def test_a_changed_script_diverges(tmp_path: Path) -> None:
    import bvm
    from fieldkit import resources

    simulate(tmp_path / "bags")
    flight = read_flight(tmp_path / "bags" / "robot1")
    src = resources.find_script(Path("task_allocation.bzz"))
    changed = src.read_text().replace("ANNOUNCE", "ANNOUNCE ", 0)  # same text: same program
    program = bvm.compile_source(changed + "\nfunction extra() { return 1 }\n", str(src),
                                 include_dirs=[str(src.parent)])  # fmt: skip
    report = replay_sim(flight, program=program)
    assert report.divergence is not None and report.divergence.tick == 0


def test_sim_run_record_then_replay_verify_on_the_command_line(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from fieldkit.cli import app

    runner = CliRunner()
    bags = tmp_path / "bags"
    result = runner.invoke(
        app,
        ["sim", "run", "task_allocation.bzz", "--robots", "3", "--seconds", "3", "--drop",
         "0.3", "--out", str(tmp_path / "run"), "--record", str(bags)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert all(f"wrote {bags / f'robot{r}'}" in result.stderr for r in (1, 2, 3))
    result = runner.invoke(app, ["replay", str(bags / "robot2"), "--verify"])
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines()[-1].startswith("replay: identical: 30 ticks")
    result = runner.invoke(
        app,
        ["sim", "run", "task_allocation.bzz", "--robots", "3", "--seconds", "3",
         "--out", str(tmp_path / "run2"), "--record", str(bags)],
    )  # fmt: skip
    assert result.exit_code == 1 and "exists already" in result.stderr


def test_ros1_bags_record_and_replay_the_same(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from fieldkit.cli import app

    runner = CliRunner()
    bags = tmp_path / "bags"
    result = runner.invoke(
        app,
        ["sim", "run", "task_allocation.bzz", "--robots", "2", "--seconds", "2",
         "--out", str(tmp_path / "run"), "--record", str(bags), "--ros1"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert (bags / "robot1.bag").is_file()
    result = runner.invoke(app, ["replay", str(bags / "robot1.bag"), "--verify"])
    assert result.exit_code == 0, result.output
