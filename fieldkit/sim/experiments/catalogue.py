"""The paper's four experiments, with their default grids, durations and scripts."""

from __future__ import annotations

from fieldkit import resources
from fieldkit.sim.experiments.base import Experiment
from fieldkit.sim.experiments.coverage import Coverage
from fieldkit.sim.experiments.task_allocation import SCALE_SHAPES, TaskAllocation
from fieldkit.sim.experiments.task_allocation_loss import LOSS_ROBOTS, TaskAllocationLoss

#: Where the shipped behaviours live.
SCRIPT_DIR = resources.script_dir()

DROPS = (0.0, 0.2, 0.5, 0.7, 0.9)

# Durations (simulated): task allocation of 6 robots takes 10-24 s after RC 900 from 0 to 90 %
# drop, so 120 s (100 s after the command) leaves room; 48 robots join one after another in
# ~60 s, so the scale runs last 180 s (160 s after the command). Coverage settles within ~20 s
# of RC 901 at 6 and at 50 robots; 120 s shows it hold, at every drop rate. The loss
# experiment kills robots at 60 s and leaves 120 s to replace them.
EXPERIMENTS: dict[str, Experiment] = {
    e.name: e
    for e in (
        TaskAllocation(
            name="task-allocation",
            robots=(6,),
            drops=DROPS,
            runs=5,
            seconds=120.0,
            script="task_allocation.bzz",
            figure="Figure 6",
            metric="fraction of robots JOINED",
            series="joined_fraction",
        ),
        TaskAllocation(
            name="task-allocation-scale",
            robots=tuple(n for n, _ in SCALE_SHAPES),
            drops=(0.0,),
            runs=1,
            seconds=180.0,
            script="task_allocation.bzz",
            figure="Figure 7",
            metric="fraction of robots JOINED",
            series="joined_fraction",
        ),
        Coverage(
            name="coverage",
            robots=(6,),
            drops=DROPS,
            runs=5,
            seconds=120.0,
            script="coverage.bzz",
            figure="Figure 12",
            metric="distance to the ideal Voronoi centroid (m)",
            series="centroid_distance_mean_m",
            robot_panel=True,
        ),
        Coverage(
            name="coverage-scale",
            robots=(10, 20, 30, 40, 50),
            drops=(0.0,),
            runs=1,
            seconds=120.0,
            script="coverage.bzz",
            figure="Figure 13",
            metric="mean pairwise distance (m)",
            series="mean_pairwise_distance_m",
        ),
        TaskAllocationLoss(
            name="task-allocation-loss",
            robots=(LOSS_ROBOTS,),
            drops=(0.0, 0.5, 0.9),
            runs=5,
            seconds=180.0,
            script="task_allocation.bzz",
            figure="beyond the paper",
            metric="fraction of the tasks held",
            series="tasks_held_fraction",
        ),
    )
}

#: The paper's experiments (what `sim sweep` runs by default); the others go beyond it.
PAPER_EXPERIMENTS = ("task-allocation", "task-allocation-scale", "coverage", "coverage-scale")
