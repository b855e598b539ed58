"""The paper's heterogeneous team, in software: `fieldkit sitl --team` runs each robot's node
against the simulated machine its profile needs (ArduPilot, PX4, the DJI M100, the Husky's MCU
and GPS), and `fieldkit sitl --ground` puts the ground station and its UDP gateway on the SITL
radio, where `fieldkit cmd` reaches every node.

Nothing waits on time: the runs' lengths are node seconds, and the ground test reads sitl's
stderr until what it waits for shows, with deadlines as hang guards only.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
import select
import signal
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import pytest
from typer.testing import CliRunner

from fieldkit.cli import app

ROOT = Path(__file__).resolve().parents[1]

#: Each kind of machine, and the flight modes its vehicle reads as while the node flies or
#: drives it (the trajectories' `mode` column).
FLYING = {"solo": "GUIDED", "spiri": "OFFBOARD", "m100": "SDK_CONTROL", "husky": "DRIVING"}


def _tracks(out: Path) -> dict[str, list[dict[str, str]]]:
    by_robot: dict[str, list[dict[str, str]]] = defaultdict(list)
    with (out / "trajectories.csv").open() as f:
        for row in csv.DictReader(f):
            by_robot[row["robot"]].append(row)
    return by_robot


@pytest.mark.long
def test_a_mixed_team_takes_off_and_drives_each_robot_by_its_kind(tmp_path: Path) -> None:
    out = tmp_path / "run"
    # RC 900 to robot 1 at 10 s of its loop: the swarm takes off (the Husky arms) and forms
    # task allocation's P. The command's time is the nodes' own (their loops start together
    # once every node is up), so a slow start-up moves nothing.
    result = CliRunner().invoke(
        app,
        ["sitl", "--team", "solo:2,husky:1,m100:1,spiri:1", "--script", "task_allocation.bzz",
         "--command", "10:1:900", "--seconds", "30", "--out", str(out)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    profiles = {"1": "solo", "2": "solo", "3": "husky", "4": "m100", "5": "spiri"}
    assert summary["profiles"] == profiles and summary["robots"] == 5
    assert summary["not_finished"] == [] and summary["errors"] == []
    for rid, node in summary["nodes"].items():
        assert node["ticks"] >= 250, (rid, node["ticks"])  # 30 s at 10 Hz, every node
        assert node["robot_id"] == int(rid)
    tracks = _tracks(out)
    for rid, name in profiles.items():
        rows = tracks[rid]
        modes = {r["mode"] for r in rows}
        assert FLYING[name] in modes, (rid, name, modes)
        top = max(float(r["alt_m"]) for r in rows)
        start, end = rows[0], rows[-1]
        moved = math.dist(
            (float(start["east_m"]), float(start["north_m"])),
            (float(end["east_m"]), float(end["north_m"])),
        )
        if name == "husky":
            assert top == 0.0 and moved > 1.0, (rid, top, moved)  # drove, on the ground
        else:
            assert top > 2.0, (rid, name, top)  # took off
    # Each node ran against its own kind of machine, and said so in its log.
    logs = {rid: (out / f"robot{rid}" / "log.txt").read_text() for rid in profiles}
    assert "MAV_AUTOPILOT_ARDUPILOTMEGA" in logs["1"] and "MAV_AUTOPILOT_PX4" in logs["5"]
    assert "M100 firmware" in logs["4"] and "MCU found: Husky" in logs["3"]
    # The M100's app came from a config file, never a command line or a log.
    from fieldkit.vehicle.sim.dji import TEST_APP_KEY

    assert TEST_APP_KEY not in (out / "log.txt").read_text()
    assert (out / "robot4" / "dji-app-key").stat().st_mode & 0o077 == 0


@pytest.mark.parametrize(
    ("args", "status", "message"),
    [
        (["--team", "solo:2", "--robots", "2"], 1, "--team and --robots: give one"),
        (["--team", "solo:2", "--profile", "solo"], 1, "--team and --profile: give one"),
        (["--team", "solo:2,drone:1"], 1, "unknown profile (known: husky, m100, solo, spiri)"),
        (["--team", "solo:0"], 1, "COUNT must be a positive integer, got 0"),
        (["--team", "solo:x"], 2, "expected NAME:COUNT[,NAME:COUNT]..."),
        (["--team", "solo"], 2, "expected NAME:COUNT[,NAME:COUNT]..."),
        (["--team", "solo:40,husky:25"], 1, "65 robots; a run takes at most 64"),
        (["--team", "solo:1", "--command", "1:2:22"], 1, "robots are 1..1"),
        ([], 1, "give --robots N"),
    ],
)
def test_team_command_line_errors(
    tmp_path: Path, args: list[str], status: int, message: str
) -> None:
    result = CliRunner().invoke(
        app, ["sitl", "--script", "task_allocation.bzz", "--out", str(tmp_path / "o"), *args]
    )
    assert result.exit_code == status, result.output
    assert result.stderr.startswith("error: ") and message in result.stderr, result.stderr
    assert "Traceback" not in result.output
    assert not (tmp_path / "o").exists()  # nothing started


def _until(proc: subprocess.Popen[str], pattern: str, seen: list[str], deadline: float) -> str:
    """Read sitl's stderr until a line matches `pattern` (the deadline a hang guard)."""
    assert proc.stderr is not None
    while True:
        left = deadline - time.monotonic()
        assert left > 0, f"no {pattern!r} in time: {seen[-5:]}"
        ready, _, _ = select.select([proc.stderr], [], [], min(left, 1.0))
        if not ready:
            continue
        line = proc.stderr.readline()
        assert line, f"sitl ended before {pattern!r}: {seen[-10:]}"
        seen.append(line)
        if re.search(pattern, line):
            return line


