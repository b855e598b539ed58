"""XBee de-framer and XbeeMav reassembler fuzzing: a short deterministic campaign slice.

Long campaigns: `python -m tests.fuzz.xbee_fuzz --seconds 600 --seed S` (see that module).
"""

from __future__ import annotations

import random

import pytest
from fuzz import xbee_fuzz

from fieldkit.radio import xbee as X
from fieldkit.radio import xbeemav as M


def test_campaign_slice() -> None:
    """3000 fixed inputs across the three targets: no failure, every target and kind hit."""
    lines: list[str] = []
    stats = xbee_fuzz.run("ci", max_inputs=3000, out=lines.append)
    assert stats.inputs == 3000
    assert stats.failures == 0, "\n".join(lines)
    assert set(stats.kinds) == {"deframe", "reassemble", "radio"}
    assert stats.kinds["radio"] > 50


def test_reference_agrees_on_a_hand_made_stream() -> None:
    """The oracle itself: frames and counters of a small stream, worked out by hand."""
    good = X.ModemStatus(1).encode(1)
    stream = b"\x01" + good + b"\x7e\x00\x00" + good[:-1] + b"\x00"
    frames, stats = xbee_fuzz.reference_deframe(stream, 1)
    assert frames == [X.ModemStatus(1)]
    assert stats == {
        "frames_in": 1,
        # 01; the zero length's 00 00; the bad frame's insides 00 02 8a 01 and its checksum
        "garbage_bytes": 1 + 2 + 5,
        "bad_length": 1,
        "bad_checksum": 1,
        "bad_frames": 2,
    }


def test_deframe_check_can_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    """A de-framer that skips a whole claimed frame after a bad checksum (losing the real
    frames inside it) is caught: the property is not vacuous."""
    original = X.FrameReader._scan

    def greedy(self: X.FrameReader, final: bool) -> list[X.Frame]:
        out = original(self, final)
        if self.stats["bad_checksum"]:
            return out[1:]
        return out

    monkeypatch.setattr(X.FrameReader, "_scan", greedy)
    stream = b"\x7e\x00\x05\x01\x02" + X.ModemStatus(1).encode(1) + X.ModemStatus(2).encode(1)
    problem = xbee_fuzz.check_deframe(random.Random(0), 1, stream)
    assert problem is not None and "frames differ" in problem


def test_reassemble_check_can_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    """An engine that forgets to drop expired partial packets is caught."""
    monkeypatch.setattr(M.XbeeMav, "_expire", lambda self, now: None)
    rng = random.Random(1)
    scenario = {
        "own": 0,
        "clean": False,
        "packets": [],
        "events": [(5, b"F\x01\x05\x00\x00\x00" + bytes(250))],
        "per_sender": 2,
        "max_partials": 4,
        "send_large": False,
    }
    problem = xbee_fuzz.check_reassemble(rng, scenario)
    assert problem is not None and "timeout" in problem
