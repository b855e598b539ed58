"""The autopilot link (fieldkit.vehicle.link) against a simulated ArduPilot on a real pty.

Both ends speak pymavlink: `SimRig` puts a `SimVehicle` on the pty master and an `Autopilot`
on the slave path, steps them in lockstep on a simulated clock and waits for the bytes (with
a wall-clock deadline), never for time. Real ArduPilot logs from tests/data/tlogs are
replayed through a pty as well, corrupt frames included.

The protocol itself (commands, flight, retries, faults) is tested without a pty, on the cores,
in tests/test_autopilot_core.py; here is what needs the transport: opening, the blocking
waits, streams over a real line, TCP, recorded logs.
"""

from __future__ import annotations

import os
import re
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink import mavutil
from pymavlink.dialects.v20 import all as mavlink2
from rigs import SimRig

from fieldkit.robot import geo
from fieldkit.robot.profiles import load_profile
from fieldkit.vehicle import (
    Autopilot,
    AutopilotError,
    FrameReader,
    MavCommand,
    SimVehicle,
    open_pty,
)

TLOGS = Path(__file__).resolve().parent / "data" / "tlogs"  # with their licences
HOME = (45.5049, -73.6133)


@pytest.fixture
def make_rig() -> Iterator[Callable[..., SimRig]]:
    """SimRigs closed at the end of the test."""
    rigs: list[SimRig] = []

    def make(profile: str = "solo", **options: object) -> SimRig:
        rig = SimRig(profile, home=HOME, **options)
        rigs.append(rig)
        return rig

    yield make
    for rig in rigs:
        rig.close()


def kinds(rig: SimRig) -> list[tuple[str, str]]:
    """The link's events so far, as (kind, text)."""
    return [(e.kind, e.text) for e in rig.link.drain_events()]


def finish(rig: SimRig, cmd: MavCommand, seconds: float = 10.0) -> MavCommand:
    """Tick until `cmd` is over."""
    assert rig.run_until(lambda: cmd.done, seconds), f"{cmd} still pending"
    return cmd


def test_heartbeats_both_ways(make_rig: Callable[..., SimRig]) -> None:
    rig = make_rig()
    t = rig.link.wait_heartbeat(5.0, idle=rig.tick, poll_interval=0.0)
    assert (rig.link.target_system, rig.link.target_component) == (1, 1)
    assert t.mav_type == mavlink2.MAV_TYPE_QUADROTOR
    assert t.autopilot_type == mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
    assert t.mode == "STABILIZE" and not t.armed
    rig.run_for(3.0)
    # Ours every second from the first poll on: at 0, 1, 2 and 3 s.
    assert rig.sim.gcs_heartbeats == 4
    assert rig.sim.received["HEARTBEAT"] == 4
    assert rig.link.heartbeat_age() < 1.0 and not rig.link.heartbeat_lost
    assert rig.link.bad_frames == 0 and rig.link.link_errors == 0
    assert ("heartbeat", "autopilot found: system 1, MAV_AUTOPILOT_ARDUPILOTMEGA, "
            "MAV_TYPE_QUADROTOR") in kinds(rig)  # fmt: skip


def test_wait_heartbeat_times_out_with_a_clear_error(make_rig: Callable[..., SimRig]) -> None:
    rig = make_rig()
    rig.sim.faults.silent = True
    with pytest.raises(AutopilotError) as e:
        rig.link.wait_heartbeat(2.0, idle=rig.tick, poll_interval=0.0)
    assert re.fullmatch(
        r"no heartbeat from the autopilot after 2 s on /dev/\S+ "
        r"\(0 bytes received, 0 bad frames\)",
        str(e.value),
    )
    assert 2.0 <= rig.now < 2.3


def test_open_failure_is_an_autopilot_error() -> None:
    with pytest.raises(AutopilotError, match="^cannot open the autopilot link /dev/nonexistent-"
                       "tty: No such file or directory$"):  # fmt: skip
        Autopilot("/dev/nonexistent-tty")


