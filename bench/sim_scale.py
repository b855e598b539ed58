"""The largest swarm the simulator runs at real time on one core, with the coverage behavior.

    python bench/sim_scale.py [--sizes 750,1000,1250] [--measure 7]
    python bench/sim_scale.py --mission task-allocation|coverage [--sizes 250,500,1000] [--at M]

Real time: 10 ticks per simulated second for every robot, so a swarm of N robots runs at
real time when one tick of all N robots takes at most 0.1 s. For each size the robots take
off, learn four hotspots spanning a square region sized for the swarm (about 150 m² each),
and run the Voronoi coverage (RC 901). The bench measures the CPU time (process time: this
process, one core) of `--measure` simulated seconds of coverage, once every robot deploys
and the command's barrier gossip has died down (its entries spread to every robot: a burst
that grows with the swarm, ~10 s at 500 robots; the "gossip s" column), in one-second
windows. It prints the median ticks per second of those windows at each size, and of the
whole run from takeoff (which includes the translation of every robot's script and the
barriers, slower than real time), and the largest real-time size, interpolated between
the two sizes that bracket 10 ticks/s (or the largest size measured, if all are real time).

Robots start on a grid at the density of the deployment (one per 150 m², 12.2 m apart) with
a 20 m radio range, so each hears about 8 others, as in the deployed swarm; the radio drops
nothing (losses make less traffic).

With `--mission`, the whole mission instead, from the ground, on the same start grid and radio:
RC 22 (takeoff) to robot 1 at 0.5 s, then the behaviour's code at 6 s, the command's barrier,
the behaviour, to its end:

- coverage: the four hotspots as above, RC 901; the end is COVER_S simulated seconds after
  the last robot enters DEPLOY.
- task-allocation: RC 900 with the graph P (6 tasks, ROOT_ID robot 1 in the grid's corner):
  6 robots take a task, every other one stays FREE (a reserve that closes in on the nodes
  about to open, and keeps scanning what it hears), the case of a swarm much larger than its
  task graph. The end is the shape formed: every label held by a robot JOINED or LOCK. (The
  paper's larger graphs are no fit for a 20 m range: YLOPPOLY is 128 m long, and its far
  labels' predecessors are out of range of the robots that could take them; in a trial
  250 robots had not formed it 240 s after the command.) A run that has not formed it
  MISSION_CAP_S after the command stops there, reported as "not done".

For each size it prints the ticks per second over the whole run (CPU process time of this
process, building the simulation and translating every robot's script included: one core),
the same as a multiple of real time, the CPU seconds of each phase (start-up: building the
simulation; takeoff: while any robot is still TURNEDOFF or TAKEOFF; barrier: then while any
is in BARRIERWAIT or IDLE, the takeoff's and the command's barriers; behaviour: every robot
in the behaviour's states), the simulated seconds, the CPU microseconds per robot-tick of
each phase after start-up (real time allows 0.1 s / N: 100 µs at 1,000 robots;
bench/sim_floor.py measures how much of it a robot costs before its script does
anything), and the outcome. Its last line is

    whole mission: N robots at >= real time (R ticks/s at M robots)

N the largest swarm whose whole mission runs at 10 ticks/s or more, interpolated as the
steady state's is between the two measured sizes that bracket 10 ticks/s (0 if no size
does; "at least" the largest measured if all do); R the measured ticks per second at M robots, the
largest size measured unless `--at M` names another measured size.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import math
import os
import platform
import statistics
import sys
import time
from pathlib import Path

from fieldkit.robot import geo
from fieldkit.sim.simulator import (
    DEFAULT_ORIGIN,
    TICK_S,
    RcCommand,
    SimConfig,
    Simulation,
    tuned_memory,
)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_args import seconds, sizes  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "buzz_scripts" / "coverage.bzz"
AREA_PER_ROBOT_M2 = 150.0
SPACING_M = math.sqrt(AREA_PER_ROBOT_M2)  # start at the deployed density
RANGE_M = 20.0
DEPLOY_AT_S = 8.0  # after takeoff and the hotspots
SETTLE_S = 6.0  # after the last robot deploys at least: the barrier lingers 50 steps
QUIET = 3.0  # messages received per robot per step: the coverage alone receives ~1.7
MAX_GOSSIP_S = 120.0

# --mission
TA_SCRIPT = ROOT / "buzz_scripts" / "task_allocation.bzz"
TA_SHAPE = "P"  # 6 tasks within 12 m of the root: it forms in range of one another
TA_TASKS = 6
MISSION_TAKEOFF_S = 0.5
MISSION_COMMAND_S = 6.0
COVER_S = 10.0  # coverage after the last robot deploys
MISSION_CAP_S = 240.0  # after the command: a mission not done by then is reported as such
MISSIONS = ("task-allocation", "coverage")
PHASES = ("start-up", "takeoff", "barrier", "behaviour")
_GROUND = frozenset({"TURNEDOFF", "TAKEOFF"})
_WAITING = frozenset({"BARRIERWAIT", "IDLE"})


def scenario(robots: int, seconds: float) -> SimConfig:
    """Takeoff, four hotspots around the swarm's start, then DEPLOY."""
    frame = geo.LocalFrame(*DEFAULT_ORIGIN)
    side = math.sqrt(robots * AREA_PER_ROBOT_M2)
    start = math.ceil(math.sqrt(robots)) * SPACING_M  # the start grid's side
    centre = start / 2.0
    commands = [RcCommand(0.5, 1, 22)]
    for k, (dx, dy) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
        east, north = centre + dx * side / 2.0, centre + dy * side / 2.0
        lat, lon, _ = frame.to_gps(east, north, 0.0)
        commands.append(RcCommand(1.0 + 0.2 * k, 1, 16, (50.0 + k, lat, lon, 0.0)))
    commands.append(RcCommand(DEPLOY_AT_S - 2.0, 1, 901))
    return SimConfig(
        script=SCRIPT,
        robots=robots,
        seconds=seconds,
        range_m=RANGE_M,
        spacing_m=SPACING_M,
        commands=commands,
        include_dirs=(str(ROOT / "buzz_scripts"),),
        seed=1,
    )


