"""The node's unit says MemoryDenyWriteExecute=yes: no memory both writable and executable.
Without systemd as PID 1 the unit cannot run here, but the kernel has the same rule of its
own (prctl PR_SET_MDWE, Linux 6.3; systemd 254 and later use it for this very setting): a
node started under it must fly, numpy, scipy, cryptography and ctypes included. Where this
test may make namespaces (root), the node also gets the unit's view of /proc
(ProtectProc=invisible, ProcSubset=pid: its own processes, no /proc/cpuinfo and the like).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from rigs import pty_vehicle

from .kit import HELLO

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


#: Runs its arguments with /proc as the unit has it, in a mount and pid namespace.
PROC_AS_THE_UNIT = [
    "unshare", "--mount", "--pid", "--fork", "sh", "-c",
    'mount -t proc -o subset=pid,hidepid=invisible proc /proc && test ! -e /proc/cpuinfo '
    '&& exec "$@"', "sh",
]  # fmt: skip


def proc_as_the_unit() -> list[str]:
    """PROC_AS_THE_UNIT where this machine lets the test make namespaces, else nothing."""
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        return []
    probe = subprocess.run([*PROC_AS_THE_UNIT, "true"], capture_output=True, check=False)
    return PROC_AS_THE_UNIT if probe.returncode == 0 else []


def test_the_node_flies_under_memory_deny_write_execute(tmp_path: Path, kernel_mdwe: None) -> None:
    """A node against a simulated ArduPilot on a pty, its script and its summary."""
    with pty_vehicle() as port:
        node = [sys.executable, "-m", "fieldkit", "node", "--profile", "solo", "--script",
                str(HELLO), "--autopilot", port, "--radio", "none", "--robot-id", "1",
                "--seconds", "1", "--out", str(tmp_path / "out")]  # fmt: skip
        argv = proc_as_the_unit() + mdwe(*node)
        done = subprocess.run(argv, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["ticks"] >= 1


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
    done = subprocess.run(argv, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "v1.patch").stat().st_size > 0
