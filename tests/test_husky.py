"""The Husky backend with real parts: its core against the simulated MCU and GPS, in memory
(`HuskyMemoryRig`, simulated time) and on real ptys (`Husky`, `fieldkit vehicle-sim`,
`fieldkit node`). Waits on ptys are on conditions with wall-clock hang guards, never on time.
"""

from __future__ import annotations

import math
import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rigs import RIG_HOME, HuskyMemoryRig, pty_husky
from rigs.flights import field_env
from typer.testing import CliRunner

from fieldkit.cli import app
from fieldkit.robot import geo
from fieldkit.robot.profiles import ProfileError, load_profile, parse_profile
from fieldkit.vehicle.autopilot import AutopilotError, CommandStatus
from fieldkit.vehicle.clearpath import messages as M
from fieldkit.vehicle.clearpath.frame import FrameReader
from fieldkit.vehicle.clearpath.link import Husky, HuskyError
from fieldkit.vehicle.core import VehicleCore
from fieldkit.vehicle.links import open_link

ROOT = Path(__file__).resolve().parents[1]
HUSKY = load_profile("husky")
SPEED = HUSKY.kinematics.max_speed_mps
ACCEL = HUSKY.kinematics.max_accel_mps2
ACCURACY = HUSKY.kinematics.hover_accuracy_m


def rig(**options: object) -> HuskyMemoryRig:
    r = HuskyMemoryRig(home=RIG_HOME, **options)  # type: ignore[arg-type]
    r.connect()
    return r


def target(north: float, east: float) -> tuple[float, float]:
    return geo.offset_gps(RIG_HOME[0], RIG_HOME[1], north, east)


def distance(r: HuskyMemoryRig, to: tuple[float, float]) -> float:
    return geo.range_bearing(*r.sim.position, *to)[0]


def drive(
    r: HuskyMemoryRig, to: tuple[float, float], seconds: float, every_tick: bool = True
) -> dict[str, float]:
    """Order a goto (each tick, as the supervisor does) until the base has stopped at it;
    the largest wheel speed and wheel acceleration seen on the way."""
    seen = {"speed": 0.0, "accel": 0.0}
    d = r.sim.drive
    r.core.goto(*to)
    for _ in range(round(seconds / r.dt)):
        if every_tick:
            r.core.goto(*to)
        r.tick()
        seen["speed"] = max(seen["speed"], abs(d.left), abs(d.right))
        seen["accel"] = max(seen["accel"], abs(d.left_accel), abs(d.right_accel))
        if r.core.controller.arrived and not d.moving:
            break
    return seen


def test_the_core_is_a_vehicle_core() -> None:
    core: VehicleCore = HuskyMemoryRig().core  # mypy checks the protocol; this, the names
    for name in ("receive_data", "data_to_send", "tick", "drain_events", "heartbeat_age"):
        assert callable(getattr(core, name))


def test_start_up_telemetry() -> None:
    r = rig()
    t = r.core.telemetry
    assert t.armed and t.mode == "HOLD" and t.landed_state == 1 and t.gps_fix_type == 3
    assert t.lat == pytest.approx(RIG_HOME[0], abs=1e-7)
    assert t.lon == pytest.approx(RIG_HOME[1], abs=1e-7)
    assert t.battery_percent == pytest.approx(100.0, abs=1.0)  # the MCU's 1 % steps
    assert t.battery_voltage_v == pytest.approx(HUSKY.battery.full_voltage, abs=0.05)
    assert t.home is not None and r.core.heartbeat_age() < 0.1 and not r.core.heartbeat_lost
    assert t.heading_deg is None and r.core.heading_source == "none"  # never moved, no IMU
    assert r.core.platform == M.PlatformInfo("A200", 1, 1234)
    assert r.sim.max_speed == (SPEED, SPEED) and r.sim.max_accel == (ACCEL, ACCEL)
    texts = [e.text for e in r.core.drain_events()]
    assert "MCU found: Husky A200-1234" in texts and "arm: done" in texts
    assert r.core.bad_frames == 0 and r.core.missed_acks == 0


def test_the_command_stream_never_stops() -> None:
    """A speed frame every control cycle, zeros when idle: the MCU's watchdog never trips."""
    r = rig()
    before = r.core.speed_frames
    r.run_for(3.0)
    assert r.core.speed_frames - before == 30
    assert r.sim.watchdog_trips == 0 and not r.sim.timed_out


