"""The node's clock is read once a tick: every part of a tick sees one time."""

from __future__ import annotations

import itertools

from fieldkit.node.clock import TickClock


def test_the_clock_is_frozen_during_a_tick_and_live_between() -> None:
    ticks = itertools.count(0.0, 0.25)  # a source that moves on at every read
    walls = itertools.count(1_000, 7)
    clock = TickClock(lambda: next(ticks), lambda: next(walls))
    assert clock.now() == 0.0 and clock.now() == 0.25  # live
    t = clock.begin_tick()
    assert clock.in_tick and [clock.now() for _ in range(5)] == [t] * 5
    assert clock.unix_ns == 1_000
    clock.end_tick()
    assert not clock.in_tick and clock.now() > t
    assert clock.begin_tick() > t and clock.unix_ns == 1_007
