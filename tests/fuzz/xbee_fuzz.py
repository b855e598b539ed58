"""Fuzzing the XBee de-framer and the XbeeMav reassembler with hostile input: a seeded campaign.

    python -m tests.fuzz.xbee_fuzz --seconds 60 --seed 1
    python -m tests.fuzz.xbee_fuzz --replay 1:12345      # one input, verbosely

Input k of seed S is made from `random.Random(f"{S}:{k}")`, so every input replays with
`--replay S:k`. Three targets:

* ``deframe``: a byte stream (API mode 1 or 2) of valid frames of every type, unknown types,
  frames too short for their type, random garbage, and mutated frames (bit flips,
  truncation, bad checksums, bad lengths, stray escapes and start bytes, splices), fed to a
  `FrameReader` in random pieces and flushed. Property: no exception; the frames and every
  counter equal those of `reference_deframe`, an independent byte-at-a-time transcription
  of the de-framing rules (fieldkit/radio/xbee.py) on the whole stream; the reader never
  holds more than one maximal escaped frame.
* ``reassemble``: the RF data of XbeeMav packets from several senders — fragments shuffled,
  duplicated or lost, pings, acks, standard packets, random bytes, mutated headers, clock
  jumps past the 30 s timeout — fed to an `XbeeMav` engine that may itself be sending a
  large packet. Property: no exception; memory within the configured caps (partial bytes,
  partials in all and per sender, queues); every frame it emits fits an XBee frame; every
  payload delivered is whole words; when the input is clean (no mutation, no loss, every
  ping after its fragments) and nothing was evicted, every packet is delivered exactly once
  and unchanged, and nothing else is.
* ``radio``: hostile bytes (valid 0x90 frames carrying packets and garbage around them) fed
  to an `XBeeRadio` through pyserial's `loop://` port, polled with a fake clock. Property: no
  exception; every delivered payload is whole words from a known sender.

Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import collections
import random
import sys
import traceback
from collections.abc import Callable

import serial

from fieldkit.radio import xbee as X
from fieldkit.radio import xbeemav as M
from fieldkit.radio.xbee_serial import XBeeRadio

from . import runner

TARGETS = ("deframe", "reassemble", "radio")
INTERESTING = (0x00, 0x01, 0x10, 0x11, 0x13, 0x7D, 0x7E, 0x80, 0x88, 0x8A, 0x8B, 0x90, 0xFE, 0xFF)


class FakeClock:
    """A clock the fuzzer moves by hand."""

    def __init__(self, now: float = 1000.0) -> None:
        self.now = now

    def __call__(self) -> float:
        """The current fake time."""
        return self.now


# ---------------------------------------------------------------- the reference de-framer


def reference_deframe(
    stream: bytes, api_mode: int, cap: int = X.MAX_FRAME_DATA
) -> tuple[list[X.Frame], collections.Counter[str]]:
    """The frames and counters of a whole stream, by the rules, one byte at a time."""
    stats: collections.Counter[str] = collections.Counter()
    out: list[X.Frame] = []
    n = len(stream)
    p = 0
    while p < n:
        if stream[p] != X.START:
            stats["garbage_bytes"] += 1
            p += 1
            continue
        frame_data, end, why = _reference_frame(stream, p, api_mode, cap)
        if frame_data is None:
            stats[why] += 1
            stats["bad_frames"] += 1
            p += 1
            continue
        p = end
        frame = X.parse_frame_data(frame_data)
        if frame is None:
            stats["short_frame" if frame_data[0] in X.MIN_FRAME_DATA else "unknown_type"] += 1
            stats["bad_frames"] += 1
            continue
        stats["frames_in"] += 1
        out.append(frame)
    return out, stats


def _reference_frame(
    stream: bytes, p: int, api_mode: int, cap: int
) -> tuple[bytes | None, int, str]:
    """(frame data, end, "") of a checksummed frame at p, or (None, p, why not)."""
    n = len(stream)
    q = p + 1
    decoded: list[int] = []

    def take(count: int) -> str:
        nonlocal q
        for _ in range(count):
            if q >= n:
                return "truncated"
            b = stream[q]
            if api_mode == 2:
                if b == X.START:
                    return "truncated"
                if b == X.ESCAPE:
                    if q + 1 >= n or stream[q + 1] == X.START:
                        return "truncated"
                    b = stream[q + 1] ^ 0x20
                    if b not in X.SPECIAL:
                        return "bad_escape"
                    q += 1
            decoded.append(b)
            q += 1
        return ""

    why = take(2)
    if why:
        return None, p, why
    length = decoded[0] << 8 | decoded[1]
    if length == 0 or length > cap:
        return None, p, "bad_length"
    why = take(length + 1)
    if why:
        return None, p, why
    body = bytes(decoded[2:])
    if (sum(body) & 0xFF) != 0xFF:  # frame data plus checksum sum to 0xFF
        return None, p, "bad_checksum"
    return body[:-1], q, ""


# ---------------------------------------------------------------- stream generation


def random_frame(rng: random.Random) -> bytes:
    """Frame data of a random frame: any known type, an unknown type, or too short."""
    r = rng.random()
    rf = rng.randbytes(rng.choice((0, 1, 3, 8, 40, rng.randrange(257))))
    if r < 0.35:
        return X.ReceivePacket(
            rng.getrandbits(64), rf, rng.getrandbits(16), rng.randrange(256)
        ).frame_data()
    if r < 0.45:
        return X.TransmitRequest(rf, rng.randrange(256), rng.getrandbits(64)).frame_data()
    if r < 0.55:
        return X.TransmitStatus(rng.randrange(256), 0xFFFE, 0, rng.choice((0, 0x21))).frame_data()
    if r < 0.62:
        return X.ModemStatus(rng.randrange(256)).frame_data()
    if r < 0.68:
        return X.AtResponse(1, rng.choice((b"SH", b"SL")), 0, rng.randbytes(4)).frame_data()
    if r < 0.8:
        # a special-byte-heavy RX: exercises escaping
        special = bytes(rng.choice(INTERESTING) for _ in range(rng.randrange(1, 60)))
        return X.ReceivePacket(0x0013A2007E7D1113, special, 0x7E7D).frame_data()
    if r < 0.9:
        kind = rng.choice((0x00, 0x08, 0x91, 0x95, 0xFF, 0x7E))
        return bytes((kind,)) + rng.randbytes(rng.randrange(20))
    kind = rng.choice(tuple(X.MIN_FRAME_DATA))
    return bytes((kind,)) + rng.randbytes(rng.randrange(X.MIN_FRAME_DATA[kind] - 1))


def frame_with(rng: random.Random, frame_data: bytes, api_mode: int) -> bytes:
    """The API frame of frame data (cut to the cap so it is valid)."""
    return X.frame_bytes(frame_data[: X.MAX_FRAME_DATA], api_mode)


def mutate_frame(rng: random.Random, frame: bytes, api_mode: int) -> tuple[str, bytes]:
    """(kind, a damaged frame)."""
    buf = bytearray(frame)
    r = rng.random()
    if r < 0.2:
        for _ in range(rng.randint(1, 3)):
            buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
        return "flip", bytes(buf)
    if r < 0.4:
        return "truncate", bytes(buf[: rng.randrange(1, len(buf))])
    if r < 0.5:
        buf[-1] ^= rng.randrange(1, 256)
        return "checksum", bytes(buf)
    if r < 0.6:
        length = rng.choice((0, X.MAX_FRAME_DATA + 1, 0xFFFF, 0x7E7E, rng.randrange(0x10000)))
        buf[1:3] = length.to_bytes(2, "big")
        return "length", bytes(buf)
    if r < 0.7:
        buf.insert(rng.randrange(1, len(buf) + 1), rng.choice((X.ESCAPE, X.START)))
        return "stray", bytes(buf)
    if r < 0.8 and api_mode == 2:
        i = rng.randrange(1, len(buf))
        buf[i : i + 1] = bytes((X.ESCAPE, rng.randrange(256)))
        return "escape", bytes(buf)
    if r < 0.9:
        buf[rng.randrange(len(buf))] = rng.choice(INTERESTING)
        return "byte", bytes(buf)
    other = frame_with(rng, random_frame(rng), api_mode)
    i, j = rng.randrange(len(buf) + 1), rng.randrange(len(other) + 1)
    return "splice", bytes(buf[:i]) + other[j:]


def deframe_input(rng: random.Random) -> tuple[str, int, bytes]:
    """(kind, API mode, stream)."""
    api_mode = rng.choice((1, 2))
    if rng.random() < 0.05:
        return "random", api_mode, rng.randbytes(rng.randrange(600))
    parts = []
    kinds = set()
    for _ in range(rng.randint(1, 8)):
        r = rng.random()
        if r < 0.45:
            parts.append(frame_with(rng, random_frame(rng), api_mode))
            kinds.add("valid")
        elif r < 0.75:
            kind, bad = mutate_frame(rng, frame_with(rng, random_frame(rng), api_mode), api_mode)
            parts.append(bad)
            kinds.add(kind)
        else:
            junk = rng.randbytes(rng.randrange(1, 40))
            if rng.random() < 0.5:
                junk = bytes(rng.choice(INTERESTING) for _ in junk)
            parts.append(junk)
            kinds.add("garbage")
    return "+".join(sorted(kinds)), api_mode, b"".join(parts)


def split(rng: random.Random, stream: bytes, bytewise: bool = True) -> list[bytes]:
    """The stream in random pieces (single bytes, small, large, or whole)."""
    r = rng.random()
    if r < 0.15:
        return [stream]
    if r < 0.3 and bytewise:
        return [stream[i : i + 1] for i in range(len(stream))]
    cuts = sorted(rng.randrange(len(stream) + 1) for _ in range(rng.randrange(1, 12)))
    return [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]


def check_deframe(rng: random.Random, api_mode: int, stream: bytes) -> str | None:
    """Failure description, or None."""
    reader = X.FrameReader(api_mode)
    bound = 2 * (X.MAX_FRAME_DATA + 3) + 1
    got: list[X.Frame] = []
    for piece in split(rng, stream):
        got += reader.feed(piece)
        if reader.pending > bound:
            return f"reader holds {reader.pending} bytes > {bound}"
    got += reader.flush()
    if reader.pending:
        return f"{reader.pending} bytes left after flush"
    want, stats = reference_deframe(stream, api_mode)
    if got != want:
        return f"frames differ: got {len(got)}, reference {len(want)}"
    mine = {k: v for k, v in reader.stats.items() if v}
    theirs = {k: v for k, v in stats.items() if v}
    if mine != theirs:
        return f"counters differ: {mine} vs reference {theirs}"
    return None


# ---------------------------------------------------------------- reassembly


def _payload(rng: random.Random, words: int) -> bytes:
    return rng.randbytes(8 * words)


def _fragments(address: int, payload: bytes, pid: int) -> list[bytes]:
    """The RF data an XbeeMav sender emits for one large packet: fragments then the ping."""
    clock = FakeClock()
    sender = M.XbeeMav(address, clock=clock, interframe_s=0, round_wait_s=0.5)
    sender.submit(payload, pid)
    return sender.pump()


def reassemble_input(rng: random.Random) -> tuple[str, dict[str, object]]:
    """(kind, a scenario for check_reassemble)."""
    own = rng.randrange(256)
    senders = [s for s in rng.sample(range(256), rng.randint(1, 4)) if s != own] or [
        (own + 1) % 256
    ]
    clean = rng.random() < 0.4
    packets = []
    used: set[tuple[int, int]] = set()
    for _ in range(rng.randint(1, 5)):
        s = rng.choice(senders)
        pid = rng.randrange(256)
        if (s, pid) in used:
            continue
        used.add((s, pid))
        words = rng.choice((31, 32, 40, rng.randint(31, 250), rng.randint(31, 1000)))
        if rng.random() < 0.01:
            words = M.MAX_DATA // 8
        packets.append((s, pid, _payload(rng, words)))
    streams = []
    for s, pid, payload in packets:
        rfs = _fragments(s, payload, pid)
        frags, ping = rfs[:-1], rfs[-1]
        events = [(s, f) for f in frags]
        if rng.random() < 0.5:
            events += [(s, f) for f in rng.sample(frags, rng.randint(0, len(frags)))]
        rng.shuffle(events)
        if not clean and rng.random() < 0.5 and events:
            del events[rng.randrange(len(events))]
        events.append((s, ping))
        if not clean and rng.random() < 0.3:
            events.append((s, ping))
        streams.append(events)
    # Merge the packets' event lists, each in its own order.
    merged: list[tuple[int, bytes] | float] = []
    while any(streams):
        i = rng.choice([i for i, st in enumerate(streams) if st])
        merged.append(streams[i].pop(0))
    kinds = {"clean" if clean else "dirty"}
    if not clean:
        for _ in range(rng.randint(1, 10)):
            r = rng.random()
            at = rng.randrange(len(merged) + 1)
            s = rng.choice(senders)
            if r < 0.25:
                merged.insert(at, (s, rng.randbytes(rng.randrange(0, 300))))
                kinds.add("random")
            elif r < 0.45:
                head = rng.choice((b"F", b"P", b"A", b"S", b"Q"))
                body = bytes(rng.choice(INTERESTING) for _ in range(rng.randrange(0, 12)))
                merged.insert(at, (s, head + body + rng.randbytes(rng.choice((0, 1, 250, 251)))))
                kinds.add("header")
            elif r < 0.65 and merged:
                j = rng.randrange(len(merged))
                ev = merged[j]
                if isinstance(ev, tuple) and ev[1]:
                    rf = bytearray(ev[1])
                    rf[rng.randrange(len(rf))] = rng.choice(INTERESTING)
                    merged[j] = (ev[0], bytes(rf))
                kinds.add("mutate")
            elif r < 0.8:
                merged.insert(at, rng.choice((0.3, 1.0, 31.0, 61.0)))
                kinds.add("clock")
            else:
                missing = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 5)))
                merged.insert(at, (s, b"A" + bytes((rng.randrange(256), s)) + missing))
                kinds.add("ack")
    scenario: dict[str, object] = {
        "own": own,
        "clean": clean,
        "packets": packets,
        "events": merged,
        "per_sender": rng.choice((1, 2, 3)),
        "max_partials": rng.choice((2, 4, 64)),
        "send_large": rng.random() < 0.3,
    }
    return "+".join(sorted(kinds)), scenario


def check_reassemble(rng: random.Random, scenario: dict[str, object]) -> str | None:
    """Failure description, or None."""
    clock = FakeClock()
    own = scenario["own"]
    assert isinstance(own, int)
    per_sender = scenario["per_sender"]
    max_partials = scenario["max_partials"]
    assert isinstance(per_sender, int) and isinstance(max_partials, int)
    engine = M.XbeeMav(
        own,
        clock=clock,
        interframe_s=0.05,
        max_partials_per_sender=per_sender,
        max_partials=max_partials,
        max_partial_bytes=M.MAX_PACKET,
        max_ack_queue=8,
        max_standard_queue=4,
    )
    if scenario["send_large"]:
        engine.submit(rng.randbytes(8 * rng.randint(31, 100)), rng.randrange(256))
        engine.submit(rng.randbytes(8), 3)
    delivered: list[tuple[int, bytes]] = []
    events = scenario["events"]
    assert isinstance(events, list)
    for ev in events:
        if isinstance(ev, float):
            clock.now += ev
        else:
            sender, rf = ev
            data = engine.receive(sender, rf)
            if data is not None:
                if not data or len(data) % 8 or len(data) > M.MAX_DATA:
                    return f"delivered {len(data)} bytes: not whole words within MAX_DATA"
                delivered.append((sender, data))
        clock.now += 0.01
        for out in engine.pump():
            if not 0 < len(out) <= M.MAX_RF_DATA:
                return f"emitted {len(out)} bytes of RF data"
        if engine.partial_bytes > engine.max_partial_bytes:
            return f"partial bytes {engine.partial_bytes} over the cap"
        if engine.partials > max_partials:
            return f"{engine.partials} partials > {max_partials}"
        if any(v > per_sender for v in engine._per_sender.values()):
            return "a sender holds more partials than allowed"
        if engine.queued > 8 + 4 + 4 + 1:
            return f"{engine.queued} frames queued"
        if len(engine._delivered) > engine.max_delivered:
            return "delivered memory over its cap"
    # Past every timeout: nothing may be left.
    clock.now += 100.0
    engine.pump()
    if engine.partials or engine.partial_bytes:
        return "partial packets survive the timeout"
    if engine.transferring:
        for _ in range(300):  # drain the transfer's frames, then its deadline
            clock.now += 1.0
            engine.pump()
        if engine.transferring:
            return "a transfer outlives its deadline"
    packets = scenario["packets"]
    assert isinstance(packets, list)
    originals = {(s, p) for s, _, p in packets}
    if scenario["clean"]:
        evicted = engine.stats["partials_evicted"] + engine.stats["partials_expired"]
        if any(d not in originals for d in delivered):
            return "a clean input delivered a packet that was never sent"
        if len(set(delivered)) != len(delivered):
            return "a packet delivered twice"
        if not evicted and sorted(delivered) != sorted(originals):
            return f"delivered {len(delivered)} of {len(originals)} clean packets, none evicted"
    return None


# ---------------------------------------------------------------- the whole radio


def radio_input(rng: random.Random) -> tuple[str, dict[str, object]]:
    """(kind, bytes for an XBeeRadio's serial port, its API mode)."""
    api_mode = rng.choice((1, 2))
    serials = [0x0013A20000000000 + i for i in range(4)]
    parts = []
    for _ in range(rng.randint(1, 12)):
        r = rng.random()
        src = rng.choice((*serials, rng.getrandbits(64)))
        if r < 0.4:
            words = rng.choice((1, 6, 29, 30))
            rf = b"S" + bytes((rng.randrange(256), rng.randrange(256))) + rng.randbytes(8 * words)
        elif r < 0.7:
            payload = rng.randbytes(8 * rng.randint(31, 80))
            frags = _fragments(rng.randrange(4), payload, rng.randrange(256))
            for f in frags:
                parts.append(X.receive_packet(src, f, api_mode=api_mode))
            continue
        elif r < 0.85:
            rf = rng.randbytes(rng.randrange(1, 256))
        else:
            parts.append(rng.randbytes(rng.randrange(1, 60)))
            continue
        frame = X.receive_packet(src, rf, api_mode=api_mode)
        if rng.random() < 0.2:
            _, frame = mutate_frame(rng, frame, api_mode)
        parts.append(frame)
    return "radio", {"api_mode": api_mode, "stream": b"".join(parts), "serials": serials}


def check_radio(rng: random.Random, scenario: dict[str, object]) -> str | None:
    """Failure description, or None."""
    clock = FakeClock()
    serials = scenario["serials"]
    stream = scenario["stream"]
    api_mode = scenario["api_mode"]
    assert isinstance(serials, list) and isinstance(stream, bytes) and isinstance(api_mode, int)
    port = serial.serial_for_url("loop://", timeout=0)
    radio = XBeeRadio(
        port,
        9,
        api_mode=api_mode,
        id_map={f"{s:016X}": i for i, s in enumerate(serials)},
        unknown=rng.choice(("drop", "sysid")),
        clock=clock,
        interframe_s=0.05,
    )
    try:
        pieces = [
            p[i : i + 1024] for p in split(rng, stream, False) for i in range(0, len(p), 1024)
        ]
        for piece in pieces:
            port.write(piece)  # loop:// holds 4 KiB: the radio reads before it writes more
            for sender, data in radio.poll():
                if not data or len(data) % 8:
                    return f"delivered {len(data)} bytes"
                if radio.unknown == "drop" and not 0 <= sender < len(serials):
                    return f"delivered from sender {sender} under the drop policy"
            clock.now += rng.choice((0.0, 0.05, 0.2))
        clock.now += 100
        radio.poll()
        if radio.engine.partials:
            return "partials survive the timeout"
    finally:
        radio.close()
    return None


# ---------------------------------------------------------------- the campaign


def run_one(seed: str, k: int) -> tuple[str, str | None]:
    """(kind, failure or None) of input k."""
    rng = random.Random(f"{seed}:{k}")
    target = rng.choices(TARGETS, weights=(12, 6, 1))[0]
    try:
        if target == "deframe":
            kind, api_mode, stream = deframe_input(rng)
            return f"deframe/{kind}", check_deframe(rng, api_mode, stream)
        if target == "reassemble":
            kind, scenario = reassemble_input(rng)
            return f"reassemble/{kind}", check_reassemble(rng, scenario)
        kind, scenario = radio_input(rng)
        return f"radio/{kind}", check_radio(rng, scenario)
    except Exception:
        return target, "unexpected exception:\n" + traceback.format_exc()


def record(seed: str, k: int, stats: runner.Stats, out: Callable[[str], None]) -> None:
    """Run input k and record the outcome."""
    kind, failure = run_one(seed, k)
    stats.kinds[kind.split("/")[0]] += 1
    if failure is not None:
        stats.fail(f"{seed}:{k}", f"FAIL {seed}:{k} ({kind}): {failure}", out)


#: run(seed, *, seconds=None, max_inputs=None, start=0, out=print) -> Stats: a campaign.
run = runner.make_run(record, runner.Stats, clock_every=64)


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
