"""The node's radio security: the mode, the keys, and the two small files that make it last.

A signed node keeps its bundle counter (`bundle.counter`: a reboot never reuses a counter)
and its neighbours' floors (`bundle.floors`: a reboot does not reopen their replay windows)
in its state directory, beside its script versions (docs/security.md#counters-and-reboots).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from fieldkit.errors import FieldkitError
from fieldkit.robot import bundle_auth as auth
from fieldkit.robot.link_security import NONE, SIGNED, LinkSecurity
from fieldkit.robot.operator_command import CommandGate, CommandSeqStore

if TYPE_CHECKING:
    from fieldkit.update.keys import RobotKeys

#: The robot's own bundle counter, in the state directory.
COUNTER_FILE = "bundle.counter"
#: Its neighbours' highest counters, saved about once a minute.
FLOORS_FILE = "bundle.floors"
#: The last operator command's sequence number acted on, saved before acting.
COMMAND_SEQ_FILE = "command.seq"


def node_security(
    robot_id: int,
    mode: str,
    keys: RobotKeys | None,
    state_dir: Path | None,
    say: Callable[[str], None],
) -> LinkSecurity:
    """The node's LinkSecurity in `mode`; FieldkitError (what, where, a hint) if signed mode
    lacks its keys or state directory, or a counter or floor file is damaged."""
    if mode == NONE:
        return LinkSecurity(robot_id, NONE, report=say)
    if mode != SIGNED:
        raise FieldkitError(f"security mode must be signed or none, got {mode!r}")
    if keys is None:
        raise FieldkitError(
            "--security signed authenticates bundles with the swarm key: give --keys DIR"
        )
    if state_dir is None:
        raise FieldkitError(
            "--security signed keeps the robot's bundle counter in --state-dir: give "
            "--state-dir DIR (the robot's own, kept across reboots), or --security none"
        )
    key = auth.bundle_key(keys.swarm_key)
    state_dir.mkdir(parents=True, exist_ok=True)
    counters = auth.CounterStore(state_dir / COUNTER_FILE)
    floors = auth.FloorStore(state_dir / FLOORS_FILE, key)
    security = LinkSecurity.signed_with(robot_id, key, counters, floors=floors, report=say)
    if floors.other_key:
        say(f"{floors.path}: floors saved under another swarm key, ignored (a re-key)")
    return security


def node_commands(
    robot_id: int, keys: RobotKeys | None, state_dir: Path | None
) -> CommandGate | None:
    """The gate for the operator's signed commands: None without keys (no command heard on
    the radio is then acted on); without a state directory its memory of the last command
    acted on lasts until the node stops."""
    if keys is None:
        return None
    store = None if state_dir is None else CommandSeqStore(state_dir / COMMAND_SEQ_FILE)
    return CommandGate(robot_id, keys.operator_pub, store)


__all__ = ["COMMAND_SEQ_FILE", "COUNTER_FILE", "FLOORS_FILE", "node_commands", "node_security"]
