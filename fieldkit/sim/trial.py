"""A new script version's trial: a few simulated seconds on a small swarm of each profile.

Before an update goes out, the originator runs the new program in the real simulator (the
runtime, script API closures, supervisor and radio model every simulated robot has), one
small swarm per device profile the field swarm uses, starting where the swarm is when
that is known. Any script error, in the global code, `init()` or a `step()`, refuses the
update; `trial` returns them as text, each naming the place in the script, the robot and
the simulated time:

    errors = trial(program, ["solo", "husky"], seconds=5.0)
    # s.bzz:12:9: division by zero (robot 2 of the solo swarm, at 2.1 s simulated)
    #   in step, called by the host

A trial is deterministic: the same program, profiles, start and seed give the same errors.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import bvm
from fieldkit.errors import ConfigError
from fieldkit.sim.simulator import SimConfig, Simulation, StartPose

#: How long a trial runs unless told: long enough for a takeoff, a few barriers and the
#: first gotos, short enough to run on every save.
DEFAULT_SECONDS = 5.0

#: Robots per profile's swarm unless a start state names them.
DEFAULT_ROBOTS = 3


@dataclass(frozen=True)
class StartState:
    """The state the field swarm is in, when known: robot id -> where it is and whether it
    flies. The trial swarms are these robots, at these places, in the air where they fly."""

    robots: Mapping[int, StartPose] = field(default_factory=dict)


def trial(
    program: bvm.Program,
    profiles: Sequence[str],
    *,
    robots: int = DEFAULT_ROBOTS,
    seconds: float = DEFAULT_SECONDS,
    seed: int = 0,
    start: StartState | None = None,
    globals_: Mapping[str, object] | None = None,
) -> list[str]:
    """Run `program` for `seconds` simulated seconds on a swarm of `robots` robots of each
    profile (the robots of `start` instead, when given) and return its script errors, one
    text each: `file:line:col: message (robot R of the PROFILE swarm, at T s simulated)`
    then the Buzz call stack, an error several robots made once, naming them all. Empty:
    the trial passed. `ConfigError` for a profile or start that cannot be simulated."""
    if not profiles:
        raise ConfigError("a trial needs at least one device profile")
    errors: list[str] = []
    for profile in dict.fromkeys(profiles):  # each profile once, in the order given
        errors += _trial_one(program, profile, robots, seconds, seed, start, globals_ or {})
    return errors


def _trial_one(
    program: bvm.Program,
    profile: str,
    robots: int,
    seconds: float,
    seed: int,
    start: StartState | None,
    globals_: Mapping[str, object],
) -> list[str]:
    """One profile's swarm: its script errors, as `trial` words them."""
    poses = dict(start.robots) if start is not None and start.robots else None
    config = SimConfig(
        script=Path(program.path),
        robots=len(poses) if poses is not None else robots,
        seconds=seconds,
        seed=seed,
        profile=profile,
        program=program,
        globals=dict(globals_),
        start=poses,
    )
    with _quiet():
        sim = Simulation(config)
        sim.run()
    # The same error on several robots is one problem: one entry naming them all.
    seen: dict[str, list[tuple[object, object]]] = {}
    for e in sim.errors:
        seen.setdefault(str(e["error"]), []).append((e["robot"], e["t_s"]))
    errors = [_describe(error, who, profile) for error, who in seen.items()]
    noted = {e["robot"] for e in sim.errors}
    for rid in sim.in_failsafe():
        if rid not in noted:  # the simulator notes every error; the rule stays explicit
            errors.append(f"robot {rid} ({profile}) ended in its failsafe after a script error")
    return errors


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    """The trial's robots log their errors and failsafes as a field robot does; the trial
    returns them instead, so their log lines would only say the same twice."""
    logger = logging.getLogger("fieldkit")
    saved = logger.level
    logger.setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        logger.setLevel(saved)


def _describe(error: str, who: list[tuple[object, object]], profile: str) -> str:
    """The error's first line (its place and message) with who and when, then its stack."""
    headline, _, rest = error.partition("\n")
    robots = ", ".join(str(r) for r, _ in who)
    first = who[0][1]
    when = f"at {first} s" if len(who) == 1 else f"first at {first} s"
    plural = "s" if len(who) > 1 else ""
    text = f"{headline} (robot{plural} {robots} of the {profile} swarm, {when} simulated)"
    return f"{text}\n{rest}" if rest else text


__all__ = ["DEFAULT_ROBOTS", "DEFAULT_SECONDS", "StartPose", "StartState", "trial"]
