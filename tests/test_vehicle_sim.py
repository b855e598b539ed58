"""The simulated ArduPilot vehicle (fieldkit.vehicle.sim) and `fieldkit vehicle-sim`.

The ground station here is pymavlink's codec alone on the slave end of a real pty, so these
tests check the vehicle's MAVLink behaviour independently of fieldkit's own link. Waits are on
bytes or conditions, with wall-clock deadlines, never on time.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import threading
import time
import tty
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import typer
from pymavlink import mavutil
from pymavlink.dialects.v20 import all as mavlink2
from typer.testing import CliRunner

from fieldkit.cli import app
from fieldkit.cli.options import parse_home
from fieldkit.robot import geo
from fieldkit.robot.profiles import load_profile
from fieldkit.vehicle import Autopilot, PtyPair, SimVehicle, VehicleSimError, open_pty

HOME = (45.5049, -73.6133)
ROOT = Path(__file__).resolve().parents[1]
ACCEPTED = mavlink2.MAV_RESULT_ACCEPTED
FAILED = mavlink2.MAV_RESULT_FAILED
DENIED = mavlink2.MAV_RESULT_DENIED
UNSUPPORTED = mavlink2.MAV_RESULT_UNSUPPORTED
ARM = mavlink2.MAV_CMD_COMPONENT_ARM_DISARM
SET_MODE = mavlink2.MAV_CMD_DO_SET_MODE
TAKEOFF = mavlink2.MAV_CMD_NAV_TAKEOFF
CUSTOM = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


class Gcs:
    """A ground station made of pymavlink's codec on the slave end of the pty."""

    def __init__(self, pty: PtyPair, sim: SimVehicle) -> None:
        self.fd = os.open(pty.slave_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.fd)
        self.sim = sim
        self.mav = mavlink2.MAVLink(self, srcSystem=255, srcComponent=190)
        self.mav.robust_parsing = True
        self.raw = bytearray()  # everything the vehicle sent
        self.sent = 0
        self.answer: list[Any] = []  # what came with the last `ask`

    def write(self, buf: bytes) -> None:
        """The codec's output: straight onto the line."""
        self.sent += os.write(self.fd, buf)

    def drain(self) -> list[Any]:
        """Every message the vehicle has sent since the last call (BAD_DATA included)."""
        deadline = time.monotonic() + 5.0
        start = len(self.raw)
        while len(self.raw) < self.sim.bytes_sent:
            assert time.monotonic() < deadline, "vehicle bytes not delivered"
            select.select([self.fd], [], [], 0.1)
            try:
                self.raw += os.read(self.fd, 65536)
            except BlockingIOError:
                pass
        return self.mav.parse_buffer(bytes(self.raw[start:])) or []

    def deliver(self) -> None:
        """Wait until the vehicle has read (and handled) everything we sent."""
        deadline = time.monotonic() + 5.0
        while self.sim.bytes_received < self.sent:
            assert time.monotonic() < deadline, "station bytes not delivered"
            self.sim.service(0.1)

    def step(self, seconds: float = 0.1, dt: float = 0.1) -> list[Any]:
        """Step the vehicle for `seconds`; the messages it sent meanwhile."""
        out: list[Any] = []
        for _ in range(round(seconds / dt)):
            self.sim.step(dt)
            out += self.drain()
        return out

    def ask(self, command: int, *params: float) -> tuple[int, list[str]]:
        """COMMAND_LONG -> (the ACK's result, STATUSTEXTs sent with it)."""
        p = [*params] + [0.0] * (7 - len(params))
        self.mav.command_long_send(1, 1, command, 0, *p)
        self.deliver()
        self.answer = msgs = self.drain()
        acks = [m for m in msgs if m.get_type() == "COMMAND_ACK"]
        assert len(acks) == 1 and acks[0].command == command, msgs
        assert (acks[0].target_system, acks[0].target_component) == (255, 190)
        return acks[0].result, [m.text for m in msgs if m.get_type() == "STATUSTEXT"]

    def mode(self, number: int) -> int:
        """DO_SET_MODE with an ArduPilot custom mode number -> the result."""
        return self.ask(SET_MODE, CUSTOM, number)[0]

    def close(self) -> None:
        """Close our end."""
        os.close(self.fd)


