"""Fuzzing the PX4 link core (`Px4Core`) with hostile PX4 traffic and orders, seeded.

    python -m tests.fuzz.px4_fuzz --count 500000 --seed 1     # no time limit
    python -m tests.fuzz.px4_fuzz --seconds 60 --seed 1
    python -m tests.fuzz.px4_fuzz --replay 1:12345            # one input, verbosely

`tests/fuzz/mavlink_fuzz.py` throws random MAVLink at the ArduPilot link (`Autopilot`); its
heartbeats sometimes claim PX4, which only exercises the mode *names*. PX4's own paths (the
custom modes, the OFFBOARD stream and its switch held back for the warm-up, leaving OFFBOARD,
the parameter reads, the refusals) are `Px4Core`'s and are fuzzed here, in memory on a fake
clock (a pty per input would cost more than the input).

Input k of seed S is made from `random.Random(f"{S}:{k}")`. It starts a `Px4Core` (the
Spiri's profile, or none) in one of four states reached by genuine PX4 frames (silent;
connected; a take-off under way, its stream running; flying in OFFBOARD), then applies up
to 24 events, each one of:

* PX4 frames, alone or several, in random chunks: HEARTBEATs with PX4 custom modes (the
  table's, random main/sub, random base_mode and status, from PX4 or another system),
  COMMAND_ACKs for the commands the core sends (every MAV_RESULT, IN_PROGRESS, targets ours
  or not), PARAM_VALUEs (PX4's names and others, every type, integers bytewise, NaN
  patterns), STATUSTEXT, EXTENDED_SYS_STATE, GLOBAL_POSITION_INT, HOME_POSITION, RC_CHANNELS;
* the same frames mutated (bit flips, truncation, broken CRC, splices) or line noise, or
  any frame of `mavlink_fuzz` (the generic hostile MAVLink);
* time: the clock moves (0 to 3 s) and `tick()` runs;
* an order: takeoff, goto, hold, land, rtl, set_mode (PX4 names and junk), arm, disarm,
  request_streams, cancel_all, with ordinary and hostile numbers (NaN, inf, out of range).

The property, per event: nothing raises; no message makes a handler fail (`link_errors`
stays 0); the telemetry stays sane (as `mavlink_fuzz` checks it); every byte the core writes
is a valid MAVLink frame, each setpoint on Earth with a finite altitude; while a setpoint is
streamed (and an altitude reference is known) a tick never leaves it older than the stream
interval; and once PX4 has left OFFBOARD by itself the core never switches back (no
DO_SET_MODE to OFFBOARD) unless the order came after the loss: it never fights the pilot.

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
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import all as mavlink2

from fieldkit.robot.profiles import load_profile
from fieldkit.vehicle.mavlink import FrameReader
from fieldkit.vehicle.px4 import MODES, OFFBOARD, PARAMS, Px4Core, custom_mode

if __package__:
    from . import mavlink_fuzz as M
    from . import runner
else:  # run as a file: python tests/fuzz/px4_fuzz.py
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
    from fuzz import mavlink_fuzz as M
    from fuzz import runner

SLICE = 20_000
SPIRI = load_profile("spiri")
STATES = ("silent", "connected", "taking_off", "offboard")
MODE_VALUES = [custom_mode(*numbers) for numbers in MODES.values()]
OFFBOARD_MODE = custom_mode(6, 0)
LAT, LON = 455049000, -736133000
# Commands the core sends (what an ACK may answer), and others.
COMMANDS = (176, 400, 511, 22, 21, 20, 192, 0, 65535)
PARAM_TYPES = tuple(range(0, 12))
HOSTILE = (math.nan, math.inf, -math.inf, 1e308, -1e9, 0.0, -0.0)

Event = tuple[str, Any]


@dataclass
class Stats(runner.EventStats):
    """What a campaign did (events and their kinds: `runner.EventStats`)."""

    offboard_losses: int = 0  # inputs in which PX4 left OFFBOARD by itself
    switches: int = 0  # DO_SET_MODE to OFFBOARD the core sent

    def details(self) -> list[str]:
        """The kinds of event, and how often the no-fighting rule was put to the test."""
        return [
            f"kinds: {dict(sorted(self.kinds.items()))}",
            f"events: {self.events}, OFFBOARD switches sent: {self.switches}, "
            f"inputs where PX4 left OFFBOARD by itself: {self.offboard_losses}",
        ]


# ---------------------------------------------------------------- frames


class Px4Side:
    """PX4's encoder (1/1), and other systems' for frames not from the vehicle."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng
        self.px4 = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.px4.seq = rng.randrange(256)

    def pack(self, msg: Any, *, foreign: bool = False) -> bytes:
        rng = self.rng
        if foreign:
            src = rng.choice(((255, 190), (1, 195), (2, 1), (M._u(rng, 8), M._u(rng, 8))))
            enc = mavlink2.MAVLink(None, srcSystem=src[0], srcComponent=src[1])
        else:
            enc = self.px4
        return bytes(msg.pack(enc, force_mavlink1=rng.random() < 0.1))

    def heartbeat(self, mode: int | None = None, armed: bool | None = None) -> Any:
        rng = self.rng
        if mode is None:
            r = rng.random()
            mode = (
                rng.choice(MODE_VALUES)
                if r < 0.6
                else custom_mode(rng.randrange(12), rng.randrange(20))
                if r < 0.85
                else M._u(rng, 32)
            )
        if armed is None:
            base = rng.choice((0x91, 0x1D, 0x9D, 0xD1, 0x51, 0x01, M._u(rng, 8)))
        else:
            base = 0x91 if armed else 0x11
        status = rng.choice((3, 4, 5, 0, 6, 7, 8, M._u(rng, 8)))
        ap = 12 if rng.random() < 0.9 else rng.choice((3, 8, M._u(rng, 8)))
        kind = 2 if rng.random() < 0.9 else rng.choice((6, 18, M._u(rng, 8)))
        return mavlink2.MAVLink_heartbeat_message(kind, ap, base, mode, status, 3)

    def ack(self, sent: list[int]) -> Any:
        rng = self.rng
        command = rng.choice(sent) if sent and rng.random() < 0.7 else rng.choice(COMMANDS)
        result = rng.choice((0, 0, 1, 2, 3, 4, 5, 6, 9, M._u(rng, 8)))
        target = rng.choice(((1, 195), (1, 195), (0, 0), (255, 190), (M._u(rng, 8), 195)))
        return mavlink2.MAVLink_command_ack_message(
            command, result, M._u(rng, 8), M._i32(rng), *target
        )

    def param(self) -> Any:
        rng = self.rng
        name = rng.choice(PARAMS) if rng.random() < 0.7 else rng.choice(("SYSID_THISMAV", ""))
        if rng.random() < 0.1:
            name = "".join(chr(rng.randrange(1, 256)) for _ in range(rng.randrange(17)))
        kind = rng.choice((9, 6, 6, *PARAM_TYPES))
        if kind == 6 and rng.random() < 0.6:
            bits = rng.choice((0, 4, 5, -1, 2**31 - 1, -(2**31), M._i32(rng)))
            value = struct.unpack("<f", struct.pack("<i", bits))[0]
        else:
            value = M._f(rng)
        raw = name.encode("latin-1")[:16]
        return mavlink2.MAVLink_param_value_message(raw, value, kind, M._u(rng, 16), M._u(rng, 16))

    def position(self) -> Any:
        rng = self.rng
        if rng.random() < 0.7:
            lat = LAT + rng.randrange(-5000, 5000)
            lon = LON + rng.randrange(-5000, 5000)
            rel = rng.randrange(-1000, 20000)
            msl = 50000 + rel if rng.random() < 0.8 else M._i32(rng)
            return mavlink2.MAVLink_global_position_int_message(
                M._u(rng, 32), lat, lon, msl, rel, 0, 0, 0, M._u(rng, 16)
            )
        return mavlink2.MAVLink_global_position_int_message(
            M._u(rng, 32), M._i32(rng), M._i32(rng), M._i32(rng), M._i32(rng),
            *(M._i(rng, 16) for _ in range(3)), M._u(rng, 16),
        )  # fmt: skip

    def any(self, sent: list[int]) -> tuple[Any, bool]:
        """(a message, whether from another system)."""
        rng = self.rng
        r = rng.random()
        foreign = rng.random() < 0.1
        if r < 0.25:
            return self.heartbeat(), foreign
        if r < 0.45:
            return self.ack(sent), foreign
        if r < 0.55:
            return self.param(), foreign
        if r < 0.65:
            return self.position(), foreign
        if r < 0.72:
            text = rng.choice((b"Failsafe: no offboard signal", b"Arming denied: GPS fix too low"))
            if rng.random() < 0.3:
                text = bytes(rng.randrange(256) for _ in range(rng.randrange(51)))
            return mavlink2.MAVLink_statustext_message(M._u(rng, 8), text, 0, 0), foreign
        if r < 0.8:
            landed = rng.choice((0, 1, 2, 3, 4, M._u(rng, 8)))
            return mavlink2.MAVLink_extended_sys_state_message(M._u(rng, 8), landed), foreign
        if r < 0.86:
            return mavlink2.MAVLink_home_position_message(
                M._i32(rng), M._i32(rng), M._i32(rng), M._f(rng), M._f(rng), M._f(rng),
                [M._f(rng)] * 4, M._f(rng), M._f(rng), M._f(rng), M._u(rng, 64),
            ), foreign  # fmt: skip
        if r < 0.92:
            channels = [rng.choice((1100, 1500, 1900, 65535, M._u(rng, 16))) for _ in range(18)]
            return mavlink2.MAVLink_rc_channels_message(
                M._u(rng, 32), M._u(rng, 8), *channels, M._u(rng, 8)
            ), foreign
        return M.message(rng), foreign