def test_dji_profiles_have_no_mavlink_link() -> None:
    with pytest.raises(AutopilotError, match="does not speak MAVLink"):
        Autopilot.from_profile(load_profile("m100"))


def test_gps_fix_wait_times_out_then_succeeds(make_rig: Callable[..., SimRig]) -> None:
    rig = make_rig(gps_fix_delay_s=1000.0)
    rig.link.wait_heartbeat(5.0, idle=rig.tick, poll_interval=0.0)
    with pytest.raises(AutopilotError, match=re.escape("no GPS fix after 1 s (no GPS_RAW_INT")):
        rig.link.wait_gps_fix(1.0, idle=rig.tick, poll_interval=0.0)
    rig.connect(10.0)
    with pytest.raises(AutopilotError) as e:
        rig.link.wait_gps_fix(30.0, idle=rig.tick, poll_interval=0.0)
    assert str(e.value) == "no GPS fix after 30 s (fix type 1, 3 satellites)"
    assert rig.link.telemetry.lat is None  # ArduPilot's 0, 0 before a fix is no position
    rig.sim.gps_fix_delay_s = rig.sim.time + 2.0
    t = rig.link.wait_gps_fix(5.0, idle=rig.tick, poll_interval=0.0)
    assert (t.gps_fix_type, t.satellites) == (3, 10)
    rig.run_for(0.5)
    assert t.lat == pytest.approx(HOME[0], abs=1e-7) and t.lon == pytest.approx(HOME[1], abs=1e-7)
    assert t.home == pytest.approx((HOME[0], HOME[1], 50.0), abs=1e-6)


def test_a_node_waits_for_a_position_after_the_fix(make_rig: Callable[..., SimRig]) -> None:
    """A fix can come before any GLOBAL_POSITION_INT: the node used to take home as 0,0."""
    rig = make_rig(gps_fix_delay_s=0.0)
    rig.link.wait_heartbeat(5.0, idle=rig.tick, poll_interval=0.0)
    with pytest.raises(AutopilotError, match=r"GPS fix but no position .* after 1 s"):
        rig.link.wait_position(1.0, idle=rig.tick, poll_interval=0.0)  # no streams asked yet
    rig.link.request_streams(10.0)
    rig.link.wait_gps_fix(5.0, idle=rig.tick, poll_interval=0.0)
    t = rig.link.wait_position(5.0, idle=rig.tick, poll_interval=0.0)
    assert t.lat == pytest.approx(HOME[0], abs=1e-7) and t.lon == pytest.approx(HOME[1], abs=1e-7)


def test_stream_rates_follow_requests(make_rig: Callable[..., SimRig]) -> None:
    rig = make_rig()
    rig.link.wait_heartbeat(5.0, idle=rig.tick, poll_interval=0.0)
    rig.run_for(2.0)
    # An ArduPilot port with SRn_ rates at 0: heartbeats only (and home, once, when set).
    assert set(rig.link.message_counts) == {"HEARTBEAT", "HOME_POSITION"}
    cmd = finish(rig, rig.link.request_streams(4.0))
    assert cmd.ok and cmd.warnings == []
    assert rig.sim.received["REQUEST_DATA_STREAM"] == 1
    assert rig.sim.commands[mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL] == 8
    before = rig.link.message_counts.copy()
    rig.run_for(5.0)
    got = rig.link.message_counts - before
    for name in ("GLOBAL_POSITION_INT", "GPS_RAW_INT", "SYS_STATUS", "ATTITUDE", "RC_CHANNELS"):
        assert 19 <= got[name] <= 21, (name, got[name])
    assert 2 <= got["HOME_POSITION"] <= 3  # asked for at 0.5 Hz at most
    assert 4 <= got["HEARTBEAT"] <= 6

    # One message faster, one off, by SET_MESSAGE_INTERVAL.
    att = mavlink2.MAVLINK_MSG_ID_ATTITUDE
    pos = mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT
    assert finish(rig, rig.link.command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, (att, 1e5))).ok
    assert finish(rig, rig.link.command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, (pos, -1))).ok
    before = rig.link.message_counts.copy()
    rig.run_for(5.0)
    got = rig.link.message_counts - before
    assert 49 <= got["ATTITUDE"] <= 51 and got["GLOBAL_POSITION_INT"] == 0
    # A message the vehicle cannot stream: refused, and the refusal is reported.
    bad = finish(rig, rig.link.command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, (9999, 1e5)))
    assert not bad.ok and bad.result_name == "MAV_RESULT_FAILED"


