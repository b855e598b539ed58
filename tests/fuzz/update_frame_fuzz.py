"""Fuzzing the update frame decoder and a live update agent with hostile frames, seeded.

    python tests/fuzz/update_frame_fuzz.py --count 1000000 --seed 1
    python -m tests.fuzz.update_frame_fuzz --seconds 60 --seed 1
    python -m tests.fuzz.update_frame_fuzz --replay 1:12345      # one input, verbosely

Input k of seed S is made from `random.Random(f"{S}:{k}")`, so every input replays with
`--replay S:k`. Two targets (docs/update.md#on-air-format):

* ``decode``: `fieldkit.update.packets.decode` on a valid frame (records of every kind,
  edge-biased fields, up to MAX_FRAME_BYTES), random bytes, or a mutation of a valid frame:
  bit flips, interesting bytes, truncation, extension, a record's length or kind edited,
  the record count edited, ENTRIES' own count edited, word 0's type, format or reserved
  bytes edited, an interesting u16/u32 over a field, records cut out or repeated, splices of
  two frames; most structural mutations are padded again to whole words so that they reach
  the record parser. Property: the decoder returns a Frame or raises `FrameError` whose
  offset lies within the input, nothing else; a frame it accepts re-encodes to the very
  same bytes and has frame_type 16; a valid frame decodes to the frame it was made from.
* ``agent``: a live `UpdateAgent` (robot 2, running version 1, version 0 before it) in the
  middle of pulling a patch to version 2 from robot 1, with neighbours in its barrier table,
  gets 1 to 12 events: hostile frames (mutations as above of the frames of this transfer:
  its OFFER, its CHUNKs, WANTs, STATUS, ENTRIES and VERDICT of the versions at play; a
  forger's whole consistent patch that the verifier must refuse; random bytes), the real
  frames of the transfer (so that some runs complete, verify, stand by and switch), and
  ticks (the agent decides and sends). The patch check is a stand-in verifier (magic,
  version rule, base hash, result hash) that records what it accepted. Property: no
  exception escapes `receive`, `tick` or `frame`; `bad_frames` counts exactly the frames the
  decoder refuses; `receive` never changes the version; a tick changes it only by a
  `Switch` to a release the verifier accepted or a `Rollback` to one the robot ran before
  (0 accepted forgeries); at most one patch is being pulled, within its announced size and
  MAX_PATCH_BYTES; every frame the agent sends decodes, comes from robot 2 and keeps
  within the byte budget.

Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import hashlib
import random
import struct
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from fieldkit.update import packets as pk
from fieldkit.update.agent import (
    MAX_PATCH_BYTES,
    AgentConfig,
    Rollback,
    Switch,
    UpdateAgent,
    digest_of,
    short,
)
from fieldkit.update.packets import Phase, Reason
from fieldkit.update.release import Release

if __package__:
    from . import runner
else:  # run as a file: python tests/fuzz/update_frame_fuzz.py
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from fuzz import runner

TARGETS = ("decode", "agent")
INTERESTING_BYTES = (0, 1, 2, 5, 6, 7, 8, 16, 23, 24, 0x7F, 0x80, 0xFE, 0xFF)
INTERESTING_U16 = (0, 1, 2, 0x7FFF, 0x8000, 0xFFFE, 0xFFFF)
INTERESTING_U32 = (0, 1, 2, 3, 1000, 1001, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF)
#: Slice of a counted campaign between two progress lines.
SLICE = 20_000


@dataclass
class Stats(runner.Stats):
    """What a campaign did."""

    accepted: int = 0  # decode inputs the decoder accepted
    switches: int = 0  # agent runs that switched to a verified version
    rollbacks: int = 0
    refused_patches: int = 0  # whole patches the verifier refused (forgeries among them)

    def details(self) -> list[str]:
        """The kinds of input run, and what the decoder and the agents did with them."""
        return [
            *super().details(),
            f"decoded: {self.accepted}, agent switches: {self.switches}, "
            f"rollbacks: {self.rollbacks}, patches refused: {self.refused_patches}",
        ]


# ---------------------------------------------------------------- valid frames


def _u16(rng: random.Random) -> int:
    return rng.choice((*INTERESTING_U16, rng.randrange(1 << 16)))


def _u32(rng: random.Random) -> int:
    return rng.choice((*INTERESTING_U32, rng.randrange(1 << 32), rng.randrange(10)))


def _short(rng: random.Random, known: tuple[bytes, ...] = ()) -> bytes:
    return rng.choice((bytes(8), b"\xff" * 8, rng.randbytes(8), *known))


def random_record(rng: random.Random, known: tuple[bytes, ...] = ()) -> pk.Record:
    """A valid record of any kind, fields biased to edges (and to `known` hashes)."""
    kind = rng.randrange(6)
    if kind == 0:
        return pk.Status(
            _u32(rng),
            _short(rng, known),
            rng.choice(list(Phase)),
            _u32(rng),
            _u32(rng),
            _u16(rng),
        )
    if kind == 1:
        return pk.Offer(_short(rng, known), _u32(rng), _u32(rng), _short(rng, known))
    if kind == 2:
        bitmap = rng.choice((0, 1, (1 << 64) - 1, rng.getrandbits(64)))
        return pk.Want(_short(rng, known), _u16(rng), bitmap)
    if kind == 3:
        n = rng.choice((1, pk.CHUNK_BYTES, rng.randint(1, pk.CHUNK_BYTES)))
        return pk.Chunk(_short(rng, known), _u16(rng), rng.randbytes(n))
    if kind == 4:
        entries = tuple(
            pk.Entry(_u16(rng), _u16(rng), rng.choice(list(Phase)), _u32(rng))
            for _ in range(rng.choice((0, 1, 2, 12, 24, rng.randint(0, 24))))
        )
        return pk.Entries(entries)
    return pk.Verdict(_u32(rng), rng.choice(list(Reason)))


def record_size(r: pk.Record) -> int:
    """Bytes `r` takes in a frame (what packets.image_size adds up, without encoding)."""
    if isinstance(r, pk.Chunk):
        return pk.chunk_bytes(len(r.data))
    if isinstance(r, pk.Entries):
        return pk.entries_bytes(len(r.entries))
    return {pk.Status: pk.STATUS_BYTES, pk.Offer: pk.OFFER_BYTES, pk.Want: pk.WANT_BYTES}.get(
        type(r), pk.VERDICT_BYTES
    )


def random_frame(rng: random.Random, known: tuple[bytes, ...] = ()) -> pk.Frame:
    """A valid frame: 0 to 12 records that fit MAX_FRAME_BYTES."""
    records: list[pk.Record] = []
    room = pk.MAX_FRAME_BYTES - 8
    for _ in range(rng.choice((0, 1, 1, 2, 3, 5, 12))):
        r = random_record(rng, known)
        size = record_size(r)
        if size <= room:
            records.append(r)
            room -= size
    return pk.Frame(_u16(rng), tuple(records))


# ---------------------------------------------------------------- mutations


def swap(data: bytes) -> bytes:
    """Memory image <-> air bytes (every 8-byte group reversed, a partial one too)."""
    return b"".join(data[i : i + 8][::-1] for i in range(0, len(data), 8))


def record_heads(image: bytes) -> list[int]:
    """Offsets of the record heads of a valid frame's memory image."""
    heads, pos = [], 8
    for _ in range(image[3]):
        heads.append(pos)
        pos += 2 + image[pos + 1]
    return heads


