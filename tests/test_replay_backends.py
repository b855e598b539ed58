"""Record and replay for every vehicle backend (issue 18): a Clearpath Husky (its MCU and its
GPS receiver, two ports) and a DJI M100 (its movement control streamed by a thread, its
frames encrypted with the app key), each recorded by `fieldkit node --record` against its
simulator on real ptys and replayed with `fieldkit replay --verify` through `open_link`.

Nothing waits on time: the processes' output is read until what a test waits for shows,
with a deadline as a hang guard only.
"""

from __future__ import annotations

import copy
import os
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from rigs import pty_husky
from rigs.lines import Lines
from typer.testing import CliRunner

from fieldkit.cli import app
from fieldkit.node.replay import plan_feeds, replay
from fieldkit.record.bag import TOPIC_GPS_RX, TOPIC_STREAM, BagReader
from fieldkit.record.compare import ReplayError
from fieldkit.record.flight_bag import read_flight
from fieldkit.vehicle.sim.dji import TEST_APP_ID, TEST_APP_KEY

ROOT = Path(__file__).resolve().parents[1]
HOME = (45.5049, -73.6133)


def _env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=str(ROOT))


def _verify(bag: Path, *extra: str) -> str:
    """`fieldkit replay BAG --verify` (as fast as it goes): its last line, asserting exit 0."""
    result = CliRunner().invoke(app, ["replay", str(bag), "--verify", "--speed", "max", *extra])
    assert result.exit_code == 0, result.output
    return result.stdout.splitlines()[-1]


# ---------------------------------------------------------------------------- feeding lines


@given(
    st.lists(st.lists(st.binary(max_size=3000), max_size=6), min_size=1, max_size=3),
    st.integers(1, 4096),
)
def test_a_ticks_bytes_over_several_lines_keep_each_lines_order_and_the_lines_order(
    lines: list[list[bytes]], limit: int
) -> None:
    polls = plan_feeds(lines, limit)
    for i, chunks in enumerate(lines):  # every line's bytes, in order, nothing else
        assert b"".join(b"".join(p[i]) for p in polls) == b"".join(chunks)
    for p in polls:
        assert len(p) == len(lines) and all(sum(map(len, part)) <= limit for part in p)
    # A poll reads line 0, then line 1...: a line's bytes never come after a later line's.
    for k, p in enumerate(polls):
        for i, part in enumerate(p):
            if b"".join(part):
                assert not any(b"".join(q[j]) for q in polls[k + 1 :] for j in range(i))


# ---------------------------------------------------------------------------- the Husky

DRIVE = """
function init() { n = 0 }
function step() {
  n = n + 1
  if (n == 2) arm()
  if (n > 5) goto_abs(3.0 - pose.position.x, 0.0 - pose.position.y, 0.0, 0.0)
}
"""


