"""The process tests/update/test_store_crash.py kills: a run of store calls, each announced.

    python store_crash_child.py STATE_DIR STEPS

opens the store at STATE_DIR (seeding version 0 when it is empty), then for STEPS versions
puts a release, keeps its patch, commits it and, for every third version, rolls it back.
Before each call it prints `step KIND VERSION -> V HASH` (the committed version the call
leaves when it completes: the test accepts that one or the one before it, never anything
else), and `done` after it.

With STORE_CRASH_AT=K in the environment, the process SIGKILLs itself at its K-th durable
write: just before an `os.replace` (the temporary file written and fsynced, not renamed) or
halfway through an `os.write` (a history line torn). It prints `ops N` at the end: how many
such writes a whole run makes.

Every release and patch is self-describing (its sidecars and its checksum name its bytes), so
the test can tell a whole one from a mix without knowing which run wrote it.
"""

from __future__ import annotations

import hashlib
import os
import signal
import sys
from pathlib import Path
from typing import Any

from fieldkit.update.release import Release
from fieldkit.update.store import VersionStore

CRASH_AT = int(os.environ.get("STORE_CRASH_AT", "0"))
_ops = 0
_real_replace = os.replace
_real_write = os.write


def _crash_now() -> bool:
    global _ops
    _ops += 1
    return _ops == CRASH_AT


def _die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _replace(src: Any, dst: Any, **kw: Any) -> None:
    if _crash_now():
        _die()
    _real_replace(src, dst, **kw)


def _write(fd: int, data: Any) -> int:
    if _crash_now():
        _real_write(fd, bytes(data)[: len(data) // 2])
        _die()
    return _real_write(fd, data)


os.replace = _replace  # type: ignore[assignment]
os.write = _write


def filler(seed: bytes, n: int) -> bytes:
    """`n` deterministic bytes drawn from `seed`."""
    out = b""
    block = seed
    while len(out) < n:
        block = hashlib.sha256(block).digest()
        out += block
    return out[:n]


def release_for(v: int) -> Release:
    """Version v's release: its sidecars name its bytecode's hash; every 4th has no .bpos."""
    bo = f"bo {v}\n".encode() + filler(b"bo%d" % v, 2000 + v * 397 % 6000)
    h = hashlib.sha256(bo).hexdigest().encode()
    bdb = b"bdb " + h + filler(b"bdb%d" % v, 1500)
    bpos = b"" if v % 4 == 0 else b"bpos " + h + filler(b"bpos%d" % v, 700)
    return Release(bo, bdb, bpos)


def patch_for(v: int) -> bytes:
    """Version v's patch: a prefix, filler, then the SHA-256 of both."""
    body = f"patch {v}\n".encode() + filler(b"patch%d" % v, 3000)
    return body + hashlib.sha256(body).digest()


def say(line: str) -> None:
    print(line, flush=True)


def main(state: Path, steps: int) -> None:
    say("open")
    store = VersionStore(state)
    cur = store.current
    say("start none" if cur is None else f"start {cur.version} {cur.hash}")
    if cur is None:
        r = release_for(0)
        say("step put 0 -> none")
        store.put(r)
        say("done")
        say(f"step commit 0 -> 0 {r.hash}")
        store.commit(0, r.hash, reason="seeded by the crash test")
        say("done")
    for _ in range(steps):
        cur = store.current
        assert cur is not None
        v = cur.highest + 1
        r = release_for(v)
        keep = f"{cur.version} {cur.hash}"
        say(f"step put {v} -> {keep}")
        store.put(r)
        say("done")
        say(f"step patch {v} -> {keep}")
        store.put_patch(v, patch_for(v))
        say("done")
        say(f"step commit {v} -> {v} {r.hash}")
        store.commit(v, r.hash, reason=f"update to {v}")
        say("done")
        if v % 3 == 0:
            back = store.current.previous[0]  # type: ignore[union-attr]
            say(f"step rollback {v} -> {back[0]} {back[1]}")
            store.rollback(v, reason=f"version {v} failed its grace period")
            say("done")
    say(f"ops {_ops}")
    say("end")


if __name__ == "__main__":
    main(Path(sys.argv[1]), int(sys.argv[2]))