def mutate(rng: random.Random, frame: bytes) -> bytes:
    """A damaged frame: a bit flip, truncation, broken CRC, or a splice with noise."""
    f = bytearray(frame)
    kind = rng.randrange(4)
    if kind == 0:
        i = rng.randrange(1, len(f))
        f[i] ^= 1 << rng.randrange(8)
        return bytes(f)
    if kind == 1:
        return bytes(f[: rng.randrange(1, len(f))])
    if kind == 2:
        f[-1 - rng.randrange(2)] ^= 1 << rng.randrange(8)
        return bytes(f)
    return bytes(f[: rng.randrange(1, len(f))]) + M.noise(rng)


# ---------------------------------------------------------------- orders


def order(rng: random.Random) -> tuple[str, tuple[Any, ...]]:
    """An API call with ordinary or hostile arguments."""

    def num(mid: float, spread: float) -> float:
        return rng.choice(HOSTILE) if rng.random() < 0.15 else mid + rng.uniform(-spread, spread)

    kind = rng.choice(
        ("goto", "goto", "goto", "takeoff", "hold", "land", "rtl", "set_mode", "arm", "disarm",
         "request_streams", "cancel_all", "hold_keep")
    )  # fmt: skip
    if kind == "goto":
        return kind, (num(45.5049, 0.001), num(-73.6133, 0.001), num(5.0, 5.0))
    if kind == "takeoff":
        return kind, (num(3.0, 3.0),)
    if kind == "set_mode":
        name = rng.choice((*MODES, OFFBOARD, OFFBOARD, "GUIDED", "", "offboard"))
        return kind, (name,)
    if kind in ("arm", "disarm"):
        return kind, (rng.random() < 0.2,)
    if kind == "request_streams":
        return kind, (num(10.0, 10.0),)
    return kind, ()


