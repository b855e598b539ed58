"""The simulator's radio security: signed swarms, and a hostile radio in their middle."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from fieldkit import resources
from fieldkit.robot import bundle_auth as A
from fieldkit.sim.attacker import ATTACKS
from fieldkit.sim.experiments import make_plan
from fieldkit.sim.simulator import ConfigError, SimConfig, Simulation

SWARM_KEY = bytes(range(32))
OPERATOR = Ed25519PrivateKey.from_private_bytes(b"\x07" * 32)
TASKS = resources.find_script(Path("task_allocation.bzz"))


def run(drop: float = 0.0, security: str = "signed", attacks: tuple[str, ...] = ()) -> Simulation:
    """The paper's task allocation (take-off, then RC 900 at 20 s) on 6 robots for 40 s."""
    plan = make_plan("task-allocation", robots=[6], drops=[drop], runs=1, seed=3, seconds=40)
    config = dataclasses.replace(
        plan.specs()[0].config(),
        security=security,
        swarm_key=SWARM_KEY,
        attacks=attacks,
        operator_pub=OPERATOR.public_key(),
    )
    sim = Simulation(config)
    sim.run()
    return sim


def outcome(sim: Simulation) -> tuple[object, ...]:
    """What the swarm did: states, positions, logs, errors."""
    s = sim.summary()
    where = {r.id: (r.vehicle.x, r.vehicle.y, r.vehicle.z) for r in sim.robots.values()}
    return s["final_states"], where, sim.log, s["errors"], sim.radio.delivered


@pytest.fixture(autouse=True)
def _quiet() -> object:
    # Every forged bundle is logged by each receiver: thousands of lines.
    logging.disable(logging.WARNING)
    yield
    logging.disable(logging.NOTSET)


@pytest.mark.parametrize("drop", [0.0, 0.5])
def test_the_attacker_changes_nothing_in_a_signed_swarm(drop: float) -> None:
    calm = run(drop)
    attacked = run(drop, attacks=ATTACKS)
    assert set(calm.summary()["final_states"].values()) == {"LOCK"}  # type: ignore[union-attr]
    assert outcome(attacked) == outcome(calm)
    sec = attacked.summary()["security"]
    assert isinstance(sec, dict)
    assert sec["accepted_from_attacker"] == 0
    sent = sec["attacker"]["sent"]
    assert set(sent) == set(ATTACKS) and all(n > 0 for n in sent.values())
    rejected = sec["rejected"]
    # Each kind meets the check it was made for.
    for reason in (A.BAD_TAG, A.TOO_OLD, A.MISSING_TRAILER, A.UNKNOWN_KEY):
        assert rejected.get(reason, 0) > 0, (reason, rejected)
    # Forged operator commands: refused by every robot's gate, none acted on.
    commands = sec["commands"]
    assert commands["bad-signature"] > 0 and commands["unknown-key"] > 0
    assert "accepted" not in commands and "relayed" not in commands
    # Honest bundles only are accepted: as many as without the attacker.
    assert sec["accepted"] == calm.summary()["security"]["accepted"]  # type: ignore[index]


def test_without_signatures_the_same_attacker_gets_in() -> None:
    calm = run(0.0, security="none")
    attacked = run(0.0, security="none", attacks=ATTACKS)
    sec = attacked.summary()["security"]
    assert isinstance(sec, dict) and sec["accepted_from_attacker"] > 0
    assert outcome(attacked)[:2] != outcome(calm)[:2]  # and the swarm does something else


def test_a_signed_bundle_costs_sixteen_bytes_on_the_air() -> None:
    plain, sealed = run(security="none"), run()
    assert plain.summary()["final_states"] == sealed.summary()["final_states"]
    gap = sealed.summary()["mean_bundle_air_bytes"] - plain.summary()["mean_bundle_air_bytes"]  # type: ignore[operator]
    assert gap == pytest.approx(A.TRAILER_BYTES, abs=0.5)