@pytest.mark.parametrize(("north", "east", "yaw_deg"), [(12.0, -5.0, 0.0), (-8.0, 3.0, 90.0)])
def test_goto_arrives_within_accuracy_and_limits(north: float, east: float, yaw_deg: float) -> None:
    r = rig(yaw_deg=yaw_deg)
    to = target(north, east)
    seen = drive(r, to, 40.0)
    assert r.core.controller.arrived and not r.sim.drive.moving
    assert distance(r, to) <= ACCURACY
    assert seen["speed"] <= SPEED + 1e-9
    assert seen["accel"] <= ACCEL + 1e-6  # the MCU ramps at what the core asked: the profile's
    assert r.core.heading_source == "gps"
    err = math.remainder(r.core.telemetry.heading_deg - r.sim.heading_deg, 360.0)  # type: ignore[operator]
    assert abs(err) < 5.0
    # The reported position follows the real one between fixes (odometry).
    t = r.core.telemetry
    assert geo.range_bearing(t.lat, t.lon, *r.sim.position)[0] < 0.1  # type: ignore[arg-type]


def test_a_ubx_receiver_drives_as_well() -> None:
    r = rig(gps_protocol="ubx")
    assert r.core.gps.ubx_messages > 0 and r.core.gps.sentences == 0
    to = target(-6.0, 6.0)
    drive(r, to, 30.0)
    assert distance(r, to) <= ACCURACY and r.core.heading_source == "gps"


def test_stop_is_on_the_wire_at_once() -> None:
    r = rig()
    to = target(30.0, 0.0)
    for _ in range(40):
        r.core.goto(*to)
        r.tick()
    assert r.sim.drive.speed > 0.9
    r.core.data_to_send()  # nothing pending, and no tick between the order and the check
    stop = r.core.hold()
    wire = r.core.data_to_send()
    frames = FrameReader().feed(wire)
    assert [f.type for f in frames] == [M.MsgType.SET_DIFF_SPEED]
    assert M.decode_command(frames[0]) == M.DiffSpeeds(0.0, 0.0, ACCEL, ACCEL)
    assert not stop.done  # done when the MCU acknowledges it
    r.sim.mcu.receive_data(wire)
    r.core.receive_data(r.sim.mcu.data_to_send())
    assert stop.ok and r.core.telemetry.mode == "HOLD" and r.core.target is None
    # Braking at the profile's acceleration: stopped within v / a (and a cycle).
    assert r.run_until(lambda: not r.sim.drive.moving, SPEED / ACCEL + 0.15)
    r.run_for(1.0)
    assert not r.sim.drive.moving and r.core.wheel_command == (0.0, 0.0)


def test_a_lost_acknowledgement_is_sent_again() -> None:
    r = rig()
    r.sim.faults.drop_acks = 1
    sent = r.sim.mcu.received["SET_MAX_ACCEL"]
    arm = r.core.arm()
    assert r.run_until(lambda: arm.done, 2.0) and arm.ok
    assert r.sim.mcu.received["SET_MAX_ACCEL"] - sent == 2  # sent again after its ack was lost


def test_a_stop_never_acknowledged_fails_after_every_try() -> None:
    r = rig()
    r.sim.faults.drop_acks = 10_000
    stop = r.core.land()
    assert r.run_until(lambda: stop.done, 2.0) and not stop.ok
    assert stop.attempts == 4 and stop.name == "land (stop)"
    assert stop.error == "land (stop) failed: SET_DIFF_SPEED not acknowledged after 4 tries"
    assert r.core.wheel_command == (0.0, 0.0)  # the zeros go on all the same


def test_mcu_silent_is_a_lost_heartbeat_and_back() -> None:
    r = rig()
    r.sim.faults.mcu_silent = True
    frames = r.core.speed_frames
    assert r.run_until(lambda: r.core.heartbeat_lost, HUSKY.autopilot.heartbeat_timeout_s + 0.5)
    assert r.core.speed_frames - frames >= 30  # zeros keep going to a silent MCU
    r.sim.faults.mcu_silent = False
    assert r.run_until(lambda: not r.core.heartbeat_lost, 1.0)
    texts = [e.text for e in r.core.drain_events() if e.kind == "heartbeat"][1:]  # not "found"
    assert texts[0].startswith("MCU silent: no answer for 3.") and texts[1] == "MCU answering again"


