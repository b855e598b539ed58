"""The node as a systemd service, with real parts: a real NOTIFY_SOCKET (a Unix datagram
socket this test reads), the simulated ArduPilot on a pty, real signals to a real process.

Waits are for a line or a datagram, bounded only as hang guards; no assertion depends on
how fast this machine is.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from rigs import pty_vehicle

from fieldkit.node.daemon import Notifier, WatchdogPacer, watchdog_interval
from fieldkit.node.journal import ERR, INFO, WARNING, Journal, encode, priority_of
from fieldkit.node.log import NodeLog
from fieldkit.robot.profiles import load_profile
from fieldkit.vehicle.pty import open_pty

HANG_GUARD_S = 120.0

LOOPING = 'function init() { log("version A") }\nfunction step() { log("tick") }\n'


class NotifySocket:
    """A Unix datagram socket standing in for systemd's, read by a thread into a queue."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.messages: queue.Queue[list[str]] = queue.Queue()
        self.seen: list[list[str]] = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while True:
            try:
                data = self.sock.recv(65536)
            except OSError:
                return
            self.messages.put(data.decode().split("\n"))

    def wait_for(self, field: str, *also: str) -> list[list[str]]:
        """Every datagram up to and including the first holding `field` and fields
        starting with each of `also`."""
        got: list[list[str]] = []
        while True:
            fields = self.messages.get(timeout=HANG_GUARD_S)
            got.append(fields)
            self.seen.append(fields)
            if field in fields and all(any(f.startswith(a) for f in fields) for a in also):
                return got

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def notify(tmp_path: Path) -> Iterator[NotifySocket]:
    sock = NotifySocket(tmp_path / "notify.sock")
    yield sock
    sock.close()


def config(
    tmp_path: Path, vehicle: str, src: str = LOOPING, extra: str = "", profile: str = "solo"
) -> Path:
    script = tmp_path / "s.bzz"
    script.write_text(src)
    path = tmp_path / "fieldkit.toml"
    path.write_text(
        f'[node]\nprofile = "{profile}"\nrobot_id = 1\nscript = "s.bzz"\nautopilot = "{vehicle}"\n'
        f'radio = "none"\nout = "o"\n{extra}'
    )
    return path


def start(
    cfg: Path, notify: NotifySocket | None, *, watchdog_usec: int = 2_000_000
) -> subprocess.Popen[str]:
    env = dict(os.environ)
    if notify is not None:
        env |= {"NOTIFY_SOCKET": str(notify.path), "WATCHDOG_USEC": str(watchdog_usec)}
    return subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "node", "--config", str(cfg)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def read_until(proc: subprocess.Popen[str], ending: str) -> list[str]:
    assert proc.stdout is not None
    seen = []
    for line in proc.stdout:
        seen.append(line)
        if line.rstrip().endswith(ending):
            return seen
    raise AssertionError(f"ended before {ending!r}: {''.join(seen)}")


def finish(proc: subprocess.Popen[str]) -> tuple[str, str]:
    try:
        return proc.communicate(timeout=HANG_GUARD_S)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_ready_watchdog_status_then_a_safe_stop_on_sigterm(
    tmp_path: Path, notify: NotifySocket
) -> None:
    with pty_vehicle() as vehicle:
        recorded = '[record]\ndir = "bags"\nkeep_mb = 100\n'  # made by the node
        proc = start(config(tmp_path, vehicle, extra=recorded), notify)
        before_ready = notify.wait_for("READY=1")
        read_until(proc, "robot 1: tick")
        pings = notify.wait_for("WATCHDOG=1")  # the loop pings while it ticks
        proc.send_signal(signal.SIGTERM)
        stopping = notify.wait_for("STOPPING=1")
        out, err = finish(proc)
    # READY came once the heartbeat, the fix and the script were up: nothing else before.
    assert all("WATCHDOG=1" not in m for m in before_ready)
    assert any(f.startswith("STATUS=tick ") for m in before_ready + pings for f in m)
    assert any(f.startswith("STATUS=stopping") for m in stopping for f in m)
    assert proc.returncode == 0, err
    assert "Traceback" not in err
    assert "robot 1: stop: hold acknowledged by the autopilot" in out
    assert "robot 1: stopped by a signal: " in out
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["stop"] == {"action": "hold", "acknowledged": True}
    assert summary["ticks"] >= 1
    # The flight was recorded to a new bag under record.dir, and replays as it flew.
    (bag,) = (tmp_path / "bags").iterdir()
    assert bag.name.startswith("flight-")
    replayed = subprocess.run(
        [sys.executable, "-m", "fieldkit", "replay", str(bag), "--verify", "--speed", "max"],
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
    )
    assert replayed.returncode == 0, replayed.stdout + replayed.stderr
    assert f"{summary['ticks']} ticks" in replayed.stdout


