"""Patch verifier fuzzing: a short deterministic slice of the campaign, and proof that its
oracle sees a crash and a forgery.

Long campaigns: `python tests/fuzz/fuzz_patch.py --count 1000000 --seed S` (see that module).
"""

from __future__ import annotations

from typing import Any

import pytest
from fuzz import fuzz_patch

from fieldkit.update import patch


def test_campaign_slice() -> None:
    """3000 fixed inputs of every kind: no crash, no forgery, and both outcomes seen."""
    lines: list[str] = []
    stats = fuzz_patch.run("ci", max_inputs=3000, out=lines.append)
    assert stats.inputs == 3000
    assert stats.failures == 0, "\n".join(lines)
    assert set(stats.kinds) == set(fuzz_patch.KIND_NAMES)
    assert set(stats.targets) == {"read_header", "open_update", "open_rollback", "apply_deltas"}
    # Refusals at every stage, the deep ones reached through signed seeds.
    assert set(stats.reasons) >= {
        "accepted", "truncated", "too-large", "bad-magic", "bad-format", "bad-signature",
        "replayed", "fast-forward", "wrong-base", "bad-body", "bad-decrypt", "bad-delta",
        "bad-result",
    }  # fmt: skip
    assert 0 < stats.accepted < stats.inputs // 5


def test_every_seed_opens_as_expected() -> None:
    """The seeds are what they claim: good ones open to their release, bad ones do not."""
    w = fuzz_patch.world()
    for seed in w.seeds:
        if seed.name == "rollback":
            assert patch.open_rollback(seed.data, w.keys).version == 2
            continue
        outcome, problem = fuzz_patch.check("open_update", seed.data, seed.base, seed.current)
        assert problem is None
        assert (outcome == "accepted") == (seed.result is not None), seed.name


class _Lax:
    """A public key that accepts every signature."""

    def verify(self, signature: bytes, data: bytes) -> None:
        return None


def test_oracle_reports_a_verifier_that_skips_the_signature(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    real = patch.read_header

    def lax(data: bytes, operator_pub: Any) -> patch.PatchHeader:
        return real(data, _Lax())  # type: ignore[arg-type]

    monkeypatch.setattr(patch, "read_header", lax)
    lines: list[str] = []
    stats = fuzz_patch.run("ci", max_inputs=500, out=lines.append)
    assert stats.failures > 0
    assert any("nobody signed" in line for line in lines)


def test_oracle_reports_a_crash(monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(*args: object) -> int:
        raise IndexError("past the end")

    monkeypatch.setattr(patch, "_check_delta", broken)
    lines: list[str] = []
    stats = fuzz_patch.run("ci", max_inputs=500, out=lines.append)
    assert stats.failures > 0
    assert any("IndexError" in line for line in lines)