@pytest.fixture
def bench() -> Iterator[Any]:
    """make(profile, **options) -> (SimVehicle, Gcs) on a fresh pty, all closed afterwards."""
    opened: list[tuple[PtyPair, SimVehicle, Gcs]] = []

    def make(profile: str = "solo", **options: Any) -> tuple[SimVehicle, Gcs]:
        pty = open_pty()
        sim = SimVehicle(load_profile(profile), pty.master, home=HOME, **options)
        gcs = Gcs(pty, sim)
        opened.append((pty, sim, gcs))
        return sim, gcs

    yield make
    for pty, sim, gcs in opened:
        gcs.close()
        sim.close()
        pty.close()


def types(msgs: list[Any]) -> Counter[str]:
    """Message counts by type."""
    return Counter(m.get_type() for m in msgs)


def last(msgs: list[Any], name: str) -> Any:
    """The last message of a type."""
    found = [m for m in msgs if m.get_type() == name]
    assert found, f"no {name} in {types(msgs)}"
    return found[-1]


# ---------------------------------------------------------------------------- identity


@pytest.mark.parametrize(
    ("profile", "mav_type", "mode"),
    [("solo", mavlink2.MAV_TYPE_QUADROTOR, "STABILIZE"), ("husky", 10, "MANUAL")],
)
def test_heartbeat_says_ardupilot(bench: Any, profile: str, mav_type: int, mode: str) -> None:
    sim, gcs = bench(profile)
    msgs = gcs.step(1.0)
    assert gcs.raw[0] == 0xFD  # MAVLink 2 frames, as current ArduPilot sends
    # Nothing but heartbeats (at 0.1 and 1.0 s) until asked, and home, once, at the fix.
    assert types(msgs) == Counter({"HEARTBEAT": 2, "HOME_POSITION": 1})
    hb = last(msgs, "HEARTBEAT")
    assert (hb.type, hb.autopilot) == (mav_type, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA)
    assert hb.base_mode & CUSTOM and not hb.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.custom_mode == 0 and mavutil.mode_string_v10(hb) == mode
    assert hb.system_status == mavlink2.MAV_STATE_STANDBY
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, 1)
    assert gcs.ask(ARM, 1)[0] == ACCEPTED
    hb = last(gcs.step(1.0), "HEARTBEAT")
    assert hb.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
    assert hb.system_status == mavlink2.MAV_STATE_ACTIVE


@pytest.mark.parametrize(
    ("profile", "table", "modes"),
    [
        ("solo", mavutil.mode_mapping_acm, {0: "STABILIZE", 4: "GUIDED", 5: "LOITER", 6: "RTL"}),
        ("solo", mavutil.mode_mapping_acm, {9: "LAND"}),
        ("husky", mavutil.mode_mapping_rover, {0: "MANUAL", 4: "HOLD", 11: "RTL", 15: "GUIDED"}),
    ],
)
def test_custom_mode_numbers_are_ardupilots(
    bench: Any, profile: str, table: dict[int, str], modes: dict[int, str]
) -> None:
    sim, gcs = bench(profile)
    gcs.step()
    for number, name in modes.items():
        assert table[number] == name
        assert gcs.mode(number) == ACCEPTED
        hb = last(gcs.step(1.0), "HEARTBEAT")
        assert hb.custom_mode == number and mavutil.mode_string_v10(hb) == name
        assert sim.mode == name
    assert gcs.mode(99) == FAILED  # no such mode
    assert gcs.ask(SET_MODE, 0, 4)[0] == DENIED  # ArduPilot takes custom modes only
    # The SET_MODE message is acknowledged with its message id as the command.
    gcs.mav.set_mode_send(1, CUSTOM, 0)
    gcs.deliver()
    ack = last(gcs.drain(), "COMMAND_ACK")
    assert (ack.command, ack.result) == (mavlink2.MAVLINK_MSG_ID_SET_MODE, ACCEPTED)
    assert sim.mode == table[0]


# ---------------------------------------------------------------------------- commands


