"""A serial device that vanishes mid-flight and comes back (issue 17): the autopilot's link.

On a robot the autopilot is /dev/autopilot, a udev symlink to its ttyACM0 or ttyUSB0; a loose
USB cable makes the device vanish (reads fail, the node file goes) and come back, possibly as
another ttyUSBn that the symlink then points at. Here `LooseCable` plays that: a symlink in a
temporary folder to a real pty with a simulated ArduPilot on its master; `unplug()` closes the
pty and removes the symlink, `plug()` makes a new pty (another /dev/pts/N), points the
symlink at it and boots a new simulated ArduPilot there (one that streams nothing until
asked). The link and the node tick on a simulated clock; waits are on bytes, with a
wall-clock deadline as a hang guard, never on time.

The reopen policy itself and the core's fresh start are tested without a port first.
"""

from __future__ import annotations

import logging
import os
import re
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import all as mavlink2
from rigs import RIG_HOME, MemoryRig

import bvm
from fieldkit.node.autopilot_port import MavlinkAutopilot
from fieldkit.node.node import Node
from fieldkit.robot.profiles import Profile, load_profile
from fieldkit.robot.rc import RcCommand
from fieldkit.robot.safety import HEARTBEAT_LOST
from fieldkit.vehicle.autopilot import AutopilotCore
from fieldkit.vehicle.link import Autopilot
from fieldkit.vehicle.mavlink import new_codec
from fieldkit.vehicle.pty import PtyPair, open_pty
from fieldkit.vehicle.reopen import ReopenPolicy
from fieldkit.vehicle.sim.vehicle import SimVehicle

#: Hang guard for bytes crossing a pty (real seconds); a healthy exchange takes milliseconds.
SYNC_TIMEOUT_S = 10.0

# ---------------------------------------------------------------- the policy, no port


def test_the_policy_tells_each_outage_once_and_paces_the_attempts() -> None:
    policy = ReopenPolicy(1.0)
    assert not policy.down and not policy.due(0.0)
    assert policy.lost(10.0, "read failed: Input/output error")
    assert not policy.lost(10.2, "write failed: Input/output error")  # the same outage
    assert policy.down and policy.reason == "read failed: Input/output error"
    # The first attempt a whole interval after the loss, then one per interval.
    assert not policy.due(10.5) and policy.due(11.0)
    policy.failed(11.05)
    assert not policy.due(11.9) and policy.due(12.05)
    policy.failed(12.05)
    assert policy.attempts == 2
    assert policy.back(12.6) == pytest.approx(2.6)
    assert not policy.down and not policy.due(20.0)
    assert policy.lost(30.0, "gone again") and policy.outages == 2 and policy.attempts == 0
    assert policy.back(29.0) == 0.0  # a clock read before the loss cannot make it negative


@pytest.mark.parametrize("interval", [0.0, -1.0, float("nan"), float("inf")])
def test_the_policy_wants_a_positive_interval(interval: float) -> None:
    with pytest.raises(ValueError, match="reopen interval"):
        ReopenPolicy(interval)


def _heartbeat_frame(seq: int = 0) -> bytes:
    """One autopilot HEARTBEAT as an ArduCopter sends it."""
    out = bytearray()

    class Sink:
        def write(self, buf: bytes) -> None:
            out.extend(buf)

    mav = new_codec(Sink(), 1, 1)
    mav.seq = seq
    mav.heartbeat_send(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 3)
    return bytes(out)


@pytest.mark.parametrize("fresh", [True, False])
def test_a_half_frame_from_before_the_loss_is_forgotten(fresh: bool) -> None:
    """The rest of a frame cut by the pull never comes: after `connection_made` the next
    device's first frame is read whole, not taken for that rest (the control shows the
    difference is real: without it, the stale half costs a bad frame)."""
    core = AutopilotCore(clock=lambda: 0.0)
    frame = _heartbeat_frame()
    core.receive_data(frame[:7])  # the cable goes mid-frame
    if fresh:
        core.connection_made()
    core.receive_data(frame)
    if fresh:
        assert (core.messages, core.bad_frames) == (1, 0)
        assert core.telemetry.last_heartbeat == 0.0
    else:
        assert core.bad_frames >= 1


