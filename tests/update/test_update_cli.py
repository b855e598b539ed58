"""`fieldkit update SCRIPT --patch-out FILE --base OLD.bo`: compile, trial, patch, files."""

from __future__ import annotations

import os
import queue
import signal
import subprocess
import sys
import threading
from pathlib import Path
from typing import IO

import pytest
from typer.testing import CliRunner

import bvm
from fieldkit.cli import app
from fieldkit.update.keys import init_keys, load_robot_keys
from fieldkit.update.patch import open_update
from fieldkit.update.release import Release

runner = CliRunner()

#: Hang guard for the watching process (never a pace).
HANG_S = 120.0

V1 = "function init() { t = 0 }\nfunction step() { t = t + 1 }\n"
V2 = 'include "lib.bzz"\nfunction init() { t = 0 }\nfunction step() { t = t + helper() }\n'
LIB = "function helper() { return 2 }\n"
# Robot 2 divides by zero in step() at simulated second 2.
BROKEN = """function init() { t = 0 }
function step() {
  if (t == 20 and id == 2) { var x = 1 / 0 }
  t = t + 1
}
"""


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


@pytest.fixture
def field(tmp_path: Path) -> Path:
    """Keys in keys/, the swarm's release in out/v1.bo (version 4), lib.bzz in lib/."""
    init_keys(tmp_path / "keys")
    Release.from_program(bvm.compile_source(V1, "v1.bzz")).write(tmp_path / "out" / "v1.bo")
    (tmp_path / "out" / "v1.version").write_text("4\n")
    write(tmp_path / "lib" / "lib.bzz", LIB)
    return tmp_path


def update(field: Path, script: Path, *extra: str, base: str = "out/v1.bo") -> list[str]:
    """The command line of an update of `script` into out/v2.patch."""
    return [
        "update",
        str(script),
        "-I",
        str(field / "lib"),
        "--keys",
        str(field / "keys"),
        "--patch-out",
        str(field / "out" / "v2.patch"),
        "--base",
        str(field / base),
        *extra,
    ]


def opened(field: Path, patch: Path, base: Path, current: int) -> tuple[int, Release]:
    """What a robot running `base` as version `current` makes of the patch."""
    header, release = open_update(
        patch.read_bytes(),
        base=Release.read(base),
        keys=load_robot_keys(field / "keys"),
        current_version=current,
    )
    return header.version, release


def test_an_update_writes_the_patch_and_the_new_release_beside_it(field: Path) -> None:
    script = write(field / "v2.bzz", V2)
    result = runner.invoke(app, update(field, script))
    assert result.exit_code == 0, result.stderr
    out = field / "out"
    expected = Release.from_program(bvm.compile_file(script, [str(field / "lib")]))
    assert Release.read(out / "v2.bo") == expected
    assert (out / "v2.version").read_text() == "5\n"  # one more than v1.version
    version, release = opened(field, out / "v2.patch", out / "v1.bo", current=4)
    assert version == 5 and release == expected
    for name in ("v2.bo", "v2.bdb", "v2.bpos", "v2.version", "v2.patch"):
        assert f"wrote {out / name}\n" in result.stderr  # says where everything went
    assert "version 5" in result.stdout and str(out / "v2.patch") in result.stdout
    assert "passed its trial (3 robots of solo" in result.stderr


def test_the_next_update_builds_on_the_release_written_beside_the_patch(field: Path) -> None:
    assert runner.invoke(app, update(field, write(field / "v2.bzz", V2))).exit_code == 0
    v3 = write(field / "v3.bzz", V2.replace("helper()", "helper() * 3"))
    cmd = update(field, v3, base="out/v2.bo")
    cmd[cmd.index("--patch-out") + 1] = str(field / "out" / "v3.patch")
    result = runner.invoke(app, cmd)
    assert result.exit_code == 0, result.stderr
    out = field / "out"
    version, release = opened(field, out / "v3.patch", out / "v2.bo", current=5)
    assert version == 6 and release == Release.read(out / "v3.bo")


def test_the_version_is_one_without_a_record_and_the_given_one_with_version(
    field: Path,
) -> None:
    (field / "out" / "v1.version").unlink()
    script = write(field / "v2.bzz", V2)
    assert runner.invoke(app, update(field, script)).exit_code == 0
    assert opened(field, field / "out" / "v2.patch", field / "out" / "v1.bo", 0)[0] == 1
    assert runner.invoke(app, update(field, script, "--version", "40")).exit_code == 0
    assert opened(field, field / "out" / "v2.patch", field / "out" / "v1.bo", 0)[0] == 40
    assert (field / "out" / "v2.version").read_text() == "40\n"


def new_files(field: Path) -> list[str]:
    return sorted(p.name for p in (field / "out").iterdir() if not p.name.startswith("v1."))


def test_a_script_error_in_the_trial_refuses_the_update_and_writes_nothing(
    field: Path,
) -> None:
    script = write(field / "v2.bzz", BROKEN)
    result = runner.invoke(app, update(field, script, "--profile", "husky"))
    assert result.exit_code == 1
    lines = result.stderr.splitlines()
    assert lines[0] == f"error: {script}: the new version failed its trial in the simulator " + (
        "with 1 script error, so it is not released:"
    )
    assert lines[1] == (
        f"  - {script}:3:40: division by zero (robot 2 of the husky swarm, at 2.0 s simulated)"
    )
    assert new_files(field) == []
    assert "Traceback" not in result.stderr


def test_a_compile_error_is_path_line_col_and_writes_nothing(field: Path) -> None:
    script = write(field / "v2.bzz", "function step() {\n  x = (1 +\n}\n")
    result = runner.invoke(app, update(field, script))
    assert result.exit_code == 1
    assert result.stderr.startswith(f"error: {script}:3:1: ")
    assert new_files(field) == []


