"""One swarm across worker processes: ticks per second at 1 process, 1 worker and W workers.

    python bench/sim_workers.py [--sizes 500,1000] [--seconds 3] [--warmup 10] [--workers 2]

For each size, the same seeded coverage mission (the scale bench's setup: a start grid at
the deployed density, 12.2 m apart, a 20 m radio range, takeoff, four hotspots, then
DEPLOY) runs three ways in turn: in one process (`Simulation`), and split across 1 and W
local worker processes (`DistributedSimulation`, as `sim run --workers`). After `--warmup`
simulated seconds (the scripts' first calls translate them), it times `--seconds` more
with the wall clock: the workers are other processes, so process time would miss them.
Each split run must end with the single-process run's summary, or the bench fails.

It prints ticks per second and the speed-up over one process, and for the split runs where
a tick's time went: the coordinator's own (serial) work and its wait for the workers (their
parallel part: stepping the robots, plus the transport). From the largest size's split run
it estimates, by Amdahl's law, a swarm of `--estimate` robots on `--cores` workers: the
serial part grows with the robots (their broadcasts, receptions and bundles all pass the
coordinator), the parallel part with the robots per worker. The machine is shared: read the
ratios, not the absolute speeds.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from fieldkit.sim.distributed import DistributedSimulation
from fieldkit.sim.simulator import TICK_S, Simulation

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the scale bench's scenario
from bench_args import at_least, seconds, sizes  # noqa: E402
from sim_scale import scenario  # noqa: E402


class Measured:
    """One way of running one size, per tick: wall seconds, the serial CPU seconds (the
    one process's, or the coordinator's) and the workers' CPU seconds (all of them)."""

    def __init__(self, label: str, wall: float, serial: float, workers: float) -> None:
        self.label = label
        self.wall = wall
        self.serial = serial
        self.workers = workers


def measure(robots: int, workers: list[int], warmup_s: float, seconds: float) -> list[Measured]:
    """The size run in one process, then split across each worker count."""
    warmup, ticks = round(warmup_s / TICK_S), round(seconds / TICK_S)
    config = scenario(robots, warmup_s + seconds)
    sim = Simulation(config)
    for _ in range(warmup):
        sim.step()
    t0, cpu0 = time.perf_counter(), time.process_time()
    for _ in range(ticks):
        sim.step()
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    want = sim.summary()
    out = [Measured("1 process", wall / ticks, cpu / ticks, 0.0)]
    for n in workers:
        split = DistributedSimulation(config, workers=n)
        try:
            for _ in range(warmup):
                split.step()
            split.timings.reset()
            t0 = time.perf_counter()
            for _ in range(ticks):
                split.step()
            wall = time.perf_counter() - t0
            got = split.summary()
        finally:
            split.close()
        if got != want:
            raise SystemExit(f"{robots} robots on {n} workers: not the single-process summary")
        t = split.timings
        serial, parallel = t.coordinator_cpu_s / ticks, t.workers_cpu_s / ticks
        out.append(Measured(f"--workers {n}", wall / ticks, serial, parallel))
    return out


def main() -> None:
    """Measure every size, print the table and the estimate."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument(
        "--sizes", type=sizes, default=[500, 1000], help="Robot counts (comma-separated)."
    )
    p.add_argument("--seconds", type=seconds, default=3.0, help="Simulated seconds timed.")
    p.add_argument("--warmup", type=seconds, default=10.0, help="Simulated seconds not timed.")
    p.add_argument("--workers", type=at_least(1), default=2, help="The split run's worker count.")
    p.add_argument("--estimate", type=at_least(1), default=10_000, help="Robots of the estimate.")
    p.add_argument("--cores", type=at_least(1), default=16, help="Workers of the estimate.")
    args = p.parse_args()
    if args.workers > args.sizes[0]:
        p.error(f"--workers {args.workers}: more workers than the {args.sizes[0]} robots to split")
    print(
        f"{'robots':>7} {'run':<12} {'ticks/s':>8} {'speed-up':>9}"
        f" {'serial CPU ms':>14} {'workers CPU ms':>15}"
    )
    last: list[Measured] = []
    for n in args.sizes:
        last = measure(n, sorted({1, args.workers}), args.warmup, args.seconds)
        base = last[0].wall
        for m in last:
            print(
                f"{n:7d} {m.label:<12} {1 / m.wall:8.2f} {base / m.wall:8.2f}x"
                f" {m.serial * 1e3:14.1f} {m.workers * 1e3:15.1f}",
                flush=True,
            )
    # Amdahl from the largest size's split run, in CPU time (which the machine's other
    # tenants do not inflate): the coordinator's work per robot stays serial, the workers'
    # divides among them. Transport latency and imbalance between parts come on top.
    n, split, one = args.sizes[-1], last[-1], last[0]
    serial = split.serial / n
    parallel = split.workers / n
    big, cores = args.estimate, args.cores
    tick = serial * big + parallel * big / cores
    share = serial / (serial + parallel)
    print(
        f"per robot and tick at {n}: one process {one.serial / n * 1e6:.1f} us CPU; split:"
        f" serial {serial * 1e6:.1f} us, parallel {parallel * 1e6:.1f} us"
        f" (serial share {share:.1%}: at most {1 / share:.1f}x from more workers)"
    )
    print(
        f"estimate: {big} robots on {cores} workers: {1 / tick:.1f} ticks/s"
        f" ({1 / tick * TICK_S:.2f}x real time)"
    )


if __name__ == "__main__":
    main()
