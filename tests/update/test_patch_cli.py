"""`fieldkit keys init` and `fieldkit patch apply`: what a robot does with a patch, offline."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from fieldkit.cli import app
from fieldkit.update.keys import load_robot_keys, load_signing_key
from fieldkit.update.patch import HEADER_LEN, MAX_PATCH_BYTES, make_update
from fieldkit.update.release import Release

from .patchkit import SCRIPTS, source

runner = CliRunner()


def fieldkit(*args: str | Path) -> subprocess.CompletedProcess[str]:
    """Run the real command in its own process."""
    return subprocess.run(
        [sys.executable, "-m", "fieldkit", *map(str, args)],
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )


def invoke(*args: str | Path) -> tuple[int, str, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.stdout, result.stderr


@pytest.fixture
def work(tmp_path: Path) -> Path:
    """Keys, and versions 1 and 2 of a shipped script compiled by `fieldkit compile` (the
    script at the same path both times, as an operator edits it), with the patch 1 -> 2."""
    assert invoke("keys", "init", tmp_path / "keys")[0] == 0
    script = tmp_path / "coverage.bzz"
    for n in (1, 2):
        script.write_text(source(n))
        code, _, err = invoke("compile", script, "-I", SCRIPTS, "-o", tmp_path / f"v{n}.bo")
        assert code == 0, err
    patch = make_update(
        Release.read(tmp_path / "v1.bo"),
        Release.read(tmp_path / "v2.bo"),
        1,
        load_signing_key(tmp_path / "keys"),
        load_robot_keys(tmp_path / "keys").swarm_key,
    )
    (tmp_path / "p1.fkup").write_bytes(patch)
    return tmp_path


def test_keys_init_writes_three_files_and_says_what_a_robot_needs(tmp_path: Path) -> None:
    proc = fieldkit("keys", "init", tmp_path / "k")
    assert proc.returncode == 0, proc.stderr
    for name in ("operator.key", "operator.pub", "swarm.key"):
        assert f"wrote {tmp_path / 'k' / name}" in proc.stderr
    assert f"robots need {tmp_path / 'k' / 'operator.pub'} and {tmp_path / 'k' / 'swarm.key'}" in (
        proc.stdout
    )
    load_robot_keys(tmp_path / "k")
    load_signing_key(tmp_path / "k")


def test_keys_init_never_overwrites(tmp_path: Path) -> None:
    assert invoke("keys", "init", tmp_path)[0] == 0
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    code, _, err = invoke("keys", "init", tmp_path)
    assert code == 1
    assert err.startswith(f"error: {tmp_path / 'operator.key'}: already exists")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_patch_apply_makes_exactly_what_the_compiler_makes(work: Path) -> None:
    proc = fieldkit(
        "patch",
        "apply",
        work / "p1.fkup",
        "--base",
        work / "v1.bo",
        "--keys",
        work / "keys",
        "-o",
        work / "new.bo",
    )
    assert proc.returncode == 0, proc.stderr
    for suffix in (".bo", ".bdb", ".bpos"):
        made = (work / "new").with_suffix(suffix)
        assert made.read_bytes() == (work / "v2").with_suffix(suffix).read_bytes(), suffix
        assert f"wrote {made}" in proc.stderr
    assert (work / "new.version").read_text() == "1\n"
    assert "version 1" in proc.stdout


def test_the_version_beside_the_base_stops_a_replay(work: Path) -> None:
    args = ["patch", "apply", work / "p1.fkup", "--keys", work / "keys"]
    assert invoke(*args, "--base", work / "v1.bo", "-o", work / "new.bo")[0] == 0
    # new.version says 1: the same patch applied to the robot's new state is a replay.
    (work / "v1.bo").with_suffix(".version").write_text("1\n")
    code, _, err = invoke(*args, "--base", work / "v1.bo", "-o", work / "again.bo")
    assert code == 1
    assert err.startswith(f"error: {work / 'p1.fkup'}: rejected (replayed): ")
    assert not list(work.glob("again.*"))
    # --current-version overrides the recorded one.
    code, _, err = invoke(
        *args, "--base", work / "v1.bo", "-o", work / "again.bo", "--current-version", "0"
    )
    assert code == 0, err


REJECTIONS = {
    "bad-signature": lambda data: data[:HEADER_LEN] + bytes(64) + data[HEADER_LEN + 64 :],
    "bad-body": lambda data: data[:-1] + bytes([data[-1] ^ 1]),
    "truncated": lambda data: data[:-10],
    "bad-magic": lambda data: b"XXXX" + data[4:],
    "too-large": lambda data: data + bytes(MAX_PATCH_BYTES),
}


@pytest.mark.parametrize("reason", sorted(REJECTIONS))
def test_a_rejected_patch_writes_nothing_and_says_why(work: Path, reason: str) -> None:
    bad = work / "bad.fkup"
    bad.write_bytes(REJECTIONS[reason]((work / "p1.fkup").read_bytes()))
    code, out, err = invoke(
        "patch",
        "apply",
        bad,
        "--base",
        work / "v1.bo",
        "--keys",
        work / "keys",
        "-o",
        work / "new.bo",
    )
    assert code == 1
    assert err.startswith(f"error: {bad}: rejected ({reason}): "), err
    assert len(err.splitlines()) == 1
    assert not list(work.glob("new.*"))


def test_a_patch_for_another_base_or_swarm_is_rejected(work: Path) -> None:
    args = ["patch", "apply", work / "p1.fkup", "-o", work / "new.bo"]
    code, _, err = invoke(*args, "--base", work / "v2.bo", "--keys", work / "keys")
    assert code == 1 and "rejected (wrong-base)" in err
    other = work / "other"
    assert invoke("keys", "init", other)[0] == 0
    code, _, err = invoke(*args, "--base", work / "v1.bo", "--keys", other)
    assert code == 1 and "rejected (bad-signature)" in err
    # The operator's key with another swarm's key: the body does not decrypt.
    (other / "operator.pub").write_bytes((work / "keys" / "operator.pub").read_bytes())
    code, _, err = invoke(*args, "--base", work / "v1.bo", "--keys", other)
    assert code == 1 and "rejected (bad-decrypt)" in err
    assert not list(work.glob("new.*"))


def test_key_problems_are_clear_errors(work: Path) -> None:
    args = ["patch", "apply", work / "p1.fkup", "--base", work / "v1.bo", "-o", work / "n.bo"]
    code, _, err = invoke(*args, "--keys", work / "nowhere")
    assert code == 1
    assert err.startswith(f"error: {work / 'nowhere' / 'operator.pub'}: missing\nhint: ")
    (work / "keys" / "swarm.key").chmod(0o644)
    code, _, err = invoke(*args, "--keys", work / "keys")
    assert code == 1 and f"hint: chmod 600 {work / 'keys' / 'swarm.key'}" in err
    assert not list(work.glob("n.*"))


def test_a_robot_without_the_signing_key_applies_patches(work: Path) -> None:
    robot = work / "robot"
    robot.mkdir()
    for name in ("operator.pub", "swarm.key"):
        (robot / name).write_bytes((work / "keys" / name).read_bytes())
    (robot / "swarm.key").chmod(0o600)
    code, _, err = invoke(
        "patch",
        "apply",
        work / "p1.fkup",
        "--base",
        work / "v1.bo",
        "--keys",
        robot,
        "-o",
        work / "new.bo",
    )
    assert code == 0, err


def test_base_and_version_file_problems(work: Path) -> None:
    args = ["patch", "apply", work / "p1.fkup", "--keys", work / "keys", "-o", work / "n.bo"]
    code, _, err = invoke(*args, "--base", work / "missing.bo")
    assert code == 1 and err.startswith(f"error: {work / 'missing.bo'}: cannot read")
    (work / "v1.version").write_text("seven\n")
    code, _, err = invoke(*args, "--base", work / "v1.bo")
    assert code == 1 and err.startswith(f"error: {work / 'v1.version'}: expected a version number")
    code, _, err = invoke(
        "patch",
        "apply",
        work / "nofile",
        "--keys",
        work / "keys",
        "--base",
        work / "v1.bo",
        "-o",
        work / "n.bo",
        "--current-version",
        "0",
    )
    assert code == 1 and err.startswith(f"error: {work / 'nofile'}: cannot read")
    assert not list(work.glob("n.*"))


def test_a_command_line_that_does_not_parse_is_exit_2(work: Path) -> None:
    code, _, err = invoke("patch", "apply", work / "p1.fkup", "--base", work / "v1.bo")
    assert code == 2 and "--keys" in err
