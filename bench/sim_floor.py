"""What a simulated robot costs before its script does anything: the floor of a tick.

    python bench/sim_floor.py [--sizes 10,100,1000] [--robot-ticks 100000]

Real time at N robots leaves 0.1 s / N of CPU for each robot's tick: 100 µs at 1,000
robots. Part of that goes to what every robot does whatever its script: its sensors, the
sensor tables and neighbour columns pushed into its VM, the call of `step`, its bundle
encoded and broadcast, its heard table and radio receptions, its vehicle model. This bench
measures that floor with a script whose functions are empty, on the scale bench's start
grid and radio (bench/sim_scale.py: 12.2 m apart, 20 m range, about 8 robots in range),
robots on the ground, no command; then the same robots running each mission's script, idle
on the ground before any command (the script's own cost of waiting: its step, its
listeners, its status messages).

For each size it prints CPU microseconds per robot-tick (process time, one core, about
`--robot-ticks` robot-ticks after 10 ticks to warm up), and the floor as a share of the
real-time budget at that size.
Its last line is

    floor: F µs per robot-tick at N robots, P% of the real-time budget (B µs)

N the largest size measured. The floor is not one cost at every size: a few robots share
the work done once per tick for the whole swarm (the radio's positions, the neighbour
geometry's numpy calls), and in a large swarm each robot's objects have left the CPU caches
by its next turn (bench/sim_memory.py; docs/results.md measured the same few robots stepped
over and over at about half the floor of 1,000).
"""

from __future__ import annotations

import argparse
import gc
import sys
import tempfile
import time
from pathlib import Path

from fieldkit.sim.simulator import TICK_S, SimConfig, Simulation, tuned_memory

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the scale bench's grid and scripts
from sim_scale import RANGE_M, SCRIPT, SPACING_M, TA_SCRIPT  # noqa: E402

EMPTY = "function init() {}\nfunction step() {}\nfunction destroy() {}\n"
WARM_TICKS = 10
SCRIPTS = {"task allocation": TA_SCRIPT, "coverage": SCRIPT}


def per_robot_tick_us(script: Path, robots: int, ticks: int) -> float:
    """CPU microseconds per robot-tick of `robots` running `script` on the ground."""
    config = SimConfig(
        script=script,
        robots=robots,
        seconds=1e6,
        range_m=RANGE_M,
        spacing_m=SPACING_M,
        include_dirs=(str(script.parent),),
        seed=1,
    )
    gc.collect()  # the last size's swarm is gone before this one is timed
    with tuned_memory():  # as `Simulation.run` steps a swarm it has built
        sim = Simulation(config)
        for _ in range(WARM_TICKS):  # first calls translate the script's functions
            sim.step()
        t0 = time.process_time()
        for _ in range(ticks):
            sim.step()
        spent = time.process_time() - t0
    return spent / (ticks * robots) * 1e6


def main(argv: list[str] | None = None) -> None:
    """Measure the floor and each script idle at each size; the last line sums up."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="10,100,1000", help="robot counts, comma-separated")
    ap.add_argument(
        "--robot-ticks", type=int, default=100_000, help="robot-ticks timed at each size"
    )
    args = ap.parse_args(argv)
    try:
        sizes = sorted({int(s) for s in args.sizes.split(",")})
    except ValueError:
        ap.error(f"--sizes: a comma-separated list of robot counts, got {args.sizes!r}")
    if args.robot_ticks < 1 or sizes[0] < 1:
        ap.error("--robot-ticks and every size must be at least 1")
    names = ["empty script", *(f"{name} idle" for name in SCRIPTS)]
    print(f"{'robots':>7s} {'budget µs':>10s} " + " ".join(f"{n:>22s}" for n in names))
    floor = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        empty = Path(tmp) / "empty.bzz"
        empty.write_text(EMPTY)
        for n in sizes:
            budget = TICK_S / n * 1e6
            ticks = max(1, args.robot_ticks // n)
            floor = per_robot_tick_us(empty, n, ticks)
            cells = [f"{floor:8.1f} µs ({floor / budget:4.0%})"]
            for script in SCRIPTS.values():
                us = per_robot_tick_us(script, n, ticks)
                cells.append(f"{us:8.1f} µs ({us - floor:+5.1f})")
            print(f"{n:7d} {budget:10.1f} " + " ".join(f"{c:>22s}" for c in cells), flush=True)
    budget = TICK_S / sizes[-1] * 1e6
    print(
        f"floor: {floor:.1f} µs per robot-tick at {sizes[-1]} robots, "
        f"{floor / budget:.0%} of the real-time budget ({budget:.0f} µs)"
    )


if __name__ == "__main__":
    main()
