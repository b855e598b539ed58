"""Fuzzing the authenticated-bundle Verifier (fieldkit.robot.bundle_auth) with genuine and
hostile sealed bundles, seeded.

    python tests/fuzz/bundle_auth_fuzz.py --count 1000000 --seed 1
    python -m tests.fuzz.bundle_auth_fuzz --seconds 60 --seed 1
    python -m tests.fuzz.bundle_auth_fuzz --replay 1:12345      # one input, verbosely

Input k of seed S is made from `random.Random(f"{S}:{k}")`, so every input replays with
`--replay S:k`. One input is a fresh `Verifier` (sometimes with a cap of 1 or 2 senders, so
that evictions happen, and sometimes with floors restored as after a reboot) fed 1 to 10
events, each one of:

* a genuine sealed bundle from the pool (three senders, counters 1..200 each, sealed once at
  import with the swarm's key), delivered as a swarm's mesh does: mostly in order, with
  duplicates, reorderings within and beyond the 64-counter window and jumps forward;
* a mutation of a genuine one: bit flips, interesting bytes, truncations, extensions, the
  trailer's format, key id, counter or tag edited, the counter rewound or advanced under the
  old tag, the sender id or the bundle's word count edited, splices of two bundles, the
  trailer of another bundle of the same sender, the plain bundle with its trailer cut off;
* another swarm's bundle (another key), a forger's bundle (a random key under this swarm's
  key id), an update frame (plain or sealed), a ROSBuzz OTA packet, random bytes.

The property, per event: `verify` returns bytes or raises `AuthError` with a reason in
REASONS, nothing else; whatever it accepts is a genuine pool bundle not accepted before by
this verifier (0 accepted forgeries, 0 replays), and the returned bytes are its plain bundle;
a genuine bundle is accepted exactly when a model of the rules (a set of counters seen per
sender, the 64-counter window, floors, least-recently-heard eviction that keeps the evicted
sender's highest counter) accepts it, and refused as `replayed` or `too-old` as the model
says; the plain bundle is refused as `missing-trailer`, another swarm's as `unknown-key`, a
forger's as `bad-tag`, a frame of another type as `bad-format`; the counters add up.

Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import random
import sys
import traceback
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from fieldkit.robot import bundle as B
from fieldkit.robot import bundle_auth as A
from fieldkit.update import packets as pk

if __package__:
    from . import runner
else:  # run as a file: python tests/fuzz/bundle_auth_fuzz.py
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from fuzz import runner

SWARM = bytes(range(100, 132))
KEY = A.bundle_key(SWARM)
SENDERS = (1, 2, 300)
POOL_N = 200
INTERESTING_BYTES = (0, 1, 2, 7, 8, 0x7F, 0x80, 0xFE, 0xFF)
#: Slice of a counted campaign between two progress lines.
SLICE = 50_000


def _messages(rng: random.Random) -> tuple[bytes, ...]:
    """Messages that fit a sealed bundle: often none, often a full one."""
    room = A.SEALED_MAX_BUZZ_BYTES
    out = []
    for _ in range(rng.choice((0, 1, 1, 2, 3, 8))):
        if room < B.MSG_OVERHEAD + 1:
            break
        most = room - B.MSG_OVERHEAD
        n = min(most, rng.choice((1, 3, most, rng.randint(1, most))))
        out.append(rng.randbytes(n))
        room -= n + B.MSG_OVERHEAD
    return tuple(out)


def _plain(rng: random.Random, robot: int) -> bytes:
    return B.encode_fields(
        robot,
        _messages(rng),
        rng.uniform(-90, 90),
        rng.uniform(-180, 180),
        rng.uniform(0, 50),
        rng.randrange(1 << 16),
        rng.getrandbits(64),
    )


def _other_key() -> A.BundleKey:
    for i in range(1, 100):
        k = A.bundle_key(bytes([i]) * 32)
        if k.id != KEY.id:
            return k
    raise AssertionError("no other key id")


def _forger_key() -> A.BundleKey:
    """A random key that claims this swarm's key id: only the tag can tell."""
    k = A.bundle_key(bytes(range(50, 82)))
    return A.BundleKey(k.secret, KEY.id, KEY.fingerprint, k._mac)


