"""Fuzzing the patch verifier (fieldkit.update.patch) with mutated patches: a seeded campaign.

    python tests/fuzz/fuzz_patch.py --count 1000000 --seed 1
    python -m tests.fuzz.fuzz_patch --seconds 60 --seed 1
    python tests/fuzz/fuzz_patch.py --replay 1:12345      # one input, verbosely

A patch comes over the radio from anyone, so every byte is hostile. Input k of seed S is
made from `random.Random(f"{S}:{k}")`. Seeds are real patches between small scripts with
fixed keys: good updates and a rollback order, and patches the operator signed that are bad
inside (another swarm's key, a lying result hash, a broken delta, a version far ahead) or
that another key signed. Inputs are those, or mutations of them: bit flips, interesting
bytes, truncations, extensions, insertions, deletions, splices of two patches (at any offset
or at a field boundary), header fields set to interesting values or to another patch's
(mix-and-match), random bytes, and patches larger than any script. Each is fed to `read_header`,
`open_update` (against the base and version it was made for, or another) or `open_rollback`.
A few inputs fuzz the decrypted-body stage (`apply_deltas`) with mutated plaintexts.

The property, per input:

* nothing but a PatchError with a known reason escapes (0 crashes);
* nothing forged is accepted: an accepted header is a genuine signed one, a refusal after the
  signature check only happens to a genuine signed header, an accepted update is byte for
  byte a genuine good patch opened against its base and gives exactly its release, and an
  accepted rollback order is the genuine one.

Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import argparse
import collections
import itertools
import random
import struct
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

import bvm
from fieldkit.update import patch as P
from fieldkit.update.keys import RobotKeys
from fieldkit.update.release import Release

try:
    from . import runner
except ImportError:  # run as a file: `python tests/fuzz/fuzz_patch.py`
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from fuzz import runner  # type: ignore[no-redef]

#: Reasons given only once the header's signature has been checked.
AFTER_SIGNATURE = frozenset(
    {"replayed", "fast-forward", "wrong-base", "bad-body", "bad-decrypt", "bad-delta"}
    | {"bad-result", "bad-bytecode"}
)

SOURCES = (
    "function init() { x = 1 }\nfunction step() { x = x + 1 }\n",
    "function init() { x = 2 }\nfunction step() { x = x + 1\n log(x) }\n",
    "function init() { x = 2; y = {} }\nfunction step() { y[x] = x\n x = x + 3 }\n",
)

#: (offset, size) of each header field and of the signature.
FIELDS = {
    "magic": (0, 4),
    "format": (4, 1),
    "kind": (5, 1),
    "version": (6, 4),
    "base": (10, 32),
    "result": (42, 32),
    "body_len": (74, 4),
    "salt": (78, 16),
    "body_hash": (94, 32),
    "signature": (P.HEADER_LEN, P.SIGNATURE_LEN),
}
INTERESTING = {
    1: (0, 1, 2, 3, 0x7F, 0x80, 0xFF),
    4: (0, 1, 2, 15, 16, 28, 29, 999, 1000, 1001, 1002, 0x3FF00, 0x40000, 0x7FFFFFFF, 0xFFFFFFFF),
}
KINDS = (
    ("valid", 2),
    ("flip", 22),
    ("byte", 10),
    ("truncate", 10),
    ("extend", 7),
    ("insert", 7),
    ("delete", 7),
    ("splice", 10),
    ("field", 15),
    ("random", 3),
    ("huge", 1),
    ("delta", 6),
)
KIND_NAMES = tuple(k for k, _ in KINDS)
KIND_CUM = tuple(itertools.accumulate(w for _, w in KINDS))


@dataclass(frozen=True)
class Seed:
    """A patch to mutate, and what a robot opening it holds."""

    name: str
    data: bytes
    base: Release
    current: int
    #: The release a good update gives (None: this patch must never be accepted).
    result: Release | None = None


@dataclass(frozen=True)
class World:
    """Everything precomputed: keys, releases, seeds, the genuine signed prefixes."""

    keys: RobotKeys
    releases: tuple[Release, ...]
    seeds: tuple[Seed, ...]
    plaintexts: tuple[tuple[Release, bytes], ...]
    #: header+signature of every patch the operator signed.
    signed_prefixes: frozenset[bytes]
    #: whole good updates -> (base, current version, result)
    good_updates: dict[bytes, tuple[Release, int, Release]]
    good_rollbacks: frozenset[bytes]


@cache
def world() -> World:
    """Build the seeds once (fixed keys and salts: every run sees the same bytes)."""
    signing = Ed25519PrivateKey.from_private_bytes(b"\x11" * 32)
    forger = Ed25519PrivateKey.from_private_bytes(b"\x22" * 32)
    swarm, other_swarm = b"\x33" * 32, b"\x44" * 32
    keys = RobotKeys(signing.public_key(), swarm)
    r = tuple(Release.from_program(bvm.compile_source(s.encode(), "fuzz.bzz")) for s in SOURCES)

    def seal(
        base: Release,
        new: Release,
        version: int,
        *,
        key: Ed25519PrivateKey = signing,
        swarm_key: bytes = swarm,
        result: str | None = None,
        plaintext: bytes | None = None,
    ) -> bytes:
        text = P.plaintext_of(base, new) if plaintext is None else plaintext
        salt = bytes([version & 0xFF, len(text) & 0xFF]) * 8
        return P._seal(
            P.PatchKind.UPDATE, version, base.hash, result or new.hash, text, key,
            swarm_key, salt=salt,
        )  # fmt: skip

    junk_delta = struct.pack(">I", 8) + b"BSDIFF40" + struct.pack(">II", 0, 0)
    seeds = (
        Seed("update 0->1", seal(r[0], r[1], 1), r[0], 0, r[1]),
        Seed("update 1->2", seal(r[1], r[2], 2), r[1], 1, r[2]),
        Seed("update 0->2 v7", seal(r[0], r[2], 7), r[0], 3, r[2]),
        Seed("fast-forward", seal(r[0], r[1], 5000), r[0], 0),
        Seed("rollback", P.make_rollback(2, r[2].hash, r[1].hash, signing), r[2], 2),
        Seed("forged", seal(r[0], r[1], 1, key=forger), r[0], 0),
        Seed("other swarm", seal(r[0], r[1], 1, swarm_key=other_swarm), r[0], 0),
        Seed("lying result", seal(r[0], r[1], 1, result=r[2].hash), r[0], 0),
        Seed("junk delta", seal(r[0], r[1], 1, plaintext=junk_delta), r[0], 0),
        Seed("forged rollback", P.make_rollback(2, r[2].hash, r[1].hash, forger), r[2], 2),
    )
    signed = frozenset(s.data[: P.PREFIX_LEN] for s in seeds if not s.name.startswith("forged"))
    good = {s.data: (s.base, s.current, s.result) for s in seeds if s.result is not None}
    return World(
        keys=keys,
        releases=r,
        seeds=seeds,
        plaintexts=((r[0], P.plaintext_of(r[0], r[1])), (r[1], P.plaintext_of(r[1], r[2]))),
        signed_prefixes=signed,
        good_updates=good,
        good_rollbacks=frozenset(s.data for s in seeds if s.name == "rollback"),
    )


def mutate(rng: random.Random, data: bytes, others: tuple[Seed, ...]) -> bytes:
    """One to three byte-level changes."""
    b = bytearray(data)
    for _ in range(rng.choice((1, 1, 1, 2, 3))):
        what = rng.randrange(6)
        if what == 0 and b:
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        elif what == 1 and b:
            b[rng.randrange(len(b))] = rng.choice(INTERESTING[1])
        elif what == 2:
            del b[rng.randrange(len(b) + 1) :]
        elif what == 3:
            at = rng.randrange(len(b) + 1)
            b[at:at] = rng.randbytes(rng.randint(1, 16))
        elif what == 4 and b:
            at = rng.randrange(len(b))
            del b[at : at + rng.randint(1, 16)]
        else:
            b = bytearray(edit_field(rng, bytes(b), others))
    return bytes(b)


def edit_field(rng: random.Random, data: bytes, others: tuple[Seed, ...]) -> bytes:
    """A header field (or the signature) set to an interesting value or another patch's."""
    name = rng.choice(tuple(FIELDS))
    at, size = FIELDS[name]
    if len(data) < at + size:
        return data
    donor = rng.choice(others).data
    if rng.random() < 0.4 and len(donor) >= at + size:
        value = donor[at : at + size]  # mix-and-match
    elif size in INTERESTING:
        value = rng.choice(INTERESTING[size]).to_bytes(size, "big")
    elif name == "body_len":
        value = struct.pack(">I", max(0, len(data) - P.PREFIX_LEN + rng.randint(-2, 2)))
    else:
        value = rng.randbytes(size)
    return data[:at] + value + data[at + size :]