def test_a_fresh_start_asks_for_the_streams_again_at_the_last_rate() -> None:
    rig = MemoryRig("solo", home=RIG_HOME, gps_fix_delay_s=0.0)
    rig.link.connection_made()
    assert rig.link.pending == ()  # never asked: nothing to ask again
    rig.connect(rate_hz=4.0)
    asked = rig.sim.received["REQUEST_DATA_STREAM"]
    rig.link.connection_made()  # as after a reopen
    (again,) = rig.link.pending
    assert again.name == "request_streams 4 Hz"
    assert rig.run_until(lambda: again.done, 5.0) and again.ok
    assert rig.sim.received["REQUEST_DATA_STREAM"] == asked + 1


# ---------------------------------------------------------------- a loose cable on a pty


class LooseCable:
    """/dev/autopilot in a temporary folder: a symlink to the pty a simulated ArduPilot is on.

    The link on `path` and the vehicle tick in lockstep on a simulated clock (`now`), as in
    tests/rigs `SimRig`: each `tick()` steps the vehicle, polls the link and, while the link
    is up, waits until every byte has crossed both ways. While unplugged the vehicle is not
    stepped (its line is gone; what it does meanwhile is not what these tests are about).
    """

    def __init__(self, folder: Path, profile: str | Profile = "solo", dt: float = 0.1) -> None:
        self.profile = load_profile(profile) if isinstance(profile, str) else profile
        self.path = str(folder / "autopilot")
        self.dt = dt
        self.now = 0.0
        self.pty: PtyPair | None = None
        self.sim: SimVehicle | None = None  # the vehicle on the line, None while unplugged
        self.away: SimVehicle | None = None  # the vehicle while unplugged
        # Where the byte counters stood when the current line opened, at each end.
        self._rx_link = self._rx_sim = self._tx_link = self._tx_sim = 0
        self.plug()
        self.link = Autopilot(self.path, profile=self.profile, clock=self.clock)

    def clock(self) -> float:
        """The simulated time, seconds."""
        return self.now

    def plug(self, vehicle: SimVehicle | None = None) -> SimVehicle:
        """Plug the cable (back): a new pty, the symlink pointed at it (atomically, as udev
        does), and on it `vehicle` (the same autopilot, still flying) or, by default, a
        freshly booted one."""
        assert self.pty is None
        self.pty = open_pty()
        staged = self.path + ".new"
        os.symlink(self.pty.slave_path, staged)
        os.replace(staged, self.path)
        if vehicle is None:
            vehicle = SimVehicle(self.profile, self.pty.master, home=RIG_HOME, gps_fix_delay_s=0.0)
        else:
            vehicle.attach(self.pty.master)
        self.sim, self.away = vehicle, None
        if hasattr(self, "link"):
            assert self.link.link_down  # it writes nothing until it reopens
            self._tx_link, self._tx_sim = self.link.bytes_sent, vehicle.bytes_received
        return vehicle

    def unplug(self) -> None:
        """Pull the cable: the device closes under the link and its node file goes."""
        assert self.pty is not None
        self.pty.close()
        os.unlink(self.path)
        self.pty, self.away, self.sim = None, self.sim, None

    def tick(self, node: Node | None = None) -> None:
        """The node's tick (if any), a step of the vehicle, a poll of the link, bytes delivered."""
        if node is not None:
            self._watch(node.tick)
        sim = self.sim
        if sim is not None:
            sim.step(self.dt)
        self.now += self.dt
        self._watch(self.link.poll)
        if sim is None or self.link.link_down:
            return
        deadline = time.monotonic() + SYNC_TIMEOUT_S
        link = self.link
        while link.bytes_received - self._rx_link < sim.bytes_sent - self._rx_sim:
            assert time.monotonic() < deadline, "vehicle -> link: bytes not delivered"
            self._watch(lambda: link.poll(0.1))
        while sim.bytes_received - self._tx_sim < link.bytes_sent - self._tx_link:
            assert time.monotonic() < deadline, "link -> vehicle: bytes not delivered"
            sim.service(0.1)

    def _watch(self, poll: Callable[[], object]) -> None:
        """Run `poll`; if the link came back in it, count the new line's bytes from there
        (pyserial may flush what the vehicle wrote before the port opened)."""
        down = self.link.link_down
        poll()
        if down and not self.link.link_down and self.sim is not None:
            self._rx_link, self._rx_sim = self.link.bytes_received, self.sim.bytes_sent

    def run_until(self, cond: Callable[[], bool], seconds: float, node: Node | None = None) -> bool:
        """Tick until `cond()` holds (True) or `seconds` of simulated time pass (False)."""
        for _ in range(round(seconds / self.dt)):
            if cond():
                return True
            self.tick(node)
        return cond()

    def connect(self, rate_hz: float = 10.0) -> None:
        """Wait for the heartbeat and the GPS fix, streams going at `rate_hz`."""
        t = self.link.telemetry
        assert self.run_until(lambda: t.last_heartbeat is not None, 5.0)
        streams = self.link.request_streams(rate_hz)
        assert self.run_until(lambda: streams.done and t.lat is not None, 10.0) and streams.ok

    def close(self) -> None:
        """Close the link and whatever pty is plugged."""
        self.link.close()
        if self.pty is not None:
            self.pty.close()


