"""The command line's contract across every command (issue 13): exit 0 on success, 1 after an
`error:` line, 2 when the command line does not parse, never a traceback; one CLI package
that no library module imports; one JSON writer that says where it wrote."""

from __future__ import annotations

import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from bvm.errors import BuzzCompileError, BuzzError, BuzzLoadError
from fieldkit.cli import app
from fieldkit.cli.errors import error_text
from fieldkit.cli.output import write_json

ROOT = Path(__file__).resolve().parent.parent
runner = CliRunner()

GOOD = "function init() {}\nfunction step() {}\n"
BROKEN = "x = 1\ny = (2 +\n"
RUNTIME = "x = 1\ny = x + nil\nz = 2\n"  # (bvm places an error in the last line at (null))


@pytest.fixture
def files(tmp_path: Path) -> Path:
    """Scripts, a corrupt .bdb beside a good .bo, bad assembly and an existing plain file."""
    (tmp_path / "good.bzz").write_text(GOOD)
    (tmp_path / "bad.bzz").write_text(BROKEN)
    (tmp_path / "rt.bzz").write_text(RUNTIME)
    (tmp_path / "g.basm").write_text("garbage\n")
    (tmp_path / "file").write_text("not a directory")
    assert runner.invoke(app, ["compile", str(tmp_path / "good.bzz")]).exit_code == 0
    (tmp_path / "corrupt.bo").write_bytes((tmp_path / "good.bo").read_bytes())
    (tmp_path / "corrupt.bdb").write_bytes(b"xx")
    return tmp_path


# (arguments, with {d} for the files' directory; the exit status; text of the error line)
CASES = [
    # 2: the command line does not parse
    (["nosuchcommand"], 2, "No such command"),
    (["sim", "run"], 2, "Missing argument"),
    (["run", "{d}/good.bzz", "--steps", "abc"], 2, "'--steps'"),
    (["sim", "run", "{d}/good.bzz", "--robots", "2", "--out", "{d}/o", "--seconds", "abc"], 2,
     "'--seconds'"),
    (["sim", "run", "{d}/good.bzz", "--robots", "2", "--out", "{d}/o", "--command", "x"], 2,
     "--command 'x'"),
    (["sim", "experiment", "coverage", "--seconds", "abc", "--out", "{d}/o"], 2, "'--seconds'"),
    (["sim", "sweep", "coverage", "--workers", "x", "--out", "{d}/o"], 2, "'--workers'"),
    (["node", "--profile", "solo", "--script", "{d}/good.bzz", "--robot-id", "1", "--command",
      "5"], 2, "--command '5'"),
    (["sitl", "--robots", "2", "--script", "{d}/good.bzz", "--out", "{d}/o", "--command", "5"], 2,
     "--command '5'"),
    (["vehicle-sim", "--profile", "solo", "--home", "45.5"], 2, "--home"),
    # 1: it parses, and fails
    (["compile", "{d}/nope.bzz"], 1, "nope.bzz"),
    (["compile", "{d}/bad.bzz"], 1, "bad.bzz:2:"),
    (["compile", "{d}/good.bzz", "-o", "{d}/file/x.bo"], 1, "cannot write"),
    (["run", "{d}/rt.bzz"], 1, "rt.bzz:"),
    (["run", "{d}/nope.bo"], 1, "nope.bo"),
    (["asm", "{d}/g.basm"], 1, "g.basm:1:"),
    (["disasm", "{d}/corrupt.bo"], 1, "corrupted .bdb"),
    (["disasm", "{d}/nope.bo"], 1, "cannot read"),
    (["sim", "run", "{d}/bad.bzz", "--robots", "2", "--out", "{d}/o"], 1, "bad.bzz:2:"),
    (["sim", "run", "{d}/good.bzz", "--robots", "0", "--out", "{d}/o"], 1, "--robots"),
    (["sim", "run", "{d}/good.bzz", "--robots", "2", "--out", "{d}/file", "--seconds", "1"], 1,
     "cannot create"),
    (["sim", "experiment", "coverage", "--drop", "1.5", "--out", "{d}/o"], 1, "--drop"),
    (["sim", "experiment", "coverage", "--script", "{d}/bad.bzz", "--out", "{d}/o"], 1,
     "bad.bzz:2:"),
    (["node", "--profile", "nope", "--script", "{d}/good.bzz"], 1, "unknown profile"),
    (["node", "--profile", "solo", "--script", "{d}/bad.bzz", "--robot-id", "1"], 1,
     "bad.bzz:2:"),
    (["node", "--profile", "solo", "--script", "{d}/good.bzz", "--robot-id", "300"], 1,
     "--robot-id"),
    (["sitl", "--robots", "2", "--script", "{d}/bad.bzz", "--out", "{d}/o"], 1, "bad.bzz:2:"),
    (["sitl", "--robots", "2", "--script", "{d}/good.bzz", "--out", "{d}/file"], 1,
     "cannot create"),
    (["sitl", "--robots", "0", "--script", "{d}/good.bzz", "--out", "{d}/o"], 1, "--robots"),
    (["vehicle-sim", "--profile", "solo", "--rate", "0"], 1, "--rate"),
]  # fmt: skip


