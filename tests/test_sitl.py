"""Software in the loop, end to end: real node processes, simulated ArduPilots on ptys, and
XBee frames through a relay that drops and corrupts them."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from fieldkit.cli import app
from fieldkit.robot.profiles import load_profile
from fieldkit.sitl import SitlConfig, run

ROOT = Path(__file__).resolve().parents[1]

GOSSIP = """
s = swarm.create(1)
v = stigmergy.create(1)
function init() { s.join()  BVMSTATE = "START"  heard = {} }
neighbors.listen("hi", function(topic, value, sender) { heard[sender] = value })
function step() {
  neighbors.broadcast("hi", id)
  v.put(id, 1)
  if (size(heard) == ROBOTS - 1 and ROBOTS == 3 and v.size() == 3) BVMSTATE = "ALL"
}
"""


def test_three_nodes_exchange_bundles_over_a_lossy_corrupting_relay(tmp_path: Path) -> None:
    script = tmp_path / "gossip.bzz"
    script.write_text(GOSSIP)
    cfg = SitlConfig(
        script=script,
        robots=3,
        out=tmp_path / "run",
        profile=load_profile("solo"),
        drop=0.3,
        corrupt=0.1,
        seconds=8.0,
        seed=4,
    )
    summary = run(cfg)
    assert summary["errors"] == []
    assert summary["final_states"] == {"1": "ALL", "2": "ALL", "3": "ALL"}
    assert summary["relay"]["dropped"] > 0 and summary["relay"]["corrupted"] > 0
    assert all(b > 0 for b in summary["bytes_sent_per_robot"].values())
    nodes = summary["nodes"]
    # A corrupted frame fails its checksum (or the bundle check): counted, nothing else.
    assert sum(n["radio_bad_frames"] + n["bundle_errors"] for n in nodes.values()) > 0
    assert all(n["ticks"] >= 60 for n in nodes.values())
    written = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert written["final_states"] == summary["final_states"]


def test_sitl_command_line_errors(tmp_path: Path) -> None:
    runner = CliRunner()
    bad = runner.invoke(app, ["sitl", "--robots", "0", "--script", "x.bzz", "--out", str(tmp_path)])
    assert bad.exit_code == 1 and "--robots" in bad.output
    missing = runner.invoke(
        app, ["sitl", "--robots", "2", "--script", "nope.bzz", "--out", str(tmp_path)]
    )
    assert missing.exit_code == 1 and "no such file" in missing.output