def test_a_host_held_up_is_not_a_silent_mcu() -> None:
    # The node's loop held up for 5 s (a slow start-up on a loaded computer): the MCU, which
    # answers only when asked, was asked nothing; its silence is not a lost heartbeat.
    r = rig()
    r.core.drain_events()
    for _ in range(50):  # 5 s of the machine while the host neither reads nor asks
        r.sim.step(0.1)
        r.now += 0.1
    r.core.receive_gps(r.sim.gps.data_to_send())  # what the GPS port queued meanwhile
    r.core.tick()
    assert not r.core.heartbeat_lost and r.core.heartbeat_age() == 0.0
    r.deliver()
    r.run_for(2.0)
    assert not r.core.heartbeat_lost
    assert not [e for e in r.core.drain_events() if e.kind == "heartbeat"]
    r.sim.faults.mcu_silent = True  # a silent MCU is still found, from the host's asking on
    assert r.run_until(lambda: r.core.heartbeat_lost, HUSKY.autopilot.heartbeat_timeout_s + 0.5)


def test_the_mcu_watchdog_stops_the_base_when_commands_stop() -> None:
    r = rig()
    to = target(30.0, 0.0)
    for _ in range(30):
        r.core.goto(*to)
        r.tick()
    assert r.sim.drive.moving
    cut = r.core.data_to_send  # the line from the node breaks: nothing reaches the MCU
    r.core.data_to_send = lambda: (cut(), b"")[1]  # type: ignore[method-assign]
    assert r.run_until(lambda: not r.sim.drive.moving, r.sim.watchdog_s + SPEED / ACCEL + 0.3)
    assert r.sim.timed_out and r.sim.watchdog_trips == 1
    r.core.data_to_send = cut  # type: ignore[method-assign]
    r.run_for(0.3)
    assert not r.sim.timed_out  # the next speed command clears it


def test_gps_garbage_only_costs_counters() -> None:
    r = rig()
    to = target(6.0, 4.0)
    r.core.goto(*to)
    for _ in range(150):
        r.sim.gps_garbage(40)
        r.core.goto(*to)
        r.tick()
        if r.core.controller.arrived and not r.sim.drive.moving:
            break
    assert distance(r, to) <= ACCURACY
    g = r.core.gps
    assert g.garbage_bytes + g.bad_sentences > 0 and r.core.bad_frames >= g.bad_sentences


def test_gps_fix_loss_stops_the_base_and_it_goes_on_after() -> None:
    r = rig()
    to = target(15.0, 0.0)
    for _ in range(30):
        r.core.goto(*to)
        r.tick()
    r.sim.faults.gps_fix = False
    r.run_for(0.3)
    assert not r.core.gps.has_fix and r.core.telemetry.gps_fix_type == 1
    assert r.core.wheel_command == (0.0, 0.0)
    assert r.run_until(lambda: not r.sim.drive.moving, 1.0)
    texts = [e.text for e in r.core.drain_events()]
    assert any(t.endswith("fix lost (GGA fix quality 0)") for t in texts)
    r.sim.faults.gps_fix = True
    seen = drive(r, to, 30.0)
    assert distance(r, to) <= ACCURACY and seen["speed"] <= SPEED + 1e-9


def test_gps_silent_is_a_lost_fix() -> None:
    r = rig()
    r.sim.faults.gps_silent = True
    assert r.run_until(lambda: not r.core.gps.has_fix, 2.5)
    assert "nothing heard for" in [e.text for e in r.core.drain_events() if e.kind == "gps"][-1]


def test_estop_disarms_forgets_the_target_and_refuses_arming() -> None:
    r = rig()
    to = target(20.0, 0.0)
    for _ in range(20):
        r.core.goto(*to)
        r.tick()
    r.sim.faults.estop = True
    r.run_for(0.3)
    core = r.core
    assert not core.telemetry.armed and core.pilot_override and core.target is None
    assert r.run_until(lambda: not r.sim.drive.moving, 1.0)
    refused = core.goto(*to)
    assert refused.status is CommandStatus.FAILED and "arm first" in (refused.error or "")
    arm = core.arm()
    assert r.run_until(lambda: arm.done, 1.0) and not arm.ok
    assert arm.error == "arm refused: the base will not move: e_stop"
    r.sim.faults.estop = False
    r.run_for(0.3)
    assert core.telemetry.armed and not core.pilot_override and not r.sim.drive.moving


def test_rtl_drives_home_and_holds() -> None:
    r = rig()
    drive(r, target(5.0, 5.0), 30.0)
    cmd = r.core.rtl()
    assert cmd.ok and r.core.telemetry.mode == "RTL"
    assert r.run_until(lambda: r.core.telemetry.mode == "HOLD" and not r.sim.drive.moving, 30.0)
    assert distance(r, RIG_HOME) <= ACCURACY


