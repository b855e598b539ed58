"""End-to-end message fuzzing: a deterministic slice of `tests/fuzz/net_fuzz.py`.

Long campaigns: `python -m tests.fuzz.net_fuzz --seconds 600 --seed S`.
"""

from __future__ import annotations

import pytest
from fuzz import net_fuzz

from bvm import network, wire


def test_campaign_slice() -> None:
    lines: list[str] = []
    inputs, payloads, failures = net_fuzz.run("ci", max_inputs=300, out=lines.append)
    assert inputs == 300 and payloads > 1000
    assert failures == 0, "\n".join(lines)


def test_the_property_can_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    # A decoder that lets a non-DecodeError escape must be caught by the harness.
    real = wire.decode

    def leaky(payload: bytes, closure: object = None) -> wire.Message:
        if payload[:1] == b"\x01":
            raise IndexError("a bug")
        return real(payload, closure=closure)

    monkeypatch.setattr(wire, "decode", leaky)
    monkeypatch.setattr(network, "_shared", {})  # no decoding shared with earlier tests
    problem = net_fuzz.check([(3, bytes.fromhex("01 0001 0003"))])
    assert problem is not None and "IndexError" in problem
