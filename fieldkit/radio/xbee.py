"""XBee API frames: building them, and de-framing the serial byte stream.

The frame format: docs/bundle.md#xbee-api-frames and #worked-example.

A frame is ``7E | length (u16 BE) | frame data | checksum``: the length counts the frame
data, the checksum is ``0xFF - (sum of the frame data & 0xFF)``. In API mode 1 (AP=1, what
XbeeMav radios run) nothing is escaped; in API mode 2 (AP=2) every byte after the 7E that is
0x7E, 0x7D, 0x11 or 0x13 travels as ``7D, byte ^ 0x20``.

Frame types handled: transmit request 0x10 (what we write: broadcast to
0x000000000000FFFF), receive packet 0x90 (what we read), transmit status 0x8B and modem
status 0x8A (read, counted, otherwise ignored), AT command response 0x88 (parsed; the
answer to the local AT command 0x08 that `fieldkit doctor` writes to ask the module its
settings).
`transmit_request` reproduces XbeeMav's frame byte for byte: frame id 1, 16-bit destination
FF FF (Digi documents FF FE, "unknown", but XbeeMav sends FF FF and DigiMesh ignores the
field), radius 0, options 0 — the docs/bundle.md#worked-example frame
``7e 00 51 10 01 00..00 ff ff ff ff 00 00``.

`FrameReader` is the streaming de-framer: `feed(bytes)` returns the complete, checksummed
frames and keeps any partial one for the next call, so any split of a stream gives the same
frames as the whole. It never raises on any bytes. Its rules, which `tests/fuzz/xbee_fuzz.py`
checks against a byte-at-a-time reference:

* a candidate frame starts at any 0x7E; a candidate that fails (length 0 or over
  `max_length`, bad checksum, a bad escape, a raw 0x7E inside an escaped frame, or still
  incomplete at `flush`) is abandoned and the search resumes at the byte after its 0x7E —
  in API mode 1 a 0x7E is also an ordinary data byte, so a stray 0x7E must not swallow the
  real frames that follow it;
* a checksummed frame is consumed whole, even when its type is unknown or it is too short
  for its type (counted, not returned): the checksum says it is a real frame, whose insides
  must not be searched for frames;
* `flush()` declares the burst over: what is still incomplete was truncated. The radio calls
  it when the line has been idle for a while (a module writes a frame in one go, about 12 ms
  for the largest at 230400 baud), so a truncated frame cannot hold back the frames after it.

Counters (in `stats`, a Counter that a radio shares): frames_in, bad_checksum, bad_length,
bad_escape, truncated, short_frame, unknown_type, bad_frames (the sum of the six), and
garbage_bytes (bytes skipped while hunting for a 0x7E, including the insides of abandoned
candidates).

Why not digi-xbee's packet classes (docs/third-party.md#digi-xbee)? We tried them and test
against them (tests/test_xbee.py builds and parses the same frames with digi-xbee 1.5.0),
but the radio does not use them at run time: (1) the de-framer is ours anyway (digi-xbee
only de-frames inside its device reader thread), and once it has checked length and
checksum, what is left
is slicing 12 fixed bytes off a 0x90; (2) `build_frame` raises a family of exceptions on
hostile bytes, re-verifies what we verified, and parsing a 0x90 with it takes 5 to 8 times
as long as `FrameReader.feed` de-framing and parsing it (~44 µs a frame, idle 2-core box);
(3) its `TransmitPacket` examples use the 16-bit address FF FE, not XbeeMav's FF FF; (4) it
would add a dependency to every robot's companion computer for ~40 lines of struct packing.
"""

from __future__ import annotations

import re
import struct
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

from fieldkit.errors import FrameError

