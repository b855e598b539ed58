"""The command line's contract across every command (issue 13): exit 0 on success, 1 after an
`error:` line, 2 when the command line does not parse, never a traceback; one CLI package
that no library module imports; one JSON writer that says where it wrote."""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
import typing
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path
from typing import Any

import pytest
import typer.main
from typer.testing import CliRunner

from bvm.errors import BuzzCompileError, BuzzError, BuzzLoadError
from fieldkit.cli import app
from fieldkit.cli.errors import error_text
from fieldkit.cli.output import write_json
from fieldkit.update.keys import init_keys

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
    (["bag", "info", "{d}/file"], 1, "not a bag directory"),
    (["bag", "info", "{d}"], 1, "not a fieldkit bag"),
    (["bag", "from-tlog", "{d}/good.bzz", "-o", "{d}/o"], 1, "no MAVLink record"),
    (["bag", "from-tlog", "{d}/good.bzz"], 2, "Missing option"),
    (["deploy", "--root", "{d}/r"], 2, "Missing option '--profile'"),
    (["deploy", "--profile", "solo", "--root", "{d}/r", "--purge"], 2, "--purge"),
    (["deploy", "--profile", "nope", "--root", "{d}/r"], 1, "unknown profile"),
    (["deploy", "--profile", "solo", "--root", "{d}/r", "--script", "{d}/bad.bzz"], 1,
     "bad.bzz:2:"),
    (["deploy", "--profile", "solo", "--root", "{d}/file"], 1, "not a directory"),
    # values that parse but would never end, or overflow
    (["sitl", "--robots", "1", "--script", "{d}/good.bzz", "--out", "{d}/o", "--seconds", "inf"], 1,
     "--seconds"),
    (["node", "--profile", "solo", "--script", "{d}/good.bzz", "--robot-id", "1",
      "--connect-timeout", "nan"], 1, "--connect-timeout"),
    (["node", "--profile", "solo", "--script", "{d}/good.bzz", "--robot-id", "1", "--seconds",
      "-1"], 1, "--seconds"),
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


# ------------------------------------------------------------------ every command, walked


def _tree() -> dict[tuple[str, ...], Any]:
    """Every command and group of `fieldkit` by its path (() is the root), as click has them."""
    found: dict[tuple[str, ...], Any] = {}

    def walk(command: Any, path: tuple[str, ...]) -> None:
        found[path] = command
        for name, sub in getattr(command, "commands", {}).items():
            walk(sub, (*path, name))

    walk(typer.main.get_command(app), ())
    return found


TREE = _tree()
LEAVES = {path: c for path, c in TREE.items() if not getattr(c, "commands", None)}


def test_the_walk_finds_every_command() -> None:
    names = {" ".join(path) for path in LEAVES}
    assert names >= {"compile", "run", "asm", "disasm", "node", "vehicle-sim", "sitl", "update"}
    assert names >= {"sim run", "sim experiment", "sim sweep"}


@pytest.mark.parametrize("path", list(TREE), ids=[" ".join(p) or "fieldkit" for p in TREE])
def test_every_help_prints_as_written(path: tuple[str, ...]) -> None:
    result = runner.invoke(app, [*path, "--help"])
    assert result.exit_code == 0, result.output
    text = result.stdout
    # No emoji (rich read `:robot:` as one), no box drawing, no Python types as placeholders.
    assert text.isascii(), sorted({c for c in text if not c.isascii()})
    for junk in ("<bool>", "list[", "Optional", "NoneType"):
        assert junk not in text, junk
    # Every `A:B:C`-like word of a parameter's help appears as written.
    for param in TREE[path].params:
        for word in re.findall(r"\S*:\S+", param.help or ""):
            assert word in text, word


def test_the_command_option_help_keeps_its_colons() -> None:
    text = runner.invoke(app, ["sim", "run", "--help"]).stdout
    assert "T:ROBOT:CODE[:P...]" in text
    assert "--include <path>" in text and "--command T:ROBOT:CODE[:P...]" in text


def test_version_comes_from_the_package_metadata() -> None:
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0, result.output
    assert result.stdout == f"fieldkit {metadata.version('fieldkit')}\n"
    assert re.fullmatch(r"fieldkit \d+\.\d+\.\d+\n", result.stdout)
    import fieldkit

    assert fieldkit.__version__ == metadata.version("fieldkit")  # one version, not two