def _make_pool() -> tuple[dict[int, list[bytes]], dict[bytes, tuple[int, int, bytes]]]:
    rng = random.Random("bundle-auth-pool")
    pool: dict[int, list[bytes]] = {}
    genuine: dict[bytes, tuple[int, int, bytes]] = {}
    for s in SENDERS:
        sealer = A.Sealer(s, KEY, A.MemoryCounter())
        pool[s] = []
        for c in range(1, POOL_N + 1):
            plain = _plain(rng, s)
            sealed = sealer.seal(plain)
            assert sealer.last == c
            pool[s].append(sealed)
            genuine[sealed] = (s, c, plain)
    return pool, genuine


#: POOL[sender][counter - 1]: the genuine sealed bundles; GENUINE: bytes -> (sender, counter,
#: plain bytes).
POOL, GENUINE = _make_pool()
OTHER = _other_key()
FORGER = _forger_key()


@dataclass
class Stats(runner.EventStats):
    """What a campaign did."""

    accepted: int = 0
    reasons: dict[str, int] = field(default_factory=dict)

    def details(self) -> list[str]:
        """The kinds of input run, and what the verifiers did with them."""
        return [
            *super().details(),
            f"events: {self.events}, accepted: {self.accepted}, "
            f"rejected: {dict(sorted(self.reasons.items()))}",
        ]


# ---------------------------------------------------------------- mutations


def mutate(rng: random.Random, g: bytes) -> tuple[str, bytes]:
    """(kind, a mutant of the genuine sealed bundle `g`)."""
    s, c, plain = GENUINE[g]
    buf = bytearray(g)
    n = len(g)
    r = rng.random()
    if r < 0.12:
        for _ in range(rng.randint(1, 4)):
            buf[rng.randrange(n)] ^= 1 << rng.randrange(8)
        return "flip", bytes(buf)
    if r < 0.2:
        for _ in range(rng.randint(1, 3)):
            buf[rng.randrange(n)] = rng.choice(INTERESTING_BYTES)
        return "byte", bytes(buf)
    if r < 0.28:
        cut = rng.choice((n - 8, n - 16, n - 1, n - 9, rng.randrange(n), 48, 56, 64))
        return "truncate", bytes(buf[: max(cut, 0)])
    if r < 0.34:
        extra = rng.choice((bytes(8), bytes(16), rng.randbytes(rng.randint(1, 40)), g[-16:]))
        return "extend", bytes(buf) + extra
    if r < 0.46:
        # The trailer edited in place: format, key id, a counter byte, a tag byte.
        at = rng.choice((n - 9, n - 10, rng.randrange(n - 16, n - 10), rng.randrange(n - 8, n)))
        buf[at] = rng.choice((*INTERESTING_BYTES, buf[at] ^ 1, rng.randrange(256)))
        return "trailer", bytes(buf)
    if r < 0.56:
        # The counter moved under the old tag: a rewind to replay, or a jump ahead.
        new = rng.choice((c - 1, c - 64, c - 65, 0, c + 1, c + 64, A.MAX_COUNTER))
        new = max(new, 0)
        buf[n - 16 : n - 10] = new.to_bytes(6, "big")
        return "counter", bytes(buf)
    if r < 0.62:
        # The sender id (bundle header, air bytes 44-45): another robot's, the same tag.
        other = rng.choice([x for x in SENDERS if x != s] + [0, 0xFFFF])
        buf[44:46] = other.to_bytes(2, "big")
        return "sender", bytes(buf)
    if r < 0.68:
        # The bundle's word count: the trailer then sits elsewhere, or nowhere.
        words = (n - 16) // 8 - B.HEADER_WORDS
        new = rng.choice((words - 2, words - 1, words + 1, words + 2, 0, 0xFFFF))
        buf[46:48] = max(new, 0).to_bytes(2, "big")
        return "nwords", bytes(buf)
    if r < 0.78:
        # The trailer of another bundle of the same sender (a valid pair, the wrong bundle).
        d = rng.choice((POOL[s][rng.randrange(POOL_N)], POOL[s][min(c, POOL_N - 1)]))
        if rng.random() < 0.5:
            return "swap-trailer", plain + d[-16:]
        return "swap-tag", g[:-8] + d[-8:]
    if r < 0.88:
        other = POOL[rng.choice(SENDERS)][rng.randrange(POOL_N)]
        i, j = rng.randrange(n + 1), rng.randrange(len(other) + 1)
        if rng.random() < 0.5:
            i = i - i % 8
            j = j - j % 8
        return "splice", bytes(buf[:i]) + other[j:]
    if r < 0.94:
        return "strip", plain
    return "plain-extra", plain + bytes(8) + g[-8:]


