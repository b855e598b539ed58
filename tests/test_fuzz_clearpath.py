"""Clearpath MCU de-framer and Husky core fuzzing: a short deterministic campaign slice.

Long campaigns: `python -m tests.fuzz.clearpath_fuzz --count 500000 --seed S` (see that module).
"""

from __future__ import annotations

import random

import pytest
from fuzz import clearpath_fuzz

from fieldkit.vehicle.clearpath import frame as F
from fieldkit.vehicle.clearpath import messages as M


def test_campaign_slice() -> None:
    """1000 fixed inputs across both targets: no failure, both hit."""
    lines: list[str] = []
    stats = clearpath_fuzz.run("ci", max_inputs=1000, out=lines.append)
    assert stats.inputs == 1000
    assert stats.failures == 0, "\n".join(lines)
    assert set(stats.kinds) == {"deframe", "core"} and stats.kinds["core"] > 150


def test_reference_agrees_on_a_hand_made_stream() -> None:
    """The oracle itself: frames, counters and what is left of a small stream, by hand."""
    good = M.request(M.MsgType.ENCODERS).encode()
    bad_crc = good[:-1] + bytes([good[-1] ^ 1])
    stream = b"\x01\x02" + bad_crc + good + b"\xaa\x13"
    frames, stats, left = clearpath_fuzz.reference_deframe(stream)
    assert frames == [good] and left == 2  # AA 13: waiting for its ~LEN
    assert stats == {
        "frames": 1,
        "bad_crc": 1,
        "bad_frames": 1,
        # 01 02; the bad frame's SOH, then its 15 other bytes skipped byte by byte
        "garbage_bytes": 2 + 1 + 15,
    }


def test_deframe_check_can_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    """A de-framer that skips a whole claimed frame after a bad CRC (losing the frame that
    starts inside it) is caught: the property is not vacuous."""
    original = F.FrameReader.feed

    def greedy(self: F.FrameReader, data: bytes) -> list[F.Frame]:
        out = original(self, data)
        return out[1:] if self.stats["bad_crc"] else out

    monkeypatch.setattr(F.FrameReader, "feed", greedy)
    good = M.request(M.MsgType.ENCODERS).encode()
    stream = good[:-1] + b"\x00" + good + good
    problem = clearpath_fuzz.check_deframe(random.Random(0), stream)
    assert problem is not None and ("frames differ" in problem or "counters" in problem)


def test_core_check_can_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    """A core that trusts the power message's charge as it comes is caught."""
    from fieldkit.vehicle.clearpath.core import HuskyCore

    original = HuskyCore._on_frame

    def trusting(self: HuskyCore, frame: F.Frame, now: float) -> None:
        original(self, frame, now)
        value = M.decode(frame) if frame.type == M.MsgType.POWER_SYSTEM else None
        if isinstance(value, M.PowerSystem) and value.charges:
            self.telemetry.battery_percent = value.charges[0] * 100.0

    monkeypatch.setattr(HuskyCore, "_on_frame", trusting)
    power = M.power_system(M.PowerSystem((-3.0,), (480,), (1,))).encode()
    problem = clearpath_fuzz.check_core(random.Random(0), power, [power])
    assert problem is not None and "battery" in problem
