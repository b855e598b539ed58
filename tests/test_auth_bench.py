"""The authentication cost bench still runs and measures what it says (figures by hand)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

BENCH = Path(__file__).resolve().parent.parent / "bench" / "auth_cost.py"


def test_auth_bench_measures_every_step_and_the_trailer() -> None:
    spec = importlib.util.spec_from_file_location("auth_cost", BENCH)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    f = bench.measure(30, 1, 1)
    assert all(f[k] > 0 for k in ("encode", "decode", "seal", "verify"))
    assert f["trailer_bytes"] == 16
    assert f["max_bytes"] + 16 == 240  # the full sealed budget is among the bundles
