"""The M100 end to end as the field runs it: `fieldkit vehicle-sim --profile m100` (the simulated
flight controller on a pty) and `fieldkit node --config FILE` flying a script on it, the
developer's app id and key from the config's `[dji]` table, never from a command line.

Nothing waits on time: the test reads the node's output until what it waits for shows (with a
deadline as a hang guard only), then stops the processes by signal.
"""

from __future__ import annotations

import json
import select
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from rigs.flights import FLY_NORTH, NORTH, field_env
from rigs.lines import Lines

from fieldkit.vehicle.sim.dji import TEST_APP_ID, TEST_APP_KEY

HOME = (45.5049, -73.6133)


@pytest.fixture
def m100_sim(tmp_path: Path) -> Iterator[str]:
    """`fieldkit vehicle-sim --profile m100` on a new pty (the test app id and key): its path."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "vehicle-sim", "--profile", "m100",
         "--gps-delay", "0", "--home", f"{HOME[0]},{HOME[1]}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=field_env(),
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        ready, _, _ = select.select([proc.stdout], [], [], 30.0)
        assert ready, "no pty path printed"
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/")
        yield path
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _config(tmp_path: Path, autopilot: str, dji: str) -> Path:
    script = tmp_path / "fly.bzz"
    script.write_text(FLY_NORTH.replace("BROKEN == 1", "0 == 1"))
    config = tmp_path / "fieldkit.toml"
    config.write_text(
        f'[node]\nprofile = "m100"\nrobot_id = 1\nscript = "{script}"\n'
        f'autopilot = "{autopilot}"\nradio = "none"\ncommand = ["0:1:22"]\n'
        f'out = "{tmp_path / "o"}"\n\n[dji]\n{dji}'
    )
    return config


def test_fieldkit_node_flies_the_m100_with_the_app_from_its_config(
    tmp_path: Path, m100_sim: str
) -> None:
    key_file = tmp_path / "dji-app-key"
    key_file.write_text(TEST_APP_KEY + "\n")
    key_file.chmod(0o600)
    config = _config(tmp_path, m100_sim, f'app_id = {TEST_APP_ID}\napp_key_file = "{key_file}"\n')
    node = subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "node", "--config", str(config)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path, env=field_env(),
    )  # fmt: skip
    try:
        lines = Lines(node)
        deadline = time.monotonic() + 120.0  # a hang guard: the flight takes about 15 s
        while True:
            m = lines.until(NORTH, deadline)
            assert m is not None, f"the node ended: {lines.seen[-5:]} {node.stderr.read()}"  # type: ignore[union-attr]
            north, alt = float(m.group(1)), float(m.group(2))
            if north > 9.0:
                break
        node.send_signal(signal.SIGTERM)
        _, err = node.communicate(timeout=60)
    finally:
        if node.poll() is None:
            node.kill()
            node.wait()
    assert node.returncode == 0, err
    assert alt > 0.9 * 3.0, alt  # in the air (TARGET_ALTITUDE is at least 3 m)
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["ticks"] > 0 and summary["robot_id"] == 1
    # The key is a secret: not in anything the node printed or wrote.
    for text in ["".join(lines.seen), err, (tmp_path / "o" / "summary.json").read_text()]:
        assert TEST_APP_KEY not in text and TEST_APP_KEY.upper() not in text


def test_an_m100_without_its_app_is_refused_before_flight(tmp_path: Path) -> None:
    config = _config(tmp_path, "/dev/null", "")
    config.write_text(config.read_text().replace("\n[dji]\n", ""))
    r = subprocess.run(
        [sys.executable, "-m", "fieldkit", "node", "--config", str(config)],
        capture_output=True, text=True, cwd=tmp_path, env=field_env(), timeout=120,
    )  # fmt: skip
    assert r.returncode == 1, r.stderr
    assert "error: m100: the DJI Onboard SDK needs the developer's app id and app key" in r.stderr
    assert "Traceback" not in r.stderr
