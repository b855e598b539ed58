"""The recording cost bench still runs and measures what it says (figures by hand)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parent.parent / "bench" / "record_cost.py"


@pytest.mark.parametrize("storage", ["mcap", "ros1"])
def test_record_bench_measures_ticks_and_bytes(storage: str) -> None:
    spec = importlib.util.spec_from_file_location("record_cost", BENCH)
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = bench  # its dataclass looks its module up there
    spec.loader.exec_module(bench)
    data = bench.ticks(25, 1)
    assert [len(t.rx) for t in data] == [3] * 25 and len(data[0].radio_in) == 2
    f = bench.measure(25, 1, storage)
    assert 0 < f["mean"] <= f["p99"] <= f["max"]
    # A second of flight: 10 ticks of ~1 kB of frames, plus MAVLink and the rows: kilobytes.
    assert 5_000 < f["bytes_per_s"] < 200_000
