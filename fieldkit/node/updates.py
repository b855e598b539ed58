"""The field node's over-the-air updates: the update agent backed by the `--state-dir` store.

`node_updater` builds the robot's `RobotUpdater` from what the store remembers (the
committed version, the versions before it, the highest version ever accepted, the versions
rolled back, the patches kept) and makes every decision durable before the robot acts on
it: a verified patch is kept, a version is stored whole and committed when the robot
switches to it, a rollback is committed when it happens. So a robot killed at any instant
restarts on a complete, verified version, and a robot back from a reboot serves and pulls
patches like the others (docs/update.md#the-version-store).
"""

from __future__ import annotations

from collections.abc import Callable

from fieldkit.errors import FieldkitError
from fieldkit.robot.runtime import RobotRuntime
from fieldkit.update.agent import Action, Resume, Rollback, Switch, UpdateAgent
from fieldkit.update.host import RobotUpdater
from fieldkit.update.keys import RobotKeys
from fieldkit.update.packets import frame_key
from fieldkit.update.patch import open_update, read_header
from fieldkit.update.release import Release
from fieldkit.update.store import VersionStore


def node_updater(
    runtime: RobotRuntime,
    store: VersionStore,
    keys: RobotKeys,
    log: Callable[[str], None],
    *,
    seed: int = 0,
) -> RobotUpdater:
    """The node's update agent over `store`, verifying with `keys`; `log` takes its lines."""
    committed = store.current
    if committed is None:
        raise FieldkitError(f"{store.root}: no committed version to update from")
    previous = [(v, store.get(h)) for v, h in committed.previous if store.has(h)]

    def verify(data: bytes, base: Release, current: int) -> tuple[int, Release]:
        header, release = open_update(data, base=base, keys=keys, current_version=current)
        return header.version, release

    agent = UpdateAgent(
        runtime.id,
        committed.version,
        store.get(committed.hash),
        verify,
        previous=previous,
        highest=committed.highest,
        bad={v: "rolled back before this start" for v in committed.bad},
        seed=seed,
        frame_key=frame_key(keys.swarm_key),
    )
    for version in store.patches():
        data = store.patch(version)
        try:
            header = read_header(data, keys.operator_pub)
        except FieldkitError as e:  # kept under other keys, or damaged: not served
            log(f"patch for version {version} in {store.root} not served: {e}")
            continue
        agent.hold(data, header.version, header.base_hash)

    def on_change(action: Action) -> None:
        # Durable before the robot runs it: a kill -9 after this restarts on this version.
        if isinstance(action, Switch):
            store.put(action.release)
            store.commit(action.version, action.release.hash, reason=action.reason)
        elif isinstance(action, Rollback):
            store.rollback(action.bad, reason=action.reason, to_hash=action.release.hash)
        elif isinstance(action, Resume):
            store.rollback(action.version, reason=action.reason)

    return RobotUpdater(runtime, agent, log=log, on_change=on_change, on_patch=store.put_patch)


__all__ = ["node_updater"]