START = 0x7E
"""The frame start delimiter."""
ESCAPE = 0x7D
"""API mode 2's escape byte: the next byte is XORed with 0x20."""
SPECIAL = frozenset((0x7E, 0x7D, 0x11, 0x13))
"""Bytes API mode 2 escapes: start, escape, XON, XOFF."""
TX_REQUEST = 0x10
"""Frame type: transmit request (host -> module)."""
RX_PACKET = 0x90
"""Frame type: receive packet (module -> host)."""
TX_STATUS = 0x8B
"""Frame type: transmit status (module -> host, when the request's frame id is not 0)."""
MODEM_STATUS = 0x8A
"""Frame type: modem status (module -> host)."""
AT_RESPONSE = 0x88
"""Frame type: AT command response (module -> host)."""
AT_COMMAND = 0x08
"""Frame type: local AT command (host -> module): a query or a setting, answered by 0x88."""
AT_QUEUE = 0x09
"""Frame type: AT command, queued (host -> module: XbeeMav asks "SL"/"SH" with it)."""
BROADCAST64 = 0x000000000000FFFF
"""The 64-bit broadcast address."""
XBEEMAV_DEST16 = 0xFFFF
"""The 16-bit destination XbeeMav writes (docs/bundle.md#xbee-api-frames, #worked-example)."""
UNKNOWN16 = 0xFFFE
"""Digi's "16-bit address unknown" value, what receive packets carry on DigiMesh."""
RX_OPT_BROADCAST = 0x02
"""Receive-options bit: the packet was a broadcast."""
MAX_FRAME_DATA = 270
"""The longest frame data accepted: XbeeMav treats longer frames as corrupt
(docs/bundle.md#xbee-api-frames).

It fits a transmit request with 256 bytes of RF data (XbeeMav's largest: a 6-byte fragment
header and 250 bytes), 14 + 256 = 270.
"""
API_MODES: tuple[int, ...] = (1, 2)
"""AP=1: no escaping (XbeeMav); AP=2: escaped."""

_ESCAPE_RE = re.compile(b"[\x7e\x7d\x11\x13]")
_TX_HEAD = struct.Struct(">BBQHBB")
_RX_HEAD = struct.Struct(">BQHB")
_TX_STATUS = struct.Struct(">BBHBBB")
_AT_HEAD = struct.Struct(">BB2sB")


class _ApiFrame:
    """What every frame class shares: its API frame is its frame data, framed."""

    __slots__ = ()

    def frame_data(self) -> bytes:
        """The frame data: type byte, fields and payload."""
        raise NotImplementedError

    def encode(self, api_mode: int = 1) -> bytes:
        """The whole API frame in `api_mode`."""
        return frame_bytes(self.frame_data(), api_mode)


@dataclass(frozen=True, slots=True)
class TransmitRequest(_ApiFrame):
    """Frame 0x10: send `rf_data` to `dest64` (broadcast by default)."""

    rf_data: bytes
    frame_id: int = 1
    dest64: int = BROADCAST64
    dest16: int = XBEEMAV_DEST16
    radius: int = 0
    options: int = 0

    def frame_data(self) -> bytes:
        """The frame data: type byte, header fields, RF data."""
        head = _TX_HEAD.pack(
            TX_REQUEST, self.frame_id, self.dest64, self.dest16, self.radius, self.options
        )
        return head + self.rf_data


@dataclass(frozen=True, slots=True)
class ReceivePacket(_ApiFrame):
    """Frame 0x90: `rf_data` received from the radio with serial `source64`."""

    source64: int
    rf_data: bytes
    source16: int = UNKNOWN16
    options: int = RX_OPT_BROADCAST

    def frame_data(self) -> bytes:
        """The frame data: type byte, header fields, RF data."""
        return _RX_HEAD.pack(RX_PACKET, self.source64, self.source16, self.options) + self.rf_data


@dataclass(frozen=True, slots=True)
class TransmitStatus(_ApiFrame):
    """Frame 0x8B: the outcome of the transmit request with `frame_id` (0 = success)."""

    frame_id: int
    dest16: int = UNKNOWN16
    retries: int = 0
    delivery_status: int = 0
    discovery_status: int = 0

    def frame_data(self) -> bytes:
        """The frame data: type byte and fields."""
        return _TX_STATUS.pack(
            TX_STATUS,
            self.frame_id,
            self.dest16,
            self.retries,
            self.delivery_status,
            self.discovery_status,
        )


