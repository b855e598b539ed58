"""The Clearpath MCU's serial frame ("Horizon legacy"): layout, CRC, and a streaming de-framer.

    frame = Frame(type=0x0200, payload=b"...")          # flags 0: please acknowledge
    wire = frame.encode()                                # AA LEN ~LEN 00 TS FLAGS TYPE 55 .. CRC
    parse_frame(wire) == frame                           # one whole frame, or FrameError
    reader = FrameReader()
    for f in reader.feed(chunk): ...                     # any split, line noise resynced

Layout (docs: /shared/spec/clearpath-husky.md sections 2, 3 and 7.1), little-endian throughout:

    0 SOH 0xAA | 1 LEN = total - 3 | 2 ~LEN | 3 VERSION | 4..7 TIMESTAMP u32 ms | 8 FLAGS |
    9..10 TYPE u16 | 11 STX 0x55 | 12.. PAYLOAD (LEN - 11 bytes) | CRC u16 over bytes 0..11+n

The CRC is CRC-16/CCITT-FALSE (polynomial 0x1021, initial 0xFFFF, no reflection, no final
XOR). The de-framer follows the reference receiver on clean input and resynchronises better
on noise: after a bad header or a bad CRC it rescans from the byte after the SOH it tried, so
a real frame hidden in line noise is never lost. Every byte it skips counts as garbage and
every rejected candidate as a bad frame; nothing it is fed can make it raise.
"""

from __future__ import annotations

import struct
from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass

from fieldkit.errors import FrameError

SOH = 0xAA
"""First byte of every frame."""
STX = 0x55
"""Byte 11 of every frame, just before the payload."""
HEADER_LEN = 12
"""Bytes before the payload."""
MIN_FRAME = 14
"""A frame with an empty payload: header and CRC."""
MAX_PAYLOAD = 242
"""The largest payload the spec allows: a frame is at most 256 bytes."""
MAX_FRAME = HEADER_LEN + MAX_PAYLOAD + 2
"""The longest frame, 256 bytes."""
NO_ACK = 0x01
"""FLAGS bit 0: the sender wants no acknowledgement (the host always sends 0: ack, please)."""

_HEADER = struct.Struct("<BBBBIBHB")


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
        table.append(crc)
    return tuple(table)


_TABLE = _crc_table()