def apply_order(core: Px4Core, kind: str, args: tuple[Any, ...]) -> None:
    if kind == "goto":
        core.goto(*args)
    elif kind == "takeoff":
        core.takeoff(*args)
    elif kind in ("hold", "land", "rtl"):
        getattr(core, kind)()
    elif kind == "hold_keep":
        core.hold(keep_guided=True)
    elif kind == "set_mode":
        core.set_mode(*args)
    elif kind in ("arm", "disarm"):
        getattr(core, kind)(force=args[0])
    elif kind == "request_streams":
        core.request_streams(*args)
    else:
        core.cancel_all("fuzz")


# ---------------------------------------------------------------- inputs


_PX4_ENCODER = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
_PACKED: dict[bytes, bytes] = {}


def _packed(msg: Any) -> bytes:
    """A setup message from PX4 as bytes, encoded once (inputs share their setups)."""
    key = msg.get_type().encode() + repr(msg.to_dict()).encode()
    data = _PACKED.get(key)
    if data is None:
        _PX4_ENCODER.seq = 0
        data = _PACKED[key] = bytes(msg.pack(_PX4_ENCODER))
    return data


def make_input(seed: str, k: int) -> tuple[str, bool, list[Event]]:
    """(the starting state, whether with the Spiri's profile, the events)."""
    rng = random.Random(f"{seed}:{k}")
    state = rng.choice(STATES)
    profiled = rng.random() < 0.85
    side = Px4Side(rng)
    events: list[Event] = []
    for _ in range(rng.randrange(1, 25)):
        r = rng.random()
        if r < 0.45:
            frames = []
            for _ in range(rng.randrange(1, 5)):
                msg, foreign = side.any([176, 400, 511])
                frames.append(side.pack(msg, foreign=foreign))
            stream = b"".join(frames)
            cuts = [rng.choice((1, 3, 17, 64, 4096)) for _ in range(4)]
            events.append(("frames", (stream, cuts)))
        elif r < 0.58:
            msg, foreign = side.any([176, 400])
            data = side.pack(msg, foreign=foreign)
            events.append(("mutated", (mutate(rng, data) + bytes(rng.choice((0, 300))), [4096])))
        elif r < 0.63:
            data = M.frame(rng) if rng.random() < 0.6 else M.noise(rng)
            events.append(("generic", (data, [rng.choice((1, 64, 4096))])))
        elif r < 0.82:
            events.append(("time", rng.choice((0.0, 0.01, 0.05, 0.1, 0.1, 0.5, 1.05, 1.5, 3.0))))
        else:
            events.append(("order", order(rng)))
    return state, profiled, events