@pytest.mark.long
def test_cmd_through_the_sitl_ground_gateway_reaches_every_node(tmp_path: Path) -> None:
    out = tmp_path / "run"
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    # No --seconds: with --ground the run lasts until it is interrupted.
    sitl = subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "sitl", "--team", "solo:1,husky:1,m100:1",
         "--script", "task_allocation.bzz", "--out", str(out), "--ground",
         "--ground-port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    seen: list[str] = []
    try:
        deadline = time.monotonic() + 240.0  # hang guard: three nodes start in ~20 s
        page = _until(sitl, r"ground: page at http://127\.0\.0\.1:\d+/", seen, deadline)
        gateway = _until(sitl, r"ground: radio gateway udp://", seen, deadline)
        url = re.search(r"udp://[\d.]+:\d+", gateway)
        assert url is not None and "--keys" in gateway
        _until(sitl, r"sitl: every node is up: 3 robots", seen, deadline)
        done = subprocess.run(
            [sys.executable, "-m", "fieldkit", "cmd", "takeoff", "--radio", url.group(0),
             "--keys", str(out / "keys"), "--timeout", "60"],
            capture_output=True, text=True, env=env, timeout=180,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        assert "takeoff (22) to all: acknowledged by 1, 2, 3" in done.stdout, done.stdout
        sitl.send_signal(signal.SIGINT)  # a normal end: every node stops, results written
        last, rest = sitl.communicate(timeout=180)
    finally:
        if sitl.poll() is None:
            sitl.kill()
            sitl.wait()
    assert sitl.returncode == 0, "".join(seen) + rest
    assert f"wrote {out / 'summary.json'}" in rest
    assert last.startswith("sitl: 3 robots; ") and last.rstrip().endswith(f"results in {out}")
    assert "127.0.0.1" in page
    summary = json.loads((out / "summary.json").read_text())
    assert summary["not_finished"] == [] and summary["seconds"] > 0
    assert summary["profiles"] == {"1": "solo", "2": "husky", "3": "m100"}
    assert summary["ground"]["robots_heard"] == [1, 2, 3]
    assert summary["security"]["mode"] == "signed"  # operator commands are signed
    for node in summary["nodes"].values():
        # Each node acted on the command once, and was stopped as systemd stops it.
        assert node["commands"]["accepted"] == 1, node["commands"]
        assert node["stop"]["acknowledged"], node["stop"]
