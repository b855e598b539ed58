"""The originator's outbox (`fieldkit node --update-outbox FILE`): a patch the update monitor
writes there is verified by the node and spread to the swarm; a damaged one is logged once
and ignored; the recorded originator's flight replays with --verify.

The outbox itself is tested on real files first. Then two real `fieldkit node` processes
(simulated ArduPilots on ptys, the UDP radio between them, a state directory and the robot's
keys each): robot 1 looks at its outbox, robot 2 only hears robot 1. The patch is made by
`fieldkit update --patch-out`, as the update monitor makes it, and renamed into the outbox as
the monitor writes it. Nothing waits on time: the test waits for the nodes' lines, each wait
with a generous hang guard.
"""

from __future__ import annotations

import os
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
from typer.testing import CliRunner

from fieldkit.cli import app
from fieldkit.node.outbox import OUTBOX_MAX_BYTES, Outbox, RecordedOutbox
from fieldkit.update.keys import init_keys
from fieldkit.update.store import VersionStore
from fieldkit.vehicle.sim.ardupilot import DEFAULT_HOME

runner = CliRunner()

#: A wait this long for a line means the node hangs (a hang guard, not a timing).
HANG_S = 120.0

V0 = 'function init() { log("version zero") }\nfunction step() { x = 0 }\n'
V1 = 'function init() { log("version one") }\nfunction step() { x = 1 }\n'


def put(path: Path, data: bytes) -> None:
    """Write `path` as the update monitor does: whole, then renamed into place."""
    staged = path.with_name(path.name + ".tmp")
    staged.write_bytes(data)
    os.replace(staged, path)


# ---------------------------------------------------------------- the outbox, real files


def test_the_outbox_reads_a_file_once_per_change_at_its_ticks(tmp_path: Path) -> None:
    lines: list[str] = []
    path = tmp_path / "update.patch"
    box = Outbox(path, lines.append, every=10)
    assert box.poll(0) is None  # no file yet
    put(path, b"first")
    assert box.poll(5) is None  # not a tick to look at
    assert box.poll(10) == b"first"
    assert box.poll(20) is None and box.poll(30) is None  # the same file: only a stat
    put(path, b"first")  # the same bytes, renamed in again: a new patch file
    assert box.poll(40) == b"first"
    put(path, b"second")
    assert box.poll(50) == b"second"
    path.unlink()
    assert box.poll(60) is None
    put(path, b"second")  # back after being removed: new again
    assert box.poll(70) == b"second"
    assert box.reads == 4 and lines == []


def test_a_file_too_large_for_a_patch_is_said_once_and_not_read(tmp_path: Path) -> None:
    lines: list[str] = []
    path = tmp_path / "update.patch"
    put(path, bytes(OUTBOX_MAX_BYTES + 1))
    box = Outbox(path, lines.append, every=1)
    assert [box.poll(t) for t in range(5)] == [None] * 5
    assert lines == [f"outbox {path}: {OUTBOX_MAX_BYTES + 1} bytes, more than any patch: not read"]
    put(path, b"a patch")
    assert box.poll(5) == b"a patch"


def test_a_recorded_outbox_gives_each_patch_at_its_tick() -> None:
    box = RecordedOutbox({4: [b"p"], 9: [b"q"], 12: []})
    assert [box.poll(t) for t in range(14)] == [None] * 4 + [b"p"] + [None] * 4 + [b"q"] + [
        None
    ] * 4


# ---------------------------------------------------------------- two real nodes


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

    def stop(self) -> int:
        """SIGTERM (the service's stop), then the rest of its lines; its exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        code = self.proc.wait(timeout=HANG_S)
        while (line := self.lines.get(timeout=HANG_S)) is not None:
            self.seen.append(line)
        return code

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(timeout=HANG_S)


@pytest.fixture(scope="module")
def kit(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The operator's keys, the robots' copy (no signing key), version 0 as the robots seed
    it and as the monitor's base, and the patch to version 1 made by `fieldkit update`."""
    root = tmp_path_factory.mktemp("kit")
    keys = root / "keys"
    init_keys(keys)
    robot = root / "robot-keys"
    robot.mkdir()
    for name in ("operator.pub", "swarm.key"):
        shutil.copy(keys / name, robot / name)
        (robot / name).chmod(0o600)
    v0, v1 = root / "v0.bzz", root / "v1.bzz"
    v0.write_text(V0)
    v1.write_text(V1)
    base = root / "outbox" / "update.bo"
    base.parent.mkdir()
    done = runner.invoke(app, ["compile", str(v0), "-o", str(base)])
    assert done.exit_code == 0, done.output
    made = root / "outbox" / "made.patch"
    done = runner.invoke(app, ["update", str(v1), "--keys", str(keys), "--patch-out", str(made),
                               "--base", str(base)])  # fmt: skip
    assert done.exit_code == 0, done.output
    return {"robot_keys": robot, "v0": v0, "patch": made}


