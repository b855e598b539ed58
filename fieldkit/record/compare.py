"""What a replay compares, tick by tick, whatever drove it (a node through a loopback
serial, or a simulated robot's runtime): the outputs a recording holds against a replay's.

    autopilot   every message written, decoded, field by field: MAVLink's (NaN equals NaN;
                the header's sequence number left out: it counts the start-up's writes
                too), an M100's OPEN protocol frames (decrypted with the app key; session
                and sequence number included), a Clearpath MCU's frames
    radio       every frame sent, byte for byte
    order       what the supervisor told the vehicle (kind and numbers)
    state       BVMSTATE, then the script-state digest
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import all as mavlink2

from fieldkit.errors import FieldkitError
from fieldkit.record.flight import FlightTick


class ReplayError(FieldkitError):
    """A flight that cannot be replayed: what is missing or wrong, and where."""


@dataclass(frozen=True)
class Divergence:
    """The first place the replay did something else: tick, channel, expected, got."""

    tick: int
    channel: str
    expected: str
    got: str

    def __str__(self) -> str:
        """One line for the terminal."""
        return f"tick {self.tick}, {self.channel}: expected {self.expected}, got {self.got}"


@dataclass
class ReplayReport:
    """What a replay verified, and where it diverged (None: identical)."""

    ticks: int = 0
    messages: int = 0  # messages to the autopilot compared (MAVLink's, DJI frames...)
    frames: int = 0  # radio frames compared
    digests: int = 0  # script-state digests compared
    divergence: Divergence | None = None
    #: What the node did, tick by tick, when not verifying (an autopilot log's replay).
    replayed: list[FlightTick] = field(default_factory=list)


#: A byte stream to the autopilot as its messages, each a field dict with its name under
#: "mavpackettype" (MAVLink's own key), for the comparison.
Decoder = Callable[[Sequence[bytes]], list[dict[str, object]]]


def mavlink_messages(chunks: Sequence[bytes]) -> list[dict[str, object]]:
    """The MAVLink messages in a byte stream, as field dicts (header fields left out: the
    sequence number counts start-up writes too)."""
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    out: list[dict[str, object]] = []
    for chunk in chunks:
        for m in parser.parse_buffer(chunk) or []:
            if m.get_type() == "BAD_DATA":
                continue
            out.append(m.to_dict())
    return out


def dji_frames(app_key: str) -> Decoder:
    """A decoder of the OPEN protocol frames a host sends an M100, decrypted with `app_key`:
    every header field (session, sequence number, ACK and encryption flags), CMD SET and ID
    and the value; a frame that does not decrypt is its ciphertext, compared as bytes."""
    from fieldkit.vehicle.dji.crypto import FrameCipher
    from fieldkit.vehicle.dji.frame import FrameReader

    cipher = FrameCipher.from_app_key(app_key)

    def decode(chunks: Sequence[bytes]) -> list[dict[str, object]]:
        reader = FrameReader(cipher)
        out: list[dict[str, object]] = []
        for chunk in chunks:
            for f in reader.feed(chunk):
                d = f.describe()
                name = "ACK" if f.ack else f"{f.cmd_set or 0:#04x}/{f.cmd_id or 0:#04x}"
                out.append({"mavpackettype": name, **d, "readable": f.readable})
        return out

    return decode


def clearpath_frames(chunks: Sequence[bytes]) -> list[dict[str, object]]:
    """The frames a host sends a Clearpath MCU: type, flags, timestamp, version, payload."""
    from fieldkit.vehicle.clearpath.frame import FrameReader

    reader = FrameReader()
    out: list[dict[str, object]] = []
    for chunk in chunks:
        for f in reader.feed(chunk):
            out.append({
                "mavpackettype": f"{f.type:#06x}", "type": f.type, "flags": f.flags,
                "timestamp": f.timestamp, "version": f.version, "payload": f.payload.hex(),
            })  # fmt: skip
    return out


def _same(a: object, b: object) -> bool:
    """Field equality in which a NaN equals a NaN (MAVLink uses NaN for "not set")."""
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def compare_tick(
    expected: FlightTick,
    got: FlightTick,
    report: ReplayReport,
    decode: Decoder = mavlink_messages,
) -> Divergence | None:
    """The first difference between a recorded tick and its replay, counting what matched;
    `decode` reads the autopilot's messages out of the bytes written to it."""
    k = expected.tick
    want, have = decode(expected.autopilot_tx), decode(got.autopilot_tx)
    for i, (a, b) in enumerate(zip(want, have, strict=False)):
        diff = sorted(f for f in set(a) | set(b) if not _same(a.get(f), b.get(f)))
        if diff:
            return Divergence(
                k, f"autopilot message {i + 1} of the tick ({a.get('mavpackettype')})",
                f"{ {f: a.get(f) for f in diff} }", f"{ {f: b.get(f) for f in diff} }",
            )  # fmt: skip
        report.messages += 1
    if len(want) != len(have):
        extra = have[len(want) :] or want[len(have) :]
        names = ", ".join(str(m.get("mavpackettype")) for m in extra[:5])
        return Divergence(
            k, "autopilot messages", f"{len(want)} messages", f"{len(have)} ({names} ...)"
        )
    for i, (sent, again) in enumerate(zip(expected.radio_out, got.radio_out, strict=False)):
        if sent != again:
            at = next(
                (j for j, (x, y) in enumerate(zip(sent, again, strict=False)) if x != y), None
            )
            where = f"byte {at}" if at is not None else "the length"
            return Divergence(
                k, f"radio frame {i + 1} of the tick",
                f"{len(sent)} bytes {sent.hex()}", f"{len(again)} bytes, differing at {where}: "
                f"{again.hex()}",
            )  # fmt: skip
        report.frames += 1
    if len(expected.radio_out) != len(got.radio_out):
        return Divergence(
            k, "radio frames", f"{len(expected.radio_out)} frames", f"{len(got.radio_out)}"
        )
    if not _same(expected.order, got.order):
        return Divergence(k, "order to the vehicle", repr(expected.order), repr(got.order))
    if expected.state != got.state:
        return Divergence(k, "script state (BVMSTATE)", repr(expected.state), repr(got.state))
    if expected.digest != got.digest:
        return Divergence(
            k, "script state digest", expected.digest.hex()[:16], got.digest.hex()[:16]
        )
    report.digests += 1
    return None


__all__ = [
    "Decoder",
    "Divergence",
    "ReplayError",
    "ReplayReport",
    "clearpath_frames",
    "compare_tick",
    "dji_frames",
    "mavlink_messages",
]
