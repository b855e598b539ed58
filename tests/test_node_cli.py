"""`fieldkit node` from the command line, with real parts: the simulated ArduPilot on a pty
(stepped in real time by a thread, as `fieldkit vehicle-sim` runs it), a pty standing in for
the XBee's serial port, and the node itself in this process or as a subprocess.

Nothing here waits on time: a test waits for output or for the node to end. The node's own
run is bounded by `--seconds`, and what a test asserts holds after any number of ticks >= 1
(the first tick always runs).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from rigs import pty_vehicle
from typer.testing import CliRunner

from fieldkit.cli import app
from fieldkit.node.log import NodeLog, wall_stamp
from fieldkit.radio.xbee import FrameReader
from fieldkit.robot.profiles import load_profile
from fieldkit.vehicle.pty import PtyPair, open_pty

runner = CliRunner()

#: A node's log line: UTC wall time to the millisecond, then the robot.
LINE = re.compile(r"\[(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z)\] robot 1: (.*)")

PLAIN = "function init() {}\nfunction step() {}\n"

HELLO = """
function init() { log(SHAPE)  log(N + 1) }
function step() { if (flight.rc_cmd == 22) log("rc 22") }
"""


@pytest.fixture
def vehicle() -> Iterator[str]:
    """The solo's simulated ArduPilot on a pty, GPS fixed, in real time: the pty's path."""
    with pty_vehicle() as path:
        yield path


@pytest.fixture
def xbee() -> Iterator[PtyPair]:
    """A pty standing in for the XBee's serial port (the node opens its slave end)."""
    pty = open_pty()
    yield pty
    pty.close()


def solo_text() -> str:
    """The shipped solo profile's TOML."""
    path = load_profile("solo").path
    assert path is not None
    return path.read_text()


def profile_with_radio_port(tmp_path: Path, port: str) -> Path:
    """The solo profile, its XBee on `port`."""
    text = solo_text()
    assert 'port = "/dev/ttyUSB0"' in text
    path = tmp_path / "mine.toml"
    path.write_text(text.replace('port = "/dev/ttyUSB0"', f'port = "{port}"'))
    return path


def script(tmp_path: Path, src: str = PLAIN) -> Path:
    path = tmp_path / "s.bzz"
    path.write_text(src)
    return path


def node(*args: str | Path) -> list[str]:
    return ["node", "--robot-id", "1", *(str(a) for a in args)]


def errors(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("error: ")]


# ------------------------------------------------------------------ the log


def test_a_log_line_is_utc_wall_time_and_the_robot() -> None:
    lines: list[str] = []

    class Sink:
        def write(self, text: str) -> None:
            lines.append(text)

        def flush(self) -> None:
            pass

    log = NodeLog(4, Sink(), wall=lambda: 1795683804.1239)  # type: ignore[arg-type]
    log("hello")
    log("a\nb")
    assert lines == [
        "[2026-11-26T09:03:24.123Z] robot 4: hello\n",
        "[2026-11-26T09:03:24.123Z] robot 4: a\n[2026-11-26T09:03:24.123Z] robot 4: b\n",
    ]
    assert wall_stamp(0.0) == "1970-01-01T00:00:00.000Z"
    assert wall_stamp(59.9999) == "1970-01-01T00:00:59.999Z"  # truncated, never :60.000


# ------------------------------------------------------------------ the command line


def test_the_two_field_command_is_gone(tmp_path: Path) -> None:
    result = runner.invoke(app, node("--profile", "solo", "--script", script(tmp_path),
                                     "--command", "5:22"))  # fmt: skip
    assert result.exit_code == 2, result.output
    assert errors(result.stderr) == [
        "error: --command '5:22': expected T:ROBOT:CODE[:P...], e.g. 5:1:22 (robot 1 takes "
        "off at 5 s); the two-field T:CODE form is gone"
    ]


def test_a_command_for_another_robot_is_refused(tmp_path: Path) -> None:
    result = runner.invoke(app, node("--profile", "solo", "--script", script(tmp_path),
                                     "--command", "5:3:22"))  # fmt: skip
    assert result.exit_code == 1, result.output
    assert errors(result.stderr) == [
        "error: --command '5:3:22' is for robot 3, this node is robot 1"
    ]


def test_a_set_that_does_not_parse_is_a_usage_error(tmp_path: Path) -> None:
    result = runner.invoke(app, node("--profile", "solo", "--script", script(tmp_path),
                                     "--set", "9X=1"))  # fmt: skip
    assert result.exit_code == 2 and "--set '9X=1'" in errors(result.stderr)[0]


@pytest.mark.parametrize(
    ("option", "value"), [("--seconds", "0"), ("--seconds", "nan"), ("--connect-timeout", "-1")]
)
def test_a_duration_must_be_positive(tmp_path: Path, option: str, value: str) -> None:
    result = runner.invoke(app, node("--profile", "solo", "--script", script(tmp_path),
                                     option, value))  # fmt: skip
    assert result.exit_code == 1, result.output
    assert errors(result.stderr)[0].startswith(f"error: {option} must be > 0")


def test_a_profile_without_a_radio_says_what_to_write(tmp_path: Path) -> None:
    # Without its [radio] and [radio.id_map] tables (up to the next table, [robot_id]).
    text, n = re.subn(r"\[radio\].*?(?=\[robot_id\])", "", solo_text(), flags=re.S)
    assert n == 1 and "[radio" not in text
    path = tmp_path / "noradio.toml"
    path.write_text(text)
    result = runner.invoke(app, node("--profile", path, "--script", script(tmp_path)))
    assert result.exit_code == 1, result.output
    assert "radio" in errors(result.stderr)[0]
    assert "hint: the node's radio is the profile's [radio] table, e.g. kind = \"xbee\"" in (
        result.stderr
    )