def test_no_ready_without_a_heartbeat(tmp_path: Path, notify: NotifySocket) -> None:
    """Nothing answers on the autopilot's port: the node gives up, never having said READY."""
    pty = open_pty()
    try:
        cfg = config(tmp_path, pty.slave_path, extra="connect_timeout = 1\n")
        proc = start(cfg, notify)
        out, err = finish(proc)
    finally:
        pty.close()
    assert proc.returncode == 1 and "error: " in err
    assert notify.messages.empty()  # READY=1 never sent


def test_no_ready_without_a_gps_fix(tmp_path: Path, notify: NotifySocket) -> None:
    """A heartbeat but no fix within the profile's wait: exit 1, no READY."""
    from fieldkit.vehicle.sim.vehicle import SimVehicle

    solo = load_profile("solo").path
    assert solo is not None
    profile = tmp_path / "slow.toml"
    profile.write_text(
        solo.read_text().replace("gps_fix_timeout_s = 120.0", "gps_fix_timeout_s = 1.0")
    )
    pty = open_pty()
    sim = SimVehicle(load_profile("solo"), pty.master, gps_fix_delay_s=1e9)
    stop = threading.Event()
    thread = threading.Thread(target=sim.run, args=(50.0, stop), daemon=True)
    thread.start()
    try:
        cfg = config(tmp_path, pty.slave_path, extra="\n[node.x]\n")
        cfg.write_text(
            cfg.read_text()
            .replace('profile = "solo"', f'profile = "{profile}"')
            .replace("\n[node.x]\n", "")
        )
        proc = start(cfg, notify)
        out, err = finish(proc)
    finally:
        stop.set()
        thread.join()
        sim.close()
        pty.close()
    assert proc.returncode == 1 and "GPS" in err, err
    assert notify.messages.empty()


def test_sigterm_during_start_up_exits_0_having_ordered_nothing(tmp_path: Path) -> None:
    pty = open_pty()  # nothing answers: the node waits for a heartbeat
    try:
        proc = start(config(tmp_path, pty.slave_path), None)
        read_until(proc, "for a heartbeat on " + pty.slave_path)
        proc.send_signal(signal.SIGTERM)
        out, err = finish(proc)
    finally:
        pty.close()
    assert proc.returncode == 0, err
    assert "stopped by SIGTERM during start-up" in out and "Traceback" not in err


