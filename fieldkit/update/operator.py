"""The operator's end of an update over the radio: serve the patch, watch the swarm switch.

`OperatorSession` is sans-I/O like the robots' agent it wraps (a ground station's agent:
it runs no script, is never waited for by a barrier, and serves patches and verdicts). The
command line feeds it the radio's frames and the tick count and sends what it returns;
the session says, robot by robot, where the update is, and when it is over:

* every robot heard recently runs the new version: done;
* the version was rolled back (a barrier timeout, a script error, an order): failed, with
  the reason the swarm gives;
* the time is up: failed, naming the robots that did not switch.

The same session orders a rollback (`order_rollback`): the swarm's newest version is
declared bad and every robot returns to the one before it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from fieldkit.update.agent import AgentConfig, UpdateAgent
from fieldkit.update.packets import Phase, frame_key
from fieldkit.update.release import Release

if TYPE_CHECKING:
    from fieldkit.radio.base import RadioLink

#: The ground station's id on the radio: above every robot id the radios carry (0..254).
GROUND_ID = 255


@dataclass(frozen=True)
class RobotView:
    """What the operator knows of one robot."""

    robot: int
    version: int
    phase: Phase

    def describe(self) -> str:
        """`robot 3: version 2, standing by for the swarm`, in words."""
        what = {
            Phase.RUNNING: "running",
            Phase.STANDBY: "standing by for the swarm",
            Phase.GRACE: "switched (grace period)",
            Phase.OPERATOR: "ground station",
        }[self.phase]
        return f"robot {self.robot}: version {self.version}, {what}"


def _refuse_all(_data: bytes, _base: Release, _current: int) -> tuple[int, Release]:
    raise ValueError("a ground station applies no patch")


class OperatorSession:
    """A ground station serving one update (or ordering a rollback) to a live swarm."""

    def __init__(
        self, swarm_key: bytes, *, config: AgentConfig | None = None, ground_id: int = GROUND_ID
    ) -> None:
        """`swarm_key` seals the session's frames and checks the robots' ones."""
        self.agent = UpdateAgent(
            ground_id, 0, None, _refuse_all, config=config, frame_key=frame_key(swarm_key)
        )
        self.version: int | None = None  # the version being sent (None: only listening)
        self.rollback_of: int | None = None
        self._told: dict[int, RobotView] = {}

    # ------------------------------------------------------------ what the swarm runs

    def robots(self) -> dict[int, RobotView]:
        """Every robot heard recently and what it runs or waits for."""
        return {
            rid: RobotView(rid, p.version, p.phase) for rid, p in sorted(self.agent.live().items())
        }

    def running(self) -> dict[int, tuple[int, bytes]]:
        """Robot id -> (version, short hash) of what it runs, for robots heard directly."""
        return {
            rid: (p.version, p.running)
            for rid, p in sorted(self.agent.live().items())
            if p.running and p.phase in (Phase.RUNNING, Phase.GRACE)
        }

    # ------------------------------------------------------------ orders

    def send(self, patch: bytes, version: int, base_hash: str) -> None:
        """Serve `patch` (version `version`, built on `base_hash`) to the swarm."""
        self.version = version
        self.agent.hold(patch, version, base_hash)

    def order_rollback(self, version: int) -> None:
        """Declare `version` bad: every robot goes back to the version before it."""
        self.rollback_of = version
        self.agent.order_rollback(version)

    # ------------------------------------------------------------ the loop

    def step(self, now: int, frames: list[bytes]) -> bytes | None:
        """Tick `now`: the frames heard since the last one in, this tick's frame out."""
        for data in frames:
            self.agent.receive(data)
        self.agent.tick(now)
        return self.agent.frame()

    def changes(self) -> list[str]:
        """Lines for the robots whose state changed since the last call."""
        lines = []
        for rid, view in self.robots().items():
            if self._told.get(rid) != view:
                self._told[rid] = view
                lines.append(view.describe())
        return lines

    def outcome(self) -> tuple[bool, str] | None:
        """(success, why) once the update or rollback is over; None while it goes on."""
        robots = self.robots()
        if self.version is not None:
            bad = self.agent.bad.get(self.version)
            if bad is not None:
                return False, f"version {self.version} was rolled back: {bad}"
            if robots and all(
                v.version == self.version and v.phase is not Phase.STANDBY for v in robots.values()
            ):
                return True, f"all {len(robots)} robots run version {self.version}"
        elif self.rollback_of is not None:
            if robots and all(
                v.version < self.rollback_of and v.phase is Phase.RUNNING for v in robots.values()
            ):
                return True, f"all {len(robots)} robots left version {self.rollback_of}"
        return None

    def behind(self) -> list[int]:
        """The robots that have not reached the session's goal yet."""
        out = []
        for rid, v in self.robots().items():
            if self.version is not None and (v.version != self.version or v.phase is Phase.STANDBY):
                out.append(rid)
            elif self.rollback_of is not None and v.version >= self.rollback_of:
                out.append(rid)
        return out


def run_session(
    session: OperatorSession,
    radio: RadioLink,
    *,
    seconds: float,
    say: Callable[[str], None],
    until: Callable[[], bool] | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    hear: Callable[[bytes], None] | None = None,
) -> float:
    """Drive `session` over `radio` at 10 Hz for at most `seconds`, or until `until()` (by
    default: the session's outcome is known); `say` takes each robot's change of state,
    `hear` every other frame (bundles). The seconds it ran."""
    from fieldkit.update.packets import UPDATE_FRAME, frame_type

    done = until if until is not None else lambda: session.outcome() is not None
    start = clock()
    tick = 0
    while clock() - start < seconds and not done():
        frames = []
        for _sender, data in radio.poll():
            if frame_type(data) == UPDATE_FRAME:
                frames.append(data)
            elif hear is not None:
                hear(data)
        out = session.step(tick, frames)
        if out is not None:
            radio.send(out)
        for line in session.changes():
            say(line)
        tick += 1
        delay = start + tick * 0.1 - clock()
        if delay > 0:
            sleep(delay)
    return clock() - start


__all__ = ["GROUND_ID", "OperatorSession", "RobotView", "run_session"]
