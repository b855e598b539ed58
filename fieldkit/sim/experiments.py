"""The paper's experiments on the simulator: task allocation and coverage, under loss and at scale.

An experiment is a grid of runs (robot counts x drop rates x seeded runs); every run is one
`Simulation` driven as the ground station drives the field swarm: RC 22 (takeoff) to robot 1
at `TAKEOFF_S`, then, once the swarm is up, either RC 900 (task allocation) at `MISSION_S`,
or the coverage hotspots (RC 16, waypoint ids 50..) to robot 1 followed by RC 901 (DEPLOY).
A run is a pure function of its `RunSpec`: the same spec gives the same `RunResult` bit for
bit, wherever and in whatever order it runs (see `fieldkit.sim.sweep`).

* `task-allocation` (Figure 6): 6 robots form the P graph at drop 0, 0.2, 0.5, 0.7 and 0.9,
  5 seeded runs each; the fraction of robots JOINED over time.
* `task-allocation-scale` (Figure 7): 6, 12, 18, 24, 30 and 48 robots form P, PO, POL, POLY,
  PPOLY and YLOPPOLY without loss, 1 run each.
* `coverage` (Figure 12): 6 robots cover the hotspots' region at the same drop rates, 5 runs
  each; each robot's distance to its ideal Voronoi centroid over time.
* `coverage-scale` (Figure 13): 10, 20, 30, 40 and 50 robots, no loss, 1 run each; the mean
  pairwise distance over time.

Every experiment also records the bytes each robot puts on the air per step against the
250-byte XBee frame, and the Buzz bundle content against ROSBuzz's 190-byte limit (Fig. 10).

Outputs (`write_outputs`): `summary.json` (sorted keys, no wall times: same seed, same
bytes), `timeseries.csv` (one row per run and simulated second), `robots.csv` (coverage:
each robot's position and centroid distance per second), `plot.png` (the paper's figure)
and `bytes.png` (the radio load).
"""

from __future__ import annotations

import csv
import math
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from fieldkit import bundle as wirebundle
from fieldkit import geo, voronoi
from fieldkit.sim.simulator import DEFAULT_ORIGIN, TICK_S, RcCommand, SimConfig, Simulation

#: Where the shipped behaviours live.
SCRIPT_DIR = Path(__file__).resolve().parent.parent.parent / "buzz_scripts"

#: The XBee's RF frame (XbeeMav sends one bundle per frame).
XBEE_FRAME_BYTES = 250
#: ROSBuzz's per-step bundle content limit.
BUNDLE_LIMIT_BYTES = wirebundle.MAX_MSG_SIZE

#: The ground station's schedule, in simulated seconds. Takeoff is handed to robot 1 only: the
#: command spreads through the swarm. At 90 % drop every robot is up and IDLE within ~10 s, so
#: the mission command at 20 s finds the swarm in the air.
TAKEOFF_S = 1.0
HOTSPOTS_S = 15.0  # the first coverage hotspot; the next ones HOTSPOT_GAP_S apart
HOTSPOT_GAP_S = 0.5  # one RC code per robot per tick, so hotspots go one at a time
MISSION_S = 20.0

#: RC codes (rosbuzz §6.2).
RC_TAKEOFF = 22
RC_TASK_ALLOCATE = 900
RC_DEPLOY = 901
RC_WAYPOINT = 16
#: Waypoint ids 50..99 are coverage hotspots (attractors), shared through stigmergy.
FIRST_HOTSPOT_ID = 50

#: Samples of the time series: one per simulated second.
SAMPLE_TICKS = round(1.0 / TICK_S)

#: The states in which a robot holds its task-graph node (LOCK: JOINED and the shape formed).
JOINED_STATES = frozenset({"JOINED", "LOCK"})

