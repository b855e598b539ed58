"""A serial device that vanishes and comes back (issue 18) for the non-MAVLink backends: the
M100's DJI link and the Husky's two ports, on `fieldkit.vehicle.serial_port.ReopeningSerial`.

As in tests/test_device_loss.py (the MAVLink link's), a device is a udev-like symlink in a
temporary folder to a real pty; `unplug()` closes the pty and removes the symlink, `plug()`
makes a new pty (another /dev/pts/N) and points the symlink at it. The machine on the other
end is the simulator's (`SimM100Vehicle`, `SimHuskyPorts`), moved to the new pty when the
cable goes back in (`attach`: the same machine, still flying or driving). Everything ticks
on a simulated clock; waits are on bytes, with a wall-clock deadline as a hang guard only.
"""

from __future__ import annotations

import errno
import logging
import os
import re
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import serial
from rigs import RIG_HOME
from rigs.dji import DJI_HOME
from rigs.flights import FLY_NORTH

import bvm
from fieldkit.node.autopilot_port import vehicle_port
from fieldkit.node.node import Node
from fieldkit.robot import geo
from fieldkit.robot.profiles import load_profile
from fieldkit.robot.rc import RcCommand
from fieldkit.robot.safety import HEARTBEAT_LOST
from fieldkit.vehicle.clearpath.link import Husky
from fieldkit.vehicle.dji import messages as M
from fieldkit.vehicle.dji.link import DjiLink
from fieldkit.vehicle.pty import PtyPair, open_pty
from fieldkit.vehicle.serial_port import ReopeningSerial, port_reason
from fieldkit.vehicle.sim.dji import TEST_APP_ID, TEST_APP_KEY
from fieldkit.vehicle.sim.dji_vehicle import SimM100Vehicle
from fieldkit.vehicle.sim.husky_pty import SimHuskyPorts

#: Hang guard for bytes crossing a pty (real seconds); a healthy exchange takes milliseconds.
SYNC_TIMEOUT_S = 10.0


