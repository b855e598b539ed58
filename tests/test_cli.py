"""The `fieldkit` command-line contract: compile, run, disasm, asm."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from fieldkit.cli import app

runner = CliRunner()


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_compile_writes_bo_and_bdb_beside_the_script(tmp_path: Path) -> None:
    script = write(tmp_path / "a.bzz", "x = 1\nlog(x)\n")
    result = runner.invoke(app, ["compile", str(script)])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "a.bo").read_bytes()[:2] == b"\x02\x00"
    assert (tmp_path / "a.bdb").stat().st_size > 0
    assert not (tmp_path / "a.basm").exists()


def test_compile_output_and_asm(tmp_path: Path) -> None:
    script = write(tmp_path / "a.bzz", "x = 1\n")
    out = tmp_path / "out" / "b.bo"
    out.parent.mkdir()
    result = runner.invoke(app, ["compile", str(script), "-o", str(out), "--asm"])
    assert result.exit_code == 0, result.output
    assert out.exists() and (tmp_path / "out" / "b.bdb").exists()
    assert (tmp_path / "out" / "b.basm").read_text().startswith("!1\n'x\n")


def test_compile_include_dirs_and_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    write(tmp_path / "lib1" / "one.bzz", "one = 1\n")
    write(tmp_path / "lib2" / "two.bzz", "two = 2\n")
    script = write(tmp_path / "main" / "m.bzz", 'include "one.bzz"\ninclude "two.bzz"\n')
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("BUZZ_INCLUDE_PATH", str(tmp_path / "lib2"))
    result = runner.invoke(app, ["compile", str(script), "-I", str(tmp_path / "lib1")])
    assert result.exit_code == 0, result.output
    monkeypatch.delenv("BUZZ_INCLUDE_PATH")
    result = runner.invoke(app, ["compile", str(script), "-I", str(tmp_path / "lib1")])
    assert result.exit_code == 1
    assert "m.bzz:2:" in result.stderr and "two.bzz" in result.stderr


def test_compile_error_is_path_line_col_and_exit_1(tmp_path: Path) -> None:
    script = write(tmp_path / "bad.bzz", "x = 1\ny = (2 +\n")
    result = runner.invoke(app, ["compile", str(script)])
    assert result.exit_code == 1
    first = result.stderr.splitlines()[0]
    assert first.startswith((f"error: {script.resolve()}:", f"error: {script}:"))
    assert "Syntax error" in first
    assert "Traceback" not in result.stderr


def test_run_steps_and_robot_id(tmp_path: Path) -> None:
    script = write(
        tmp_path / "s.bzz",
        'n = 0\nfunction init() { log("init ", id) }\n'
        "function step() { n = n + 1  log(n) }\n"
        'function destroy() { log("bye") }\n',
    )
    result = runner.invoke(app, ["run", str(script), "--robot-id", "4", "--steps", "2"])
    assert result.exit_code == 0, result.output
    assert result.stdout == "init 4\n1\n2\nbye\n"


def test_run_compiled_bo_uses_its_bpos_then_its_bdb_for_errors(tmp_path: Path) -> None:
    script = write(tmp_path / "e.bzz", "x = 1\ny = x + nil\nz = 2\n")
    assert runner.invoke(app, ["compile", str(script)]).exit_code == 0
    script.unlink()  # the .bo and its sidecar suffice: no source needed
    result = runner.invoke(app, ["run", str(tmp_path / "e.bo")])
    assert result.exit_code == 1
    expected = f"error: {script}:2:7: type mismatch: cannot add integer and nil"
    assert result.stderr.strip() == expected
    # Without the sidecar, where the reference puts it (the token after), from the .bdb.
    (tmp_path / "e.bpos").unlink()
    result = runner.invoke(app, ["run", str(tmp_path / "e.bo")])
    assert result.exit_code == 1
    expected = f"error: {script.resolve()}:3:0: type mismatch: cannot add integer and nil"
    assert result.stderr.strip() == expected
    (tmp_path / "e.bdb").unlink()
    result = runner.invoke(app, ["run", str(tmp_path / "e.bo")])
    assert result.exit_code == 1 and "bytecode offset" in result.stderr


def test_run_corrupt_bo_is_a_clean_error(tmp_path: Path) -> None:
    bo = tmp_path / "x.bo"
    bo.write_bytes(b"\x05\x00abc")
    result = runner.invoke(app, ["run", str(bo)])
    assert result.exit_code == 1
    assert "truncated bytecode" in result.stderr


def test_disasm_then_asm_gives_back_the_same_bytes(tmp_path: Path) -> None:
    src = (Path(__file__).parent.parent / "buzz_scripts/examples/hello.bzz").read_text()
    script = write(tmp_path / "h.bzz", src)
    assert runner.invoke(app, ["compile", str(script)]).exit_code == 0
    listing = runner.invoke(app, ["disasm", str(tmp_path / "h.bo")])
    assert listing.exit_code == 0
    basm = tmp_path / "again.basm"
    basm.write_bytes(listing.stdout_bytes)
    assert runner.invoke(app, ["asm", str(basm)]).exit_code == 0
    assert (tmp_path / "again.bo").read_bytes() == (tmp_path / "h.bo").read_bytes()


def test_console_script_prints_no_traceback(tmp_path: Path) -> None:
    script = write(tmp_path / "bad.bzz", "x = = 1\n")
    proc = subprocess.run(
        [sys.executable, "-m", "fieldkit", "compile", str(script)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert proc.returncode == 1
    assert "Traceback" not in proc.stderr and "bad.bzz:1:" in proc.stderr
