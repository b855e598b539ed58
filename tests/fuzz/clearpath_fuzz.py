"""Fuzzing the Clearpath MCU de-framer and the Husky core with hostile bytes: a seeded campaign.

    python -m tests.fuzz.clearpath_fuzz --seconds 60 --seed 1
    python -m tests.fuzz.clearpath_fuzz --count 500000 --seed 1
    python -m tests.fuzz.clearpath_fuzz --replay 1:12345      # one input, verbosely

Input k of seed S is made from `random.Random(f"{S}:{k}")`, so every input replays with
`--replay S:k`. Two targets:

* ``deframe``: a byte stream of valid frames (every message kind the MCU or the host sends,
  random types and payloads, flags and timestamps), mutated frames (bit flips, truncation,
  broken CRC, LEN and ~LEN, STX, stray SOH, splices) and line noise rich in 0xAA and 0x55,
  fed to a `FrameReader` in random pieces. Property: no exception; the frames and every
  counter equal those of `reference_deframe`, an independent byte-at-a-time transcription of
  the de-framing rules (fieldkit/vehicle/clearpath/frame.py, with a bitwise CRC) on the whole
  stream; the reader never holds more than one maximal frame.
* ``core``: a `HuskyCore` fed, in random pieces and between ticks of a fake clock, MCU
  streams of data frames with ordinary to hostile values (huge, negative and wrong-length
  counts, every safety flag, acknowledgements of anything with any result) among noise, and
  GPS bytes, while orders (goto, hold, arm, rtl...) come in. Property: no exception; line
  noise only costs counters (the good frames behind it are all handled); the telemetry stays
  sane: coordinates on the Earth or None, finite heading and speeds, battery 0..100 % or None;
  every frame the core writes parses back and asks for an acknowledgement; the wheel speeds
  it sends stay within the profile's speed.

Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import collections
import math
import random
import struct
import sys
import traceback
from collections.abc import Callable

from fieldkit.robot.profiles import load_profile
from fieldkit.vehicle.clearpath import messages as M
from fieldkit.vehicle.clearpath.core import HuskyCore
from fieldkit.vehicle.clearpath.frame import (
    MAX_FRAME,
    MAX_PAYLOAD,
    Frame,
    FrameReader,
    parse_frame,
)

from . import runner

TARGETS = ("deframe", "core")
INTERESTING = (0x00, 0x01, 0x0D, 0x55, 0x7F, 0x80, 0xAA, 0xF2, 0xFE, 0xFF)
HUSKY = load_profile("husky")


class FakeClock:
    """A clock the fuzzer moves by hand."""

    def __init__(self, now: float = 100.0) -> None:
        self.now = now

    def __call__(self) -> float:
        """The current fake time."""
        return self.now


# ---------------------------------------------------------------- the reference de-framer


def _crc_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE, the spec's bitwise form (not the codec's table)."""
    crc = 0xFFFF
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def reference_deframe(stream: bytes) -> tuple[list[bytes], collections.Counter[str], int]:
    """The frames (as bytes), counters and bytes left pending of a whole stream, by the
    rules, one candidate at a time: a bad candidate costs its SOH, then the scan goes on."""
    stats: collections.Counter[str] = collections.Counter()
    out: list[bytes] = []
    n = len(stream)
    p = 0
    while p < n:
        if stream[p] != 0xAA:
            stats["garbage_bytes"] += 1
            p += 1
            continue
        if n - p < 3:
            break
        length = stream[p + 1]
        if stream[p + 2] != 0xFF - length or not 14 <= length + 3 <= 256:
            why = "bad_length"
        elif n - p < 12:
            break
        elif stream[p + 11] != 0x55:
            why = "bad_stx"
        elif n - p < length + 3:
            break
        else:
            frame = stream[p : p + length + 3]
            if _crc_bitwise(frame[:-2]) == frame[-2] + 256 * frame[-1]:
                out.append(frame)
                stats["frames"] += 1
                p += length + 3
                continue
            why = "bad_crc"
        stats[why] += 1
        stats["bad_frames"] += 1
        stats["garbage_bytes"] += 1
        p += 1
    return out, stats, n - p


# ---------------------------------------------------------------- stream generation


def _s16(rng: random.Random) -> int:
    return (
        rng.choice((0, 1, -1, 32767, -32768, 500))
        if rng.random() < 0.3
        else rng.randrange(-32768, 32768)
    )