def hostile(rng: random.Random) -> tuple[str, bytes, str | None]:
    """(kind, bytes, the reason they must get or None for any) of a non-mutant input."""
    s = rng.choice(SENDERS)
    r = rng.random()
    if r < 0.2:
        return (
            "foreign",
            A.Sealer(s, OTHER, A.MemoryCounter(rng.randint(1, 300))).seal(_plain(rng, s)),
            A.UNKNOWN_KEY,
        )
    if r < 0.45:
        return (
            "forged",
            A.Sealer(s, FORGER, A.MemoryCounter(rng.randint(1, 300))).seal(_plain(rng, s)),
            A.BAD_TAG,
        )
    if r < 0.6:
        return "plain", _plain(rng, s), A.MISSING_TRAILER
    if r < 0.7:
        frame = pk.encode(pk.Frame(s, (pk.Verdict(rng.randrange(9), pk.Reason.OPERATOR),)))
        if rng.random() < 0.5:
            frame = pk.seal(frame, pk.frame_key(SWARM))
        return "update-frame", frame, A.BAD_FORMAT
    if r < 0.75:
        ota = (1).to_bytes(8, "big") + rng.randbytes(8 * rng.randint(5, 40))
        return "rosbuzz-ota", ota, A.BAD_FORMAT
    if r < 0.9:
        # Random words with a bundle's word 0 type and a consistent word count: these reach
        # the trailer checks, and the tag check when format and key id happen to be right.
        words = rng.randint(1, 23)
        body = bytearray(rng.randbytes(8 * (B.HEADER_WORDS + words) + 16))
        body[6:8] = B.BUZZ_MESSAGE.to_bytes(2, "big")
        body[46:48] = words.to_bytes(2, "big")
        if rng.random() < 0.7:
            body[-9] = A.FORMAT
            body[-10] = KEY.id
        return "random-sealed", bytes(body), None
    blob = rng.randbytes(rng.choice((0, 7, 8, 48, 64, 240, 248, rng.randrange(300))))
    return "random", blob, None


# ---------------------------------------------------------------- the model


class Model:
    """The replay rules, written plainly: a set of counters seen per sender, a floor under
    which all count as seen, least-recently-heard eviction that keeps the highest as floor."""

    def __init__(self, cap: int, floors: dict[int, int]) -> None:
        self.cap = cap
        self.seen: OrderedDict[int, set[int]] = OrderedDict()
        self.floor: dict[int, int] = {}
        for s, f in floors.items():
            if f:
                self.floor[s] = f
                self._touch(s, set())

    def _touch(self, s: int, seen: set[int]) -> None:
        self.seen[s] = seen
        self.seen.move_to_end(s)
        if len(self.seen) > self.cap:
            old, oseen = self.seen.popitem(last=False)
            self.floor[old] = max([self.floor.get(old, 0), *oseen])

    def expect(self, s: int, c: int) -> str:
        """ACCEPTED, REPLAYED or TOO_OLD; records an acceptance."""
        floor = self.floor.get(s, 0)
        seen = self.seen.get(s)
        if seen is None and not floor:
            self._touch(s, {c})
            return A.ACCEPTED
        seen = seen if seen is not None else set()
        highest = max([floor, *seen])
        if c <= highest - A.WINDOW - 1:
            return A.TOO_OLD
        if c <= floor or c in seen:
            return A.REPLAYED
        seen.add(c)
        self._touch(s, seen)
        return A.ACCEPTED


# ---------------------------------------------------------------- one input


Event = tuple[str, bytes, str | None]


