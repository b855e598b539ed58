"""The node's time, read once a tick: what makes a flight replayable.

Everything a tick does (the remote-control commands falling due, the autopilot core's
heartbeats, command retries and timeouts, the time field of the bundle) asks `TickClock`,
which reads its sources once, when the tick begins, and gives that one value until the tick
ends. So a tick's decisions depend on the tick's time and its inputs, not on how long its
own work took; a recording of each tick's time (`clock_s`, `unix_ns`) and inputs gives a
replay the same decisions (docs/replay.md, "What it takes for a node to replay exactly").
Between ticks the clock runs live, for the loop's pacing and the start-up waits.
"""

from __future__ import annotations

import time
from collections.abc import Callable


class TickClock:
    """Monotonic seconds and wall nanoseconds, frozen from `begin_tick` to `end_tick`."""

    def __init__(
        self,
        source: Callable[[], float] = time.monotonic,
        wall: Callable[[], int] = time.time_ns,
    ) -> None:
        self.source = source
        self.wall = wall
        self._frozen: float | None = None
        self._unix_ns = 0

    def now(self) -> float:
        """The tick's time during a tick, the source's between ticks (seconds)."""
        frozen = self._frozen
        return self.source() if frozen is None else frozen

    def begin_tick(self) -> float:
        """Read both sources once for the tick that begins; its time in seconds."""
        self._frozen = t = self.source()
        self._unix_ns = self.wall()
        return t

    def end_tick(self) -> None:
        """The tick is over: time runs live again."""
        self._frozen = None

    @property
    def unix_ns(self) -> int:
        """The wall time (ns since 1970) read when the current or last tick began."""
        return self._unix_ns

    @property
    def in_tick(self) -> bool:
        """Whether a tick is running (the clock is frozen)."""
        return self._frozen is not None


__all__ = ["TickClock"]
