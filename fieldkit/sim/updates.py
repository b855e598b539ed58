"""Over-the-air updates in the simulator: `sim run --update T:NEW.bzz[:ROBOT]`.

Every robot gets the field's update agent (fieldkit.update), and its frames travel the
simulated radio with the real bytes, losses and ranges of the bundles. At simulated second
T the operator's patch (signed and encrypted with keys made for the run, built against what
robot ROBOT runs then, one version above the highest it knows) is handed to that robot, as
`fieldkit update --radio` hands it to the robot it reaches. From there it spreads, is
verified, agreed on and switched to (or rolled back) exactly as in the field.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from fieldkit.robot.runtime import RobotRuntime
from fieldkit.update.agent import AgentConfig, UpdateAgent
from fieldkit.update.host import RobotUpdater
from fieldkit.update.keys import RobotKeys
from fieldkit.update.packets import frame_key
from fieldkit.update.patch import make_update, open_update
from fieldkit.update.release import Release


@dataclass(frozen=True)
class SimUpdate:
    """An update to inject: at simulated second `t`, at robot `robot`, this release."""

    t: float
    release: Release
    robot: int = 1
    name: str = ""  # the script it was compiled from, for the log


@dataclass
class UpdateRecord:
    """What became of one injected update (the summary's `update`)."""

    version: int
    injected_s: float
    release: Release
    patch_bytes: int
    all_switched_s: float | None = None
    rolled_back: bool = False
    reason: str | None = None

    def summary(self, update_bytes_sent: int) -> dict[str, object]:
        """The summary.json form."""
        return {
            "version": self.version,
            "injected_s": self.injected_s,
            "all_switched_s": self.all_switched_s,
            "rolled_back": self.rolled_back,
            "reason": self.reason,
            "patch_bytes": self.patch_bytes,
            "update_bytes_sent": update_bytes_sent,
        }


class SwarmUpdates:
    """The update agents of a simulated swarm and the updates to inject into it."""

    def __init__(
        self,
        updates: list[SimUpdate],
        first: Release,
        *,
        seed: int,
        tick_s: float,
        config: AgentConfig | None = None,
        keys: RobotKeys | None = None,
    ) -> None:
        """`first` is what every robot runs at the start (version 0); `keys` are the swarm's
        (a ground station sends patches signed by their operator), else made for the run."""
        self.pending = sorted(updates, key=lambda u: u.t)
        self.first = first
        self.seed = seed
        self.tick_s = tick_s
        self.config = config or AgentConfig()
        # Keys made for this run: the operator's, and the swarm's every robot holds.
        self.signing_key = Ed25519PrivateKey.generate()
        self.keys = keys or RobotKeys(self.signing_key.public_key(), os.urandom(32))
        self.frame_key = frame_key(self.keys.swarm_key)
        self.updaters: dict[int, RobotUpdater] = {}
        self.records: list[UpdateRecord] = []

    def verify(self, data: bytes, base: Release, current: int) -> tuple[int, Release]:
        """What a robot does with a whole patch (fieldkit.update.patch.open_update)."""
        header, release = open_update(data, base=base, keys=self.keys, current_version=current)
        return header.version, release

    def attach(self, runtime: RobotRuntime, log: Callable[[str], None]) -> RobotUpdater:
        """Give robot `runtime` its update agent (every robot starts on `first`)."""
        agent = UpdateAgent(
            runtime.id,
            0,
            self.first,
            self.verify,
            config=self.config,
            seed=self.seed,
            frame_key=self.frame_key,
        )
        updater = RobotUpdater(runtime, agent, log=log)
        self.updaters[runtime.id] = updater
        return updater

    def inject_due(self, tick: int) -> list[str]:
        """Hand over every update due at `tick`; what happened, for the log."""
        lines = []
        while self.pending and round(self.pending[0].t / self.tick_s) <= tick:
            u = self.pending.pop(0)
            updater = self.updaters.get(u.robot)
            if updater is None:
                lines.append(f"update {u.name}: no robot {u.robot} to hand it to")
                continue
            agent = updater.agent
            base = agent.release
            assert base is not None
            version = max(agent.version, agent.highest) + 1
            patch = make_update(base, u.release, version, self.signing_key, self.keys.swarm_key)
            self.records.append(
                UpdateRecord(version, round(tick * self.tick_s, 6), u.release, len(patch))
            )
            lines.append(
                f"update {u.name or ''} injected at robot {u.robot}: version {version},"
                f" {len(patch)} bytes of patch"
            )
            agent.inject(patch)
        return lines

    def after_tick(self, tick: int) -> None:
        """Note when every robot first runs the newest update, and its rollbacks."""
        if not self.records:
            return
        record = self.records[-1]
        agents = [u.agent for u in self.updaters.values()]
        if record.all_switched_s is None and not record.rolled_back:
            if all(a.version == record.version for a in agents):
                record.all_switched_s = round((tick + 1) * self.tick_s, 6)
        if not record.rolled_back:
            for a in agents:
                if record.version in a.bad:
                    record.rolled_back = True
                    record.reason = a.bad[record.version]
                    break

    def versions(self) -> dict[str, str]:
        """Each robot's running version, as the hex SHA-256 of its bytecode."""
        return {str(rid): u.agent.running_hash for rid, u in sorted(self.updaters.items())}

    def bytes_sent(self) -> int:
        """Update bytes every robot put on the air."""
        return sum(u.agent.bytes_sent for u in self.updaters.values())


__all__ = ["SimUpdate", "SwarmUpdates", "UpdateRecord"]