def data_frame(rng: random.Random) -> Frame:
    """A data frame from the MCU: any kind the core reads, values ordinary to hostile, or a
    wrong layout, or an acknowledgement."""
    ts = rng.getrandbits(32)
    r = rng.random()
    if r < 0.15:
        n = rng.choice((0, 1, 2, 2, 2, 4, 40))
        travel = [
            rng.choice((0, 2**31 - 1, -(2**31)))
            if rng.random() < 0.2
            else rng.randrange(-(10**6), 10**6)
            for _ in range(n)
        ]  # noqa: E501
        body = bytes((n,)) + struct.pack(f"<{n}i{n}h", *travel, *(_s16(rng) for _ in range(n)))
        return Frame(M.MsgType.ENCODERS, body, 0, ts)
    if r < 0.25:
        groups = b"".join(
            bytes((k,)) + struct.pack(f"<{k}h", *(_s16(rng) for _ in range(k)))
            for k in (rng.randrange(5), rng.randrange(5), rng.randrange(5))
        )
        return Frame(M.MsgType.SYSTEM_STATUS, struct.pack("<I", ts) + groups, 0, ts)
    if r < 0.35:
        n = rng.randrange(4)
        body = bytes((n,)) + struct.pack(f"<{2 * n}h", *(_s16(rng) for _ in range(2 * n)))
        return Frame(M.MsgType.POWER_SYSTEM, body + rng.randbytes(n), 0, ts)
    if r < 0.45:
        return M.safety_status(
            rng.getrandbits(16) if rng.random() < 0.5 else rng.choice((0, 8, 1, 2, 16)), ts
        )
    if r < 0.5:
        model = rng.randbytes(rng.randrange(20))
        body = (
            bytes((len(model),))
            + model
            + struct.pack("<BI", rng.randrange(256), rng.getrandbits(32))
        )
        return Frame(M.MsgType.PLATFORM_INFO, body, 0, ts)
    if r < 0.55:
        return Frame(
            M.MsgType.ORIENTATION, struct.pack("<3h", _s16(rng), _s16(rng), _s16(rng)), 0, ts
        )
    if r < 0.75:
        kind = rng.choice(
            (
                0x0200,
                0x0210,
                0x0211,
                0x4800,
                0x4010,
                0x4004,
                0x4005,
                0x4001,
                0x4600,
                rng.randrange(0x8000),
            )
        )  # noqa: E501
        result = rng.choice((0, 0, 0, 1, 2, 8, 0x40, rng.getrandbits(16)))
        return M.ack(kind, result, ts)
    if r < 0.9:  # a known kind with a payload of any length
        kind = rng.choice(tuple(t for t in M.MsgType if t >= 0x8000))
        return Frame(kind, rng.randbytes(rng.randrange(30)), rng.randrange(256), ts)
    return Frame(
        rng.randrange(0x10000),
        rng.randbytes(rng.randrange(MAX_PAYLOAD + 1)),
        rng.randrange(256),
        ts,
    )


def any_frame(rng: random.Random) -> bytes:
    """A valid frame of any kind (host or MCU side), encoded."""
    if rng.random() < 0.6:
        return data_frame(rng).encode()
    r = rng.random()
    if r < 0.5:
        f = M.set_diff_speed(
            rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(0, 6), rng.uniform(0, 6)
        )
    elif r < 0.8:
        f = M.request(rng.choice(tuple(M.MsgType)), rng.choice((0, 1, 10, 0xFFFF)))
    else:
        f = Frame(rng.randrange(0x10000), rng.randbytes(rng.choice((0, 1, 2, 8, MAX_PAYLOAD))))
    return f.encode()


