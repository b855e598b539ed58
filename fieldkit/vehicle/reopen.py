"""When to try a lost serial device again: a small state machine fed time, without I/O.

A USB cable that works loose makes the autopilot's device vanish (reads fail with EIO, the
node file goes) and come back a moment later, possibly as another ttyUSBn behind the same
udev symlink. The transport closes the port, tells `ReopenPolicy.lost`, and asks `due` on
each poll: an attempt (one open() of the path) is allowed once every `interval_s` of the
caller's clock, so a device that stays away costs one failed open a second, and a device
that flaps cannot flood the log (`lost` says True once per outage, `back` once).

    policy = ReopenPolicy(1.0)
    if policy.lost(now, "read failed: Input/output error"):   # True: a new outage, log it
        log("lost ...; reopening")
    if policy.due(now):                                       # on each poll while down
        try:
            port = open(path)
        except OSError:
            policy.failed(now)
        else:
            log(f"back after {policy.back(now):g} s")
"""

from __future__ import annotations

import math

DEFAULT_INTERVAL_S = 1.0
"""Seconds between two attempts to reopen a lost device."""


class ReopenPolicy:
    """Whether a lost device is down, and when the next attempt to reopen it is due."""

    def __init__(self, interval_s: float = DEFAULT_INTERVAL_S) -> None:
        """A policy for a device that is up; attempts at most once every `interval_s`."""
        if not (math.isfinite(interval_s) and interval_s > 0):
            raise ValueError(f"reopen interval must be > 0 s, got {interval_s}")
        self.interval_s = interval_s
        self.down_since: float | None = None  # the caller's clock at the loss
        self.reason = ""  # why it was lost
        self.attempts = 0  # failed attempts in this outage
        self.outages = 0  # losses so far, this one included
        self.down_s = 0.0  # seconds down in the outages that ended
        self._next = 0.0

    @property
    def down(self) -> bool:
        """Whether the device is lost and not reopened yet."""
        return self.down_since is not None

    def lost(self, now: float, reason: str) -> bool:
        """The device failed at `now`; True if it was up (a new outage, to be told once).

        The first attempt is due `interval_s` later, not at once: a device in the middle of
        going away can still open and fail again, which would make one pull look like many.
        """
        if self.down_since is not None:
            return False
        self.down_since, self.reason, self.attempts = now, reason, 0
        self.outages += 1
        self._next = now + self.interval_s
        return True

    def due(self, now: float) -> bool:
        """Whether an attempt to reopen should be made now."""
        return self.down_since is not None and now >= self._next

    def failed(self, now: float) -> None:
        """An attempt at `now` failed: the next one is due `interval_s` later."""
        self.attempts += 1
        self._next = now + self.interval_s

    def back(self, now: float) -> float:
        """The device opened again at `now`: seconds it was down (0 if it was not)."""
        since, self.down_since = self.down_since, None
        down = 0.0 if since is None else max(0.0, now - since)
        self.down_s += down
        return down

    def down_for(self, now: float) -> float:
        """Seconds the device has been down at `now` (0 while it is up)."""
        since = self.down_since
        return 0.0 if since is None else max(0.0, now - since)


__all__ = ["DEFAULT_INTERVAL_S", "ReopenPolicy"]
