"""Update frame decoder and update agent fuzzing: a short deterministic campaign slice.

Long campaigns: `python tests/fuzz/update_frame_fuzz.py --count 1000000 --seed S` (see that
module).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from fuzz import update_frame_fuzz as F

from fieldkit.update import packets as pk
from fieldkit.update.agent import UpdateAgent, _Transfer
from fieldkit.update.release import Release

HARNESS = Path(__file__).resolve().parent / "fuzz" / "update_frame_fuzz.py"


def test_campaign_slice() -> None:
    """3000 fixed inputs: no failure, both targets and every mutation hit, and the agents
    both switched (to verified versions) and rolled back, and refused forged patches."""
    lines: list[str] = []
    stats = F.run("ci", max_inputs=3000, out=lines.append)
    assert stats.inputs == 3000
    assert stats.failures == 0, "\n".join(lines)
    mutations = {k.split("/")[1] for k in stats.kinds if k.startswith("decode/")}
    assert mutations >= {
        "valid", "random", "flip", "byte", "truncate", "extend", "record-length",
        "record-kind", "count", "header", "field", "entries-count", "records", "splice",
        "random-body",
    }  # fmt: skip
    assert {k for k in stats.kinds if k.startswith("agent/")} == {
        f"agent/{k}" for k in ("complete", "forged", "mutant", "random", "valid")
    }
    assert stats.accepted > 300  # mutants often stay frames: the re-encoding is checked
    assert stats.switches > 20 and stats.rollbacks > 10 and stats.refused_patches > 100


def test_the_decode_check_can_fail(monkeypatch: pytest.MonkeyPatch) -> None:
    """A decoder that lets junk through in the padding is caught (its frame re-encodes to
    other bytes): the property is not vacuous."""
    original = pk.decode

    def lax(data: bytes) -> pk.Frame:
        image = bytearray(pk._swap(bytes(data)))
        image[-1] = 0
        return original(pk._swap(bytes(image)))

    good = pk.encode(pk.Frame(1, (pk.Verdict(2, pk.Reason.OPERATOR),)))
    image = bytearray(pk._swap(good))
    image[-1] = 1  # one byte of padding that is not zero
    junk = pk._swap(bytes(image))
    assert F.check_decode(junk, None) == (False, None)
    monkeypatch.setattr(pk, "decode", lax)
    accepted, problem = F.check_decode(junk, None)
    assert accepted and problem is not None and "re-encodes differently" in problem


def test_the_agent_check_catches_a_forgery(monkeypatch: pytest.MonkeyPatch) -> None:
    """An agent that stages a whole patch without asking the verifier switches to a
    forger's release: caught."""

    def trusting(self: UpdateAgent, t: _Transfer, *, local: bool) -> bool:
        self.transfers[t.digest] = t
        self.staged = (t.version, Release(t.data()[72:]))
        return True

    evil = F.stand_in_patch(F.R1, Release(b"the forger's script"), 1)  # a replay
    digest = pk.Offer(F.digest_of(evil), 3, len(evil), F.short(F.R1.hash))
    events: list[object] = [
        ("forged", pk.encode(pk.Frame(3, (digest,)))),
        *(("forged", c) for c in F._chunk_frames(evil, 3)),
        5,
    ]
    scenario = {"held": [], "events": events, "seed": 0}
    assert F.check_agent(scenario) is None  # the real agent refuses it
    monkeypatch.setattr(UpdateAgent, "_complete", trusting)
    problem = F.check_agent(scenario)
    assert problem is not None and "never verified" in problem


def test_the_agent_check_catches_an_exception(monkeypatch: pytest.MonkeyPatch) -> None:
    """An agent whose CHUNK handling trips over a hostile index is caught."""

    def fragile(self: UpdateAgent, c: pk.Chunk) -> None:
        t = self.transfers[c.digest]  # KeyError for a chunk of a patch it does not pull
        t.chunks[c.index] = c.data

    monkeypatch.setattr(UpdateAgent, "_on_chunk", fragile)
    stray = pk.encode(pk.Frame(3, (pk.Chunk(bytes(8), 0, b"x"),)))
    problem = F.check_agent({"held": [], "events": [("mutant", stray)], "seed": 0})
    assert problem is not None and "KeyError" in problem


def test_the_harness_runs_as_a_file_with_a_count(tmp_path: Path) -> None:
    """`python tests/fuzz/update_frame_fuzz.py --count N` (no package, no time limit)."""
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