class Harness:
    """One core on a fake clock, with the checks of the property."""

    def __init__(self, state: str, profiled: bool) -> None:
        self.now = 0.0
        self.core = Px4Core(profile=SPIRI if profiled else None, clock=lambda: self.now)
        self.reader = FrameReader(mavlink2.MAVLink(None))
        self.sent_commands: list[int] = []
        self.lost_at: float | None = None  # when the core saw PX4 leave OFFBOARD
        self.asked_at = -1.0  # the last explicit takeoff / set_mode OFFBOARD
        self.switches = 0
        self.lost = False
        self._setup(state)

    def feed(self, data: bytes, cuts: list[int]) -> None:
        pos = k = 0
        while pos < len(data):
            n = cuts[k % len(cuts)]
            self.core.receive_data(data[pos : pos + n])
            pos, k = pos + n, k + 1

    def _px4(self, msg: Any) -> None:
        self.core.receive_data(_packed(msg))

    def _setup(self, state: str) -> None:
        if state == "silent":
            return
        core = self.core
        self._px4(mavlink2.MAVLink_heartbeat_message(2, 12, 0x51, custom_mode(3), 3, 3))
        self._px4(mavlink2.MAVLink_global_position_int_message(0, LAT, LON, 50000, 0, 0, 0, 0, 0))
        self.check_output()
        if state == "connected":
            return
        self.asked_at = self.now
        core.takeoff(3.0)
        self.step(0.1)
        if state == "taking_off":
            return
        for _ in range(12):  # the warm-up, streamed at 10 Hz: the OFFBOARD switch goes out
            self.step(0.1)
        self._px4(mavlink2.MAVLink_command_ack_message(176, 0, 0, 0, 1, 195))
        self._px4(mavlink2.MAVLink_command_ack_message(400, 0, 0, 0, 1, 195))
        self._px4(mavlink2.MAVLink_heartbeat_message(2, 12, 0x91, OFFBOARD_MODE, 4, 3))
        self._px4(mavlink2.MAVLink_extended_sys_state_message(0, 2))
        self._px4(
            mavlink2.MAVLink_global_position_int_message(0, LAT, LON, 53000, 3000, 0, 0, 0, 0)
        )
        self.check_output()
        assert core._commanded_mode == OFFBOARD and not core.pending, "setup: not in OFFBOARD"

    def step(self, dt: float) -> None:
        self.now += dt
        self.core.tick()

    def check_output(self) -> str | None:
        """The bytes the core wrote: valid frames, sane setpoints, no fighting."""
        core = self.core
        out = core.data_to_send()
        msgs = self.reader.feed(out)
        if self.reader.bad_frames or self.reader.unknown_frames:
            return f"the core wrote a bad frame: {out.hex()}"
        if core.offboard_lost is not None and self.lost_at is None:
            self.lost_at, self.lost = self.now, True
        elif core.offboard_lost is None:
            self.lost_at = None
        for m in msgs:
            kind = m.get_type()
            if kind == "COMMAND_LONG":
                self.sent_commands.append(m.command)
                if m.command == 176 and m.param2 == 6.0:
                    self.switches += 1
                    if self.lost_at is not None and self.asked_at < self.lost_at:
                        return "an OFFBOARD switch after PX4 left OFFBOARD, not asked for since"
            elif kind == "SET_POSITION_TARGET_GLOBAL_INT":
                on_earth = abs(m.lat_int) <= 900_000_000 and abs(m.lon_int) <= 1_800_000_000
                if not (on_earth and math.isfinite(m.alt)):
                    return f"a setpoint off the Earth: {m}"
        return None

    def check_state(self, ticked: bool) -> str | None:
        core = self.core
        if core.link_errors:
            return f"link error: {[e.text for e in core.events if e.kind == 'link'][:1]}"
        problem = sane(core)
        if problem is not None:
            return problem
        if (
            ticked
            and core.setpoint is not None
            and core._setpoint_amsl() is not None
            and core.target_system is not None
            and core._last_setpoint is not None
            and self.now - core._last_setpoint > core.setpoint_interval_s + 1e-9
        ):
            return f"the stream stalled: last setpoint {self.now - core._last_setpoint:.2f} s ago"
        return None