@dataclass(frozen=True, slots=True)
class ModemStatus(_ApiFrame):
    """Frame 0x8A: a modem event (0 hardware reset, 1 watchdog reset, ...)."""

    status: int

    def frame_data(self) -> bytes:
        """The frame data: type byte and status."""
        return bytes((MODEM_STATUS, self.status))


@dataclass(frozen=True, slots=True)
class AtResponse(_ApiFrame):
    """Frame 0x88: the answer to an AT command (e.g. b"SH"/b"SL", the serial halves)."""

    frame_id: int
    command: bytes
    status: int
    data: bytes = b""

    def frame_data(self) -> bytes:
        """The frame data: type byte, fields, command data."""
        return _AT_HEAD.pack(AT_RESPONSE, self.frame_id, self.command, self.status) + self.data


@dataclass(frozen=True, slots=True)
class AtCommand(_ApiFrame):
    """Frame 0x08: a local AT command, e.g. b"AP" (a query without `parameter`); the module
    answers with an `AtResponse` of the same frame id (0: no answer). Host to module only:
    `FrameReader` counts one as an unknown type, since no module sends it."""

    frame_id: int
    command: bytes
    parameter: bytes = b""

    def frame_data(self) -> bytes:
        """The frame data: type byte, frame id, the two command letters, the parameter."""
        if len(self.command) != 2:
            raise ValueError(f"an AT command is two letters, got {self.command!r}")
        return bytes((AT_COMMAND, self.frame_id)) + self.command + self.parameter


Frame = TransmitRequest | ReceivePacket | TransmitStatus | ModemStatus | AtResponse
"""Any frame `FrameReader` returns."""

#: Shortest frame data of each known type (type byte included).
MIN_FRAME_DATA: dict[int, int] = {
    TX_REQUEST: _TX_HEAD.size,
    RX_PACKET: _RX_HEAD.size,
    TX_STATUS: _TX_STATUS.size,
    MODEM_STATUS: 2,
    AT_RESPONSE: _AT_HEAD.size,
}


def checksum(frame_data: bytes) -> int:
    """The API frame checksum of `frame_data`."""
    return 0xFF - (sum(frame_data) & 0xFF)


def _escape_one(m: re.Match[bytes]) -> bytes:
    return bytes((ESCAPE, m[0][0] ^ 0x20))


def escape(data: bytes) -> bytes:
    """API mode 2 escaping of `data` (everything after the start delimiter)."""
    return _ESCAPE_RE.sub(_escape_one, data)


def frame_bytes(frame_data: bytes, api_mode: int = 1) -> bytes:
    """The API frame carrying `frame_data` (type byte first) in API mode 1 or 2.

    ValueError for an empty frame or one longer than MAX_FRAME_DATA (no reader would take it).
    """
    if api_mode not in API_MODES:
        raise ValueError(f"API mode must be 1 or 2, got {api_mode!r}")
    n = len(frame_data)
    if not 0 < n <= MAX_FRAME_DATA:
        raise ValueError(f"frame data of {n} bytes, must be 1..{MAX_FRAME_DATA}")
    body = n.to_bytes(2, "big") + frame_data + bytes((checksum(frame_data),))
    return b"\x7e" + (escape(body) if api_mode == 2 else body)


def transmit_request(
    rf_data: bytes,
    *,
    frame_id: int = 1,
    dest64: int = BROADCAST64,
    dest16: int = XBEEMAV_DEST16,
    radius: int = 0,
    options: int = 0,
    api_mode: int = 1,
) -> bytes:
    """A 0x10 frame broadcasting `rf_data`, by default exactly as XbeeMav writes it."""
    return TransmitRequest(rf_data, frame_id, dest64, dest16, radius, options).encode(api_mode)


