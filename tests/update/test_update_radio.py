"""`fieldkit update --radio` and `--rollback`: the operator's laptop against real nodes.

Two `fieldkit node` processes (each with its simulated ArduPilot on a pty, and UDP radios on
the loopback broadcast) run with `--state-dir` and `--keys`; `fieldkit update` runs as the
operator would, in its own process, on the same radio. Nothing waits on the clock: each
step waits for the command's exit, with hang guards only.
"""

from __future__ import annotations

import json
import os
import random
import subprocess
import sys
from collections.abc import Iterator
from contextlib import ExitStack
from pathlib import Path

import pytest
from rigs import pty_vehicle

from fieldkit.update.keys import init_keys
from fieldkit.update.release import Release
from fieldkit.update.store import VersionStore

V0 = 'function init() { log("v0") }\nfunction step() { x = 0 }\n'
V1 = 'function init() { log("v1 running") }\nfunction step() { x = 1 }\n'
HANG_GUARD_S = 300


@pytest.fixture
def vehicles() -> Iterator[list[str]]:
    """Two simulated ArduPilots on ptys, GPS fixed, in real time: the ptys' paths."""
    with ExitStack() as stack:
        yield [stack.enter_context(pty_vehicle((45.5017 + k * 1e-5, -73.5673))) for k in range(2)]


def fieldkit(*args: object) -> list[str]:
    return [sys.executable, "-m", "fieldkit", *(str(a) for a in args)]


def test_the_operator_updates_a_live_swarm_and_rolls_it_back(
    tmp_path: Path, vehicles: list[str]
) -> None:
    keys = init_keys(tmp_path / "keys").directory
    robot_keys = tmp_path / "robot-keys"
    robot_keys.mkdir()
    for name in ("operator.pub", "swarm.key"):
        (robot_keys / name).write_bytes((keys / name).read_bytes())
        (robot_keys / name).chmod(0o600)
    v0, v1 = tmp_path / "v0.bzz", tmp_path / "v1.bzz"
    v0.write_text(V0)
    v1.write_text(V1)
    url = f"udp://127.255.255.255:{random.Random(os.getpid()).randrange(30000, 60000)}"
    nodes = [
        subprocess.Popen(
            fieldkit(
                "node",
                "--robot-id",
                k + 1,
                "--profile",
                "solo",
                "--script",
                v0,
                "--autopilot",
                path,
                "--radio",
                url,
                "--seconds",
                240,
                "--state-dir",
                tmp_path / f"state{k + 1}",
                "--keys",
                robot_keys,
            ),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )  # fmt: skip
        for k, path in enumerate(vehicles)
    ]
    try:
        up = subprocess.run(
            fieldkit("update", v1, "--keys", keys, "--radio", url, "--base", v0, "--timeout", 200),
            capture_output=True, text=True, timeout=HANG_GUARD_S,
        )  # fmt: skip
        assert up.returncode == 0, up.stdout + up.stderr
        assert "all 2 robots run version 1" in up.stdout
        new_hash = Release.read(next((keys / "releases").glob("*.bo"))).hash
        # The next update needs no --base: the laptop kept what it sent.
        back = subprocess.run(
            fieldkit("update", "--rollback", "--keys", keys, "--radio", url, "--timeout", 200),
            capture_output=True, text=True, timeout=HANG_GUARD_S,
        )  # fmt: skip
        assert back.returncode == 0, back.stdout + back.stderr
        assert "left version 1" in back.stdout
    finally:
        for p in nodes:
            p.terminate()
        outputs = [p.communicate(timeout=HANG_GUARD_S)[0] for p in nodes]
    for k, text in enumerate(outputs):
        assert "v1 running" in text, text
        assert "rolled back from version 1 to 0" in text, text
        store = VersionStore(tmp_path / f"state{k + 1}")
        committed = store.committed()
        assert committed is not None and committed.version == 0 and 1 in committed.bad
        assert store.has(new_hash)
        events = [e["event"] for e in store.history()]
        assert "committed" in events and "rolled-back" in events
    summary_lines = [json.dumps(e) for e in VersionStore(tmp_path / "state1").history()]
    assert any("operator" in line for line in summary_lines)


def test_update_radio_says_so_when_no_robot_answers(tmp_path: Path) -> None:
    keys = init_keys(tmp_path / "keys").directory
    v1 = tmp_path / "v1.bzz"
    v1.write_text(V1)
    url = f"udp://127.255.255.255:{random.Random(os.getpid() + 1).randrange(30000, 60000)}"
    r = subprocess.run(
        fieldkit("update", v1, "--keys", keys, "--radio", url),
        capture_output=True, text=True, timeout=HANG_GUARD_S,
    )  # fmt: skip
    assert r.returncode == 1
    assert "error: no robot heard on" in r.stderr and "Traceback" not in r.stderr
    assert not (keys / "releases").exists()
