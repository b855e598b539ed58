"""Operator-command gate fuzzing: a short deterministic campaign slice, and proof that the
harness's checks catch a broken gate.

Long campaigns: `python tests/fuzz/operator_command_fuzz.py --count 1000000 --seed S` (see
that module).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from fuzz import operator_command_fuzz as F

from fieldkit.robot import operator_command as C

HARNESS = Path(__file__).resolve().parent / "fuzz" / "operator_command_fuzz.py"


def test_campaign_slice() -> None:
    """3000 fixed inputs: no failure, every kind of input and every reason hit, reboots,
    relays, acts and frames for other robots among them."""
    lines: list[str] = []
    stats = F.run("ci", max_inputs=3000, out=lines.append)
    assert stats.inputs == 3000
    assert stats.failures == 0, "\n".join(lines)
    assert set(stats.kinds) >= {
        "genuine", "flip", "byte", "truncate", "extend", "field", "params", "swap-signature",
        "key-id", "words", "splice", "foreign", "forged", "bundle", "sealed-bundle",
        "update-frame", "rosbuzz-ota", "random-command", "random", "reboot",
    }  # fmt: skip
    assert set(stats.reasons) == set(C.REASONS)
    assert stats.acted > 1000 and stats.relayed > 2000 and stats.not_for_me > 1000
    assert stats.reasons[C.REPLAYED] > 300 and stats.reboots > 300


def _genuine(*seqs: int) -> list[F.Event]:
    return [("genuine", F.POOL[s], None) for s in seqs]


def _mine(robot: int) -> list[int]:
    """Pool sequence numbers of commands robot `robot` acts on."""
    return [s for s in F.SEQS if F.GENUINE[F.POOL[s]].for_robot(robot)]


def test_the_check_catches_a_gate_without_a_signature_check(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    forged = F.FORGED[1]  # a genuine command under a forger's signature
    events: list[F.Event] = [("forged", forged, C.BAD_SIGNATURE)]
    setup = F.Setup(1, 0)
    assert F.check(setup, events) is None
    monkeypatch.setattr(C.CommandGate, "_signature_ok", lambda self, sig, msg: True)
    problem = F.check(setup, events)
    assert problem is not None and "FORGERY" in problem


def test_the_check_catches_a_gate_that_forgets_its_sequence(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A gate that acts but does not persist the number acts again after a reboot."""
    s = _mine(1)[0]
    events = [*_genuine(s), F.REBOOT, *_genuine(s)]
    setup = F.Setup(1, 0)
    assert F.check(setup, events) is None

    def forgetful(self: C.CommandGate, seq: int) -> None:
        self.last_acted = seq  # in memory only

    monkeypatch.setattr(C.CommandGate, "_persist", forgetful)
    problem = F.check(setup, events)
    assert problem is not None and "the store holds 0" in problem


def test_the_check_catches_a_gate_that_forgets_in_memory(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Without a store too (the simulator's gate): acting twice on one number is caught."""
    s = _mine(2)[0]
    events = _genuine(s, s)
    setup = F.Setup(2, None)
    assert F.check(setup, events) is None
    monkeypatch.setattr(C.CommandGate, "_persist", lambda self, seq: None)
    problem = F.check(setup, events)
    assert problem is not None and "the model says" in problem


def test_the_check_catches_a_gate_that_relays_twice(monkeypatch: pytest.MonkeyPatch) -> None:
    s = [x for x in F.SEQS if not F.GENUINE[F.POOL[x]].for_robot(1)][0]
    events = _genuine(s, s)
    assert F.check(F.Setup(1, None), events) is None
    monkeypatch.setattr(C.CommandGate, "_relay_fresh", lambda self, seq: True)
    problem = F.check(F.Setup(1, None), events)
    assert problem is not None and "the model says" in problem


def test_the_check_catches_an_exception(monkeypatch: pytest.MonkeyPatch) -> None:
    def fragile(self: C.CommandGate, data: bytes) -> C.GateResult:
        return bytes(data)[100:200][50]  # type: ignore[return-value]

    monkeypatch.setattr(C.CommandGate, "receive", fragile)
    problem = F.check(F.Setup(1, None), [("random", bytes(8), None)])
    assert problem is not None and "IndexError" in problem


def test_the_harness_runs_as_a_file_with_a_count(tmp_path: Path) -> None:
    """`python tests/fuzz/operator_command_fuzz.py --count N` (no package, no time limit)."""
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