@pytest.fixture(scope="module")
def husky_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`fieldkit node --profile husky --record` driving the simulated Husky for 4 s."""
    d = tmp_path_factory.mktemp("husky")
    script = d / "drive.bzz"
    script.write_text(DRIVE)
    with pty_husky() as (mcu, gps, _sim):
        result = CliRunner().invoke(
            app,
            ["node", "--profile", "husky", "--autopilot", mcu, "--gps", gps, "--script",
             str(script), "--robot-id", "1", "--radio", "none", "--seconds", "4",
             "--record", str(d / "flight")],
        )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "run over: 40 ticks" in result.output
    return d / "flight"


def test_a_husky_flight_records_its_gps_and_replays_identically(husky_bag: Path) -> None:
    reader = BagReader(husky_bag)
    assert reader.count(TOPIC_GPS_RX) > 0 and reader.count(TOPIC_STREAM) == 0
    gps = b"".join(c.data for c in reader.gps_rx())
    assert b"$GPGGA" in gps and b"$GPRMC" in gps
    info = CliRunner().invoke(app, ["bag", "info", str(husky_bag)])
    assert "profile:     husky (flavour clearpath)" in info.output
    last = _verify(husky_bag)
    assert last.startswith("replay: identical: 40 ticks, ")
    assert " MCU frames, 0 radio frames, 40 script states" in last


def test_a_husky_replay_depends_on_the_recorded_gps(husky_bag: Path) -> None:
    flight = read_flight(husky_bag)
    edited = copy.deepcopy(flight)
    for t in edited.ticks[10:]:  # the receiver's fixes gone from tick 10 on
        t.gps_rx = [c.replace(b"$GPGGA", b"$GPXXX").replace(b"$GPRMC", b"$GPXXX")
                    for c in t.gps_rx]  # fmt: skip
    report = replay(edited)
    assert report.divergence is not None and report.divergence.tick >= 10


def test_a_husky_tick_that_read_more_than_a_pty_holds_on_both_lines_replays(
    husky_bag: Path,
) -> None:
    # Noise (zeros: no MCU frame and no NMEA sentence) larger than a pty's 4095 bytes, on
    # the MCU's line and on the GPS's in the same tick: fed in parts, in the link's order.
    edited = copy.deepcopy(read_flight(husky_bag))
    edited.ticks[20].autopilot_rx.insert(0, bytes(5000))
    edited.ticks[20].gps_rx.insert(0, bytes(6000))
    edited.ticks[21].gps_rx[:0] = [bytes(700)] * 8
    report = replay(edited)
    assert report.divergence is None, report.divergence
    assert report.ticks == 40


def test_a_changed_script_diverges_on_a_husky_flight(husky_bag: Path, tmp_path: Path) -> None:
    script = tmp_path / "drive.bzz"
    script.write_text(DRIVE.replace("if (n == 2) arm()", "if (n == 3) arm()"))
    result = CliRunner().invoke(
        app, ["replay", str(husky_bag), "--verify", "--speed", "max", "--script", str(script)]
    )
    assert result.exit_code == 1, result.output
    # Tick 1 armed the base (its speed and acceleration limits to the MCU): not any more.
    assert "error: first divergence: tick 1, autopilot messages: expected " in result.output


# ---------------------------------------------------------------------------- the M100

#: Take off on RC code 22, then north: the movement stream runs through the climb and the
#: goto. Logs how far north it is once it goes.
FLY_NORTH = """
function init() { BVMSTATE = "TURNEDOFF" }
function step() {
  if (flight.rc_cmd == 22 and BVMSTATE == "TURNEDOFF") BVMSTATE = "TAKEOFF"
  if (BVMSTATE == "TAKEOFF") {
    uav_takeoff(TARGET_ALTITUDE)
    if (pose.position.altitude > TARGET_ALTITUDE * 0.9) {
      BVMSTATE = "GO"
      LAT0 = pose.position.latitude
      goto_abs(10.0, 0.0, 0.0, 0.0)
    }
  }
  if (BVMSTATE == "GO") {
    log("north ", (pose.position.latitude - LAT0) * 111140.0)
  }
}
"""


@pytest.fixture(scope="module")
def m100(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, Path, Path]]:
    """A flight of `fieldkit node --config FILE --record` on `fieldkit vehicle-sim --profile
    m100`, stopped once it goes north: (the bag, the node config, the app key file)."""
    d = tmp_path_factory.mktemp("m100")
    sim = subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "vehicle-sim", "--profile", "m100",
         "--gps-delay", "0", "--home", f"{HOME[0]},{HOME[1]}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=d, env=_env(),
    )  # fmt: skip
    node: subprocess.Popen[str] | None = None
    try:
        assert sim.stdout is not None
        ready, _, _ = select.select([sim.stdout], [], [], 30.0)
        assert ready, "no pty path printed"
        port = sim.stdout.readline().strip()
        script = d / "fly.bzz"
        script.write_text(FLY_NORTH)
        key_file = d / "dji-app-key"
        key_file.write_text(TEST_APP_KEY + "\n")
        key_file.chmod(0o600)
        config = d / "fieldkit.toml"
        config.write_text(
            f'[node]\nprofile = "m100"\nrobot_id = 1\nscript = "{script}"\n'
            f'autopilot = "{port}"\nradio = "none"\ncommand = ["0:1:22"]\n'
            f'record = "{d / "flight"}"\n\n[dji]\napp_id = {TEST_APP_ID}\n'
            f'app_key_file = "{key_file}"\n'
        )
        node = subprocess.Popen(
            [sys.executable, "-m", "fieldkit", "node", "--config", str(config)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=d, env=_env(),
        )  # fmt: skip
        import re

        m = Lines(node).until(re.compile(r"robot 1: north "), time.monotonic() + 120.0)
        assert m is not None, node.stderr.read()  # type: ignore[union-attr]
        node.send_signal(signal.SIGTERM)
        _, err = node.communicate(timeout=60)  # a hang guard
        assert node.returncode == 0, err
        yield d / "flight", config, key_file
    finally:
        for proc in (node, sim):
            if proc is not None and proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(60)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait()


def test_an_m100_flight_replays_identically_with_the_app_key_from_its_config(
    m100: tuple[Path, Path, Path],
) -> None:
    bag, config, key_file = m100
    reader = BagReader(bag)
    sends = list(reader.stream_sends())
    assert len(sends) > 10  # the thread streamed movement control between the ticks
    # The key is a secret: not in the bag in any form; its fingerprint and the app id are.
    blob = b"".join(p.read_bytes() for p in bag.iterdir())
    for form in (TEST_APP_KEY.encode(), TEST_APP_KEY.upper().encode(), bytes.fromhex(TEST_APP_KEY)):
        assert form not in blob
    info = CliRunner().invoke(app, ["bag", "info", str(bag)])
    assert f"profile:     m100 (flavour dji), DJI app {TEST_APP_ID} key " in info.output
    last = _verify(bag, "--config", str(config))
    assert last.startswith("replay: identical: ") and " DJI frames, 0 radio frames, " in last
    frames = int(last.split(" DJI frames")[0].rsplit(" ", 1)[1])
    assert frames > len(sends)  # the stream's frames and the commands', all compared
    assert _verify(bag, "--dji-app-key-file", str(key_file)) == last


def test_an_m100_replay_needs_the_right_app_key(
    m100: tuple[Path, Path, Path], tmp_path: Path
) -> None:
    bag = m100[0]
    runner = CliRunner()
    result = runner.invoke(app, ["replay", str(bag), "--verify", "--speed", "max"])
    assert result.exit_code == 2 and "Traceback" not in result.output
    assert "which the recording never holds" in result.output
    assert "--dji-app-key-file FILE" in result.output
    other = tmp_path / "other-key"
    other.write_text("00" * 32 + "\n")
    other.chmod(0o600)
    result = runner.invoke(
        app, ["replay", str(bag), "--verify", "--speed", "max", "--dji-app-key-file", str(other)]
    )
    assert result.exit_code == 2, result.output
    assert "the flight's M100 was activated with app key " in result.output
    assert "00" * 32 not in result.output
    other.chmod(0o644)
    result = runner.invoke(
        app, ["replay", str(bag), "--verify", "--speed", "max", "--dji-app-key-file", str(other)]
    )
    assert result.exit_code == 1 and "readable by others" in result.output


def test_an_m100_replay_sends_the_streams_frames_at_their_recorded_times(
    m100: tuple[Path, Path, Path],
) -> None:
    flight = read_flight(m100[0])
    k = next(i for i, t in enumerate(flight.ticks) if len(t.stream_s) > 1)
    edited = copy.deepcopy(flight)
    edited.ticks[k].stream_s.pop(0)  # one frame the thread sent, left out
    report = replay(edited, dji_app_key=TEST_APP_KEY)
    assert report.divergence is not None and report.divergence.tick == k
    assert report.divergence.channel == "autopilot messages"
    with pytest.raises(ReplayError, match="app key"):
        replay(flight)
