"""The Spiri end to end: `fieldkit vehicle-sim --profile spiri` (the simulated PX4 on a pty) and
`fieldkit node --profile spiri` flying a script on it, both as the field runs them: processes
in real time, the flight recorded and replayed. And the node in this process against PX4 in
lockstep, deterministic.

Nothing waits on time: a test reads output until what it waits for shows (with a deadline as
a hang guard only), then stops the processes by signal.
"""

from __future__ import annotations

import json
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from rigs import SimRig
from rigs.flights import FLY_NORTH, NORTH, field_env
from rigs.lines import Lines
from typer.testing import CliRunner

import bvm
from fieldkit.cli import app
from fieldkit.node.autopilot_port import MavlinkAutopilot
from fieldkit.node.node import Node
from fieldkit.robot.rc import RcCommand

ROOT = Path(__file__).resolve().parents[1]
HOME = (45.5049, -73.6133)


@pytest.fixture
def px4_sim(tmp_path: Path) -> Iterator[tuple[str, subprocess.Popen[str]]]:
    """`fieldkit vehicle-sim --profile spiri` on a new pty: (its path, the process)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "vehicle-sim", "--profile", "spiri",
         "--gps-delay", "0", "--home", f"{HOME[0]},{HOME[1]}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=field_env(),
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], 30.0)
        assert ready, "no pty path printed"
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/")
        yield path, proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def test_fieldkit_node_flies_the_spiri_on_the_simulated_px4_and_the_flight_replays(
    tmp_path: Path, px4_sim: tuple[str, subprocess.Popen[str]]
) -> None:
    path, sim = px4_sim
    script = tmp_path / "fly.bzz"
    script.write_text(FLY_NORTH.replace("BROKEN == 1", "0 == 1"))
    bag = tmp_path / "flight"
    node = subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "node", "--robot-id", "1", "--profile", "spiri",
         "--script", str(script), "--autopilot", path, "--radio", "none",
         "--command", "0:1:22", "--out", str(tmp_path / "o"), "--record", str(bag)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=field_env(),
    )  # fmt: skip
    try:
        lines = Lines(node)
        deadline = time.monotonic() + 90.0  # a hang guard: the flight takes about 12 s
        while True:
            m = lines.until(NORTH, deadline)
            assert m is not None, f"the node ended: {lines.seen[-5:]} {node.stderr.read()}"  # type: ignore[union-attr]
            north, alt = float(m.group(1)), float(m.group(2))
            if north > 9.0:  # 10 m, less the float32 latitude's 0.4 m
                break
        node.send_signal(signal.SIGTERM)
        rest, err = node.communicate(timeout=60)
    finally:
        if node.poll() is None:
            node.kill()
            node.wait()
    assert node.returncode == 0, err
    assert 2.7 <= alt <= 3.1  # the take-off altitude (the script goes on at 90 % of it)
    log = "".join(lines.seen) + rest
    assert "Traceback" not in err and "error:" not in log
    assert "PX4 left OFFBOARD" not in log and "override" not in log  # never lost OFFBOARD
    assert "autopilot: takeoff 3: done" in log
    assert "stop: hold acknowledged by the autopilot" in rest  # spiri's on_stop: AUTO.LOITER
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["final_state"] == "GO" and summary["errors"] == []
    assert summary["mavlink_bad_frames"] == 0
    sim.send_signal(signal.SIGINT)
    _, sim_err = sim.communicate(timeout=60)
    assert sim.returncode == 0, sim_err
    assert "spiri (PX4 multicopter, system 1) at 45.5049,-73.6133" in sim_err
    assert "mode POSCTL -> OFFBOARD (GCS)" in sim_err and "armed in OFFBOARD" in sim_err
    assert "mode OFFBOARD -> LOITER (GCS)" in sim_err  # the stop
    assert "Failsafe" not in sim_err and "denied" not in sim_err
    # The flight replays identically: the PX4 link's stream and switch, timed by the link
    # clock, come out the same (`fieldkit replay --verify`).
    replay = CliRunner().invoke(app, ["replay", str(bag), "--verify", "--speed", "max"])
    assert replay.exit_code == 0, replay.output
    assert replay.stdout.splitlines()[-1].startswith("replay: identical: ")


def test_the_node_flies_the_spiri_in_lockstep() -> None:
    """The node, the supervisor and the PX4 link against the simulated PX4 on a pty, stepped
    together: take-off in OFFBOARD, 10 m north, and a script error holds in AUTO.LOITER."""
    with SimRig("spiri", home=HOME) as rig:
        rig.connect(10.0)
        t = rig.link.telemetry
        home = (t.lat, t.lon, 0.0)
        lines: list[str] = []
        node = Node(
            rig.profile,
            bvm.compile_source(FLY_NORTH.replace("BROKEN == 1", "1 == 1")),
            1,
            MavlinkAutopilot(rig.link, home),  # type: ignore[arg-type]
            None,
            home=home,  # type: ignore[arg-type]
            commands=[RcCommand(0.5, 1, 22)],
            clock=rig.clock,
            out=lines.append,
        )
        for _ in range(300):
            node.tick()
            rig.tick()
        v = rig.sim.vehicle
        assert 9.0 < v.y < 10.5 and v.x == pytest.approx(0.0, abs=0.01)  # 10 m north, nearly
        assert 2.7 <= v.z <= 3.1 and v.status == 2  # holding in the air
        summary = node.summary()
        assert "division by zero" in summary["errors"][0]  # type: ignore[index]
        assert summary["failsafe"].startswith("script error")  # type: ignore[union-attr]
        assert rig.sim.mode == "LOITER" and t.mode == "LOITER"  # the spiri's hold: PX4's own
        assert not rig.link.streaming and not rig.link.pilot_override
        assert summary["mavlink_bad_frames"] == 0 and rig.sim.failsafe is None
