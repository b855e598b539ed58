"""The scale bench still runs end to end (its figures are measured by hand, not here)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

BENCH = Path(__file__).resolve().parent.parent / "bench" / "sim_scale.py"


def test_scale_bench_measures_a_deploying_swarm() -> None:
    spec = importlib.util.spec_from_file_location("sim_scale", BENCH)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    rate, whole, gossip_s, states = bench.ticks_per_second(16, 1.0)
    assert states == {"DEPLOY": 16}  # every robot covering when measured
    assert rate > 0 and whole > 0
    assert bench.SETTLE_S <= gossip_s <= bench.MAX_GOSSIP_S
