"""Fuzzing the Husky's GPS input (NMEA sentences, UBX frames) with hostile bytes: a seeded campaign.

    python -m tests.fuzz.nmea_fuzz --seconds 60 --seed 1
    python -m tests.fuzz.nmea_fuzz --count 500000 --seed 1
    python -m tests.fuzz.nmea_fuzz --replay 1:12345      # one input, verbosely

Input k of seed S is made from `random.Random(f"{S}:{k}")`: a stream of up to 10 pieces, each
a good sentence (GGA, RMC, VTG, HDT, GSA, GSV from any talker, fields ordinary to hostile:
empty, huge, negative, off the Earth, letters where digits belong, with a correct checksum),
a good UBX frame (NAV-PVT with any fix and position, or another message), or noise: random
bytes, bytes rich in `$`, `*`, `,`, CR, LF and the UBX sync bytes, sentences with a flipped
character or a broken checksum, cut short, run together or overlong, UBX frames with a bad
checksum or length. Fed to a `GpsCore` in random pieces, with time moving on, then padded
with enough 0xFF to complete any UBX candidate, then to a `HuskyCore`'s GPS input.

The property, per input:

* no exception;
* line noise only costs counters: noise never counts as a good sentence or frame
  (`messages` at most the number of good ones put in), and when the good pieces are
  separated by noise that cannot join them (noise ending in CR LF, no UBX sync), every good
  one whose fields are all ordinary is counted (a hostile field may be refused);
* the fix is sane: fix type 0..6, coordinates on the Earth (and both or neither), finite
  altitude, speed >= 0, course and heading in 0..360, satellites >= 0;
* the Husky core's telemetry stays sane after the same bytes (three inputs in ten).

Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import math
import random
import sys
import traceback
from collections.abc import Callable

import pyubx2

from fieldkit.robot.profiles import load_profile
from fieldkit.vehicle.clearpath.core import HuskyCore
from fieldkit.vehicle.clearpath.gps import MAX_UBX_PAYLOAD, GpsCore, nmea_lat, nmea_lon, sentence

from . import runner

HUSKY = load_profile("husky")
TALKERS = ("GP", "GN", "GL", "GA", "GB", "IN", "ZZ")
NOISY = b"$*,\r\n\xb5\x62AGN0123456789.-"


class FakeClock:
    """A clock the fuzzer moves by hand."""

    def __init__(self, now: float = 100.0) -> None:
        self.now = now

    def __call__(self) -> float:
        """The current fake time."""
        return self.now


class _Hostile:
    """Whether the sentence being made got a hostile field (it may then be refused)."""

    used = False


def _num(rng: random.Random, ordinary: Callable[[], str]) -> str:
    r = rng.random()
    if r < 0.7:
        return ordinary()
    _Hostile.used = True
    return rng.choice(("", "-1", "0", "999999999", "1e308", "nan", "inf", "abc", "12.34.5", "-0"))


def _lat(rng: random.Random) -> tuple[str, str]:
    if rng.random() < 0.8:
        return nmea_lat(rng.uniform(-89.9, 89.9))
    _Hostile.used = True
    return rng.choice(("", "9999.9999", "-4530.1", "x")), rng.choice(("N", "S", "", "Q"))


def _lon(rng: random.Random) -> tuple[str, str]:
    if rng.random() < 0.8:
        return nmea_lon(rng.uniform(-179.9, 179.9))
    _Hostile.used = True
    return rng.choice(("", "19999.9999", "-07334.0", "y")), rng.choice(("E", "W", "", "Q"))


def _date(rng: random.Random) -> str:
    return f"{rng.randint(1, 28):02d}{rng.randint(1, 12):02d}{rng.randrange(99):02d}"


def good_sentence(rng: random.Random) -> bytes:
    """A sentence with a correct checksum: fields from ordinary to hostile (`_Hostile.used`
    says which)."""
    _Hostile.used = False
    talker = rng.choice(TALKERS)
    kind = rng.choice(("GGA", "GGA", "RMC", "RMC", "VTG", "HDT", "GSA", "GSV"))
    hms = _num(
        rng, lambda: f"{rng.randrange(24):02d}{rng.randrange(60):02d}{rng.randrange(60):02d}.00"
    )
    lat, ns = _lat(rng)
    lon, ew = _lon(rng)
    if kind == "GGA":
        values = (
            hms, lat, ns, lon, ew,
            _num(rng, lambda: str(rng.choice((0, 1, 2, 4, 5, 6, 9)))),
            _num(rng, lambda: f"{rng.randrange(30):02d}"),
            _num(rng, lambda: f"{rng.uniform(0.5, 20):.1f}"),
            _num(rng, lambda: f"{rng.uniform(-100, 9000):.1f}"), "M",
            _num(rng, lambda: f"{rng.uniform(-50, 50):.1f}"), "M", "", "",
        )  # fmt: skip
    elif kind == "RMC":
        values = (
            hms, rng.choice(("A", "A", "V", "", "X")), lat, ns, lon, ew,
            _num(rng, lambda: f"{rng.uniform(0, 50):.3f}"),
            _num(rng, lambda: f"{rng.uniform(0, 360):.1f}"),
            _num(rng, lambda: _date(rng)),
            "", "", rng.choice(("A", "D", "N", "R")),
        )  # fmt: skip
    elif kind == "VTG":
        values = (
            _num(rng, lambda: f"{rng.uniform(0, 360):.1f}"), "T", "", "M",
            _num(rng, lambda: f"{rng.uniform(0, 50):.1f}"), "N",
            _num(rng, lambda: f"{rng.uniform(0, 90):.1f}"), "K",
        )  # fmt: skip
    elif kind == "HDT":
        values = (_num(rng, lambda: f"{rng.uniform(0, 360):.2f}"), "T")
    elif kind == "GSA":
        values = ("A", "3", *(str(rng.randrange(33)) for _ in range(12)), "1.0", "0.9", "1.3")
    else:
        values = ("3", "1", "11", "01", "40", "083", "46", "02", "17", "308", "41", "", "", "", "")
    try:
        return sentence(talker, kind, values)
    except (ValueError, TypeError, KeyError):
        return b""


def _nav_pvt(rng: random.Random) -> bytes:
    msg = pyubx2.UBXMessage(
        "NAV", "NAV-PVT", pyubx2.GET,
        fixType=rng.randrange(6), gnssFixOk=rng.randrange(2), carrSoln=rng.randrange(3),
        numSV=rng.randrange(256), lat=rng.uniform(-90, 90), lon=rng.uniform(-180, 180),
        hMSL=rng.randrange(-(2**31), 2**31), gSpeed=rng.randrange(-(2**31), 2**31),
        headMot=rng.uniform(-180, 180),
    )  # fmt: skip
    return bytes(msg.serialize())


# pyubx2 takes milliseconds to build a message: a pool made once (seeded) serves every input.
_POOL_RNG = random.Random("nav-pvt pool")
UBX_POOL: tuple[bytes, ...] = (
    tuple(_nav_pvt(_POOL_RNG) for _ in range(256))
    + (bytes(pyubx2.UBXMessage("MON", "MON-VER", pyubx2.POLL).serialize()),) * 32
)


def good_ubx(rng: random.Random) -> bytes:
    """A UBX frame pyubx2 built: NAV-PVT with any fix and position, or a MON-VER poll."""
    return rng.choice(UBX_POOL)


def noise(rng: random.Random) -> tuple[str, bytes]:
    """(kind, bytes that are not one good sentence or frame)."""
    r = rng.random()
    if r < 0.2:
        return "random", rng.randbytes(rng.randrange(1, 60))
    if r < 0.4:
        return "noisy", bytes(rng.choice(NOISY) for _ in range(rng.randrange(1, 60)))
    line = good_sentence(rng) or b"$GPGGA,,,,,,0,,,,,,,,*66\r\n"
    buf = bytearray(line)
    if r < 0.55:
        i = rng.randrange(1, max(2, len(buf) - 5))
        buf[i] = rng.choice(b"0123456789,.*$AZ") if buf[i] != ord(",") else ord("9")
        if bytes(buf) == line:
            buf[i] ^= 1
        return "flip", bytes(buf)
    if r < 0.65:
        star = buf.rfind(b"*")
        new = b"ZZ" if rng.random() < 0.5 else b"00"
        if buf[star + 1 : star + 3] == new:
            new = b"ZZ"  # its checksum was 00: another wrong one
        buf[star + 1 : star + 3] = new
        return "checksum", bytes(buf)
    if r < 0.75:
        return "cut", bytes(buf[: rng.randrange(1, len(buf) - 2)])
    if r < 0.8:
        return "long", b"$GPGGA," + b"1," * rng.randrange(50, 200) + b"*00\r\n"
    frame = bytearray(good_ubx(rng))
    if r < 0.9:
        frame[-1] ^= rng.randrange(1, 256)
        return "ubx-checksum", bytes(frame)
    if r < 0.95:
        n = rng.choice((0xFFFF, MAX_UBX_PAYLOAD + 1, rng.randrange(0x10000)))
        if n == frame[4] | frame[5] << 8:
            n ^= 0x8000  # its own length would leave the frame good
        frame[4:6] = n.to_bytes(2, "little")
        return "ubx-length", bytes(frame)
    return "ubx-cut", bytes(frame[: rng.randrange(1, len(frame))])


def gps_input(rng: random.Random) -> tuple[str, bytes, int, int, bool]:
    """(kind, stream, good pieces put in (plus, unfenced, the cut sentences that noise after
    them may complete), how many have only ordinary fields, whether noise is fenced off)."""
    parts = []
    good = ordinary = 0
    kinds = set()
    fenced = rng.random() < 0.5
    for _ in range(rng.randint(1, 10)):
        r = rng.random()
        if r < 0.5:
            s = good_sentence(rng)
            if s:
                parts.append(s)
                good += 1
                ordinary += not _Hostile.used
                kinds.add("nmea")
        elif r < 0.57:  # pyubx2's parse takes milliseconds: fewer of these than sentences
            parts.append(good_ubx(rng))
            good += 1
            ordinary += 1
            kinds.add("ubx")
        else:
            kind, bad = noise(rng)
            if kind in ("cut", "ubx-cut") and not fenced:
                # Noise after it can complete it: "*27" LF (a 1 in 256 checksum), or the
                # "4" (0x34) a MON-VER poll cut before its last byte lacks.
                good += 1
            if fenced:
                # Noise that ends a line and holds no UBX sync cannot swallow what follows.
                bad = bad.replace(b"\xb5", b"?") + b"\r\n"
            parts.append(bad)
            kinds.add(kind)
    return "+".join(sorted(kinds)), b"".join(parts), good, ordinary, fenced


def split(rng: random.Random, stream: bytes) -> list[bytes]:
    """The stream in random pieces (single bytes, small, large, or whole)."""
    r = rng.random()
    if r < 0.2 or not stream:
        return [stream]
    if r < 0.3:
        return [stream[i : i + 1] for i in range(len(stream))]
    cuts = sorted(rng.randrange(len(stream) + 1) for _ in range(rng.randrange(1, 12)))
    return [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]


def _sane_fix(g: GpsCore) -> str | None:
    f = g.fix
    if not 0 <= f.fix_type <= 6:
        return f"fix type {f.fix_type}"
    if (f.lat is None) != (f.lon is None):
        return "half a position"
    if f.lat is not None and not (-90 <= f.lat <= 90 and -180 <= f.lon <= 180):  # type: ignore[operator]
        return f"position off the Earth: {f.lat}, {f.lon}"
    for name in ("alt_msl_m", "hdop", "speed_mps"):
        v = getattr(f, name)
        if v is not None and not math.isfinite(v):
            return f"{name} = {v}"
    for name in ("track_deg", "heading_deg"):
        v = getattr(f, name)
        if v is not None and not 0 <= v < 360:
            return f"{name} = {v}"
    if f.satellites is not None and f.satellites < 0:
        return f"{f.satellites} satellites"
    return None


def check(rng: random.Random, stream: bytes, good: int, ordinary: int, fenced: bool) -> str | None:
    """Failure description, or None."""
    clock = FakeClock()
    g = GpsCore(clock=clock, timeout_s=2.0)
    for piece in split(rng, stream):
        g.receive_data(piece)
        clock.now += rng.choice((0.0, 0.0, 0.1, 0.5, 3.0))
        g.tick()
        problem = _sane_fix(g)
        if problem:
            return problem
    held = len(g._buf)
    # 0xFF completes any UBX candidate (a zero padding would itself make B5 62 00 00 00 00
    # 00 00 a valid empty frame); a candidate completed so can still pass its checksum by
    # chance (1 in 65536): one more message is allowed then.
    g.receive_data(b"\xff" * (MAX_UBX_PAYLOAD + 8))
    if len(g._buf) > MAX_UBX_PAYLOAD + 8:
        return f"{len(g._buf)} bytes held"
    extra = 1 if held else 0
    # Sentences with hostile fields may be refused; the others must all come through.
    if fenced and not ordinary <= g.messages <= good + extra:
        return f"{good} good ({ordinary} ordinary) put in, {g.messages} counted"
    if g.messages > good + extra:
        return f"{g.messages} counted from {good} good ones"
    g.drain_events()
    if rng.random() < 0.7:
        return None  # the core's GPS input is the same GpsCore: a share of inputs suffices
    core = HuskyCore(profile=HUSKY, clock=clock)
    for piece in split(rng, stream):
        core.receive_gps(piece)
        if rng.random() < 0.2:
            clock.now += 0.1
            core.tick()
    t = core.telemetry
    if t.lat is not None and not (-90 <= t.lat <= 90 and -180 <= t.lon <= 180):  # type: ignore[operator]
        return f"core position off the Earth: {t.lat}, {t.lon}"
    if t.heading_deg is not None and not 0 <= t.heading_deg < 360:
        return f"core heading {t.heading_deg}"
    return None


def run_one(seed: str, k: int) -> tuple[str, str | None]:
    """(kind, failure or None) of input k."""
    rng = random.Random(f"{seed}:{k}")
    try:
        kind, stream, good, ordinary, fenced = gps_input(rng)
        return kind, check(rng, stream, good, ordinary, fenced)
    except Exception:
        return "gps", "unexpected exception:\n" + traceback.format_exc()


def record(seed: str, k: int, stats: runner.Stats, out: Callable[[str], None]) -> None:
    """Run input k and record the outcome."""
    kind, failure = run_one(seed, k)
    for part in kind.split("+"):
        stats.kinds[part] += 1
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