# ---------------------------------------------------------------------------- parsing


@settings(max_examples=150, deadline=None)
@given(
    picks=st.lists(st.integers(0, 3), min_size=1, max_size=12),
    noise=st.lists(st.binary(max_size=40), min_size=12, max_size=12),
    cuts=st.lists(st.integers(1, 64), min_size=1, max_size=20),
)
def test_frame_reader_recovers_every_frame_from_noise(
    picks: list[int], noise: list[bytes], cuts: list[int]
) -> None:
    enc = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    samples = [
        enc.heartbeat_encode(2, 3, 209, 4, 4),
        enc.global_position_int_encode(1000, 455049000, -736133000, 50000, 5000, 1, 2, 3, 9000),
        enc.command_ack_encode(400, 0, 0, 0, 255, 191),
        enc.statustext_encode(2, b"PreArm: Need 3D Fix"),
    ]
    frames = [samples[i].pack(enc, force_mavlink1=j % 3 == 2) for j, i in enumerate(picks)]
    stream = b"".join(noise[j] + f for j, f in enumerate(frames)) + noise[-1] + bytes(300)
    reader = FrameReader(mavlink2.MAVLink(None))
    got = []
    pos, k = 0, 0
    while pos < len(stream):
        step = cuts[k % len(cuts)]
        got += reader.feed(stream[pos : pos + step])
        pos, k = pos + step, k + 1
    assert [bytes(m.get_msgbuf()) for m in got] == [bytes(f) for f in frames]
    assert reader.messages == len(frames)
    if any(noise[: len(frames)]) or noise[-1]:
        assert reader.bad_frames + reader.unknown_frames > 0


def test_fuzz_slice_hostile_streams() -> None:
    """A short deterministic slice of `python -m tests.fuzz.mavlink_fuzz` (see there)."""
    from fuzz import mavlink_fuzz

    lines: list[str] = []
    stats = mavlink_fuzz.run("ci", max_inputs=400, out=lines.append)
    assert stats.failures == 0, "\n".join(lines)
    assert stats.inputs == 400 and stats.frames > 2000