def mutate(rng: random.Random, frame: bytes) -> tuple[str, bytes]:
    """(kind, a damaged frame)."""
    buf = bytearray(frame)
    r = rng.random()
    if r < 0.2:
        for _ in range(rng.randint(1, 3)):
            buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
        return "flip", bytes(buf)
    if r < 0.35:
        return "truncate", bytes(buf[: rng.randrange(1, len(buf))])
    if r < 0.45:
        buf[-1 - rng.randrange(2)] ^= rng.randrange(1, 256)
        return "crc", bytes(buf)
    if r < 0.6:
        length = rng.choice((0, 1, 10, 11, 253, 254, 255, rng.randrange(256)))
        buf[1] = length
        buf[2] = (0xFF - length) if rng.random() < 0.6 else rng.randrange(256)
        return "length", bytes(buf)
    if r < 0.7:
        buf[11] = rng.randrange(256)
        return "stx", bytes(buf)
    if r < 0.8:
        buf.insert(rng.randrange(len(buf) + 1), 0xAA)
        return "stray", bytes(buf)
    if r < 0.9:
        buf[rng.randrange(len(buf))] = rng.choice(INTERESTING)
        return "byte", bytes(buf)
    other = any_frame(rng)
    i, j = rng.randrange(len(buf) + 1), rng.randrange(len(other) + 1)
    return "splice", bytes(buf[:i]) + other[j:]


def noise(rng: random.Random) -> bytes:
    """Line noise, often rich in SOH, STX and plausible LEN/~LEN pairs."""
    junk = rng.randbytes(rng.randrange(1, 40))
    r = rng.random()
    if r < 0.4:
        junk = bytes(rng.choice(INTERESTING) for _ in junk)
    elif r < 0.6:
        length = rng.randrange(11, 254)
        junk = bytes((0xAA, length, 0xFF - length)) + junk
    return junk


def stream_input(
    rng: random.Random, frames: Callable[[random.Random], bytes]
) -> tuple[str, bytes, list[bytes]]:
    """(kind, stream, the valid frames put in it)."""
    if rng.random() < 0.05:
        return "random", rng.randbytes(rng.randrange(600)), []
    parts = []
    good = []
    kinds = set()
    for _ in range(rng.randint(1, 8)):
        r = rng.random()
        if r < 0.5:
            f = frames(rng)
            parts.append(f)
            good.append(f)
            kinds.add("valid")
        elif r < 0.75:
            kind, bad = mutate(rng, frames(rng))
            parts.append(bad)
            kinds.add(kind)
        else:
            parts.append(noise(rng))
            kinds.add("noise")
    return "+".join(sorted(kinds)), b"".join(parts), good


def split(rng: random.Random, stream: bytes) -> list[bytes]:
    """The stream in random pieces (single bytes, small, large, or whole)."""
    r = rng.random()
    if r < 0.15 or not stream:
        return [stream]
    if r < 0.3:
        return [stream[i : i + 1] for i in range(len(stream))]
    cuts = sorted(rng.randrange(len(stream) + 1) for _ in range(rng.randrange(1, 12)))
    return [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]


# ---------------------------------------------------------------- the de-framer


def check_deframe(rng: random.Random, stream: bytes) -> str | None:
    """Failure description, or None."""
    reader = FrameReader()
    got: list[bytes] = []
    for piece in split(rng, stream):
        got += [f.encode() for f in reader.feed(piece)]
        if reader.pending > MAX_FRAME:
            return f"reader holds {reader.pending} bytes > {MAX_FRAME}"
    want, stats, left = reference_deframe(stream)
    if got != want:
        return f"frames differ: got {len(got)}, reference {len(want)}"
    mine = {k: v for k, v in reader.stats.items() if v}
    theirs = {k: v for k, v in stats.items() if v}
    if mine != theirs:
        return f"counters differ: {mine} vs reference {theirs}"
    if reader.pending != left:
        return f"{reader.pending} bytes pending, reference {left}"
    return None


# ---------------------------------------------------------------- the core


def _sane(core: HuskyCore) -> str | None:
    t = core.telemetry
    if (t.lat is None) != (t.lon is None):
        return "half a position"
    if t.lat is not None and not (-90 <= t.lat <= 90 and -180 <= t.lon <= 180):  # type: ignore[operator]
        return f"position off the Earth: {t.lat}, {t.lon}"
    for name in (
        "heading_deg",
        "yaw_rad",
        "ground_speed_mps",
        "vel_north_mps",
        "vel_east_mps",
        "battery_voltage_v",
        "battery_current_a",
    ):  # noqa: E501
        v = getattr(t, name)
        if v is not None and not math.isfinite(v):
            return f"{name} = {v}"
    if t.heading_deg is not None and not 0 <= t.heading_deg < 360:
        return f"heading {t.heading_deg}"
    if t.battery_percent is not None and not 0 <= t.battery_percent <= 100:
        return f"battery {t.battery_percent} %"
    return None