def _pad(rng: random.Random, buf: bytearray) -> bytearray:
    """Mostly, zeros to whole words again, so that the mutant reaches the record parser."""
    if rng.random() < 0.75:
        buf += bytes(-len(buf) % 8)
    return buf


def mutate(rng: random.Random, data: bytes, other: Callable[[], bytes]) -> tuple[str, bytes]:
    """(kind, a mutant of the valid air frame `data`); `other()` gives another valid frame."""
    image = bytearray(swap(data))
    heads = record_heads(bytes(image))
    r = rng.random()
    if r < 0.12:
        buf = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
        return "flip", bytes(buf)
    if r < 0.2:
        for _ in range(rng.randint(1, 3)):
            image[rng.randrange(len(image))] = rng.choice(INTERESTING_BYTES)
        return "byte", swap(bytes(image))
    if r < 0.28:
        cut = rng.choice((rng.randrange(len(data) + 1), len(data) - 8, len(data) - 1, 8, 7))
        return "truncate", data[: max(cut, 0)]
    if r < 0.34:
        extra = rng.choice(
            (bytes(8), bytes(rng.randint(1, 7)), rng.randbytes(8 * rng.randint(1, 4)))
        )
        return "extend", data + extra
    if r < 0.46 and heads:
        h = rng.choice(heads)
        size = image[h + 1]
        image[h + 1] = rng.choice((0, 1, size - 1, size + 1, 255, rng.randrange(256))) & 0xFF
        return "record-length", swap(bytes(_pad(rng, image)))
    if r < 0.52 and heads:
        image[rng.choice(heads)] = rng.choice((0, 7, 255, rng.randint(1, 6)))
        return "record-kind", swap(bytes(image))
    if r < 0.6:
        n = image[3]
        image[3] = rng.choice((n - 1, n + 1, 0, 255, rng.randrange(256))) & 0xFF
        return "count", swap(bytes(_pad(rng, image)))
    if r < 0.64:
        i = rng.choice((0, 1, 2, 6, 7))
        image[i] = rng.choice((0, 1, 2, 16, 0xFF))
        return "header", swap(bytes(image))
    if r < 0.72 and heads:
        # An edge value over a field of some record: a version, a length, an index, a phase.
        h = rng.choice(heads)
        end = min(h + 2 + image[h + 1], len(image))
        width = rng.choice((1, 2, 4))
        if end - (h + 2) >= width:
            at = rng.randrange(h + 2, end - width + 1)
            value = rng.choice(
                {1: INTERESTING_BYTES, 2: INTERESTING_U16, 4: INTERESTING_U32}[width]
            )
            image[at : at + width] = value.to_bytes(width, "little")
        return "field", swap(bytes(image))
    if r < 0.76:
        ent = [h for h in heads if image[h] == pk.Entries.KIND]
        if ent:
            h = rng.choice(ent)
            n = image[h + 2]
            image[h + 2] = rng.choice((n - 1, n + 1, 0, 255, 28, 29)) & 0xFF
        return "entries-count", swap(bytes(image))
    if r < 0.84 and heads:
        # Whole records cut out or repeated, the count left as it was (or not).
        h = rng.choice(heads)
        rec = bytes(image[h : h + 2 + image[h + 1]])
        if rng.random() < 0.5:
            del image[h : h + len(rec)]
        else:
            image[h:h] = rec * rng.randint(1, 3)
        if rng.random() < 0.5:
            image[3] = len(record_heads_loose(bytes(image))) & 0xFF
        return "records", swap(bytes(_pad(rng, image)))
    if r < 0.92:
        theirs = swap(other())
        i, j = rng.randrange(8, len(image) + 1), rng.randrange(8, max(len(theirs), 8) + 1)
        spliced = bytearray(image[:i] + theirs[j:])
        return "splice", swap(bytes(_pad(rng, spliced)))
    # A valid word 0 and random records: the decoder's own walk, from byte 8 on.
    n = rng.choice((1, 2, 4, 28))
    head = struct.pack("<HBBHH", pk.UPDATE_FRAME, pk.FORMAT, rng.randrange(8), 1, 0)
    return "random-body", swap(head + rng.randbytes(8 * n))