def test_a_tcp_link_like_sitl() -> None:
    """The link on `tcp:` against a vehicle listening like SITL, both in real time."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    sim = SimVehicle(load_profile("solo"), f"tcpin:127.0.0.1:{port}", default_rate_hz=10.0)
    stop = threading.Event()
    runner = threading.Thread(target=sim.run, args=(50.0, stop), daemon=True)
    runner.start()
    try:
        with Autopilot(f"tcp:127.0.0.1:{port}", profile=load_profile("solo")) as link:
            link.wait_heartbeat(10.0)
            link.wait_gps_fix(10.0)
            assert link.wait_command(link.takeoff(1.0), 10.0).ok
            deadline = time.monotonic() + 10.0
            while link.telemetry.alt_rel_m is None or link.telemetry.alt_rel_m < 0.9:
                assert time.monotonic() < deadline, "no climb seen"
                link.poll(0.1)
            assert link.telemetry.lat == pytest.approx(geo.DEFAULT_HOME[0], abs=1e-6)
    finally:
        stop.set()
        runner.join(5.0)
        sim.close()
    assert not runner.is_alive()


# ---------------------------------------------------------------------------- real logs


def _tlog_frames(path: Path) -> list[bytes]:
    """The raw MAVLink frames of a tlog (each record: 8-byte timestamp, then one frame)."""
    data = path.read_bytes()
    frames: list[bytes] = []
    i = 0
    while i + 10 < len(data):
        j = i + 8
        if data[j] == 0xFE:
            n = data[j + 1] + 8
        elif data[j] == 0xFD:
            n = data[j + 1] + 12 + (13 if data[j + 2] & 1 else 0)
        else:
            raise AssertionError(f"{path.name}: record at byte {i} is not a MAVLink frame")
        frames.append(data[j : j + n])
        i = j + n
    return frames


@pytest.mark.parametrize(
    ("name", "first", "last", "changes"),
    [
        # Arming, LOITER, disarming, re-arming, RTL and back to STABILIZE; 240 bad CRCs.
        ("quad-flight-arducopter.tlog", 30_000, 48_000, 8),
        # An ROV sitting disarmed in MANUAL, no GPS position, 348 corrupt frames.
        ("rov-ardusub-baddata.tlog", 20_000, 32_000, 1),
    ],
)
def test_a_real_log_through_a_pty(name: str, first: int, last: int, changes: int) -> None:
    frames = _tlog_frames(TLOGS / name)[first:last]
    # What pymavlink itself makes of these frames, one record at a time.
    ref = mavlink2.MAVLink(None)
    ref.robust_parsing = True
    good, bad = [], 0
    for f in frames:
        for m in ref.parse_buffer(f) or []:
            if m.get_type() == "BAD_DATA":
                bad += 1
            else:
                good.append(m)
    assert bad > 200
    hb = [m for m in good if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1]
    hb = [m for m in hb if m.get_srcSystem() == 1]
    last_of = {m.get_type(): m for m in good if m.get_srcSystem() == 1}
    # The battery as the link documents it: the latest of SYS_STATUS and BATTERY_STATUS #0.
    volts: float | None = None
    percent: float | None = None
    for m in good:
        if m.get_srcSystem() != 1:
            continue
        if m.get_type() == "SYS_STATUS":
            volts = m.voltage_battery * 1e-3 if m.voltage_battery != 65535 else volts
            percent = float(m.battery_remaining) if m.battery_remaining != -1 else None
        elif m.get_type() == "BATTERY_STATUS" and m.id == 0:
            cells = [v for v in m.voltages if v != 65535]
            volts = sum(cells) * 1e-3 if cells else volts
            percent = float(m.battery_remaining) if m.battery_remaining != -1 else percent
    transitions: list[str] = []
    state = ("UNKNOWN", False)
    for m in hb:
        mode, armed = mavutil.mode_string_v10(m), bool(m.base_mode & 128)
        if armed != state[1]:
            transitions.append("armed" if armed else "disarmed")
        if mode != state[0]:
            transitions.append(f"mode {state[0]} -> {mode}")
        state = (mode, armed)

    pty = open_pty()
    now = [0.0]
    link = Autopilot(pty.slave_path, clock=lambda: now[0], heartbeat_interval_s=None)
    try:
        stream = b"".join(frames)
        sent = 0
        while link.bytes_received < len(stream):
            if sent < len(stream):
                try:
                    sent += os.write(pty.master, stream[sent : sent + 4096])
                except BlockingIOError:
                    pass  # the pty is full: let the link read
            link.poll(0.5)
            now[0] += 0.001
    finally:
        link.close()
        pty.close()

    assert link.messages == len(good)  # not one good frame lost to the corrupt ones
    assert link.bad_frames >= bad and link.link_errors == 0
    assert [e.text for e in link.drain_events() if e.kind in ("mode", "armed")] == transitions
    assert len(transitions) == changes
    t = link.telemetry
    assert (t.mode, t.armed) == state
    pos = last_of["GLOBAL_POSITION_INT"]
    if pos.lat or pos.lon:
        assert (t.lat, t.lon) == (pos.lat * 1e-7, pos.lon * 1e-7)
        assert t.alt_rel_m == pos.relative_alt * 1e-3
    else:
        assert t.lat is None  # 0, 0 is ArduPilot's "no position"
    assert volts is not None and t.battery_voltage_v == pytest.approx(volts, abs=1e-9)
    assert t.battery_percent == percent
    gps = last_of["GPS_RAW_INT"]
    assert (t.gps_fix_type, t.satellites) == (gps.fix_type, gps.satellites_visible)
