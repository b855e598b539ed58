"""Task allocation (Figures 6 and 7): robots take the nodes of a letter-shaped task graph after
RC 900; measured by the fraction of robots JOINED over time and the time until all are."""

from __future__ import annotations

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
from fieldkit.sim.simulator import TICK_S, RcCommand

if TYPE_CHECKING:
    from fieldkit.sim.simulator import SimRobot, Simulation

RC_TASK_ALLOCATE = 900

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
class TaskAllocation(Experiment):
    """RC 900 at MISSION_S; each robot's state says whether it holds a node of the graph."""

    columns: ClassVar[tuple[str, ...]] = ("joined", "joined_fraction")
    per_run: ClassVar[tuple[str, ...]] = ("joined_fraction", "time_to_all_joined_s")
    y_limits: ClassVar[tuple[float, float] | None] = (-0.02, 1.02)

    def shape(self, robots: int) -> str | None:
        """The smallest graph with a node for every robot."""
        return shape_for(robots)

    def commands(self, spec: RunSpec) -> list[RcCommand]:
        """Takeoff, then the task allocation, both to robot 1."""
        return [RcCommand(TAKEOFF_S, 1, RC_TAKEOFF), RcCommand(MISSION_S, 1, RC_TASK_ALLOCATE)]

    def script_globals(self, spec: RunSpec) -> dict[str, object]:
        """The task graph to form."""
        return {"SHAPE": spec.shape} if spec.shape is not None else {}

    def probe(self, spec: RunSpec, sim: Simulation) -> _JoinedProbe:
        """Counts the JOINED robots."""
        return _JoinedProbe(list(sim.robots.values()))

    def summary_fields(self, robots: tuple[int, ...]) -> dict[str, object]:
        """The graph of each robot count and the states that count as joined."""
        return {
            "shapes": {str(n): shape_for(n) for n in robots},
            "joined_states": sorted(JOINED_STATES),
        }


class _JoinedProbe:
    """The fraction of robots JOINED, and the first tick after RC 900 when all of them were."""

    def __init__(self, robots: list[SimRobot]) -> None:
        self.robots = robots
        self.mission_tick = round(MISSION_S / TICK_S)
        self.all_joined_tick: int | None = None

    def after_step(self, tick: int) -> None:
        """Note the first tick when every robot holds its node."""
        if self.all_joined_tick is None and tick > self.mission_tick:
            if all(r.state in JOINED_STATES for r in self.robots):
                self.all_joined_tick = tick

    def sample(self, row: Row, robot_rows: list[Row]) -> None:
        """How many robots hold a node, and which fraction of the swarm that is."""
        joined = sum(r.state in JOINED_STATES for r in self.robots)
        row["joined"] = joined
        row["joined_fraction"] = rounded(joined / len(self.robots))

    def figures(self, last: Mapping[str, float | int]) -> dict[str, object]:
        """The final fraction joined and the time from RC 900 until all were (None: never)."""
        tick = self.all_joined_tick
        return {
            "joined_fraction": last.get("joined_fraction", 0.0),
            "time_to_all_joined_s": (
                None if tick is None else rounded((tick - self.mission_tick) * TICK_S)
            ),
        }
