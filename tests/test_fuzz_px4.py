"""The PX4 link core under hostile traffic and orders: a short deterministic campaign slice.

Long campaigns: `python -m tests.fuzz.px4_fuzz --count 500000 --seed S` (see that module).
"""

from __future__ import annotations

from typing import Any

import pytest
from fuzz import px4_fuzz as F

from fieldkit.vehicle.px4 import OFFBOARD, Px4Core


def test_campaign_slice() -> None:
    """800 fixed inputs: no failure; every start and kind of event, PX4 leaving OFFBOARD by
    itself in many of them, and OFFBOARD switches the core was asked for."""
    lines: list[str] = []
    stats = F.run("ci", max_inputs=800, out=lines.append)
    assert stats.inputs == 800
    assert stats.failures == 0, "\n".join(lines)
    assert set(stats.kinds) == {
        "frames", "mutated", "generic", "time", "order",
        "start:silent", "start:connected", "start:taking_off", "start:offboard",
    }  # fmt: skip
    assert stats.offboard_losses > 100 and stats.switches > 100


def test_the_no_fighting_check_can_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    """A core that takes OFFBOARD back when PX4 leaves it (the bug the rule is about) is
    caught: the property is not vacuous."""
    original = Px4Core._mode_taken

    def fighting(self: Px4Core, mode: str, now: float) -> str:
        text = original(self, mode, now)
        t = self.telemetry
        if self.offboard_lost is not None and t.lat is not None and t.lon is not None:
            self._start_stream(t.lat, t.lon, 3.0, None)
            step: Any = self._mode_step(OFFBOARD)
            self._new("take it back", [step], None)
        return text

    monkeypatch.setattr(Px4Core, "_mode_taken", fighting)
    lines: list[str] = []
    stats = F.run("ci", max_inputs=200, out=lines.append)
    assert stats.failures > 0
    assert any("an OFFBOARD switch after PX4 left OFFBOARD" in line for line in lines)