@pytest.mark.parametrize(("args", "status", "text"), CASES, ids=[" ".join(c[0]) for c in CASES])
def test_every_command_follows_the_exit_code_rule(
    files: Path, args: list[str], status: int, text: str
) -> None:
    result = runner.invoke(app, [a.format(d=files) for a in args])
    assert result.exit_code == status, result.output
    errors = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and text in errors[0], result.stderr
    assert "Traceback" not in result.output
    assert isinstance(result.exception, SystemExit)


def test_an_unexpected_exception_is_an_error_line(
    files: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import bvm

    def boom(*_: object) -> str:
        raise RuntimeError("boom")

    monkeypatch.setattr(bvm, "compile_source", boom)
    result = runner.invoke(app, ["compile", str(files / "good.bzz")])
    assert result.exit_code == 1
    assert result.stderr.startswith("error: unexpected RuntimeError: boom"), result.stderr
    assert "Traceback" not in result.stderr


def test_the_console_script_follows_it_too(files: Path) -> None:
    for args, status in ((["sim", "run"], 2), (["disasm", str(files / "corrupt.bo")], 1)):
        proc = subprocess.run(
            [sys.executable, "-m", "fieldkit", *args], capture_output=True, text=True, check=False
        )
        assert proc.returncode == status, proc.stderr
        assert "\nerror: " in "\n" + proc.stderr and "Traceback" not in proc.stderr


def test_help_lists_every_command_from_the_cli_package() -> None:
    top = runner.invoke(app, ["--help"])
    assert top.exit_code == 0
    for name in ("compile", "run", "asm", "disasm", "sim", "node", "vehicle-sim", "sitl"):
        assert f" {name} " in top.output, name
    sim = runner.invoke(app, ["sim", "--help"])
    for name in ("run", "experiment", "sweep"):
        assert f" {name} " in sim.output, name
    for group in app.registered_groups:
        assert group.typer_instance is not None
        for command in group.typer_instance.registered_commands:
            assert command.callback is not None
            assert command.callback.__module__.startswith("fieldkit.cli.")
    for command in app.registered_commands:
        assert command.callback is not None
        assert command.callback.__module__.startswith("fieldkit.cli.")


def test_no_library_module_imports_the_command_line() -> None:
    offenders = []
    for path in sorted((ROOT / "fieldkit").rglob("*.py")):
        rel = path.relative_to(ROOT)
        if rel.parts[1] == "cli" or rel.name == "__main__.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            offenders += [f"{rel}: {n}" for n in names if n.split(".")[:2] == ["fieldkit", "cli"]]
    assert offenders == []


def test_error_text_places_each_kind_of_error() -> None:
    assert error_text(BuzzCompileError("a.bzz", 2, 5, "oops")) == "a.bzz:2:5: oops"
    located = BuzzError("division by zero")
    located.location = ("a.bzz", 3, 1)
    assert error_text(located, "other.bo") == "a.bzz:3:1: division by zero"
    assert error_text(BuzzError("bad", offset=7), "a.bo") == "a.bo: bytecode offset 7: bad"
    assert error_text(BuzzLoadError("truncated"), "a.bo") == "a.bo: truncated"
    missing = FileNotFoundError(2, "No such file or directory", "x.toml")
    assert error_text(missing) == "x.toml: No such file or directory"
    assert error_text("plain") == "plain"


def test_write_json_is_stable_and_says_where(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_json(tmp_path / "s.json", {"b": 1, "a": [1.5, None]})
    assert path.read_text() == '{\n  "a": [\n    1.5,\n    null\n  ],\n  "b": 1\n}\n'
    assert json.loads(path.read_text()) == {"a": [1.5, None], "b": 1}
    assert capsys.readouterr().err == f"wrote {path}\n"