def node_argv(
    rid: int, state: Path, kit: dict[str, Path], autopilot: str, port: int, peer: int
) -> list[str]:
    return [
        sys.executable, "-m", "fieldkit", "node", "--profile", "solo", "--robot-id", str(rid),
        "--script", str(kit["v0"]), "--autopilot", autopilot,
        "--radio", f"udp://127.0.0.1:{port}?peers=127.0.0.1:{peer}",
        "--state-dir", str(state), "--keys", str(kit["robot_keys"]),
    ]  # fmt: skip


def test_a_patch_in_the_outbox_reaches_the_swarm_and_the_flight_replays(
    tmp_path: Path, kit: dict[str, Path]
) -> None:
    """A damaged patch first: refused once, with the reason, the node flying on. Then the
    real one: robot 1 verifies it, robot 2 pulls it over the radio, both switch; robot 1's
    recording replays identically with the robots' keys."""
    outbox, bag = tmp_path / "outbox" / "update.patch", tmp_path / "flight"
    outbox.parent.mkdir()
    good = kit["patch"].read_bytes()
    damaged = bytearray(good)
    damaged[len(damaged) // 2] ^= 0xFF
    p1, p2 = free_port(), free_port()
    nodes: list[NodeProcess] = []
    try:
        with pty_vehicle(DEFAULT_HOME) as ap1, pty_vehicle(DEFAULT_HOME) as ap2:
            one = NodeProcess(
                node_argv(1, tmp_path / "s1", kit, ap1, p1, p2)
                + ["--update-outbox", str(outbox), "--record", str(bag)]
            )
            nodes.append(one)
            two = NodeProcess(node_argv(2, tmp_path / "s2", kit, ap2, p2, p1))
            nodes.append(two)
            one.wait_for("robot 1: version zero")
            one.wait_for(rf"robot 1: update outbox: {re.escape(str(outbox))}")
            two.wait_for("robot 2: version zero")
            put(outbox, bytes(damaged))
            one.wait_for(rf"outbox {re.escape(str(outbox))}: a new patch \({len(good)} bytes\)")
            refused = one.wait_for(r"robot 1: patch refused \(([\w-]+)\): (.+)")
            assert refused.group(1) in ("bad-signature", "bad-body", "bad-decrypt")
            put(outbox, good)
            one.wait_for(r"robot 1: version 1 \(\w+\) made here and verified")
            two.wait_for(r"robot 2: pulling version 1")
            two.wait_for(r"robot 2: version 1 \(\w+\) received and verified")
            one.wait_for(r"robot 1: switched to version 1")
            two.wait_for(r"robot 2: switched to version 1")
            assert one.stop() == 0 and two.stop() == 0
    finally:
        for n in nodes:
            n.kill()
    # The new version's init() ran on both (it logs before the switch is said).
    assert any(line.endswith("robot 1: version one") for line in one.seen)
    assert any(line.endswith("robot 2: version one") for line in two.seen)
    # Refused once: the file was looked at again every second, but not read again.
    assert sum("patch refused" in line for line in one.seen) == 1
    assert sum(": a new patch (" in line for line in one.seen) == 2
    for state in (tmp_path / "s1", tmp_path / "s2"):
        committed = VersionStore(state).committed()
        assert committed is not None and committed.version == 1
    # The patch is an input of the tick that read it: a replay hands it back there.
    result = runner.invoke(app, ["bag", "info", str(bag)])
    assert re.search(r"/update/outbox\s+2 msgs", result.stdout), result.stdout
    result = runner.invoke(
        app, ["replay", str(bag), "--verify", "--speed", "max", "--keys", str(kit["robot_keys"])]
    )
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines()[-1].startswith("replay: identical: ")


def test_the_outbox_needs_the_update_agent(tmp_path: Path, kit: dict[str, Path]) -> None:
    result = runner.invoke(app, ["node", "--profile", "solo", "--robot-id", "1", "--radio",
                                 "none", "--script", str(kit["v0"]), "--update-outbox",
                                 str(tmp_path / "update.patch")])  # fmt: skip
    assert result.exit_code == 1, result.output
    assert result.stderr.startswith(
        f"error: --update-outbox {tmp_path / 'update.patch'}: originating updates needs the "
        "update agent\nhint: give --state-dir DIR and --keys DIR too"
    )