def crc16(data: bytes | bytearray | memoryview, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE of `data` (the reference's `crc16(len, 0xFFFF, data)`)."""
    table = _TABLE
    for b in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[(crc >> 8) ^ b]
    return crc


@dataclass(frozen=True, slots=True)
class Frame:
    """One frame: its header fields and its payload bytes."""

    type: int  # message type code (section 5: 0x0000-0x3FFF set, 0x4000- request, 0x8000- data)
    payload: bytes = b""
    flags: int = 0  # bit 0: no acknowledgement wanted
    timestamp: int = 0  # ms; the host sends 0
    version: int = 0

    def encode(self) -> bytes:
        """The frame's bytes on the wire (ValueError for a payload or field out of range)."""
        n = len(self.payload)
        if n > MAX_PAYLOAD:
            raise ValueError(f"payload of {n} bytes > {MAX_PAYLOAD}")
        length = HEADER_LEN - 1 + n
        head = _HEADER.pack(
            SOH,
            length,
            length ^ 0xFF,
            self.version,
            self.timestamp & 0xFFFFFFFF,
            self.flags,
            self.type,
            STX,
        )
        body = head + bytes(self.payload)
        return body + crc16(body).to_bytes(2, "little")

    @property
    def is_data(self) -> bool:
        """Whether the MCU sends this kind unasked or as an answer (type >= 0x8000)."""
        return self.type >= 0x8000


def parse_frame(data: bytes) -> Frame:
    """Exactly one frame from `data`; FrameError naming the first bad byte otherwise."""
    n = len(data)
    if n < 1 or data[0] != SOH:
        raise FrameError(
            f"not the start of a frame (0x{data[0]:02X}, want 0xAA)" if n else "empty", 0
        )
    if n < 3:
        raise FrameError(f"truncated: {n} bytes, a frame has at least {MIN_FRAME}", n)
    length = data[1]
    if length ^ data[2] != 0xFF:
        raise FrameError(f"0x{data[2]:02X} is not the complement of LEN 0x{length:02X}", 2)
    if length + 3 < MIN_FRAME:
        raise FrameError(f"LEN {length} is shorter than a header and CRC ({MIN_FRAME - 3})", 1)
    if length + 3 > MAX_FRAME:
        raise FrameError(f"LEN {length} is longer than a frame may be ({MAX_FRAME - 3})", 1)
    want = length + 3
    if n < want:
        raise FrameError(f"truncated: {n} bytes, LEN says {want}", n)
    if n > want:
        raise FrameError(f"{n - want} bytes after the frame's end (LEN says {want})", want)
    if data[11] != STX:
        raise FrameError(f"0x{data[11]:02X} where STX 0x55 belongs", 11)
    got = int.from_bytes(data[want - 2 : want], "little")
    crc = crc16(data[: want - 2])
    if got != crc:
        raise FrameError(f"CRC 0x{got:04X}, computed 0x{crc:04X}", want - 2)
    _, _, _, version, timestamp, flags, type_, _ = _HEADER.unpack_from(data)
    return Frame(type_, bytes(data[HEADER_LEN : want - 2]), flags, timestamp, version)


class FrameReader:
    """A resynchronising de-framer: bytes in any split, whole valid frames out.

    Counters (`stats`): `frames` good frames, `garbage_bytes` bytes skipped outside any
    frame, `bad_length` headers whose LEN fails its complement or range, `bad_stx`,
    `bad_crc`, and `bad_frames` (all rejected candidates). It holds at most one frame's
    bytes between calls.
    """

    def __init__(self) -> None:
        """An empty reader."""
        self._buf = bytearray()
        self.stats: Counter[str] = Counter()

    @property
    def frames(self) -> int:
        """Good frames so far."""
        return self.stats["frames"]

    @property
    def bad_frames(self) -> int:
        """Rejected frame candidates so far (bad LEN, STX or CRC)."""
        return self.stats["bad_frames"]

    @property
    def pending(self) -> int:
        """Bytes held, waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """Take `data`; the frames it completed, in order."""
        buf = self._buf
        buf += data
        out: list[Frame] = []
        stats = self.stats
        i = 0
        n = len(buf)
        while i < n:
            if buf[i] != SOH:
                j = buf.find(SOH, i)
                if j < 0:
                    j = n
                stats["garbage_bytes"] += j - i
                i = j
                continue
            if n - i < 3:
                break  # LEN and ~LEN not here yet
            length = buf[i + 1]
            if length ^ buf[i + 2] != 0xFF or not MIN_FRAME <= length + 3 <= MAX_FRAME:
                self._reject(i, "bad_length")
                i += 1
                continue
            if n - i < HEADER_LEN:
                break  # the header is still on its way
            if buf[i + 11] != STX:
                # Checked before waiting for the whole frame: a noise SOH with a plausible
                # LEN must not hold up the real frames behind it.
                self._reject(i, "bad_stx")
                i += 1
                continue
            end = i + length + 3
            if end > n:
                break  # the rest of the frame is still on its way
            if crc16(buf[i : end - 2]) != buf[end - 2] | buf[end - 1] << 8:
                self._reject(i, "bad_crc")
                i += 1
                continue
            _, _, _, version, timestamp, flags, type_, _ = _HEADER.unpack_from(buf, i)
            out.append(
                Frame(type_, bytes(buf[i + HEADER_LEN : end - 2]), flags, timestamp, version)
            )
            stats["frames"] += 1
            i = end
        del buf[:i]
        return out

    def _reject(self, i: int, why: str) -> None:
        """A candidate at `i` failed: count it, and its SOH as garbage (the scan goes on
        from the next byte, so a frame that starts inside it is still found)."""
        self.stats[why] += 1
        self.stats["bad_frames"] += 1
        self.stats["garbage_bytes"] += 1


def deframe(chunks: Iterable[bytes], stats: Counter[str]) -> Iterator[bytes]:
    """The bytes of every frame `FrameReader` finds in a byte stream (a valid frame encodes
    back to exactly its bytes); stats["bad_frames"] counts the candidates it rejects, and a
    frame the stream ended inside."""
    reader = FrameReader()
    for chunk in chunks:
        seen = reader.bad_frames
        found = reader.feed(chunk)
        stats["bad_frames"] += reader.bad_frames - seen
        for frame in found:
            yield frame.encode()
    if reader.pending >= HEADER_LEN:  # a checked header whose frame never ended
        stats["bad_frames"] += 1


__all__ = [
    "MAX_FRAME",
    "MAX_PAYLOAD",
    "MIN_FRAME",
    "NO_ACK",
    "SOH",
    "STX",
    "Frame",
    "FrameError",
    "FrameReader",
    "crc16",
    "deframe",
    "parse_frame",
]
