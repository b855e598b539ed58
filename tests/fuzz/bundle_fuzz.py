"""Fuzzing the ROSBuzz bundle decoders (fieldkit.robot.bundle) with hostile input, seeded.

    python -m tests.fuzz.bundle_fuzz --seconds 60 --seed 1
    python -m tests.fuzz.bundle_fuzz --replay 1:12345      # one input, verbosely

Input k of seed S is made from `random.Random(f"{S}:{k}")`, so every input replays with
`--replay S:k`. Each input targets one decoder (`decode` of air bytes, `from_payload64` of
words, `unpack_bundle` of L1 bytes, `from_rf_data` of XBee RF data) with one of: a valid
bundle, random bytes, a mutation of a valid bundle (bit flips, interesting bytes, field
tampering: nwords, message lengths, zero lengths, message type, NaN/inf positions, padding
junk, a whole extra word of padding; truncation, extension, splices), or, for words, hostile
list elements (negative, > 64 bits, floats, None, bools) and containers.

The property, per input:

* the decoder returns or raises `BundleError` whose offset lies within the input; any other
  exception is a failure;
* an accepted input re-encodes to itself, except for what the format lets a decoder ignore:
  the 4 junk bytes of payload64 word 0 (re-encoded as zeros) and the RF sysid/msgid bytes;
* a valid input is accepted and decodes to the bundle it was made from.

Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import math
import random
import struct
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from fieldkit.robot import bundle as B

from . import runner

INTERESTING_BYTES = (0, 1, 2, 3, 7, 8, 0x7F, 0x80, 0xBE, 0xFE, 0xFF)
INTERESTING_U16 = (0, 1, 2, 3, 5, 6, 23, 24, 25, 29, 184, 185, 186, 190, 0xFF, 0x7FFF, 0xFFFF)
SPECIAL_DOUBLES = (math.nan, math.inf, -math.inf, -0.0, 1e308, 5e-324, 90.0, -180.0)
LAYERS = ("air", "words", "l1", "rf")

#: The spec's worked example (docs/bundle.md#worked-example): robot 7, BROADCAST "cmd"=22 + JOIN 3.
EXAMPLE = B.Bundle(
    7,
    (bytes.fromhex("00 03 0003 636d64 01 00000016"), bytes.fromhex("04 0003")),
    45.5,
    -73.6,
    10.0,
    number=1,
)


@dataclass
class Stats(runner.Stats):
    """What a campaign did."""

    accepted: int = 0

    def details(self) -> list[str]:
        """The kinds of input run and how many were accepted."""
        return [*super().details(), f"accepted: {self.accepted}"]


# ---------------------------------------------------------------- valid bundles


def random_messages(rng: random.Random) -> tuple[bytes, ...]:
    """Messages that fit one bundle: often none, often a full one, sizes biased to edges."""
    room = B.MAX_BUZZ_BYTES
    out = []
    for _ in range(rng.choice((0, 1, 1, 2, 3, 5, 10, 40))):
        if room < B.MSG_OVERHEAD + 1:
            break
        most = room - B.MSG_OVERHEAD
        n = min(most, rng.choice((1, 2, 3, most, rng.randint(1, most), rng.randint(1, 20))))
        out.append(rng.randbytes(n))
        room -= n + B.MSG_OVERHEAD
    return tuple(out)


def random_double(rng: random.Random) -> float:
    """A finite double: a coordinate, an edge value, or any finite bit pattern."""
    r = rng.random()
    if r < 0.5:
        return rng.uniform(-180.0, 180.0)
    if r < 0.7:
        return rng.choice((0.0, -0.0, 1e308, -1e308, 5e-324, 90.0, -90.0, 180.0))
    while True:
        (x,) = struct.unpack("<d", rng.randbytes(8))
        if math.isfinite(x):
            return x


def random_bundle(rng: random.Random) -> B.Bundle:
    """A valid Bundle with edge-biased fields."""
    return B.Bundle(
        rng.choice((0, 1, 7, 255, 256, 0xFFFF, rng.randrange(0x10000))),
        random_messages(rng),
        random_double(rng),
        random_double(rng),
        random_double(rng),
        number=rng.choice((0, 1, 0xFFFF, rng.randrange(0x10000))),
        time_ns=rng.choice((0, 1 << 63, (1 << 64) - 1, rng.getrandbits(64))),
    )


def serialize(layer: str, b: B.Bundle) -> Any:
    """The input of `layer`'s decoder for bundle `b`."""
    if layer == "air":
        return B.encode(b)
    if layer == "words":
        return B.to_payload64(b)
    if layer == "l1":
        return B.pack_bundle(b.robot, b.messages)
    return B.to_rf_data(b)


