"""An experiment's output files: summary.json, timeseries.csv, robots.csv (and the plots)."""

from __future__ import annotations

import csv
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import SupportsInt, cast

from fieldkit.results import write_json
from fieldkit.robot.bundle_auth import SEALED_MAX_MSG_SIZE
from fieldkit.sim.experiments.base import (
    BUNDLE_LIMIT_BYTES,
    XBEE_FRAME_BYTES,
    Row,
    RunResult,
    rounded,
)
from fieldkit.sim.experiments.plan import Plan
from fieldkit.sim.experiments.plots import plot_bytes, plot_experiment

#: The grid keys that start every CSV row, and the radio columns that end timeseries.csv.
GRID_KEYS = ("robots", "drop", "run", "seed")
RADIO_COLUMNS = ("air_bytes_mean", "air_bytes_max", "bundle_bytes_mean")


def _one_or_all(values: Sequence[object]) -> object:
    """A grid axis as summary.json gives it: the value when there is one, else the list."""
    return values[0] if len(values) == 1 else list(values)


def _int(result: RunResult, key: str) -> int:
    """An integer end figure of a run (figures are typed `object`: they go to JSON as they are)."""
    return int(cast(SupportsInt, result.figures[key]))


def summarize(plan: Plan, results: Sequence[RunResult]) -> dict[str, object]:
    """The experiment's `summary.json`: grid, radio load, and the per-run figures.

    Per-run lists (`joined_fraction`, `time_to_all_joined_s`, `final_centroid_distance_m`,
    `seeds`, `run_params`) follow grid order: robots, then drop, then run. `cells` holds
    the same figures per (robots, drop).
    """
    e = plan.experiment
    bundles = sum(_int(r, "bundles") for r in results)
    content = sum(_int(r, "total_bundle_bytes") for r in results)
    air_steps = sum(_int(r, "air_steps") for r in results)
    air = sum(_int(r, "air_bytes") for r in results)
    errors: list[dict[str, object]] = []
    for r in results:
        run_errors = cast(list[dict[str, object]], r.figures["errors"])  # the simulator's list
        errors.extend(
            {"robots": r.spec.robots, "drop": r.spec.drop, "run": r.spec.run, **err}
            for err in run_errors
        )
    summary: dict[str, object] = {
        "experiment": e.name,
        "figure": e.figure,
        "script": Path(plan.script).name,
        "robots": _one_or_all(plan.robots),
        "drop": _one_or_all(plan.drops),
        **({} if plan.burst is None else {"burst": plan.burst}),
        "runs": plan.runs,
        "seed": plan.seed,
        "seeds": [r.spec.seed for r in results],
        "run_params": [
            {"robots": r.spec.robots, "drop": r.spec.drop, "run": r.spec.run, "seed": r.spec.seed}
            for r in results
        ],
        "seconds_simulated": plan.seconds,
        "schedule_s": e.schedule(),
        "max_bundle_bytes": max(_int(r, "max_bundle_bytes") for r in results),
        "mean_bundle_bytes": rounded(content / bundles) if bundles else 0.0,
        "bundle_limit_bytes": SEALED_MAX_MSG_SIZE if plan.swarm_key else BUNDLE_LIMIT_BYTES,
        "security": "signed" if plan.swarm_key else "none",
        "max_air_bytes_per_step": max(_int(r, "max_air_bytes") for r in results),
        "mean_air_bytes_per_step": rounded(air / air_steps) if air_steps else 0.0,
        "xbee_frame_bytes": XBEE_FRAME_BYTES,
        "errors": errors,
        **e.summary_fields(plan.robots),
    }
    for key in e.per_run:
        summary[key] = [r.figures[key] for r in results]
    cells = []
    for n in plan.robots:
        for d in plan.drops:
            rs = [r for r in results if r.spec.robots == n and r.spec.drop == d]
            cell: dict[str, object] = {
                "robots": n,
                "drop": d,
                "max_bundle_bytes": max(_int(r, "max_bundle_bytes") for r in rs),
                "final_states": [r.figures["final_states"] for r in rs],
            }
            for key in e.per_run:
                cell[key] = [r.figures[key] for r in rs]
            cells.append(cell)
    summary["cells"] = cells
    return summary


def _csv_value(v: object) -> object:
    """None is an empty CSV field."""
    return "" if v is None else v


def write_csv(path: Path, header: Sequence[str], rows: Iterable[Mapping[str, object]]) -> None:
    """Write rows (dicts) under `header`, `\\n` line ends, so files compare byte for byte."""
    with path.open("w", encoding="utf-8", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(header)
        for row in rows:
            w.writerow([_csv_value(row.get(h)) for h in header])


def _with_keys(results: Sequence[RunResult], per_robot: bool) -> Iterable[dict[str, object]]:
    """Every run's rows (or per-robot rows), each prefixed with its run's grid keys."""
    for r in results:
        s = r.spec
        rows: list[Row] = r.robot_rows if per_robot else r.rows
        for row in rows:
            yield {"robots": s.robots, "drop": s.drop, "run": s.run, "seed": s.seed, **row}


def write_outputs(plan: Plan, results: Sequence[RunResult], out: Path) -> dict[str, object]:
    """Write summary.json, timeseries.csv (+ robots.csv), plot.png and bytes.png into `out`."""
    e = plan.experiment
    out.mkdir(parents=True, exist_ok=True)
    summary = summarize(plan, results)
    write_json(out / "summary.json", summary)
    write_csv(
        out / "timeseries.csv",
        [*GRID_KEYS, "t_s", *e.columns, *RADIO_COLUMNS],
        _with_keys(results, per_robot=False),
    )
    if e.robot_columns:
        write_csv(
            out / "robots.csv",
            [*GRID_KEYS, "t_s", *e.robot_columns],
            _with_keys(results, per_robot=True),
        )
    plot_experiment(plan, results, out / "plot.png")
    plot_bytes(plan, results, out / "bytes.png")
    return summary