def test_an_unchanged_bytecode_is_nothing_to_update(field: Path) -> None:
    script = write(field / "v2.bzz", "# only a comment more\n" + V1)
    result = runner.invoke(app, update(field, script))
    assert result.exit_code == 1
    assert f"error: {script}: compiles to {field / 'out' / 'v1.bo'}: the same bytecode" in (
        result.stderr
    )
    assert new_files(field) == []


def test_key_problems_are_clear_and_found_before_anything_runs(field: Path) -> None:
    script = write(field / "v2.bzz", "this does not compile (")
    cmd = update(field, script)
    cmd[cmd.index("--keys") + 1] = str(field / "nokeys")
    result = runner.invoke(app, cmd)
    assert result.exit_code == 1
    assert result.stderr.splitlines() == [
        f"error: --keys {field / 'nokeys'}: no such directory",
        f"  hint: `fieldkit keys init {field / 'nokeys'}` creates the operator's keys",
    ]
    os.chmod(field / "keys" / "swarm.key", 0o644)
    result = runner.invoke(app, update(field, script))
    assert result.exit_code == 1
    assert result.stderr.startswith(f"error: {field / 'keys' / 'swarm.key'}")
    assert "chmod 600" in result.stderr
    os.chmod(field / "keys" / "swarm.key", 0o600)
    (field / "keys" / "operator.key").unlink()
    result = runner.invoke(app, update(field, script))
    assert result.exit_code == 1
    assert result.stderr.startswith(f"error: {field / 'keys' / 'operator.key'}")
    assert new_files(field) == []


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"--profile": "nosuch"}, "--profile 'nosuch'"),
        ({"--version": "0"}, "--version 0: a version number is 1 or more"),
        ({"--patch-out": "out/v2.bo"}, "give the patch another name, such as out/v2.patch"),
        ({"--base": "out/missing.bo"}, "missing.bo: cannot read"),
    ],
)
def test_bad_values_exit_1_and_write_nothing(
    field: Path, change: dict[str, str], words: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(field)
    cmd = update(field, write(field / "v2.bzz", V2))
    for option, value in change.items():
        if option in cmd:
            cmd[cmd.index(option) + 1] = value
        else:
            cmd += [option, value]
    result = runner.invoke(app, cmd)
    assert result.exit_code == 1
    assert result.stderr.startswith("error: ") and words in result.stderr
    assert new_files(field) == []


def test_a_bad_recorded_version_names_its_file(field: Path) -> None:
    (field / "out" / "v1.version").write_text("four\n")
    result = runner.invoke(app, update(field, write(field / "v2.bzz", V2)))
    assert result.exit_code == 1
    assert result.stderr.startswith(f"error: {field / 'out' / 'v1.version'}: expected")
    assert "--version N" in result.stderr


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["update", "s.bzz", "--keys", "k"], "one of --radio URL"),
        (["update", "s.bzz", "--keys", "k", "--radio", "udp:x", "--patch-out", "p"], "one of"),
        (["update", "s.bzz", "--keys", "k", "--patch-out", "p"], "--patch-out needs --base"),
        (["update", "--keys", "k", "--patch-out", "p", "--base", "b.bo"], "missing argument"),
        (["update", "s.bzz", "--patch-out", "p", "--base", "b.bo"], "missing option --keys"),
        (["update", "s.bzz", "--keys", "k", "--version", "x"], "--version"),
    ],
)
def test_a_command_line_that_does_not_parse_is_exit_2(args: list[str], words: str) -> None:
    result = runner.invoke(app, args)
    assert result.exit_code == 2
    assert "error: " in result.stderr and words in result.stderr


class Lines:
    """A process's stderr, line by line, read in a thread (waits have a hang guard)."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        self.lines: queue.Queue[str] = queue.Queue()
        assert proc.stderr is not None
        threading.Thread(target=self._read, args=(proc.stderr,), daemon=True).start()

    def _read(self, stream: IO[str]) -> None:
        for line in stream:
            self.lines.put(line)

    def until(self, words: str) -> list[str]:
        """The lines up to the first holding `words`."""
        seen: list[str] = []
        while not seen or words not in seen[-1]:
            seen.append(self.lines.get(timeout=HANG_S))
        return seen


def test_watch_makes_a_new_version_on_every_save_until_ctrl_c(field: Path) -> None:
    script = write(field / "v2.bzz", V2)
    out = field / "out"
    cmd = [sys.executable, "-m", "fieldkit", *update(field, script, "--watch")]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        err = Lines(proc)
        err.until(f"wrote {out / 'v2.patch'}")  # the first run, at once
        first = Release.read(out / "v2.bo")
        # A broken save is refused and waited past; the base stays the last release.
        tmp = field / ".v2.bzz.tmp"
        tmp.write_text(BROKEN)
        os.replace(tmp, script)
        refused = err.until("waiting for the next save")
        assert any("division by zero (robot 2 of the solo swarm" in line for line in refused)
        script.write_text(V2.replace("helper()", "helper() + 1"))  # in place this time
        err.until(f"wrote {out / 'v2.patch'}")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=HANG_S) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert "stopped watching after 3 runs" in err.until("stopped watching")[-1]
    assert proc.stdout is not None
    stdout = proc.stdout.read().splitlines()
    assert len(stdout) == 2 and "version 5 (" in stdout[0] and "version 6 (" in stdout[1]
    # Version 6 builds on version 5, the release the first run wrote beside the patch.
    second = Release.read(out / "v2.bo")
    header, release = open_update(
        (out / "v2.patch").read_bytes(),
        base=first,
        keys=load_robot_keys(field / "keys"),
        current_version=5,
    )
    assert header.version == 6 and release == second != first
    assert (out / "v2.version").read_text() == "6\n"
