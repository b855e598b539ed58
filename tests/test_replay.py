"""A recorded flight replayed into a fresh node through a real loopback serial.

The flight is recorded the way a field node records it: a simulated ArduPilot on one end of
a pty, the node's link on the other, the link read and written only inside the node's
ticks, each tick at one time. The replay then drives a new node from the recording alone.
"""

from __future__ import annotations

import fcntl
import struct
import termios
import time
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pymavlink.dialects.v20 import all as mavlink2
from rigs import RIG_HOME

import bvm
from fieldkit.node.autopilot_port import MavlinkAutopilot
from fieldkit.node.clock import TickClock
from fieldkit.node.node import Node
from fieldkit.node.replay import (
    LINE_QUEUE_BYTES,
    ReplayError,
    ReplayRadio,
    recording_meta,
    replay,
    split_for_line,
)
from fieldkit.node.security import node_commands, node_security
from fieldkit.record.flight import Flight, FlightRecorder, FlightTick
from fieldkit.robot.bundle import encode_fields
from fieldkit.robot.bundle_auth import MemoryCounter, bundle_key
from fieldkit.robot.link_security import LinkSecurity
from fieldkit.robot.operator_command import CommandSigner
from fieldkit.robot.profiles import load_profile
from fieldkit.robot.rc import RcCommand
from fieldkit.update.keys import init_keys, load_robot_keys, load_signing_key
from fieldkit.update.release import Release
from fieldkit.vehicle.link import Autopilot
from fieldkit.vehicle.pty import open_pty
from fieldkit.vehicle.sim.vehicle import SimVehicle

FLY = """
function init() { BVMSTATE = "IDLE"  n = 0 }
function step() {
  n = n + 1
  if (flight.rc_cmd == 22) BVMSTATE = "UP"
  if (BVMSTATE == "UP") {
    uav_takeoff(6.0)
    if (pose.position.altitude > 5.0) { BVMSTATE = "GO"  goto_abs(8.0, 3.0, 6.0, 0.0) }
  }
  neighbors.broadcast("n", n)
  if (n % 10 == 0) log("tick ", n, " ", BVMSTATE, " ", math.rng.uniform(1.0))
}
"""


def _queued(fd: int) -> int:
    return int(struct.unpack("i", fcntl.ioctl(fd, termios.TIOCINQ, b"\0\0\0\0"))[0])


def record_flight(src: str, seconds: float, keys_dir: Path | None = None) -> Flight:
    """Fly `src` on a simulated Solo, recorded, `seconds` of ticks at 10 Hz; with
    `keys_dir`, signed, hearing robot 2's sealed bundles, a forgery, and the operator."""
    profile = load_profile("solo")
    assert profile.path is not None
    program = bvm.compile_source(src, "fly.bzz")
    release = Release.from_program(program)
    pty = open_pty()
    now = [1000.0]
    clock = TickClock(lambda: now[0], lambda: 1_764_000_000_000_000_000 + int(now[0] * 1e9))
    sim = SimVehicle(profile, pty.master, home=RIG_HOME, gps_fix_delay_s=0.0)
    link = Autopilot(pty.slave_path, profile=profile, clock=clock.now)
    flight = Flight({}, profile.path.read_text(), release.bo, release.bdb, release.bpos)
    recorder = FlightRecorder(flight)
    link.on_rx, link.on_tx = recorder.autopilot_rx, recorder.autopilot_tx
    try:

        def deliver() -> None:
            # what the node wrote reaches the vehicle; what the vehicle wrote waits, unread,
            # at the node's end, as on a UART between two ticks
            deadline = time.monotonic() + 10
            while sim.bytes_received < link.bytes_sent:
                assert time.monotonic() < deadline
                sim.service(0.05)
            while _queued(pty.slave_fd) < sim.bytes_sent - link.bytes_received:
                assert time.monotonic() < deadline
                time.sleep(0.001)

        def idle() -> None:
            sim.step(0.1)
            now[0] += 0.1
            deliver()

        link.wait_heartbeat(10.0, idle=idle, poll_interval=0.0)
        cmd = link.request_streams(10.0)
        link.wait_command(cmd, 10.0, idle=idle, poll_interval=0.0)
        link.wait_gps_fix(10.0, idle=idle, poll_interval=0.0)
        t = link.wait_position(10.0, idle=idle, poll_interval=0.0)
        home = (t.lat, t.lon, 0.0)
        commands = [RcCommand(1.0, 1, 22)]
        radio = ReplayRadio()
        extra: dict[str, object] = {}
        neighbour = None
        if keys_dir is not None:
            keys = load_robot_keys(keys_dir)
            state = keys_dir.parent / "state"
            extra = {
                "security": node_security(1, "signed", keys, state, lambda _l: None),
                "command_gate": node_commands(1, keys, state),
            }
            neighbour = LinkSecurity.signed_with(2, bundle_key(keys.swarm_key), MemoryCounter())
            signer = CommandSigner(load_signing_key(keys_dir), keys_dir / "command.seq")
        node = Node(
            # A radio that hears what the test hands it and keeps what is sent.
            profile, program, 1, MavlinkAutopilot(link, home), radio,  # type: ignore[arg-type]
            home=home, commands=commands, clock=clock, out=lambda _l: None, seed=7,
            recorder=recorder, **extra,  # type: ignore[arg-type]
        )  # fmt: skip
        flight.meta = recording_meta(
            node, link, script_name="fly.bzz", seed=7, globals_={}, commands=commands
        )
        for k in range(round(seconds * 10)):
            if neighbour is not None:
                air = encode_fields(2, (), RIG_HOME[0], RIG_HOME[1], 0.0, k)
                heard = [(2, neighbour.seal(air))]
                if k == 40:
                    heard.append((2, heard[0][1][:-1] + b"\x00"))  # forged: dropped
                if k == 60:
                    heard.append((200, signer.sign(1, 900)))  # the operator's command
                radio.inbox = heard
            node.tick()
            sim.step(0.1)
            now[0] += 0.1
            deliver()
    finally:
        link.close()
        sim.close()
        pty.close()
    return flight


