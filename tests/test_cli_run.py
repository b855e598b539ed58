"""`fieldkit run` (issue 13): init() and destroy() only if defined, the robot API of one
simulated robot on request (`--robot-api`) and a hint when a script needs it, a loop budget,
Ctrl-C that says where the script was, and one `log` format in run, the simulator and the node."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

import bvm
from fieldkit.cli import app
from fieldkit.cli.buzz import DEFAULT_MAX_LOOPS, ROBOT_API_GLOBALS, ROBOT_API_HINT
from fieldkit.robot import geo
from fieldkit.robot.profiles import load_profile
from fieldkit.robot.runtime import RobotRuntime
from fieldkit.robot.script_api import Sensors

runner = CliRunner()

ROOT = Path(__file__).resolve().parent.parent

# Loops forever inside step(), after saying so: a place the VM can name.
SPIN = """x = 0
function step() {
  log("spinning")
  while (1) {
    x = x + 1
  }
}
"""


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("error: ")]


@pytest.mark.parametrize("robot_api", [False, True], ids=["bare", "robot-api"])
def test_init_and_destroy_are_called_only_if_defined(tmp_path: Path, robot_api: bool) -> None:
    script = write(tmp_path / "s.bzz", 'n = 0\nfunction step() { n = n + 1  log("step ", n) }\n')
    args = ["run", str(script), "--steps", "2"] + (["--robot-api"] if robot_api else [])
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    if robot_api:  # the simulator's log: simulated time and robot id on every line
        assert result.stdout == "[    0.000 s] robot 1: step 1\n[    0.100 s] robot 1: step 2\n"
    else:
        assert result.stdout == "step 1\nstep 2\n"


def test_a_missing_step_is_still_an_error(tmp_path: Path) -> None:
    script = write(tmp_path / "s.bzz", 'function init() { log("init") }\n')
    result = runner.invoke(app, ["run", str(script), "--steps", "1"])
    assert result.exit_code == 1
    assert "cannot find function 'step()'" in error_lines(result.stderr)[0]


def test_robot_api_is_one_simulated_robot_at_the_default_home(tmp_path: Path) -> None:
    script = write(
        tmp_path / "fly.bzz",
        'function init() { log("init ", id, " status ", flight.status) }\n'
        "function step() { if (flight.status == 1) { uav_takeoff(5.0) } }\n"
        "function destroy() {\n"
        '  log("status ", flight.status, " alt ", pose.position.altitude)\n'
        '  log("at ", pose.position.latitude, ",", pose.position.longitude)\n'
        "}\n",
    )
    args = ["run", str(script), "--robot-api", "--robot-id", "7", "--steps", "150"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    init, flying, at = result.stdout.splitlines()
    assert init == "[    0.000 s] robot 7: init 7 status 1"  # on the ground at the start
    m = re.fullmatch(r"\[ *[\d.]+ s\] robot 7: status 2 alt (\S+)", flying)  # then IN_AIR
    assert m is not None, flying
    assert float(m.group(1)) == pytest.approx(5.0, abs=0.5)
    lat, lon = (float(v) for v in at.split("robot 7: at ")[1].split(","))
    assert (lat, lon) == pytest.approx(geo.DEFAULT_HOME, abs=1e-4)


def test_a_script_needing_the_robot_api_gets_a_hint_then_runs_with_it() -> None:
    script = str(ROOT / "buzz_scripts" / "task_allocation.bzz")
    bare = runner.invoke(app, ["run", script, "--steps", "3"])
    assert bare.exit_code == 1
    assert "expected table, got nil" in error_lines(bare.stderr)[0]
    assert f"hint: {ROBOT_API_HINT}" in bare.stderr
    assert "Traceback" not in bare.output
    with_api = runner.invoke(app, ["run", script, "--steps", "3", "--robot-api"])
    assert with_api.exit_code == 0, with_api.output


def test_no_robot_api_hint_for_an_ordinary_nil_error(tmp_path: Path) -> None:
    script = write(tmp_path / "s.bzz", "t = nil\nx = t.a\ny = 1\n")
    result = runner.invoke(app, ["run", str(script)])
    assert result.exit_code == 1
    assert "hint:" not in result.stderr


def test_the_robot_api_names_are_those_the_runtime_adds() -> None:
    # The hint's list of names cannot drift from what the robot API really provides.
    program = bvm.compile_source(b"x = 1\n", "a.bzz")
    runtime = RobotRuntime(1, load_profile("solo"), geo.LocalFrame(*geo.DEFAULT_HOME, 0.0))
    assert runtime.start(program, Sensors(lat=0.0, lon=0.0, alt=0.0, north=0.0, east=0.0))
    bare = bvm.VM(robot_id=1)
    bare.load(program)
    bare.execute()
    added = {k for k, v in runtime.vm.globals.items() if v is not None and k not in bare.globals}
    assert added - {"log"} == ROBOT_API_GLOBALS


@pytest.mark.parametrize("robot_api", [False, True], ids=["bare", "robot-api"])
def test_an_endless_loop_ends_at_the_loop_budget(tmp_path: Path, robot_api: bool) -> None:
    script = write(tmp_path / "spin.bzz", SPIN)
    args = ["run", str(script), "--steps", "1", "--max-loops", "5000"]
    result = runner.invoke(app, args + (["--robot-api"] if robot_api else []))
    assert result.exit_code == 1
    (line,) = error_lines(result.stderr)
    assert re.fullmatch(
        rf"error: {re.escape(str(script))}:\d+:\d+: budget exceeded: more than 5000 loop "
        "iterations",
        line,
    ), line
    assert "--max-loops" in result.stderr  # the hint says how to give it more
    assert "Traceback" not in result.output


def test_the_default_budget_ends_an_endless_loop(tmp_path: Path) -> None:
    script = write(tmp_path / "spin.bzz", SPIN)
    result = runner.invoke(app, ["run", str(script), "--steps", "1"])
    assert result.exit_code == 1
    assert f"more than {DEFAULT_MAX_LOOPS} loop iterations" in error_lines(result.stderr)[0]


def test_max_loops_must_be_positive(tmp_path: Path) -> None:
    script = write(tmp_path / "s.bzz", "x = 1\n")
    result = runner.invoke(app, ["run", str(script), "--max-loops", "0"])
    assert result.exit_code == 1
    assert error_lines(result.stderr) == ["error: --max-loops must be >= 1, got 0"]


@pytest.mark.parametrize("robot_api", [False, True], ids=["bare", "robot-api"])
def test_ctrl_c_says_where_the_script_was(tmp_path: Path, robot_api: bool) -> None:
    script = write(tmp_path / "spin.bzz", SPIN)
    args = ["run", str(script), "--steps", "1", "--max-loops", str(2**62)]
    proc = subprocess.Popen(
        [sys.executable, "-u", "-m", "fieldkit", *args, *(["--robot-api"] if robot_api else [])],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # A shell's background job ignores SIGINT, and a child inherits that: undo it.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        assert proc.stdout is not None
        # Once the script has logged, it is in its loop: no sleeping, whatever the load.
        assert proc.stdout.readline().endswith("spinning\n")
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 1, err
    assert re.fullmatch(rf"error: interrupted at {re.escape(str(script))}:\d+:\d+\n", err), err


def test_log_is_one_format_in_run_the_simulator_and_the_node(tmp_path: Path) -> None:
    # The reference bzzrun's format (values joined with nothing between), everywhere;
    # ROSBuzz put spaces between them (docs/compat.md#H2).
    source = 'log("a", 1, " b", nil, 2.5)\nfunction step() {}\n'
    script = write(tmp_path / "log.bzz", source)
    bare = runner.invoke(app, ["run", str(script)])
    assert bare.stdout == "a1 b[nil]2.500000\n"
    simulated = runner.invoke(app, ["run", str(script), "--robot-api"])
    assert simulated.stdout == "[    0.000 s] robot 1: a1 b[nil]2.500000\n"
    # The node's host is the same runtime the simulator steps, with its own sink.
    lines: list[str] = []
    node = RobotRuntime(
        3, load_profile("solo"), geo.LocalFrame(*geo.DEFAULT_HOME, 0.0), log_sink=lines.append
    )
    node.start(
        bvm.compile_source(source.encode(), str(script)),
        Sensors(lat=0.0, lon=0.0, alt=0.0, north=0.0, east=0.0),
    )
    assert lines == ["[3] a1 b[nil]2.500000"]


def test_robot_api_runs_a_compiled_bo_too(tmp_path: Path) -> None:
    script = write(tmp_path / "s.bzz", "function step() {}\n")
    assert runner.invoke(app, ["compile", str(script)]).exit_code == 0
    result = runner.invoke(app, ["run", str(tmp_path / "s.bo"), "--robot-api"])
    assert result.exit_code == 0, result.output