#: The task graphs of the scale experiment, by robot count (the paper's Fig. 7).
SCALE_SHAPES: tuple[tuple[int, str], ...] = (
    (6, "P"),
    (12, "PO"),
    (18, "POL"),
    (24, "POLY"),
    (30, "PPOLY"),
    (48, "YLOPPOLY"),
)

#: Coverage hotspots, (east, north) metres in the simulation frame, around the takeoff grid
#: (robots start at 0..3 sqrt(N) m east and north). The region covered is their convex hull
#: inflated by the script's margin.
HOTSPOTS: tuple[tuple[float, float], ...] = (
    (-10.0, -10.0),
    (30.0, -10.0),
    (30.0, 30.0),
    (-10.0, 30.0),
)
#: The inflation of the hotspots' hull: coverage.bzz's margin (ROSBuzz: 20 m).
COVERAGE_MARGIN_M = 20.0


class ExperimentError(ValueError):
    """An invalid experiment parameter, with a message saying which and why."""


@dataclass(frozen=True)
class Experiment:
    """One of the paper's experiments: its default grid, duration and behaviour script."""

    name: str
    kind: str  # "task-allocation" or "coverage"
    robots: tuple[int, ...]
    drops: tuple[float, ...]
    runs: int  # seeded runs per (robots, drop) cell
    seconds: float  # simulated seconds per run
    script: str  # file name under SCRIPT_DIR
    figure: str  # the paper's figure it reproduces
    metric: str  # what plot.png shows
    series: str  # the timeseries.csv column plot.png shows


DROPS = (0.0, 0.2, 0.5, 0.7, 0.9)

# Durations (simulated): task allocation of 6 robots takes 10-24 s after RC 900 from 0 to 90 %
# drop, so 120 s (100 s after the command) leaves room; 48 robots join one after another in
# ~60 s, so the scale runs last 180 s (160 s after the command). Coverage settles within ~20 s
# of RC 901 at 6 and at 50 robots; 120 s shows it hold, at every drop rate.
EXPERIMENTS: dict[str, Experiment] = {
    e.name: e
    for e in (
        Experiment(
            "task-allocation",
            "task-allocation",
            (6,),
            DROPS,
            5,
            120.0,
            "task_allocation.bzz",
            "Figure 6",
            "fraction of robots JOINED",
            "joined_fraction",
        ),
        Experiment(
            "task-allocation-scale",
            "task-allocation",
            tuple(n for n, _ in SCALE_SHAPES),
            (0.0,),
            1,
            180.0,
            "task_allocation.bzz",
            "Figure 7",
            "fraction of robots JOINED",
            "joined_fraction",
        ),
        Experiment(
            "coverage",
            "coverage",
            (6,),
            DROPS,
            5,
            120.0,
            "coverage.bzz",
            "Figure 12",
            "distance to the ideal Voronoi centroid (m)",
            "centroid_distance_mean_m",
        ),
        Experiment(
            "coverage-scale",
            "coverage",
            (10, 20, 30, 40, 50),
            (0.0,),
            1,
            120.0,
            "coverage.bzz",
            "Figure 13",
            "mean pairwise distance (m)",
            "mean_pairwise_distance_m",
        ),
    )
}

#: Bounds on the parameters (beyond them a run is either meaningless or would take days).
MAX_ROBOTS = 1000
MAX_RUNS = 1000
MAX_SECONDS = 100_000.0


def shape_for(robots: int) -> str:
    """The task graph for `robots` robots: the smallest of SCALE_SHAPES with enough nodes."""
    for n, name in SCALE_SHAPES:
        if n >= robots:
            return name
    raise ExperimentError(
        f"--robots {robots}: the largest task graph ({SCALE_SHAPES[-1][1]}) has "
        f"{SCALE_SHAPES[-1][0]} nodes"
    )


