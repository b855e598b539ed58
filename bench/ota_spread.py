"""How long an over-the-air update takes to reach and switch a whole swarm, and its bytes.

    python bench/ota_spread.py [--sizes 10,50,200] [--drops 0,0.5,0.8] [--seeds 5]
        [--big-seeds 1] [--topologies line,rgg] [--workers 1] [--out DIR]

Every robot runs `buzz_scripts/examples/hello.bzz`; at simulated second INJECT_S (20 s, once
every robot has heard the others' barrier entries for a while) the operator's update to a
changed hello (a real signed, encrypted bsdiff patch, `fieldkit.sim.updates`) is handed to
robot 1, and the swarm spreads, verifies, agrees on and switches to it over the simulated
radio, with the drop rate of the cell on every link. Two layouts:

* line: robots in one row SPACING_M (10 m) apart with RANGE_M (45 m) of radio range, so a
  robot hears the 4 nearest on each side; robot 1 is at one end, so the patch crosses the
  whole line: ceil((N-1)/4) hops (3, 13, 50 for 10, 50, 200 robots; computed from the
  positions, printed);
* rgg: a random geometric graph, positions drawn uniformly (seeded) in a square sized for
  RGG_DEGREE (8) robots in range of each robot on average; a draw that is not connected is
  drawn again with the next seed (the draw seed is reported), and its diameter in hops is
  computed and reported.

Reported per run: the time from injection to the first tick every robot runs the new version
(`update.all_switched_s - update.injected_s` of the simulator's summary), whether the update
was rolled back, whether the run ended split (robots on different `script_versions`), the
summary's `update_bytes_sent` (all update frames from t = 0), the update bytes and the bundle
bytes put on the air between injection and the last switch, and the wall time. A run stops
STOP_AFTER_S after every robot left its grace period on one version (nothing can change
after that but a new update), or at MAX_S (300 s) of simulated time.

Run k of a cell has seed k (the simulator's seed: radio losses, the update's keys are
random but change no timing); the RGG layout of run k is drawn from seed k too. The same
arguments give the same `summary.json` (wall times are kept apart, in `wall_s` per run, and
left out with `--no-wall`). Writes `DIR/summary.json` and `DIR/plot.png` (default
docs/results/ota-spread) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import random
import statistics
import time
from collections import deque
from collections.abc import Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from contextlib import nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path

import bvm
from fieldkit.sim.simulator import TICK_S, SimConfig, Simulation, StartPose, tuned_memory
from fieldkit.sim.updates import SimUpdate
from fieldkit.update.agent import Switch
from fieldkit.update.packets import Phase
from fieldkit.update.release import Release

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "buzz_scripts" / "examples" / "hello.bzz"
OUT = ROOT / "docs" / "results" / "ota-spread"
SPACING_M = 10.0
RANGE_M = 45.0
RGG_DEGREE = 8.0  # mean robots in range of one robot in the random layout
INJECT_S = 20.0
MAX_S = 300.0
STOP_AFTER_S = 5.0
#: The update: hello.bzz with a new state name and a second hello topic (a real change of
#: code, constants and debug info, so the patch carries all three deltas).
NEW_STEP = (
    'neighbors.broadcast("hello", id)\n'
    '  neighbors.broadcast("hello2", steps)\n'
    '  BVMSTATE = "UPDATED"'
)


def base_program() -> bvm.Program:
    """What every robot runs at the start: hello.bzz, compiled under a fixed name (the
    debug info holds the path: the patch's size must not depend on where the repo is)."""
    return bvm.compile_source(SCRIPT.read_text(), "/bench/hello.bzz")


def new_release() -> Release:
    """The version the update brings: hello.bzz, changed."""
    source = SCRIPT.read_text().replace('neighbors.broadcast("hello", id)', NEW_STEP, 1)
    assert "hello2" in source, "hello.bzz changed: the bench's edit no longer applies"
    return Release.from_program(bvm.compile_source(source, "/bench/hello-v2.bzz"))


# ------------------------------------------------------------------ layouts


Positions = dict[int, tuple[float, float]]


def line_layout(n: int) -> Positions:
    """Robots 1..n in one row, SPACING_M apart, robot 1 at one end."""
    return {k + 1: (k * SPACING_M, 0.0) for k in range(n)}


def hops_from(positions: Mapping[int, tuple[float, float]], source: int) -> dict[int, int]:
    """Hops from `source` to every robot it reaches (in range: distance <= RANGE_M, as the
    simulated radio decides)."""
    ids = list(positions)
    dist = {source: 0}
    queue = deque([source])
    while queue:
        a = queue.popleft()
        ax, ay = positions[a]
        for b in ids:
            if b not in dist:
                bx, by = positions[b]
                if math.hypot(ax - bx, ay - by) <= RANGE_M:
                    dist[b] = dist[a] + 1
                    queue.append(b)
    return dist


@dataclass(frozen=True)
class Layout:
    """Where the robots are, and the graph's figures."""

    positions: Positions
    draw_seed: int  # the seed the positions were drawn with (rgg; the line: -1)
    diameter: int  # hops between the two robots farthest apart
    from_source: int  # hops from robot 1 (where the update is injected) to the farthest


def describe(positions: Positions, draw_seed: int) -> Layout | None:
    """The layout's hop counts; None if the graph is not connected."""
    ecc = []
    for rid in positions:
        d = hops_from(positions, rid)
        if len(d) < len(positions):
            return None
        ecc.append(max(d.values()))
    return Layout(positions, draw_seed, max(ecc), max(hops_from(positions, 1).values()))


def rgg_layout(n: int, seed: int) -> Layout:
    """A connected random geometric graph of n robots: uniform positions in a square sized
    for RGG_DEGREE neighbours each, drawn again with the next seed until connected."""
    side = RANGE_M * math.sqrt(math.pi * n / RGG_DEGREE)
    draw = seed
    while True:
        rng = random.Random(f"ota-rgg:{n}:{draw}")
        positions = {k + 1: (rng.uniform(0, side), rng.uniform(0, side)) for k in range(n)}
        layout = describe(positions, draw)
        if layout is not None:
            return layout
        draw += 1000  # the next seed of this run, far from the other runs' seeds


def layout_for(topology: str, n: int, seed: int) -> Layout:
    """The robots' layout of one run."""
    if topology == "line":
        # A line's hops: robot 1 is at one end, so its eccentricity is the diameter.
        positions = line_layout(n)
        far = max(hops_from(positions, 1).values())
        return Layout(positions, -1, far, far)
    if topology == "rgg":
        return rgg_layout(n, seed)
    raise ValueError(f"topology {topology!r}: expected line or rgg")


# ------------------------------------------------------------------ one run


@dataclass(frozen=True)
class Run:
    """The figures of one update of one swarm (summary.json's `runs`)."""

    topology: str
    robots: int
    drop: float
    seed: int
    draw_seed: int  # the rgg's positions' seed (-1: the line)
    diameter_hops: int
    hops_from_source: int  # from robot 1, where the update is injected
    switch_s: float | None  # injection to every robot on the new version (None: never)
    rolled_back: bool
    reason: str | None
    split: bool  # robots on different versions at the end
    on_new_version: int  # robots running the new version at the end
    patch_bytes: int
    update_bytes_sent: int  # the summary's: every update frame from t = 0 to the end
    spread_update_bytes: int | None  # update frames, injection to the last switch
    spread_bundle_bytes: int | None  # bundles (Buzz traffic), over the same ticks
    quiet_update_bytes_per_robot_s: float  # before the injection: STATUS and barrier entries
    live_at_inject_min: int  # robots a robot counts as live (waits for) at the injection
    live_at_inject_mean: float
    # Robots that switched from standby, their barrier passed (every live robot ready, or
    # one already running the version); the others caught up without standing by.
    switched_on_agreement: int
    seconds_simulated: float
    script_errors: int
    wall_s: float


def run_one(topology: str, n: int, drop: float, seed: int) -> Run:
    """One update of an n-robot swarm at this drop rate; its figures (see the module doc)."""
    layout = layout_for(topology, n, seed)
    new = new_release()
    config = SimConfig(
        script=SCRIPT,
        program=base_program(),
        robots=n,
        drop=drop,
        range_m=RANGE_M,
        seconds=MAX_S,
        seed=seed,
        start={rid: StartPose(x, y) for rid, (x, y) in layout.positions.items()},
        updates=[SimUpdate(INJECT_S, new, 1, "hello-v2.bzz")],
    )
    wall0 = time.perf_counter()
    sim = Simulation(config)
    updates = sim.updates
    assert updates is not None
    agents = [u.agent for u in updates.updaters.values()]
    inject_tick = round(INJECT_S / TICK_S)
    at_inject = at_switch = (0, 0)  # (update bytes, all bytes) sent by then
    switched_tick: int | None = None
    known: list[int] = []
    settled_at: int | None = None
    total = round(MAX_S / TICK_S)
    with tuned_memory():
        while sim.tick < total:
            if sim.tick == inject_tick:
                at_inject = (updates.bytes_sent(), sum(sim.radio.bytes_sent.values()))
                # How full the barrier tables are when the update arrives: the robots each
                # one counts as live (and so waits for), out of the n - 1 others.
                known = [len(a.live()) for a in agents]
            sim.step()
            record = updates.records[-1] if updates.records else None
            if record is None:
                continue
            if switched_tick is None and record.all_switched_s is not None:
                switched_tick = sim.tick
                at_switch = (updates.bytes_sent(), sum(sim.radio.bytes_sent.values()))
            # Every robot out of its grace period, on one version, nothing staged: only a
            # new update could change anything now (a split never settles: it runs on).
            settled = all(a.phase is Phase.RUNNING and a.staged is None for a in agents) and (
                len({a.version for a in agents}) == 1
            )
            if settled and (record.all_switched_s is not None or record.rolled_back):
                settled_at = sim.tick if settled_at is None else settled_at
                if sim.tick - settled_at >= round(STOP_AFTER_S / TICK_S):
                    break
            else:
                settled_at = None
    wall = time.perf_counter() - wall0
    record = updates.records[-1]
    versions = updates.versions()
    spread_update = spread_bundle = None
    if switched_tick is not None:
        spread_update = at_switch[0] - at_inject[0]
        spread_bundle = (at_switch[1] - at_inject[1]) - spread_update
    agreed = sum(
        isinstance(a, Switch) and a.reason == "the swarm agreed"
        for u in updates.updaters.values()
        for _, a in u.actions
    )
    return Run(
        topology=topology,
        robots=n,
        drop=drop,
        seed=seed,
        draw_seed=layout.draw_seed,
        diameter_hops=layout.diameter,
        hops_from_source=layout.from_source,
        switch_s=None
        if record.all_switched_s is None
        else round(record.all_switched_s - record.injected_s, 6),
        rolled_back=record.rolled_back,
        reason=record.reason,
        split=len(set(versions.values())) > 1,
        on_new_version=sum(v == new.hash for v in versions.values()),
        patch_bytes=record.patch_bytes,
        update_bytes_sent=updates.bytes_sent(),
        spread_update_bytes=spread_update,
        spread_bundle_bytes=spread_bundle,
        quiet_update_bytes_per_robot_s=round(at_inject[0] / n / INJECT_S, 3),
        live_at_inject_min=min(known),
        live_at_inject_mean=round(statistics.fmean(known), 1),
        switched_on_agreement=agreed,
        seconds_simulated=round(sim.tick * TICK_S, 6),
        script_errors=len(sim.errors),
        wall_s=round(wall, 1),
    )


# ------------------------------------------------------------------ the grid


@dataclass(frozen=True)
class Cell:
    """A grid cell's figures over its runs (summary.json's `cells`)."""

    topology: str
    robots: int
    drop: float
    runs: int
    diameter_hops: list[int]  # the distinct diameters of its layouts
    all_switched: int  # runs in which every robot switched
    rolled_back: int
    split: int
    switch_s: list[float]  # of the runs that switched, by seed
    switch_s_median: float | None
    switch_s_max: float | None
    spread_update_bytes_median: float | None
    spread_bundle_bytes_median: float | None
    update_bytes_per_robot_s_median: float | None  # during the spread
    live_at_inject_min: int
    patch_bytes: int

    @classmethod
    def of(cls, runs: Sequence[Run]) -> Cell:
        """The cell of these runs (all of one topology, size and drop rate)."""
        first = runs[0]
        times = [r.switch_s for r in runs if r.switch_s is not None]
        spread = [r.spread_update_bytes for r in runs if r.spread_update_bytes is not None]
        bundle = [r.spread_bundle_bytes for r in runs if r.spread_bundle_bytes is not None]
        rate = [
            r.spread_update_bytes / r.robots / r.switch_s
            for r in runs
            if r.spread_update_bytes is not None and r.switch_s
        ]
        return cls(
            topology=first.topology,
            robots=first.robots,
            drop=first.drop,
            runs=len(runs),
            diameter_hops=sorted({r.diameter_hops for r in runs}),
            all_switched=len(times),
            rolled_back=sum(r.rolled_back for r in runs),
            split=sum(r.split for r in runs),
            switch_s=times,
            switch_s_median=statistics.median(times) if times else None,
            switch_s_max=max(times) if times else None,
            spread_update_bytes_median=statistics.median(spread) if spread else None,
            spread_bundle_bytes_median=statistics.median(bundle) if bundle else None,
            update_bytes_per_robot_s_median=round(statistics.median(rate), 1) if rate else None,
            live_at_inject_min=min(r.live_at_inject_min for r in runs),
            patch_bytes=first.patch_bytes,
        )


def table(cells: Sequence[Cell]) -> str:
    """The printed (and docs/results.md) table, in Markdown."""
    lines = [
        "| layout | robots | hops (diameter) | drop | all switched | rolled back | split"
        " | time to switch, s (median, max) | update bytes, spread (median)"
        " | per robot per s | bundle bytes meanwhile |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in cells:
        lo, hi = c.diameter_hops[0], c.diameter_hops[-1]
        hops = str(lo) if lo == hi else f"{lo}-{hi}"
        med, worst = c.switch_s_median, c.switch_s_max
        timing = "never" if med is None or worst is None else f"{med:.1f}, {worst:.1f}"
        rate = (
            "-"
            if c.update_bytes_per_robot_s_median is None
            else (f"{c.update_bytes_per_robot_s_median:,.0f} B")
        )
        lines.append(
            f"| {c.topology} | {c.robots} | {hops} | {c.drop:g}"
            f" | {c.all_switched}/{c.runs} | {c.rolled_back} | {c.split} | {timing}"
            f" | {_kb(c.spread_update_bytes_median)} | {rate}"
            f" | {_kb(c.spread_bundle_bytes_median)} |"
        )
    return "\n".join(lines)


def _kb(v: float | None) -> str:
    return "-" if v is None else f"{v / 1000:,.0f} kB"


def plot(cells: Sequence[Cell], runs: Sequence[Run], path: Path) -> None:
    """Time to switch against swarm size, a line per drop rate, line and RGG side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import ScalarFormatter

    topologies = list(dict.fromkeys(c.topology for c in cells))
    fig, axs = plt.subplots(1, len(topologies), figsize=(5.5 * len(topologies), 4.2), sharey=True)
    axes = [axs] if len(topologies) == 1 else list(axs)
    drops = sorted({c.drop for c in cells})
    never = MAX_S - INJECT_S
    for ax, topology in zip(axes, topologies, strict=True):
        for k, drop in enumerate(drops):
            mine = [c for c in cells if c.topology == topology and c.drop == drop]
            color = f"C{k}"
            done = [c for c in mine if c.switch_s_median is not None]
            ax.plot(
                [c.robots for c in done],
                [c.switch_s_median for c in done],
                "-o",
                color=color,
                label=f"drop {drop:g}: median",
            )
            for r in runs:
                if r.topology == topology and r.drop == drop:
                    if r.switch_s is None:  # never: a cross at the end of the run
                        ax.plot(r.robots, never, "x", color=color, ms=8)
                    else:
                        ax.plot(r.robots, r.switch_s, ".", color=color, alpha=0.5)
        ax.set_xscale("log")
        ax.set_xticks(sorted({c.robots for c in cells}))
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.set_xlabel("robots")
        ax.set_title(
            f"line ({SPACING_M:g} m apart, {RANGE_M:g} m range)"
            if topology == "line"
            else f"random geometric graph (~{RGG_DEGREE:g} in range)"
        )
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("injection to every robot switched (s)")
    axes[0].legend(loc="upper left", fontsize=8)
    fig.suptitle(f"Over-the-air update: time for every robot to switch (x: not in {never:g} s)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _run_job(job: tuple[str, int, float, int]) -> Run:
    return run_one(*job)


def main(argv: Sequence[str] | None = None) -> None:
    """Run the grid, write summary.json and plot.png, print the table."""
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--sizes", default="10,50,200")
    ap.add_argument("--drops", default="0,0.5,0.8")
    ap.add_argument("--topologies", default="line,rgg")
    ap.add_argument("--seeds", type=int, default=5, help="runs per cell (seeds 0..)")
    ap.add_argument("--big", type=int, default=200, help="sizes from this one get --big-seeds")
    ap.add_argument("--big-seeds", type=int, default=1)
    ap.add_argument("--workers", type=int, default=1, help="processes (1: in this one)")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--no-wall", action="store_true", help="leave wall times out of the files")
    args = ap.parse_args(argv)
    # The robots' standby and resume lines are the runtime's warnings: hundreds per run.
    logging.getLogger("fieldkit").setLevel(logging.ERROR)
    grid = [
        (t, int(n), float(d))
        for t in args.topologies.split(",")
        for n in args.sizes.split(",")
        for d in args.drops.split(",")
    ]
    jobs = [
        (t, n, d, k)
        for t, n, d in grid
        for k in range(args.big_seeds if n >= args.big else args.seeds)
    ]
    # The largest swarms first: the workers then finish together.
    jobs.sort(key=lambda j: -j[1])
    wall0 = time.perf_counter()
    runs: list[Run] = []
    with ProcessPoolExecutor(args.workers) if args.workers > 1 else nullcontext() as pool:
        results = pool.map(_run_job, jobs) if pool is not None else map(_run_job, jobs)
        for r in results:
            runs.append(r)
            print(
                f"  {r.topology:4s} {r.robots:4d} robots, drop {r.drop:<4g} seed {r.seed}:"
                f" switched in {r.switch_s} s, rolled back {r.rolled_back}, split {r.split},"
                f" wall {r.wall_s} s",
                flush=True,
            )
    runs.sort(key=lambda r: (grid.index((r.topology, r.robots, r.drop)), r.seed))
    cells = [Cell.of([r for r in runs if (r.topology, r.robots, r.drop) == g]) for g in grid]
    run_dicts = [asdict(r) for r in runs]
    if args.no_wall:
        for d in run_dicts:
            del d["wall_s"]
    args.out.mkdir(parents=True, exist_ok=True)
    result = {
        "script": str(SCRIPT.relative_to(ROOT)),
        "spacing_m": SPACING_M,
        "range_m": RANGE_M,
        "rgg_degree": RGG_DEGREE,
        "inject_s": INJECT_S,
        "max_s": MAX_S,
        "cells": [asdict(c) for c in cells],
        "runs": run_dicts,
    }
    (args.out / "summary.json").write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    plot(cells, runs, args.out / "plot.png")
    print(table(cells))
    print(f"wrote {args.out / 'summary.json'} and {args.out / 'plot.png'}")
    print(f"wall time {time.perf_counter() - wall0:.0f} s")


if __name__ == "__main__":
    main()
