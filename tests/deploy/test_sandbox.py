"""The node as its unit runs it, as near as a machine whose PID 1 is not systemd allows.

- MemoryDenyWriteExecute=yes: no memory both writable and executable. The kernel has the same
  rule of its own (prctl PR_SET_MDWE, Linux 6.3; systemd 254 and later use it for this very
  setting): the node, and the update pipeline, must run under it, numpy, scipy,
  cryptography and ctypes included.
- ProtectProc=invisible, ProcSubset=pid: /proc with its own processes only, no /proc/cpuinfo
  and the like (a mount of /proc with those options, in namespaces of the test's own).
- The files deploy staged under --root, put where the robot has them (overlay mounts in a
  mount namespace: /etc read-only, /var writable), run by the unit's own ExecStart= under
  the notify protocol.

The last two need root (CI runs as root); the first runs anywhere the kernel has the rule.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from rigs import pty_husky, pty_vehicle

from .kit import HELLO, deploy, dji_app_key, m100

#: prctl(PR_SET_MDWE, PR_MDWE_REFUSE_EXEC_GAIN): from linux/prctl.h.
PR_SET_MDWE = 65
PR_MDWE_REFUSE_EXEC_GAIN = 1

#: Runs its arguments under the rule (inherited across fork and exec), as systemd does.
LAUNCHER = f"""
import ctypes, os, sys
libc = ctypes.CDLL(None, use_errno=True)
if libc.prctl({PR_SET_MDWE}, {PR_MDWE_REFUSE_EXEC_GAIN}, 0, 0, 0) != 0:
    sys.exit("prctl: " + os.strerror(ctypes.get_errno()))
os.execv(sys.argv[1], sys.argv[1:])
"""

#: What the rule forbids: a mapping writable and executable at once.
PROBE = """
import mmap
try:
    mmap.mmap(-1, 4096, prot=mmap.PROT_READ | mmap.PROT_WRITE | mmap.PROT_EXEC)
except OSError:
    print("refused")
else:
    print("allowed")
