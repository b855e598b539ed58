"""kill -9 a real `fieldkit node` at points of an over-the-air update; it restarts whole.

Each round: a fresh state directory, a `fieldkit node` on it (a simulated ArduPilot on a
pty, the UDP radio), and a ground station (`OperatorSession`) on its own UDP socket serving
a real signed patch. The test waits for the node to log a point of the update (pulling,
verified, standing by, switched, rolled back), SIGKILLs it, and starts `fieldkit node` again
on the same state directory: it must say it runs the old or the new version (the new one
once it has said it switched), and the store must hold that version whole and verified.

Nothing waits on time: the test waits for lines, each wait with a generous hang guard.
"""

from __future__ import annotations

import queue
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from rigs import pty_vehicle

import bvm
from fieldkit.radio.udp import UdpRadio
from fieldkit.update.keys import init_keys, load_robot_keys, load_signing_key
from fieldkit.update.operator import GROUND_ID, OperatorSession
from fieldkit.update.patch import make_update
from fieldkit.update.release import Release
from fieldkit.update.store import VersionStore
from fieldkit.vehicle.sim.ardupilot import DEFAULT_HOME

#: A wait this long for a line means the node hangs (a hang guard, not a timing).
HANG_S = 120.0

V0 = 'function init() { log("version zero") }\nfunction step() { x = 0 }\n'
V1 = 'function init() { log("version one") }\nfunction step() { x = 1 }\n'

RUNNING = re.compile(r"robot 1: running version (\d+) \(([0-9a-f]{12})…\)")


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class NodeProcess:
    """A `fieldkit node` child, its output lines in a queue (read by a thread)."""

    def __init__(self, argv: list[str]) -> None:
        self.proc = subprocess.Popen(
            argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        self.lines: queue.Queue[str | None] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.put(line.rstrip("\n"))
        self.lines.put(None)

    def wait_for(self, pattern: str) -> re.Match[str]:
        """The first line from now matching `pattern` (fails if the node ends first)."""
        while True:
            try:
                line = self.lines.get(timeout=HANG_S)
            except queue.Empty:
                raise AssertionError(f"no {pattern!r} in {HANG_S:g} s: {self.seen[-10:]}") from None
            if line is None:
                raise AssertionError(f"the node ended before {pattern!r}: {self.seen[-20:]}")
            self.seen.append(line)
            m = re.search(pattern, line)
            if m:
                return m

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
        self.proc.wait(timeout=HANG_S)


class Ground(threading.Thread):
    """The operator's radio: an `OperatorSession` stepped 10 times a second on UDP."""

    def __init__(self, session: OperatorSession, port: int, node_port: int) -> None:
        super().__init__(daemon=True)
        self.session = session
        self.radio = UdpRadio(
            GROUND_ID, port=port, group="127.0.0.1", peers=[("127.0.0.1", node_port)]
        )
        self.stop = threading.Event()
        self.rollback = threading.Event()  # order the rollback of version 1 (once)

    def run(self) -> None:
        tick = 0
        while not self.stop.wait(0.1):  # the radio's pace, like the node's loop
            if self.rollback.is_set() and self.session.rollback_of is None:
                self.session.order_rollback(1)
            frame = self.session.step(tick, [data for _, data in self.radio.poll()])
            if frame is not None:
                self.radio.send(frame)
            tick += 1

    def close(self) -> None:
        self.stop.set()
        self.join(timeout=HANG_S)
        self.radio.close()


@pytest.fixture(scope="module")
def kit(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    """Keys (the robot's copy holds no signing key), version 0's script, the patch to 1."""
    root = tmp_path_factory.mktemp("kit")
    init_keys(root / "keys")
    robot = root / "robot-keys"
    robot.mkdir()
    for name in ("operator.pub", "swarm.key"):
        shutil.copy(root / "keys" / name, robot / name)
        (robot / name).chmod(0o600)
    script = root / "v0.bzz"
    script.write_text(V0)
    base = Release.from_program(bvm.compile_file(script))
    new = Release.from_program(bvm.compile_source(V1, "v1.bzz"))
    swarm_key = load_robot_keys(robot).swarm_key
    patch = make_update(base, new, 1, load_signing_key(root / "keys"), swarm_key)
    return {"script": script, "robot_keys": robot, "swarm_key": swarm_key, "base": base,
            "new": new, "patch": patch}  # fmt: skip


def node_argv(
    state: Path, keys: Path, script: Path, autopilot: str, port: int, ground: int
) -> list[str]:
    return [
        sys.executable, "-m", "fieldkit", "node", "--profile", "solo", "--robot-id", "1",
        "--script", str(script), "--autopilot", autopilot,
        "--radio", f"udp://127.0.0.1:{port}?peers=127.0.0.1:{ground}",
        "--state-dir", str(state), "--keys", str(keys),
    ]  # fmt: skip


#: (the line to kill the node after, the versions it may restart on).
POINTS = [
    ("pulling version 1", {0, 1}),
    (r"version 1 \(\w+\) received and verified", {0, 1}),
    ("standing by for version 1", {0, 1}),
    ("switched to version 1", {1}),  # committed before the line is written
    ("rolled back from version 1 to 0", {0}),
]


@pytest.mark.parametrize(
    ("point", "allowed"), POINTS, ids=["pull", "verify", "standby", "switch", "rollback"]
)
def test_kill_9_during_an_update_restarts_on_a_whole_version(
    tmp_path: Path, kit: dict[str, object], point: str, allowed: set[int]
) -> None:
    base, new = kit["base"], kit["new"]
    assert isinstance(base, Release) and isinstance(new, Release)
    state, keys, script = tmp_path / "state", kit["robot_keys"], kit["script"]
    assert isinstance(keys, Path) and isinstance(script, Path)
    port, ground_port = free_port(), free_port()
    session = OperatorSession(kit["swarm_key"])  # type: ignore[arg-type]
    session.send(kit["patch"], 1, base.hash)  # type: ignore[arg-type]
    ground = Ground(session, ground_port, port)
    ground.start()
    try:
        with pty_vehicle(DEFAULT_HOME) as autopilot:
            node = NodeProcess(node_argv(state, keys, script, autopilot, port, ground_port))
            try:
                if point.startswith("rolled back"):
                    node.wait_for("switched to version 1")
                    ground.rollback.set()
                node.wait_for(point)
            finally:
                node.kill()  # SIGKILL: no destroy(), no summary, no clean anything
            again = NodeProcess(node_argv(state, keys, script, autopilot, port, ground_port))
            try:
                m = again.wait_for(RUNNING.pattern)
            finally:
                again.kill()
    finally:
        ground.close()
    version = int(m.group(1))
    assert version in allowed, (point, node.seen[-5:])
    c = VersionStore(state).committed()  # re-hashes the release
    assert c is not None and c.version == version and c.hash.startswith(m.group(2))
    # Whole: the old release or the new one, every file of it, never a mix.
    assert VersionStore(state).get(c.hash) == (base if version == 0 else new)
    if point.startswith("rolled back"):
        assert 1 in c.bad  # and it never goes back to it