class Socket:
    """A device node in a folder: a symlink to the pty that plays the device, as udev's."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)
        self.pty: PtyPair | None = None

    def plug(self) -> PtyPair:
        """A new pty, the symlink pointed at it (atomically, as udev does)."""
        assert self.pty is None
        self.pty = open_pty()
        staged = self.path + ".new"
        os.symlink(self.pty.slave_path, staged)
        os.replace(staged, self.path)
        return self.pty

    def unplug(self) -> None:
        """Pull the cable: the device closes under its reader and its node file goes."""
        assert self.pty is not None
        self.pty.close()
        os.unlink(self.path)
        self.pty = None

    def close(self) -> None:
        """Close whatever pty is plugged."""
        if self.pty is not None:
            self.pty.close()
            self.pty = None


def hang_guard(what: str) -> Callable[[], None]:
    """A check to call in a wait loop: fails after SYNC_TIMEOUT_S real seconds."""
    deadline = time.monotonic() + SYNC_TIMEOUT_S

    def check() -> None:
        assert time.monotonic() < deadline, f"{what}: bytes not delivered"

    return check


class Stepped:
    """A machine and its link ticking in lockstep on a simulated clock."""

    dt: float
    now: float

    def clock(self) -> float:
        """The simulated time, seconds."""
        return self.now

    def tick(self, node: Node | None = None) -> None:
        """One step of the machine, the node (if any) and the link."""
        raise NotImplementedError

    def run_until(self, cond: Callable[[], bool], seconds: float, node: Node | None = None) -> bool:
        """Tick until `cond()` holds (True) or `seconds` of simulated time pass (False)."""
        for _ in range(round(seconds / self.dt)):
            if cond():
                return True
            self.tick(node)
        return cond()


# ---------------------------------------------------------------- the port alone


def test_port_reasons_are_short() -> None:
    eio = OSError(errno.EIO, "Input/output error")
    assert port_reason("read failed", eio) == "read failed: Input/output error"
    try:
        raise serial.SerialException(f"read failed: {eio}") from eio
    except serial.SerialException as wrapped:
        assert port_reason("read failed", wrapped) == "read failed: Input/output error"
    eof = serial.SerialException(
        "device reports readiness to read but returned no data (device disconnected or "
        "multiple access on port?)"
    )
    assert port_reason("read failed", eof) == "read failed: end of file, device disconnected"


def test_a_port_is_lost_once_dropped_while_down_and_reopened_at_the_pace(tmp_path: Path) -> None:
    socket = Socket(tmp_path / "dev")
    pty = socket.plug()
    now = [0.0]
    port = ReopeningSerial(socket.path, 115200, clock=lambda: now[0])
    told: list[str] = []
    port.on_lost = lambda reason: told.append(f"lost ({reason})")
    port.on_back = lambda down: told.append(f"back after {down:g} s")
    try:
        os.write(pty.master, b"hello")
        check = hang_guard("device -> port")
        got = b""
        while got != b"hello":
            check()
            got += port.read(64)
        assert port.write_some(b"ping") == 4
        socket.unplug()
        now[0] = 10.0
        assert port.read(64) == b"" and port.down and port.fileno() is None
        assert port.write_some(b"12345") == 0 and port.bytes_dropped == 5
        assert not port.write_all(b"123") and port.bytes_dropped == 8
        assert port.read(64) == b""  # down: no second loss
        # EIO, or end of file where the tty had no error to give: either way a short reason.
        (lost,) = told
        assert re.fullmatch(r"lost \(read failed: (Input/output error|end of file, .+)\)", lost)
        assert port.reopen.down_since == 10.0 and port.reopen.outages == 1
        pty = socket.plug()
        now[0] = 10.5
        assert not port.try_reopen()  # not due: no open() at all
        assert port.reopen.attempts == 0
        now[0] = 11.2
        assert port.try_reopen() and not port.down
        assert told[1:] == ["back after 1.2 s"] and port.reopen.down_s == pytest.approx(1.2)
        os.write(pty.master, b"again")
        check = hang_guard("new device -> port")
        got = b""
        while got != b"again":
            check()
            got += port.read(64)
        # A write that fails takes it down as well, with its own reason.
        socket.unplug()
        now[0] = 20.0
        assert port.write_some(b"x") == 0 and port.down
        assert told[2:] == ["lost (write failed: Input/output error)"]
        now[0] = 25.0
        assert not port.try_reopen()  # still gone: one failed open, the next a second later
        assert port.reopen.attempts == 1 and not port.reopen.due(25.5)
        port.close()
        socket.plug()
        assert not port.try_reopen() and not port.down  # closed for good
    finally:
        port.close()
        socket.close()


# ---------------------------------------------------------------- the M100

#: Take off on RC code 22, then 10 m north (the M100 end-to-end test's flight, unbroken).
FLY = FLY_NORTH.replace("BROKEN == 1", "0 == 1")


class M100Cable(Stepped):
    """/dev/m100 in a temporary folder: the DJI link on it, a simulated M100 at the other end.

    Stepped at DJI's 50 Hz on a simulated clock; the node (if any) ticks every fifth step,
    at its profile's 10 Hz. While unplugged the flight controller is not stepped.
    """

    dt = 0.02

    def __init__(self, folder: Path) -> None:
        self.profile = load_profile("m100")
        self.socket = Socket(folder / "m100")
        self.now = 0.0
        self.steps = 0
        pty = self.socket.plug()
        self.sim: SimM100Vehicle | None = SimM100Vehicle(
            self.profile, pty.master, home=DJI_HOME, gps_fix_delay_s=0.0
        )
        self.away: SimM100Vehicle | None = None
        self.link = DjiLink(
            self.socket.path,
            app_id=TEST_APP_ID,
            app_key=TEST_APP_KEY,
            profile=self.profile,
            clock=self.clock,
            release_on_close=False,
        )
        self._mark()

    @property
    def path(self) -> str:
        """The device's path (the symlink)."""
        return self.socket.path

    def _mark(self) -> None:
        """Count each end's bytes from here (a new line)."""
        sim = self.sim
        assert sim is not None
        self._rx = (self.link.core.bytes_received, sim.bytes_sent)
        self._tx = (self.link.bytes_written, sim.bytes_received)

    def unplug(self) -> None:
        """Pull the cable."""
        self.socket.unplug()
        self.away, self.sim = self.sim, None

    def plug(self) -> SimM100Vehicle:
        """Plug it back: a new pty, the same flight controller (still flying) on it."""
        sim = self.away
        assert sim is not None
        pty = self.socket.plug()
        sim.attach(pty.master)
        self.sim, self.away = sim, None
        return sim

    def tick(self, node: Node | None = None) -> None:
        """A step of the FC, the node's tick when due, a poll of the link, bytes delivered."""
        if node is not None and self.steps % 5 == 0:
            self._watch(node.tick)
        self.steps += 1
        sim = self.sim
        if sim is not None:
            sim.step(self.dt)
        self.now += self.dt
        self._watch(self.link.poll)
        if sim is None or self.link.link_down:
            return
        link = self.link
        check = hang_guard("FC <-> link")
        while link.core.bytes_received - self._rx[0] < sim.bytes_sent - self._rx[1]:
            check()
            self._watch(lambda: link.poll(0.1))
        while sim.bytes_received - self._tx[1] < link.bytes_written - self._tx[0]:
            check()
            sim.service(0.1)

    def _watch(self, poll: Callable[[], object]) -> None:
        """Run `poll`; if the link came back in it, count the new line's bytes from there."""
        down = self.link.link_down
        poll()
        if down and not self.link.link_down and self.sim is not None:
            self._mark()

    def close(self) -> None:
        """Close the link, the FC's line and the pty."""
        self.link.close()
        for sim in (self.sim, self.away):
            if sim is not None:
                sim.close()
        self.socket.close()


