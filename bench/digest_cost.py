"""What the script-state digest a recording keeps per tick costs, as a share of a 10 Hz tick.

    python bench/digest_cost.py [--seconds S] [--repeat R]

A node that records (`--record`) hashes its script's state after every tick
(`bvm.digest.state_digest`), on top of what `bench/record_cost.py` measures for the bag. The
paper's two scripts are run for S simulated seconds on 6 robots (task allocation past its
RC 900, coverage past its RC 901, so their states hold the swarm, the task graph, the
stigmergy); then each robot's digest is timed, best of R. Reported per script: the mean and
the worst over the robots, in ms and as a share of the 100 ms tick.
"""

from __future__ import annotations

import argparse
import logging
import time

from bvm.digest import state_digest
from fieldkit.sim.experiments import make_plan
from fieldkit.sim.simulator import Simulation


def main(argv: list[str] | None = None) -> None:
    """Run both scripts, time the digests, print the table."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=40.0)
    p.add_argument("--repeat", type=int, default=20)
    args = p.parse_args(argv)
    logging.disable(logging.WARNING)
    for name in ("task-allocation", "coverage"):
        plan = make_plan(name, robots=[6], drops=[0.0], runs=1, seconds=args.seconds)
        sim = Simulation(plan.specs()[0].config())
        sim.run()
        costs = []
        for robot in sim.robots.values():
            best = float("inf")
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                state_digest(robot.runtime.vm)
                best = min(best, time.perf_counter() - t0)
            costs.append(best * 1e3)
        mean = sum(costs) / len(costs)
        print(
            f"{name}: digest {mean:.2f} ms mean, {max(costs):.2f} ms worst over 6 robots = "
            f"{mean / 100 * 100:.2f}% / {max(costs) / 100 * 100:.2f}% of the 100 ms tick"
        )


if __name__ == "__main__":
    main()