@dataclass(frozen=True)
class RunSpec:
    """Everything one run depends on (picklable: a Dask task's argument)."""

    experiment: str
    kind: str
    robots: int
    drop: float
    run: int  # index within its (robots, drop) cell
    seed: int
    seconds: float
    script: str
    include_dirs: tuple[str, ...] = ()
    shape: str | None = None  # task allocation: the task graph
    hotspots: tuple[tuple[float, float], ...] = ()  # coverage: (east, north) metres
    margin_m: float = COVERAGE_MARGIN_M  # coverage: hull inflation for the ideal centroids

    def commands(self) -> list[RcCommand]:
        """The ground station's RC codes for this run."""
        cmds = [RcCommand(TAKEOFF_S, 1, RC_TAKEOFF)]
        if self.kind == "task-allocation":
            cmds.append(RcCommand(MISSION_S, 1, RC_TASK_ALLOCATE))
            return cmds
        frame = geo.LocalFrame(*DEFAULT_ORIGIN)
        for k, (east, north) in enumerate(self.hotspots):
            lat, lon, alt = frame.to_gps(east, north, 0.0)
            params = (float(FIRST_HOTSPOT_ID + k), lat, lon, alt)
            cmds.append(RcCommand(HOTSPOTS_S + k * HOTSPOT_GAP_S, 1, RC_WAYPOINT, params))
        cmds.append(RcCommand(MISSION_S, 1, RC_DEPLOY))
        return cmds

    def script_globals(self) -> dict[str, object]:
        """The globals set before the script runs: the task graph, or the coverage margin."""
        if self.kind == "task-allocation":
            return {"SHAPE": self.shape} if self.shape is not None else {}
        # The same margin as the metric's region, whatever the script's default.
        return {"MARGIN": float(self.margin_m)}

    def config(self) -> SimConfig:
        """The simulator configuration of this run."""
        return SimConfig(
            script=Path(self.script),
            robots=self.robots,
            drop=self.drop,
            seconds=self.seconds,
            seed=self.seed,
            commands=self.commands(),
            include_dirs=self.include_dirs,
            globals=self.script_globals(),
        )

    @property
    def total_ticks(self) -> int:
        """Ticks this run simulates."""
        return round(self.seconds / TICK_S)


@dataclass
class RunResult:
    """What one run measured: per-second rows, per-robot rows (coverage) and end figures."""

    spec: RunSpec
    rows: list[dict[str, float | int]] = field(default_factory=list)
    robot_rows: list[dict[str, float | int]] = field(default_factory=list)
    figures: dict[str, object] = field(default_factory=dict)


def _mean_pairwise(points: Sequence[tuple[float, float]]) -> float:
    """Mean horizontal distance over all pairs of robots (0 for fewer than 2)."""
    n = len(points)
    if n < 2:
        return 0.0
    total = 0.0
    for i in range(n):
        xi, yi = points[i]
        for j in range(i + 1, n):
            total += math.hypot(points[j][0] - xi, points[j][1] - yi)
    return total / (n * (n - 1) / 2)


def _r(x: float) -> float:
    """Round for the outputs: 6 decimals keep every figure and hide nothing that matters."""
    return round(x, 6) if math.isfinite(x) else x