def splice(rng: random.Random, a: bytes, b: bytes) -> bytes:
    """A prefix of one patch and a suffix of another, at a field boundary or anywhere."""
    if rng.random() < 0.5:
        cut = rng.choice((P.HEADER_LEN, P.PREFIX_LEN, *(at for at, _ in FIELDS.values())))
        return a[:cut] + b[cut:]
    return a[: rng.randrange(len(a) + 1)] + b[rng.randrange(len(b) + 1) :]


def make_input(seed: str, k: int) -> tuple[str, str, Seed, bytes, Release, int]:
    """Input k of `seed`: (kind, target, seed patch, bytes, base, current version)."""
    rng = random.Random(f"{seed}:{k}")
    w = world()
    kind = KIND_NAMES[_pick(rng.random() * KIND_CUM[-1])]
    s = rng.choice(w.seeds)
    data = s.data
    if kind == "flip":
        b = bytearray(data)
        for _ in range(rng.choice((1, 1, 2, 4))):
            b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        data = bytes(b)
    elif kind == "byte":
        data = mutate(rng, data, w.seeds)
    elif kind == "truncate":
        data = data[: rng.randrange(len(data))]
    elif kind == "extend":
        data = data + rng.randbytes(rng.choice((1, 1, 2, 16, 300)))
    elif kind == "insert":
        at = rng.randrange(len(data) + 1)
        data = data[:at] + rng.randbytes(rng.randint(1, 32)) + data[at:]
    elif kind == "delete":
        at = rng.randrange(len(data))
        data = data[:at] + data[at + rng.randint(1, 32) :]
    elif kind == "splice":
        data = splice(rng, data, rng.choice(w.seeds).data)
    elif kind == "field":
        data = edit_field(rng, data, w.seeds)
        if rng.random() < 0.3:
            data = edit_field(rng, data, w.seeds)
    elif kind == "random":
        head = P.MAGIC + b"\x01" if rng.random() < 0.5 else b""
        data = head + rng.randbytes(rng.randint(0, 400))
    elif kind == "huge":
        data = data + bytes(P.MAX_PATCH_BYTES - len(data) + rng.randint(1, 4096))
    elif kind == "delta":
        base, text = rng.choice(w.plaintexts)
        return kind, "apply_deltas", s, mutate(rng, text, w.seeds), base, 0
    base, current = s.base, s.current
    roll = rng.random()
    if roll < 0.1:
        base = rng.choice(w.releases)
    elif roll < 0.2:
        current = rng.choice((0, 1, 2, 5, 7, 1000, 0xFFFFFFFF))
    roll = rng.random()
    target = "open_update" if roll < 0.7 else "open_rollback" if roll < 0.85 else "read_header"
    return kind, target, s, data, base, current


