"""What every experiment shares: the ground station's schedule, the run's spec and result, and
the interface each experiment implements (`Experiment`, and the `Probe` that measures a run)."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar, Protocol

from fieldkit.errors import FieldkitError
from fieldkit.robot import bundle as wirebundle
from fieldkit.sim.simulator import TICK_S, RcCommand, SimConfig

if TYPE_CHECKING:
    from fieldkit.sim.simulator import Simulation

#: The XBee's RF frame (XbeeMav sends one bundle per frame).
XBEE_FRAME_BYTES = 250
#: ROSBuzz's per-step bundle content limit.
BUNDLE_LIMIT_BYTES = wirebundle.MAX_MSG_SIZE

#: The ground station's schedule, in simulated seconds. Takeoff is handed to robot 1 only: the
#: command spreads through the swarm. At 90 % drop every robot is up and IDLE within ~10 s, so
#: the mission command at 20 s finds the swarm in the air.
TAKEOFF_S = 1.0
MISSION_S = 20.0

#: RC codes (docs/rosbuzz.md#commands).
RC_TAKEOFF = 22

#: Samples of the time series: one per simulated second.
SAMPLE_TICKS = round(1.0 / TICK_S)

#: One row of a time series: column name -> value.
Row = dict[str, float | int]


class ExperimentError(FieldkitError, ValueError):
    """An invalid experiment parameter, with a message saying which and why."""


def rounded(x: float) -> float:
    """Round for the outputs: 6 decimals keep every figure and hide nothing that matters."""
    return round(x, 6) if math.isfinite(x) else x


class Probe(Protocol):
    """Measures one run of an experiment as the simulation advances."""

    def after_step(self, tick: int) -> None:
        """Called after every simulated step (for events between samples)."""

    def sample(self, row: Row, robot_rows: list[Row]) -> None:
        """Add the experiment's columns to `row` (and per-robot rows), once a second."""

    def figures(self, last: Mapping[str, float | int]) -> dict[str, object]:
        """The run's end figures, from the last sample."""


@dataclass(frozen=True)
class Experiment(ABC):
    """One of the paper's experiments: its default grid, duration, script, metric and figure.

    Subclasses give what differs between kinds of experiment: the ground station's commands,
    the script's globals, what is measured and the summary's own fields.
    """

    name: str
    robots: tuple[int, ...]
    drops: tuple[float, ...]
    runs: int  # seeded runs per (robots, drop) cell
    seconds: float  # simulated seconds per run
    script: str  # file name under SCRIPT_DIR
    figure: str  # the paper's figure it reproduces
    metric: str  # what plot.png shows
    series: str  # the timeseries.csv column plot.png shows

    #: The experiment's columns in timeseries.csv, after the grid keys and `t_s`.
    columns: ClassVar[tuple[str, ...]]
    #: The end figures summary.json lists per run (and per cell).
    per_run: ClassVar[tuple[str, ...]]
    #: The columns of robots.csv after the grid keys (empty: no robots.csv).
    robot_columns: ClassVar[tuple[str, ...]] = ()
    #: plot.png's y range, when the metric has natural bounds.
    y_limits: ClassVar[tuple[float, float] | None] = None

    def shape(self, robots: int) -> str | None:
        """The task graph for `robots` robots if the experiment forms one (ExperimentError)."""
        return None

    def check_robots(self, robots: int) -> None:
        """Raise ExperimentError if this experiment cannot run with `robots` robots."""
        self.shape(robots)

    def check_seconds(self, seconds: float) -> None:
        """Raise ExperimentError if runs of `seconds` end before something the experiment
        measures happens (make_plan has checked that they reach the mission command)."""
        return  # most experiments measure from the mission command on

    def plots_each_robot(self) -> bool:
        """Whether plot.png has a second panel with each robot's curve (from robot_rows)."""
        return False

    def schedule(self) -> dict[str, float]:
        """The ground station's schedule as summary.json gives it (seconds)."""
        return {"takeoff": TAKEOFF_S, "mission": MISSION_S}

    def events(self) -> tuple[tuple[float, str], ...]:
        """Moments plot.png marks besides the mission command: (seconds, what)."""
        return ()

    @abstractmethod
    def commands(self, spec: RunSpec) -> list[RcCommand]:
        """The ground station's RC codes for one run."""

    @abstractmethod
    def script_globals(self, spec: RunSpec) -> dict[str, object]:
        """The globals set before the script runs."""

    @abstractmethod
    def probe(self, spec: RunSpec, sim: Simulation) -> Probe:
        """A fresh measurement of one run of `sim`."""

    @abstractmethod
    def summary_fields(self, robots: tuple[int, ...]) -> dict[str, object]:
        """The fields summary.json holds for this kind of experiment only."""


@dataclass(frozen=True)
class RunSpec:
    """Everything one run depends on (picklable: a Dask task's argument)."""

    experiment: Experiment
    robots: int
    drop: float
    run: int  # index within its (robots, drop) cell
    seed: int
    seconds: float
    script: str
    include_dirs: tuple[str, ...] = ()
    shape: str | None = None  # task allocation: the task graph
    swarm_key: bytes | None = None  # signed bundles (None: plain, ROSBuzz's bytes)
    burst: float | None = None  # bursty losses: mean burst length in ticks (Gilbert-Elliott)

    def commands(self) -> list[RcCommand]:
        """The ground station's RC codes for this run."""
        return self.experiment.commands(self)

    def script_globals(self) -> dict[str, object]:
        """The globals set before the script runs (the task graph, the coverage margin)."""
        return self.experiment.script_globals(self)

    def config(self) -> SimConfig:
        """The simulator configuration of this run."""
        return SimConfig(
            script=Path(self.script),
            robots=self.robots,
            drop=self.drop,
            burst=self.burst,
            seconds=self.seconds,
            seed=self.seed,
            commands=self.commands(),
            include_dirs=self.include_dirs,
            globals=self.script_globals(),
            security="none" if self.swarm_key is None else "signed",
            swarm_key=self.swarm_key,
        )

    @property
    def total_ticks(self) -> int:
        """Ticks this run simulates."""
        return round(self.seconds / TICK_S)


@dataclass
class RunResult:
    """What one run measured: per-second rows, per-robot rows (coverage) and end figures."""

    spec: RunSpec
    rows: list[Row] = field(default_factory=list)
    robot_rows: list[Row] = field(default_factory=list)
    figures: dict[str, object] = field(default_factory=dict)