@pytest.fixture
def m100(tmp_path: Path) -> Iterator[M100Cable]:
    """The M100 behind a symlink, activated and holding control authority, a position known."""
    c = M100Cable(tmp_path)
    try:
        c.link.wait_connected(10.0, idle=c.tick, poll_interval=0.0)
        c.link.wait_position(5.0, idle=c.tick, poll_interval=0.0)
        yield c
    finally:
        c.close()


def node_on(link: object, profile_name: str, src: str, clock: Callable[[], float]) -> Node:
    """A node flying `src` on `link` (home where the vehicle is), robot 3, RC 22 at 0.5 s."""
    t = link.telemetry  # type: ignore[attr-defined]
    assert t.lat is not None and t.lon is not None
    home = (t.lat, t.lon, 0.0)
    return Node(
        load_profile(profile_name),
        bvm.compile_source(src),
        3,
        vehicle_port(link, home),  # type: ignore[arg-type]
        None,
        home=home,
        commands=[RcCommand(0.5, 3, 22)],
        clock=clock,
        out=lambda line: None,
    )


def link_lines(caplog: pytest.LogCaptureFixture, *words: str) -> list[tuple[str, str]]:
    """(level, text) of the node's log lines holding any of `words`."""
    return [
        (r.levelname, r.getMessage())
        for r in caplog.records
        if r.name == "fieldkit.node" and any(w in r.getMessage() for w in words)
    ]


def fly_and_pull(m100: M100Cable, caplog: pytest.LogCaptureFixture) -> Node:
    """The M100 flying its script, its cable pulled for five seconds: the node keeps ticking,
    its heartbeat-loss failsafe fires (land), one warning says the device is lost."""
    caplog.set_level(logging.INFO, logger="fieldkit")
    link = m100.link
    node = node_on(link, "m100", FLY, m100.clock)
    assert m100.run_until(lambda: node.runtime.state == "GO", 60.0, node)
    ticks = node.runtime.ticks
    m100.unplug()
    m100.run_until(lambda: False, 5.0, node)
    assert node.runtime.ticks == ticks + 50  # every tick ran
    supervisor = node.runtime.supervisor
    assert supervisor.failsafe == HEARTBEAT_LOST and supervisor.action == "land"
    assert link.link_down and link.fileno() is None and link.bytes_dropped > 0
    assert link.reopen.attempts in (3, 4)  # one open() a second, not one a poll
    (lost,) = link_lines(caplog, " lost (")
    assert lost[0] == "WARNING"
    path = re.escape(m100.path)
    assert re.fullmatch(rf"autopilot: {path} lost \(read failed: .+\); reopening", lost[1])
    status = node.status_line()
    assert re.search(r", autopilot link down [\d.]+ s, ", status), status
    return node


