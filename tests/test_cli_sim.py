"""`fieldkit sim run` end to end (issue 13): it says where its results went and how the run
ended, writes a time-ordered log, trajectories and a plot, takes --home, --spacing and --set,
and exits 1 when a script error left robots in their failsafe."""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from fieldkit.cli import app, output
from fieldkit.cli.output import progress_bar
from fieldkit.robot.geo import DEFAULT_HOME
from fieldkit.sim.simulator import CROWD, SPACING_M, default_spacing, log_line

runner = CliRunner()

#: Every robot logs X at init and its step count every second step (one value a line: the
#: way `log` joins several is not this test's business); robots 3 and 5 divide by zero at tick 6.
CHATTY = """
function init() { log(X) }
function step() {
  T = T + 1
  if (T % 2 == 0) log(T)
  if (BREAK == 1 and (id == 3 or id == 5) and T == 6) { var z = 1 / 0 }
  BVMSTATE = "STEPPING"
}
T = 0
"""

LINE = re.compile(r"\[ *(\d+\.\d{3}) s\] robot (\d+): (.*)")


def sim_run(tmp_path: Path, *args: str) -> tuple[int, str, str, Path]:
    """Run `sim run CHATTY` with `args`: (exit code, stdout, stderr, out dir)."""
    script = tmp_path / "chatty.bzz"
    script.write_text(CHATTY)
    out = tmp_path / "out"
    result = runner.invoke(app, ["sim", "run", str(script), "--out", str(out), *args])
    return result.exit_code, result.stdout, result.stderr, out