def _pick(x: float) -> int:
    """The kind whose cumulative weight first exceeds x."""
    for i, c in enumerate(KIND_CUM):
        if x < c:
            return i
    return len(KIND_CUM) - 1


def check(target: str, data: bytes, base: Release, current: int) -> tuple[str, str | None]:
    """(outcome: `accepted` or the reason code, the problem found or None)."""
    w = world()
    try:
        if target == "read_header":
            header = P.read_header(data, w.keys.operator_pub)
            if data[: P.PREFIX_LEN] not in w.signed_prefixes:
                return "accepted", "read_header accepted a header nobody signed"
            if header.raw + header.signature != data[: P.PREFIX_LEN]:
                return "accepted", "the header does not hold the bytes it was read from"
        elif target == "open_update":
            header, release = P.open_update(data, base=base, keys=w.keys, current_version=current)
            good = w.good_updates.get(data)
            if good is None:
                return "accepted", "open_update accepted bytes that are no good patch"
            good_base, _, good_result = good
            if base != good_base or release != good_result:
                return "accepted", "open_update gave another release than the genuine one"
            if not current < header.version <= current + P.MAX_VERSION_STEP:
                return "accepted", f"version {header.version} accepted at current {current}"
        elif target == "open_rollback":
            P.open_rollback(data, w.keys)
            if data not in w.good_rollbacks:
                return "accepted", "open_rollback accepted an order nobody signed"
        else:
            P.apply_deltas(base, data)  # after decryption: no forgery to check, only crashes
        return "accepted", None
    except P.PatchError as e:
        reason = e.reason
        if reason not in P.REASONS:
            return reason, f"unknown reason {reason!r}"
        if reason in AFTER_SIGNATURE and target != "apply_deltas":
            if data[: P.PREFIX_LEN] not in w.signed_prefixes:
                return reason, f"{reason} past the signature of a header nobody signed"
        if not str(e):
            return reason, "a PatchError without a message"
        return reason, None
    except Exception:  # noqa: BLE001 - the property: nothing else escapes
        return "crash", f"{target} raised: " + traceback.format_exc(limit=-3)