@pytest.fixture
def cable(tmp_path: Path) -> Iterator[LooseCable]:
    """The solo's autopilot behind a symlink, connected, streams at 10 Hz."""
    c = LooseCable(tmp_path)
    c.connect()
    yield c
    c.close()


def events(link: Autopilot, *kinds: str) -> list[str]:
    """The texts of the link's events of `kinds` since the last call."""
    return [e.text for e in link.drain_events() if e.kind in kinds]


def test_the_link_outlives_its_device_and_reopens_the_path(cable: LooseCable) -> None:
    link = cable.link
    assert cable.pty is not None
    first_tty = cable.pty.slave_path
    # Something still holds the old tty open: the device must come back as another one
    # (ttyUSB1 for ttyUSB0), and only the symlink leads there.
    stale = os.open(first_tty, os.O_RDWR | os.O_NOCTTY)
    link.drain_events()
    cable.unplug()
    pulled = cable.now
    for _ in range(50):  # five seconds without the device: every poll returns
        cable.tick()
    (lost,) = events(link, "link", "reopened")  # once, not once a poll
    assert re.fullmatch(rf"{re.escape(cable.path)} lost \(read failed: .+\); reopening", lost)
    assert link.link_down and link.fileno() is None and link.heartbeat_lost
    assert link.bytes_dropped > 0  # our heartbeats while it was gone, not written anywhere
    # Seen at the first poll after the pull; then one open() a second, not one a poll.
    lost_at = link.reopen.down_since
    assert lost_at == pytest.approx(pulled + cable.dt)
    assert link.reopen.attempts == 4  # at 1, 2, 3 and 4 s after the loss
    try:
        sim = cable.plug()
    finally:
        os.close(stale)
    assert cable.pty is not None and cable.pty.slave_path != first_tty
    assert cable.run_until(lambda: not link.link_down, 1.5)
    back = cable.now
    (text,) = events(link, "link", "reopened")
    assert text == f"{cable.path} back after {round(back - lost_at, 1):g} s"
    # The vehicle booted again: it streams only because the link asked again, at 10 Hz.
    t = link.telemetry
    assert cable.run_until(lambda: link.heartbeat_age() < 0.5 and t.lat is not None, 3.0)
    assert not link.heartbeat_lost
    assert sim.received["REQUEST_DATA_STREAM"] == 1
    assert sim.commands[mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL] >= 1
    t.lat = None  # streams, not a position left from before the pull
    cable.run_until(lambda: False, 0.3)
    assert t.lat is not None and link.message_counts["GLOBAL_POSITION_INT"] > 0
    assert link.bad_frames == 0


def test_a_write_to_a_vanished_device_takes_the_link_down(
    cable: LooseCable, capsys: pytest.CaptureFixture[str]
) -> None:
    link = cable.link
    link.drain_events()
    cable.unplug()
    link.send_heartbeat()  # before any read has noticed
    assert link.link_down
    assert events(link, "link") == [
        f"{cable.path} lost (write failed: Input/output error); reopening"
    ]
    link.send_heartbeat()  # down: dropped, not written
    assert link.bytes_dropped > 0
    assert "is dead" not in capsys.readouterr().out  # pymavlink's own print never ran


def test_a_closed_link_does_not_reopen(cable: LooseCable) -> None:
    cable.unplug()
    cable.tick()
    assert cable.link.link_down
    cable.link.close()
    cable.plug()
    cable.now += 5.0
    cable.link.poll()
    assert cable.link.fileno() is None
    assert events(cable.link, "reopened") == []


# ---------------------------------------------------------------- the node through it

FLY = """
function init() { BVMSTATE = "TURNEDOFF" }
function step() {
  if (flight.rc_cmd == 22) BVMSTATE = "TAKEOFF"
  if (BVMSTATE == "TAKEOFF") {
    uav_takeoff(TARGET_ALTITUDE)
    if (pose.position.altitude > TARGET_ALTITUDE * 0.9) {
      BVMSTATE = "GO"
      goto_abs(10.0, 0.0, 0.0, 0.0)
    }
  }
}
"""