def test_command_acks_like_arducopter(bench: Any) -> None:
    sim, gcs = bench("solo", gps_fix_delay_s=1.0)
    gcs.step()
    assert gcs.ask(ARM, 1) == (FAILED, ["PreArm: Need 3D Fix"])
    assert gcs.ask(SET_MODE, CUSTOM, 4) == (
        FAILED,
        ["Mode change to GUIDED failed: requires position"],
    )
    assert gcs.ask(ARM, 1, 2989) == (ACCEPTED, [])  # forced: no checks
    assert gcs.ask(ARM, 0) == (ACCEPTED, [])
    gcs.step(1.0)  # the fix
    assert gcs.ask(TAKEOFF, 0, 0, 0, 0, 0, 0, 5)[0] == FAILED  # STABILIZE, disarmed
    assert gcs.mode(9) == ACCEPTED  # LAND
    assert gcs.ask(ARM, 1) == (FAILED, ["Arm: Mode not armable"])
    assert gcs.mode(4) == ACCEPTED  # GUIDED
    assert gcs.ask(TAKEOFF, 0, 0, 0, 0, 0, 0, 5)[0] == FAILED  # disarmed
    assert gcs.ask(ARM, 1) == (ACCEPTED, [])
    assert gcs.ask(ARM, 1) == (ACCEPTED, [])  # already armed: fine
    assert gcs.ask(TAKEOFF, 0, 0, 0, 0, 0, 0, -3)[0] == FAILED
    assert gcs.ask(TAKEOFF, 0, 0, 0, 0, 0, 0, 5)[0] == ACCEPTED
    gcs.step(1.0)
    assert gcs.ask(TAKEOFF, 0, 0, 0, 0, 0, 0, 5)[0] == FAILED  # already flying
    assert gcs.ask(ARM, 0)[0] == FAILED  # no disarming in the air...
    assert sim.armed and sim.vehicle.z > 1.0
    assert gcs.ask(ARM, 0, 21196) == (ACCEPTED, ["Disarmed in the air (forced)"])  # ...unless
    assert not sim.armed and sim.vehicle.z == 0.0
    assert gcs.ask(ARM, 0.5)[0] == DENIED
    assert gcs.ask(mavlink2.MAV_CMD_DO_DIGICAM_CONTROL)[0] == UNSUPPORTED
    gcs.mav.command_int_send(1, 1, 0, mavlink2.MAV_CMD_DO_REPOSITION, 0, 0, 0, 0, 0, 0, 0, 0, 0)
    gcs.deliver()
    assert last(gcs.drain(), "COMMAND_ACK").result == UNSUPPORTED
    # Commands for another system are not ours to answer.
    gcs.mav.command_long_send(7, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0)
    gcs.deliver()
    assert "COMMAND_ACK" not in types(gcs.drain())
    assert sim.commands[ARM] == 9


def test_a_rover_does_not_take_off_or_land(bench: Any) -> None:
    sim, gcs = bench("husky")
    gcs.step()
    assert gcs.mode(15) == ACCEPTED and gcs.ask(ARM, 1)[0] == ACCEPTED
    assert gcs.ask(TAKEOFF, 0, 0, 0, 0, 0, 0, 5)[0] == UNSUPPORTED
    assert gcs.ask(mavlink2.MAV_CMD_NAV_LAND)[0] == UNSUPPORTED
    assert gcs.ask(mavlink2.MAV_CMD_NAV_RETURN_TO_LAUNCH)[0] == ACCEPTED
    assert sim.mode == "RTL" and sim.vehicle.z == 0.0