def run_one(spec: RunSpec, progress: Callable[[int], None] | None = None) -> RunResult:
    """Simulate one run and measure it; `progress(ticks_done)` is called every second."""
    sim = Simulation(spec.config())
    result = RunResult(spec)
    n = spec.robots
    total = spec.total_ticks
    boundary = voronoi.convex_hull(spec.hotspots, spec.margin_m) if spec.hotspots else []
    mission_tick = round(MISSION_S / TICK_S)
    all_joined_tick: int | None = None
    # Radio load of the current sample: air bytes per (robot, step), and bundle content.
    air_sum = air_count = air_max = 0
    last_total, last_bundles = sim.total_bundle, sim.bundles
    air_all = air_all_count = air_all_max = 0
    robots = list(sim.robots.values())
    while sim.tick < total:
        sim.step()
        step_bytes = sim.radio.step_bytes().values()
        for b in step_bytes:
            air_sum += b
            air_count += 1
            if b > air_max:
                air_max = b
        if spec.kind == "task-allocation" and all_joined_tick is None and sim.tick > mission_tick:
            if all(r.state in JOINED_STATES for r in robots):
                all_joined_tick = sim.tick
        if sim.tick % SAMPLE_TICKS and sim.tick != total:
            continue
        row: dict[str, float | int] = {"t_s": _r(sim.tick * TICK_S)}
        if spec.kind == "task-allocation":
            joined = sum(r.state in JOINED_STATES for r in robots)
            row["joined"] = joined
            row["joined_fraction"] = _r(joined / n)
        else:
            points = [(r.vehicle.x, r.vehicle.y) for r in robots]
            dists = voronoi.centroid_distances(points, boundary)
            row["centroid_distance_mean_m"] = _r(sum(dists) / n)
            row["centroid_distance_max_m"] = _r(max(dists))
            row["mean_pairwise_distance_m"] = _r(_mean_pairwise(points))
            for r, p, d in zip(robots, points, dists, strict=True):
                result.robot_rows.append(
                    {
                        "t_s": row["t_s"],
                        "robot": r.id,
                        "x_m": _r(p[0]),
                        "y_m": _r(p[1]),
                        "centroid_distance_m": _r(d),
                    }
                )
        sent = sim.bundles - last_bundles
        row["bundle_bytes_mean"] = _r((sim.total_bundle - last_total) / sent) if sent else 0.0
        row["air_bytes_mean"] = _r(air_sum / air_count) if air_count else 0.0
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
    figures: dict[str, object] = {
        "max_bundle_bytes": sim.max_bundle,
        "total_bundle_bytes": sim.total_bundle,
        "bundles": sim.bundles,
        "air_bytes": air_all,
        "air_steps": air_all_count,
        "max_air_bytes": air_all_max,
        "seconds_simulated": summary["seconds_simulated"],
        "final_states": dict(sorted(Counter(str(r.state) for r in robots).items())),
        "errors": summary["errors"],
    }
    last = result.rows[-1] if result.rows else {}
    if spec.kind == "task-allocation":
        figures["joined_fraction"] = last.get("joined_fraction", 0.0)
        figures["time_to_all_joined_s"] = (
            None if all_joined_tick is None else _r((all_joined_tick - mission_tick) * TICK_S)
        )
    else:
        figures["final_centroid_distance_m"] = last.get("centroid_distance_mean_m", math.inf)
        figures["final_centroid_distance_max_m"] = last.get("centroid_distance_max_m", math.inf)
        figures["final_mean_pairwise_distance_m"] = last.get("mean_pairwise_distance_m", 0.0)
    result.figures = figures
    return result


# ------------------------------------------------------------------ plans


@dataclass(frozen=True)
class Plan:
    """An experiment's grid as asked for: which robot counts, drop rates, runs and seeds."""

    experiment: Experiment
    robots: tuple[int, ...]
    drops: tuple[float, ...]
    runs: int
    seed: int
    seconds: float
    script: str

    def specs(self) -> list[RunSpec]:
        """The runs, in grid order (robots, then drop, then run): the order of every output."""
        e = self.experiment
        base = RunSpec(
            experiment=e.name,
            kind=e.kind,
            robots=0,
            drop=0.0,
            run=0,
            seed=0,
            seconds=self.seconds,
            script=self.script,
            include_dirs=(str(Path(self.script).parent),),
            hotspots=HOTSPOTS if e.kind == "coverage" else (),
        )
        out = []
        for n in self.robots:
            shape = shape_for(n) if e.kind == "task-allocation" else None
            for drop in self.drops:
                for k in range(self.runs):
                    # Run k of every cell has the same seed: common random numbers across cells.
                    out.append(
                        replace(base, robots=n, drop=drop, run=k, seed=self.seed + k, shape=shape)
                    )
        return out


