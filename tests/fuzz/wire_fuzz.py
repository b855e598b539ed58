"""Fuzzing the Buzz message decoder (bvm.wire) with hostile payloads: a seeded campaign.

    python -m tests.fuzz.wire_fuzz --seconds 60 --seed 1
    python -m tests.fuzz.wire_fuzz --replay 1:12345      # one input, verbosely

Input k of seed S is made from `random.Random(f"{S}:{k}")`, so every input replays with
`--replay S:k`. Inputs: random bytes, valid messages, and mutations of valid messages (bit
flips, interesting bytes, truncations, extensions, splices, length/count field tampering),
nesting bombs, huge claimed lengths, and rare big (up to 64 KiB) payloads.

The property, per input:

* `wire.decode` returns a message or raises DecodeError whose text names a byte offset;
  any other exception is a failure;
* an accepted message re-encodes without error, no longer than the input, and
  decode . encode is then a fixpoint: it gives an equal message with the same bytes;
* big payloads are decoded under a line counter: the Python lines executed while decoding
  must stay within LINES_PER_BYTE per payload byte (linear work, counted rather than timed),
  and the CPU time must stay far under a generous budget (catching quadratic work in C).

Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import random
import struct
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from bvm import wire
from bvm.values import Table

from . import runner

#: Work bound: Python lines run per payload byte while decoding (measured: 4.3 at worst).
LINES_PER_BYTE = 12
#: CPU seconds allowed to decode a 64 KiB payload (it takes a few milliseconds).
BIG_SECONDS = 2.0
BIG = 64 * 1024

INTERESTING_BYTES = (0, 1, 2, 3, 4, 5, 6, 7, 0x7F, 0x80, 0xFE, 0xFF)
INTERESTING_U16 = (0, 1, 2, 0x7F, 0x80, 0xFF, 0x100, 0x7FFF, 0x8000, 0xFFFE, 0xFFFF)
INTERESTING_I32 = (0, 1, -1, 0x7FFFFFFF, -0x80000000, -0x7FFFFFFF, 129, 128, -125, -149, 256)

#: The documented payloads (docs/wire-format.md#message-types, docs/bundle.md#worked-example),
#: mutated like generated ones.
SEEDS = [
    bytes.fromhex(x)
    for x in (
        "00 03 0003 636d64 01 00000016",
        "00 03 0001 66 02 b33332ff fffffffd",
        "00 03 0001 66 00",
        "01 0001 0003",
        "02 0005 03 0001 6b 01 0000002a 0001 0007",
        "02 0005 01 00000007 02 40000001 00000001 0001 0007",
        "02 0005 03 0001 74 04 01 03 0001 61 01 00000001 0001 0007",
        "03 0005 03 0007 6d697373696e67 00 0000 0007",
        "02 0005 03 0001 6b 00 0002 0002",
        "04 0003",
        "05 0003",
        "00 03 0001 66 05 01 00000098",
    )
]


# ---------------------------------------------------------------- valid inputs


def random_float(rng: random.Random) -> float:
    """A binary32 value, biased to the edges: zeros, subnormals, extremes, inf, NaN."""
    r = rng.random()
    if r < 0.1:
        return rng.choice([0.0, -0.0, float("inf"), float("-inf"), float("nan"), 1.0, -0.5])
    bits = rng.getrandbits(32)
    if r < 0.3:
        bits &= 0x807FFFFF  # subnormal
    return struct.unpack(">f", struct.pack(">I", bits))[0]


def random_string(rng: random.Random) -> str:
    """A Buzz string (latin-1), mostly short."""
    n = rng.choice((0, 1, 1, 2, 3, 5, 8, 13, rng.randrange(300)))
    if rng.random() < 0.5:
        return "".join(rng.choice("abcdefghxyz_") for _ in range(n))
    return rng.randbytes(n).decode("latin-1")


def random_key(rng: random.Random) -> Any:
    """A table or vstig key: int, non-NaN float or string."""
    r = rng.random()
    if r < 0.4:
        return random_string(rng)
    if r < 0.8:
        return rng.choice((rng.randrange(-10, 300), rng.choice(INTERESTING_I32)))
    x = random_float(rng)
    return 0.5 if x != x else x


def random_value(rng: random.Random, depth: int) -> Any:
    """A Buzz value whose tables nest at most `depth` more levels."""
    r = rng.random()
    if r < 0.12:
        return None
    if r < 0.35:
        return rng.choice((rng.randrange(-1000, 1000), rng.choice(INTERESTING_I32)))
    if r < 0.55:
        return random_float(rng)
    if r < 0.75:
        return random_string(rng)
    if r < 0.8:
        return wire.WireClosure(rng.random() < 0.5, rng.choice((0, 0x98, rng.getrandbits(32))))
    if depth <= 0:
        return rng.randrange(100)
    t = Table()
    for _ in range(rng.choice((0, 1, 2, 3, 4, rng.randrange(20)))):
        t[random_key(rng)] = random_value(rng, depth - 1)
    return t


def random_message(rng: random.Random) -> wire.Message:
    """A valid message; tables nest up to MAX_DEPTH, usually much less."""
    depth = wire.MAX_DEPTH if rng.random() < 0.02 else rng.randrange(4)
    u16 = rng.choice((rng.randrange(10), rng.randrange(0x10000), rng.choice(INTERESTING_U16)))
    t = rng.randrange(6)
    if t == 0:
        return wire.Broadcast(random_string(rng), random_value(rng, depth))
    if t == 1:
        return wire.SwarmList(tuple(rng.randrange(0x10000) for _ in range(rng.randrange(12))))
    if t in (2, 3):
        cls = wire.VstigPut if t == 2 else wire.VstigQuery
        value = None if rng.random() < 0.2 else random_value(rng, depth)
        return cls(u16, random_key(rng), value, rng.randrange(0x10000), rng.randrange(256))
    return (wire.SwarmJoin if t == 4 else wire.SwarmLeave)(u16)


def valid_payload(rng: random.Random) -> bytes:
    """A valid payload: a spec example or a random message, encoded."""
    if rng.random() < 0.15:
        return rng.choice(SEEDS)
    return wire.encode(random_message(rng))


def length_fields(buf: bytes) -> list[tuple[int, int]]:
    """(offset, width) of the length and count fields of a valid payload (a tiny walker)."""
    found: list[tuple[int, int]] = []

    def obj(p: int) -> int:
        tag = buf[p]
        if tag == 3:
            found.append((p + 1, 2))
            return p + 3 + int.from_bytes(buf[p + 1 : p + 3], "big")
        if tag == 4:
            found.append((p + 1, 1))
            q = p + 2
            for _ in range(buf[p + 1]):
                q = obj(obj(q))
            return q
        return p + {0: 1, 1: 5, 2: 9, 5: 6}[tag]

    t = buf[0]
    if t == 0:
        obj(obj(1))
    elif t == 1:
        found.append((1, 2))
    elif t in (2, 3):
        obj(obj(3))
    return found


# ---------------------------------------------------------------- hostile inputs


def nest_bomb(rng: random.Random) -> bytes:
    """Tables nested around the limit, or far past it, with honest or lying counts."""
    depth = rng.choice((rng.randrange(28, 37), rng.randrange(1, 3000)))
    count = rng.choice((1, 1, 2, 0xFF))
    level = bytes([4, count, 3, 0, 1, 0x78])  # {"x": <next level>}
    inner = rng.choice((b"\x00", b"\x04\x00", b"\x01\x00\x00\x00\x07", b""))
    body = level * depth + inner
    if rng.random() < 0.5:
        return b"\x00\x03\x00\x01a" + body
    return b"\x02\x00\x05\x03\x00\x01k" + body + b"\x00\x01\x00\x07"


def huge_claim(rng: random.Random) -> bytes:
    """Length and count fields that claim far more than the payload holds."""
    r = rng.randrange(5)
    tail = rng.randbytes(rng.randrange(20))
    if r == 0:
        return b"\x00\x03" + struct.pack(">H", rng.choice((0xFFFF, 0x8000, 0x100))) + tail
    if r == 1:
        return b"\x01" + struct.pack(">H", rng.choice((0xFFFF, 0x7FFF, 100))) + tail
    if r == 2:
        return b"\x00\x03\x00\x01a\x04\xff" + tail
    if r == 3:
        return b"\x02\x00\x05\x03" + struct.pack(">H", 0xFFFF) + tail
    n = rng.choice((0xFFFF, 0xFFFE))  # a real 64 KiB string: valid only if complete
    return b"\x00\x03\x00\x01s\x03" + struct.pack(">H", n) + b"z" * (n - rng.randrange(2))


def big_payload(rng: random.Random) -> bytes:
    """A payload of about 64 KiB, mostly small objects (the worst case for work per byte)."""
    r = rng.randrange(6)
    head = b"\x00\x03\x00\x01t"
    if r == 0:  # tables of 255 int-keyed entries (nil values: dropped), valid, ~64 KiB
        value = rng.choice((b"\x00", b"\x01\x00\x00\x00\x01"))
        inner = b"\x04\xff" + b"".join(b"\x01" + struct.pack(">i", j) + value for j in range(255))
        n = (BIG - 10) // (5 + len(inner))
        payload = (
            head
            + bytes([4, n])
            + b"".join(b"\x01" + struct.pack(">i", i) + inner for i in range(n))
        )
    elif r == 1:  # the longest SWARM_LIST that fits
        n = (BIG - 3) // 2
        payload = b"\x01" + struct.pack(">H", n) + rng.randbytes(2 * n)
    elif r == 2:  # a string of 65535 bytes (the longest)
        payload = head + b"\x03\xff\xff" + rng.randbytes(0xFFFF)
    elif r == 3:  # 255 chains {"": {"": ...}} 31 deep inside one table: 32 levels, valid
        chain = b"\x04\x01\x03\x00\x00" * 31 + b"\x01\x00\x00\x00\x01"
        payload = (
            head
            + b"\x04\xff"
            + b"".join(b"\x01" + struct.pack(">i", i) + chain for i in range(255))
        )
    elif r == 4:  # 40 levels of 254 nil entries then the next level: fails at level 33
        level = b"\x04\xff" + b"\x03\x00\x00\x00" * 254 + b"\x03\x00\x00"
        payload = head + level * 40
    else:  # claims 255 x 255 entries of floats, cut at 64 KiB: truncated at the very end
        inner = b"\x04\xff" + b"".join(
            b"\x01" + struct.pack(">i", j) + b"\x02" + struct.pack(">ii", rng.getrandbits(31), j)
            for j in range(255)
        )
        body = b"\x04\xff" + b"".join(b"\x01" + struct.pack(">i", i) + inner for i in range(255))
        payload = (head + body)[:BIG]
    if rng.random() < 0.5:
        payload = mutate(rng, payload, light=True)
    return payload


def mutate(rng: random.Random, data: bytes, light: bool = False) -> bytes:
    """One to a few byte-level mutations of `data`."""
    b = bytearray(data)
    for _ in range(1 if light else rng.choice((1, 1, 1, 2, 3, 5))):
        op = rng.randrange(7)
        if not b:
            b += rng.randbytes(rng.randrange(1, 8))
            continue
        i = rng.randrange(len(b))
        if op == 0:  # bit flip
            b[i] ^= 1 << rng.randrange(8)
        elif op == 1:  # interesting byte
            b[i] = rng.choice(INTERESTING_BYTES)
        elif op == 2:  # random byte
            b[i] = rng.randrange(256)
        elif op == 3:  # delete a run
            del b[i : i + rng.randrange(1, 6)]
        elif op == 4:  # insert bytes
            b[i:i] = rng.randbytes(rng.randrange(1, 6))
        elif op == 5:  # duplicate a run
            j = rng.randrange(i, min(len(b), i + 16) + 1)
            b[i:i] = b[i:j]
        else:  # overwrite with an interesting u16
            b[i : i + 2] = struct.pack(">H", rng.choice(INTERESTING_U16))
    return bytes(b)


def tamper_length(rng: random.Random, data: bytes) -> bytes:
    """Change a string length, table count or list count of a valid payload."""
    spots = length_fields(data)
    if not spots:
        return mutate(rng, data)
    off, width = rng.choice(spots)
    old = int.from_bytes(data[off : off + width], "big")
    top = (1 << (8 * width)) - 1
    new = rng.choice((0, 1, old - 1, old + 1, old + 2, old * 2, top, top - 1, rng.randrange(top)))
    new = min(max(new, 0), top)
    return data[:off] + new.to_bytes(width, "big") + data[off + width :]


def splice(rng: random.Random) -> bytes:
    """Parts of two valid payloads joined, or one inserted into the other."""
    a, b = valid_payload(rng), valid_payload(rng)
    i, j = rng.randrange(len(a) + 1), rng.randrange(len(b) + 1)
    if rng.random() < 0.5:
        return a[:i] + b[j:]
    return a[:i] + b[j : j + rng.randrange(1, 20)] + a[i:]


def random_bytes(rng: random.Random) -> bytes:
    """Random bytes, with a plausible message type byte more often than not."""
    data = rng.randbytes(rng.choice((0, 1, 2, 3, 5, 8, 16, 64, rng.randrange(200))))
    if data and rng.random() < 0.7:
        data = bytes([rng.randrange(7)]) + data[1:]
    return data


KINDS: list[tuple[str, float, Callable[[random.Random], bytes]]] = [
    ("valid", 10, valid_payload),
    ("random", 10, random_bytes),
    ("mutate", 30, lambda rng: mutate(rng, valid_payload(rng))),
    ("truncate", 8, lambda rng: (p := valid_payload(rng))[: rng.randrange(len(p))]),
    ("extend", 4, lambda rng: valid_payload(rng) + rng.randbytes(rng.randrange(1, 6))),
    ("splice", 10, splice),
    ("length", 15, lambda rng: tamper_length(rng, valid_payload(rng))),
    ("nest", 4, nest_bomb),
    ("huge", 4, huge_claim),
    ("big", 0.1, big_payload),
]
_NAMES = [k[0] for k in KINDS]
_WEIGHTS = [k[1] for k in KINDS]
_MAKERS = {k[0]: k[2] for k in KINDS}


def make_input(seed: str, k: int) -> tuple[str, bytes]:
    """Input k of seed `seed`: (kind, payload)."""
    rng = random.Random(f"{seed}:{k}")
    kind = rng.choices(_NAMES, _WEIGHTS)[0]
    return kind, _MAKERS[kind](rng)


# ---------------------------------------------------------------- the property


def _short(x: Any) -> str:
    """A repr for reports that survives absurdly deep values."""
    try:
        text = repr(x)
    except RecursionError:
        return f"<{type(x).__name__} too deep to print>"
    return text if len(text) <= 300 else text[:300] + "..."


def check(payload: bytes) -> str | None:
    """The decoder property for one payload: None if it holds, else what went wrong."""
    return verdict(payload)[1]


def verdict(payload: bytes) -> tuple[bool, str | None]:
    """(whether the payload decoded to a message, the problem or None)."""
    try:
        msg = wire.decode(payload)
    except wire.DecodeError as e:
        text = str(e)
        if "byte" not in text and text != "empty payload" and "message type" not in text:
            return False, f"DecodeError without an offset: {text!r}"
        return False, None
    except Exception:  # noqa: BLE001 - anything else is exactly what we look for
        return False, "decode raised " + traceback.format_exc(limit=-3)
    return True, _check_accepted(payload, msg)


def _check_accepted(payload: bytes, msg: wire.Message) -> str | None:
    """The re-encoding properties of an accepted payload."""
    try:
        again = wire.encode(msg)
    except Exception:  # noqa: BLE001
        return f"accepted {_short(msg)} does not re-encode: " + traceback.format_exc(limit=-3)
    if len(again) > len(payload):
        return f"re-encoding grew: {len(payload)} -> {len(again)} bytes: {again.hex()}"
    try:
        msg2 = wire.decode(again)
        again2 = wire.encode(msg2)
    except Exception:  # noqa: BLE001
        return f"re-encoded {again.hex()} fails: " + traceback.format_exc(limit=-3)
    if msg2 != msg:
        return f"decode(encode(m)) != m: {_short(msg)} vs {_short(msg2)}"
    if again2 != again:
        return f"encode(decode) is not a fixpoint: {again.hex()} vs {again2.hex()}"
    return None


def count_lines(fn: Callable[[], Any]) -> tuple[int, float]:
    """(Python lines executed while running fn, in any module, CPU seconds)."""
    n = 0

    def local(frame: Any, event: str, arg: Any) -> Any:
        nonlocal n
        if event == "line":
            n += 1
        return local

    t0 = time.process_time()
    sys.settrace(local)
    try:
        fn()
    except wire.DecodeError:
        pass
    finally:
        sys.settrace(None)
    return n, time.process_time() - t0


def check_work(payload: bytes) -> str | None:
    """Linear work: Python lines run bounded per byte; CPU time far under budget."""
    lines, _ = count_lines(lambda: wire.decode(payload))
    limit = LINES_PER_BYTE * len(payload) + 200
    if lines > limit:
        return f"decoding {len(payload)} bytes ran {lines} Python lines (limit {limit})"
    t0 = time.process_time()
    try:
        wire.decode(payload)
    except wire.DecodeError:
        pass
    spent = time.process_time() - t0
    if spent > BIG_SECONDS * max(1.0, len(payload) / BIG):
        return f"decoding {len(payload)} bytes took {spent:.3f} s of CPU"
    return None


# ---------------------------------------------------------------- the campaign


@dataclass
class Stats(runner.Stats):
    """What a campaign did."""

    accepted: int = 0
    slowest: float = 0.0

    def details(self) -> list[str]:
        """The kinds of input run, how many decoded, and the slowest check."""
        return [
            *super().details(),
            f"accepted (decoded to a message): {self.accepted}",
            f"slowest check: {self.slowest * 1000:.1f} ms",
        ]


def run_one(seed: str, k: int, stats: Stats, out: Callable[[str], None]) -> None:
    """Make input k, check it, and record the outcome."""
    kind, payload = make_input(seed, k)
    t0 = time.perf_counter()
    try:
        accepted, problem = verdict(payload)
        spent = time.perf_counter() - t0
        if problem is None and kind == "big":
            problem = check_work(payload)
    except Exception:  # noqa: BLE001 - a harness error is reported, not fatal
        accepted, spent = False, 0.0
        problem = "harness error: " + traceback.format_exc(limit=-3)
    stats.kinds[kind] += 1
    stats.accepted += accepted
    stats.slowest = max(stats.slowest, spent)
    if problem is None:
        return
    shown = payload.hex() if len(payload) <= 256 else payload[:256].hex() + "..."
    text = f"FAILURE [replay {seed}:{k}] ({kind}) {problem}\n  payload: {shown}"
    stats.fail(f"{seed}:{k}", text, out, shown=20)


#: run(seed, *, seconds=None, max_inputs=None, start=0, out=print) -> Stats: a campaign.
run = runner.make_run(run_one, Stats, clock_every=256, progress=True)


def replay(spec: str) -> int:
    """Run one input verbosely; 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    kind, payload = make_input(seed, int(k))
    print(f"input {spec}: {kind}, {len(payload)} bytes")
    print(payload.hex() if len(payload) <= 4096 else payload[:4096].hex() + "...")
    try:
        print("decodes to:", _short(wire.decode(payload)))
    except wire.DecodeError as e:
        print("DecodeError:", e)
    except Exception:  # noqa: BLE001
        traceback.print_exc()
    problem = check(payload) or (check_work(payload) if kind == "big" else None)
    print("verdict:", problem or "ok")
    return 1 if problem else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    return runner.main(argv, __doc__, run, replay)


if __name__ == "__main__":
    sys.exit(main())