def _takes_off(tick: FlightTick) -> bool:
    parser = mavlink2.MAVLink(None)
    for chunk in tick.autopilot_tx:
        for m in parser.parse_buffer(chunk) or []:
            if m.get_type() == "COMMAND_LONG" and m.command == mavlink2.MAV_CMD_NAV_TAKEOFF:
                return True
    return False


@pytest.fixture(scope="module")
def flight() -> Flight:
    return record_flight(FLY, 12.0)


def test_a_recorded_flight_replays_identically_through_a_loopback_serial(flight: Flight) -> None:
    states = {t.state for t in flight.ticks}
    assert {"IDLE", "UP", "GO"} <= states  # it flew: took off and went
    assert sum(len(t.autopilot_tx) for t in flight.ticks) > 20
    report = replay(flight)
    assert report.divergence is None, report.divergence
    assert report.ticks == len(flight.ticks) == 120
    assert report.digests == 120 and report.messages > 20 and report.frames == 120


def test_a_tick_that_read_more_than_a_pty_holds_replays(flight: Flight) -> None:
    # A loaded robot reads seconds of telemetry in one tick, more than the 4095 unread bytes
    # a pty's line discipline holds. Line noise (zeros, skipped by the MAVLink parser) makes
    # such ticks here: one chunk larger than a pty holds, and many chunks that add up to it.
    import copy

    edited = copy.deepcopy(flight)
    edited.ticks[30].autopilot_rx.insert(0, bytes(9000))
    edited.ticks[31].autopilot_rx[:0] = [bytes(700)] * 12
    assert sum(map(len, edited.ticks[30].autopilot_rx)) > 4095
    report = replay(edited)
    assert report.divergence is None, report.divergence
    assert report.ticks == len(flight.ticks)


@given(st.lists(st.binary(max_size=3000), max_size=8), st.integers(1, 4096))
def test_a_ticks_bytes_split_for_the_line_keep_their_order(chunks: list[bytes], limit: int) -> None:
    head, rest = split_for_line(chunks, limit)
    assert b"".join(head + rest) == b"".join(chunks)
    assert sum(map(len, rest)) <= limit
    if sum(map(len, chunks)) <= limit:
        assert head == [] and rest == chunks
    else:
        assert sum(map(len, rest)) == limit  # as much as fits is left for the node's own poll
    assert LINE_QUEUE_BYTES < 4095


def test_a_changed_script_is_caught_at_the_tick_it_changes(flight: Flight) -> None:
    # Climbs to 7 m instead of 6: the first takeoff command differs, at the tick of RC 22.
    changed = bvm.compile_source(FLY.replace("uav_takeoff(6.0)", "uav_takeoff(7.0)"), "f.bzz")
    report = replay(flight, program=changed)
    d = report.divergence
    assert d is not None
    # The first order to take off: the supervisor's order differs before any byte does.
    order = next(t.tick for t in flight.ticks if t.order and t.order[0] == "takeoff")
    assert d.tick == order and d.channel == "order to the vehicle"
    assert d.expected == "('takeoff', (6.0,))" and d.got == "('takeoff', (7.0,))"
    assert report.ticks == order + 1 and report.digests == order
    # The command on the line (after arming is acknowledged) comes later: had the orders
    # agreed, the bytes would have told.
    assert next(t.tick for t in flight.ticks if _takes_off(t)) > order