def mission_scenario(mission: str, robots: int, seconds: float) -> SimConfig:
    """The whole `mission` from the ground: RC 22, then the behaviour's code (see the top)."""
    if mission == "coverage":
        config = scenario(robots, seconds)
        config.commands = [
            RcCommand(MISSION_TAKEOFF_S, 1, 22),
            *config.commands[1:-1],
            RcCommand(MISSION_COMMAND_S, 1, 901),
        ]
        return config
    return SimConfig(
        script=TA_SCRIPT,
        robots=robots,
        seconds=seconds,
        range_m=RANGE_M,
        spacing_m=SPACING_M,
        commands=[RcCommand(MISSION_TAKEOFF_S, 1, 22), RcCommand(MISSION_COMMAND_S, 1, 900)],
        include_dirs=(str(ROOT / "buzz_scripts"),),
        globals={"SHAPE": TA_SHAPE},
        seed=1,
    )


def _phase(sim: Simulation) -> str:
    """The phase of the swarm: that of its least advanced robot."""
    states = {r.state for r in sim.robots.values()}
    if states & _GROUND or None in states:  # None: before the first step
        return "takeoff"
    if states & _WAITING:
        return "barrier"
    return "behaviour"


def _labels_held(sim: Simulation) -> int:
    """How many distinct labels of the task graph robots hold, JOINED or LOCK."""
    labels = set()
    for r in sim.robots.values():
        if r.state == "JOINED" or r.state == "LOCK":
            labels.add(r.vm.globals.get("TA_LABEL"))
    return len(labels)