def test_ground_orders() -> None:
    r = HuskyMemoryRig(home=RIG_HOME)
    assert "no answer from the MCU" in (r.core.arm().error or "")
    r.connect()
    assert r.core.takeoff(5.0).ok and not r.sim.drive.moving
    assert not r.core.goto(math.nan, 0.0).ok and not r.core.goto(95.0, 0.0).ok
    disarm = r.core.disarm()
    assert r.run_until(lambda: disarm.done, 1.0) and disarm.ok and not r.core.telemetry.armed
    assert "arm first" in (r.core.goto(*target(1.0, 1.0)).error or "")


def test_profile_checks() -> None:
    text = HUSKY.path.read_text()  # type: ignore[union-attr]
    import tomllib

    data = tomllib.loads(text)
    del data["gps"]
    with pytest.raises(ProfileError, match=r"gps: missing required table with autopilot\.flav"):
        parse_profile(data, "x.toml")
    data = tomllib.loads(text)
    data["gps"]["protocol"] = "sirf"
    with pytest.raises(ProfileError, match='gps.protocol: must be one of "nmea", "ubx"'):
        parse_profile(data, "x.toml")
    assert HUSKY.gps is not None and HUSKY.gps.protocol == "nmea"
    assert HUSKY.drive is not None and HUSKY.drive.wheel_separation_m == pytest.approx(1.0703)
    with pytest.raises(AutopilotError, match="--gps is for a base with a GPS of its own"):
        open_link(load_profile("solo"), "/dev/null", gps="/dev/null")


# ---------------------------------------------------------------------------- real ptys


def test_the_link_drives_the_simulated_husky_over_ptys() -> None:
    to = geo.offset_gps(RIG_HOME[0], RIG_HOME[1], 3.0, 0.0)
    with pty_husky() as (mcu, gps, sim):
        with Husky(mcu, gps, profile=HUSKY) as husky:
            rx: list[bytes] = []
            gps_rx: list[bytes] = []
            husky.on_rx, husky.on_gps_rx = rx.append, gps_rx.append
            husky.wait_heartbeat(10.0)
            husky.wait_command(husky.request_streams(10.0), 10.0)
            husky.wait_gps_fix(10.0)
            husky.wait_command(husky.arm(), 10.0)
            deadline = time.monotonic() + 30.0  # a hang guard, not a speed test
            while not (husky.controller.arrived and not sim.drive.moving):
                assert time.monotonic() < deadline, husky.telemetry
                husky.goto(*to)
                husky.poll(0.05)
            assert geo.range_bearing(*sim.position, *to)[0] <= ACCURACY
            husky.wait_command(husky.hold(), 10.0)
            assert rx and gps_rx and husky.bad_frames == 0
            assert b"$GPGGA" in b"".join(gps_rx)


def test_open_failures_are_one_clear_line() -> None:
    with pytest.raises(HuskyError, match="^cannot open the Husky MCU port /dev/nonexistent-tty"):
        Husky("/dev/nonexistent-tty", "/dev/null", profile=HUSKY)
    with pty_husky() as (mcu, _, _):
        with pytest.raises(HuskyError, match="^cannot open the GPS port /dev/nonexistent-gps"):
            Husky(mcu, "/dev/nonexistent-gps", profile=HUSKY)


def test_vehicle_sim_prints_the_mcu_then_the_gps(tmp_path: Path) -> None:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "vehicle-sim", "--profile", "husky", "--port",
         "ttyMCU", "--gps-port", "ttyGPS", "--home", "45.5,-73.6"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=env,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], 30.0)
        assert ready, "no pty path printed"
        # Both lines at once: after the first readline the second is in the stream's buffer.
        lines = [proc.stdout.readline().strip(), proc.stdout.readline().strip()]
        assert lines == [str(tmp_path / "ttyMCU"), str(tmp_path / "ttyGPS")]
        with Husky(lines[0], lines[1], profile=HUSKY) as husky:
            husky.wait_heartbeat(10.0)
            t = husky.wait_gps_fix(10.0)
            assert t.lat == pytest.approx(45.5, abs=1e-6)
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)  # a hang guard
    assert proc.returncode == 0, err
    assert "husky (Clearpath Husky: MCU on" in err and "Traceback" not in err
    assert not (tmp_path / "ttyMCU").exists() and not (tmp_path / "ttyGPS").is_symlink()