def test_an_m100_whose_cable_comes_back_is_activated_again_and_lands(
    m100: M100Cable, caplog: pytest.LogCaptureFixture
) -> None:
    """The same flight controller, still flying, on another tty: the link reopens the path,
    the session starts over (activation, the broadcast rate, control authority), and the
    landing the failsafe could not send goes out."""
    node = fly_and_pull(m100, caplog)
    link = m100.link
    sim = m100.away
    assert sim is not None
    asked = sim.received.copy()
    m100.plug()
    assert m100.run_until(lambda: not link.link_down, 1.5, node)
    assert m100.run_until(lambda: link.core.connected, 3.0, node)
    (back,) = link_lines(caplog, " back after ")
    assert back[0] == "INFO"
    assert re.fullmatch(rf"autopilot: {re.escape(m100.path)} back after [\d.]+ s", back[1])
    for command in (M.CMD_GET_VERSION, M.CMD_ACTIVATE, M.CMD_SET_BROADCAST, M.CMD_CONTROL):
        assert sim.received[command] > asked[command], command
    assert link_lines(caplog, "activated: app id")[-1][1].startswith("autopilot: activated")
    assert m100.run_until(lambda: sim.task == "landing", 5.0, node)
    assert m100.run_until(lambda: sim.vehicle.z == 0.0, 30.0, node)  # landed
    assert node.runtime.supervisor.failsafe == HEARTBEAT_LOST  # a land is never undone
    summary = node.summary()
    assert summary["autopilot_outages"] == 1 and summary["autopilot_down_s"] > 1.0
    assert summary["autopilot_bytes_dropped"] == link.bytes_dropped > 0
    assert summary["errors"] == [] and link.bad_frames == 0


def test_an_m100_the_pilot_took_meanwhile_is_left_to_the_pilot(
    m100: M100Cable, caplog: pytest.LogCaptureFixture
) -> None:
    """The pilot flipped the mode switch out of F while the cable was out: the link reopens
    and activates again, but asks for no control authority, and the landing is not sent."""
    node = fly_and_pull(m100, caplog)
    link = m100.link
    sim = m100.away
    assert sim is not None
    sim.pilot_switch("A")
    asked = sim.received.copy()
    m100.plug()
    assert m100.run_until(lambda: link.core.activated, 3.0, node)
    m100.run_until(lambda: False, 3.0, node)
    assert link.pilot_override and not sim.authority
    assert sim.received[M.CMD_ACTIVATE] > asked[M.CMD_ACTIVATE]
    assert sim.received[M.CMD_CONTROL] == asked[M.CMD_CONTROL]  # nothing to take it back
    assert sim.received[M.CMD_TASK] == asked[M.CMD_TASK] and sim.task is None


# ---------------------------------------------------------------- the Husky's two ports

DRIVE = """
function init() { n = 0 }
function step() {
  n = n + 1
  if (n == 2) arm()
  if (n > 5) goto_abs(40.0 - pose.position.x, 0.0 - pose.position.y, 0.0, 0.0)
}
"""


