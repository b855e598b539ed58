"""Deliveries per second through the simulator's radio model, for 1,000 and 5,000 robots.

    python bench/radio_speed.py [--ticks T] [--neighbors K] [--seed S] [--sizes 1000 5000]

Robots are spread uniformly over a square sized so that each hears about K others (density
K / (pi range^2)); each tick every robot moves a little, the grid is rebuilt, every robot
broadcasts one 120-byte bundle, and the due deliveries are collected. Two link models: a
lossless fixed-delay one (the fast path) and a realistic one (Gilbert-Elliott bursts of 10%
mean loss, 1-tick jitter, a 232-byte bandwidth). Reported: deliveries per second of the radio's
wall time per tick (set_positions with its grid, broadcasts, deliveries; the moves are made
beforehand), best of the runs.
"""

from __future__ import annotations

import argparse
import math
import random
import time

from fieldkit.sim.radio import LinkModel, RadioModel

RANGE = 50.0


def run(n: int, model: LinkModel, ticks: int, neighbors: float, seed: int) -> tuple[int, float]:
    """(deliveries, seconds) for `ticks` ticks of `n` robots."""
    rng = random.Random(seed)
    side = RANGE * math.sqrt(math.pi * n / neighbors)
    pos = {i: (rng.uniform(0, side), rng.uniform(0, side), 0.0) for i in range(n)}
    radio = RadioModel(model, seed)
    data = bytes(120)
    # The robots' moves are made up front: only the radio's work is timed.
    frames = []
    for _ in range(ticks):
        pos = {
            i: (x + rng.uniform(-1, 1), y + rng.uniform(-1, 1), z) for i, (x, y, z) in pos.items()
        }
        frames.append(pos)
    delivered = 0
    t0 = time.perf_counter()
    for step, frame in enumerate(frames):
        radio.set_positions(frame)
        for i in range(n):
            radio.broadcast(step, i, data)
        delivered += len(radio.deliveries(step))
    return delivered, time.perf_counter() - t0


def main() -> None:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--ticks", type=int, default=20)
    ap.add_argument("--neighbors", type=float, default=10.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 5000])
    args = ap.parse_args()
    models = {
        "lossless": LinkModel(range_m=RANGE),
        "bursty": LinkModel.bursty(0.1, 4.0, range_m=RANGE, jitter=1, bandwidth=232),
    }
    for n in args.sizes:
        for name, model in models.items():
            best = math.inf
            delivered = 0
            for _ in range(args.repeat):
                delivered, seconds = run(n, model, args.ticks, args.neighbors, args.seed)
                best = min(best, seconds)
            per_tick = delivered / args.ticks
            print(
                f"{n:6d} robots, {name:8s}: {per_tick / n:5.1f} neighbours heard/robot,"
                f" {delivered / best:,.0f} deliveries/s, {best / args.ticks * 1000:.1f} ms/tick"
            )


if __name__ == "__main__":
    main()