DRIVE = """
function init() { n = 0 }
function step() {
  n = n + 1
  if (n == 2) arm()
  if (n > 5) goto_abs(3.0 - pose.position.x, 0.0 - pose.position.y, 0.0, 0.0)
}
"""


def test_fieldkit_node_drives_the_husky(tmp_path: Path) -> None:
    script = tmp_path / "drive.bzz"
    script.write_text(DRIVE)
    to = geo.offset_gps(RIG_HOME[0], RIG_HOME[1], 3.0, 0.0)
    # As the field runs it: its own process (an in-process run inherits whatever earlier
    # tests left in the logging module).
    with pty_husky() as (mcu, gps, sim):
        proc = subprocess.run(
            [sys.executable, "-m", "fieldkit", "node", "--profile", "husky", "--autopilot", mcu,
             "--gps", gps, "--script", str(script), "--robot-id", "1", "--radio", "none",
             "--seconds", "8"],
            capture_output=True, text=True, cwd=tmp_path, env=field_env(), timeout=180,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert geo.range_bearing(*sim.position, *to)[0] <= ACCURACY
    output = proc.stdout + proc.stderr
    assert "husky: arm: done" in output
    assert "run over: 80 ticks" in output


def test_an_mcu_port_that_vanishes_is_reopened_by_path(tmp_path: Path) -> None:
    """The USB adapter unplugged and back: the link says so once, keeps the loop going, and
    opens the same path again (a udev name now pointing at the new device)."""
    from fieldkit.vehicle.pty import open_pty
    from fieldkit.vehicle.sim.husky_pty import SimHuskyPorts, _Port

    first, gps, second = open_pty(), open_pty(), open_pty()
    path = tmp_path / "prolific"
    path.symlink_to(first.slave_path)
    sim = SimHuskyPorts(HUSKY, first.master, gps.master, home=RIG_HOME)
    now = [0.0]
    husky = Husky(str(path), gps.slave_path, profile=HUSKY, clock=lambda: now[0])

    def step(cond: object, limit_s: float) -> bool:
        deadline = time.monotonic() + 30.0  # a hang guard
        for _ in range(round(limit_s / 0.02)):
            if cond():  # type: ignore[operator]
                return True
            assert time.monotonic() < deadline
            sim.step(0.02)
            now[0] += 0.02
            husky.poll(0.005)
        return bool(cond())  # type: ignore[operator]

    try:
        assert step(lambda: husky.telemetry.last_heartbeat is not None, 5.0)
        first.close()  # unplugged
        assert step(lambda: husky.link_down, 2.0)
        path.unlink()
        path.symlink_to(second.slave_path)  # plugged in again: a new device behind the name
        sim.mcu_port = _Port(second.master, 115200)
        sim.mcu.sink = sim.mcu_port.write
        assert step(lambda: not husky.link_down, 2.0)
        heard = husky.telemetry.last_heartbeat
        assert step(lambda: husky.telemetry.last_heartbeat != heard, 2.0)
        texts = [e.text for e in husky.drain_events() if e.kind in ("link", "reopened")]
        assert len(texts) == 2
        assert texts[0].startswith(f"MCU port {path} lost (read failed: ")
        assert texts[1].startswith(f"MCU port {path} back after ")
    finally:
        husky.close()
        sim.close()
        for pty in (first, gps, second):
            pty.close()


def test_gps_options_belong_to_a_clearpath_base(tmp_path: Path) -> None:
    runner = CliRunner()
    result = runner.invoke(app, ["vehicle-sim", "--profile", "solo", "--gps-port", "ttyGPS"])
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert "error: --gps-port is for a Clearpath base; solo's GPS is its autopilot's" in (
        result.output
    )
    script = tmp_path / "s.bzz"
    script.write_text("function init() {}\nfunction step() {}\n")
    result = runner.invoke(
        app,
        ["node", "--profile", "solo", "--script", str(script), "--robot-id", "1", "--radio",
         "none", "--gps", "/dev/null"],
    )  # fmt: skip
    assert result.exit_code == 1
    assert "error: solo: --gps is for a base with a GPS of its own (flavour clearpath)" in (
        result.output
    )
    result = runner.invoke(
        app,
        ["node", "--profile", "husky", "--script", str(script), "--robot-id", "1", "--radio",
         "none", "--autopilot", "/dev/nonexistent-mcu", "--gps", "/dev/null"],
    )  # fmt: skip
    assert result.exit_code == 1 and "Traceback" not in result.output
    assert "error: cannot open the Husky MCU port /dev/nonexistent-mcu: No such file" in (
        result.output
    )