def receive_packet(
    source64: int,
    rf_data: bytes,
    *,
    source16: int = UNKNOWN16,
    options: int = RX_OPT_BROADCAST,
    api_mode: int = 1,
) -> bytes:
    """A 0x90 frame as a module writes it on receiving `rf_data` from `source64`."""
    return ReceivePacket(source64, rf_data, source16, options).encode(api_mode)


def parse_frame_data(data: bytes) -> Frame | None:
    """The frame in checksummed frame data, or None if its type is unknown or it is too short."""
    kind = data[0]
    least = MIN_FRAME_DATA.get(kind)
    if least is None or len(data) < least:
        return None
    if kind == RX_PACKET:
        _, src64, src16, opts = _RX_HEAD.unpack_from(data)
        return ReceivePacket(src64, data[_RX_HEAD.size :], src16, opts)
    if kind == TX_STATUS:
        return TransmitStatus(*_TX_STATUS.unpack_from(data)[1:])
    if kind == MODEM_STATUS:
        return ModemStatus(data[1])
    if kind == TX_REQUEST:
        _, fid, dest64, dest16, radius, opts = _TX_HEAD.unpack_from(data)
        return TransmitRequest(data[_TX_HEAD.size :], fid, dest64, dest16, radius, opts)
    _, fid, cmd, status = _AT_HEAD.unpack_from(data)
    return AtResponse(fid, cmd, status, data[_AT_HEAD.size :])


# Outcomes of _unescape.
_OK, _SHORT, _BAD = 0, 1, 2


def _unescape(buf: bytearray, r: int, limit: int, need: int) -> tuple[bytes, int, int]:
    """(`need` unescaped bytes from buf[r:limit], raw end, outcome).

    `limit` is the next 0x7E (or the end of the buffer): an escaped frame never contains one.
    _SHORT if buf[r:limit] holds fewer than `need` bytes; _BAD if an escape is not followed
    by an escaped special byte.
    """
    out = bytearray()
    while True:
        want = need - len(out)
        if want <= 0:
            return bytes(out), r, _OK
        k = buf.find(ESCAPE, r, limit)
        if k < 0 or k - r >= want:
            take = min(want, limit - r)
            out += buf[r : r + take]
            r += take
            return bytes(out), r, _OK if take == want else _SHORT
        out += buf[r:k]
        if k + 1 >= limit:
            return bytes(out), k, _SHORT
        x = buf[k + 1] ^ 0x20
        if x not in SPECIAL:
            return bytes(out), k, _BAD
        out.append(x)
        r = k + 2


