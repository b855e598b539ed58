"""The originator's outbox: a patch file the node hands to its update agent when it changes.

A robot that originates updates the ROSBuzz way runs the update monitor beside its node
(`fieldkit update SCRIPT --watch --patch-out /var/lib/fieldkit/outbox/update.patch`, the
`fieldkit-update.service` of `fieldkit deploy --originator`). Each save of the script becomes
a signed patch, written whole and renamed into place. The node (`--update-outbox FILE`,
`[node] update_outbox`) looks at that file every `OUTBOX_EVERY_TICKS` ticks at a tick
boundary: a `stat`, nothing read, while it stays the same file with the same size and time.
A new or changed file is read and handed to the update agent as if it had been received
whole (`RobotUpdater.inject`): verified with the robot's keys, then spread robot to robot
like any patch. A patch the agent refuses (other keys, a version not above the running one,
damaged bytes) is logged once with the reason, and the file is not read again until it
changes.

The node records each patch it read as an input of its tick (a recording's `/update/outbox`),
and a replay hands it back at that tick (`RecordedOutbox`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Protocol

#: Ticks between two looks at the outbox file (one a second at 10 Hz): a stat each.
OUTBOX_EVERY_TICKS = 10
#: A file larger than this is not read (no patch is this large: MAX_PATCH_BYTES is far less).
OUTBOX_MAX_BYTES = 4 * 1024 * 1024


class PatchSource(Protocol):
    """Where a node's locally made patches come from: the outbox file, or a recording's."""

    #: What the node's log lines name it by (the file's path).
    name: str

    def poll(self, tick: int) -> bytes | None:
        """A patch that is new at tick `tick`, else None."""


class Outbox:
    """The update monitor's patch file, looked at every `every` ticks (a stat, not a read)."""

    def __init__(
        self,
        path: Path,
        log: Callable[[str], None],
        *,
        every: int = OUTBOX_EVERY_TICKS,
    ) -> None:
        """`log` takes the lines about a file that cannot be read (each problem once)."""
        self.path = path
        self.name = str(path)
        self.log = log
        self.every = max(1, every)
        # What the file was at the last read: a change of any of these is a new patch (the
        # monitor renames a new file into place: a new inode, even at the same size and time).
        self._seen: tuple[int, int, int, int] | None = None
        self._problem: str | None = None  # the last problem logged, so it is logged once
        #: Files read (each a new or changed patch).
        self.reads = 0

    def poll(self, tick: int) -> bytes | None:
        """The file's bytes if it is new or changed since the last read, else None."""
        if tick % self.every:
            return None
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            self._seen = None  # none yet, or removed: the next file is new whatever it holds
            return None
        except OSError as e:
            self._say(f"cannot look at it: {e.strerror or e}")
            return None
        key = (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
        if key == self._seen:
            return None
        self._seen = key  # read once per change, whether or not the read works
        if st.st_size > OUTBOX_MAX_BYTES:
            self._say(f"{st.st_size} bytes, more than any patch: not read")
            return None
        try:
            with open(self.path, "rb") as f:
                data = f.read(OUTBOX_MAX_BYTES + 1)
        except OSError as e:
            self._say(f"cannot read it: {e.strerror or e}")
            return None
        self._problem = None
        self.reads += 1
        return data

    def _say(self, problem: str) -> None:
        if problem != self._problem:
            self._problem = problem
            self.log(f"outbox {self.path}: {problem}")


class RecordedOutbox:
    """A recording's outbox patches, handed back at their ticks (a replay's `PatchSource`)."""

    def __init__(self, patches: Mapping[int, Sequence[bytes]], name: str = "the recording") -> None:
        """`patches`: the patches read at each tick (a tick reads at most one)."""
        self.name = name
        self._patches = {tick: list(p) for tick, p in patches.items() if p}

    def poll(self, tick: int) -> bytes | None:
        """The patch recorded at `tick`, if one was."""
        found = self._patches.get(tick)
        return found.pop(0) if found else None


__all__ = ["OUTBOX_EVERY_TICKS", "OUTBOX_MAX_BYTES", "Outbox", "PatchSource", "RecordedOutbox"]
