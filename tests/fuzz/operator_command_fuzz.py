"""Fuzzing the operator-command gate (fieldkit.robot.operator_command) with genuine and
hostile command frames, seeded.

    python tests/fuzz/operator_command_fuzz.py --count 1000000 --seed 1
    python -m tests.fuzz.operator_command_fuzz --seconds 60 --seed 1
    python -m tests.fuzz.operator_command_fuzz --replay 1:12345      # one input, verbosely

Input k of seed S is made from `random.Random(f"{S}:{k}")`, so every input replays with
`--replay S:k`. One input is a fresh `CommandGate` for robot 1, 2 or 300 (most often with a
sequence store, in memory here, sometimes already holding a last acted number as after
earlier runs) fed 1 to 10 events, each one of:

* a genuine frame from the pool (sequence numbers 1..600 signed once at import with the
  operator's key, for robots 1, 2, 300, ALL or a robot not in the swarm, every code and
  params shape, and one at the largest sequence number), delivered mostly in order, with
  duplicates, steps back and jumps around the 256-number relay window;
* a mutation of a genuine one: bit flips, interesting bytes, truncations, extensions, a field
  edited under the old signature (type, format, params count, target, code, sequence number,
  a param, key id), the params count and length changed together, the signature of another
  genuine frame or a forger's, words swapped, dropped or repeated, splices of two frames;
* another key's frame (its own key id), a forger's frame (the operator's key id, another
  key's signature, often over a genuine command), a bundle (plain or sealed), an update frame
  (plain or sealed), a ROSBuzz OTA packet, random command-shaped bytes, random bytes;
* a reboot: a new gate on the same store.

The property, per event: `receive` returns a GateResult and raises nothing; whatever is not
a genuine pool frame is refused with a reason in REASONS (the one its kind must get, when it
has one), acted on never and relayed never (0 accepted forgeries); for a genuine frame, what
is acted on, relayed and the reason agree with a plain model of the rules (a set of numbers
relayed since boot, refusing those 256 or more below the highest since boot, which starts at
the last acted number; act on a command for this robot above the last acted number), the
relayed bytes are the frame's own, nothing is acted on twice across reboots, and the store
holds the number of a command before the gate returns it; the counters add up.

Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import random
import struct
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from fieldkit.robot import bundle as B
from fieldkit.robot import bundle_auth as A
from fieldkit.robot import operator_command as C
from fieldkit.update import packets as pk

if __package__:
    from . import runner
else:  # run as a file: python tests/fuzz/operator_command_fuzz.py
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from fuzz import runner

OPERATOR = Ed25519PrivateKey.from_private_bytes(bytes(range(1, 33)))
OPERATOR_PUB = OPERATOR.public_key()
OPERATOR_ID = C.operator_key_id(OPERATOR_PUB)
#: Another operator's key (another swarm's ground station): frames under its own key id.
OTHER = Ed25519PrivateKey.from_private_bytes(bytes(range(40, 72)))
#: A forger's key: frames claiming the operator's key id, signed with this.
FORGER = Ed25519PrivateKey.from_private_bytes(bytes(range(80, 112)))
SWARM = bytes(range(100, 132))
ROBOTS = (1, 2, 300)
TARGETS = (1, 2, 300, C.ALL, C.ALL, 7)
POOL_N = 600
CODES = (22, 21, 20, 900, 901, 16, 0, 1, 0xFFFF)
INTERESTING_BYTES = (0, 1, 2, 0x10, 0x11, 0x7F, 0x80, 0xFE, 0xFF)
#: Slice of a counted campaign between two progress lines.
SLICE = 20_000


def _command(rng: random.Random, seq: int) -> C.OperatorCommand:
    code = rng.choice(CODES)
    if code == 16:
        params: tuple[float, ...] = (
            float(rng.randrange(100)),
            rng.uniform(-90, 90),
            rng.uniform(-180, 180),
            rng.uniform(0, 120),
        )
    else:
        params = tuple(rng.uniform(-1e6, 1e6) for _ in range(rng.choice((0, 0, 0, 1, 2, 4))))
    return C.OperatorCommand(seq, rng.choice(TARGETS), code, params)


def _signed_by(key: Ed25519PrivateKey, cmd: C.OperatorCommand, key_id: bytes) -> bytes:
    """`cmd` signed with `key` under `key_id` (the operator's, to forge)."""
    image = C._image(cmd, key_id)
    return C._swap(image + key.sign(C.DOMAIN + image))


def _make_pool() -> tuple[dict[int, bytes], dict[bytes, C.OperatorCommand]]:
    rng = random.Random("operator-command-pool")
    pool: dict[int, bytes] = {}
    genuine: dict[bytes, C.OperatorCommand] = {}
    for seq in [*range(1, POOL_N + 1), C.MAX_SEQ]:
        cmd = _command(rng, seq)
        frame = C.sign_command(OPERATOR, cmd)
        pool[seq] = frame
        genuine[frame] = cmd
    return pool, genuine


def _make_hostile_pools() -> tuple[list[bytes], list[bytes]]:
    """Frames of another operator (own key id), and forgeries under the operator's key id
    (half of them over genuine commands: the same image, another signature)."""
    rng = random.Random("operator-command-hostile")
    other_id = C.operator_key_id(OTHER.public_key())
    foreign = [
        _signed_by(OTHER, _command(rng, rng.randint(1, POOL_N)), other_id) for _ in range(64)
    ]
    forged = []
    for i in range(64):
        seq = rng.randint(1, POOL_N)
        cmd = GENUINE[POOL[seq]] if i % 2 else _command(rng, seq)
        forged.append(_signed_by(FORGER, cmd, OPERATOR_ID))
    return foreign, forged


#: POOL[seq]: the genuine frames; GENUINE: bytes -> the command they carry.
POOL, GENUINE = _make_pool()
FOREIGN, FORGED = _make_hostile_pools()
SEQS = [*range(1, POOL_N + 1)]


class MemoryStore:
    """A sequence store in memory that survives the gate's 'reboots' (a new gate on it)."""

    def __init__(self, n: int) -> None:
        self.n = n

    def load(self) -> int:
        """The last acted number."""
        return self.n

    def save(self, n: int) -> None:
        """Keep `n`."""
        self.n = n


@dataclass
class Stats(runner.EventStats):
    """What a campaign did."""

    acted: int = 0
    relayed: int = 0
    not_for_me: int = 0
    reboots: int = 0
    reasons: dict[str, int] = field(default_factory=dict)

    def details(self) -> list[str]:
        """The kinds of input run, and what the gates did with them."""
        return [
            *super().details(),
            f"events: {self.events}, acted: {self.acted}, relayed: {self.relayed}, "
            f"not-for-me: {self.not_for_me}, reboots: {self.reboots}, "
            f"refused: {dict(sorted(self.reasons.items()))}",
        ]


# ---------------------------------------------------------------- mutations

_HEAD = struct.Struct("<HBBHHQ")


def _edit_field(rng: random.Random, image: bytearray, cmd: C.OperatorCommand) -> None:
    """One field of the memory image changed, the signature left as it was."""
    n = len(cmd.params)
    which = rng.choice(("type", "format", "count", "target", "code", "seq", "param", "key-id"))
    if which == "type":
        image[0:2] = rng.choice((2, 16, 1, 18, 0x1100, 0)).to_bytes(2, "little")
    elif which == "format":
        image[2] = rng.choice((0, 2, 0xFF))
    elif which == "count":
        image[3] = rng.choice((n - 1, n + 1, 4, 5, 0xFF)) & 0xFF
    elif which == "target":
        t = rng.choice((*ROBOTS, C.ALL, 0, cmd.target ^ 1))
        image[4:6] = t.to_bytes(2, "little")
    elif which == "code":
        image[6:8] = rng.choice((22, 21, 16, cmd.code ^ 1)).to_bytes(2, "little")
    elif which == "seq":
        s = rng.choice((cmd.seq + 1, cmd.seq - 1, cmd.seq + 256, 0, C.MAX_SEQ, C.MAX_SEQ + 1))
        image[8:16] = (s % (1 << 64)).to_bytes(8, "little")
    elif which == "param" and n:
        i = rng.randrange(n)
        v = rng.choice((0.0, -0.0, cmd.params[i] + 1, float("nan"), float("inf"), 1e308))
        image[16 + 8 * i : 24 + 8 * i] = struct.pack("<d", v)
    else:
        at = 16 + 8 * n + rng.randrange(8)
        image[at] ^= 1 << rng.randrange(8)


def mutate(rng: random.Random, g: bytes) -> tuple[str, bytes]:
    """(kind, a mutant of the genuine frame `g`)."""
    cmd = GENUINE[g]
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
    if r < 0.27:
        cut = rng.choice((n - 8, n - 64, n - 1, 88, 80, 8, rng.randrange(n)))
        return "truncate", bytes(buf[: max(cut, 0)])
    if r < 0.33:
        extra = rng.choice((bytes(8), g[-8:], rng.randbytes(rng.randint(1, 40)), g))
        return "extend", bytes(buf) + extra
    image = bytearray(C._swap(g))
    if r < 0.5:
        _edit_field(rng, image, cmd)
        return "field", C._swap(bytes(image))
    if r < 0.56:
        # One param more or less, the count and the length agreeing: only the signature can
        # tell (the key id and signature stay at the end).
        k = len(cmd.params)
        tail = image[16 + 8 * k :]
        params = image[16 : 16 + 8 * k]
        if k and rng.random() < 0.5:
            params = params[:-8]
        else:
            params += struct.pack("<d", rng.choice((0.0, 1.0, 45.5)))
        image[3] = len(params) // 8
        return "params", C._swap(bytes(image[:16] + params + tail))
    if r < 0.66:
        # Another genuine frame's signature, or a forger's (often over this very command).
        donor = POOL[rng.choice(SEQS)] if rng.random() < 0.6 else rng.choice(FORGED)
        sig = C._swap(donor)[-C.SIGNATURE_BYTES :]
        return "swap-signature", C._swap(bytes(image[: -C.SIGNATURE_BYTES]) + sig)
    if r < 0.72:
        other_id = C.operator_key_id(OTHER.public_key())
        k = len(cmd.params)
        image[16 + 8 * k : 24 + 8 * k] = rng.choice((other_id, bytes(8), b"\xff" * 8))
        return "key-id", C._swap(bytes(image))
    if r < 0.82:
        words = [g[i : i + 8] for i in range(0, n, 8)]
        i, j = rng.randrange(len(words)), rng.randrange(len(words))
        op = rng.random()
        if op < 0.4:
            words[i], words[j] = words[j], words[i]
        elif op < 0.7:
            del words[i]
        else:
            words.insert(i, words[j])
        return "words", b"".join(words)
    other = POOL[rng.choice(SEQS)]
    i, j = rng.randrange(n + 1), rng.randrange(len(other) + 1)
    if rng.random() < 0.6:
        i, j = i - i % 8, j - j % 8
    return "splice", bytes(buf[:i]) + other[j:]


def _bundle(rng: random.Random) -> bytes:
    messages = tuple(rng.randbytes(rng.randint(1, 40)) for _ in range(rng.randint(0, 3)))
    return B.encode_fields(rng.choice(ROBOTS), messages, 45.5, -73.6, 10.0, 1, rng.getrandbits(64))


def hostile(rng: random.Random) -> tuple[str, bytes, str | None]:
    """(kind, bytes, the reason they must get or None for any) of a non-mutant input."""
    r = rng.random()
    if r < 0.2:
        return "foreign", rng.choice(FOREIGN), C.UNKNOWN_KEY
    if r < 0.45:
        return "forged", rng.choice(FORGED), C.BAD_SIGNATURE
    if r < 0.53:
        plain = _bundle(rng)
        if rng.random() < 0.5:
            return "bundle", plain, C.BAD_FORMAT
        sealer = A.Sealer(B.decode(plain).robot, A.bundle_key(SWARM), A.MemoryCounter())
        return "sealed-bundle", sealer.seal(plain), C.BAD_FORMAT
    if r < 0.61:
        frame = pk.encode(pk.Frame(rng.choice(ROBOTS), (pk.Verdict(3, pk.Reason.OPERATOR),)))
        if rng.random() < 0.5:
            frame = pk.seal(frame, pk.frame_key(SWARM))
        return "update-frame", frame, C.BAD_FORMAT
    if r < 0.66:
        ota = (1).to_bytes(8, "big") + rng.randbytes(8 * rng.randint(10, 14))
        return "rosbuzz-ota", ota, C.BAD_FORMAT
    if r < 0.86:
        # Random words with a command's head, length and (mostly) the operator's key id: these
        # reach the signature check whenever their fields happen to be valid.
        k = rng.randint(0, 4)
        image = bytearray(rng.randbytes(C.MIN_COMMAND_BYTES + 8 * k))
        image[0:4] = bytes((C.COMMAND_FRAME, 0, C.FORMAT, k))
        if rng.random() < 0.7:
            image[8:16] = rng.randint(1, POOL_N).to_bytes(8, "little")
            for i in range(k):
                image[16 + 8 * i : 24 + 8 * i] = struct.pack("<d", rng.uniform(-100, 100))
            if k != 4 and image[6:8] == b"\x10\x00":
                image[6] = 22
        if rng.random() < 0.8:
            image[16 + 8 * k : 24 + 8 * k] = OPERATOR_ID
        return "random-command", C._swap(bytes(image)), None
    blob = rng.randbytes(rng.choice((0, 7, 8, 88, 96, 120, 128, rng.randrange(300))))
    return "random", blob, None


# ---------------------------------------------------------------- the model


class Model:
    """The gate's rules, written plainly: numbers relayed since boot in a set, a highest
    relayed that starts at the last acted number, a last acted number that a reboot keeps."""

    def __init__(self, robot: int, last: int) -> None:
        self.robot = robot
        self.last = last
        self.boot()

    def boot(self) -> None:
        """What a reboot forgets: the relay memory."""
        self.relayed: set[int] = set()
        self.high = self.last

    def expect(self, cmd: C.OperatorCommand) -> tuple[bool, bool, str | None]:
        """(acts, relays, reason) for a genuine frame; records both."""
        relay = cmd.seq not in self.relayed and cmd.seq > self.high - C.RELAY_WINDOW
        if relay:
            self.relayed.add(cmd.seq)
            self.high = max(self.high, cmd.seq)
        mine = cmd.target in (self.robot, C.ALL)
        act = mine and cmd.seq > self.last
        if act:
            self.last = cmd.seq
        return act, relay, (C.REPLAYED if mine and not act else None)


# ---------------------------------------------------------------- one input


Event = tuple[str, bytes, str | None]
REBOOT: Event = ("reboot", b"", None)


@dataclass
class Setup:
    """An input's gate: its robot id and its store (None: in memory, no reboots)."""

    robot: int
    stored: int | None


def make_input(seed: str, k: int) -> tuple[Setup, list[Event]]:
    """Input k: the gate's setup and its events (kind, bytes, forced reason or None)."""
    rng = random.Random(f"{seed}:{k}")
    stored = rng.choice((None, 0, 0, 0, 0, 1, 50, 300, 599))
    setup = Setup(rng.choice(ROBOTS), stored)
    cursor = rng.choice((1, 1, 1, 100, 300, 550))
    events: list[Event] = []
    for _ in range(rng.choice((1, 2, 3, 5, 10))):
        r = rng.random()
        if stored is not None and r < 0.06:
            events.append(REBOOT)
            continue
        step = rng.choice((1, 1, 1, 1, 2, 3, 0, -1, -5, -255, -256, -257, 255, 256, 257, 300, -300))
        cursor = min(max(cursor + step, 1), POOL_N)
        seq = C.MAX_SEQ if rng.random() < 0.01 else cursor
        g = POOL[seq]
        if r < 0.45:
            events.append(("genuine", g, None))
        elif r < 0.85:
            kind, data = mutate(rng, g)
            events.append((kind, data, None))
        else:
            events.append(hostile(rng))
    return setup, events


def _outcome_problem(res: object) -> str | None:
    """What is wrong with the shape of a receive's result, or None."""
    if not isinstance(res, C.GateResult):
        return f"returned {res!r:.80}, not a GateResult"
    if res.act is not None and not isinstance(res.act, C.OperatorCommand):
        return f"act {res.act!r:.80}"
    if res.relay is not None and type(res.relay) is not bytes:
        return f"relay {res.relay!r:.80}"
    if res.reason is not None and res.reason not in C.REASONS:
        return f"unknown reason {res.reason!r}"
    return None


def check(setup: Setup, events: list[Event], stats: Stats | None = None) -> str | None:
    """Failure description of one input, or None."""
    store = None if setup.stored is None else MemoryStore(setup.stored)
    gate = C.CommandGate(setup.robot, OPERATOR_PUB, store)
    model = Model(setup.robot, setup.stored or 0)
    acted: set[int] = set()
    calls = relays = 0
    for i, (kind, data, forced) in enumerate(events):
        where = f"event {i} ({kind}, {data.hex()})"
        if kind == "reboot":
            problem = _gate_counts(gate, calls, relays)
            if problem is not None:
                return f"{where}: before it, {problem}"
            gate = C.CommandGate(setup.robot, OPERATOR_PUB, store)
            model.boot()
            calls = relays = 0
            if gate.last_acted != model.last:
                return f"{where}: the gate starts at {gate.last_acted}, {model.last} was acted on"
            if stats is not None:
                stats.reboots += 1
            continue
        calls += 1
        try:
            res = gate.receive(data)
        except Exception:
            return f"{where}: raised\n" + traceback.format_exc()
        problem = _outcome_problem(res)
        if problem is not None:
            return f"{where}: {problem}"
        act, relay, reason = res
        relays += relay is not None
        if stats is not None:
            stats.acted += act is not None
            stats.relayed += relay is not None
            if reason is not None:
                stats.reasons[reason] = stats.reasons.get(reason, 0) + 1
        cmd = GENUINE.get(data)
        if cmd is None:
            if act is not None:
                return f"{where}: FORGERY ACTED ON: {act}"
            if relay is not None:
                return f"{where}: FORGERY RELAYED"
            if reason is None:
                return f"{where}: a forgery passed as valid, not for this robot"
            if forced is not None and reason != forced:
                return f"{where}: refused as {reason}, {forced} expected"
            continue
        want_act, want_relay, want_reason = model.expect(cmd)
        if stats is not None and want_reason is None and not want_act:
            stats.not_for_me += 1
        got = (act is not None, relay is not None, reason)
        if got != (want_act, want_relay, want_reason):
            return (
                f"{where}: seq {cmd.seq} for {cmd.target}: (acts, relays, reason) {got}, "
                f"the model says {(want_act, want_relay, want_reason)}"
            )
        if act is not None:
            if act != cmd:
                return f"{where}: acted on {act}, the frame says {cmd}"
            if cmd.seq in acted:
                return f"{where}: ACTED TWICE on {cmd.seq}"
            acted.add(cmd.seq)
            if store is not None and store.n != cmd.seq:
                return f"{where}: acted on {cmd.seq}, the store holds {store.n}"
        if relay is not None and relay != data:
            return f"{where}: relayed other bytes {relay.hex()}"
    return _gate_counts(gate, calls, relays)


def _gate_counts(gate: C.CommandGate, calls: int, relays: int) -> str | None:
    """Whether a gate's counters add up to what it was fed."""
    c = gate.counters
    outcomes = c[C.ACCEPTED] + c[C.NOT_FOR_ME] + sum(c[r] for r in C.REASONS)
    if outcomes != calls or c[C.RELAYED] != relays:
        return f"counters {dict(c)} for {calls} frames, {relays} relayed"
    if set(c) - {C.ACCEPTED, C.NOT_FOR_ME, C.RELAYED, *C.REASONS}:
        return f"unknown counters {dict(c)}"
    return None


def _build_and_check(seed: str, k: int, stats: Stats) -> tuple[list[Event], str | None]:
    setup, events = make_input(seed, k)
    return events, check(setup, events, stats)


def run_one(seed: str, k: int, stats: Stats, out: Callable[[str], None]) -> None:
    """Make input k, check it, and record the outcome."""
    runner.run_events(seed, k, stats, out, _build_and_check)


#: run(seed, *, seconds=None, max_inputs=None, start=0, out=print) -> Stats: a campaign.
run = runner.make_run(run_one, Stats, clock_every=16)


def replay(spec: str) -> int:
    """Run input SEED:K verbosely; exit status 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    setup, events = make_input(seed, int(k))
    print(f"robot {setup.robot}, store {setup.stored}")
    for kind, data, forced in events:
        cmd = GENUINE.get(data)
        tag = f"genuine {cmd}" if cmd else forced or ""
        print(f"  {kind} ({tag}): {data.hex(' ')}")
    failure = check(setup, events)
    print(failure or "ok")
    return 1 if failure else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point: --count N runs exactly N inputs (no time limit)."""
    return runner.counted_main(argv, __doc__, run, replay, Stats, slice_inputs=SLICE)


if __name__ == "__main__":
    sys.exit(main())
