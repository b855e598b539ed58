"""kill -9 at any instant leaves the version store able to start a whole, verified version.

A real child process (tests/update/store_crash_child.py) puts, commits and rolls back
versions and announces each store call before making it; the test SIGKILLs it, opens the
store and checks that the committed version is the one before the call in progress or the
one after it, whole (never a mix of two versions' files), and that the history parses.

Two ways to pick the instant: by the child's output (the test kills it after N lines: where
exactly it is then is up to the scheduler), and by the child's own hand at its K-th durable
write (just before a rename, or halfway through a history line): every such write of a run.
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

from rigs import kill_and_drain

from fieldkit.update.store import VersionStore

CHILD = Path(__file__).with_name("store_crash_child.py")

#: A child that neither ends nor dies within this is hung (a hang guard, not a timing).
HANG_S = 120

State = tuple[int, str] | None


def child(state: Path, steps: int, crash_at: int = 0) -> subprocess.Popen[str]:
    env = os.environ | {"STORE_CRASH_AT": str(crash_at)}
    return subprocess.Popen(
        [sys.executable, str(CHILD), str(state), str(steps)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def parse_state(text: str) -> State:
    if text == "none":
        return None
    v, h = text.split()
    return int(v), h


def old_and_new(lines: list[str], before: State) -> tuple[State, State]:
    """The committed version before the store call the child died in, and after it."""
    old: State = before
    new: State = before
    for line in lines:
        if line.startswith("start "):
            old = new = parse_state(line.removeprefix("start "))
        elif line.startswith("step "):
            new = parse_state(line.split(" -> ")[1])
        elif line == "done":
            old = new
    return old, new


def check(state: Path, lines: list[str], before: State) -> tuple[State, VersionStore]:
    """Open the store as a rebooted node would and check what it would run."""
    old, new = old_and_new(lines, before)
    store = VersionStore(state)
    c = store.committed()
    got = None if c is None else (c.version, c.hash)
    assert got in (old, new), (got, old, new, lines[-3:])
    if c is not None:
        r = store.get(c.hash)  # re-hashed
        # Whole: the sidecars are this bytecode's own, and only every 4th has no .bpos.
        v = int(r.bo.split(b"\n", 1)[0].removeprefix(b"bo "))
        assert r.bdb.startswith(b"bdb " + c.hash.encode())
        if v % 4 == 0:
            assert r.bpos == b""
        else:
            assert r.bpos.startswith(b"bpos " + c.hash.encode())
        assert json.loads((state / "committed.json").read_text())["hash"] == c.hash
    # The history parses, every line (a torn last one was cut at open).
    data = (state / "history.jsonl").read_bytes() if c is not None else b""
    assert data == b"" or data.endswith(b"\n")
    for line in data.splitlines():
        assert isinstance(json.loads(line), dict)
    if c is not None:
        last = [e for e in store.history() if e["event"] != "refused"][-1]
        assert (last["version"], last["hash"]) == (c.version, c.hash)
    # A kept patch is whole.
    for v in store.patches():
        p = store.patch(v)
        assert p.startswith(f"patch {v}\n".encode())
        assert hashlib.sha256(p[:-32]).digest() == p[-32:]
    # Nothing half-written is left beside the real files.
    assert not [p for p in state.rglob("*.tmp")]
    return got, store


def test_killed_after_n_lines_the_store_starts_a_whole_version(tmp_path: Path) -> None:
    state = tmp_path / "state"
    before: State = None
    highest = -1
    instants = set()
    for run in range(34):
        n = 1 + (run * 5) % 17  # 1..17 lines in: open, put, patch, commit, rollback
        proc = child(state, 3)
        assert proc.stdout is not None
        lines: list[str] = []
        while len(lines) < n:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line.rstrip("\n"))
        rest, err = kill_and_drain(proc, HANG_S)
        lines += rest.splitlines()
        assert "Traceback" not in err, err
        if lines[-1] != "end":
            assert proc.returncode == -signal.SIGKILL
            instants.add(lines[-1] if lines[-1] == "done" else lines[-1].split(" -> ")[0])
        before, store = check(state, lines, before)
        c = store.committed()
        if c is not None:  # (None only before the first seed was committed)
            assert c.highest >= highest  # the replay floor never comes down
            highest = c.highest
    assert highest >= 8  # the runs got somewhere, through several commits and rollbacks
    assert len(instants) >= 5, instants  # killed in several kinds of call


def test_killed_at_every_durable_write_the_store_starts_the_old_or_the_new(
    tmp_path: Path,
) -> None:
    whole = child(tmp_path / "dry", 4)
    out, err = whole.communicate(timeout=HANG_S)
    assert whole.returncode == 0, err
    ops = int(out.splitlines()[-2].removeprefix("ops "))
    assert ops >= 25
    for k in range(1, ops + 1):
        state = tmp_path / f"k{k}"
        proc = child(state, 4, crash_at=k)
        out, err = proc.communicate(timeout=HANG_S)
        assert proc.returncode == -signal.SIGKILL, (k, err)
        got, store = check(state, out.splitlines(), None)
        # And the store goes on from there: the next version commits.
        c = store.committed()
        if c is not None:
            nxt = c.highest + 1
            store.put_patch(nxt, b"")
            assert store.commit(nxt, c.hash, reason="after the crash").version == nxt
            assert VersionStore(state).committed() == store.current
