"""Running an experiment: one run as a pure function of its spec, or a whole plan here."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable

from fieldkit.sim.experiments.base import SAMPLE_TICKS, Row, RunResult, RunSpec, rounded
from fieldkit.sim.experiments.plan import Plan
from fieldkit.sim.simulator import TICK_S, Simulation


def run_one(spec: RunSpec, progress: Callable[[int], None] | None = None) -> RunResult:
    """Simulate one run and measure it; `progress(ticks_done)` is called every second."""
    sim = Simulation(spec.config())
    result = RunResult(spec)
    probe = spec.experiment.probe(spec, sim)
    total = spec.total_ticks
    # Radio load of the current sample: air bytes per (robot, step), and bundle content.
    air_sum = air_count = air_max = 0
    last_total, last_bundles = sim.total_bundle, sim.bundles
    air_all = air_all_count = air_all_max = 0
    while sim.tick < total:
        sim.step()
        step_bytes = sim.radio.step_bytes().values()
        for b in step_bytes:
            air_sum += b
            air_count += 1
            if b > air_max:
                air_max = b
        probe.after_step(sim.tick)
        if sim.tick % SAMPLE_TICKS and sim.tick != total:
            continue
        row: Row = {"t_s": rounded(sim.tick * TICK_S)}
        probe.sample(row, result.robot_rows)
        sent = sim.bundles - last_bundles
        row["bundle_bytes_mean"] = rounded((sim.total_bundle - last_total) / sent) if sent else 0.0
        row["air_bytes_mean"] = rounded(air_sum / air_count) if air_count else 0.0
        row["air_bytes_max"] = air_max
        result.rows.append(row)
        air_all += air_sum
        air_all_count += air_count
        air_all_max = max(air_all_max, air_max)
        air_sum = air_count = air_max = 0
        last_total, last_bundles = sim.total_bundle, sim.bundles
        if progress is not None:
            progress(sim.tick)
    summary = sim.summary()
    result.figures = {
        "max_bundle_bytes": sim.max_bundle,
        "total_bundle_bytes": sim.total_bundle,
        "bundles": sim.bundles,
        "air_bytes": air_all,
        "air_steps": air_all_count,
        "max_air_bytes": air_all_max,
        "seconds_simulated": summary["seconds_simulated"],
        "final_states": dict(sorted(Counter(str(r.state) for r in sim.robots.values()).items())),
        "errors": summary["errors"],
        **probe.figures(result.rows[-1] if result.rows else {}),
    }
    return result


def run_plan(plan: Plan, progress: Callable[[int, int], None] | None = None) -> list[RunResult]:
    """Run every spec of the plan in order, here; `progress(ticks_done, ticks_total)`."""
    specs = plan.specs()
    total = sum(s.total_ticks for s in specs)
    done = 0
    results = []
    for spec in specs:
        before = done

        def advance(ticks: int, before: int = before) -> None:
            if progress is not None:
                progress(before + ticks, total)

        results.append(run_one(spec, advance))
        done += spec.total_ticks
    return results
