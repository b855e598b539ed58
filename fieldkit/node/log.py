"""The field node's log: one writer, every line stamped `[UTC time] robot N: text`.

What the script logs, what the node says about itself (radio, autopilot, late ticks, the
stop) and what the runtime and the autopilot link report through `logging` all go through
one `NodeLog`, so a node's log reads in time order and each line names its robot. The stamp
is UTC wall time to the millisecond, ISO 8601 (`[2026-11-26T09:03:24.123Z] robot 4: ...`):
nodes on different computers can be merged by time; the simulator stamps the same shape with
simulated seconds (`[    9.300 s] robot 4: ...`).

Under systemd (`journal` set, see fieldkit/node/journal.py) each line goes to journald
instead, unstamped (the journal stamps it), with its priority (`error:` and `warning:` lines
rank as such) and the fields ROBOT_ID and TICK (the tick in progress, `tick`).
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Callable
from typing import TextIO

from fieldkit.node.journal import Journal, priority_of


def wall_stamp(t: float) -> str:
    """`t` (seconds since the epoch) as `2026-11-26T09:03:24.123Z`: UTC, milliseconds."""
    whole, ms = divmod(int(t * 1000), 1000)
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(whole)) + f".{ms:03d}Z"


class NodeLog:
    """Writes lines `[UTC time] robot N: text` to one stream, one whole line at a time.

    Callable with the text of a line: pass it as `Node(out=...)`. A text of several lines
    stamps each (a script error's call stack stays with its robot and time when grepped).
    """

    def __init__(
        self,
        robot_id: int,
        stream: TextIO | None = None,
        wall: Callable[[], float] = time.time,
        journal: Journal | None = None,
    ) -> None:
        """`stream` defaults to sys.stdout as it is when a line is written; with `journal`,
        lines go there first (the stream takes those it could not send)."""
        self.robot_id = robot_id
        self.stream = stream
        self.wall = wall
        self.journal = journal
        #: The tick in progress (the node sets it), sent as the journal's TICK field.
        self.tick: int | None = None
        # The runtime logs from the node's loop, a radio or link thread may log too: the
        # lock keeps their lines whole and in the order they were stamped.
        self._lock = threading.Lock()

    def format(self, text: str, t: float) -> str:
        """The line(s) for `text` logged at `t`, without the final newline."""
        head = f"[{wall_stamp(t)}] robot {self.robot_id}: "
        return "\n".join(head + line for line in text.splitlines() or [""])

    def __call__(self, text: str) -> None:
        """Stamp `text` with the time now and write it (flushed: a service's log is live)."""
        with self._lock:
            stream = self.stream if self.stream is not None else sys.stdout
            if self.journal is not None:
                priority = priority_of(text)
                fields = {"ROBOT_ID": str(self.robot_id)}
                if self.tick is not None:
                    fields["TICK"] = str(self.tick)
                if self.journal.send(text, priority, fields):
                    return
                # journald's stream reads a `<N>` prefix as the line's priority.
                stream.write(f"<{priority}>{self.format(text, self.wall())}\n")
            else:
                stream.write(self.format(text, self.wall()) + "\n")
            stream.flush()

    def handler(self) -> logging.Handler:
        """A `logging` handler that writes records through this log."""
        return _Handler(self)


class _Handler(logging.Handler):
    """`logging` records as NodeLog lines (the message only: the line names the robot)."""

    def __init__(self, log: NodeLog) -> None:
        super().__init__()
        self.log = log
        # The runtime names its robot in its messages ("robot 4: ..."), for hosts of many.
        self._own = f"robot {log.robot_id}: "

    def emit(self, record: logging.LogRecord) -> None:
        """Write the record's message (a warning or error says so first)."""
        try:
            text = record.getMessage().removeprefix(self._own)
            if record.levelno >= logging.WARNING:
                text = f"{record.levelname.lower()}: {text}"
            self.log(text)
        except Exception:  # noqa: BLE001  # logging's rule: a bad record must not kill the node
            self.handleError(record)


__all__ = ["NodeLog", "wall_stamp"]
