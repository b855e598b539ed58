"""What memory costs a large swarm: the same robots' code, a few robots over and over
(their objects stay in the CPU caches) against every robot in turn (each robot's objects
have left the caches by its next turn).

    python bench/sim_memory.py [--mission coverage|task-allocation] [--robots 1000] [--at 150]

It runs the mission (bench/sim_scale.py's, from the ground) for `--at` ticks, then times,
for K robots spread over the swarm (K = 10, 50, 100, 300 and all), K robots in turn, again
and again:

- `sensor tables`: pushing a tick's sensor tables into the VM (ScriptAPI.before_step), the
  same work every time;
- `robot tick`: the robot's whole tick (RobotRuntime.tick: step, radio out, actuators)
  without the radio in: rounds after the first do other work than the mission would (no
  messages, stale neighbours), so this column only hints.

and prints CPU microseconds per robot for each K, and the ratio of all robots to 10. A
ratio near 1 means the swarm's size costs nothing per robot. On the machine of
docs/results.md the sensor tables, the same work every time, cost 2.7-3.9x as much at
1,000 robots as at 10: the code is the same, the difference is where its objects are.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path

from fieldkit.sim.simulator import SimRobot, Simulation, tuned_memory

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the scale bench's missions
from sim_scale import mission_scenario  # noqa: E402


def per_robot_us(robots: list[SimRobot], work: Callable[[SimRobot], object]) -> float:
    """CPU microseconds per call of `work` over `robots` in turn, about 4,000 calls."""
    rounds = max(1, 4000 // len(robots))
    t0 = time.process_time()
    for _ in range(rounds):
        for robot in robots:
            work(robot)
    return (time.process_time() - t0) / (rounds * len(robots)) * 1e6


def main(argv: list[str] | None = None) -> None:
    """Parse the command line, run the mission to `--at`, print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mission", choices=("coverage", "task-allocation"), default="coverage")
    ap.add_argument("--robots", type=int, default=1000)
    ap.add_argument("--at", type=int, default=150, help="ticks of the mission first")
    args = ap.parse_args(argv)
    with tuned_memory():
        sim = Simulation(mission_scenario(args.mission, args.robots, 1e6))
        while sim.tick < args.at:
            sim.step()
        everyone = list(sim.robots.values())

        def tables(robot: SimRobot) -> None:
            robot.runtime.api.before_step(robot.sensors, None)

        def tick(robot: SimRobot) -> None:
            robot.runtime.tick(sim._sensors(robot))

        sizes = [k for k in (10, 50, 100, 300) if k < len(everyone)] + [len(everyone)]
        print(f"{args.mission}, {len(everyone)} robots, from tick {sim.tick}: CPU us per robot")
        print(f"{'robots in turn':>14} {'sensor tables':>14} {'robot tick':>11}")
        first: tuple[float, float] | None = None
        last = (0.0, 0.0)
        for k in sizes:
            chosen = everyone[:: max(1, len(everyone) // k)][:k]
            last = (per_robot_us(chosen, tables), per_robot_us(chosen, tick))
            first = first or last
            print(f"{k:>14} {last[0]:>14.1f} {last[1]:>11.1f}")
        assert first is not None
        print(
            f"all robots / 10 robots: sensor tables {last[0] / first[0]:.2f}x,"
            f" robot tick {last[1] / first[1]:.2f}x"
        )


if __name__ == "__main__":
    main()