def record_heads_loose(image: bytes) -> list[int]:
    """Record heads of an image whose count may be wrong: walk while records fit."""
    heads, pos = [], 8
    while pos + 2 <= len(image) and image[pos]:
        heads.append(pos)
        pos += 2 + image[pos + 1]
    return heads


def decode_input(
    rng: random.Random, known: tuple[bytes, ...] = ()
) -> tuple[str, bytes, pk.Frame | None]:
    """(kind, air bytes, the frame they are if valid)."""
    frame = random_frame(rng, known)
    data = pk.encode(frame)
    r = rng.random()
    if r < 0.1:
        return "valid", data, frame
    if r < 0.15:
        n = rng.choice((0, 7, 8, 16, 232, 240, rng.randrange(300)))
        return "random", rng.randbytes(n), None
    kind, mutant = mutate(rng, data, lambda: pk.encode(random_frame(rng, known)))
    return kind, mutant, None


# ---------------------------------------------------------------- decode


def check_decode(data: bytes, original: pk.Frame | None) -> tuple[bool, str | None]:
    """(accepted, failure description or None) of one input."""
    try:
        frame = pk.decode(data)
    except pk.FrameError as e:
        if not (isinstance(e.offset, int) and 0 <= e.offset <= len(data)):
            return False, f"offset {e.offset} outside the {len(data)}-byte input: {e}"
        if original is not None:
            return False, f"valid frame refused: {e}"
        return False, None
    except Exception:
        return False, "unexpected exception:\n" + traceback.format_exc()
    try:
        again = pk.encode(frame)
    except Exception:
        return True, "accepted frame does not re-encode:\n" + traceback.format_exc()
    if again != bytes(data):
        return True, f"accepted frame re-encodes differently: {again.hex()} for {data.hex()}"
    if pk.frame_type(data) != pk.UPDATE_FRAME:
        return True, f"accepted frame of frame_type {pk.frame_type(data)}"
    if original is not None and frame != original:
        return True, f"valid frame decodes to {frame}, not {original}"
    return True, None