class FrameReader:
    """Streaming de-framer: bytes in any pieces -> checksummed API frames; never raises.

    Holds at most one candidate frame between calls (at most 2·(max_length + 3) + 1 bytes in
    API mode 2), so its memory is bounded whatever it is fed.
    """

    def __init__(
        self,
        api_mode: int = 1,
        *,
        max_length: int = MAX_FRAME_DATA,
        stats: Counter[str] | None = None,
    ) -> None:
        if api_mode not in API_MODES:
            raise ValueError(f"API mode must be 1 or 2, got {api_mode!r}")
        if not 0 < max_length <= 0xFFFF:
            raise ValueError(f"max_length must be 1..65535, got {max_length}")
        self.api_mode = api_mode
        self.max_length = max_length
        self.stats: Counter[str] = Counter() if stats is None else stats
        self._buf = bytearray()

    @property
    def pending(self) -> int:
        """Bytes held: the start of a frame not yet complete."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Frame]:
        """The frames completed by `data` (any bytes-like; never raises)."""
        self._buf += data
        return self._scan(final=False)

    def flush(self) -> list[Frame]:
        """End of a burst: abandon incomplete candidates as truncated, return what follows."""
        return self._scan(final=True)

    def feed_data(self, data: bytes) -> list[bytes]:
        """`feed`, but the frame data (type byte first) of every checksummed frame it completes,
        unknown types and frames too short for their type included: an inspector shows those
        too. The counters move exactly as `feed` moves them."""
        self._buf += data
        raw: list[bytes] = []
        self._scan(final=False, raw=raw)
        return raw

    def flush_data(self) -> list[bytes]:
        """`flush`, returning frame data as `feed_data` does."""
        raw: list[bytes] = []
        self._scan(final=True, raw=raw)
        return raw

    def reset(self) -> None:
        """Forget any buffered bytes (e.g. after reopening the port), uncounted."""
        self._buf.clear()

    def _scan(self, final: bool, raw: list[bytes] | None = None) -> list[Frame]:
        buf = self._buf
        n = len(buf)
        stats = self.stats
        out: list[Frame] = []
        pos = 0
        garbage = 0
        escaped = self.api_mode == 2
        cap = self.max_length
        while pos < n:
            i = buf.find(START, pos)
            if i < 0:
                garbage += n - pos
                pos = n
                break
            garbage += i - pos
            pos = i
            if escaped:
                j = buf.find(START, i + 1)
                limit = n if j < 0 else j
                head, r, outcome = _unescape(buf, i + 1, limit, 2)
                if outcome == _OK:
                    length = head[0] << 8 | head[1]
                    if length == 0 or length > cap:
                        self._bad(stats, "bad_length")
                        pos = i + 1
                        continue
                    body, r, outcome = _unescape(buf, r, limit, length + 1)
                if outcome == _BAD:
                    self._bad(stats, "bad_escape")
                    pos = i + 1
                    continue
                if outcome == _SHORT:
                    if j < 0 and not final:
                        break  # wait for the rest
                    self._bad(stats, "truncated")
                    pos = i + 1
                    continue
                frame_data = body[:-1]
                check = body[-1]
                end = r
            else:
                if n - i < 3:
                    if not final:
                        break
                    self._bad(stats, "truncated")
                    pos = i + 1
                    continue
                length = buf[i + 1] << 8 | buf[i + 2]
                if length == 0 or length > cap:
                    self._bad(stats, "bad_length")
                    pos = i + 1
                    continue
                end = i + 4 + length
                if end > n:
                    if not final:
                        break
                    self._bad(stats, "truncated")
                    pos = i + 1
                    continue
                frame_data = bytes(buf[i + 3 : end - 1])
                check = buf[end - 1]
            if (sum(frame_data) + check) & 0xFF != 0xFF:
                self._bad(stats, "bad_checksum")
                pos = i + 1
                continue
            pos = end
            if raw is not None:
                raw.append(bytes(frame_data))
            frame = parse_frame_data(frame_data)
            if frame is None:
                known = frame_data[0] in MIN_FRAME_DATA
                self._bad(stats, "short_frame" if known else "unknown_type")
                continue
            stats["frames_in"] += 1
            out.append(frame)
        if garbage:
            stats["garbage_bytes"] += garbage
        del buf[:pos]
        return out

    @staticmethod
    def _bad(stats: Counter[str], what: str) -> None:
        stats[what] += 1
        stats["bad_frames"] += 1


# ------------------------------------------------------------------ the inspector's view

#: Names `describe_frame` gives the frame types it knows.
FRAME_NAMES: dict[int, str] = {
    TX_REQUEST: "transmit_request",
    RX_PACKET: "receive_packet",
    TX_STATUS: "transmit_status",
    MODEM_STATUS: "modem_status",
    AT_RESPONSE: "at_response",
    AT_COMMAND: "at_command",
    AT_QUEUE: "at_command_queue",
}
#: Shortest frame data `describe_frame` accepts per type: the radio's, and the AT commands'
#: (type, frame id, two command letters).
_MIN_DESCRIBED: dict[int, int] = {**MIN_FRAME_DATA, AT_COMMAND: 4, AT_QUEUE: 4}
#: Where the RF data starts in the frame data of the types that carry it.
_RF_START: dict[int, int] = {TX_REQUEST: _TX_HEAD.size, RX_PACKET: _RX_HEAD.size}
#: FrameReader counters of candidates it abandoned (the rest are frames it consumed).
_REJECTED = ("bad_checksum", "bad_length", "bad_escape", "truncated")

Offsets = Callable[[int], int]
"""Maps an offset in the frame data (its length: the checksum) to the offset in the frame."""


def _unescaped(frame: bytes, api_mode: int) -> tuple[bytes, list[int], FrameError | None]:
    """frame[1:] unescaped, the offset in `frame` of each byte, and the first bad escape
    (API mode 2: the bytes before it are returned, the caller decides if it matters)."""
    n = len(frame)
    if api_mode == 1:
        return frame[1:], list(range(1, n)), None
    out = bytearray()
    where: list[int] = []
    i = 1
    while i < n:
        b = frame[i]
        if b == START:
            return bytes(out), where, FrameError("a raw 0x7e inside an API mode 2 frame", i)
        if b == ESCAPE:
            if i + 1 == n:
                return bytes(out), where, FrameError("the frame ends inside an escape", n)
            x = frame[i + 1] ^ 0x20
            if x not in SPECIAL:
                what = f"0x7d escapes 0x{frame[i + 1]:02x}, not one of 7e 7d 11 13 (xor 0x20)"
                return bytes(out), where, FrameError(what, i + 1)
            out.append(x)
            where.append(i)
            i += 2
        else:
            out.append(b)
            where.append(i)
            i += 1
    return bytes(out), where, None


def _layout(frame: bytes, api_mode: int) -> tuple[bytes, int, Offsets]:
    """(frame data, checksum, offsets) of exactly one API frame; FrameError where it is bad.

    The same rules as `FrameReader`: start delimiter, length 1..MAX_FRAME_DATA, API mode 2
    escapes, checksum; and nothing after the checksum.
    """
    if api_mode not in API_MODES:
        raise ValueError(f"API mode must be 1 or 2, got {api_mode!r}")
    n = len(frame)
    if n == 0:
        raise FrameError("empty frame", 0)
    if frame[0] != START:
        raise FrameError(f"0x{frame[0]:02x} is not the start delimiter 0x7e", 0)
    body, where, bad = _unescaped(frame, api_mode)
    if len(body) < 2:
        raise bad or FrameError("the frame ends before its length field", n)
    length = body[0] << 8 | body[1]
    if not 0 < length <= MAX_FRAME_DATA:
        raise FrameError(f"length {length}, must be 1..{MAX_FRAME_DATA}", where[0])
    total = length + 3  # length field, frame data, checksum
    if len(body) < total:
        what = f"truncated: length {length} and a checksum, {len(body) - 2} bytes follow"
        raise bad or FrameError(what, n)
    last = where[total - 1]
    end = last + (2 if frame[last] == ESCAPE and api_mode == 2 else 1)
    if end < n:
        raise FrameError(f"{n - end} bytes after the checksum", end)
    data = body[2 : total - 1]
    check = body[total - 1]
    if checksum(data) != check:
        raise FrameError(
            f"checksum 0x{check:02x}, the frame data's is 0x{checksum(data):02x}", last
        )

    def at(k: int) -> int:
        return where[2 + min(k, length)]

    return data, check, at


def _fields(data: bytes, at: Offsets) -> dict[str, Any]:
    """The fields of checksummed frame data, by type (FrameError if too short for its type)."""
    kind = data[0]
    least = _MIN_DESCRIBED.get(kind)
    if least is not None and len(data) < least:
        what = f"{FRAME_NAMES[kind]} frame data of {len(data)} bytes, it has at least {least}"
        raise FrameError(what, at(len(data)))
    if kind in (AT_COMMAND, AT_QUEUE):
        return {
            "frame_id": data[1],
            "command": data[2:4].decode("latin-1"),
            "parameter": data[4:].hex(),
        }
    frame = parse_frame_data(data)
    if isinstance(frame, TransmitRequest):
        return {
            "frame_id": frame.frame_id,
            "dest64": f"{frame.dest64:016x}",
            "dest16": f"{frame.dest16:04x}",
            "radius": frame.radius,
            "options": frame.options,
            "rf_data": frame.rf_data.hex(),
        }
    if isinstance(frame, ReceivePacket):
        return {
            "source64": f"{frame.source64:016x}",
            "source16": f"{frame.source16:04x}",
            "options": frame.options,
            "rf_data": frame.rf_data.hex(),
        }
    if isinstance(frame, TransmitStatus):
        return {
            "frame_id": frame.frame_id,
            "dest16": f"{frame.dest16:04x}",
            "retries": frame.retries,
            "delivery_status": frame.delivery_status,
            "discovery_status": frame.discovery_status,
        }
    if isinstance(frame, ModemStatus):
        return {"status": frame.status}
    if isinstance(frame, AtResponse):
        return {
            "frame_id": frame.frame_id,
            "command": frame.command.decode("latin-1"),
            "status": frame.status,
            "data": frame.data.hex(),
        }
    return {"data": data[1:].hex()}  # a type the radio does not read: its bytes


def _describe(frame: bytes, api_mode: int) -> tuple[dict[str, Any], bytes, Offsets]:
    """`describe_frame`'s dict, the frame data and its offsets."""
    data, check, at = _layout(bytes(frame), api_mode)
    kind = data[0]
    out: dict[str, Any] = {
        "api_mode": api_mode,
        "length": len(data),
        "frame_type": kind,
        "name": FRAME_NAMES.get(kind),
        **_fields(data, at),
        "checksum": check,
    }
    return out, data, at