DRIVE = """
function init() { BVMSTATE = "DRIVE" }
function step() { goto_abs(5.0, 0.0, 0.0, 0.0) }
"""


def make_node(cable: LooseCable, src: str) -> Node:
    """A node on the cable's link (home where the vehicle is), its lines kept by `out`."""
    t = cable.link.telemetry
    assert t.lat is not None and t.lon is not None
    home = (t.lat, t.lon, 0.0)
    return Node(
        cable.profile,
        bvm.compile_source(src),
        3,
        MavlinkAutopilot(cable.link, home),
        None,
        home=home,
        commands=[RcCommand(0.5, 3, 22)],
        clock=cable.clock,
        out=lambda line: None,
    )


def autopilot_lines(caplog: pytest.LogCaptureFixture) -> list[tuple[str, str]]:
    """(level, text) of the autopilot's link lines the node logged."""
    return [
        (r.levelname, r.getMessage())
        for r in caplog.records
        if r.name == "fieldkit.node"
        and (" lost (" in r.getMessage() or " back after " in r.getMessage())
    ]


def pull_in_flight(cable: LooseCable, caplog: pytest.LogCaptureFixture) -> Node:
    """solo flying its script, the autopilot's cable pulled for eight seconds: the loop goes
    on, the heartbeat-loss failsafe trips after heartbeat_timeout_s, one line says so."""
    caplog.set_level(logging.INFO, logger="fieldkit")
    node = make_node(cable, FLY)
    supervisor = node.runtime.supervisor
    assert cable.run_until(lambda: node.runtime.state == "GO", 40.0, node)
    link = cable.link
    last_hb = link.telemetry.last_heartbeat
    assert last_hb is not None
    ticks = node.runtime.ticks
    cable.unplug()
    timeout = cable.profile.autopilot.heartbeat_timeout_s
    tripped: float | None = None
    for _ in range(80):
        cable.tick(node)
        if tripped is None and supervisor.failsafe is not None:
            tripped = cable.now
    assert node.runtime.ticks == ticks + 80  # every tick ran
    assert supervisor.failsafe == HEARTBEAT_LOST
    assert supervisor.action == cable.profile.failsafe.on_heartbeat_loss == "land"
    # On the tick the heartbeat's age passes the timeout: not before, not later.
    assert tripped is not None and last_hb + timeout < tripped <= last_hb + timeout + 2 * cable.dt
    assert link.reopen.attempts == 7  # one a second from the loss, whatever the loop's rate
    (lost,) = autopilot_lines(caplog)
    assert lost[0] == "WARNING"
    assert re.fullmatch(rf"autopilot: {re.escape(cable.path)} lost \(.+\); reopening", lost[1])
    return node


def test_a_pulled_cable_lands_the_robot_once_it_is_back(
    cable: LooseCable, caplog: pytest.LogCaptureFixture
) -> None:
    """The same autopilot, still flying in GUIDED, comes back on another tty: the node
    reopens it, asks for the streams again, and the land it could not send goes out."""
    node = pull_in_flight(cable, caplog)
    link, sim = cable.link, cable.away
    assert sim is not None
    asked = sim.received["REQUEST_DATA_STREAM"]
    cable.plug(sim)
    assert cable.run_until(lambda: link.heartbeat_age() < 1.0, 3.0, node)
    lines = autopilot_lines(caplog)
    assert len(lines) == 2 and lines[1][0] == "INFO"
    assert re.fullmatch(rf"autopilot: {re.escape(cable.path)} back after [\d.]+ s", lines[1][1])
    assert sim.received["REQUEST_DATA_STREAM"] == asked + 1
    land = cable.profile.autopilot.land_mode
    assert cable.run_until(lambda: sim.mode == land, 3.0, node)
    assert cable.run_until(lambda: sim.vehicle.z < 0.1, 30.0, node)  # landed
    assert node.runtime.supervisor.failsafe == HEARTBEAT_LOST  # a land is never undone
    assert node.summary()["errors"] == []