def make_input(seed: str, k: int) -> tuple[int, dict[int, int], list[Event]]:
    """Input k: (max_senders, floors, events (kind, bytes, forced reason or None))."""
    rng = random.Random(f"{seed}:{k}")
    cap = rng.choice((A.MAX_SENDERS, A.MAX_SENDERS, A.MAX_SENDERS, 1, 2))
    floors: dict[int, int] = {}
    if rng.random() < 0.15:
        floors = {s: rng.choice((0, 1, 50, 100, 199)) for s in rng.sample(SENDERS, 2)}
    cursor = {s: rng.choice((1, 1, 30, 100, 180)) for s in SENDERS}
    events: list[Event] = []
    for _ in range(rng.choice((1, 2, 3, 5, 10))):
        s = rng.choice(SENDERS)
        step = rng.choice((1, 1, 1, 1, 2, 3, 0, -1, -2, -10, -63, -64, -65, -100, 64, 70))
        c = min(max(cursor[s] + step, 1), POOL_N)
        cursor[s] = max(cursor[s], c)
        g = POOL[s][c - 1]
        r = rng.random()
        if r < 0.45:
            events.append(("genuine", g, None))
        elif r < 0.85:
            kind, data = mutate(rng, g)
            events.append((kind, data, None))
        else:
            events.append(hostile(rng))
    return cap, floors, events


def check(
    cap: int, floors: dict[int, int], events: list[Event], stats: Stats | None = None
) -> str | None:
    """Failure description of one input, or None."""
    v = A.Verifier(KEY, floors=floors, max_senders=cap)
    model = Model(cap, floors)
    accepted: set[bytes] = set()
    calls = 0
    for i, (kind, data, forced) in enumerate(events):
        where = f"event {i} ({kind}, {data.hex()})"
        calls += 1
        try:
            out: bytes | None = v.verify(data)
            got = A.ACCEPTED
        except A.AuthError as e:
            out = None
            got = e.reason
            if got not in A.REASONS:
                return f"{where}: unknown reason {got!r}"
        except Exception:
            return f"{where}: raised\n" + traceback.format_exc()
        if stats is not None:
            if got == A.ACCEPTED:
                stats.accepted += 1
            else:
                stats.reasons[got] = stats.reasons.get(got, 0) + 1
        origin = GENUINE.get(data)
        if origin is None:
            if got == A.ACCEPTED:
                return f"{where}: FORGERY ACCEPTED"
            if forced is not None and got != forced:
                return f"{where}: refused as {got}, {forced} expected"
            continue
        s, c, plain = origin
        want = model.expect(s, c)
        if got != want:
            return f"{where}: robot {s} counter {c} got {got}, the model says {want}"
        if got == A.ACCEPTED:
            if data in accepted:
                return f"{where}: ACCEPTED TWICE"
            accepted.add(data)
            if out != plain:
                return f"{where}: accepted, but returned {out!r:.60} for the plain bundle"
    if sum(v.counters.values()) != calls or v.counters[A.ACCEPTED] != len(accepted):
        return f"counters {dict(v.counters)} for {calls} calls, {len(accepted)} accepted"
    if v.tracked() > cap:
        return f"{v.tracked()} senders tracked, over the cap {cap}"
    return None


def _build_and_check(seed: str, k: int, stats: Stats) -> tuple[list[Event], str | None]:
    cap, floors, events = make_input(seed, k)
    return events, check(cap, floors, events, stats)


def run_one(seed: str, k: int, stats: Stats, out: Callable[[str], None]) -> None:
    """Make input k, check it, and record the outcome."""
    runner.run_events(seed, k, stats, out, _build_and_check)


#: run(seed, *, seconds=None, max_inputs=None, start=0, out=print) -> Stats: a campaign.
run = runner.make_run(run_one, Stats, clock_every=64)


def replay(spec: str) -> int:
    """Run input SEED:K verbosely; exit status 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    cap, floors, events = make_input(seed, int(k))
    print(f"max_senders {cap}, floors {floors}")
    for kind, data, forced in events:
        origin = GENUINE.get(data)
        tag = f"genuine robot {origin[0]} counter {origin[1]}" if origin else forced or ""
        print(f"  {kind} ({tag}): {data.hex(' ')}")
    failure = check(cap, floors, events)
    print(failure or "ok")
    return 1 if failure else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point: --count N runs exactly N inputs (no time limit)."""
    return runner.counted_main(argv, __doc__, run, replay, Stats, slice_inputs=SLICE)


if __name__ == "__main__":
    sys.exit(main())