class HuskyCable(Stepped):
    """/dev/husky and /dev/gps in a temporary folder: the Husky link on them, a simulated
    Husky at the other ends, ticking at the node's 10 Hz on a simulated clock.

    The base keeps running whichever cable is out: its end of a pulled cable dangles (a pty
    nobody reads) until it goes back in.
    """

    dt = 0.1

    def __init__(self, folder: Path) -> None:
        self.profile = load_profile("husky")
        self.mcu = Socket(folder / "husky")
        self.gps = Socket(folder / "gps")
        self.now = 0.0
        mcu, gps = self.mcu.plug(), self.gps.plug()
        self.sim = SimHuskyPorts(self.profile, mcu.master, gps.master, home=RIG_HOME)
        self.link = Husky(self.mcu.path, self.gps.path, profile=self.profile, clock=self.clock)
        self.dangling: dict[str, PtyPair] = {}
        self._mark()

    def _mark(self) -> None:
        """Count each line's bytes from here (a new line)."""
        link, sim = self.link, self.sim
        self._mcu_rx = (link.bytes_received, sim.mcu.bytes_sent)
        self._mcu_tx = (link.bytes_sent, sim.mcu.bytes_received)
        self._gps_rx = (link.gps.bytes_received, sim.gps.bytes_sent)

    def unplug(self, which: str) -> None:
        """Pull the MCU's ("mcu") or the GPS's ("gps") cable."""
        socket = self.mcu if which == "mcu" else self.gps
        socket.unplug()
        void = self.dangling[which] = open_pty()
        self.sim.attach(**{which: void.master})

    def plug(self, which: str) -> None:
        """Plug it back: a new pty behind the same name, the base's end on it."""
        socket = self.mcu if which == "mcu" else self.gps
        pty = socket.plug()
        self.sim.attach(**{which: pty.master})
        self.dangling.pop(which).close()

    def tick(self, node: Node | None = None) -> None:
        """The node's tick (or a poll of the link), a step of the base, bytes delivered."""
        link, sim = self.link, self.sim
        down = (link.reopen.down, link.gps_reopen.down)
        if node is not None:
            node.tick()
        else:
            link.poll()
        sim.step(self.dt)
        self.now += self.dt
        link.poll()
        if down != (link.reopen.down, link.gps_reopen.down):
            self._mark()  # a line came back (or went): count it afresh
        check = hang_guard("base <-> link")
        while not link.reopen.down:
            check()
            if link.bytes_received - self._mcu_rx[0] >= sim.mcu.bytes_sent - self._mcu_rx[1]:
                break
            link.poll(0.1)
        while not link.gps_reopen.down:
            check()
            if link.gps.bytes_received - self._gps_rx[0] >= sim.gps.bytes_sent - self._gps_rx[1]:
                break
            link.poll(0.1)
        while not link.reopen.down:
            check()
            if sim.mcu.bytes_received - self._mcu_tx[1] >= link.bytes_sent - self._mcu_tx[0]:
                break
            sim.service(0.1)

    def close(self) -> None:
        """Close the link, the base's lines and every pty."""
        self.link.close()
        self.sim.close()
        for socket in (self.mcu, self.gps):
            socket.close()
        for pty in self.dangling.values():
            pty.close()


@pytest.fixture
def husky(tmp_path: Path) -> Iterator[HuskyCable]:
    """The Husky behind two symlinks, its MCU answering and a GPS fix."""
    c = HuskyCable(tmp_path)
    try:
        c.link.wait_heartbeat(10.0, idle=c.tick, poll_interval=0.0)
        c.link.wait_gps_fix(10.0, idle=c.tick, poll_interval=0.0)
        yield c
    finally:
        c.close()