def mission_rate(
    mission: str, robots: int
) -> tuple[float, dict[str, float], dict[str, int], float, str]:
    """CPU-time ticks per second of the whole `mission` at `robots`; the CPU seconds and the
    ticks of each phase; the simulated seconds; the outcome."""
    cap = round((MISSION_COMMAND_S + MISSION_CAP_S) / TICK_S)
    cpu = dict.fromkeys(PHASES, 0.0)
    ticks = dict.fromkeys(PHASES, 0)
    gc.collect()  # what the last size left is not this one's start-up
    t0 = time.process_time()
    sim = Simulation(mission_scenario(mission, robots, 1e6))
    cpu["start-up"] = time.process_time() - t0
    tasks = min(robots, TA_TASKS)  # a smaller swarm never forms it: "not done"
    end: int | None = None
    outcome = "not done"
    with tuned_memory():  # as `Simulation.run` steps a swarm it has built
        while sim.tick < cap:
            phase = _phase(sim)
            t1 = time.process_time()
            sim.step()
            cpu[phase] += time.process_time() - t1
            ticks[phase] += 1
            end, outcome = _mission_end(mission, sim, phase, tasks, end, outcome)
            if end is not None and sim.tick >= end:
                if mission == "coverage":
                    outcome = "covered"
                break
    total = time.process_time() - t0
    return sim.tick / total, cpu, ticks, sim.tick * TICK_S, outcome


def _mission_end(
    mission: str, sim: Simulation, phase: str, tasks: int, end: int | None, outcome: str
) -> tuple[int | None, str]:
    """The tick the mission ends at (None: not known yet) and its outcome so far."""
    if end is None and phase == "behaviour":
        if mission == "coverage":
            if all(r.state == "DEPLOY" for r in sim.robots.values()):
                end = sim.tick + round(COVER_S / TICK_S)
        elif _labels_held(sim) >= tasks:
            end = sim.tick
            outcome = f"{TA_SHAPE} formed"
    return end, outcome


def ticks_per_second(robots: int, measure_s: float) -> tuple[float, float, float, dict[str, int]]:
    """CPU-time ticks per second of `robots` covering, and over the whole run from takeoff;
    how long the command's gossip lasted after the last robot deployed; the robots' states."""
    cap = DEPLOY_AT_S + 60.0  # every size here deploys well before: a bug if not
    sim = Simulation(scenario(robots, 1e6))
    t0 = time.process_time()
    deployed = None
    while deployed is None:
        sim.step()
        if all(r.state == "DEPLOY" for r in sim.robots.values()):
            deployed = sim.tick
        elif sim.tick * TICK_S > cap:
            raise RuntimeError(f"{robots} robots: not all deploying after {cap:.0f} s")
    # Then the barrier's entries spread to every robot (a burst of gossip that grows with
    # the swarm) before traffic settles to the coverage's own.
    window = round(1.0 / TICK_S)
    received = sum(r.vm.counters["received"] for r in sim.robots.values())
    while True:
        for _ in range(window):
            sim.step()
        now = sum(r.vm.counters["received"] for r in sim.robots.values())
        rate, received = (now - received) / (window * robots), now
        settled = rate < QUIET and sim.tick >= deployed + round(SETTLE_S / TICK_S)
        if settled or sim.tick > deployed + round(MAX_GOSSIP_S / TICK_S):
            break
    gossip_s = (sim.tick - deployed) * TICK_S
    # One-second windows, and their median: on a shared (virtual) machine a window now
    # and then runs much slower for reasons outside this process.
    rates = []
    for _ in range(max(1, round(measure_s))):
        t1 = time.process_time()
        for _ in range(window):
            sim.step()
        rates.append(window / (time.process_time() - t1))
    t2 = time.process_time()
    states: dict[str, int] = {}
    for r in sim.robots.values():
        states[str(r.state)] = states.get(str(r.state), 0) + 1
    return statistics.median(rates), sim.tick / (t2 - t0), gossip_s, states


def machine() -> str:
    """The processor, its count of CPUs and the Python: what these figures belong to (the same
    code ran 1.76x faster on one 2-core VM than on another, see docs/results.md)."""
    model = platform.processor() or platform.machine()
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.partition(":")[2].strip()
                break
    return f"machine: {model}, {os.cpu_count()} CPUs, Python {platform.python_version()}"


