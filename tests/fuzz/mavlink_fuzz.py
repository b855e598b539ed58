"""Fuzzing the autopilot link's MAVLink input: hostile byte streams, a seeded campaign.

    python -m tests.fuzz.mavlink_fuzz --seconds 60 --seed 1
    python -m tests.fuzz.mavlink_fuzz --replay 1:123        # one input, verbosely

Input k of seed S is made from `random.Random(f"{S}:{k}")`: a stream of up to 24 pieces, each
a good frame (any message the link reads, v1 or v2, from the vehicle or another system, with
field values from ordinary to hostile: NaN and infinite floats, out-of-range coordinates,
255 RC channels, unknown modes and types) or noise (random bytes, bytes rich in the 0xFD/0xFE
magic values, truncated frames, frames with a flipped bit or a broken CRC, spliced frames).

The property, per input:

* `FrameReader` fed the stream in random-size chunks gives back every good frame, in order,
  byte for byte. The only excuse is noise that decodes as a valid frame (a CRC-16 collision,
  or a splice that rebuilt a whole frame), which MAVLink cannot tell from a real one and
  which may swallow the frames behind it (counted, not a failure);
* an `Autopilot` reading the same stream through a real pty never raises out of `poll()`,
  counts no link error (no message made a handler fail), and its telemetry stays sane:
  coordinates on Earth or None, finite yaw and speed or None, battery 0..100 % or None.

Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import math
import os
import random
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import all as mavlink2

from fieldkit.vehicle.link import Autopilot
from fieldkit.vehicle.mavlink import FrameReader
from fieldkit.vehicle.pty import PtyPair, open_pty

from . import runner

FLOATS = (0.0, -0.0, 1.5, -1e9, 3.4e38, math.nan, math.inf, -math.inf)
I32 = (0, 1, -1, 2**31 - 1, -(2**31), 455049000, -736133000, 900_000_001)
U16 = (0, 1, 1500, 1900, 65534, 65535)


def _f(rng: random.Random) -> float:
    return rng.choice(FLOATS) if rng.random() < 0.3 else rng.uniform(-1e4, 1e4)


def _i32(rng: random.Random) -> int:
    return rng.choice(I32) if rng.random() < 0.5 else rng.randrange(-(2**31), 2**31)


def _u(rng: random.Random, bits: int) -> int:
    top = (1 << bits) - 1
    return rng.choice((0, 1, top, top - 1)) if rng.random() < 0.3 else rng.randrange(top + 1)


def _i(rng: random.Random, bits: int) -> int:
    half = 1 << (bits - 1)
    return (
        rng.choice((0, -1, half - 1, -half)) if rng.random() < 0.3 else rng.randrange(-half, half)
    )


def message(rng: random.Random) -> Any:
    """One message of a type the link reads, with ordinary or hostile fields."""
    enc = mavlink2.MAVLink(None)
    kind = rng.randrange(13)
    u8, u16, u32 = (lambda: _u(rng, 8)), (lambda: _u(rng, 16)), (lambda: _u(rng, 32))
    if kind == 0:
        return enc.heartbeat_encode(
            rng.choice((2, 10, 6, 12, u8())), rng.choice((3, 12, 0, 8, u8())), u8(), u32(), u8()
        )
    if kind == 1:
        return enc.global_position_int_encode(
            u32(), _i32(rng), _i32(rng), _i32(rng), _i32(rng), *(_i(rng, 16) for _ in range(3)),
            u16(),
        )  # fmt: skip
    if kind == 2:
        return enc.gps_raw_int_encode(
            _u(rng, 64), rng.choice((0, 1, 3, 6, u8())), _i32(rng), _i32(rng), _i32(rng),
            u16(), u16(), u16(), u16(), u8(),
        )  # fmt: skip
    if kind == 3:
        return enc.attitude_encode(u32(), *(_f(rng) for _ in range(6)))
    if kind == 4:
        return enc.sys_status_encode(
            u32(), u32(), u32(), u16(), u16(), _i(rng, 16), _i(rng, 8), u16(), u16(), u16(),
            u16(), u16(), u16(),
        )  # fmt: skip
    if kind == 5:
        return enc.battery_status_encode(
            rng.choice((0, u8())), u8(), u8(), _i(rng, 16), [u16() for _ in range(10)],
            _i(rng, 16), _i32(rng), _i32(rng), _i(rng, 8),
        )  # fmt: skip
    if kind == 6:
        return enc.home_position_encode(
            _i32(rng), _i32(rng), _i32(rng), _f(rng), _f(rng), _f(rng), [_f(rng)] * 4,
            _f(rng), _f(rng), _f(rng),
        )  # fmt: skip
    if kind == 7:
        return enc.extended_sys_state_encode(u8(), u8())
    if kind == 8:
        return enc.rc_channels_encode(u32(), u8(), *(u16() for _ in range(18)), u8())
    if kind == 9:
        return enc.rc_channels_raw_encode(u32(), u8(), *(u16() for _ in range(8)), u8())
    if kind == 10:
        text = bytes(rng.randrange(256) for _ in range(rng.randrange(51)))
        return enc.statustext_encode(u8(), text)
    if kind == 11:
        return enc.command_ack_encode(u16(), u8(), u8(), _i32(rng), u8(), u8())
    return enc.vfr_hud_encode(_f(rng), _f(rng), _i(rng, 16), u16(), _f(rng), _f(rng))


def frame(rng: random.Random) -> bytes:
    """A good frame: mostly from the vehicle (1, 1), sometimes from another system."""
    src = rng.choice(((1, 1), (1, 1), (1, 1), (255, 190), (51, 68), (_u(rng, 8), _u(rng, 8))))
    enc = mavlink2.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
    enc.seq = rng.randrange(256)
    return bytes(message(rng).pack(enc, force_mavlink1=rng.random() < 0.3))


def noise(rng: random.Random) -> bytes:
    """Bytes that are not a good frame."""
    kind = rng.randrange(6)
    if kind == 0:
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 64)))
    if kind == 1:  # magic values and lengths, the worst for a parser
        pool = (0xFD, 0xFE, 0x00, 0xFF, 0x01, rng.randrange(256))
        return bytes(rng.choice(pool) for _ in range(rng.randrange(1, 48)))
    f = bytearray(frame(rng))
    if kind == 2:
        return bytes(f[: rng.randrange(1, len(f))])  # truncated
    if kind == 3:
        f[-1 - rng.randrange(2)] ^= 1 << rng.randrange(8)  # broken CRC
        return bytes(f)
    if kind == 4:
        i = rng.randrange(1, len(f))  # a flipped bit past the magic
        f[i] ^= 1 << rng.randrange(8)
        return bytes(f)
    g = frame(rng)
    return bytes(f[: rng.randrange(1, len(f))]) + g[rng.randrange(1, len(g)) :]  # spliced


def make_input(seed: str, k: int) -> tuple[list[bytes], bytes, list[int]]:
    """(the good frames in order, the whole stream, chunk sizes to feed it in)."""
    rng = random.Random(f"{seed}:{k}")
    good: list[bytes] = []
    parts: list[bytes] = []
    for _ in range(rng.randrange(1, 25)):
        if rng.random() < 0.55:
            f = frame(rng)
            good.append(f)
            parts.append(f)
        else:
            parts.append(noise(rng))
    # Enough plain bytes at the end to settle any half-believed frame (280 bytes at most).
    stream = b"".join(parts) + bytes(300)
    cuts = [rng.choice((1, 2, 7, 64, 4096, rng.randrange(1, 300))) for _ in range(8)]
    return good, stream, cuts


def check_reader(good: list[bytes], stream: bytes, cuts: list[int]) -> tuple[str | None, bool]:
    """(a problem or None, whether a CRC collision explains a difference)."""
    reader = FrameReader(mavlink2.MAVLink(None))
    got: list[bytes] = []
    pos = k = 0
    while pos < len(stream):
        n = cuts[k % len(cuts)]
        got += [bytes(m.get_msgbuf()) for m in reader.feed(stream[pos : pos + n])]
        pos, k = pos + n, k + 1
    if reader.messages != len(got):
        return f"messages counter {reader.messages} != {len(got)} decoded", False
    if got == good:
        return None, False
    extra = [g for g in got if g not in good]
    if extra:
        return None, True  # noise that passed a CRC-16: indistinguishable from a frame
    missing = [g.hex() for g in good if g not in got]
    return f"lost good frames {missing[:3]} (got {len(got)} of {len(good)})", False


def _sane(link: Autopilot) -> str | None:
    t = link.telemetry
    if t.lat is not None and not (-90 <= t.lat <= 90 and -180 <= (t.lon or 0) <= 180):
        return f"position off the Earth: {t.lat}, {t.lon}"
    if t.home is not None and not (-90 <= t.home[0] <= 90 and -180 <= t.home[1] <= 180):
        return f"home off the Earth: {t.home}"
    for name in ("yaw_rad", "ground_speed_mps"):
        v = getattr(t, name)
        if v is not None and not math.isfinite(v):
            return f"telemetry {name} = {v}"
    if t.battery_percent is not None and not 0 <= t.battery_percent <= 100:
        return f"battery at {t.battery_percent} %"
    return None


class PtyLink:
    """An Autopilot on a pty, fed raw bytes by the harness."""

    def __init__(self) -> None:
        self.pty: PtyPair = open_pty()
        self.now = 0.0
        self.link = Autopilot(
            self.pty.slave_path, clock=lambda: self.now, heartbeat_interval_s=None
        )

    def feed(self, stream: bytes) -> None:
        """Write `stream` on the line and poll until the link has read all of it."""
        target = self.link.bytes_received + len(stream)
        sent = 0
        deadline = time.monotonic() + 10.0
        while self.link.bytes_received < target:
            if time.monotonic() > deadline:
                raise TimeoutError("bytes not delivered through the pty")
            if sent < len(stream):
                try:
                    sent += os.write(self.pty.master, stream[sent : sent + 4096])
                except BlockingIOError:
                    pass
            self.link.poll(0.2)
            self.now += 0.01

    def close(self) -> None:
        """Close the link and the pty."""
        self.link.close()
        self.pty.close()


def check_link(pl: PtyLink, stream: bytes) -> str | None:
    """Feed the stream to a live link; a problem or None."""
    errors = pl.link.link_errors
    events = len(pl.link.events)
    try:
        pl.feed(stream)
    except TimeoutError as e:
        return str(e)
    if pl.link.link_errors != errors:
        text = [e.text for e in list(pl.link.events)[events:] if e.kind == "link"]
        return f"link error: {text[:1]}"
    return _sane(pl.link)


@dataclass
class Stats(runner.Stats):
    """What a campaign did."""

    collisions: int = 0
    frames: int = 0

    def details(self) -> list[str]:
        """The good frames sent and the noise that passed for frames (inputs have no kinds)."""
        return [
            f"good frames: {self.frames}",
            f"noise that decoded as a valid frame (not failures): {self.collisions}",
        ]


def run_one(seed: str, k: int, pl: PtyLink, stats: Stats, out: Callable[[str], None]) -> None:
    """Make input k, check it, and record the outcome."""
    good, stream, cuts = make_input(seed, k)
    try:
        problem, collision = check_reader(good, stream, cuts)
        problem = problem or check_link(pl, stream)
    except Exception:  # a harness error is reported, not fatal
        problem, collision = "exception: " + traceback.format_exc(limit=-3), False
    stats.frames += len(good)
    stats.collisions += collision
    if problem is not None:
        stats.fail(f"{seed}:{k}", f"FAILURE [replay {seed}:{k}] {problem}", out, shown=20)


def run(seed: str, **budget: Any) -> Stats:
    """Check inputs of `seed` on one live link; `budget`: seconds, max_inputs, start, out."""
    pl = PtyLink()
    try:
        # One pty serves the whole campaign: opening one per input would dominate its time.
        on_link = runner.make_run(lambda s, k, stats, out: run_one(s, k, pl, stats, out), Stats)
        return on_link(seed, **budget)
    finally:
        pl.close()


def replay(spec: str) -> int:
    """Run one input verbosely; 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    good, stream, cuts = make_input(seed, int(k))
    print(f"input {spec}: {len(good)} good frames, {len(stream)} bytes, chunks {cuts}")
    print(stream.hex())
    stats = Stats()
    pl = PtyLink()
    try:
        run_one(seed, int(k), pl, stats, print)
        print("telemetry:", pl.link.telemetry)
    finally:
        pl.close()
    print("verdict:", "FAILED" if stats.failures else "ok")
    return 1 if stats.failures else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    return runner.main(argv, __doc__, run, replay)


if __name__ == "__main__":
    sys.exit(main())