def make_plan(
    name: str,
    *,
    robots: Iterable[int] | None = None,
    drops: Iterable[float] | None = None,
    runs: int | None = None,
    seed: int = 0,
    seconds: float | None = None,
    script: str | Path | None = None,
) -> Plan:
    """Validate the parameters of experiment `name` and build its grid (ExperimentError)."""
    e = EXPERIMENTS.get(name)
    if e is None:
        raise ExperimentError(
            f"unknown experiment {name!r}: choose one of {', '.join(EXPERIMENTS)}"
        )
    robots_t = e.robots if robots is None else tuple(dict.fromkeys(robots))
    drops_t = e.drops if drops is None else tuple(dict.fromkeys(float(d) for d in drops))
    for n in robots_t:
        if not 1 <= n <= MAX_ROBOTS:
            raise ExperimentError(f"--robots must be between 1 and {MAX_ROBOTS}, got {n}")
        if e.kind == "task-allocation":
            shape_for(n)
    for d in drops_t:
        if not 0.0 <= d <= 1.0:
            raise ExperimentError(f"--drop must be a probability in [0, 1], got {d}")
    runs = e.runs if runs is None else runs
    if not 1 <= runs <= MAX_RUNS:
        raise ExperimentError(f"--runs must be between 1 and {MAX_RUNS}, got {runs}")
    if not 0 <= seed < 2**31:
        raise ExperimentError(f"--seed must be between 0 and {2**31 - 1}, got {seed}")
    seconds = e.seconds if seconds is None else seconds
    if not math.isfinite(seconds) or not MISSION_S < seconds <= MAX_SECONDS:
        raise ExperimentError(
            f"--seconds must be more than {MISSION_S:g} (the mission starts at "
            f"{MISSION_S:g} s) and at most {MAX_SECONDS:g}, got {seconds:g}"
        )
    path = Path(script) if script is not None else SCRIPT_DIR / e.script
    return Plan(e, robots_t, drops_t, runs, seed, float(seconds), str(path.resolve()))


def check_script(plan: Plan) -> None:
    """Compile the plan's script once, so a missing or broken one fails before any run."""
    import bvm
    from bvm.errors import BuzzCompileError, BuzzError

    if not Path(plan.script).is_file():
        raise ExperimentError(f"{plan.experiment.name}: behaviour script {plan.script} not found")
    try:
        bvm.compile_file(plan.script, include_dirs=(str(Path(plan.script).parent),))
    except (BuzzCompileError, BuzzError) as e:
        raise ExperimentError(str(e)) from None
    except OSError as e:
        raise ExperimentError(f"{plan.script}: cannot read: {e.strerror}") from None


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


# ------------------------------------------------------------------ outputs


def _one_or_all(values: Sequence[object]) -> object:
    """A grid axis as summary.json gives it: the value when there is one, else the list."""
    return values[0] if len(values) == 1 else list(values)


