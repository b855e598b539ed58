"""Task allocation with robots lost mid-mission (issue 20, beyond the paper): once the shape is
formed, 20 % of the robots die at once (hardware loss, a flat battery); the others must take
the tasks the dead held. Measured by the fraction of the graph's tasks held by live robots
over time, and the time from the loss until every task is held again (never, when fewer
robots than tasks are left: the default grid has spares enough)."""

from __future__ import annotations

import itertools
import random
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from fieldkit.sim.experiments.base import (
    MISSION_S,
    RC_TAKEOFF,
    TAKEOFF_S,
    Experiment,
    ExperimentError,
    Row,
    RunSpec,
    rounded,
)
from fieldkit.sim.experiments.task_allocation import JOINED_STATES, RC_TASK_ALLOCATE
from fieldkit.sim.simulator import TICK_S, RcCommand

if TYPE_CHECKING:
    from fieldkit.sim.simulator import Simulation

#: When the robots die (simulated seconds): 40 s after RC 900, when every run of the paper's
#: grid has formed its shape (the slowest, at 90 % drop, took 24 s).
KILL_S = 60.0
#: The share of the swarm that dies.
KILL_FRACTION = 0.2
#: The graph every run forms. Any robot may die, label 0's included (task_allocation.bzz
#: hands label 0 over).
LOSS_SHAPE = "P"
#: Robots of the default grid: 10 robots for the 6 tasks of P, so the 2 that die can always
#: be replaced by robots without a task.
LOSS_ROBOTS = 10


def killed_ids(robots: int, seed: int) -> list[int]:
    """The robots a run kills: round(20 %) of ids 1..robots, drawn from the run's seed."""
    count = round(KILL_FRACTION * robots)
    return sorted(random.Random(f"kill:{seed}").sample(range(1, robots + 1), count))


@dataclass(frozen=True)
class TaskAllocationLoss(Experiment):
    """Task allocation of LOSS_SHAPE; at KILL_S 20 % of the robots die."""

    columns: ClassVar[tuple[str, ...]] = ("alive", "tasks_held", "tasks_held_fraction")
    per_run: ClassVar[tuple[str, ...]] = (
        "killed",
        "killed_holding_tasks",
        "formed_s",
        "recovered_s",
        "tasks_held_fraction",
    )

    y_limits: ClassVar[tuple[float, float] | None] = (-0.02, 1.02)

    def commands(self, spec: RunSpec) -> list[RcCommand]:
        """Those of the task allocation: takeoff, then RC 900, both to robot 1."""
        return [RcCommand(TAKEOFF_S, 1, RC_TAKEOFF), RcCommand(MISSION_S, 1, RC_TASK_ALLOCATE)]

    def script_globals(self, spec: RunSpec) -> dict[str, object]:
        """The task graph to form."""
        return {"SHAPE": spec.shape or LOSS_SHAPE}

    def shape(self, robots: int) -> str | None:
        """Always LOSS_SHAPE: robots beyond its tasks are the spares that replace the dead."""
        return LOSS_SHAPE

    def check_robots(self, robots: int) -> None:
        """At least one robot must die."""
        if round(KILL_FRACTION * robots) < 1:
            fewest = next(n for n in itertools.count(robots) if round(KILL_FRACTION * n) >= 1)
            raise ExperimentError(
                f"--robots {robots}: {self.name} kills {KILL_FRACTION:.0%} of the robots,"
                f" which needs at least {fewest}"
            )

    def check_seconds(self, seconds: float) -> None:
        """The runs must go on past the loss: a run that ends first kills nobody."""
        if seconds <= KILL_S:
            raise ExperimentError(
                f"--seconds {seconds:g}: {self.name} kills robots at {KILL_S:g} s, so runs"
                f" must be longer (the default, {self.seconds:g} s, leaves time to recover)"
            )

    def schedule(self) -> dict[str, float]:
        """Takeoff, RC 900, and the loss."""
        return {**super().schedule(), "kill": KILL_S}

    def events(self) -> tuple[tuple[float, str], ...]:
        """The loss."""
        return ((KILL_S, f"{KILL_FRACTION:.0%} of the robots die"),)

    def probe(self, spec: RunSpec, sim: Simulation) -> _LossProbe:
        """Kills the robots at KILL_S and follows the tasks held."""
        return _LossProbe(spec, sim)

    def summary_fields(self, robots: tuple[int, ...]) -> dict[str, object]:
        """The graph, what counts as holding a task, and who dies when."""
        return {
            "shape": LOSS_SHAPE,
            "tasks": _tasks(LOSS_SHAPE),
            "joined_states": sorted(JOINED_STATES),
            "kill_fraction": KILL_FRACTION,
            "kill_s": KILL_S,
        }


def _tasks(shape: str) -> int:
    """The number of tasks (nodes) of a graph."""
    from fieldkit.robot import shapes

    return len(shapes.compose(shape))


class _LossProbe:
    """Kills at KILL_S; counts distinct labels held by live robots; times the recovery."""

    def __init__(self, spec: RunSpec, sim: Simulation) -> None:
        self.sim = sim
        self.tasks = _tasks(spec.shape or LOSS_SHAPE)
        self.killed = killed_ids(spec.robots, spec.seed)
        self.kill_tick = round(KILL_S / TICK_S)
        self.mission_tick = round(MISSION_S / TICK_S)
        self.formed_tick: int | None = None
        self.recovered_tick: int | None = None
        self.killed_holding: list[int] = []

    def held(self) -> int:
        """How many distinct tasks live robots hold (JOINED or LOCK)."""
        labels = set()
        for r in self.sim.robots.values():
            if r.state in JOINED_STATES:
                label = r.vm.globals.get("TA_LABEL")
                if isinstance(label, int) and 0 <= label < self.tasks:
                    labels.add(label)
        return len(labels)

    def after_step(self, tick: int) -> None:
        """Kill on time; note when the shape first formed, and when it formed again."""
        if tick == self.kill_tick:
            for rid in self.killed:
                robot = self.sim.robots.get(rid)
                if robot is not None and robot.state in JOINED_STATES:
                    self.killed_holding.append(rid)
                self.sim.kill(rid)
        if self.formed_tick is None and self.mission_tick < tick <= self.kill_tick:
            if self.held() == self.tasks:
                self.formed_tick = tick
        if self.recovered_tick is None and tick > self.kill_tick:
            if self.held() == self.tasks:
                self.recovered_tick = tick

    def sample(self, row: Row, robot_rows: list[Row]) -> None:
        """Live robots and tasks held."""
        held = self.held()
        row["alive"] = len(self.sim.robots)
        row["tasks_held"] = held
        row["tasks_held_fraction"] = rounded(held / self.tasks)

    def figures(self, last: Mapping[str, float | int]) -> dict[str, object]:
        """Who died, when the shape formed and re-formed, and the tasks held at the end."""
        formed, recovered = self.formed_tick, self.recovered_tick
        return {
            "killed": self.killed,
            "killed_holding_tasks": self.killed_holding,
            "formed_s": None if formed is None else rounded((formed - self.mission_tick) * TICK_S),
            "recovered_s": (
                None if recovered is None else rounded((recovered - self.kill_tick) * TICK_S)
            ),
            "tasks_held_fraction": last.get("tasks_held_fraction", 0.0),
        }


__all__ = ["KILL_FRACTION", "KILL_S", "LOSS_SHAPE", "TaskAllocationLoss", "killed_ids"]