def test_a_group_alone_prints_its_help() -> None:
    result = runner.invoke(app, ["sim"])
    assert result.exit_code == 2
    assert re.match(r"Usage: \S+ sim \[OPTIONS\] COMMAND", result.stderr), result.stderr
    assert "error:" not in result.stderr


# Arguments that would run each command as briefly as it can, should a bad value slip by:
# every case below replaces one of them by a bad one. {d}: the files' directory.
BASE: dict[str, dict[str, str | list[str]]] = {
    "compile": {"script": "{d}/good.bzz"},
    "run": {"file": "{d}/good.bzz"},
    "asm": {"file": "{d}/good.basm"},
    "disasm": {"file": "{d}/good.bo"},
    "keys init": {"directory": "{d}/keys"},
    "patch apply": {
        "patch": "{d}/good.bo", "base": "{d}/good.bo", "keys": "{d}/keys", "output": "{d}/n.bo",
    },
    "sim run": {"script": "{d}/good.bzz", "robots": "1", "out": "{d}/o", "seconds": "0.1"},
    "sim experiment": {"name": "coverage", "out": "{d}/o", "runs": "1", "seconds": "21"},
    "sim sweep": {
        "names": ["coverage"], "out": "{d}/o", "runs": "1", "seconds": "21", "workers": "1",
    },
    "node": {
        "profile": "solo", "script": "{d}/good.bzz", "robot_id": "1", "radio": "none",
        "seconds": "0.1", "connect_timeout": "0.1",
    },
    "vehicle-sim": {"profile": "solo", "rate": "0"},
    "sitl": {"robots": "1", "script": "{d}/good.bzz", "out": "{d}/o", "seconds": "0.1"},
    "replay": {"bag": "{d}/good.bo", "speed": "max"},
    "bag plot": {"bag": "{d}/good.bo", "output": "{d}/o.png"},
    "update": {
        "script": "{d}/good.bzz", "keys": "{d}/keys", "out": "{d}/o/p.patch", "base": "{d}/good.bo",
    },
    "bag info": {"bag": "{d}/nope"},
    "doctor": {"config": "{d}/nope.toml", "timeout": "0.1", "skip": ["autopilot", "radio"]},
    "bag from-tlog": {
        "tlog": str(ROOT / "tests" / "data" / "tlogs" / "quad-flight-arducopter.tlog"),
        "output": "{d}/out.bag",
    },
    "deploy": {"profile": "solo", "root": "{d}/root", "script": "{d}/good.bzz", "robot_id": "1"},
    "frames decode": {"protocol": "xbee", "frames": ["7e 00 02 8a 00 75"], "api_mode": "1"},
    "ground": {"radio": "udp://127.255.255.255:24999", "keys": "{d}/keys", "http_port": "0",
               "seconds": "0.1"},
    "cmd": {"code": "takeoff", "radio": "udp://127.255.255.255:24999", "keys": "{d}/keys",
            "timeout": "0.1", "listen": "0"},
}  # fmt: skip


def _args(path: tuple[str, ...], values: dict[str, str | list[str]]) -> list[str]:
    """The command line of `path` with these parameter values (by parameter name)."""
    command = LEAVES[path]
    args = list(path)
    for param in command.params:
        if param.name not in values:
            continue
        value = values[param.name]
        for v in [value] if isinstance(value, str) else value:
            args += [v] if param.param_type_name == "argument" else [param.opts[0], v]
    return args


def _annotation(param: Any) -> Any:
    """The parameter's Python type (a list's element type)."""
    annotation = param.type_descriptor.annotation
    return (typing.get_args(annotation) or (annotation,))[0]


