"""What a replay rebuilds from a recording's meta: the profile and the robot's security.

Shared by the field node's replay (`fieldkit.node.replay`) and a simulated robot's
(`fieldkit.sim.replay`): the recording keeps the security state (mode, the swarm key's
fingerprint, the next counter, the neighbours' floors, the last operator command acted on),
never a key; the replay takes the keys from the operator.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from fieldkit.record.compare import ReplayError
from fieldkit.robot.bundle_auth import MemoryCounter, Sealer, Verifier, bundle_key
from fieldkit.robot.link_security import LinkSecurity
from fieldkit.robot.operator_command import CommandGate
from fieldkit.robot.profiles import Profile, load_profile

if TYPE_CHECKING:
    from fieldkit.update.keys import RobotKeys


def recorded_profile(text: str) -> Profile:
    """The device profile a recording holds as text (ProfileError if it is not one)."""
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "recorded.toml"
        path.write_text(text, encoding="utf-8")
        return load_profile(path)


class _RecordedSeq:
    """A command gate's store in a replay: starts where the recording did, saves nowhere."""

    def __init__(self, last: int) -> None:
        self.last = last

    def load(self) -> int:
        """The recorded last sequence number acted on."""
        return self.last

    def save(self, n: int) -> None:
        """Nothing to keep: a replay is not a flight."""


def recorded_security(
    meta: dict[str, object], robot_id: int, keys: RobotKeys | None
) -> tuple[LinkSecurity | None, CommandGate | None]:
    """The recorded robot's security (its LinkSecurity, its command gate), rebuilt from its
    meta and `keys`; ReplayError if the keys are missing or another swarm's."""
    mode = meta.get("security")
    gate = None
    if "command_last_acted" in meta:
        if keys is None:
            raise ReplayError(
                "the recorded robot checked operator commands with its keys: give --keys DIR"
            )
        last = int(meta["command_last_acted"])  # type: ignore[call-overload]
        gate = CommandGate(robot_id, keys.operator_pub, _RecordedSeq(last))
    if mode is None:
        return None, gate
    if mode != "signed":
        return LinkSecurity(robot_id, "none"), gate
    if keys is None:
        raise ReplayError("the flight was signed: give the robot's keys, --keys DIR")
    key = bundle_key(keys.swarm_key)
    if key.fingerprint != meta.get("key_fingerprint"):
        raise ReplayError(
            f"the flight was signed under swarm key {meta.get('key_fingerprint')}; "
            f"the keys given are {key.fingerprint}\nhint: give the robot's own --keys DIR"
        )
    floors = {int(s): int(c) for s, c in dict(meta.get("floors", {})).items()}  # type: ignore[call-overload]
    start = int(meta.get("counter_start", 1))  # type: ignore[call-overload]
    security = LinkSecurity(
        robot_id,
        "signed",
        sealer=Sealer(robot_id, key, MemoryCounter(start)),
        verifier=Verifier(key, floors=floors),
    )
    return security, gate


__all__ = ["recorded_profile", "recorded_security"]