def test_sighup_refuses_a_bad_script_and_restarts_on_a_good_one(
    tmp_path: Path, notify: NotifySocket
) -> None:
    with pty_vehicle() as vehicle:
        cfg = config(tmp_path, vehicle)
        proc = start(cfg, notify)
        notify.wait_for("READY=1")
        read_until(proc, "robot 1: tick")
        (tmp_path / "s.bzz").write_text("function step() { x = }\n")  # does not compile
        proc.send_signal(signal.SIGHUP)
        refused = read_until(proc, "the node runs on unchanged:")
        read_until(proc, "robot 1: tick")  # it flies on
        (tmp_path / "s.bzz").write_text(LOOPING.replace("version A", "version B"))
        proc.send_signal(signal.SIGHUP)
        restart = read_until(proc, "robot 1: version B")  # the new process's init()
        # The restarted node is up, on the same socket.
        restarted = notify.wait_for("READY=1", "STATUS=tick 0")
        proc.send_signal(signal.SIGTERM)
        out, err = finish(proc)
    assert any("reload: checking the config and script" in line for line in refused)
    text = "".join(restart)
    assert "reload: restarting on the new settings" in text
    assert "stop: hold acknowledged by the autopilot" in text  # the old node stopped safely
    assert proc.returncode == 0, err
    assert "stopped by a signal" in out
    # The watchdog was widened for the restart's waits, and set back at its READY.
    widened = [int(f[14:]) for m in restarted[:-1] for f in m if f.startswith("WATCHDOG_USEC=")]
    assert widened and widened[-1] > 150_000_000  # 30 s heartbeat + 120 s fix + margin
    assert "WATCHDOG_USEC=2000000" in restarted[-1]


# --------------------------------------------------------------------- the parts, no process


def test_the_pacer_pings_at_most_every_quarter_interval() -> None:
    pacer = WatchdogPacer(2.0)
    times = [0.0, 0.1, 0.4, 0.5, 0.6, 1.05, 1.1, 5.0]
    assert [t for t in times if pacer.due(t)] == [0.0, 0.5, 1.05, 5.0]
    assert not WatchdogPacer(None).due(0.0)