def test_a_script_change_that_only_touches_state_is_caught_by_the_digest(flight: Flight) -> None:
    changed = bvm.compile_source(FLY.replace("n = n + 1", "n = n + 1  m = n"), "f.bzz")
    d = replay(flight, program=changed).divergence
    assert d is not None and d.tick == 0 and d.channel == "script state digest"


def test_an_edited_recording_is_caught(flight: Flight) -> None:
    import copy

    edited = copy.deepcopy(flight)
    k = 50
    edited.ticks[k].radio_out[0] = bytes(len(edited.ticks[k].radio_out[0]))
    d = replay(edited).divergence
    assert d is not None and d.tick == k and d.channel.startswith("radio frame")
    edited = copy.deepcopy(flight)
    edited.ticks[k].digest = bytes(32)
    d = replay(edited).divergence
    assert d is not None and d.tick == k and d.channel == "script state digest"


def test_a_signed_flight_replays_with_the_robots_keys_and_only_with_them(tmp_path: Path) -> None:
    init_keys(tmp_path / "keys")
    flight = record_flight(FLY, 8.0, tmp_path / "keys")
    assert flight.meta["security"] == "signed" and "swarm" not in str(flight.meta).lower()
    heard = flight.ticks[60]
    assert any(sender == 200 for sender, _ in heard.radio_in)
    assert heard.radio_out and all(len(f) % 8 == 0 for f in heard.radio_out)
    report = replay(flight, keys=load_robot_keys(tmp_path / "keys"))
    assert report.divergence is None, report.divergence
    assert report.frames >= 80 + 1  # every sealed bundle, and the command relayed once
    with pytest.raises(ReplayError, match="--keys"):
        replay(flight)
    init_keys(tmp_path / "other")
    with pytest.raises(ReplayError, match="swarm key"):
        replay(flight, keys=load_robot_keys(tmp_path / "other"))


def test_the_flight_plot_shows_the_flight(flight: Flight, tmp_path: Path) -> None:
    from fieldkit.record.plot import plot_flight

    path = plot_flight(flight, tmp_path / "flight.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 20_000


WATCH = """
function init() { fixes = 0  armed_ticks = 0 }
function step() {
  if (pose.position.latitude != 0.0) fixes = fixes + 1
  if (flight.status == 3) armed_ticks = armed_ticks + 1
  BVMSTATE = "WATCHING"
}
"""


def tlog_flight(path: Path, seconds: float) -> Flight:
    """A real autopilot log as ticks of 10 Hz by its own timestamps (what `bag from-tlog`
    makes): no node outputs, no script, no profile."""
    data = path.read_bytes()
    ticks: list[FlightTick] = []
    i, t0 = 0, None
    while i + 10 < len(data):
        stamp = int.from_bytes(data[i : i + 8], "big")
        j = i + 8
        n = data[j + 1] + (8 if data[j] == 0xFE else 12 + (13 if data[j + 2] & 1 else 0))
        t0 = stamp if t0 is None else t0
        k = (stamp - t0) // 100_000
        if k >= seconds * 10:
            break
        while len(ticks) <= k:
            ticks.append(FlightTick(len(ticks), 10.0 + len(ticks) / 10, 0))
        ticks[k].autopilot_rx.append(data[j : j + n])
        i = j + n
    return Flight({}, "", b"", ticks=ticks)


def test_a_real_autopilot_log_drives_a_node_without_verify() -> None:
    log = Path(__file__).parent / "data" / "tlogs" / "quad-flight-arducopter.tlog"
    flight = tlog_flight(log, 100.0)  # the GPS gets its fix at 66 s
    with pytest.raises(ReplayError, match="no node outputs"):
        replay(flight)
    with pytest.raises(ReplayError, match="--profile"):
        replay(flight, verify=False)
    program = bvm.compile_source(WATCH, "watch.bzz")
    report = replay(flight, program=program, profile=load_profile("solo"), verify=False)
    assert report.divergence is None and 300 < report.ticks < 400  # from the fix on
    last = report.replayed[-1]
    assert last.state == "WATCHING" and len(report.replayed) == report.ticks
    assert abs(float(last.sensors["lat"]) - -35.36) < 0.1  # the real field, CMAC
