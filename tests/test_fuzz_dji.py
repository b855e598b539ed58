"""DJI OPEN protocol fuzzing: a short deterministic slice of the campaign, and its oracles.

Long campaigns: `python -m tests.fuzz.dji_fuzz --seconds 900 --max-inputs 500000 --seed S`.
"""

from __future__ import annotations

import random

import pytest
from fuzz import dji_fuzz

from fieldkit.vehicle.dji import messages as M
from fieldkit.vehicle.dji.core import DjiCore
from fieldkit.vehicle.dji.frame import FrameReader, ack_frame, command_frame


def test_campaign_slice() -> None:
    """1000 fixed inputs across the three targets: no failure, every target hit."""
    lines: list[str] = []
    stats = dji_fuzz.run("ci", max_inputs=1000, out=lines.append)
    assert stats.inputs == 1000
    assert stats.failures == 0, "\n".join(lines)
    assert set(stats.kinds) == {"deframe", "core", "sim"}
    assert stats.kinds["core"] > 100 and stats.kinds["sim"] > 50


def test_reference_agrees_on_a_hand_made_stream() -> None:
    """The oracle itself: frames and counters of a small stream, worked out by hand."""
    good = command_frame(2, 1, 0, 0, b"\x00")
    broken = bytearray(ack_frame(2, 9, b"\x02\x00"))
    broken[-1] ^= 1
    stream = b"\x01\x02" + good + bytes(broken) + good[:5]
    frames, stats, pending = dji_fuzz.reference_deframe(stream, None)
    assert [f.seq for f in frames] == [1]
    assert stats == {
        "frames": 1,
        "garbage_bytes": 2 + len(broken),  # the broken ACK is slid past one byte at a time
        "crc_errors": 1,
        "bad_frames": 2,
    }
    assert pending == 5  # a header still coming


def test_deframe_check_can_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    """A reader that forgets to count a run of noise is caught: the property is not vacuous."""
    monkeypatch.setattr(FrameReader, "_discard", lambda self, count: None)
    stream = b"\x55\x66" + command_frame(2, 1, 0, 0, b"\x00")
    problem = dji_fuzz.check_deframe(random.Random(0), stream, False)
    assert problem is not None and "counters differ" in problem


def test_core_check_can_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    """A core whose RC handler breaks on hostile values is caught (a link error)."""

    def broken(self: DjiCore, rc: tuple[int, ...]) -> None:
        raise ValueError("boom")

    monkeypatch.setattr(DjiCore, "_on_rc", broken)
    failures = []
    for k in range(200):
        rng = random.Random(f"can-fail:{k}")
        kinds, failure = dji_fuzz.check_core(rng)
        if failure is not None:
            failures.append(failure)
    assert failures and all("link errors" in f for f in failures)


def test_a_broadcast_that_promises_absent_items_is_only_counted() -> None:
    core, clock = dji_fuzz.connected_core(random.Random(1))
    value = M.Broadcast(position=(0.1, 0.2, 3.0, 4.0, 5)).encode()[:-3]
    assert core.receive_data(command_frame(0, 1, *M.PUSH_BROADCAST, value)) == 1
    assert core.malformed == 1 and core.link_errors == 0 and core.telemetry.lat is None
