"""Where every robot went and what it was doing: `trajectories.csv` and `plot.png` of a run.

`sim run` and `sitl` record the same thing: once a second, each robot's position and state,
and the radio load since the last sample. `Tracks` holds it compactly (one array per
sample, not one object per robot and sample: a 1,000-robot run has a million points);
`write_tracks` writes

* `trajectories.csv`: one row per robot per sample, sorted by time then robot id:
  `t_s, robot, east_m, north_m, alt_m, lat, lon, <state column>`, east and north in metres
  from the run's home, the altitude above it; the state column is `state` (the script's
  BVMSTATE, `sim run`) or `mode` (the vehicle's flight mode, `sitl`), empty when none;
* `plot.png`: the tracks of all robots coloured by that state, and the radio load over time
  (the plotting is the experiments' module's, `fieldkit.sim.experiments.plots`).
"""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from fieldkit.robot import geo

if TYPE_CHECKING:
    from fieldkit.sim.radio import RadioModel
    from fieldkit.sim.simulator import SimConfig

#: Samples per simulated (or wall-clock, in SITL) second.
SAMPLE_S = 1.0

#: The columns of trajectories.csv before the state column.
POSITION_COLUMNS = ("t_s", "robot", "east_m", "north_m", "alt_m", "lat", "lon")


@dataclass
class Sample:
    """Every robot at one time: positions (metres from home) and states, in `Tracks.ids` order."""

    t_s: float
    east: list[float]
    north: list[float]
    alt: list[float]
    states: list[str | None]


@dataclass
class LoadSample:
    """The radio load over the interval ending at `t_s`: bytes per robot per `unit`."""

    t_s: float
    mean: float
    max: float


@dataclass
class Tracks:
    """A run's samples: robot ids, positions and states over time, and the radio load."""

    ids: list[int]
    home: tuple[float, float]  # (lat, lon) of east = north = 0
    state_column: str = "state"  # "state" (BVMSTATE) or "mode" (the vehicle's flight mode)
    load_unit: str = "step"  # the radio load is in bytes per robot per this
    samples: list[Sample] = field(default_factory=list)
    load: list[LoadSample] = field(default_factory=list)

    def add(
        self,
        t_s: float,
        positions: Sequence[tuple[float, float, float]],
        states: Sequence[str | None],
    ) -> None:
        """One sample: each robot's (east, north, alt) and state, in `ids` order."""
        self.samples.append(
            Sample(
                round(t_s, 6),
                [round(p[0], 3) for p in positions],
                [round(p[1], 3) for p in positions],
                [round(p[2], 3) for p in positions],
                list(states),
            )
        )

    def add_load(self, t_s: float, mean: float, peak: float) -> None:
        """The radio load of the interval ending at `t_s`: bytes per robot per unit, the mean
        over the robots and the most one robot sent."""
        self.load.append(LoadSample(round(t_s, 6), round(mean, 3), round(peak, 3)))

    @property
    def header(self) -> tuple[str, ...]:
        """The columns of trajectories.csv."""
        return (*POSITION_COLUMNS, self.state_column)


class _Positioned(Protocol):
    x: float
    y: float
    z: float


class _Sampled(Protocol):
    """A robot as sampled: its vehicle's position and its script's state."""

    @property
    def vehicle(self) -> _Positioned: ...

    @property
    def state(self) -> str | None: ...


class SampledSwarm(Protocol):
    """What `SimRecorder` reads of a run: a `Simulation`, or one split across workers."""

    config: SimConfig
    frame: geo.LocalFrame
    radio: RadioModel
    tick: int

    @property
    def robots(self) -> Mapping[int, _Sampled]: ...


class SimRecorder:
    """Samples a `Simulation` into `Tracks`: positions and states every simulated second (and
    at the last tick), the bytes each robot put on the air per step in between."""

    def __init__(self, sim: SampledSwarm) -> None:
        from fieldkit.sim.simulator import TICK_S

        self.sim = sim
        self.every = max(1, round(SAMPLE_S / TICK_S))
        self.tick_s = TICK_S
        self.last = round(sim.config.seconds / TICK_S)
        self.tracks = Tracks(ids=list(sim.robots), home=(sim.frame.lat, sim.frame.lon))
        self._air = 0  # bytes on the air since the last sample...
        self._air_max = 0  # ...the most one robot sent in one step...
        self._steps = 0  # ...and the steps they were counted over
        self.sample()

    def sample(self) -> None:
        """Every robot's position and state now."""
        robots = self.sim.robots.values()
        self.tracks.add(
            self.sim.tick * self.tick_s,
            [(r.vehicle.x, r.vehicle.y, r.vehicle.z) for r in robots],
            [r.state for r in robots],
        )

    def after_step(self) -> None:
        """Count the step's radio bytes; sample on the second (and at the end)."""
        step = self.sim.radio.step_bytes().values()
        self._air += sum(step)
        self._air_max = max(self._air_max, max(step, default=0))
        self._steps += 1
        tick = self.sim.tick
        if tick % self.every == 0 or tick == self.last:
            self.sample()
            robots = len(self.sim.robots)
            mean = self._air / (robots * self._steps)
            self.tracks.add_load(tick * self.tick_s, mean, self._air_max)
            self._air = self._air_max = self._steps = 0


def write_trajectories(tracks: Tracks, path: Path) -> None:
    """trajectories.csv: a row per robot per sample (`\\n` line ends, a byte-stable file)."""
    frame = geo.LocalFrame(tracks.home[0], tracks.home[1], 0.0)
    with path.open("w", encoding="utf-8", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(tracks.header)
        for s in tracks.samples:
            for k, rid in enumerate(tracks.ids):
                east, north = s.east[k], s.north[k]
                lat, lon, _ = frame.to_gps(east, north, 0.0)
                state = s.states[k]
                w.writerow(
                    (
                        s.t_s,
                        rid,
                        east,
                        north,
                        s.alt[k],
                        round(lat, 7),
                        round(lon, 7),
                        "" if state is None else state,
                    )
                )


def write_tracks(tracks: Tracks, out: Path, title: str) -> list[Path]:
    """Write OUT/trajectories.csv and OUT/plot.png; the paths written."""
    from fieldkit.sim.experiments.plots import plot_tracks

    csv_path = out / "trajectories.csv"
    write_trajectories(tracks, csv_path)
    png_path = out / "plot.png"
    plot_tracks(tracks, png_path, title)
    return [csv_path, png_path]


__all__ = [
    "POSITION_COLUMNS",
    "SAMPLE_S",
    "LoadSample",
    "Sample",
    "SimRecorder",
    "Tracks",
    "write_tracks",
    "write_trajectories",
]