def test_an_autopilot_rebooted_meanwhile_is_left_in_its_own_mode(
    cable: LooseCable, caplog: pytest.LogCaptureFixture
) -> None:
    """A new autopilot behind the symlink (it rebooted): the link reopens, the heartbeats
    resume, the streams are asked again. It is in its boot mode, not the GUIDED the node
    asked for: the node reads that as the pilot's or the autopilot's own doing (as for any
    mode change it did not ask for) and sends it nothing, the land included."""
    node = pull_in_flight(cable, caplog)
    link = cable.link
    sim = cable.plug()
    assert cable.run_until(lambda: link.heartbeat_age() < 1.0, 3.0, node)
    assert sim.received["REQUEST_DATA_STREAM"] == 1
    assert link.pilot_override
    cable.run_until(lambda: False, 3.0, node)
    assert sim.mode == "STABILIZE" and sim.commands[mavlink2.MAV_CMD_DO_SET_MODE] == 0
    assert [line for _, line in autopilot_lines(caplog)][1].endswith(" s")  # back, once
    assert node.runtime.supervisor.failsafe == HEARTBEAT_LOST


def test_a_ground_robot_stops_and_gets_its_script_back_when_the_cable_returns(
    tmp_path: Path,
) -> None:
    """husky: heartbeat loss means stop (a hold); once the device is back and the heartbeat
    healthy for a few seconds, the supervisor gives the script its robot back."""
    cable = LooseCable(tmp_path, "husky")
    try:
        cable.connect()
        node = make_node(cable, DRIVE)
        supervisor = node.runtime.supervisor
        cable.run_until(lambda: False, 2.0, node)
        cable.unplug()
        cable.run_until(lambda: False, 5.0, node)
        assert supervisor.failsafe == HEARTBEAT_LOST and supervisor.action == "stop"
        sim = cable.plug()
        assert cable.run_until(lambda: supervisor.failsafe is None, 10.0, node)
        assert sim.mode == cable.profile.autopilot.loiter_mode  # the stop reached it first
        assert sim.received["REQUEST_DATA_STREAM"] == 1
        # The script's targets go out again (the supervisor's carrot, every tick).
        setpoints = sim.received["SET_POSITION_TARGET_GLOBAL_INT"]
        cable.run_until(lambda: False, 1.0, node)
        assert sim.received["SET_POSITION_TARGET_GLOBAL_INT"] >= setpoints + 9
    finally:
        cable.close()


# ---------------------------------------------------------------- what the node reports


def test_status_and_summary_say_how_long_the_autopilot_was_lost(tmp_path: Path) -> None:
    """STATUS= says `autopilot link down N s` while the device is gone, and how many times
    and how long in all once it is back; summary.json keeps the outages, the seconds down
    and the bytes dropped."""
    cable = LooseCable(tmp_path, "husky")
    try:
        cable.connect()
        node = make_node(cable, DRIVE)
        link = cable.link
        cable.run_until(lambda: False, 1.0, node)
        assert "link" not in node.status_line()
        before = node.summary()
        assert (before["autopilot_outages"], before["autopilot_down_s"]) == (0, 0.0)
        assert (before["radio_outages"], before["radio_down_s"]) == (0, 0.0)
        assert before["autopilot_bytes_dropped"] == before["radio_frames_dropped_down"] == 0
        cable.unplug()
        cable.run_until(lambda: False, 3.2, node)
        lost_at = link.reopen.down_since
        assert lost_at is not None
        down = cable.now - lost_at
        status = node.status_line()
        assert f", autopilot link down {down:.1f} s, " in status, status
        during = node.summary()
        assert during["autopilot_outages"] == 1
        assert during["autopilot_down_s"] == pytest.approx(down)
        cable.plug()
        assert cable.run_until(lambda: not link.link_down, 2.0, node)
        total = link.reopen.down_s
        assert total > down
        cable.run_until(lambda: False, 1.0, node)  # up again: the total no longer grows
        status = node.status_line()
        assert f", autopilot link lost once, {total:.1f} s in all" in status, status
        after = node.summary()
        assert after["autopilot_outages"] == 1
        assert after["autopilot_down_s"] == round(total, 3)
        assert after["autopilot_bytes_dropped"] == link.bytes_dropped > 0
        assert after["radio_outages"] == 0  # no radio: nothing to lose
        # A second pull counts as a second outage, its seconds added.
        cable.unplug()
        cable.run_until(lambda: False, 1.5, node)
        assert node.summary()["autopilot_outages"] == 2
        assert node.summary()["autopilot_down_s"] == pytest.approx(
            total + cable.now - link.reopen.down_since, abs=1e-3
        )
    finally:
        cable.close()