def summarize(plan: Plan, results: Sequence[RunResult]) -> dict[str, object]:
    """The experiment's `summary.json`: grid, radio load, and the per-run figures.

    Per-run lists (`joined_fraction`, `time_to_all_joined_s`, `final_centroid_distance_m`,
    `seeds`, `run_params`) follow grid order: robots, then drop, then run. `cells` holds
    the same figures per (robots, drop).
    """
    e = plan.experiment
    bundles = sum(int(r.figures["bundles"]) for r in results)  # type: ignore[call-overload]
    content = sum(int(r.figures["total_bundle_bytes"]) for r in results)  # type: ignore[call-overload]
    air_steps = sum(int(r.figures["air_steps"]) for r in results)  # type: ignore[call-overload]
    air = sum(int(r.figures["air_bytes"]) for r in results)  # type: ignore[call-overload]
    per_run = (
        ("joined_fraction", "time_to_all_joined_s")
        if e.kind == "task-allocation"
        else (
            "final_centroid_distance_m",
            "final_centroid_distance_max_m",
            "final_mean_pairwise_distance_m",
        )
    )
    summary: dict[str, object] = {
        "experiment": e.name,
        "figure": e.figure,
        "script": Path(plan.script).name,
        "robots": _one_or_all(plan.robots),
        "drop": _one_or_all(plan.drops),
        "runs": plan.runs,
        "seed": plan.seed,
        "seeds": [r.spec.seed for r in results],
        "run_params": [
            {"robots": r.spec.robots, "drop": r.spec.drop, "run": r.spec.run, "seed": r.spec.seed}
            for r in results
        ],
        "seconds_simulated": plan.seconds,
        "schedule_s": {"takeoff": TAKEOFF_S, "mission": MISSION_S},
        "max_bundle_bytes": max(int(r.figures["max_bundle_bytes"]) for r in results),  # type: ignore[call-overload]
        "mean_bundle_bytes": _r(content / bundles) if bundles else 0.0,
        "bundle_limit_bytes": BUNDLE_LIMIT_BYTES,
        "max_air_bytes_per_step": max(int(r.figures["max_air_bytes"]) for r in results),  # type: ignore[call-overload]
        "mean_air_bytes_per_step": _r(air / air_steps) if air_steps else 0.0,
        "xbee_frame_bytes": XBEE_FRAME_BYTES,
        "errors": [
            {"robots": r.spec.robots, "drop": r.spec.drop, "run": r.spec.run, **err}
            for r in results
            for err in r.figures["errors"]  # type: ignore[attr-defined]
        ],
    }
    if e.kind == "task-allocation":
        summary["shapes"] = {str(n): shape_for(n) for n in plan.robots}
        summary["joined_states"] = sorted(JOINED_STATES)
    else:
        summary["schedule_s"]["hotspots"] = HOTSPOTS_S  # type: ignore[index]
        summary["hotspots_east_north_m"] = [list(h) for h in HOTSPOTS]
        summary["coverage_margin_m"] = COVERAGE_MARGIN_M
    for key in per_run:
        summary[key] = [r.figures[key] for r in results]
    cells = []
    for n in plan.robots:
        for d in plan.drops:
            rs = [r for r in results if r.spec.robots == n and r.spec.drop == d]
            cell: dict[str, object] = {
                "robots": n,
                "drop": d,
                "max_bundle_bytes": max(int(r.figures["max_bundle_bytes"]) for r in rs),  # type: ignore[call-overload]
                "final_states": [r.figures["final_states"] for r in rs],
            }
            for key in per_run:
                cell[key] = [r.figures[key] for r in rs]
            cells.append(cell)
    summary["cells"] = cells
    return summary


def _csv_value(v: object) -> object:
    return "" if v is None else v


