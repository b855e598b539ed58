"""`fieldkit node --record`, then `fieldkit replay --verify`: a real flight as a regression test.

The node flies against the simulated ArduPilot in real time (another thread on a pty, as in
the field: the node's ticks and the vehicle's stream are not in lockstep); the bag it writes
is then replayed into a fresh node through a real loopback serial.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from rigs import pty_vehicle
from typer.testing import CliRunner

from fieldkit.cli import app

runner = CliRunner()

FLY = """
function init() { BVMSTATE = "IDLE"  n = 0 }
function step() {
  n = n + 1
  if (flight.rc_cmd == 22) BVMSTATE = "UP"
  if (BVMSTATE == "UP") uav_takeoff(4.0)
  if (n % 5 == 0) log("n ", n, " ", math.rng.uniform(1.0))
}
"""


@pytest.fixture
def vehicle() -> Iterator[str]:
    with pty_vehicle() as path:
        yield path


def test_a_recorded_flight_replays_identically_and_a_changed_script_does_not(
    tmp_path: Path, vehicle: str
) -> None:
    script = tmp_path / "fly.bzz"
    script.write_text(FLY)
    bag = tmp_path / "flight"
    result = runner.invoke(
        app,
        ["node", "--robot-id", "1", "--profile", "solo", "--script", str(script),
         "--autopilot", vehicle, "--radio", "none", "--seconds", "3", "--seed", "5",
         "--command", "1:1:22", "--record", str(bag)],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert f"wrote {bag}" in result.stderr and bag.is_dir()
    result = runner.invoke(app, ["replay", str(bag), "--verify", "--speed", "max"])
    assert result.exit_code == 0, result.output
    line = result.stdout.splitlines()[-1]
    assert line.startswith("replay: identical: ") and str(bag) in line
    ticks = int(line.split("identical: ")[1].split(" ticks")[0])
    assert 20 <= ticks <= 31
    changed = tmp_path / "fly2.bzz"
    changed.write_text(FLY.replace("uav_takeoff(4.0)", "uav_takeoff(5.0)"))
    result = runner.invoke(
        app, ["replay", str(bag), "--verify", "--speed", "max", "--script", str(changed)]
    )
    assert result.exit_code == 1, result.output
    assert "error: first divergence: tick " in result.stderr
    assert "order to the vehicle: expected ('takeoff', (4.0,))" in result.stderr


def test_replay_refuses_what_it_cannot_read(tmp_path: Path) -> None:
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag at all" * 10)
    for path in (tmp_path / "missing", junk):
        result = runner.invoke(app, ["replay", str(path), "--verify"])
        assert result.exit_code == 2, result.output
        assert result.stderr.startswith("error: ") and "Traceback" not in result.output
    result = runner.invoke(app, ["replay", str(junk), "--verify", "--speed", "fast"])
    assert result.exit_code == 2 and "--speed" in result.stderr


def test_a_node_killed_mid_flight_leaves_a_bag_that_replays_up_to_the_cut(
    tmp_path: Path, vehicle: str
) -> None:
    import subprocess
    import sys

    from rigs import kill_and_drain

    script = tmp_path / "fly.bzz"
    script.write_text(FLY)
    bag = tmp_path / "flight"
    proc = subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "node", "--robot-id", "1", "--profile", "solo",
         "--script", str(script), "--autopilot", vehicle, "--radio", "none", "--seconds", "60",
         "--command", "1:1:22", "--record", str(bag)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # the script's lines: ticks have run and been written
            if ": n 40 " in line:
                break
    finally:
        kill_and_drain(proc, 60)
    result = runner.invoke(app, ["replay", str(bag), "--verify", "--speed", "max"])
    assert result.exit_code == 0, result.output
    line = result.stdout.splitlines()[-1]
    ticks = int(line.split("identical: ")[1].split(" ticks")[0])
    assert ticks >= 40 - 10  # at most a second (10 ticks) lost to the kill


COMMITTED = Path(__file__).parent / "data" / "bags" / "sitl-climb"


@pytest.mark.parametrize("robot", [1, 2])
def test_the_committed_sitl_bags_replay_identically(robot: int, tmp_path: Path) -> None:
    bag = COMMITTED / f"robot{robot}"
    result = runner.invoke(app, ["replay", str(bag), "--verify", "--speed", "max"])
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines()[-1].startswith("replay: identical: 40 ticks")
    # And with the script edited, the divergence is found where the climb starts.
    edited = Path(__file__).parent / "data" / "bags" / "climb.bzz"
    text = edited.read_text().replace("uav_takeoff(3.0)", "uav_takeoff(3.5)")
    changed = tmp_path / "climb.bzz"
    changed.write_text(text)
    result = runner.invoke(
        app, ["replay", str(bag), "--verify", "--speed", "max", "--script", str(changed)]
    )
    assert result.exit_code == 1 and "('takeoff', (3.5,))" in result.stderr, result.output


WATCH = """
function init() { fixes = 0 }
function step() {
  if (pose.position.latitude != 0.0) fixes = fixes + 1
  BVMSTATE = "WATCHING"
  if (fixes == 1) log("first fix at ", pose.position.latitude)
}
"""


def test_a_real_tlog_converted_to_a_bag_drives_a_node(tmp_path: Path) -> None:
    tlog = Path(__file__).parent / "data" / "tlogs" / "quad-flight-arducopter.tlog"
    data, i, t0 = tlog.read_bytes(), 0, None
    while i + 10 < len(data):  # the first 100 s of the log, whole records
        stamp = int.from_bytes(data[i : i + 8], "big")
        t0 = stamp if t0 is None else t0
        if stamp - t0 > 100_000_000:
            break
        j = i + 8
        i = j + data[j + 1] + (8 if data[j] == 0xFE else 12 + (13 if data[j + 2] & 1 else 0))
    short = tmp_path / "short.tlog"
    short.write_bytes(data[:i])
    bag = tmp_path / "flight"
    assert runner.invoke(app, ["bag", "from-tlog", str(short), "-o", str(bag)]).exit_code == 0
    script = tmp_path / "watch.bzz"
    script.write_text(WATCH)
    result = runner.invoke(app, ["replay", str(bag), "--verify"])
    assert result.exit_code == 2 and "no node outputs" in result.stderr
    result = runner.invoke(
        app, ["replay", str(bag), "--script", str(script), "--profile", "solo", "--speed", "max"]
    )
    assert result.exit_code == 0, result.output
    assert "first fix at -35.36" in result.stdout  # the real field (CMAC), 66 s into the log
    assert "; final state WATCHING;" in result.stdout.splitlines()[-1]


@pytest.mark.long
def test_a_signed_sitl_flight_with_an_update_replays_with_the_keys(tmp_path: Path) -> None:
    from fieldkit.update.keys import init_keys

    init_keys(tmp_path / "keys")
    climb = Path(__file__).parent / "data" / "bags" / "climb.bzz"
    v2 = tmp_path / "climb2.bzz"
    v2.write_text(climb.read_text().replace("uav_takeoff(3.0)", "uav_takeoff(3.5)"))
    bags = tmp_path / "bags"
    result = runner.invoke(
        app,
        ["sitl", "--robots", "2", "--script", str(climb), "--seconds", "12", "--keys",
         str(tmp_path / "keys"), "--out", str(tmp_path / "out"), "--record", str(bags),
         "--update", f"2:{v2}:1"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "every robot switched" in result.stdout
    for robot in (1, 2):
        bag = bags / f"robot{robot}"
        result = runner.invoke(
            app,
            ["replay", str(bag), "--verify", "--speed", "max", "--keys", str(tmp_path / "keys")],
        )
        assert result.exit_code == 0, result.output  # the patch, the barrier, the switch
        assert result.stdout.splitlines()[-1].startswith("replay: identical: ")
    result = runner.invoke(app, ["replay", str(bags / "robot1"), "--verify"])
    assert result.exit_code == 2 and "--keys" in result.stderr


def test_a_recording_stops_at_its_size_cap_and_what_it_kept_replays(
    tmp_path: Path, vehicle: str
) -> None:
    script = tmp_path / "fly.bzz"
    script.write_text(FLY)
    bag = tmp_path / "flight"
    result = runner.invoke(
        app,
        ["node", "--robot-id", "1", "--profile", "solo", "--script", str(script),
         "--autopilot", vehicle, "--radio", "none", "--seconds", "4", "--record", str(bag),
         "--record-max-mb", "0.03"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "recording stopped:" in result.stdout and "its cap" in result.stdout
    result = runner.invoke(app, ["replay", str(bag), "--verify", "--speed", "max"])
    assert result.exit_code == 0, result.output
    ticks = int(result.stdout.splitlines()[-1].split("identical: ")[1].split(" ticks")[0])
    assert 5 <= ticks < 40  # the beginning, up to the cap
