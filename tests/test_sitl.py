"""Software in the loop, end to end: real node processes, simulated ArduPilots on ptys, and
XBee frames through a relay that drops and corrupts them."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from fieldkit.cli import app
from fieldkit.robot.profiles import load_profile
from fieldkit.sitl import SitlConfig, run

ROOT = Path(__file__).resolve().parents[1]

GOSSIP = """
s = swarm.create(1)
v = stigmergy.create(1)
function init() { s.join()  BVMSTATE = "START"  heard = {} }
neighbors.listen("hi", function(topic, value, sender) { heard[sender] = value })
function step() {
  neighbors.broadcast("hi", id)
  v.put(id, 1)
  if (size(heard) == ROBOTS - 1 and ROBOTS == 3 and v.size() == 3) BVMSTATE = "ALL"
}
"""


def test_three_nodes_exchange_bundles_over_a_lossy_corrupting_relay(tmp_path: Path) -> None:
    script = tmp_path / "gossip.bzz"
    script.write_text(GOSSIP)
    cfg = SitlConfig(
        script=script,
        robots=3,
        out=tmp_path / "run",
        profile=load_profile("solo"),
        drop=0.3,
        corrupt=0.1,
        # ROBOTS counts a robot once its swarm announcement (one every 10 ticks) gets
        # through; at 8 s (8 announcements a pair) losing all of one pair's happened about
        # once in 500 runs (the deterministic simulator shows it: 27 of 200 seeds at 60 %
        # loss in 8 s, 1 of 200 in 16 s). 16 s makes it about one in a million.
        seconds=16.0,
        seed=4,
    )
    summary = run(cfg)
    assert summary["errors"] == []
    assert summary["final_states"] == {"1": "ALL", "2": "ALL", "3": "ALL"}
    assert summary["relay"]["dropped"] > 0 and summary["relay"]["corrupted"] > 0
    assert all(b > 0 for b in summary["bytes_sent_per_robot"].values())
    nodes = summary["nodes"]
    # A corrupted frame fails its checksum (or the bundle check): counted, nothing else.
    assert sum(n["radio_bad_frames"] + n["bundle_errors"] for n in nodes.values()) > 0
    assert all(n["ticks"] >= 60 for n in nodes.values())
    written = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert written["final_states"] == summary["final_states"]


def test_sitl_command_line_errors(tmp_path: Path) -> None:
    runner = CliRunner()
    bad = runner.invoke(app, ["sitl", "--robots", "0", "--script", "x.bzz", "--out", str(tmp_path)])
    assert bad.exit_code == 1 and "--robots" in bad.output
    missing = runner.invoke(
        app, ["sitl", "--robots", "2", "--script", "nope.bzz", "--out", str(tmp_path)]
    )
    assert missing.exit_code == 1 and "no such file" in missing.output
    for args, status in ((["--home", "x"], 2), (["--set", "=1"], 2), (["--home", "0,200"], 1)):
        bad = runner.invoke(
            app,
            [
                "sitl",
                "--robots",
                "2",
                "--script",
                "task_allocation.bzz",
                "--out",
                str(tmp_path),
                *args,
            ],
        )
        assert bad.exit_code == status and "error: --" in bad.stderr, bad.output


#: Both nodes log X at init; robot 2's script fails at its second step.
FAILING = """
function init() { log(X)  BVMSTATE = "UP" }
T = 0
function step() {
  T = T + 1
  if (id == 2 and T == 2) { var z = 1 / 0 }
}
"""

STAMP = re.compile(r"\[\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z\] robot (\d): ")


def test_sitl_says_where_logs_in_time_order_and_fails_on_a_script_error(tmp_path: Path) -> None:
    script = tmp_path / "failing.bzz"
    script.write_text(FAILING)
    out = tmp_path / "run"
    result = CliRunner().invoke(
        app,
        [
            "sitl",
            "--robots",
            "2",
            "--script",
            str(script),
            "--seconds",
            "2",
            "--out",
            str(out),
            "--set",
            "X=hello",
            "--home",
            "10.5,20.25",
        ],
    )
    # A node whose script error left its robot in the failsafe fails the run, and says so.
    assert result.exit_code == 1, result.output
    (error,) = [ln for ln in result.stderr.splitlines() if ln.startswith("error:")]
    assert error.startswith("error: robot 2 ended in its failsafe after a script error: robot 2:")
    assert "failing.bzz:6:" in error and "division by zero" in error
    for name in ("summary.json", "log.txt", "trajectories.csv", "plot.png"):
        assert f"wrote {out / name}" in result.stderr
    (line,) = result.stdout.splitlines()
    assert line.startswith("sitl: 2 robots; 2 s; final states UP 2; 1 error; bytes sent per robot")
    assert line.endswith(f"results in {out}")
    # One merged log, in time order, every line stamped with the wall time and the robot.
    lines = (out / "log.txt").read_text().splitlines()
    assert all(STAMP.match(ln) for ln in lines), lines
    assert [ln[:26] for ln in lines] == sorted(ln[:26] for ln in lines)
    for rid in ("1", "2"):  # --set reached every node before init()
        assert any(re.search(rf"robot {rid}: (\[{rid}\] )?hello$", ln) for ln in lines)
    own = (out / "robot1" / "log.txt").read_text().splitlines()
    assert own and all(STAMP.match(ln).group(1) == "1" for ln in own)  # type: ignore[union-attr]
    with (out / "trajectories.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["t_s", "robot", "east_m", "north_m", "alt_m", "lat", "lon", "mode"]
    assert [(r["t_s"], r["robot"]) for r in rows[:2]] == [("0.0", "1"), ("0.0", "2")]
    assert float(rows[0]["lat"]) == pytest.approx(10.5) and rows[0]["mode"] == "DISARMED"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["in_failsafe"] == [2] and summary["not_finished"] == []
    assert summary["globals"] == {"X": "hello"} and summary["home"] == [10.5, 20.25]