@dataclass
class Stats(runner.Stats):
    """What a campaign did."""

    accepted: int = 0
    reasons: collections.Counter[str] = field(default_factory=collections.Counter)
    targets: collections.Counter[str] = field(default_factory=collections.Counter)

    def details(self) -> list[str]:
        """The kinds and targets of input run, the outcomes, and how many were accepted."""
        return [
            *super().details(),
            f"targets: {dict(sorted(self.targets.items()))}",
            f"outcomes: {dict(sorted(self.reasons.items()))}",
            f"accepted: {self.accepted}",
        ]


def run_one(seed: str, k: int, stats: Stats, out: Callable[[str], None]) -> None:
    """Make input k, check it, and record the outcome."""
    try:
        kind, target, s, data, base, current = make_input(seed, k)
        outcome, problem = check(target, data, base, current)
    except Exception:  # noqa: BLE001 - a harness error is reported, not fatal
        kind, target, data = "?", "?", b""
        outcome, problem = "harness", "harness error: " + traceback.format_exc(limit=-3)
    stats.kinds[kind] += 1
    stats.targets[target] += 1
    stats.reasons[outcome] += 1
    stats.accepted += outcome == "accepted"
    if problem is not None:
        text = f"FAILURE [replay {seed}:{k}] ({kind} -> {target}) {problem}\n  {data[:96].hex()}"
        stats.fail(f"{seed}:{k}", text, out, shown=20)


#: run(seed, *, seconds=None, max_inputs=None, start=0, out=print) -> Stats: a campaign.
run = runner.make_run(run_one, Stats, clock_every=64, progress=True)


def replay(spec: str) -> int:
    """Run one input verbosely; 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    kind, target, s, data, base, current = make_input(seed, int(k))
    print(f"input {spec}: {kind} of {s.name!r} -> {target}, {len(data)} bytes")
    print(f"base {base.hash[:12]}, current version {current}")
    print(data[:512].hex())
    outcome, problem = check(target, data, base, current)
    print("outcome:", outcome)
    print("verdict:", problem or "ok")
    return 1 if problem else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point: `--count N` inputs, or `--seconds S` (60 by default)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--count", "--max-inputs", dest="count", type=int, help="inputs to run")
    ap.add_argument("--seconds", type=float, help="time budget (default 60 without --count)")
    ap.add_argument("--seed", default="0")
    ap.add_argument("--start", type=int, default=0, help="first input index")
    ap.add_argument("--replay", help="SEED:K -- run one input verbosely")
    args = ap.parse_args(argv)
    if args.replay:
        return replay(args.replay)
    seconds = args.seconds if args.seconds is not None else (None if args.count else 60.0)
    world()
    t0 = time.monotonic()
    # A finite time budget makes the campaign print progress lines; a count alone runs on.
    stats = run(args.seed, seconds=seconds or 1e12, max_inputs=args.count, start=args.start)
    spent = time.monotonic() - t0
    print(f"seed {args.seed}, {spent:.0f} s, {stats.inputs / max(spent, 1e-9):.0f} inputs/s")
    for line in stats.details():
        print(line)
    return runner.summary(stats)


if __name__ == "__main__":
    sys.exit(main())
