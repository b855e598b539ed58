"""`fieldkit node --state-dir DIR --keys DIR`: the committed version runs, `--script` only
seeds an empty store, and bad keys or an unusable store stop the node at start.

Runs that must show which script ran use the simulated ArduPilot on a pty (as in
test_node_cli.py); the others stop before the autopilot, or at its heartbeat wait on a port
where no autopilot answers (a failure after `--connect-timeout`, never a pass that waits).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from rigs import pty_vehicle
from typer.testing import CliRunner

import bvm
from fieldkit.cli import app
from fieldkit.update.release import Release
from fieldkit.update.store import VersionStore

runner = CliRunner()

SAYS_A = 'function init() { log("I am A") }\nfunction step() {}\n'
SAYS_B = 'function init() { log("I am B") }\nfunction step() {}\n'

#: No autopilot answers here: a run that gets this far has already chosen its version.
NOWHERE = ("--autopilot", "udpin:127.0.0.1:0", "--connect-timeout", "0.2")


@pytest.fixture
def vehicle() -> Iterator[str]:
    """The solo's simulated ArduPilot on a pty, GPS fixed, in real time: the pty's path."""
    with pty_vehicle() as path:
        yield path


def node(*args: str | Path) -> list[str]:
    return ["node", "--robot-id", "1", "--profile", "solo", "--radio", "none",
            *(str(a) for a in args)]  # fmt: skip


def texts(stdout: str) -> list[str]:
    """The node's log lines without their stamps."""
    return [line.split("robot 1: ", 1)[1] for line in stdout.splitlines()]


def errors(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("error: ")]


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_the_script_seeds_an_empty_store_then_the_committed_version_wins(
    tmp_path: Path, vehicle: str
) -> None:
    state, a = tmp_path / "state", write(tmp_path / "a.bzz", SAYS_A)
    result = runner.invoke(app, node("--state-dir", state, "--script", a, "--autopilot", vehicle,
                                     "--seconds", "0.2"))  # fmt: skip
    assert result.exit_code == 0, result.output
    lines = texts(result.stdout)
    release = Release.from_program(bvm.compile_file(a))
    assert f"running version 0 ({release.hash[:12]}…), seeded from --script {a}" in lines
    assert "I am A" in lines
    assert any(t.startswith(f"starting version 0 ({release.hash[:12]}…) at ") for t in lines)
    seeded = VersionStore(state).committed()
    assert seeded is not None and (seeded.version, seeded.hash) == (0, release.hash)
    # An update (as the agent commits it), then a reboot with the same command line.
    store = VersionStore(state)
    b = Release.from_program(bvm.compile_source(SAYS_B, "b.bzz"))
    store.commit(1, store.put(b), reason="update to 1 agreed by 4 robots")
    when = store.current.time  # type: ignore[union-attr]
    result = runner.invoke(app, node("--state-dir", state, "--script", a, "--autopilot", vehicle,
                                     "--seconds", "0.2"))  # fmt: skip
    assert result.exit_code == 0, result.output
    lines = texts(result.stdout)
    assert "I am B" in lines and "I am A" not in lines
    assert f"--script {a} not used: {state} holds a committed version (--script only seeds " \
        "an empty state directory)" in lines  # fmt: skip
    assert (
        f"running version 1 ({b.hash[:12]}…), committed {when}: update to 1 agreed by 4 robots"
        in lines
    )
    assert [e["event"] for e in VersionStore(state).history()] == ["seeded", "committed"]


