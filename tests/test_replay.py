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

import pytest
from pymavlink.dialects.v20 import all as mavlink2
from rigs import RIG_HOME

import bvm
from fieldkit.node.autopilot_port import MavlinkAutopilot
from fieldkit.node.clock import TickClock
from fieldkit.node.node import Node
from fieldkit.node.replay import ReplayRadio, recording_meta, replay
from fieldkit.record.flight import Flight, FlightRecorder, FlightTick
from fieldkit.robot.profiles import load_profile
from fieldkit.robot.rc import RcCommand
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


def record_flight(src: str, seconds: float) -> Flight:
    """Fly `src` on a simulated Solo, recorded, `seconds` of ticks at 10 Hz."""
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
        node = Node(
            # A radio that hears nothing and keeps what is sent: the bundles get recorded.
            profile, program, 1, MavlinkAutopilot(link, home), ReplayRadio(),  # type: ignore[arg-type]
            home=home, commands=commands, clock=clock, out=lambda _l: None, seed=7,
            recorder=recorder,
        )  # fmt: skip
        flight.meta = recording_meta(
            node, link, script_name="fly.bzz", seed=7, globals_={}, commands=commands
        )
        for _ in range(round(seconds * 10)):
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


def test_a_changed_script_is_caught_at_the_tick_it_changes(flight: Flight) -> None:
    # Climbs to 7 m instead of 6: the first takeoff command differs, at the tick of RC 22.
    changed = bvm.compile_source(FLY.replace("uav_takeoff(6.0)", "uav_takeoff(7.0)"), "f.bzz")
    report = replay(flight, program=changed)
    d = report.divergence
    assert d is not None
    # The tick whose recorded writes hold the takeoff command (after arming is acknowledged).
    takeoff = next(t.tick for t in flight.ticks if _takes_off(t))
    assert d.tick == takeoff and "COMMAND_LONG" in d.channel
    assert d.expected == "{'param7': 6.0}" and d.got == "{'param7': 7.0}"
    assert report.ticks == takeoff + 1 and report.digests == takeoff


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
