"""The benches still run end to end (their figures are measured by hand, not here)."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

BENCH = Path(__file__).resolve().parent.parent / "bench"


def load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, BENCH / f"{name}.py")
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    sys.modules[name] = bench  # dataclasses look their module up there
    spec.loader.exec_module(bench)
    return bench


def table_rows(out: str) -> list[list[str]]:
    """The rows of a bench's table: the lines that start with a robot count."""
    return [line.split() for line in out.splitlines() if line.split()[0].isdigit()]


def test_scale_bench_measures_a_deploying_swarm() -> None:
    bench = load("sim_scale")
    rate, whole, gossip_s, states = bench.ticks_per_second(16, 1.0)
    assert states == {"DEPLOY": 16}  # every robot covering when measured
    assert rate > 0 and whole > 0
    assert bench.SETTLE_S <= gossip_s <= bench.MAX_GOSSIP_S


def test_mission_bench_runs_a_small_swarm_through_every_phase() -> None:
    bench = load("sim_scale")
    rate, cpu, ticks, simulated, outcome = bench.mission_rate("task-allocation", 9)
    assert outcome == "P formed" and rate > 0
    assert all(ticks[p] > 0 for p in bench.PHASES[1:])  # takeoff, barrier, behaviour
    assert simulated == sum(ticks.values()) * bench.TICK_S > bench.MISSION_COMMAND_S


def test_scale_bench_names_the_machine_its_figures_belong_to() -> None:
    line = load("sim_scale").machine()
    assert line.startswith("machine: ") and f"Python {sys.version.split()[0]}" in line


def test_scale_bench_interpolates_the_largest_real_time_swarm() -> None:
    bench = load("sim_scale")
    # 0.05 s a tick at 500 robots, 0.15 s at 1,500: 0.1 s halfway, at 1,000.
    assert bench.largest_real_time([(500, 20.0), (1500, 1 / 0.15)]) == 1000
    assert bench.largest_text([(500, 20.0), (1500, 1 / 0.15)]) == "1000"
    assert bench.largest_text([(20, 400.0), (40, 200.0)]) == "at least 40"  # no limit found
    assert bench.largest_text([(500, 9.0)]) == "0"


def test_mission_bench_runs_coverage_to_its_end() -> None:
    bench = load("sim_scale")
    rate, cpu, ticks, simulated, outcome = bench.mission_rate("coverage", 9)
    assert outcome == "covered" and ticks["behaviour"] >= bench.COVER_S / bench.TICK_S


@pytest.mark.parametrize(
    ("name", "args", "message"),
    [
        ("sim_scale", ["--sizes", "0"], "robot counts must be at least 1"),
        ("sim_scale", ["--sizes", "x"], "a comma-separated list of robot counts"),
        ("sim_scale", ["--mission", "coverage", "--measure", "3"], "--measure"),
        ("barrier_traffic", ["--drop", "2"], "must be in [0, 1]"),
        ("sim_workers", ["--workers", "0"], "must be at least 1"),
        ("sim_workers", ["--sizes", "1", "--workers", "2"], "more workers than the 1 robots"),
    ],
)
def test_benches_refuse_bad_arguments_with_a_usage_error(
    name: str, args: list[str], message: str
) -> None:
    run = subprocess.run(
        [sys.executable, str(BENCH / f"{name}.py"), *args], capture_output=True, text=True
    )
    assert run.returncode == 2 and "Traceback" not in run.stderr, run.stderr
    assert message in run.stderr.splitlines()[-1]


def test_ota_bench_layouts_have_the_hops_it_reports() -> None:
    bench = load("ota_spread")
    # 10 m apart, 45 m of range: 4 robots further per hop.
    assert [bench.layout_for("line", n, 0).diameter for n in (10, 50, 200)] == [3, 13, 50]
    rgg = bench.layout_for("rgg", 30, 0)
    assert len(rgg.positions) == 30
    hops = bench.hops_from(rgg.positions, 1)
    assert len(hops) == 30 and max(hops.values()) == rgg.from_source <= rgg.diameter


def test_ota_bench_updates_a_small_swarm_and_writes_its_files(tmp_path: Path) -> None:
    bench = load("ota_spread")
    bench.main(
        ["--sizes", "5", "--drops", "0.5", "--seeds", "1", "--out", str(tmp_path), "--no-wall"]
    )
    s = json.loads((tmp_path / "summary.json").read_text())
    assert [(c["topology"], c["robots"]) for c in s["cells"]] == [("line", 5), ("rgg", 5)]
    for run in s["runs"]:
        assert run["switch_s"] is not None and run["switch_s"] > 0
        assert run["on_new_version"] == 5 and not run["split"] and not run["rolled_back"]
        assert run["spread_update_bytes"] > run["patch_bytes"]
        assert "wall_s" not in run
    assert (tmp_path / "plot.png").stat().st_size > 10_000


def test_attack_bench_finds_the_signed_swarm_unchanged(tmp_path: Path) -> None:
    bench = load("attack_sim")
    bench.main(["--drops", "0.5", "--runs", "1", "--seconds", "40", "--out", str(tmp_path)])
    s = json.loads((tmp_path / "summary.json").read_text())
    (run,) = s["runs"]
    assert s["all_unchanged"] and s["accepted_from_attacker_signed"] == 0
    assert run["accepted_from_attacker"]["none"] > 0 and run["plain_swarm_changed_by_attack"]
    gap = run["mean_bundle_air_bytes"]["signed"] - run["mean_bundle_air_bytes"]["none"]
    assert abs(gap - 16) < 0.5
    assert run["commands"]["bad-signature"] > 0 and "accepted" not in run["commands"]


def test_digest_bench_runs(capsys: object) -> None:
    bench = load("digest_cost")
    bench.main(["--seconds", "21", "--repeat", "1"])
    out = capsys.readouterr().out  # type: ignore[attr-defined]
    assert out.count("of the 100 ms tick") == 2


def test_memory_bench_times_the_same_code_at_each_size(capsys: object) -> None:
    bench = load("sim_memory")
    bench.main(["--robots", "20", "--at", "3"])
    out = capsys.readouterr().out  # type: ignore[attr-defined]
    rows = table_rows(out)
    assert [int(r[0]) for r in rows] == [10, 20]
    assert all(float(v) > 0 for r in rows for v in r[1:])
    assert "all robots / 10 robots: sensor tables" in out


def test_ground_bench_hears_every_robot() -> None:
    bench = load("ground_throughput")
    r = bench.measure(20, 2.0, 1, True)
    assert r["robots_in_view"] == 20 and r["frames"] > 400
    assert r["counters"].get("suspect", 0) == 0 and r["ratio"] > 0


def test_floor_bench_prints_each_size_and_the_share_of_the_budget(capsys: object) -> None:
    bench = load("sim_floor")
    bench.main(["--sizes", "2,3", "--robot-ticks", "12"])
    out = capsys.readouterr().out  # type: ignore[attr-defined]
    assert [int(r[0]) for r in table_rows(out)] == [2, 3]
    assert out.splitlines()[-1].startswith("floor: ") and "at 3 robots" in out