# ---------------------------------------------------------------- mutations


def _air_field(offset: int) -> int:
    """The air byte holding byte `offset` of the payload64 memory image."""
    return offset - offset % 8 + 7 - offset % 8


def mutate_bytes(
    rng: random.Random, data: bytes, layer: str, original: B.Bundle
) -> tuple[str, bytes]:
    """(kind, mutated data) of `original` serialized for `layer`."""
    buf = bytearray(data)
    base = {"air": 0, "rf": B.RF_PREFIX, "l1": 0}[layer]

    def put_u16(mem: int, value: int) -> None:
        """Write a little-endian u16 at memory offset `mem` of the payload64 image (or L1)."""
        for k, byte in enumerate(value.to_bytes(2, "little")):
            m = mem + k
            pos = m if layer == "l1" else base + _air_field(m)
            if pos < len(buf):
                buf[pos] = byte

    body = 0 if layer == "l1" else 8 * B.HEADER_WORDS  # where the L1 bundle starts
    r = rng.random()
    if r < 0.2:
        for _ in range(rng.randint(1, 4)):
            if buf:
                buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
        return "flip", bytes(buf)
    if r < 0.3:
        for _ in range(rng.randint(1, 3)):
            if buf:
                buf[rng.randrange(len(buf))] = rng.choice(INTERESTING_BYTES)
        return "byte", bytes(buf)
    if r < 0.4:
        put_u16(body, rng.choice(INTERESTING_U16))
        return "nwords", bytes(buf)
    if r < 0.55:
        # A message length prefix (or any u16 slot in the bundle body), set to an edge value.
        size = len(buf) - base - body
        if size > 4:
            put_u16(body + rng.randrange(4, size - 1), rng.choice(INTERESTING_U16))
        return "length", bytes(buf)
    if r < 0.6 and layer != "l1":
        i = rng.randrange(3)
        x = rng.choice(SPECIAL_DOUBLES)
        bits = struct.pack(">d", x)
        pos = base + 8 * (2 + i)
        buf[pos : pos + 8] = bits
        return "position", bytes(buf)
    if r < 0.65 and layer != "l1":
        put_u16(0, rng.choice((0, 1, 3, 0xFFFF, 0x102)))
        if rng.random() < 0.3:
            buf[base : base + 8] = bytes(7) + b"\x01"  # exactly payload64[0] == 1
        return "type", bytes(buf)
    if r < 0.72:
        cut = rng.choice((rng.randrange(len(buf) + 1), len(buf) - 8, len(buf) - 1, 8, 0))
        return "truncate", bytes(buf[: max(cut, 0)])
    if r < 0.8:
        extra = rng.choice((bytes(8), bytes(rng.randint(1, 7)), rng.randbytes(rng.randint(1, 40))))
        return "extend", bytes(buf) + extra
    if r < 0.85:
        other = serialize(layer, random_bundle(rng))
        i, j = rng.randrange(len(buf) + 1), rng.randrange(len(other) + 1)
        return "splice", bytes(buf[:i]) + other[j:]
    if r < 0.9:
        # One more word of zeros, announced in nwords: a whole word of padding.
        words = (len(buf) - base) // 8 - (0 if layer == "l1" else B.HEADER_WORDS)
        buf += bytes(8)
        put_u16(body, words + rng.choice((1, 1, 2)))
        return "grow", bytes(buf)
    # Junk in the padding after the last message: a stray byte, or a hidden message.
    end = B.block_size(original.messages)
    pad = -end % 8
    if pad:
        if pad >= 2 and rng.random() < 0.5:
            put_u16(body + end, rng.randint(1, pad))
        else:
            put_u16(body + end + rng.randrange(pad), rng.randrange(1, 256))
    return "padding", bytes(buf)


def hostile_words(rng: random.Random, words: list[int]) -> tuple[str, Any]:
    """(kind, words) with a non-u64 element or the wrong container."""
    bad: Any = rng.choice(
        (-1, 1 << 64, 1 << 200, 1.5, math.nan, None, True, "2", b"\x02", [2], 2**63 + 0.0)
    )
    out: Any = list(words)
    if rng.random() < 0.1:
        return "container", rng.choice((tuple(words), iter(words), "words", None, b"", 7))
    out[rng.randrange(len(out))] = bad
    return "element", out


