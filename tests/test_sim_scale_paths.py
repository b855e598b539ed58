"""The simulator's faster paths give the same runs, bit for bit, as the paths they replace."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import bvm
from bvm.translate import CodeCache, TranslateOptions
from fieldkit.robot import geo
from fieldkit.sim.simulator import DEFAULT_ORIGIN, RcCommand, SimConfig, Simulation

ROOT = Path(__file__).resolve().parent.parent


def _mission(script: str) -> SimConfig:
    """A small whole mission from the ground: takeoff, the behaviour's command, its barrier."""
    frame = geo.LocalFrame(*DEFAULT_ORIGIN)
    commands = [RcCommand(0.5, 1, 22)]
    if script == "coverage.bzz":
        for k, (east, north) in enumerate(((-10.0, -10.0), (40.0, -10.0), (40.0, 40.0))):
            lat, lon, _ = frame.to_gps(east, north, 0.0)
            commands.append(RcCommand(1.0 + 0.2 * k, 1, 16, (50.0 + k, lat, lon, 0.0)))
        commands.append(RcCommand(5.0, 1, 901))
    else:
        commands.append(RcCommand(5.0, 1, 900))
    return SimConfig(
        script=ROOT / "buzz_scripts" / script,
        robots=9,
        seconds=14.0,
        range_m=20.0,
        spacing_m=8.0,
        commands=commands,
        include_dirs=(str(ROOT / "buzz_scripts"),),
        seed=3,
    )


def _outcome(sim: Simulation) -> str:
    """Everything a run produced: summary, log, every robot's position and traffic."""
    robots = {
        rid: [r.vehicle.x, r.vehicle.y, r.vehicle.position[2], dict(r.vm.counters)]
        for rid, r in sim.robots.items()
    }
    return json.dumps([sim.summary(), sim.log, robots], sort_keys=True)


@pytest.mark.parametrize("script", ["coverage.bzz", "task_allocation.bzz"])
def test_shared_translations_change_no_run(script: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Robots reusing each other's translations run exactly as robots translating alone."""
    outcomes = []
    for share in (False, True):
        options = TranslateOptions(share_translations=share, cache=CodeCache())
        monkeypatch.setitem(bvm.VM.__init__.__kwdefaults__, "translate_options", options)
        sim = Simulation(_mission(script))
        sim.run()
        assert {r.state for r in sim.robots.values()} - {"IDLE", "BARRIERWAIT"}  # got going
        outcomes.append(_outcome(sim))
    assert outcomes[0] == outcomes[1]
