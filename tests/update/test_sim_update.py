"""Over-the-air updates in the simulator: real signed patches over the simulated radio."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

import bvm
from fieldkit.cli import app
from fieldkit.sim.simulator import SimConfig, Simulation
from fieldkit.sim.updates import SimUpdate
from fieldkit.update.packets import UPDATE_FRAME, frame_type
from fieldkit.update.release import Release

HELLO = Path(__file__).parents[2] / "buzz_scripts" / "examples" / "hello.bzz"
runner = CliRunner()
V2 = 'function init() { log("version two") }\nfunction step() { x = 2 }\n'
# Fails only after its 5-second trial, and only on robot 3: what a trial cannot catch.
LATE_BUG = (
    "function init() { n = 0 }\n"
    "function step() {\n  n = n + 1\n  if (n > 80 and id == 3) { foo() }\n}\n"
)


def release(source: str, name: str) -> Release:
    return Release.from_program(bvm.compile_source(source, name))


def run(updates: list[SimUpdate], **kw: object) -> Simulation:
    config = SimConfig(
        script=HELLO, robots=kw.pop("robots", 10), seconds=kw.pop("seconds", 30.0), **kw
    )  # type: ignore[arg-type]
    config.updates = updates
    sim = Simulation(config)
    sim.run()
    return sim


def test_an_update_reaches_every_robot_over_a_lossy_multi_hop_radio() -> None:
    new = release(V2, "v2.bzz")
    # 20 robots 6 m apart, 20 m of range: several hops from robot 1 to the far corner.
    sim = run(
        [SimUpdate(5.0, new, 1, "v2.bzz")], robots=20, drop=0.5, range_m=20.0, spacing_m=6.0, seed=1
    )
    s = sim.summary()
    update = s["update"]
    assert isinstance(update, dict)
    assert update["version"] == 1 and not update["rolled_back"]
    assert update["all_switched_s"] is not None and update["all_switched_s"] > 5.0
    assert set(s["script_versions"].values()) == {new.hash}  # type: ignore[union-attr]
    assert update["patch_bytes"] > 0 and update["update_bytes_sent"] > update["patch_bytes"]
    assert not s["errors"] and not s["in_failsafe"]
    # The robots ran the new script: its init() logged.
    assert sum("version two" in line for line in sim.log) == 20


def test_a_script_error_after_the_switch_rolls_the_swarm_back_to_the_previous_version() -> None:
    v2, bug = release(V2, "v2.bzz"), release(LATE_BUG, "bug.bzz")
    sim = run(
        [SimUpdate(3.0, v2, 1, "v2.bzz"), SimUpdate(12.0, bug, 4, "bug.bzz")],
        seconds=40.0,
        drop=0.3,
    )
    s = sim.summary()
    update = s["update"]
    assert isinstance(update, dict)
    assert update["version"] == 2 and update["rolled_back"]
    assert "bug.bzz:4" in str(update["reason"]) and "robot 3" in str(update["reason"])
    # Every robot back on version 1 (not the launch-time script), none left in its failsafe.
    assert set(s["script_versions"].values()) == {v2.hash}  # type: ignore[union-attr]
    assert s["in_failsafe"] == [] and [e["robot"] for e in s["errors"]] == [3]  # type: ignore[index,union-attr]


def test_the_same_seed_gives_the_same_summary_updates_included() -> None:
    new = release(V2, "v2.bzz")
    a = run([SimUpdate(2.0, new, 2, "v2.bzz")], drop=0.4, seed=7, seconds=15.0).summary()
    b = run([SimUpdate(2.0, new, 2, "v2.bzz")], drop=0.4, seed=7, seconds=15.0).summary()
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_update_frames_travel_the_simulated_radio_as_real_bytes() -> None:
    new = release(V2, "v2.bzz")
    config = SimConfig(script=HELLO, robots=3, seconds=3.0, updates=[SimUpdate(0.5, new)])
    sim = Simulation(config)
    seen: list[bytes] = []
    broadcast = sim.radio.broadcast

    def spy(step: int, sender: int, data: bytes, *a: object, **k: object) -> None:
        if frame_type(data) == UPDATE_FRAME:
            seen.append(data)
        broadcast(step, sender, data, *a, **k)  # type: ignore[arg-type]

    sim.radio.broadcast = spy  # type: ignore[method-assign]
    sim.run()
    assert seen and all(len(f) <= 232 for f in seen)


def test_sim_run_update_writes_the_update_in_its_summary(tmp_path: Path) -> None:
    v2 = tmp_path / "v2.bzz"
    v2.write_text(V2)
    out = tmp_path / "out"
    r = runner.invoke(
        app,
        [
            "sim",
            "run",
            str(HELLO),
            "--robots",
            "4",
            "--seconds",
            "12",
            "--out",
            str(out),
            "--update",
            f"2:{v2}:3",
        ],
    )
    assert r.exit_code == 0, r.output
    s = json.loads((out / "summary.json").read_text())
    assert s["update"]["version"] == 1 and s["update"]["all_switched_s"] is not None
    assert "every robot switched" in r.output


@pytest.mark.parametrize(
    ("update", "code", "message"),
    [
        ("soon:x.bzz", 2, "expected T:NEW.bzz[:ROBOT]"),
        ("-1:x.bzz", 2, "T must be a time"),
        ("2:{bad}", 1, "failed its trial"),
        ("2:{v2}:9", 1, "--update at robot 9: robots are 1..4"),
        ("2:{missing}", 1, "missing.bzz"),
    ],
)
def test_sim_run_refuses_an_update_it_cannot_send(
    tmp_path: Path, update: str, code: int, message: str
) -> None:
    (tmp_path / "bad.bzz").write_text("function init() {}\nfunction step() { foo() }\n")
    (tmp_path / "v2.bzz").write_text(V2)
    text = update.format(
        bad=tmp_path / "bad.bzz", v2=tmp_path / "v2.bzz", missing=tmp_path / "missing.bzz"
    )
    out = tmp_path / "out"
    r = runner.invoke(
        app,
        [
            "sim",
            "run",
            str(HELLO),
            "--robots",
            "4",
            "--seconds",
            "5",
            "--out",
            str(out),
            "--update",
            text,
        ],
    )
    assert r.exit_code == code, r.output
    assert message in r.output
    assert "Traceback" not in r.output
    assert not (out / "summary.json").exists()