def make_input(seed: str, k: int) -> tuple[str, str, Any, B.Bundle | None]:
    """Input k: (layer, kind, data, the valid bundle it is if it is one unchanged)."""
    rng = random.Random(f"{seed}:{k}")
    layer = rng.choice(LAYERS)
    r = rng.random()
    original = EXAMPLE if rng.random() < 0.05 else random_bundle(rng)
    data = serialize(layer, original)
    if r < 0.15:
        return layer, "valid", data, original
    if r < 0.25:
        if layer == "words":
            n = rng.choice((0, 5, 6, 7, 29, 30, rng.randrange(40)))
            return layer, "random", [rng.getrandbits(64) for _ in range(n)], None
        n = rng.choice((0, 7, 8, 48, 232, 233, 8 * rng.randrange(40), rng.randrange(300)))
        blob = rng.randbytes(n)
        if layer == "rf" and rng.random() < 0.5:
            blob = b"S" + blob
        return layer, "random", blob, None
    if layer == "words":
        if rng.random() < 0.25:
            kind, words = hostile_words(rng, data)
            return layer, kind, words, None
        air = B.encode(original)
        kind, air = mutate_bytes(rng, air, "air", original)
        air = air[: len(air) - len(air) % 8]
        return layer, kind, list(struct.unpack(f">{len(air) // 8}Q", air)), None
    kind, blob = mutate_bytes(rng, data, layer, original)
    return layer, kind, blob, None


# ---------------------------------------------------------------- the property


def _zero_junk(words: list[int]) -> list[int]:
    return [words[0] & 0xFFFFFFFF, *words[1:]]


def check(layer: str, data: Any, original: B.Bundle | None) -> tuple[bool, str | None]:
    """(accepted, failure description or None) of one input."""
    size = len(data) if isinstance(data, bytes | list | tuple) else 0
    limit = 8 * size if layer == "words" else size
    try:
        if layer == "air":
            got: Any = B.decode(data)
        elif layer == "words":
            got = B.from_payload64(data)
        elif layer == "l1":
            got = B.unpack_bundle(data)
        else:
            got = B.from_rf_data(data)
    except B.BundleError as e:
        if not (isinstance(e.offset, int) and 0 <= e.offset <= max(limit, 0)):
            return False, f"offset {e.offset} outside the {limit}-byte input: {e}"
        if original is not None:
            return False, f"valid input rejected: {e}"
        return False, None
    except Exception:
        return False, "unexpected exception:\n" + traceback.format_exc()
    # Accepted: the re-encoding gives the input back, up to what the decoder may ignore.
    try:
        if layer == "l1":
            robot, messages = got
            same = B.pack_bundle(robot, messages) == bytes(data)
            decoded = B.Bundle(robot, messages, 0.0, 0.0, 0.0)
        else:
            words = B.to_payload64(got)
            if layer == "air":
                same = words == _zero_junk(list(struct.unpack(f">{len(data) // 8}Q", data)))
            elif layer == "words":
                same = words == _zero_junk(data)
            else:
                air = data[B.RF_PREFIX :]
                same = words == _zero_junk(list(struct.unpack(f">{len(air) // 8}Q", air)))
            decoded = got
    except Exception:
        return True, "accepted input does not re-encode:\n" + traceback.format_exc()
    if not same:
        return True, f"accepted input re-encodes differently: {got}"
    if original is not None:
        want = original if layer != "l1" else B.Bundle(original.robot, original.messages, 0, 0, 0)
        if decoded != want:
            return True, f"valid input decodes to {decoded}, not {want}"
    return True, None


def run_one(seed: str, k: int, stats: Stats, out: Callable[[str], None]) -> None:
    """Make input k, check it, and record the outcome."""
    layer, kind, data, original = make_input(seed, k)
    accepted, failure = check(layer, data, original)
    stats.kinds[f"{layer}/{kind}"] += 1
    stats.accepted += accepted
    if failure is not None:
        stats.fail(f"{seed}:{k}", f"FAIL {seed}:{k} ({layer}/{kind}): {failure}", out)


#: run(seed, *, seconds=None, max_inputs=None, start=0, out=print) -> Stats: a campaign.
run = runner.make_run(run_one, Stats, clock_every=256)


def replay(spec: str) -> int:
    """Run input SEED:K verbosely; exit status 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    layer, kind, data, original = make_input(seed, int(k))
    print(f"layer {layer}, kind {kind}, valid {original is not None}")
    print(data.hex(" ") if isinstance(data, bytes) else repr(data))
    accepted, failure = check(layer, data, original)
    print("accepted" if accepted else "rejected", "-", failure or "ok")
    return 1 if failure else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    return runner.main(argv, __doc__, run, replay)


if __name__ == "__main__":
    sys.exit(main())