def describe_frame(frame: bytes, api_mode: int = 1) -> dict[str, Any]:
    """The fields of exactly one API frame (`fieldkit frames decode xbee`), as JSON values.

    Keys: api_mode, length, frame_type, name (None for a type not in FRAME_NAMES), the type's
    fields (dest64/source64 and dest16/source16 as hex, rf_data and other payloads as hex),
    checksum. FrameError names the first bad byte: start delimiter, length, escape, the
    checksum byte itself when the sum fails, bytes after the checksum, a frame too short
    for its type. ValueError for an API mode other than 1 or 2.
    """
    return _describe(frame, api_mode)[0]


def unwrap_rf_data(frame: bytes, api_mode: int = 1) -> tuple[dict[str, Any], bytes, Offsets]:
    """(describe_frame's dict, the RF data, the frame offset of each RF data offset) of a
    transmit request or receive packet: for the protocols that travel as RF data (XbeeMav
    packets, bundles), whose errors then name bytes of the whole frame. FrameError for a
    frame of another type."""
    out, data, at = _describe(frame, api_mode)
    start = _RF_START.get(data[0])
    if start is None:
        what = f"frame type 0x{data[0]:02x} ({out['name'] or 'unknown'}) carries no RF data"
        raise FrameError(what, at(0))
    return out, data[start:], lambda k: at(start + k)


