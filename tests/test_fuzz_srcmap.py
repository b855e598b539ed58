"""Source-map (.bpos sidecar) decoder fuzzing: a short deterministic slice of the campaign,
plus hypothesis.

Long campaigns: `python -m tests.fuzz.srcmap_fuzz --seconds 300 --seed S` (see that module).
"""

from __future__ import annotations

import pytest
from fuzz import srcmap_fuzz
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bvm import srcmap
from bvm.errors import BuzzLoadError

FAST = settings(deadline=None, suppress_health_check=[HealthCheck.too_slow], max_examples=300)


def test_campaign_slice() -> None:
    """150 fixed inputs of every kind: no failure, and some accepted, some refused."""
    lines: list[str] = []
    stats = srcmap_fuzz.run("ci", max_inputs=150, out=lines.append)
    assert stats.inputs == 150
    assert stats.failures == 0, "\n".join(lines)
    assert set(stats.kinds) >= {"valid", "random", "mutate", "splice", "other"}
    assert 0.1 < stats.accepted / stats.inputs < 0.9


@FAST
@given(st.binary(max_size=400))
def test_any_bytes_decode_or_raise_a_load_error(data: bytes) -> None:
    bytecode, _ = srcmap_fuzz.seeds()[0]
    try:
        srcmap.decode(data, bytecode, "x.bpos")
    except BuzzLoadError as e:
        assert str(e).startswith("x.bpos: ")


@FAST
@given(st.data())
def test_tampered_sidecars_of_the_right_bo_decode_or_raise_a_load_error(
    data: st.DataObject,
) -> None:
    """Past a valid header (the right .bo), the decoder meets every field."""
    bytecode, sidecar = data.draw(st.sampled_from(srcmap_fuzz.seeds()))
    cut = data.draw(st.integers(13, len(sidecar)))
    tail = data.draw(st.binary(max_size=64))
    accepted, problem = srcmap_fuzz.check(bytecode, sidecar[:cut] + tail)
    assert problem is None


def test_valid_sidecars_round_trip() -> None:
    for bytecode, sidecar in srcmap_fuzz.seeds():
        smap = srcmap.decode(sidecar, bytecode)
        assert smap.positions
        assert srcmap.encode(smap, bytecode) == sidecar


def test_a_huge_count_is_refused_before_allocating() -> None:
    bytecode, sidecar = srcmap_fuzz.seeds()[0]
    at = srcmap_fuzz.position_count_at(sidecar)
    bad = sidecar[:at] + (0xFFFFFFFF).to_bytes(4, "little") + sidecar[at + 4 :]
    with pytest.raises(BuzzLoadError, match="cannot fit"):
        srcmap.decode(bad, bytecode)


def test_oracle_reports_foreign_exceptions(monkeypatch: pytest.MonkeyPatch) -> None:
    """The property can fail: a decoder raising anything but BuzzLoadError is reported."""
    bytecode, sidecar = srcmap_fuzz.seeds()[0]

    def broken(data: bytes, code: bytes, path: str = "") -> srcmap.SourceMap:
        raise IndexError("past the end")

    monkeypatch.setattr(srcmap, "decode", broken)
    accepted, problem = srcmap_fuzz.check(bytecode, sidecar)
    assert not accepted and problem is not None and "IndexError" in problem