def test_watchdog_interval_from_the_environment() -> None:
    assert watchdog_interval({"WATCHDOG_USEC": "5000000"}) == 5.0
    assert watchdog_interval({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": "1"}) is None
    pid = str(os.getpid())
    assert watchdog_interval({"WATCHDOG_USEC": "5000000", "WATCHDOG_PID": pid}) == 5.0
    assert watchdog_interval({"WATCHDOG_USEC": "x"}) is None
    assert watchdog_interval({}) is None


def test_notify_to_an_abstract_socket_and_to_none(tmp_path: Path) -> None:
    name = f"fieldkit-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    try:
        n = Notifier({"NOTIFY_SOCKET": "@" + name})
        assert n.send("READY=1", "STATUS=two\nlines")
        assert sock.recv(100) == b"READY=1\nSTATUS=two lines"
        n.close()
    finally:
        sock.close()
    quiet = Notifier({})
    assert not quiet.enabled and not quiet.send("READY=1")
    gone = Notifier({"NOTIFY_SOCKET": str(tmp_path / "nobody")})
    assert not gone.send("WATCHDOG=1") and gone.errors == 1  # counted, never raised


class CountingNotifier(Notifier):
    """A notifier that counts what it sent (to know what the socket should have got)."""

    sent = 0

    def send(self, *fields: str) -> bool:
        self.sent += 1
        return super().send(*fields)


def test_a_stalled_loop_sends_no_watchdog_ping(tmp_path: Path) -> None:
    """A tick that never completes never pings; when it completes, pings resume."""
    import bvm
    from fieldkit.node.autopilot_port import MavlinkAutopilot
    from fieldkit.node.node import Node
    from fieldkit.node.service import NodeService, ServiceSignals
    from fieldkit.vehicle.link import Autopilot

    sock = NotifySocket(tmp_path / "n.sock")
    profile = load_profile("solo")
    with pty_vehicle() as path, Autopilot.from_profile(profile, path) as link:
        link.wait_heartbeat(HANG_GUARD_S)
        link.wait_command(link.request_streams(10.0), HANG_GUARD_S)
        t = link.wait_position(HANG_GUARD_S)
        assert t.lat is not None and t.lon is not None
        home = (t.lat, t.lon, 0.0)
        notifier = CountingNotifier({"NOTIFY_SOCKET": str(sock.path), "WATCHDOG_USEC": "400000"})
        program = bvm.compile_source("function step() {}\n")
        node = Node(profile, program, 1, MavlinkAutopilot(link, home), None, home=home, out=print)
        release = threading.Event()
        stalled = threading.Event()
        poll = node.vehicle.poll

        sent_before_stall = []

        def stalling_poll() -> None:
            if node.runtime.ticks == 3 and not stalled.is_set():
                sent_before_stall.append(notifier.sent)
                stalled.set()
                release.wait(HANG_GUARD_S)
            poll()

        node.vehicle.poll = stalling_poll  # type: ignore[method-assign]
        service = NodeService(node, notifier, ServiceSignals(), lambda _: None)
        runner = threading.Thread(target=service.run, args=(None,), daemon=True)
        runner.start()
        try:
            assert stalled.wait(HANG_GUARD_S)
            # Everything sent before the stall, then nothing for 1 s (2.5 intervals).
            drained = [sock.messages.get(timeout=HANG_GUARD_S) for _ in range(sent_before_stall[0])]
            with pytest.raises(queue.Empty):  # stalled: 1 s (2.5 intervals) without a ping
                sock.messages.get(timeout=1.0)
            release.set()
            sock.wait_for("WATCHDOG=1")  # ticking again: pinging again
        finally:
            release.set()
            node.stop()
            runner.join(HANG_GUARD_S)
            sock.close()
    assert drained[0][:1] == ["READY=1"]


def test_journal_lines_carry_priority_and_fields(tmp_path: Path) -> None:
    path = tmp_path / "journal.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    try:
        log = NodeLog(4, journal=Journal("fieldkit-node", address=str(path)))
        log.tick = 17
        log("warning: low battery")
        first = sock.recv(4096)
        log("error: script error\n  in f")
        second = sock.recv(4096)
    finally:
        sock.close()
    assert first == encode(
        {
            "MESSAGE": "warning: low battery",
            "PRIORITY": "4",
            "SYSLOG_IDENTIFIER": "fieldkit-node",
            "ROBOT_ID": "4",
            "TICK": "17",
        }
    )
    # A multi-line message goes as KEY, newline, 64-bit length, the bytes.
    assert second.startswith(
        b"MESSAGE\n"
        + len(b"error: script error\n  in f").to_bytes(8, "little")
        + b"error: script error\n  in f\n"
    )
    assert b"PRIORITY=3\n" in second


def test_a_line_the_journal_refuses_goes_to_stdout_with_its_priority(tmp_path: Path) -> None:
    import io

    stream = io.StringIO()
    log = NodeLog(4, stream=stream, journal=Journal("x", address=str(tmp_path / "gone")))
    log("error: disk full")
    assert stream.getvalue().startswith("<3>[") and stream.getvalue().endswith(
        "robot 4: error: disk full\n"
    )
    assert [priority_of(t) for t in ("error: a", "warning: b", "tick")] == [ERR, WARNING, INFO]


@pytest.mark.parametrize(
    ("profile", "action", "mode"), [("husky", "stop", "HOLD"), ("solo", "land", "LAND")]
)
def test_the_stop_order_is_acknowledged_and_takes_effect(
    profile: str, action: str, mode: str
) -> None:
    """A ground robot stops in its hold mode; a UAV whose profile says land lands."""
    from fieldkit.node.service import stop_vehicle
    from fieldkit.vehicle.link import Autopilot

    lines: list[str] = []
    with (
        pty_vehicle(profile=profile) as path,
        Autopilot.from_profile(load_profile(profile), path) as link,
    ):
        link.wait_heartbeat(HANG_GUARD_S)
        result = stop_vehicle(link, action, lines.append)
        deadline = time.monotonic() + HANG_GUARD_S  # a hang guard: the mode follows the ACK
        while link.telemetry.mode != mode and time.monotonic() < deadline:
            link.poll(0.05)
    assert result.acknowledged and result.action == action
    assert lines == [f"stop: {action} acknowledged by the autopilot"]