def describe_inside(
    frame: bytes, describe_rf: Callable[[bytes], dict[str, Any]], api_mode: int = 1
) -> dict[str, Any]:
    """`describe_rf` of the RF data of a transmit request or receive packet, with the frame's
    own fields under "xbee"; a FrameError of `describe_rf` names its byte in the frame."""
    head, rf, at = unwrap_rf_data(frame, api_mode)
    try:
        inner = describe_rf(rf)
    except FrameError as e:
        raise FrameError(e.what, at(e.offset)) from None
    return {**inner, "xbee": head}


def deframe(chunks: Iterable[bytes], stats: Counter[str], api_mode: int = 1) -> Iterator[bytes]:
    """Every checksummed API frame in a byte stream, as its bytes, by `FrameReader`'s rules
    (resynchronising at every 0x7e; unknown types included); the end of `chunks` is the end
    of the last burst. stats["bad_frames"] counts the candidates abandoned on the way."""
    reader = FrameReader(api_mode)
    rejected = 0
    pending = iter(chunks)
    while True:
        chunk = next(pending, None)
        found = reader.flush_data() if chunk is None else reader.feed_data(chunk)
        now = sum(reader.stats[k] for k in _REJECTED)
        stats["bad_frames"] += now - rejected
        rejected = now
        for data in found:
            yield frame_bytes(data, api_mode)
        if chunk is None:
            return
