"""The example scripts do what their comments and docs/field-guide.md say they do."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

import bvm
from fieldkit import resources
from fieldkit.cli import app

runner = CliRunner()

#: The shipped copy (package data), the one a user's `examples/hello.bzz` resolves to.
HELLO = resources.example_dir() / "hello.bzz"


def test_hello_compiles() -> None:
    """hello.bzz compiles; its global code says hello and defines the functions a robot calls."""
    program = bvm.compile_file(HELLO)
    vm = bvm.VM(robot_id=1)
    vm.load(program)
    said: list[str] = []
    vm.register("log", lambda *args: said.append("".join(map(str, args))))
    vm.execute()
    assert said == ["hello from robot 1"]
    for name in ("init", "step", "destroy"):
        assert vm.gload(name) is not None, name


def test_hello_runs_alone_with_fieldkit_run() -> None:
    """`fieldkit run`: the global code, init, 3 steps hearing no one, then destroy."""
    result = runner.invoke(app, ["run", str(HELLO), "--robot-id", "3", "--steps", "3"])
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines() == [
        "hello from robot 3",
        "robot 3 step 1: 0 in range, 0 said hello",
        "robot 3 stopped after 3 steps",
    ]


def test_hello_without_steps_runs_only_the_global_code() -> None:
    """`fieldkit run FILE` alone runs the global code: one hello, from robot 0."""
    result = runner.invoke(app, ["run", str(HELLO)])
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines() == ["hello from robot 0"]


def test_hello_in_the_simulator_hears_the_whole_swarm(tmp_path: Path) -> None:
    """Five robots in range of each other: each hears the four others by its second log line."""
    out = tmp_path / "hello-run"
    cmd = ["sim", "run", str(HELLO), "--robots", "5", "--seconds", "5", "--out", str(out)]
    result = runner.invoke(app, cmd)
    assert result.exit_code == 0, result.output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["errors"] == []
    assert summary["final_states"] == {str(r): "HEARD" for r in range(1, 6)}
    lines = (out / "log.txt").read_text().splitlines()
    # Whatever prefix the simulator puts on a line (robot id, time), the script's text ends it.
    for r in range(1, 6):
        mine = [line for line in lines if f"robot {r} " in line or line.endswith(f"robot {r}")]
        assert any(line.endswith(f"hello from robot {r}") for line in mine), mine
        assert any(line.endswith(f"robot {r} step 1: 0 in range, 0 said hello") for line in mine)
        for step in (11, 21, 31, 41):
            expected = f"robot {r} step {step}: 4 in range, 4 said hello"
            assert any(line.endswith(expected) for line in mine), (expected, mine)
