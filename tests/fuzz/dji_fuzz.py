"""Fuzzing the DJI OPEN protocol input: the de-framer, the host core, the simulated M100.

    python -m tests.fuzz.dji_fuzz --seconds 600 --seed 1 --max-inputs 500000
    python -m tests.fuzz.dji_fuzz --replay 1:12345       # one input, verbosely

Input k of seed S is made from `random.Random(f"{S}:{k}")`, so every input replays with
`--replay S:k`. Three targets:

* ``deframe``: a byte stream of valid frames (commands, ACKs, broadcasts, header-only,
  AES-encrypted with the key or another), mutated frames (bit flips, truncation, broken
  CRC16 or CRC32, bad lengths and versions, stray 0xAA, splices) and noise, fed to a
  `FrameReader` in random pieces. Property: no exception; the frames and every counter
  equal those of `reference_deframe`, an independent transcription of the spec's §3.6
  rules on the whole stream (it checks each candidate with `frame.decode`, the one-frame
  path, where the reader has its own inlined scan); no more than one frame's bytes wait;
  a stream of intact frames only gives them all back, in order.
* ``core``: a `DjiCore` brought through version, activation and control authority by
  answering its own frames, then fed hostile traffic (valid pushes with hostile values:
  NaN and infinite floats, out-of-range positions, any status and RC value, flags that
  promise absent items; ACKs for any session and SEQ with any code, the outstanding one
  included; lost-control pushes; noise and mutated frames), interleaved with clock steps,
  ticks and orders. Property: nothing raises, no handler fails (`link_errors` stays 0:
  line noise only costs counters), the telemetry stays sane (coordinates on Earth or None,
  finite heights, yaw and speeds or None, battery 0..100 % or None, RC 1000..2000), and
  what it sends is made of whole, valid frames.
* ``sim``: the simulated flight controller fed hostile host traffic (valid commands with
  any value, encrypted under the wrong key, noise, mutations). Property: nothing raises
  and its output is whole, valid frames.

Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import math
import random
import struct
import sys
import traceback
from collections import Counter
from collections.abc import Callable

from fieldkit.robot.profiles import load_profile
from fieldkit.vehicle.dji import messages as M
from fieldkit.vehicle.dji.core import DjiCore
from fieldkit.vehicle.dji.crypto import FrameCipher
from fieldkit.vehicle.dji.frame import (
    HEADER_LEN,
    MAX_FRAME_LEN,
    Frame,
    FrameError,
    FrameReader,
    ack_frame,
    command_frame,
    decode,
    encode,
    frame_length,
    header_problem,
)
from fieldkit.vehicle.sim.dji import TEST_APP_ID, TEST_APP_KEY, SimM100

from . import runner

TARGETS = ("deframe", "core", "sim")
KEY = FrameCipher.from_app_key(TEST_APP_KEY)
OTHER_KEY = FrameCipher.from_app_key("fe" * 32)
INTERESTING = (0x00, 0x01, 0x02, 0x03, 0x10, 0x1F, 0x20, 0x3F, 0xAA, 0xFE, 0xFF)
FLOATS = (0.0, -0.0, 1.0, -1.0, 1e-30, 3.4e38, -3.4e38, math.nan, math.inf, -math.inf)
PROFILE = load_profile("m100")


class FakeClock:
    """A clock the fuzzer moves by hand."""

    def __init__(self, now: float = 100.0) -> None:
        self.now = now

    def __call__(self) -> float:
        """The current fake time."""
        return self.now


# ---------------------------------------------------------------- the reference de-framer


def reference_deframe(
    stream: bytes, cipher: FrameCipher | None
) -> tuple[list[Frame], Counter[str], int]:
    """The frames, counters and pending bytes of a whole stream, by the rules of §3.6: slide
    one byte past anything that is not a valid header, wait for a whole frame, and after a
    CRC32 failure drop only its first byte."""
    stats: Counter[str] = Counter()
    out: list[Frame] = []
    n = len(stream)
    p = 0
    in_noise = False

    def noise(count: int) -> None:
        nonlocal in_noise
        stats["garbage_bytes"] += count
        if not in_noise:
            in_noise = True
            stats["bad_frames"] += 1

    while p < n:
        if n - p < HEADER_LEN:
            if stream[p] != 0xAA:
                noise(1)
                p += 1
                continue
            break  # a possible header, not complete yet
        if header_problem(stream[p : p + HEADER_LEN]) is not None:
            noise(1)
            p += 1
            continue
        length = frame_length(stream[p : p + HEADER_LEN])
        if n - p < length:
            break
        try:
            frame = decode(stream[p : p + length], cipher)
        except FrameError as e:
            if e.offset == length - 4 and "CRC32" in e.what:
                stats["crc_errors"] += 1
                noise(1)
                p += 1
                continue
            # A good frame whose data cannot be used (encryption layout).
            stats["undecryptable"] += 1
            stats["bad_frames"] += 1
            in_noise = False
            p += length
            continue
        in_noise = False
        p += length
        if not frame.readable:
            stats["undecryptable"] += 1
            stats["bad_frames"] += 1
            continue
        stats["frames"] += 1
        out.append(frame)
    return out, stats, n - p


# ---------------------------------------------------------------- frames


def _float(rng: random.Random) -> float:
    return rng.choice(FLOATS) if rng.random() < 0.3 else rng.uniform(-1e4, 1e4)


def _i16(rng: random.Random) -> int:
    return (
        rng.choice((0, 1, -1, 8000, -8000, 4000, 32767, -32768))
        if rng.random() < 0.5
        else (rng.randrange(-32768, 32768))
    )


def random_broadcast(rng: random.Random) -> bytes:
    """A broadcast value with hostile items (and now and then a flag that lies)."""
    b = M.Broadcast()
    for name in M.ITEMS:
        if rng.random() < 0.5:
            continue
        if name == "timestamp":
            item: tuple[float | int, ...] = (
                rng.getrandbits(32),
                rng.getrandbits(32),
                rng.randrange(256),
            )
        elif name == "quaternion":
            item = tuple(_float(rng) for _ in range(4))
        elif name in ("acceleration", "angular_rate"):
            item = tuple(_float(rng) for _ in range(3))
        elif name in ("velocity", "gimbal"):
            item = (_float(rng), _float(rng), _float(rng), rng.randrange(256))
        elif name == "position":
            if rng.random() < 0.4:
                lat, lon = math.radians(rng.uniform(-90, 90)), math.radians(rng.uniform(-180, 180))
            else:
                lat, lon = _float(rng), _float(rng)
            item = (lat, lon, _float(rng), _float(rng), rng.randrange(256))
        elif name == "magnetometer":
            item = tuple(_i16(rng) for _ in range(3))
        elif name == "rc":
            item = tuple(_i16(rng) for _ in range(6))
        elif name in ("flight_status", "battery"):
            item = (rng.choice((0, 1, 2, 3, 4, 5, 6, 100, 101, 255)),)
        else:
            item = (rng.randrange(256), rng.randrange(256))
        setattr(b, name, item)
    value = b.encode()
    r = rng.random()
    if r < 0.1:
        return value[: rng.randrange(len(value) + 1)]  # the flag promises more
    if r < 0.15:
        return rng.getrandbits(16).to_bytes(2, "little") + rng.randbytes(rng.randrange(130))
    return value


def random_frame(rng: random.Random, cipher: FrameCipher | None = None) -> bytes:
    """A valid frame of any kind the line may carry (encrypted when `cipher`)."""
    session = rng.choice((0, 0, 1, 2, 2, 3, 31))
    seq = rng.getrandbits(16)
    r = rng.random()
    if r < 0.35:
        return command_frame(0, seq, *M.PUSH_BROADCAST, random_broadcast(rng), cipher=cipher)
    if r < 0.45:
        value = bytes((rng.choice((4, 0, 255)),)) if rng.random() < 0.9 else b""
        return command_frame(session, seq, *M.PUSH_LOST_CONTROL, value, cipher=cipher)
    if r < 0.7:
        code = rng.choice((0, 1, 2, 3, 4, 5, 6, 8, 0xC9, 0xFF00, 0xFF01, rng.getrandbits(16)))
        value = code.to_bytes(2, "little") + rng.randbytes(rng.choice((0, 0, 1, 60)))
        if rng.random() < 0.1:
            value = M.version_ack_value(code) if rng.random() < 0.7 else rng.randbytes(40)
        return ack_frame(session, seq, value[: rng.choice((0, 1, 2, len(value)))], cipher=cipher)
    if r < 0.8:
        return encode(session, rng.random() < 0.5, seq, b"")
    if r < 0.9:
        key = rng.choice((M.CMD_MOVEMENT, M.CMD_TASK, M.CMD_CONTROL, M.CMD_ARM, M.PUSH_FROM_MOBILE))
        return command_frame(session, seq, *key, rng.randbytes(rng.randrange(40)), cipher=cipher)
    size = rng.choice((1, 2, 16, 100, rng.randrange(0, 1008)))
    return encode(session, rng.random() < 0.5, seq, rng.randbytes(size))


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
    if r < 0.45 and len(buf) > HEADER_LEN:
        buf[-1 - rng.randrange(4)] ^= rng.randrange(1, 256)
        return "crc32", bytes(buf)
    if r < 0.55:
        buf[10] ^= rng.randrange(1, 256)
        return "crc16", bytes(buf)
    if r < 0.7:
        # Header fields rewritten and the CRC16 fixed up: the header passes, the rest may not.
        length = rng.choice((12, 13, 15, 16, 17, MAX_FRAME_LEN, rng.randrange(1024)))
        buf[1] = length & 0xFF
        buf[2] = (length >> 8) & 3 | (rng.choice((0, 0, 0, 4)))
        buf[4] = rng.randrange(256) if rng.random() < 0.5 else buf[4]
        from fieldkit.vehicle.dji.crc import crc16

        c = crc16(bytes(buf[:10]))
        buf[10:12] = c.to_bytes(2, "little")
        return "header", bytes(buf)
    if r < 0.8:
        buf.insert(rng.randrange(len(buf) + 1), 0xAA)
        return "stray", bytes(buf)
    if r < 0.9:
        buf[rng.randrange(len(buf))] = rng.choice(INTERESTING)
        return "byte", bytes(buf)
    other = random_frame(rng)
    i, j = rng.randrange(len(buf) + 1), rng.randrange(len(other) + 1)
    return "splice", bytes(buf[:i]) + other[j:]


def stream_input(rng: random.Random) -> tuple[str, bytes, bool]:
    """(kinds, stream, clean: intact frames only)."""
    if rng.random() < 0.03:
        return "random", rng.randbytes(rng.randrange(1200)), False
    clean = rng.random() < 0.2
    parts: list[bytes] = []
    kinds: set[str] = set()
    for _ in range(rng.randint(1, 10)):
        r = rng.random()
        cipher = rng.choice((None, None, KEY, OTHER_KEY))
        if clean or r < 0.5:
            parts.append(random_frame(rng, cipher))
            kinds.add("valid" if cipher is not OTHER_KEY else "other-key")
        elif r < 0.8:
            kind, bad = mutate(rng, random_frame(rng, cipher))
            parts.append(bad)
            kinds.add(kind)
        else:
            junk = rng.randbytes(rng.randrange(1, 60))
            if rng.random() < 0.5:
                junk = bytes(rng.choice(INTERESTING) for _ in junk)
            parts.append(junk)
            kinds.add("noise")
    return "+".join(sorted(kinds)), b"".join(parts), clean


def split(rng: random.Random, stream: bytes) -> list[bytes]:
    """The stream in random pieces (single bytes, small, large, or whole)."""
    r = rng.random()
    if r < 0.2:
        return [stream]
    if r < 0.3:
        return [stream[i : i + 1] for i in range(len(stream))]
    cuts = sorted(rng.randrange(len(stream) + 1) for _ in range(rng.randrange(1, 12)))
    return [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]


# ---------------------------------------------------------------- deframe


def check_deframe(rng: random.Random, stream: bytes, clean: bool) -> str | None:
    """Failure description, or None."""
    cipher = rng.choice((None, KEY))
    reader = FrameReader(cipher)
    got: list[Frame] = []
    for piece in split(rng, stream):
        got += reader.feed(piece)
        if reader.pending >= MAX_FRAME_LEN:
            return f"reader holds {reader.pending} bytes"
    want, stats, pending = reference_deframe(stream, cipher)
    if got != want:
        return f"frames differ: got {len(got)}, reference {len(want)}"
    mine = {
        "frames": reader.frames,
        "bad_frames": reader.bad_frames,
        "garbage_bytes": reader.garbage_bytes,
        "crc_errors": reader.crc_errors,
        "undecryptable": reader.undecryptable,
    }
    mine = {k: v for k, v in mine.items() if v}
    theirs = {k: v for k, v in stats.items() if v}
    if mine != theirs:
        return f"counters differ: {mine} vs reference {theirs}"
    if reader.pending != pending:
        return f"pending {reader.pending}, reference {pending}"
    if clean and (reader.bad_frames - reader.undecryptable or reader.pending):
        return "a stream of intact frames cost bad frames"
    return None


# ---------------------------------------------------------------- core


def _answer(core: DjiCore, clock: FakeClock, value_for: Callable[[Frame], bytes | None]) -> None:
    """Answer every command the core has queued, as a flight controller would."""
    for _ in range(8):
        clock.now += 0.01
        core.tick()
        frames = FrameReader(KEY).feed(core.data_to_send())
        if not frames:
            return
        for f in frames:
            if f.session >= 1 and not f.ack:
                value = value_for(f)
                if value is not None:
                    core.receive_data(
                        ack_frame(f.session, f.seq, value, cipher=KEY if f.enc else None)
                    )


def connected_core(rng: random.Random) -> tuple[DjiCore, FakeClock]:
    """A core activated (and, mostly, in control) by answering its own frames."""
    clock = FakeClock()
    core = DjiCore(
        app_id=TEST_APP_ID,
        app_key=TEST_APP_KEY,
        profile=PROFILE,
        clock=clock,
        encrypt=rng.random() < 0.7,
    )

    def fc(f: Frame) -> bytes | None:
        key = (f.cmd_set, f.cmd_id)
        if key == M.CMD_GET_VERSION:
            return M.version_ack_value(0xFF01)
        if key == M.CMD_CONTROL:
            return (M.CONTROL_OBTAINED if f.value == b"\x01" else M.CONTROL_RELEASED).to_bytes(
                2, "little"
            )
        return b"\x00\x00"

    _answer(core, clock, fc)
    if rng.random() < 0.8:
        core.obtain_control()
        _answer(core, clock, fc)
    return core, clock


ORDERS: tuple[Callable[[DjiCore, random.Random], object], ...] = (
    lambda c, r: c.takeoff(r.choice((5.0, -1.0, math.nan, 1e9))),
    lambda c, r: c.goto(r.uniform(-90, 90), r.uniform(-180, 180), r.choice((5.0, 0.0, -3.0, 1e6))),
    lambda c, r: c.goto(r.choice((math.nan, 91.0, 45.5)), r.choice((math.inf, -73.6)), 5.0),
    lambda c, r: c.hold(),
    lambda c, r: c.land(),
    lambda c, r: c.rtl(),
    lambda c, r: c.arm(),
    lambda c, r: c.disarm(),
    lambda c, r: c.obtain_control(),
    lambda c, r: c.release_control(),
    lambda c, r: c.request_streams(r.choice((10.0, 0.0, -1.0, 1e9))),
    lambda c, r: c.cancel_all("fuzz"),
)


def _sane(core: DjiCore) -> str | None:
    t = core.telemetry
    if t.lat is not None and not -90.0 <= t.lat <= 90.0:
        return f"latitude {t.lat}"
    if t.lon is not None and not -180.0 <= t.lon <= 180.0:
        return f"longitude {t.lon}"
    for name in ("alt_rel_m", "alt_msl_m", "yaw_rad", "heading_deg", "vel_north_mps",
                 "vel_east_mps", "vel_down_mps", "ground_speed_mps"):  # fmt: skip
        v = getattr(t, name)
        if v is not None and not math.isfinite(v):
            return f"{name} {v}"
    if t.battery_percent is not None and not 0.0 <= t.battery_percent <= 100.0:
        return f"battery {t.battery_percent}"
    if any(not 1000 <= c <= 2000 for c in t.rc_channels):
        return f"RC {t.rc_channels}"
    if len(core.pending) > 50:
        return f"{len(core.pending)} commands pending"
    return None


def _valid_output(data: bytes) -> str | None:
    reader = FrameReader(KEY)
    reader.feed(data)
    if reader.bad_frames or reader.pending:
        return f"sent {len(data)} bytes that are not whole valid frames"
    return None


def check_core(rng: random.Random) -> tuple[str, str | None]:
    """(kinds, failure or None)."""
    core, clock = connected_core(rng)
    if not core.activated:
        return "core", "the handshake did not activate the core"
    kinds: set[str] = set()
    for _ in range(rng.randint(1, 25)):
        r = rng.random()
        if r < 0.45:
            cipher = rng.choice((None, None, KEY, OTHER_KEY))
            frame = random_frame(rng, cipher)
            if rng.random() < 0.2:
                kind, frame = mutate(rng, frame)
                kinds.add(kind)
            else:
                kinds.add("frame")
            for piece in split(rng, frame):
                core.receive_data(piece)
        elif r < 0.55:
            # An ACK for what the core is waiting on, with any code.
            out = FrameReader(KEY).feed(core.data_to_send())
            reliable = [f for f in out if f.session >= 1 and not f.ack]
            if reliable:
                f = rng.choice(reliable)
                code = rng.choice((0, 1, 2, 3, 4, 5, 0xC9, 0xFF00, 0xFF01, rng.getrandbits(16)))
                core.receive_data(ack_frame(f.session, f.seq, code.to_bytes(2, "little")))
                kinds.add("answer")
        elif r < 0.65:
            core.receive_data(rng.randbytes(rng.randrange(1, 80)))
            kinds.add("noise")
        elif r < 0.85:
            rng.choice(ORDERS)(core, rng)
            kinds.add("order")
        else:
            clock.now += rng.choice((0.001, 0.02, 0.1, 0.6, 3.5, 20.0))
            core.tick()
            kinds.add("time")
        problem = _sane(core) or _valid_output(core.data_to_send())
        if problem is not None:
            return "+".join(sorted(kinds)), problem
    if core.link_errors:
        return "+".join(sorted(kinds)), f"{core.link_errors} link errors: a handler failed"
    return "+".join(sorted(kinds)), None


# ---------------------------------------------------------------- sim


def host_frame(rng: random.Random) -> bytes:
    """A frame a host (or a hostile one) may send the flight controller."""
    key = rng.choice(
        (M.CMD_GET_VERSION, M.CMD_ACTIVATE, M.CMD_SET_BROADCAST, M.CMD_CONTROL, M.CMD_TASK,
         M.CMD_TASK_QUERY, M.CMD_MOVEMENT, M.CMD_ARM, (0x03, 0x10), (0xFF, 0xFF))
    )  # fmt: skip
    want = M.VALUE_LENGTHS.get(key, rng.randrange(20))
    if key == M.CMD_ACTIVATE and rng.random() < 0.5:
        value = M.activation_value(rng.choice((TEST_APP_ID, 1, 0xFFFFFFFF)))
    elif key == M.CMD_MOVEMENT and rng.random() < 0.7:
        value = struct.pack("<Bffff", rng.randrange(256), *(_float(rng) for _ in range(4)))
    else:
        value = rng.randbytes(want if rng.random() < 0.8 else rng.randrange(50))
    cipher = rng.choice((None, KEY, KEY, OTHER_KEY))
    return command_frame(rng.choice((0, 1, 2, 5)), rng.getrandbits(16), *key, value, cipher=cipher)


def check_sim(rng: random.Random) -> tuple[str, str | None]:
    """(kinds, failure or None)."""
    sim = SimM100(PROFILE, rc_mode=rng.choice(("P", "A", "F", "F")))
    kinds: set[str] = set()
    for _ in range(rng.randint(1, 30)):
        r = rng.random()
        if r < 0.6:
            frame = host_frame(rng)
            if rng.random() < 0.2:
                kind, frame = mutate(rng, frame)
                kinds.add(kind)
            else:
                kinds.add("command")
            sim.receive_data(frame)
        elif r < 0.7:
            sim.receive_data(rng.randbytes(rng.randrange(1, 80)))
            kinds.add("noise")
        elif r < 0.8:
            sim.pilot_switch(rng.choice(("P", "A", "F")))
            kinds.add("pilot")
        else:
            for _ in range(rng.randint(1, 20)):
                sim.step(0.02)
            kinds.add("time")
        problem = _valid_output(sim.data_to_send())
        if problem is not None:
            return "+".join(sorted(kinds)), problem
    return "+".join(sorted(kinds)), None


# ---------------------------------------------------------------- the campaign


def run_one(seed: str, k: int) -> tuple[str, str | None]:
    """(kind, failure or None) of input k."""
    rng = random.Random(f"{seed}:{k}")
    target = rng.choices(TARGETS, weights=(14, 4, 2))[0]
    try:
        if target == "deframe":
            kind, stream, clean = stream_input(rng)
            return f"deframe/{kind}", check_deframe(rng, stream, clean)
        if target == "core":
            kind, failure = check_core(rng)
            return f"core/{kind}", failure
        kind, failure = check_sim(rng)
        return f"sim/{kind}", failure
    except Exception:
        return target, "unexpected exception:\n" + traceback.format_exc()


def record(seed: str, k: int, stats: runner.Stats, out: Callable[[str], None]) -> None:
    """Run input k and record the outcome."""
    kind, failure = run_one(seed, k)
    stats.kinds[kind.split("/")[0]] += 1
    if failure is not None:
        stats.fail(f"{seed}:{k}", f"FAIL {seed}:{k} ({kind}): {failure}", out, shown=20)


#: run(seed, *, seconds=None, max_inputs=None, start=0, out=print) -> Stats: a campaign.
run = runner.make_run(record, runner.Stats, clock_every=64, progress=True)


def replay(spec: str) -> int:
    """Run input SEED:K verbosely; exit status 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    kind, failure = run_one(seed, int(k))
    print(f"kind {kind}:", failure or "ok")
    return 1 if failure else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    return runner.main(argv, __doc__, run, replay)


if __name__ == "__main__":
    sys.exit(main())