def test_gps_fix_after_the_delay_and_home_once(bench: Any) -> None:
    sim, gcs = bench("solo", gps_fix_delay_s=1.0)
    gcs.mav.request_data_stream_send(1, 1, mavlink2.MAV_DATA_STREAM_EXTENDED_STATUS, 10, 1)
    gcs.deliver()
    before = gcs.step(0.9)
    gps = last(before, "GPS_RAW_INT")
    assert (gps.fix_type, gps.satellites_visible, gps.lat, gps.lon) == (1, 3, 0, 0)
    assert "HOME_POSITION" not in types(before)
    after = gcs.step(2.0)
    gps = last(after, "GPS_RAW_INT")
    assert (gps.fix_type, gps.satellites_visible) == (3, 10)
    assert (gps.lat, gps.lon) == (round(HOME[0] * 1e7), round(HOME[1] * 1e7))
    home = last(after, "HOME_POSITION")
    assert types(after)["HOME_POSITION"] == 1  # announced once, not streamed
    assert (home.latitude, home.longitude, home.altitude) == (455049000, -736133000, 50000)
    # Only the extended-status group streams, at 10 Hz.
    assert set(types(after)) == {
        "SYS_STATUS",
        "GPS_RAW_INT",
        "EXTENDED_SYS_STATE",
        "HEARTBEAT",
        "HOME_POSITION",
    }
    assert types(after)["GPS_RAW_INT"] == 20


def test_stream_requests_are_honoured(bench: Any) -> None:
    sim, gcs = bench("solo")
    gcs.mav.request_data_stream_send(1, 1, mavlink2.MAV_DATA_STREAM_POSITION, 5, 1)
    gcs.deliver()
    got = types(gcs.step(2.0))
    assert got["GLOBAL_POSITION_INT"] == 10 and got["ATTITUDE"] == 0
    gcs.mav.request_data_stream_send(1, 1, mavlink2.MAV_DATA_STREAM_POSITION, 5, 0)
    gcs.mav.request_data_stream_send(1, 1, mavlink2.MAV_DATA_STREAM_ALL, 2, 1)
    gcs.deliver()
    got = types(gcs.step(2.0))
    for name in ("GLOBAL_POSITION_INT", "ATTITUDE", "VFR_HUD", "BATTERY_STATUS", "RC_CHANNELS"):
        assert got[name] == 4, name
    interval = mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL
    assert gcs.ask(interval, mavlink2.MAVLINK_MSG_ID_ATTITUDE, 50_000)[0] == ACCEPTED
    assert gcs.ask(interval, mavlink2.MAVLINK_MSG_ID_VFR_HUD, -1)[0] == ACCEPTED
    assert gcs.ask(interval, mavlink2.MAVLINK_MSG_ID_RAW_IMU, 50_000)[0] == FAILED
    got = types(gcs.step(1.0, dt=0.05))  # at most one of each per step: 20 Hz needs 20 steps
    assert got["ATTITUDE"] == 20 and got["VFR_HUD"] == 0 and got["RC_CHANNELS"] == 2
    request = mavlink2.MAV_CMD_REQUEST_MESSAGE
    assert gcs.ask(request, mavlink2.MAVLINK_MSG_ID_HOME_POSITION)[0] == ACCEPTED
    assert types(gcs.answer)["HOME_POSITION"] == 1  # sent once, right away
    assert gcs.ask(request, mavlink2.MAVLINK_MSG_ID_RAW_IMU)[0] == FAILED


# ---------------------------------------------------------------------------- flight


def _setpoint(
    gcs: Gcs, lat: float, lon: float, alt: float, frame: int = 6, mask: int = 3576
) -> None:
    gcs.mav.set_position_target_global_int_send(
        0, 1, 1, frame, mask, round(lat * 1e7), round(lon * 1e7), alt, 0, 0, 0, 0, 0, 0, 0, 0
    )
    gcs.deliver()


