"""A process's output read line by line, each wait bounded by a deadline (a hang guard)."""

from __future__ import annotations

import re
import select
import subprocess
import time


class Lines:
    """A process's stdout read line by line, with a deadline for each wait."""

    def __init__(self, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        self.proc, self.out, self.seen = proc, proc.stdout, []  # type: list[str]

    def until(self, pattern: re.Pattern[str], deadline: float) -> re.Match[str] | None:
        """The first line matching, reading on until `deadline` (monotonic); None at EOF."""
        while True:
            left = deadline - time.monotonic()
            assert left > 0, f"nothing matched {pattern.pattern!r} in time: {self.seen[-5:]}"
            ready, _, _ = select.select([self.out], [], [], min(left, 1.0))
            if not ready:
                continue
            line = self.out.readline()
            if not line:
                return None
            self.seen.append(line)
            m = pattern.search(line)
            if m is not None:
                return m