# ------------------------------------------------------------------ the radio


def test_a_missing_xbee_fails_before_the_wait_for_the_autopilot(tmp_path: Path) -> None:
    # No autopilot answers on this URL: had the node waited for one first, it would fail
    # with "no heartbeat" after the timeout instead.
    port = tmp_path / "ttyUSB-unplugged"
    prof = profile_with_radio_port(tmp_path, str(port))
    result = runner.invoke(app, node("--profile", prof, "--script", script(tmp_path),
                                     "--autopilot", "udpin:127.0.0.1:0",
                                     "--connect-timeout", "1"))  # fmt: skip
    assert result.exit_code == 1, result.output
    assert errors(result.stderr) == [f"error: radio {port}: No such file or directory"]
    assert "--radio none" in result.stderr  # the hint says how to run without it
    assert "heartbeat" not in result.output and "autopilot" not in result.stdout


def test_a_bad_radio_url_fails_the_same_way(tmp_path: Path) -> None:
    result = runner.invoke(app, node("--profile", "solo", "--script", script(tmp_path),
                                     "--radio", "serial://", "--autopilot", "udpin:127.0.0.1:0",
                                     "--connect-timeout", "1"))  # fmt: skip
    assert result.exit_code == 1, result.output
    assert errors(result.stderr)[0].startswith("error: radio serial://: no device")


def test_the_profiles_xbee_is_the_default_radio(
    tmp_path: Path, vehicle: str, xbee: PtyPair
) -> None:
    prof = profile_with_radio_port(tmp_path, xbee.slave_path)
    result = runner.invoke(app, node("--profile", prof, "--script", script(tmp_path),
                                     "--autopilot", vehicle, "--seconds", "0.5",
                                     "--out", tmp_path / "o"))  # fmt: skip
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["radio_frames_out"] >= 1
    # What reached the "XBee": API mode 2 frames (the profile's), one bundle each.
    frames = FrameReader(2).feed(os.read(xbee.master, 1 << 16))
    assert len(frames) >= 1
    assert f"robot 1: radio: {xbee.slave_path} (solo profile)" in result.stdout


def test_radio_none_runs_without_one(tmp_path: Path, vehicle: str) -> None:
    prof = profile_with_radio_port(tmp_path, str(tmp_path / "ttyUSB-unplugged"))
    result = runner.invoke(app, node("--profile", prof, "--script", script(tmp_path),
                                     "--autopilot", vehicle, "--seconds", "0.3",
                                     "--radio", "none", "--out", tmp_path / "o"))  # fmt: skip
    assert result.exit_code == 0, result.output
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["radio_frames_out"] == 0 and summary["ticks"] >= 1


# ------------------------------------------------------------------ a run


def test_set_and_command_reach_the_script_and_every_line_is_stamped(
    tmp_path: Path, vehicle: str
) -> None:
    result = runner.invoke(app, node("--profile", "solo", "--script", script(tmp_path, HELLO),
                                     "--autopilot", vehicle, "--seconds", "0.3", "--radio",
                                     "none", "--set", "SHAPE=Y", "--set", "N=4",
                                     "--command", "0:1:22"))  # fmt: skip
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    parsed = [LINE.fullmatch(line) for line in lines]
    assert all(parsed), lines
    texts = [m.group(2) for m in parsed if m]
    # The script's lines, as it logged them, among the node's own (in the order written).
    assert texts.index("Y") < texts.index("5") < texts.index("rc 22")
    assert texts[0].startswith("radio: none") and texts[-1].startswith("run over: ")
    assert any(t.startswith("autopilot: waiting") for t in texts)
    stamps = [m.group(1) for m in parsed if m]
    assert stamps == sorted(stamps)  # one writer, in time order


def test_a_script_left_failed_exits_1(tmp_path: Path, vehicle: str) -> None:
    bad = script(tmp_path, "function init() {}\nfunction step() {\n  x = 1 / 0\n}\n")
    result = runner.invoke(app, node("--profile", "solo", "--script", bad,
                                     "--autopilot", vehicle, "--seconds", "0.3",
                                     "--radio", "none", "--out", tmp_path / "o"))  # fmt: skip
    assert result.exit_code == 1, result.output
    (line,) = errors(result.stderr)
    # (Which line and column is the runtime's business, tested with it.)
    assert re.fullmatch(rf"error: {re.escape(str(bad))}:\d+:\d+: division by zero", line), line
    assert "ended the run in its failsafe" in result.stderr
    # The summary is still written, and says the same.
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["failsafe"].startswith("script error") and len(summary["errors"]) == 1
    # The error is in the log too, when it happened, stamped like every line.
    assert re.search(r"robot 1: error: script error, robot to its safe state: ", result.stdout)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_ctrl_c_stops_the_node_cleanly(tmp_path: Path, vehicle: str, sig: int) -> None:
    src = 'function step() { log("tick") }\nfunction destroy() { log("destroyed") }\n'
    argv = [sys.executable, "-m", "fieldkit", *node("--profile", "solo", "--script",
            script(tmp_path, src), "--autopilot", vehicle, "--radio", "none",
            "--out", tmp_path / "o")]  # fmt: skip
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        seen = []
        for line in proc.stdout:  # until the loop is running (no --seconds: it runs on)
            seen.append(line)
            if line.rstrip().endswith("robot 1: tick"):
                break
        else:
            raise AssertionError(f"the node ended first: {seen} {proc.stderr.read()}")  # type: ignore[union-attr]
        proc.send_signal(sig)
        rest, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr and errors(stderr) == []
    assert "robot 1: destroyed" in rest  # destroy() ran
    assert "robot 1: stopped by a signal: " in rest
    assert json.loads((tmp_path / "o" / "summary.json").read_text())["ticks"] >= 1