def sane(core: Px4Core) -> str | None:
    """`mavlink_fuzz`'s telemetry checks, on a core."""
    t = core.telemetry
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
    if any(not math.isfinite(v) for v in core.params.values()):
        return f"a parameter read as {core.params}"
    return None


def check(
    state: str, profiled: bool, events: list[Event], stats: Stats | None = None,
    trace: Callable[[str], None] | None = None,
) -> str | None:  # fmt: skip
    """Run the events on a fresh core: the first failure, or None."""
    h = Harness(state, profiled)
    for i, (kind, data) in enumerate(events):
        where = f"event {i} ({kind})"
        if kind in ("frames", "mutated", "generic"):
            h.feed(*data)
        elif kind == "time":
            h.step(data)
        else:
            name, args = data
            if name == "takeoff" or (name == "set_mode" and args == (OFFBOARD,)):
                h.asked_at = h.now
            apply_order(h.core, name, args)
        problem = h.check_output() or h.check_state(ticked=kind == "time")
        if trace is not None:
            t = h.core.telemetry
            trace(f"  {where}: mode {t.mode}, armed {t.armed}, streaming {h.core.streaming}, "
                  f"lost {h.core.offboard_lost!r}")  # fmt: skip
        if problem is not None:
            return f"{where}: {problem}"
    if stats is not None:
        stats.switches += h.switches
        stats.offboard_losses += h.lost
    return None


def _build_and_check(seed: str, k: int, stats: Stats) -> tuple[list[Event], str | None]:
    state, profiled, events = make_input(seed, k)
    stats.kinds[f"start:{state}"] += 1
    return events, check(state, profiled, events, stats)


def run_one(seed: str, k: int, stats: Stats, out: Callable[[str], None]) -> None:
    """Make input k, check it, and record the outcome."""
    runner.run_events(seed, k, stats, out, _build_and_check)


#: run(seed, *, seconds=None, max_inputs=None, start=0, out=print) -> Stats: a campaign.
run = runner.make_run(run_one, Stats, clock_every=16)


def replay(spec: str) -> int:
    """Run input SEED:K verbosely; exit status 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    state, profiled, events = make_input(seed, int(k))
    print(f"start {state}, profile {'spiri' if profiled else 'none'}, {len(events)} events")
    try:
        failure = check(state, profiled, events, trace=print)
    except Exception:
        failure = "raised:\n" + traceback.format_exc()
    print(failure or "ok")
    return 1 if failure else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point: --count N runs exactly N inputs (no time limit)."""
    return runner.counted_main(argv, __doc__, run, replay, Stats, slice_inputs=SLICE)


if __name__ == "__main__":
    sys.exit(main())
