"""Wire decoder fuzzing: a short deterministic slice of the campaign, plus hypothesis.

Long campaigns: `python -m tests.fuzz.wire_fuzz --seconds 300 --seed S` (see that module).
"""

from __future__ import annotations

import random

import pytest
from fuzz import wire_fuzz
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bvm import wire

FAST = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow])


def test_campaign_slice() -> None:
    """3000 fixed inputs of every kind: no failure, and a healthy share accepted."""
    lines: list[str] = []
    stats = wire_fuzz.run("ci", max_inputs=3000, out=lines.append)
    assert stats.inputs == 3000
    assert stats.failures == 0, "\n".join(lines)
    assert set(stats.kinds) >= {"valid", "random", "mutate", "splice", "length", "nest", "huge"}
    assert 0.1 < stats.accepted / stats.inputs < 0.6


@pytest.mark.parametrize("k", range(12))
def test_big_payloads_decode_in_linear_work(k: int) -> None:
    """Every family of ~64 KiB payloads, each decoded under the line counter."""
    payload = wire_fuzz.big_payload(random.Random(f"big:{k}"))
    assert len(payload) > 40_000
    assert wire_fuzz.check(payload) is None
    assert wire_fuzz.check_work(payload) is None


def test_work_counter_sees_quadratic_work(monkeypatch: pytest.MonkeyPatch) -> None:
    """The work check can fail: a decoder that rescans the payload per object is caught."""
    original = wire._obj

    def rescanning(buf: bytes, pos: int, end: int, depth: int, closure: object) -> object:
        seen = 0
        for _ in range(0, pos, 64):  # a Python loop over everything before `pos`
            seen += 1
        return original(buf, pos, end, depth, closure)

    # 25 tables of 255 int keys with nil values: about 12,800 objects in 38 KiB
    inner = b"\x04\xff" + b"".join(b"\x01" + j.to_bytes(4, "big") + b"\x00" for j in range(255))
    table = b"\x04\x19" + b"".join(b"\x01" + i.to_bytes(4, "big") + inner for i in range(25))
    payload = b"\x00\x03\x00\x01t" + table
    assert wire_fuzz.check_work(payload) is None
    monkeypatch.setattr(wire, "_obj", rescanning)
    problem = wire_fuzz.check_work(payload)
    assert problem is not None and "Python lines" in problem


def test_oracle_reports_foreign_exceptions(monkeypatch: pytest.MonkeyPatch) -> None:
    """The property can fail: a decoder raising anything but DecodeError is reported."""

    def broken(payload: bytes, closure: object = None) -> wire.Message:
        raise IndexError("index out of range")

    monkeypatch.setattr(wire, "decode", broken)
    problem = wire_fuzz.check(b"\x04\x00")
    assert problem is not None and "IndexError" in problem


def test_oracle_reports_unstable_round_trips(monkeypatch: pytest.MonkeyPatch) -> None:
    original = wire.decode

    def lossy(payload: bytes, closure: object = None) -> wire.Message:
        msg = original(payload)
        if isinstance(msg, wire.SwarmJoin) and len(payload) == 3:
            return wire.SwarmJoin(msg.swarm + 1)  # decodes differently each round
        return msg

    monkeypatch.setattr(wire, "decode", lossy)
    assert "!= m" in (wire_fuzz.check(b"\x04\x00\x03") or "")


def test_inputs_replay() -> None:
    assert wire_fuzz.make_input("s", 41) == wire_fuzz.make_input("s", 41)
    assert wire_fuzz.make_input("s", 41) != wire_fuzz.make_input("s", 42)


@FAST
@given(st.binary(max_size=300))
def test_any_bytes(data: bytes) -> None:
    assert wire_fuzz.check(data) is None


@FAST
@given(st.integers(0, 6), st.binary(max_size=200))
def test_any_body_after_a_type_byte(t: int, body: bytes) -> None:
    assert wire_fuzz.check(bytes([t]) + body) is None


@FAST
@given(st.binary(min_size=1, max_size=200), st.integers(0, 2**16))
def test_any_object_after_a_broadcast_topic(body: bytes, seed: int) -> None:
    """Start inside the value object, where most of the decoder is."""
    assert wire_fuzz.check(b"\x00\x03\x00\x01a" + body) is None
    rng = random.Random(seed)
    assert wire_fuzz.check(wire_fuzz.mutate(rng, wire_fuzz.valid_payload(rng))) is None