def largest_real_time(results: list[tuple[int, float]]) -> int:
    """The largest swarm at >= 10 ticks/s: interpolated between the two measured sizes
    that bracket it (the largest measured if all are real time; 0 if none is)."""
    fast = [(n, t) for n, t in results if t >= 1 / TICK_S]
    slow = [(n, t) for n, t in results if t < 1 / TICK_S]
    if not fast:
        return 0
    if not slow or slow[0][0] < fast[-1][0]:
        return fast[-1][0]
    # The time of one tick grows about linearly with N: interpolate N at 0.1 s a tick.
    (n1, t1), (n2, t2) = fast[-1], slow[0]
    s1, s2 = 1 / t1, 1 / t2
    return int(n1 + (TICK_S - s1) * (n2 - n1) / (s2 - s1))


def largest_text(results: list[tuple[int, float]]) -> str:
    """`largest_real_time` as the last line says it: "at least N" when every size measured
    was at real time (the bench did not find the limit; larger --sizes would)."""
    n = largest_real_time(results)
    return f"at least {n}" if results and all(t >= 1 / TICK_S for _, t in results) else str(n)


def main_mission(mission: str, sizes: list[int], at: int | None) -> None:
    """Measure the whole mission at each size; the last line says the largest real-time one."""
    results: list[tuple[int, float]] = []
    print(
        f"{'robots':>7s} {'ticks/s':>8s} {'x real time':>12s} "
        + " ".join(f"{p:>10s}" for p in PHASES)
        + f" {'sim s':>6s}  "
        + " ".join(f"{p[:6]:>6s}" for p in PHASES[1:])
        + " (µs per robot-tick)  outcome"
    )
    for n in sizes:
        gc.collect()  # the previous size's swarm is gone before this one is timed
        tps, cpu, ticks, simulated, outcome = mission_rate(mission, n)
        results.append((n, tps))
        # Each stepping phase's CPU per robot-tick: real time allows 0.1 s / n of it.
        per = " ".join(f"{cpu[p] / max(1, ticks[p] * n) * 1e6:6.0f}" for p in PHASES[1:])
        print(
            f"{n:7d} {tps:8.2f} {tps * TICK_S:12.2f} "
            + " ".join(f"{cpu[p]:9.1f}s" for p in PHASES)
            + f" {simulated:6.1f}  {per}  {outcome}",
            flush=True,
        )
    m, r = next((n, t) for n, t in results if n == (sizes[-1] if at is None else at))
    print(
        f"whole mission: {largest_text(results)} robots at >= real time "
        f"({r:.2f} ticks/s at {m} robots)"
    )


def main() -> None:
    """Measure each size and print the largest real-time swarm."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--sizes", type=sizes, default=None, help="default 750,1000,1250 (--mission: 250,500,1000)"
    )
    ap.add_argument(
        "--measure",
        type=seconds,
        default=None,
        help="simulated seconds measured (1 s windows; default 7; not with --mission)",
    )
    ap.add_argument("--mission", choices=MISSIONS, help="the whole mission from the ground")
    ap.add_argument("--at", type=int, help="--mission: the size the last line quotes")
    args = ap.parse_args()
    counts = args.sizes or ([250, 500, 1000] if args.mission else [750, 1000, 1250])
    if args.at is not None and args.at not in counts:
        ap.error(f"--at {args.at}: not one of the sizes measured ({counts})")
    if args.mission and args.measure is not None:
        ap.error("--measure: the steady state's window; --mission measures the whole run")
    if args.at is not None and not args.mission:
        ap.error("--at: only with --mission")
    print(machine(), flush=True)
    if args.mission:
        main_mission(args.mission, counts, args.at)
        return
    results: list[tuple[int, float]] = []
    print(
        f"{'robots':>7s} {'ticks/s':>8s} {'x real time':>12s} {'whole run':>10s}"
        f" {'gossip s':>9s}  states"
    )
    for n in counts:
        with tuned_memory():  # as `Simulation.run` steps
            tps, whole, gossip, states = ticks_per_second(n, args.measure or 7.0)
        results.append((n, tps))
        print(
            f"{n:7d} {tps:8.2f} {tps * TICK_S:12.2f} {whole * TICK_S:10.2f} {gossip:9.1f}  {states}"
        )
    print(f"largest swarm at real time on one core: {largest_text(results)} robots")


if __name__ == "__main__":
    main()