def test_guided_flight_follows_the_kinematics(bench: Any) -> None:
    sim, gcs = bench("solo", default_rate_hz=10.0)
    gcs.step()
    lat, lon = geo.offset_gps(*HOME, 20.0, 10.0)
    _setpoint(gcs, lat, lon, 10.0)  # not in GUIDED: ignored
    assert sim.guided_target is None
    assert gcs.mode(4) == ACCEPTED and gcs.ask(ARM, 1)[0] == ACCEPTED
    assert gcs.ask(TAKEOFF, 0, 0, 0, 0, 0, 0, 10)[0] == ACCEPTED
    gcs.step(0.5)
    _setpoint(gcs, lat, lon, 10.0)  # during the climb: followed once at altitude
    msgs = gcs.step(6.0)
    assert sim.vehicle.z == 10.0 and sim.vehicle.x != 0.0
    assert [m.landed_state for m in msgs if m.get_type() == "EXTENDED_SYS_STATE"][0] == 3
    msgs += gcs.step(10.0)
    assert sim.vehicle.position == pytest.approx((10.0, 20.0, 10.0), abs=0.01)  # 1e-7 degree
    pos = last(msgs, "GLOBAL_POSITION_INT")
    assert (pos.lat, pos.lon, pos.relative_alt) == (round(lat * 1e7), round(lon * 1e7), 10000)
    assert pos.alt == 60000  # MSL: home at 50 m
    assert last(msgs, "EXTENDED_SYS_STATE").landed_state == 2
    # An absolute altitude (MAV_FRAME_GLOBAL_INT) is taken from mean sea level.
    _setpoint(gcs, lat, lon, 62.0, frame=mavlink2.MAV_FRAME_GLOBAL_INT)
    gcs.step(5.0)
    assert sim.vehicle.z == pytest.approx(12.0)
    # Velocity setpoints (position ignored) are not simulated: nothing moves.
    here = sim.vehicle.position
    _setpoint(gcs, *HOME, 12.0, mask=0b1101_1100_0111)
    gcs.step(1.0)
    assert sim.vehicle.position == here
    assert gcs.mode(9) == ACCEPTED  # LAND
    msgs = gcs.step(15.0)
    assert not sim.armed and sim.vehicle.z == 0.0
    assert last(msgs, "EXTENDED_SYS_STATE").landed_state == 1
    assert not last(msgs, "HEARTBEAT").base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED


def test_rtl_climbs_then_returns_then_lands(bench: Any) -> None:
    sim, gcs = bench("solo")
    gcs.step()
    assert gcs.mode(4) == ACCEPTED and gcs.ask(ARM, 1)[0] == ACCEPTED
    assert gcs.ask(TAKEOFF, 0, 0, 0, 0, 0, 0, 5)[0] == ACCEPTED
    gcs.step(4.0)
    _setpoint(gcs, *geo.offset_gps(*HOME, 0.0, 40.0), 5.0)
    gcs.step(12.0)
    assert sim.vehicle.x == pytest.approx(40.0, abs=0.02)  # 1e-7 degree: about 1 cm
    assert gcs.mode(6) == ACCEPTED
    track = []
    for _ in range(400):
        gcs.step()
        v = sim.vehicle
        track.append((v.x, v.z))
        if not sim.armed:
            break
    assert not sim.armed and sim.vehicle.position == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)
    top = next(i for i, (_, z) in enumerate(track) if z == pytest.approx(15.0))
    assert track[top][0] == pytest.approx(40.0, abs=0.02)  # climbed where it was, before leaving
    assert sim.mode == "RTL"


def test_an_armed_copter_that_does_not_take_off_disarms(bench: Any) -> None:
    sim, gcs = bench("solo")
    gcs.step()
    assert gcs.ask(ARM, 1)[0] == ACCEPTED
    gcs.step(9.9)
    assert sim.armed
    gcs.step(0.2)
    assert not sim.armed


def test_battery_drains_as_the_profile_says(bench: Any) -> None:
    sim, gcs = bench("solo", auto_disarm_s=None, default_rate_hz=1.0)
    gcs.step()
    assert gcs.ask(ARM, 1)[0] == ACCEPTED
    msgs = gcs.step(108.0, dt=1.0)  # a tenth of the Solo's 1080 s endurance
    status, battery = last(msgs, "SYS_STATUS"), last(msgs, "BATTERY_STATUS")
    assert status.battery_remaining == battery.battery_remaining == 90
    expected_mv = round((14.0 + 2.8 * 0.9) * 1000)
    assert status.voltage_battery == battery.voltages[0] == expected_mv
    assert battery.voltages[1:] == [65535] * 9
    assert status.current_battery == battery.current_battery > 0
    assert battery.current_consumed > 0
    sim.set_battery(12.0)
    status = last(gcs.step(1.0, dt=1.0), "SYS_STATUS")
    assert status.battery_remaining == 12


# ---------------------------------------------------------------------------- faults