"""


def mdwe(*argv: str) -> list[str]:
    """`argv` run under memory-deny-write-execute."""
    return [sys.executable, "-c", LAUNCHER, *argv]


@pytest.fixture(scope="module")
def kernel_mdwe() -> None:
    """Skip where the kernel has no PR_SET_MDWE (before Linux 6.3)."""
    probe = subprocess.run(mdwe(sys.executable, "-c", PROBE), capture_output=True, text=True,
                           check=False)  # fmt: skip
    if probe.returncode != 0:
        pytest.skip(f"this kernel ({os.uname().release}) has no PR_SET_MDWE: {probe.stderr}")
    assert probe.stdout.strip() == "refused"  # the rule is in force for the child


def namespaces() -> bool:
    """Whether this test may make mount and pid namespaces (root, with unshare)."""
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        return False
    probe = ["unshare", "--mount", "--pid", "--fork", "true"]
    return subprocess.run(probe, capture_output=True, check=False).returncode == 0


def as_the_unit(root: Path | None, work: Path) -> list[str]:
    """A prefix that runs its arguments in mount and pid namespaces of their own, with /proc
    as the unit shows it and, given a staged `root`, root/etc over /etc (read-only) and
    root/var over /var (writable: what the node writes lands back in root/var)."""
    mounts = []
    if root is not None:
        mounts += [
            f"mount -t overlay overlay -o lowerdir={root}/etc:/etc /etc",
            f"mount -t overlay overlay -o lowerdir=/var,upperdir={root}/var,workdir={work} /var",
        ]
    mounts += [
        "mount -t proc -o subset=pid,hidepid=invisible proc /proc",
        "test ! -e /proc/cpuinfo",
    ]
    script = " && ".join([*mounts, 'exec "$@"'])
    return ["unshare", "--mount", "--pid", "--fork", "sh", "-c", script, "sh"]


def test_the_node_flies_under_memory_deny_write_execute(tmp_path: Path, kernel_mdwe: None) -> None:
    """A node against a simulated ArduPilot on a pty, its script and its summary (where the
    test may make namespaces, the next test runs the node this way and more: not twice)."""
    if namespaces():
        pytest.skip("test_the_deployed_files_run_the_node runs the node under this rule too")
    with pty_vehicle() as port:
        node = [sys.executable, "-m", "fieldkit", "node", "--profile", "solo", "--script",
                str(HELLO), "--autopilot", port, "--radio", "none", "--robot-id", "1",
                "--seconds", "1", "--out", str(tmp_path / "out")]  # fmt: skip
        done = subprocess.run(mdwe(*node), capture_output=True, text=True, timeout=120,
                              check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["ticks"] >= 1


@contextmanager
def robot_on_ptys(name: str, tmp_path: Path) -> Iterator[tuple[str, ...]]:
    """A simulated robot on ptys, stepped in real time: yields the deploy options that
    point the node at it (a Solo's ArduPilot; a Husky's MCU and GPS receiver; an M100's
    flight controller, with the test app's key file)."""
    if name == "husky":
        with pty_husky() as (mcu, gps, _):
            yield ("--profile", "husky", "--robot-id", "1", "--autopilot", mcu, "--gps", gps)
        return
    if name == "m100":
        from fieldkit.robot.profiles import load_profile
        from fieldkit.vehicle.pty import open_pty
        from fieldkit.vehicle.sim.dji_vehicle import SimM100Vehicle

        pty = open_pty()
        fc = SimM100Vehicle(load_profile("m100"), pty.master, home=(45.5049, -73.6133))
        stop = threading.Event()
        thread = threading.Thread(target=fc.run, args=(50.0, stop), daemon=True)
        thread.start()
        try:
            options = list(m100(dji_app_key(tmp_path), "--autopilot", pty.slave_path))
            options[options.index("--robot-id") + 1] = "1"  # the robot the test expects
            yield tuple(options)
        finally:
            stop.set()
            thread.join()
            fc.close()
            pty.close()
        return
    with pty_vehicle() as port:
        yield ("--profile", "solo", "--robot-id", "1", "--autopilot", port)


@pytest.mark.parametrize("name", ["solo", "husky", "m100"])
def test_the_deployed_files_run_the_node(tmp_path: Path, kernel_mdwe: None, name: str) -> None:
    """What deploy staged, where the robot has it, run by its unit's ExecStart= under the
    notify protocol, memory-deny-write-execute and the unit's /proc: READY=1, the script
    seeded into the state directory, the flight recorded under /var/log/fieldkit. The Husky
    opens its MCU and its GPS receiver; the M100 is activated with the app key deploy
    installed in /etc/fieldkit."""
    if not namespaces():
        pytest.skip("needs root and unshare to put the staged files where the robot has them")
    root, work = tmp_path / "root", tmp_path / "overlay-work"
    work.mkdir()
    with robot_on_ptys(name, tmp_path) as options:
        result = deploy(*options, "--root", root, "--script", HELLO, "--radio", "none")
        assert result.exit_code == 0, result.output
        unit = (root / "etc/systemd/system/fieldkit-node.service").read_text()
        (exec_start,) = [x for x in unit.splitlines() if x.startswith("ExecStart=")]
        argv = exec_start.removeprefix("ExecStart=").split()
        notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        notify.bind(str(tmp_path / "notify"))
        env = {**os.environ, "NOTIFY_SOCKET": str(tmp_path / "notify")}
        command = [*as_the_unit(root, work), *mdwe(*argv, "--seconds", "1")]
        done = subprocess.run(command, capture_output=True, text=True, env=env, timeout=120,
                              check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr + done.stdout
    notify.setblocking(False)
    said = []
    while True:
        try:
            said += notify.recv(65536).decode().split("\n")
        except BlockingIOError:
            break
    assert "READY=1" in said, said
    assert "robot 1: hello from robot 1" in done.stdout
    assert any((root / "var/lib/fieldkit/state").iterdir())
    assert list((root / "var/log/fieldkit").glob("flight-*")), done.stderr


def test_the_update_pipeline_runs_under_memory_deny_write_execute(
    tmp_path: Path, keys: Path, kernel_mdwe: None
) -> None:
    """What the update monitor's unit runs: compile, a trial in the simulator (numpy,
    scipy), sign and encrypt (cryptography)."""
    base = tmp_path / "v0.bo"
    compiled = [sys.executable, "-m", "fieldkit", "compile", str(HELLO), "-o", str(base)]
    assert subprocess.run(compiled, capture_output=True, check=False).returncode == 0
    new = tmp_path / "v1.bzz"
    new.write_text(HELLO.read_text() + "\nfunction extra() { return 1 }\n")
    argv = mdwe(sys.executable, "-m", "fieldkit", "update", str(new), "--keys", str(keys),
                "--base", str(base), "--patch-out", str(tmp_path / "v1.patch"))  # fmt: skip
    prefix = as_the_unit(None, tmp_path) if namespaces() else []
    done = subprocess.run([*prefix, *argv], capture_output=True, text=True, timeout=120,
                          check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "v1.patch").stat().st_size > 0
