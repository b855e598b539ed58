"""Coverage (Figures 12 and 13): robots spread over the region around the hotspots after
RC 901; measured by each robot's distance to its ideal Voronoi centroid and the swarm's spread."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, ClassVar

from fieldkit.robot import geo, voronoi
from fieldkit.sim.experiments.base import (
    MISSION_S,
    RC_TAKEOFF,
    TAKEOFF_S,
    Experiment,
    Row,
    RunSpec,
    rounded,
)
from fieldkit.sim.simulator import DEFAULT_ORIGIN, RcCommand

if TYPE_CHECKING:
    from fieldkit.sim.simulator import SimRobot, Simulation

RC_DEPLOY = 901
RC_WAYPOINT = 16
#: Waypoint ids 50..99 are coverage hotspots (attractors), shared through stigmergy.
FIRST_HOTSPOT_ID = 50

HOTSPOTS_S = 15.0  # the first coverage hotspot; the next ones HOTSPOT_GAP_S apart
HOTSPOT_GAP_S = 0.5  # one RC code per robot per tick, so hotspots go one at a time

#: Coverage hotspots, (east, north) metres in the simulation frame, around the takeoff grid
#: (robots start at 0..3 sqrt(N) m east and north). The region covered is their convex hull
#: inflated by the script's margin.
HOTSPOTS: tuple[tuple[float, float], ...] = (
    (-10.0, -10.0),
    (30.0, -10.0),
    (30.0, 30.0),
    (-10.0, 30.0),
)
#: The inflation of the hotspots' hull: coverage.bzz's margin (ROSBuzz: 20 m).
COVERAGE_MARGIN_M = 20.0


@dataclass(frozen=True)
class Coverage(Experiment):
    """Hotspots (RC 16) then RC 901 to robot 1; the swarm covers their inflated hull."""

    hotspots: tuple[tuple[float, float], ...] = HOTSPOTS  # (east, north) metres
    margin_m: float = COVERAGE_MARGIN_M  # hull inflation for the ideal centroids
    robot_panel: bool = False  # plot.png also shows each robot's distance (Figure 12)

    columns: ClassVar[tuple[str, ...]] = (
        "centroid_distance_mean_m",
        "centroid_distance_max_m",
        "mean_pairwise_distance_m",
    )
    per_run: ClassVar[tuple[str, ...]] = (
        "final_centroid_distance_m",
        "final_centroid_distance_max_m",
        "final_mean_pairwise_distance_m",
    )
    robot_columns: ClassVar[tuple[str, ...]] = ("robot", "x_m", "y_m", "centroid_distance_m")

    def plots_each_robot(self) -> bool:
        """Figure 12 shows each robot's distance beside the mean."""
        return self.robot_panel

    def schedule(self) -> dict[str, float]:
        """Takeoff, the first hotspot and the mission."""
        return {**super().schedule(), "hotspots": HOTSPOTS_S}

    def commands(self, spec: RunSpec) -> list[RcCommand]:
        """Takeoff, the hotspots one per tick (waypoint ids 50..), then DEPLOY."""
        cmds = [RcCommand(TAKEOFF_S, 1, RC_TAKEOFF)]
        frame = geo.LocalFrame(*DEFAULT_ORIGIN)
        for k, (east, north) in enumerate(self.hotspots):
            lat, lon, alt = frame.to_gps(east, north, 0.0)
            params = (float(FIRST_HOTSPOT_ID + k), lat, lon, alt)
            cmds.append(RcCommand(HOTSPOTS_S + k * HOTSPOT_GAP_S, 1, RC_WAYPOINT, params))
        cmds.append(RcCommand(MISSION_S, 1, RC_DEPLOY))
        return cmds

    def script_globals(self, spec: RunSpec) -> dict[str, object]:
        """The same margin as the metric's region, whatever the script's default."""
        return {"MARGIN": float(self.margin_m)}

    def probe(self, spec: RunSpec, sim: Simulation) -> _CentroidProbe:
        """Measures the distances to the ideal centroids of the region."""
        boundary = voronoi.convex_hull(self.hotspots, self.margin_m) if self.hotspots else []
        return _CentroidProbe(list(sim.robots.values()), boundary)

    def summary_fields(self, robots: tuple[int, ...]) -> dict[str, object]:
        """The hotspots and the margin that define the region."""
        return {
            "hotspots_east_north_m": [list(h) for h in self.hotspots],
            "coverage_margin_m": self.margin_m,
        }


def mean_pairwise(points: Sequence[tuple[float, float]]) -> float:
    """Mean horizontal distance over all pairs of robots (0 for fewer than 2)."""
    n = len(points)
    if n < 2:
        return 0.0
    total = 0.0
    for i in range(n):
        xi, yi = points[i]
        for j in range(i + 1, n):
            total += math.hypot(points[j][0] - xi, points[j][1] - yi)
    return total / (n * (n - 1) / 2)


class _CentroidProbe:
    """Each robot's distance to its ideal Voronoi centroid, and the mean pairwise distance."""

    def __init__(self, robots: list[SimRobot], boundary: list[tuple[float, float]]) -> None:
        self.robots = robots
        self.boundary = boundary

    def after_step(self, tick: int) -> None:
        """Nothing happens between samples that coverage measures."""

    def sample(self, row: Row, robot_rows: list[Row]) -> None:
        """The swarm's distances now, and a row per robot."""
        n = len(self.robots)
        points = [(r.vehicle.x, r.vehicle.y) for r in self.robots]
        dists = voronoi.centroid_distances(points, self.boundary)
        row["centroid_distance_mean_m"] = rounded(sum(dists) / n)
        row["centroid_distance_max_m"] = rounded(max(dists))
        row["mean_pairwise_distance_m"] = rounded(mean_pairwise(points))
        for r, p, d in zip(self.robots, points, dists, strict=True):
            robot_rows.append(
                {
                    "t_s": row["t_s"],
                    "robot": r.id,
                    "x_m": rounded(p[0]),
                    "y_m": rounded(p[1]),
                    "centroid_distance_m": rounded(d),
                }
            )

    def figures(self, last: Mapping[str, float | int]) -> dict[str, object]:
        """The last sample's distances (inf when no sample was taken)."""
        return {
            "final_centroid_distance_m": last.get("centroid_distance_mean_m", math.inf),
            "final_centroid_distance_max_m": last.get("centroid_distance_max_m", math.inf),
            "final_mean_pairwise_distance_m": last.get("mean_pairwise_distance_m", 0.0),
        }