def test_faults_on_the_line(bench: Any) -> None:
    sim, gcs = bench("solo", default_rate_hz=10.0)
    gcs.step()
    sim.faults.heartbeats = False
    got = types(gcs.step(3.0))
    assert got["HEARTBEAT"] == 0 and got["GLOBAL_POSITION_INT"] == 30
    sim.faults.heartbeats = True
    sim.faults.silent = True
    sent = sim.bytes_sent
    gcs.step(2.0)
    assert sim.bytes_sent == sent
    sim.faults.silent = False
    sim.faults.corrupt_every = 2
    msgs = gcs.step(1.0)
    bad = [m for m in msgs if m.get_type() == "BAD_DATA"]
    assert len(bad) == len(msgs) - len(bad) and len(bad) > 30
    assert all(str(m.reason).startswith("invalid MAVLink CRC") for m in bad)
    sim.faults.corrupt_every = 0
    sim.faults.drop_acks = 1
    gcs.mav.command_long_send(1, 1, ARM, 0, 1, 0, 0, 0, 0, 0, 0)
    gcs.deliver()
    assert "COMMAND_ACK" not in types(gcs.drain()) and sim.armed  # acted, answer lost
    assert gcs.ask(ARM, 1)[0] == ACCEPTED
    assert sim.acks_dropped == 1


def test_the_pilot_mode_switch(bench: Any) -> None:
    sim, gcs = bench("solo", gps_fix_delay_s=2.0, default_rate_hz=10.0)
    gcs.step()
    assert not sim.pilot_switch("LOITER")  # no position yet: refused, as ArduPilot
    assert last(gcs.step(), "STATUSTEXT").text == "Mode change to LOITER failed: requires position"
    gcs.step(2.0)
    sim.pilot_release()
    assert sim.pilot_switch("LOITER")
    msgs = gcs.step(1.0)
    rc = last(msgs, "RC_CHANNELS")
    assert rc.chancount == 16 and rc.chan5_raw == 1900 and rc.chan3_raw == 1000
    assert mavutil.mode_string_v10(last(msgs, "HEARTBEAT")) == "LOITER"


def test_stepping_is_deterministic(bench: Any) -> None:
    def flight(**faults: int) -> bytes:
        sim, gcs = bench("solo", default_rate_hz=10.0, seed=3)
        for name, value in faults.items():
            setattr(sim.faults, name, value)
        gcs.step()
        gcs.mode(4)
        gcs.ask(ARM, 1)
        gcs.ask(TAKEOFF, 0, 0, 0, 0, 0, 0, 4)
        _setpoint(gcs, *geo.offset_gps(*HOME, 7.0, -3.0), 6.0)
        gcs.step(6.0)
        return bytes(gcs.raw)

    clean = flight()
    assert clean == flight()
    noisy = flight(garbage_every=4, corrupt_every=9)
    assert noisy == flight(garbage_every=4, corrupt_every=9) and noisy != clean


def test_run_paces_steps_until_stopped(bench: Any) -> None:
    sim, gcs = bench("solo")
    stop = threading.Event()
    runner = threading.Thread(target=sim.run, args=(50.0, stop), daemon=True)
    start = time.monotonic()
    runner.start()
    try:
        deadline = start + 5.0
        while sim.time < 0.2:
            assert time.monotonic() < deadline
            select.select([gcs.fd], [], [], 0.05)
    finally:
        stop.set()
        runner.join(5.0)
    assert not runner.is_alive()
    assert time.monotonic() - start >= sim.time - 0.05  # never ahead of the wall clock
    assert types(gcs.drain())["HEARTBEAT"] == 1


def test_open_failures() -> None:
    with pytest.raises(VehicleSimError, match="^cannot open port /dev/nonexistent-tty: No such"):
        SimVehicle(load_profile("solo"), "/dev/nonexistent-tty")
    with pytest.raises(VehicleSimError, match="bad home"):
        SimVehicle(load_profile("solo"), "/dev/null", home=(95.0, 0.0))


# ---------------------------------------------------------------------------- CLI


runner = CliRunner()


