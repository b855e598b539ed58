"""Authenticated-bundle Verifier fuzzing: a short deterministic campaign slice, and proof
that the harness's checks catch a broken verifier.

Long campaigns: `python tests/fuzz/bundle_auth_fuzz.py --count 1000000 --seed S` (see that
module).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from fuzz import bundle_auth_fuzz as F

from fieldkit.robot import bundle_auth as A

HARNESS = Path(__file__).resolve().parent / "fuzz" / "bundle_auth_fuzz.py"


def test_campaign_slice() -> None:
    """3000 fixed inputs: no failure, every kind of input and every reason hit, evictions
    and restored floors among them."""
    lines: list[str] = []
    stats = F.run("ci", max_inputs=3000, out=lines.append)
    assert stats.inputs == 3000
    assert stats.failures == 0, "\n".join(lines)
    assert set(stats.kinds) >= {
        "genuine", "flip", "byte", "truncate", "extend", "trailer", "counter", "sender",
        "nwords", "swap-trailer", "swap-tag", "splice", "strip", "plain-extra", "foreign",
        "forged", "plain", "update-frame", "rosbuzz-ota", "random-sealed", "random",
    }  # fmt: skip
    assert set(stats.reasons) == set(A.REASONS)
    assert stats.accepted > 3000 and stats.reasons[A.REPLAYED] > 100
    assert stats.reasons[A.TOO_OLD] > 50


def _events(*pairs: tuple[int, int]) -> list[F.Event]:
    return [("genuine", F.POOL[s][c - 1], None) for s, c in pairs]


def test_the_check_catches_a_verifier_without_a_tag_check(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    forged = A.Sealer(1, F.FORGER, A.MemoryCounter(7)).seal(F.GENUINE[F.POOL[1][6]][2])
    events: list[F.Event] = [("forged", forged, A.BAD_TAG)]
    assert F.check(A.MAX_SENDERS, {}, events) is None
    monkeypatch.setattr(A.hmac, "compare_digest", lambda a, b: True)
    problem = F.check(A.MAX_SENDERS, {}, events)
    assert problem is not None and "FORGERY ACCEPTED" in problem


def test_the_check_catches_a_verifier_that_forgets_its_window(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    events = _events((1, 10), (1, 8), (1, 8))
    assert F.check(A.MAX_SENDERS, {}, events) is None

    def forgetful(self: A.Verifier, sender: int, counter: int) -> None:
        self._windows[sender] = A._Window(max(counter, 1), 0)

    monkeypatch.setattr(A.Verifier, "_accept", forgetful)
    problem = F.check(A.MAX_SENDERS, {}, events)
    assert problem is not None and "the model says replayed" in problem


def test_the_check_catches_an_eviction_that_reopens_replays(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A verifier that drops an evicted sender's highest counter accepts its bundles again."""
    events = _events((1, 5), (2, 5), (1, 5))
    assert F.check(1, {}, events) is None
    real = A.Verifier._remember

    def amnesic(self: A.Verifier, sender: int, w: A._Window) -> None:
        real(self, sender, w)
        self._evicted = None

    monkeypatch.setattr(A.Verifier, "_remember", amnesic)
    problem = F.check(1, {}, events)
    assert problem is not None and "the model says replayed" in problem


def test_the_check_catches_an_exception(monkeypatch: pytest.MonkeyPatch) -> None:
    def fragile(self: A.Verifier, data: bytes) -> bytes:
        return bytes(data)[100:200][50]  # type: ignore[return-value]

    monkeypatch.setattr(A.Verifier, "verify", fragile)
    problem = F.check(A.MAX_SENDERS, {}, [("random", bytes(8), None)])
    assert problem is not None and "IndexError" in problem


def test_the_harness_runs_as_a_file_with_a_count(tmp_path: Path) -> None:
    """`python tests/fuzz/bundle_auth_fuzz.py --count N` (no package, no time limit)."""
    done = subprocess.run(
        [sys.executable, str(HARNESS), "--count", "300", "--seed", "cli"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[-1] == "inputs: 300, failures: 0"
    again = subprocess.run(
        [sys.executable, str(HARNESS), "--replay", "cli:7"],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=tmp_path,
    )
    assert again.returncode == 0 and again.stdout.rstrip().endswith("ok"), again.stderr