def write_csv(path: Path, header: Sequence[str], rows: Iterable[dict[str, object]]) -> None:
    """Write rows (dicts) under `header`, `\\n` line ends, so files compare byte for byte."""
    with path.open("w", encoding="utf-8", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(header)
        for row in rows:
            w.writerow([_csv_value(row.get(h)) for h in header])


def write_outputs(plan: Plan, results: Sequence[RunResult], out: Path) -> dict[str, object]:
    """Write summary.json, timeseries.csv (+ robots.csv), plot.png and bytes.png into `out`."""
    from fieldkit.sim.cli import write_json

    out.mkdir(parents=True, exist_ok=True)
    summary = summarize(plan, results)
    write_json(out / "summary.json", summary)
    keys = ["robots", "drop", "run", "seed"]
    metric = (
        ["joined", "joined_fraction"]
        if plan.experiment.kind == "task-allocation"
        else ["centroid_distance_mean_m", "centroid_distance_max_m", "mean_pairwise_distance_m"]
    )
    radio = ["air_bytes_mean", "air_bytes_max", "bundle_bytes_mean"]

    def with_keys(r: RunResult, rows: list[dict[str, float | int]]) -> Iterable[dict[str, object]]:
        s = r.spec
        for row in rows:
            yield {"robots": s.robots, "drop": s.drop, "run": s.run, "seed": s.seed, **row}

    write_csv(
        out / "timeseries.csv",
        [*keys, "t_s", *metric, *radio],
        (row for r in results for row in with_keys(r, r.rows)),
    )
    if plan.experiment.kind == "coverage":
        write_csv(
            out / "robots.csv",
            [*keys, "t_s", "robot", "x_m", "y_m", "centroid_distance_m"],
            (row for r in results for row in with_keys(r, r.robot_rows)),
        )
    plot_experiment(plan, results, out / "plot.png")
    plot_bytes(plan, results, out / "bytes.png")
    return summary


# ------------------------------------------------------------------ plots


def _label(plan: Plan, spec: RunSpec) -> str:
    """A cell's legend: what varies across the grid (drop rate, robot count)."""
    parts = []
    if len(plan.robots) > 1 or len(plan.drops) == 1:
        shape = f" ({spec.shape})" if spec.shape else ""
        parts.append(f"{spec.robots} robots{shape}")
    if len(plan.drops) > 1 or spec.drop:
        parts.append(f"drop {spec.drop:g}")
    return ", ".join(parts)


def _cells(plan: Plan, results: Sequence[RunResult]) -> list[tuple[RunSpec, list[RunResult]]]:
    """The results grouped by (robots, drop), in grid order."""
    out = []
    for n in plan.robots:
        for d in plan.drops:
            rs = [r for r in results if r.spec.robots == n and r.spec.drop == d]
            if rs:
                out.append((rs[0].spec, rs))
    return out


def _band(rs: Sequence[RunResult], column: str) -> tuple[list[float], list[float], ...]:
    """(times, mean, low, high) of one column over the runs of a cell, sample by sample."""
    times = [float(row["t_s"]) for row in rs[0].rows]
    mean, low, high = [], [], []
    for k in range(len(times)):
        values = [float(r.rows[k][column]) for r in rs if k < len(r.rows)]
        values = [v if math.isfinite(v) else math.nan for v in values]
        finite = [v for v in values if not math.isnan(v)]
        mean.append(sum(finite) / len(finite) if finite else math.nan)
        low.append(min(finite) if finite else math.nan)
        high.append(max(finite) if finite else math.nan)
    return times, mean, low, high


def _figure(rows: int = 1, cols: int = 1, size: tuple[float, float] = (8.0, 4.5)) -> tuple:
    """A matplotlib figure on the Agg backend (no display needed, same pixels everywhere)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt.subplots(rows, cols, figsize=size, squeeze=False)


def _save(fig: object, path: Path) -> None:
    """Save without the matplotlib version in the metadata, so reruns give the same file."""
    import matplotlib.pyplot as plt

    fig.tight_layout()  # type: ignore[attr-defined]
    fig.savefig(path, dpi=100, metadata={"Software": None})  # type: ignore[attr-defined]
    plt.close(fig)  # type: ignore[arg-type]


def plot_experiment(plan: Plan, results: Sequence[RunResult], path: Path) -> None:
    """The paper's figure: the experiment's metric over time, per cell (mean, min-max band)."""
    e = plan.experiment
    per_robot = e.series == "centroid_distance_mean_m"
    fig, axes = _figure(1, 2 if per_robot else 1, (12.0, 4.5) if per_robot else (8.0, 4.5))
    ax = axes[0][0]
    for spec, rs in _cells(plan, results):
        times, mean, low, high = _band(rs, e.series)
        line = ax.plot(times, mean, label=_label(plan, spec))[0]
        if len(rs) > 1:
            ax.fill_between(times, low, high, color=line.get_color(), alpha=0.15, lw=0)
    ax.axvline(MISSION_S, color="grey", ls=":", lw=1)
    ax.set_xlabel("simulated time (s); dotted: mission command")
    runs = f", mean and range of {plan.runs} runs" if plan.runs > 1 else ""
    drop = f", drop {plan.drops[0]:g}" if len(plan.drops) == 1 else ""
    ax.set_title(f"{e.name} ({e.figure}){drop}{runs}", fontsize=10)
    if e.kind == "task-allocation":
        ax.set_ylabel(e.metric)
        ax.set_ylim(-0.02, 1.02)
    elif per_robot:
        ax.set_ylabel("mean " + e.metric)
        ax.set_yscale("log")
        ax.axhline(1.0, color="red", ls="--", lw=1, label="1 m target")
    else:
        ax.set_ylabel(e.metric)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    if per_robot:
        # Figure 12 shows every robot: here those of the first run at the highest drop rate.
        spec, rs = _cells(plan, results)[-1]
        ax2 = axes[0][1]
        run = rs[0]
        for rid in range(1, spec.robots + 1):
            pts = [row for row in run.robot_rows if row["robot"] == rid]
            ax2.plot(
                [float(p["t_s"]) for p in pts],
                [max(float(p["centroid_distance_m"]), 1e-3) for p in pts],
                lw=1,
                label=f"robot {rid}" if spec.robots <= 10 else None,
            )
        ax2.axhline(1.0, color="red", ls="--", lw=1)
        ax2.axvline(MISSION_S, color="grey", ls=":", lw=1)
        ax2.set_yscale("log")
        ax2.set_xlabel("simulated time (s)")
        ax2.set_ylabel("distance to the ideal centroid (m)")
        ax2.set_title(f"each robot, {_label(plan, spec)}, seed {run.spec.seed}", fontsize=10)
        ax2.grid(alpha=0.3)
        if spec.robots <= 10:
            ax2.legend(fontsize=7, ncol=2)
    _save(fig, path)


def plot_bytes(plan: Plan, results: Sequence[RunResult], path: Path) -> None:
    """Figure 10: bytes per robot per step on the air (vs the XBee frame) and bundle content."""
    fig, axes = _figure(2, 1, (8.0, 7.0))
    top, bottom = axes[0][0], axes[1][0]
    for spec, rs in _cells(plan, results):
        times, mean, _, _ = _band(rs, "air_bytes_mean")
        _, peak, _, _ = _band(rs, "air_bytes_max")
        line = top.plot(times, mean, label=_label(plan, spec))[0]
        top.plot(times, peak, color=line.get_color(), ls=":", lw=0.8)
        times, content, _, _ = _band(rs, "bundle_bytes_mean")
        bottom.plot(times, content, color=line.get_color(), label=_label(plan, spec))
    top.axhline(XBEE_FRAME_BYTES, color="red", ls="--", lw=1, label="XBee frame (250 B)")
    top.axhline(XBEE_FRAME_BYTES / 2, color="orange", ls="--", lw=1, label="half a frame")
    top.set_ylabel("bytes on the air per robot per step")
    top.set_title(f"{plan.experiment.name}: radio load (solid: mean, dotted: max)", fontsize=10)
    bottom.axhline(BUNDLE_LIMIT_BYTES, color="red", ls="--", lw=1, label="ROSBuzz limit (190 B)")
    bottom.axhline(XBEE_FRAME_BYTES / 2, color="orange", ls="--", lw=1, label="half a frame")
    bottom.set_ylabel("Buzz bundle content per robot per step (mean)")
    bottom.set_xlabel("simulated time (s)")
    for ax in (top, bottom):
        ax.set_ylim(0, XBEE_FRAME_BYTES + 20)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    _save(fig, path)


__all__ = [
    "EXPERIMENTS",
    "Experiment",
    "ExperimentError",
    "Plan",
    "RunResult",
    "RunSpec",
    "check_script",
    "make_plan",
    "plot_bytes",
    "plot_experiment",
    "run_one",
    "run_plan",
    "shape_for",
    "summarize",
    "write_outputs",
]