@pytest.mark.parametrize(
    ("args", "status", "message"),
    [
        (["--profile", "nope"], 1, "error: nope: unknown profile (known: husky, m100, solo"),
        (["--profile", "solo", "--home", "45.5"], 2, "--home: expected LAT,LON in degrees such"),
        (["--profile", "solo", "--home", "a,b"], 2, "got 'a,b'"),
        (
            ["--profile", "solo", "--home", "95,10"],
            1,
            "latitude must be between -90 and 90, got 95",
        ),
        (["--profile", "solo", "--home", "45,200"], 1, "longitude must be between -180 and 180"),
        (["--profile", "solo", "--port", "/dev/nonexistent-tty"], 1, "cannot open port /dev/none"),
        (["--profile", "solo", "--rate", "0"], 1, "--rate must be > 0, got 0.0"),
    ],
)
def test_cli_errors_are_one_line(args: list[str], status: int, message: str) -> None:
    # Exit 2: the command line does not parse (not two numbers); 1: it parses but is wrong.
    result = runner.invoke(app, ["vehicle-sim", *args])
    assert result.exit_code == status
    assert result.output.startswith("error: ") or "\nerror: " in result.output
    assert message in result.output and "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)


def test_parse_home() -> None:
    assert parse_home("45.5,-73.6") == (45.5, -73.6)
    assert parse_home(" 45.5 , -73.6 ") == (45.5, -73.6)
    with pytest.raises(typer.Exit):  # parses as two numbers, but no latitude: exit 1
        parse_home("nan,0")


def _start(args: list[str], cwd: Path) -> subprocess.Popen[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "vehicle-sim", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=cwd,
        env=env,
    )


def test_cli_on_a_new_pty_until_ctrl_c(tmp_path: Path) -> None:
    proc = _start(["--profile", "solo", "--gps-delay", "0", "--home", "45.5,-73.6"], tmp_path)
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], 30.0)
        assert ready, "no pty path printed"
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/")
        with Autopilot(path) as link:
            link.wait_heartbeat(10.0)
            link.wait_command(link.request_streams(10.0), 10.0)
            link.wait_gps_fix(10.0)
            deadline = time.monotonic() + 10.0
            while link.telemetry.lat is None:  # GLOBAL_POSITION_INT follows GPS_RAW_INT
                assert time.monotonic() < deadline
                link.poll(0.1)
            assert link.telemetry.lat == pytest.approx(45.5, abs=1e-6)
            assert link.wait_command(link.set_mode("GUIDED"), 10.0).ok
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)  # a hang guard, not a speed test
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    assert "solo (ArduCopter, system 1) at 45.5,-73.6" in err
    assert "mode STABILIZE -> GUIDED (GCS)" in err and err.endswith("vehicle-sim: stopped\n")


def test_cli_named_pty_link(tmp_path: Path) -> None:
    # The husky is a Clearpath base now (tests/test_husky.py): an ArduPilot here.
    proc = _start(["--profile", "solo", "--port", "ttySIM"], tmp_path)
    link = tmp_path / "ttySIM"
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], 30.0)
        assert ready
        assert proc.stdout.readline().strip() == str(link)
        assert link.is_symlink() and os.readlink(link).startswith("/dev/pts/")
        with Autopilot(str(link)) as ap:
            t = ap.wait_heartbeat(10.0)
            assert t.mav_type == mavlink2.MAV_TYPE_QUADROTOR and t.mode == "STABILIZE"
    finally:
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=120)  # a hang guard, not a speed test
    assert proc.returncode == 0, err
    assert not link.exists() and not link.is_symlink()


def test_cli_does_not_overwrite_a_file_with_the_pty_link(tmp_path: Path) -> None:
    (tmp_path / "taken").write_text("mine")  # conftest: the cwd is tmp_path
    result = runner.invoke(app, ["vehicle-sim", "--profile", "solo", "--port", "taken"])
    assert result.exit_code == 1
    assert "taken already exists: remove it or choose another name" in result.output
    assert (tmp_path / "taken").read_text() == "mine"


def test_cli_help_names_the_default_home() -> None:
    from fieldkit.vehicle.sim.ardupilot import DEFAULT_HOME

    result = runner.invoke(app, ["vehicle-sim", "--help"], env={"COLUMNS": "200"})
    assert result.exit_code == 0
    assert f"{DEFAULT_HOME[0]},{DEFAULT_HOME[1]}" in result.output