def test_sim_run_says_where_and_how_it_went_off_a_terminal(tmp_path: Path) -> None:
    status, stdout, stderr, out = sim_run(tmp_path, "--robots", "3", "--seconds", "2")
    assert status == 0, stderr
    for name in ("summary.json", "log.txt", "trajectories.csv", "plot.png"):
        assert f"wrote {out / name}" in stderr
    assert (out / "plot.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # One line: robots, simulated time, final states counted, errors, bytes, where.
    (last,) = stdout.splitlines()
    assert last.startswith("sim run: 3 robots; 2 s simulated; final states STEPPING 3; ")
    assert "0 script errors" in last and "bundles max" in last
    assert last.endswith(f"results in {out}")
    # Not a terminal: plain progress lines, the start and ten more, instead of a bar.
    progress = [ln for ln in stderr.splitlines() if ln.startswith("simulating 3 robots: ")]
    assert progress[0] == "simulating 3 robots: 0% (0/20)"
    assert progress[-1] == "simulating 3 robots: 100% (20/20)" and len(progress) == 11


def test_the_log_is_in_time_order_with_time_and_robot_on_every_line(tmp_path: Path) -> None:
    status, _, stderr, out = sim_run(tmp_path, "--robots", "3", "--seconds", "1")
    assert status == 0, stderr
    lines = (out / "log.txt").read_text().splitlines()
    parsed = [LINE.fullmatch(line) for line in lines]
    assert all(parsed), lines
    keys = [(float(m.group(1)), int(m.group(2))) for m in parsed if m]
    assert keys == sorted(keys)  # time, then robot: not grouped by robot
    assert lines[:3] == [log_line(0.0, rid, "[nil]") for rid in (1, 2, 3)]
    # T is 2 at tick 1 (0.1 s): every robot, then on to the next time.
    assert lines[3:6] == [log_line(0.1, rid, "2") for rid in (1, 2, 3)]
    assert lines[6] == log_line(0.3, 1, "4")


def test_trajectories_have_every_robot_every_second_from_home(tmp_path: Path) -> None:
    status, _, stderr, out = sim_run(
        tmp_path, "--robots", "4", "--seconds", "2", "--home", "10.5,20.25", "--spacing", "10"
    )
    assert status == 0, stderr
    with (out / "trajectories.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["t_s", "robot", "east_m", "north_m", "alt_m", "lat", "lon", "state"]
    assert [(r["t_s"], r["robot"]) for r in rows] == [
        (t, str(rid)) for t in ("0.0", "1.0", "2.0") for rid in (1, 2, 3, 4)
    ]
    first = {int(r["robot"]): r for r in rows[:4]}
    # A 2x2 grid 10 m apart (give or take the 0.2 m jitter), its corner at --home.
    assert (
        abs(float(first[2]["east_m"]) - 10.0) < 0.5 and abs(float(first[3]["north_m"]) - 10) < 0.5
    )
    assert math.isclose(float(first[1]["lat"]), 10.5, abs_tol=1e-5)
    assert math.isclose(float(first[1]["lon"]), 20.25, abs_tol=1e-5)
    assert rows[-1]["state"] == "STEPPING" and rows[0]["state"] == ""
    summary = json.loads((out / "summary.json").read_text())
    assert summary["home"] == [10.5, 20.25] and summary["spacing_m"] == 10.0


def test_set_gives_script_globals_before_init(tmp_path: Path) -> None:
    status, _, stderr, out = sim_run(
        tmp_path, "--robots", "2", "--seconds", "0.1", "--set", "X=2.5", "--set", "X=abc"
    )
    assert status == 0, stderr
    assert log_line(0.0, 1, "abc") in (out / "log.txt").read_text()  # the last --set wins
    assert json.loads((out / "summary.json").read_text())["globals"] == {"X": "abc"}


def test_script_errors_that_leave_robots_in_failsafe_fail_the_run(tmp_path: Path) -> None:
    status, stdout, stderr, out = sim_run(
        tmp_path, "--robots", "6", "--seconds", "2", "--set", "BREAK=1"
    )
    assert status == 1
    (error,) = [ln for ln in stderr.splitlines() if ln.startswith("error:")]
    assert error.startswith(
        "error: robots 3, 5 ended in their failsafe after a script error: robot 3: "
    )
    assert "chatty.bzz:6:" in error and "division by zero" in error
    # The run still says where its results are, and they are there.
    assert "2 script errors" in stdout and f"wrote {out / 'plot.png'}" in stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["in_failsafe"] == [3, 5]
    assert [(e["robot"], e["t_s"]) for e in summary["errors"]] == [(3, 0.5), (5, 0.5)]
    log = (out / "log.txt").read_text()
    assert "[    0.500 s] robot 3: script error, robot to its safe state: " in log


def test_set_chooses_the_task_allocation_shape(tmp_path: Path) -> None:
    """12 robots form PO (12 tasks) when told; by default P has tasks for 6 of them."""
    ta = ["--command", "1:1:22", "--command", "20:1:900", "--seconds", "45", "--robots", "12"]
    shaped = runner.invoke(
        app,
        [
            "sim",
            "run",
            "task_allocation.bzz",
            "--out",
            str(tmp_path / "po"),
            *ta,
            "--set",
            "SHAPE=PO",
        ],
    )
    assert shaped.exit_code == 0, shaped.stderr
    states = json.loads((tmp_path / "po" / "summary.json").read_text())["final_states"]
    assert set(states.values()) <= {"JOINED", "LOCK"}, states
    default = runner.invoke(
        app, ["sim", "run", "task_allocation.bzz", "--out", str(tmp_path / "p"), *ta]
    )
    assert default.exit_code == 0, default.stderr
    states = json.loads((tmp_path / "p" / "summary.json").read_text())["final_states"]
    assert sum(s in ("JOINED", "LOCK") for s in states.values()) == 6


@pytest.mark.parametrize(
    "args,status,words",
    [
        (["--home", "45.5"], 2, "--home: expected LAT,LON"),
        (["--home", "91,0"], 1, "--home: latitude"),
        (["--set", "1X=2"], 2, "--set '1X=2'"),
        (["--spacing", "abc"], 2, "'--spacing'"),
        (["--spacing", "0"], 1, "--spacing must be > 0"),
        (["--burst", "nan"], 1, "--burst must be a mean of at least 1 tick"),
        (["--burst", "0.5"], 1, "--burst must be a mean of at least 1 tick"),
        (["--range", "inf"], 1, "--range must be > 0"),
    ],
)
def test_bad_home_set_and_spacing(tmp_path: Path, args: list[str], status: int, words: str) -> None:
    code, _, stderr, out = sim_run(tmp_path, "--robots", "2", "--seconds", "1", *args)
    assert code == status and "error:" in stderr and words in stderr, stderr
    assert "Traceback" not in stderr


def test_default_spacing_keeps_small_swarms_and_spreads_large_ones() -> None:
    assert default_spacing(6, 500.0) == default_spacing(50, 500.0) == SPACING_M
    assert default_spacing(1000, 10.0) == SPACING_M  # few in range at 3 m anyway
    for robots, range_m in ((1000, 500.0), (5000, 500.0), (300, 50.0)):
        pitch = default_spacing(robots, range_m)
        side = math.ceil(math.sqrt(robots))
        grid = [((k % side) * pitch, (k // side) * pitch) for k in range(robots)]
        centre = grid[(side // 2) * side + side // 2]  # the busiest spot
        heard = sum(0 < math.dist(centre, p) <= range_m for p in grid)
        assert CROWD * 0.8 <= heard <= CROWD * 1.2, (robots, range_m, pitch, heard)


def test_progress_off_a_terminal_is_a_line_every_tenth(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(output, "PROGRESS_EVERY_S", math.inf)  # only the 10% steps
    with progress_bar("work", 200) as advance:
        for done in range(0, 201, 7):
            advance(done, 200)
        advance(200, 200)
    lines = capsys.readouterr().err.splitlines()
    assert lines[:2] == ["work: 0% (0/200)", "work: 10% (21/200)"]
    assert lines[-1] == "work: 100% (200/200)" and len(lines) == 11


def test_default_home_is_documented() -> None:
    cli = (Path(__file__).resolve().parents[1] / "docs" / "cli.md").read_text()
    assert f"{DEFAULT_HOME[0]},{DEFAULT_HOME[1]}" in cli


def test_a_crowded_start_grid_is_warned_about_and_the_default_is_not(tmp_path: Path) -> None:
    """100 robots 3 m apart all hear each other at 500 m: that crawls, and `sim run` says so;
    on the default grid (spread for the range) it is quiet."""
    code, _, stderr, _ = sim_run(tmp_path, "--robots", "100", "--seconds", "0.1", "--spacing", "3")
    assert code == 0, stderr
    assert "warning: about 99 robots in each robot's 500 m range" in stderr, stderr
    code, _, stderr, _ = sim_run(tmp_path, "--robots", "100", "--seconds", "0.1")
    assert code == 0 and "warning: about" not in stderr, stderr