def test_a_husky_whose_mcu_cable_comes_back_stops_then_drives_on(
    husky: HuskyCable, caplog: pytest.LogCaptureFixture
) -> None:
    """The MCU's cable out for five seconds: nothing the node sends reaches the base, whose
    MCU watchdog stops the wheels (the warning says so); the heartbeat-loss failsafe (stop)
    fires; once the cable is back and the MCU healthy, the script gets its robot back."""
    caplog.set_level(logging.INFO, logger="fieldkit")
    link, sim = husky.link, husky.sim
    node = node_on(link, "husky", DRIVE, husky.clock)
    supervisor = node.runtime.supervisor
    assert husky.run_until(lambda: sim.drive.moving, 10.0, node)
    ticks = node.runtime.ticks
    husky.unplug("mcu")
    husky.run_until(lambda: False, 5.0, node)
    assert node.runtime.ticks == ticks + 50  # every tick ran
    assert not sim.drive.moving and sim.watchdog_trips == 1  # the base's own watchdog
    assert supervisor.failsafe == HEARTBEAT_LOST and supervisor.action == "stop"
    assert link.link_down and link.bytes_dropped > 0 and link.reopen.attempts in (3, 4)
    assert not link.gps_reopen.down and link.gps.has_fix  # the GPS is another cable
    (lost,) = link_lines(caplog, " lost (")
    path = re.escape(husky.mcu.path)
    assert lost[0] == "WARNING"
    assert re.fullmatch(
        rf"husky: MCU port {path} lost \(read failed: .+\); reopening: nothing reaches the "
        r"base meanwhile, its MCU's watchdog stops the wheels",
        lost[1],
    )
    assert ", autopilot link down " in node.status_line()
    husky.plug("mcu")
    assert husky.run_until(lambda: not link.link_down, 1.5, node)
    assert husky.run_until(lambda: supervisor.failsafe is None, 10.0, node)
    (back,) = link_lines(caplog, " back after ")
    assert back[0] == "INFO"
    assert re.fullmatch(rf"husky: MCU port {path} back after [\d.]+ s", back[1])
    assert husky.run_until(lambda: sim.drive.moving, 5.0, node)  # driving on to its target
    summary = node.summary()
    assert summary["autopilot_outages"] == 1 and summary["autopilot_down_s"] > 1.0
    assert summary["autopilot_bytes_dropped"] == link.bytes_dropped
    assert summary["errors"] == []


def test_a_husky_whose_gps_cable_comes_back_loses_its_fix_then_regains_it(
    husky: HuskyCable,
) -> None:
    """The GPS's cable out: the fix is lost at once (not after the receiver's silence
    timeout) and the base stops driving; the MCU, on its own cable, answers throughout.
    Back in: the port reopens, the fix returns, and the base drives on."""
    link, sim = husky.link, husky.sim
    port = vehicle_port(link, (*RIG_HOME, 0.0))
    husky.link.wait_command(link.arm(), 5.0, idle=husky.tick, poll_interval=0.0)
    to = geo.offset_gps(RIG_HOME[0], RIG_HOME[1], 40.0, 0.0)
    link.goto(*to, 0.0)
    assert husky.run_until(lambda: sim.drive.moving, 5.0)
    link.drain_events()
    husky.unplug("gps")
    husky.tick()
    texts = [(e.kind, e.text) for e in link.drain_events()]
    assert texts[0][0] == "link" and re.fullmatch(
        rf"GPS port {re.escape(husky.gps.path)} lost \(read failed: .+\); reopening: no fix "
        r"meanwhile, the base stops",
        texts[0][1],
    )
    assert texts[1][0] == "gps"
    assert texts[1][1].startswith(f"{husky.gps.path}: fix lost (port lost: read failed: ")
    assert not link.gps.has_fix and link.telemetry.gps_fix_type <= 1
    assert link.wheel_command == (0.0, 0.0)
    assert husky.run_until(lambda: not sim.drive.moving, 3.0)
    husky.run_until(lambda: False, 3.0)
    assert not link.heartbeat_lost  # the MCU answered all along
    health = port.link_health(husky.now)  # type: ignore[attr-defined]
    assert health.down_for_s is not None and health.down_for_s > 2.9 and health.outages == 1
    husky.plug("gps")
    assert husky.run_until(lambda: link.gps.has_fix, 3.0)
    texts = [e.text for e in link.drain_events() if e.kind in ("reopened", "gps")]
    assert re.fullmatch(rf"GPS port {re.escape(husky.gps.path)} back after [\d.]+ s", texts[0])
    assert re.search(r"fix \(3D", texts[1]), texts
    assert husky.run_until(lambda: sim.drive.moving, 3.0)  # on to its target
    health = port.link_health(husky.now)  # type: ignore[attr-defined]
    assert health.down_for_s is None and health.outages == 1 and health.down_s > 3.0