def _bad_inputs() -> list[tuple[tuple[str, ...], str, str, int, str]]:
    """(command, parameter, bad value, status, text the error line names) for every
    parameter of every command that takes a file, a directory, a profile or a number."""
    cases = []
    for path, command in LEAVES.items():
        assert " ".join(path) in BASE, f"add {' '.join(path)!r} to BASE"
        for param in command.params:
            name, kind = param.name, _annotation(param)
            if kind in (int, float):
                cases.append((path, name, "abc", 2, f"'{param.opts[0]}'"))
            elif name == "profile":  # a name or a .toml file
                cases.append((path, name, "{d}/nope.toml", 1, "nope.toml"))
                cases.append((path, name, "{d}/locked.toml", 1, "locked.toml"))
                cases.append((path, name, "{d}/adir.toml", 1, "adir.toml"))
            elif kind is not Path or name == "include":
                continue  # (an include directory that does not exist is not searched)
            elif name == "record":  # a new recording: a path that must not exist yet
                cases.append((path, name, "{d}/existing.txt", 1, "existing.txt"))
                if path == ("node",):  # one bag, in a directory that exists (sim, sitl: DIR)
                    cases.append((path, name, "{d}/nodir/flight", 1, "nodir"))
            elif path == ("replay",) and name == "bag":  # unreadable input to compare: 2
                cases.append((path, name, "{d}/nope.bzz", 2, "nope.bzz"))
                cases.append((path, name, "{d}/locked.bzz", 2, "locked.bzz"))
                cases.append((path, name, "{d}/adir.bzz", 2, "adir.bzz"))
            elif name == "state_dir":  # a directory to create or open
                cases.append((path, name, "{d}/existing.txt", 1, "existing.txt"))
                cases.append((path, name, "{d}/lockeddir/s", 1, "lockeddir"))
            elif name == "out" and param.opts[0] == "--out":  # a directory to create
                cases.append((path, name, "{d}/existing.txt", 1, "existing.txt"))
                cases.append((path, name, "{d}/lockeddir/o", 1, "lockeddir"))
            elif name in ("directory", "root"):  # a directory to create (keys init, deploy)
                cases.append((path, name, "{d}/existing.txt", 1, "existing.txt"))
                cases.append((path, name, "{d}/lockeddir/k", 1, "lockeddir"))
            elif name in ("out", "output"):  # an output file
                cases.append((path, name, "{d}/existing.txt/x.bo", 1, "existing.txt"))
                cases.append((path, name, "{d}/adir.bo", 1, "adir"))
            else:  # a file to read
                cases.append((path, name, "{d}/nope.bzz", 1, "nope.bzz"))
                cases.append((path, name, "{d}/locked.bzz", 1, "locked.bzz"))
                cases.append((path, name, "{d}/adir.bzz", 1, "adir.bzz"))
    return cases


BAD_INPUTS = _bad_inputs()


@pytest.fixture
def bad_files(files: Path) -> Iterator[Path]:
    """Beside `files`: unreadable files, directories where files are expected, an existing
    plain file where a directory is expected, and a directory nobody may write in."""
    assert runner.invoke(app, ["compile", str(files / "good.bzz"), "--asm"]).exit_code == 0
    init_keys(files / "keys")
    (files / "existing.txt").write_text("not a directory")
    for name in ("adir.bzz", "adir.toml", "adir.bo"):
        (files / name).mkdir()
    (files / "locked.bzz").write_text(GOOD)
    (files / "locked.toml").write_text("")
    (files / "lockeddir").mkdir()
    for name in ("locked.bzz", "locked.toml", "lockeddir"):
        (files / name).chmod(0)
    yield files
    (files / "lockeddir").chmod(0o700)


@pytest.mark.parametrize(
    ("path", "name", "value", "status", "text"),
    BAD_INPUTS,
    ids=[f"{' '.join(c[0])} {c[1]}={c[2].removeprefix('{d}/')}" for c in BAD_INPUTS],
)
def test_every_command_rejects_bad_input_cleanly(
    bad_files: Path, path: tuple[str, ...], name: str, value: str, status: int, text: str
) -> None:
    if "locked" in value and os.geteuid() == 0:
        pytest.skip("root reads and writes whatever the permissions say")
    values = {**BASE[" ".join(path)], name: value}
    args = [a.format(d=bad_files) for a in _args(path, values)]
    result = runner.invoke(app, args)
    assert "Traceback" not in result.output
    assert result.exit_code == status, result.output
    errors = [line for line in result.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and text in errors[0], result.stderr
    assert isinstance(result.exception, SystemExit)