def test_an_attacked_run_is_reproducible() -> None:
    a, b = run(0.5, attacks=("forge", "flood")), run(0.5, attacks=("forge", "flood"))
    assert a.summary() == b.summary()


def test_the_configuration_is_checked() -> None:
    with pytest.raises(ConfigError, match="--keys"):
        Simulation(SimConfig(script=TASKS, robots=2, security="signed"))
    with pytest.raises(ConfigError, match="--security"):
        Simulation(SimConfig(script=TASKS, robots=2, security="maybe"))
    with pytest.raises(ConfigError, match="--attack"):
        Simulation(SimConfig(script=TASKS, robots=2, attacks=("jam",)))


def test_sim_run_with_keys_and_an_attacker_writes_the_security_summary(tmp_path: Path) -> None:
    import json

    from typer.testing import CliRunner

    from fieldkit.cli import app
    from fieldkit.update.keys import init_keys

    init_keys(tmp_path / "keys")
    runner = CliRunner()
    base = ["sim", "run", str(TASKS), "--robots", "4", "--seconds", "14", "--drop", "0.5"]
    out = tmp_path / "run"
    result = runner.invoke(
        app,
        [*base, "--out", str(out), "--security", "signed", "--keys", str(tmp_path / "keys"),
         "--attack", "replay,forge,command,flood"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "security none" not in result.output
    sec = json.loads((out / "summary.json").read_text())["security"]
    assert sec["mode"] == "signed" and sec["accepted_from_attacker"] == 0
    assert sum(sec["rejected"].values()) > 0 and set(sec["attacker"]["sent"]) == set(ATTACKS)
    # Without keys: none, said first thing on stderr; signed without keys, or a made-up
    # attack, is refused.
    result = runner.invoke(app, [*base, "--out", str(tmp_path / "plain")])
    assert result.exit_code == 0 and "warning: security none" in result.stderr
    result = runner.invoke(app, [*base, "--out", str(tmp_path / "x"), "--security", "signed"])
    assert result.exit_code == 1 and "--keys" in result.stderr
    result = runner.invoke(app, [*base, "--out", str(tmp_path / "x"), "--attack", "jam"])
    assert result.exit_code == 2 and "replay,forge,command,flood" in result.stderr


def test_a_world_readable_swarm_key_stops_a_run_naming_the_file(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from fieldkit.cli import app
    from fieldkit.update.keys import init_keys

    paths = init_keys(tmp_path / "keys")
    paths.swarm_key.chmod(0o644)
    result = CliRunner().invoke(
        app,
        ["sim", "run", str(TASKS), "--robots", "2", "--seconds", "1", "--out",
         str(tmp_path / "run"), "--keys", str(tmp_path / "keys")],
    )  # fmt: skip
    assert result.exit_code == 1 and result.stderr.startswith("error: ")
    assert str(paths.swarm_key) in result.stderr and "chmod 600" in result.stderr
    assert not (tmp_path / "run").exists()  # stopped before anything ran


def test_out_of_range_the_attacker_can_only_relay_genuine_bundles_late() -> None:
    # Robots 80 m apart with 50 m of range do not hear each other; the attacker between
    # them hears both. What it records of one, re-sent 10-20 s later, reaches the other,
    # which never heard that robot: a late relay of genuine bytes (docs/security.md#replay-
    # rules). Nothing it made up is ever accepted.
    config = SimConfig(
        script=TASKS,
        robots=2,
        seconds=30.0,
        spacing_m=80.0,
        range_m=50.0,
        security="signed",
        swarm_key=SWARM_KEY,
        attacks=ATTACKS,
        operator_pub=OPERATOR.public_key(),
    )
    sim = Simulation(config)
    sim.run()
    sec = sim.summary()["security"]
    assert isinstance(sec, dict)
    assert sec["forgeries_accepted"] == 0
    accepted = sec["attacker"]["accepted"]
    assert set(accepted) == {"replay"} and sec["accepted_from_attacker"] == accepted["replay"] > 0
