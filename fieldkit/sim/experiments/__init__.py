"""The paper's experiments on the simulator: task allocation and coverage, under loss and at scale.

An experiment is a grid of runs (robot counts x drop rates x seeded runs); every run is one
`Simulation` driven as the ground station drives the field swarm: RC 22 (takeoff) to robot 1
at `TAKEOFF_S`, then, once the swarm is up, either RC 900 (task allocation) at `MISSION_S`,
or the coverage hotspots (RC 16, waypoint ids 50..) to robot 1 followed by RC 901 (DEPLOY).
A run is a pure function of its `RunSpec`: the same spec gives the same `RunResult` bit for
bit, wherever and in whatever order it runs (see `fieldkit.sim.sweep`).

* `task-allocation` (Figure 6): 6 robots form the P graph at drop 0, 0.2, 0.5, 0.7 and 0.9,
  5 seeded runs each; the fraction of robots JOINED over time.
* `task-allocation-scale` (Figure 7): 6, 12, 18, 24, 30 and 48 robots form P, PO, POL, POLY,
  PPOLY and YLOPPOLY without loss, 1 run each.
* `coverage` (Figure 12): 6 robots cover the hotspots' region at the same drop rates, 5 runs
  each; each robot's distance to its ideal Voronoi centroid over time.
* `coverage-scale` (Figure 13): 10, 20, 30, 40 and 50 robots, no loss, 1 run each; the mean
  pairwise distance over time.

Every experiment also records the bytes each robot puts on the air per step against the
250-byte XBee frame, and the Buzz bundle content against ROSBuzz's 190-byte limit (Fig. 10).

Outputs (`write_outputs`): `summary.json` (sorted keys, no wall times: same seed, same
bytes), `timeseries.csv` (one row per run and simulated second), `robots.csv` (coverage:
each robot's position and centroid distance per second), `plot.png` (the paper's figure)
and `bytes.png` (the radio load).

The modules: `base` (the `Experiment` interface, `RunSpec`, `RunResult`, the schedule),
`task_allocation` and `coverage` (one `Experiment` class each: commands, script globals,
measurement, summary fields), `catalogue` (the four experiments), `plan` (validated grids),
`running` (`run_one`, `run_plan`), `outputs` (files) and `plots` (figures).
"""

from fieldkit.sim.experiments.base import (
    BUNDLE_LIMIT_BYTES,
    MISSION_S,
    TAKEOFF_S,
    XBEE_FRAME_BYTES,
    Experiment,
    ExperimentError,
    Probe,
    RunResult,
    RunSpec,
)
from fieldkit.sim.experiments.catalogue import DROPS, EXPERIMENTS, SCRIPT_DIR
from fieldkit.sim.experiments.coverage import COVERAGE_MARGIN_M, HOTSPOTS, Coverage
from fieldkit.sim.experiments.outputs import summarize, write_csv, write_outputs
from fieldkit.sim.experiments.plan import Plan, check_script, make_plan
from fieldkit.sim.experiments.plots import plot_bytes, plot_experiment
from fieldkit.sim.experiments.running import run_one, run_plan
from fieldkit.sim.experiments.task_allocation import (
    JOINED_STATES,
    SCALE_SHAPES,
    TaskAllocation,
    shape_for,
)

__all__ = [
    "BUNDLE_LIMIT_BYTES",
    "COVERAGE_MARGIN_M",
    "DROPS",
    "EXPERIMENTS",
    "HOTSPOTS",
    "JOINED_STATES",
    "MISSION_S",
    "SCALE_SHAPES",
    "SCRIPT_DIR",
    "TAKEOFF_S",
    "XBEE_FRAME_BYTES",
    "Coverage",
    "Experiment",
    "ExperimentError",
    "Plan",
    "Probe",
    "RunResult",
    "RunSpec",
    "TaskAllocation",
    "check_script",
    "make_plan",
    "plot_bytes",
    "plot_experiment",
    "run_one",
    "run_plan",
    "shape_for",
    "summarize",
    "write_csv",
    "write_outputs",
]