def check_core(rng: random.Random, stream: bytes, good: list[bytes]) -> str | None:
    """Failure description, or None."""
    clock = FakeClock()
    core = HuskyCore(profile=HUSKY, clock=clock)
    # A start-up: the MCU heard, armed, a GPS fix, so that the orders do something.
    core.receive_data(M.ack(0x4800).encode() + M.encoders((0.0, 0.0), (0.0, 0.0)).encode())
    arm = core.arm()
    core.receive_data(M.ack(0x0211).encode() + M.ack(0x0210).encode())
    core.receive_gps(b"$GPGGA,123519,4530.29400,N,07336.79800,W,1,08,0.9,45.4,M,46.9,M,,*4B\r\n")
    handled = 0
    pieces = split(rng, stream)
    for piece in pieces:
        handled += core.receive_data(piece)
        if rng.random() < 0.3:
            core.receive_gps(rng.randbytes(rng.randrange(60)))
        r = rng.random()
        if r < 0.1:
            core.goto(45.5 + rng.uniform(-1e-4, 1e-4), -73.6 + rng.uniform(-1e-4, 1e-4), 0.0)
        elif r < 0.13:
            getattr(core, rng.choice(("hold", "land", "rtl", "arm", "disarm", "cancel_all")))()
        if rng.random() < 0.25:  # ticks between some pieces (a bytewise split has hundreds)
            clock.now += rng.choice((0.0, 0.01, 0.1, 0.1, 0.5, 4.0))
            core.tick()
        problem = _sane(core)
        if problem:
            return problem
    clock.now += 0.1
    core.tick()
    core.drain_events()
    if not arm.ok:
        return f"arm at start-up: {arm.error}"
    # Line noise only costs counters: the core handled every frame the reference finds, and
    # those are all the good frames put in, unless noise made a frame of its own (a CRC
    # collision, which may swallow what follows) or a candidate still waits at the end.
    survivors, _, left = reference_deframe(stream)
    if handled != len(survivors):
        return f"handled {handled} frames, the stream holds {len(survivors)}"
    spurious = [f for f in survivors if f not in good]
    if not spurious and not left and survivors != good:
        return f"{len(good)} good frames put in, {len(survivors)} came out"
    for f in FrameReader().feed(core.data_to_send()):
        if f.flags != 0:
            return f"sent {M.name_of(f.type)} without asking for an ack"
        if f.type == M.MsgType.SET_DIFF_SPEED:
            s = M.decode_command(f)
            assert isinstance(s, M.DiffSpeeds)
            top = HUSKY.kinematics.max_speed_mps + 1e-9
            if abs(s.left) > top or abs(s.right) > top:
                return f"wheel speeds {s.left}, {s.right} past the profile's"
    return None


# ---------------------------------------------------------------- the campaign


def run_one(seed: str, k: int) -> tuple[str, str | None]:
    """(kind, failure or None) of input k."""
    rng = random.Random(f"{seed}:{k}")
    target = rng.choices(TARGETS, weights=(3, 1))[0]
    try:
        if target == "deframe":
            kind, stream, _ = stream_input(rng, any_frame)
            return f"deframe/{kind}", check_deframe(rng, stream)
        kind, stream, good = stream_input(rng, lambda r: data_frame(r).encode())
        return f"core/{kind}", check_core(rng, stream, good)
    except Exception:
        return target, "unexpected exception:\n" + traceback.format_exc()


def record(seed: str, k: int, stats: runner.Stats, out: Callable[[str], None]) -> None:
    """Run input k and record the outcome."""
    kind, failure = run_one(seed, k)
    stats.kinds[kind.split("/")[0]] += 1
    if failure is not None:
        stats.fail(f"{seed}:{k}", f"FAIL {seed}:{k} ({kind}): {failure}", out, shown=20)


#: run(seed, *, seconds=None, max_inputs=None, start=0, out=print) -> Stats: a campaign.
run = runner.make_run(record, runner.Stats, clock_every=64)


def replay(spec: str) -> int:
    """Run input SEED:K verbosely; exit status 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    kind, failure = run_one(seed, int(k))
    print(f"kind {kind}:", failure or "ok")
    return 1 if failure else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point: `--count N` (exactly N inputs) or `--seconds S`."""
    return runner.counted_main(argv, __doc__, run, replay, runner.Stats, slice_inputs=50_000)


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["check_core", "check_deframe", "parse_frame", "reference_deframe", "run"]
