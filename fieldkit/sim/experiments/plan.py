"""An experiment's grid as asked for, validated: robot counts, drop rates, runs, seeds."""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path

from fieldkit.sim.experiments.base import MISSION_S, Experiment, ExperimentError, RunSpec
from fieldkit.sim.experiments.catalogue import EXPERIMENTS, SCRIPT_DIR
from fieldkit.sim.radio import LinkModel

#: Bounds on the parameters (beyond them a run is either meaningless or would take days).
MAX_ROBOTS = 1000
MAX_RUNS = 1000
MAX_SECONDS = 100_000.0


@dataclass(frozen=True)
class Plan:
    """An experiment's grid as asked for: which robot counts, drop rates, runs and seeds."""

    experiment: Experiment
    robots: tuple[int, ...]
    drops: tuple[float, ...]
    runs: int
    seed: int
    seconds: float
    script: str
    swarm_key: bytes | None = None  # signed bundles under this key (docs/security.md)
    burst: float | None = None  # bursty losses of this mean length (ticks) at every drop

    def specs(self) -> list[RunSpec]:
        """The runs, in grid order (robots, then drop, then run): the order of every output."""
        e = self.experiment
        base = RunSpec(
            experiment=e,
            robots=0,
            drop=0.0,
            run=0,
            seed=0,
            seconds=self.seconds,
            script=self.script,
            include_dirs=(str(Path(self.script).parent),),
            swarm_key=self.swarm_key,
            burst=self.burst,
        )
        out = []
        for n in self.robots:
            shape = e.shape(n)
            for drop in self.drops:
                for k in range(self.runs):
                    # Run k of every cell has the same seed: common random numbers across cells.
                    out.append(
                        replace(base, robots=n, drop=drop, run=k, seed=self.seed + k, shape=shape)
                    )
        return out


def make_plan(
    name: str,
    *,
    robots: Iterable[int] | None = None,
    drops: Iterable[float] | None = None,
    runs: int | None = None,
    seed: int = 0,
    seconds: float | None = None,
    script: str | Path | None = None,
    swarm_key: bytes | None = None,
    burst: float | None = None,
) -> Plan:
    """Validate the parameters of experiment `name` and build its grid (ExperimentError)."""
    e = EXPERIMENTS.get(name)
    if e is None:
        raise ExperimentError(
            f"unknown experiment {name!r}: choose one of {', '.join(EXPERIMENTS)}"
        )
    robots_t = e.robots if robots is None else tuple(dict.fromkeys(robots))
    drops_t = e.drops if drops is None else tuple(dict.fromkeys(float(d) for d in drops))
    for n in robots_t:
        if not 1 <= n <= MAX_ROBOTS:
            raise ExperimentError(f"--robots must be between 1 and {MAX_ROBOTS}, got {n}")
        e.check_robots(n)
    for d in drops_t:
        if not 0.0 <= d <= 1.0:
            raise ExperimentError(f"--drop must be a probability in [0, 1], got {d}")
    runs = e.runs if runs is None else runs
    if not 1 <= runs <= MAX_RUNS:
        raise ExperimentError(f"--runs must be between 1 and {MAX_RUNS}, got {runs}")
    if not 0 <= seed < 2**31:
        raise ExperimentError(f"--seed must be between 0 and {2**31 - 1}, got {seed}")
    seconds = e.seconds if seconds is None else seconds
    if not math.isfinite(seconds) or not MISSION_S < seconds <= MAX_SECONDS:
        raise ExperimentError(
            f"--seconds must be more than {MISSION_S:g} (the mission starts at "
            f"{MISSION_S:g} s) and at most {MAX_SECONDS:g}, got {seconds:g}"
        )
    e.check_seconds(seconds)
    if burst is not None:
        _check_burst(burst, drops_t)
    path = Path(script) if script is not None else SCRIPT_DIR / e.script
    return Plan(
        e, robots_t, drops_t, runs, seed, float(seconds), str(path.resolve()), swarm_key, burst
    )


def _check_burst(burst: float, drops: Iterable[float]) -> None:
    """Raise ExperimentError unless bursts of mean length `burst` can make every drop rate."""
    if not math.isfinite(burst) or burst < 1.0:
        raise ExperimentError(f"--burst must be a mean of at least 1 tick, got {burst:g}")
    for d in drops:
        if d:
            try:
                LinkModel.bursty(d, burst)
            except ValueError as err:
                raise ExperimentError(f"--drop {d:g} with --burst {burst:g}: {err}") from None


def check_script(plan: Plan) -> None:
    """Compile the plan's script once, so a missing or broken one fails before any run."""
    import bvm
    from bvm.errors import BuzzCompileError, BuzzError

    if not Path(plan.script).is_file():
        raise ExperimentError(f"{plan.experiment.name}: behaviour script {plan.script} not found")
    try:
        bvm.compile_file(plan.script, include_dirs=(str(Path(plan.script).parent),))
    except (BuzzCompileError, BuzzError) as e:
        raise ExperimentError(str(e)) from None
    except OSError as e:
        raise ExperimentError(f"{plan.script}: cannot read: {e.strerror}") from None