# ---------------------------------------------------------------- a live agent


def stand_in_patch(base: Release, new: Release, version: int) -> bytes:
    """b"TEST" | u32 version | base sha256 | result sha256 | the new bytecode."""
    return (
        b"TEST"
        + struct.pack("<I", version)
        + bytes.fromhex(base.hash)
        + bytes.fromhex(new.hash)
        + new.bo
    )


class PatchRefused(ValueError):
    """A stand-in patch that does not check out."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


class Verifier:
    """The checks a real verifier makes of the fields, recording every release it passed."""

    def __init__(self) -> None:
        self.passed: list[tuple[int, Release]] = []

    def __call__(self, data: bytes, base: Release, current: int) -> tuple[int, Release]:
        if len(data) < 72 or data[:4] != b"TEST":
            raise PatchRefused("bad-magic")
        (version,) = struct.unpack_from("<I", data, 4)
        if version <= current:
            raise PatchRefused("replayed")
        if version > current + 1000:
            raise PatchRefused("fast-forward")
        if data[8:40] != hashlib.sha256(base.bo).digest():
            raise PatchRefused("wrong-base")
        new = Release(data[72:])
        if data[40:72] != bytes.fromhex(new.hash):
            raise PatchRefused("bad-result")
        self.passed.append((version, new))
        return version, new


R0 = Release(b"version zero: the one before")
R1 = Release(b"version one: what robot 2 runs" * 3)
R2 = Release(b"version two, the update, several chunks long " * 9)
PATCH = stand_in_patch(R1, R2, 2)
DIGEST = digest_of(PATCH)
CHUNKS = [PATCH[i : i + pk.CHUNK_BYTES] for i in range(0, len(PATCH), pk.CHUNK_BYTES)]
#: What a forger can make without the operator's key: consistent offers and chunks whose
#: patch fails the verifier (another base, an old version, a bad magic, a wrong result).
FORGED = (
    stand_in_patch(R0, R2, 2),
    stand_in_patch(R1, R2, 1),
    b"EVIL" + PATCH[4:],
    PATCH[:40] + bytes(32) + PATCH[72:],
    stand_in_patch(R1, R2, 5000),
)
VICTIM = 2
CONFIG = AgentConfig(budget_bytes=160, barrier_timeout_ticks=40, grace_ticks=10, live_ticks=60)


def _offer(patch: bytes, version: int, base: Release) -> pk.Offer:
    return pk.Offer(digest_of(patch), version, len(patch), short(base.hash))


def _chunk_frames(patch: bytes, sender: int) -> list[bytes]:
    digest = digest_of(patch)
    out = []
    for i in range(0, len(patch), pk.CHUNK_BYTES):
        chunk = pk.Chunk(digest, i // pk.CHUNK_BYTES, patch[i : i + pk.CHUNK_BYTES])
        out.append(pk.encode(pk.Frame(sender, (chunk,))))
    return out


#: The real transfer's CHUNK frames from robot 1, and each forger's whole patch (robot 3).
REAL_CHUNKS = _chunk_frames(PATCH, 1)
FORGED_CHUNKS = [_chunk_frames(f, 3) for f in FORGED]


def valid_frames(rng: random.Random) -> list[bytes]:
    """Frames of the transfer at play, as robot 1 and the neighbours would send them."""
    run1, run2 = short(R1.hash), short(R2.hash)
    version = rng.choice((1, 2, 3))
    records: list[pk.Record] = [
        pk.Status(2, run2, rng.choice(list(Phase)), rng.choice((0, 2)), 0, rng.randrange(50)),
        _offer(PATCH, 2, R1),
        pk.Want(DIGEST, 0, (1 << len(CHUNKS)) - 1),
        pk.Entries(
            tuple(
                pk.Entry(r, rng.randrange(50), rng.choice(list(Phase)), rng.choice((1, 2)))
                for r in (1, 3, 4, 5, VICTIM)
            )
        ),
        pk.Status(1, run1, Phase.RUNNING, 0, 0, rng.randrange(50)),
        pk.Verdict(version, rng.choice(list(Reason))),
        pk.Status(1, run1, Phase.RUNNING, 0, version, rng.randrange(50)),
    ]
    frames = [pk.encode(pk.Frame(rng.choice((1, 3, 4)), (r,))) for r in records]
    return frames + REAL_CHUNKS


def agent_input(rng: random.Random) -> tuple[str, dict[str, object]]:
    """(kind, a scenario for check_agent): the events a victim mid-transfer gets."""
    events: list[tuple[str, bytes] | int] = []
    pool = valid_frames(rng)
    kinds = set()
    known = (DIGEST, short(R0.hash), short(R1.hash), short(R2.hash))
    for _ in range(rng.randint(1, 12)):
        r = rng.random()
        if r < 0.25:
            events.append(rng.randint(1, 8))  # ticks
        elif r < 0.5:
            events.append(("valid", rng.choice(pool)))
        elif r < 0.85:
            base = rng.choice((*pool, pk.encode(random_frame(rng, known))))
            kind, mutant = mutate(rng, base, lambda: rng.choice(pool))
            events.append((kind, mutant))
            kinds.add("mutant")
        elif r < 0.95:
            i = rng.randrange(len(FORGED))
            offer = pk.encode(pk.Frame(3, (_offer(FORGED[i], rng.choice((2, 3)), R1),)))
            events += [("forged", offer), *(("forged", c) for c in FORGED_CHUNKS[i])]
            kinds.add("forged")
        else:
            events.append(("random", rng.randbytes(rng.choice((8, 16, 56, 232)))))
            kinds.add("random")
    if rng.random() < 0.3:  # the rest of the real transfer: some runs verify and switch
        events += [("valid", c) for c in REAL_CHUNKS]
        if rng.random() < 0.5:  # a neighbour already runs it: the robot catches up
            status = pk.Status(2, short(R2.hash), Phase.RUNNING, 0, 0, 60 + rng.randrange(9))
            events += [2, ("valid", pk.encode(pk.Frame(3, (status,))))]
        events += [rng.randint(5, 50)]
        kinds.add("complete")
    held = rng.sample(range(len(CHUNKS)), rng.randrange(len(CHUNKS)))
    scenario: dict[str, object] = {"held": held, "events": events, "seed": rng.randrange(1 << 16)}
    kind = next((k for k in ("complete", "forged", "mutant", "random") if k in kinds), "valid")
    return kind, scenario


def new_victim(held: list[int], seed: int, verify: Verifier) -> UpdateAgent:
    """Robot 2 mid-transfer: offered version 2 by robot 1, holding chunks `held` of it."""
    a = UpdateAgent(VICTIM, 1, R1, verify, previous=[(0, R0)], config=CONFIG, seed=seed)
    a.tick(0)
    run1 = short(R1.hash)
    peers = tuple(pk.Entry(r, 1, Phase.RUNNING, 1) for r in (3, 4, 5))
    a.receive(
        pk.encode(pk.Frame(1, (pk.Status(1, run1, Phase.RUNNING, 0, 0, 1), pk.Entries(peers))))
    )
    a.receive(pk.encode(pk.Frame(1, (_offer(PATCH, 2, R1),))))
    assert DIGEST in a.transfers, "the victim does not pull the patch"
    for i in held:
        a.receive(REAL_CHUNKS[i])
    return a


def check_agent(scenario: dict[str, object], stats: Stats | None = None) -> str | None:
    """Failure description, or None."""
    verify = Verifier()
    held, events, seed = scenario["held"], scenario["events"], scenario["seed"]
    assert isinstance(held, list) and isinstance(events, list) and isinstance(seed, int)
    a = new_victim(held, seed, verify)
    ran = {R0.hash, R1.hash}  # releases the robot has run: a rollback may go back to them
    now = 1
    for ev in events:
        before = (a.version, a.release)
        if isinstance(ev, int):
            for _ in range(ev):
                try:
                    action = a.tick(now)
                    frame = a.frame()
                except Exception:
                    return f"tick {now} raised:\n" + traceback.format_exc()
                now += 1
                problem = _check_tick(a, action, frame, before, verify, ran)
                if stats is not None:
                    stats.switches += isinstance(action, Switch)
                    stats.rollbacks += isinstance(action, Rollback)
                if problem:
                    return f"tick {now - 1}: {problem}"
                before = (a.version, a.release)
                a.events.clear()
            continue
        kind, data = ev
        bad = a.counters["bad_frames"]
        try:
            a.receive(data)
        except Exception:
            return f"receive({kind} {data.hex()}) raised:\n" + traceback.format_exc()
        try:
            pk.decode(data)
            refused = False
        except pk.FrameError:
            refused = True
        if a.counters["bad_frames"] - bad != refused:
            return f"bad_frames counted {a.counters['bad_frames'] - bad} for {data.hex()}"
        if (a.version, a.release) != before:
            return f"receive({kind}) changed the version: {before[0]} -> {a.version}"
        problem = _check_state(a, verify)
        if problem:
            return f"after {kind} {data.hex()}: {problem}"
        a.events.clear()
    if stats is not None:
        stats.refused_patches += sum(v for k, v in a.counters.items() if k.startswith("refused_"))
    return None


def _check_tick(
    a: UpdateAgent,
    action: object,
    frame: bytes | None,
    before: tuple[int, Release | None],
    verify: Verifier,
    ran: set[str],
) -> str | None:
    if (a.version, a.release) != before:
        if isinstance(action, Switch):
            if (action.version, action.release) not in verify.passed:
                return f"FORGERY ACCEPTED: switched to version {action.version} never verified"
            ran.add(action.release.hash)
        elif isinstance(action, Rollback):
            if action.release.hash not in ran:
                return f"rolled back to version {action.version}, a release it never ran"
        else:
            return f"version {before[0]} -> {a.version} with action {action!r}"
        if (a.version, a.release) != (action.version, action.release):
            return f"the agent runs version {a.version}, its action says {action.version}"
    elif isinstance(action, Switch | Rollback):
        return f"{type(action).__name__} without a change of version"
    if frame is not None:
        if len(frame) > a.config.budget_bytes:
            return f"a frame of {len(frame)} bytes, over the {a.config.budget_bytes}-byte budget"
        try:
            sent = pk.decode(frame)
        except pk.FrameError as e:
            return f"the agent sent a frame it cannot read: {e}"
        if sent.sender != VICTIM:
            return f"a frame from robot {sent.sender}"
    return _check_state(a, verify)


def _check_state(a: UpdateAgent, verify: Verifier) -> str | None:
    if a.staged is not None and a.staged not in verify.passed:
        return f"staged version {a.staged[0]} was never verified"
    pulling = [t for t in a.transfers.values() if not t.complete]
    if len(pulling) > 1:
        return f"{len(pulling)} patches pulled at once"
    for t in pulling:
        if not 0 < t.total <= MAX_PATCH_BYTES:
            return f"pulling a patch of {t.total} bytes"
        if any(not 0 <= i < t.count for i in t.chunks):
            return "a chunk outside the patch held"
        if sum(len(c) for c in t.chunks.values()) > t.total:
            return "more chunk bytes held than the patch has"
    return None


# ---------------------------------------------------------------- the campaign


def run_one(seed: str, k: int, stats: Stats | None = None) -> tuple[str, str | None, bool]:
    """(kind, failure or None, accepted) of input k."""
    rng = random.Random(f"{seed}:{k}")
    target = rng.choices(TARGETS, weights=(3, 1))[0]
    try:
        if target == "decode":
            kind, data, original = decode_input(rng)
            accepted, failure = check_decode(data, original)
            return f"decode/{kind}", failure, accepted
        kind, scenario = agent_input(rng)
        return f"agent/{kind}", check_agent(scenario, stats), False
    except Exception:
        return target, "harness raised:\n" + traceback.format_exc(), False


def record(seed: str, k: int, stats: Stats, out: Callable[[str], None]) -> None:
    """Run input k and record the outcome."""
    kind, failure, accepted = run_one(seed, k, stats)
    stats.kinds[kind] += 1
    stats.accepted += accepted
    if failure is not None:
        stats.fail(f"{seed}:{k}", f"FAIL {seed}:{k} ({kind}): {failure}", out, shown=20)


#: run(seed, *, seconds=None, max_inputs=None, start=0, out=print) -> Stats: a campaign.
run = runner.make_run(record, Stats, clock_every=64)


def replay(spec: str) -> int:
    """Run input SEED:K verbosely; exit status 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    rng = random.Random(f"{seed}:{k}")
    target = rng.choices(TARGETS, weights=(3, 1))[0]
    if target == "decode":
        kind, data, original = decode_input(rng)
        print(f"decode/{kind}, valid {original is not None}: {data.hex(' ')}")
    else:
        kind, scenario = agent_input(rng)
        print(f"agent/{kind}: chunks held {scenario['held']}")
        for ev in scenario["events"]:  # type: ignore[attr-defined]
            print(f"  tick x{ev}" if isinstance(ev, int) else f"  {ev[0]}: {ev[1].hex(' ')}")
    kind, failure, accepted = run_one(seed, int(k))
    print("accepted" if accepted else "", failure or "ok")
    return 1 if failure else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point: --count N runs exactly N inputs (no time limit)."""
    return runner.counted_main(argv, __doc__, run, replay, Stats, slice_inputs=SLICE)


if __name__ == "__main__":
    sys.exit(main())