def test_a_committed_version_runs_without_a_script_and_a_recovery_is_logged(
    tmp_path: Path,
) -> None:
    state = tmp_path / "state"
    store = VersionStore(state)
    a = Release.from_program(bvm.compile_source(SAYS_A, "a.bzz"))
    b = Release.from_program(bvm.compile_source(SAYS_B, "b.bzz"))
    store.commit(0, store.put(a), reason="seeded by hand")
    store.commit(1, store.put(b), reason="update")
    store.path(b.hash).write_bytes(b"rot")  # the committed version's bytecode, corrupt
    result = runner.invoke(app, node("--state-dir", state, *NOWHERE))
    assert result.exit_code == 1  # no autopilot: but the version was chosen first
    assert "no heartbeat" in errors(result.stderr)[0]
    lines = texts(result.stdout)
    assert re.fullmatch(
        rf"warning: {re.escape(str(state))}: recovered version 0 \({a.hash[:12]}\): version 1 "
        r"\([0-9a-f]{12}\) unusable: its release .* is missing or corrupt; back to the newest "
        r"version stored whole",
        lines[0],
    ), lines[0]
    assert lines[1].startswith(f"running version 0 ({a.hash[:12]}…), recovered ")


def test_an_empty_store_without_a_script_is_an_error(tmp_path: Path) -> None:
    state = tmp_path / "state"
    result = runner.invoke(app, node("--state-dir", state, *NOWHERE))
    assert result.exit_code == 1, result.output
    assert errors(result.stderr) == [
        f"error: {state}: no committed version to run, and no --script to seed one"
    ]
    assert "hint: give --script PATH once" in result.stderr


def test_neither_script_nor_state_dir_does_not_parse(tmp_path: Path) -> None:
    result = runner.invoke(app, node(*NOWHERE))
    assert result.exit_code == 2, result.output
    assert errors(result.stderr)[0].startswith("error: Missing option '--script'")


def test_a_seed_that_does_not_compile_leaves_the_store_empty(tmp_path: Path) -> None:
    state, bad = tmp_path / "state", write(tmp_path / "bad.bzz", "function init( {\n")
    result = runner.invoke(app, node("--state-dir", state, "--script", bad, *NOWHERE))
    assert result.exit_code == 1, result.output
    assert errors(result.stderr)[0].startswith(f"error: {bad}:1:")
    assert VersionStore(state).committed() is None


def test_an_unusable_store_is_an_error_at_start(tmp_path: Path) -> None:
    state = tmp_path / "state"
    store = VersionStore(state)
    store.commit(0, store.put(Release.from_program(bvm.compile_source(SAYS_A, "a.bzz"))),
                 reason="seeded")  # fmt: skip
    store.committed_path.write_text("{")
    store.history_path.unlink()
    a = write(tmp_path / "a.bzz", SAYS_A)
    result = runner.invoke(app, node("--state-dir", state, "--script", a, *NOWHERE))
    assert result.exit_code == 1, result.output
    (line,) = errors(result.stderr)
    assert line.startswith(f"error: {state / 'committed.json'}: it does not parse")
    assert "hint: move" in result.stderr and "autopilot" not in result.stdout
    assert "Traceback" not in result.output


def test_robot_keys_are_loaded_at_start_and_bad_ones_stop_the_node(tmp_path: Path) -> None:
    keys = pytest.importorskip("fieldkit.update.keys")
    a = write(tmp_path / "a.bzz", SAYS_A)
    kdir = tmp_path / "keys"
    result = runner.invoke(app, node("--script", a, "--keys", kdir, *NOWHERE))
    assert result.exit_code == 1, result.output
    assert "operator.pub" in errors(result.stderr)[0]
    paths = keys.init_keys(kdir)
    (kdir / "operator.key").unlink()  # a robot holds no signing key
    result = runner.invoke(app, node("--script", a, "--keys", kdir, *NOWHERE))
    # Keys mean signed bundles, whose counter lives in the state directory.
    assert result.exit_code == 1 and "--state-dir" in errors(result.stderr)[0]
    result = runner.invoke(app, node("--script", a, "--keys", kdir, "--security", "none", *NOWHERE))
    assert result.exit_code == 1 and "no heartbeat" in errors(result.stderr)[0]  # keys fine
    paths.swarm_key.chmod(0o644)
    result = runner.invoke(app, node("--script", a, "--keys", kdir, *NOWHERE))
    assert result.exit_code == 1, result.output
    (line,) = errors(result.stderr)
    assert "swarm.key" in line and "chmod 600" in result.stderr
    assert "autopilot" not in result.stdout  # stopped before any port
