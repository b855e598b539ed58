"""OPEN protocol frames: building them, checking one, and `FrameReader`, the de-framer.

    | AA | LEN(10) VER(6) | SESSION(5) ACK(1) RES0(2) | PADDING(5) ENC(3) | RES1(24) |
    | SEQ (u16) | CRC16 (u16) | DATA ... | CRC32 (u32) |            all little-endian

DATA is CMD SET, CMD ID and the command's value for a command (or a push from the flight
controller), the value alone for an acknowledgement; with ENC = 1 it is AES-encrypted and
padded to whole blocks (`fieldkit.vehicle.dji.crypto`). CRC16 covers the first 10 header
bytes, CRC32 everything before it (`fieldkit.vehicle.dji.crc`). A frame with no data at all
is the bare 12-byte header, without CRC32. The facts, with worked frames: the spec's §3-§5
and docs/vehicles.md.

`FrameReader` turns a byte stream cut anywhere into frames. Line noise costs only counters:
it slides one byte at a time past anything that is not a valid header, and when a frame fails
its CRC32 it drops only that frame's first byte and looks again from the next, so a real frame
that started inside the broken one is still found (what DJI's receiver does, spec §3.6).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from typing import Any

from fieldkit.errors import FrameError
from fieldkit.vehicle.dji.crc import crc16, crc32
from fieldkit.vehicle.dji.crypto import BLOCK, FrameCipher, padding_for

SOF = 0xAA
"""Start of frame."""
HEADER_LEN = 12
"""Header bytes, CRC16 included."""
CRC32_LEN = 4
"""Trailing CRC32 bytes of a frame with data."""
MAX_FRAME_LEN = 1023
"""The largest LEN the 10-bit field holds."""
MAX_DATA = MAX_FRAME_LEN - HEADER_LEN - CRC32_LEN
"""The most DATA a frame carries (padding included): 1007 bytes."""
MIN_DATA_FRAME = HEADER_LEN + CRC32_LEN
"""The shortest frame with data: LEN between 12 and this one are never valid."""
ENC_NONE = 0
"""ENC field: plain."""
ENC_AES = 1
"""ENC field: AES-256 (spec §5)."""
MAX_SESSION = 31
"""Sessions are 0..31 (5 bits)."""


@dataclass(frozen=True, slots=True)
class Frame:
    """One frame as received (or to send): header fields and its DATA in clear.

    `data` is CMD SET, CMD ID and the value for a command or push (`ack` False), the value
    alone for an acknowledgement. An encrypted frame read without the key keeps its
    ciphertext in `data` and has `readable` False.
    """

    session: int
    ack: bool
    seq: int
    data: bytes = b""
    enc: bool = False
    readable: bool = True

    @property
    def cmd_set(self) -> int | None:
        """CMD SET of a command frame (None for an ACK, unreadable or too short data)."""
        if self.ack or not self.readable or len(self.data) < 2:
            return None
        return self.data[0]

    @property
    def cmd_id(self) -> int | None:
        """CMD ID of a command frame (None for an ACK, unreadable or too short data)."""
        if self.ack or not self.readable or len(self.data) < 2:
            return None
        return self.data[1]

    @property
    def value(self) -> bytes:
        """CMD VAL of a command (the bytes after SET and ID), ACK VAL of an acknowledgement."""
        if self.ack or not self.readable:
            return self.data
        return self.data[2:]

    def describe(self) -> dict[str, object]:
        """The fields under the names of the spec (and `fieldkit frames decode dji`); an
        encrypted frame adds `decrypted` (false: `data` is the ciphertext, padding included)."""
        out: dict[str, object] = {
            "session": self.session,
            "ack": int(self.ack),
            "seq": self.seq,
            "enc": int(self.enc),
            "cmd_set": self.cmd_set,
            "cmd_id": self.cmd_id,
            "data": self.value.hex(),
        }
        if self.enc:
            out["decrypted"] = self.readable
        return out

    def encode(self, cipher: FrameCipher | None = None) -> bytes:
        """This frame's bytes (encrypted with `cipher` when `enc` is set)."""
        return encode(
            self.session, self.ack, self.seq, self.data, cipher=cipher if self.enc else None
        )


def encode(
    session: int, ack: bool, seq: int, data: bytes, *, cipher: FrameCipher | None = None
) -> bytes:
    """A whole frame: header, DATA (AES-encrypted and padded if `cipher`), the CRCs."""
    if not 0 <= session <= MAX_SESSION:
        raise ValueError(f"session must be 0..{MAX_SESSION}, got {session}")
    if not 0 <= seq <= 0xFFFF:
        raise ValueError(f"seq must be 0..65535, got {seq}")
    pad = 0
    enc = ENC_NONE
    if cipher is not None:
        pad = padding_for(len(data))
        enc = ENC_AES
        # Zeros for padding: the content is unspecified (receivers ignore it).
        data = cipher.encrypt(data + bytes(pad))
    if len(data) > MAX_DATA:
        raise ValueError(f"at most {MAX_DATA} bytes of data fit a frame, got {len(data)}")
    length = HEADER_LEN + len(data) + (CRC32_LEN if data else 0)
    header = bytearray(HEADER_LEN)
    header[0] = SOF
    header[1] = length & 0xFF
    header[2] = (length >> 8) & 0x03  # VER 0 in the upper six bits
    header[3] = session | (0x20 if ack else 0)
    header[4] = pad | enc << 5
    header[8] = seq & 0xFF
    header[9] = seq >> 8
    c16 = crc16(header[:10])
    header[10] = c16 & 0xFF
    header[11] = c16 >> 8
    if not data:
        return bytes(header)
    body = header + data
    return bytes(body) + crc32(body).to_bytes(4, "little")


def command_frame(
    session: int,
    seq: int,
    cmd_set: int,
    cmd_id: int,
    value: bytes = b"",
    *,
    cipher: FrameCipher | None = None,
) -> bytes:
    """A command (or push) frame: CMD SET, CMD ID, then `value`."""
    return encode(session, False, seq, bytes((cmd_set, cmd_id)) + value, cipher=cipher)


def ack_frame(session: int, seq: int, value: bytes, *, cipher: FrameCipher | None = None) -> bytes:
    """An acknowledgement of the command sent on (`session`, `seq`), carrying `value`."""
    return encode(session, True, seq, value, cipher=cipher)


def header_problem(header: bytes | bytearray | memoryview) -> tuple[int, str] | None:
    """(offset, problem) of the first thing wrong in a 12-byte header, or None if it is good."""
    if header[0] != SOF:
        return 0, f"start of frame 0x{header[0]:02x}, not 0xaa"
    length = header[1] | (header[2] & 0x03) << 8
    if length < HEADER_LEN or HEADER_LEN < length < MIN_DATA_FRAME:
        return 1, f"length {length}: a frame is 12 bytes, or 16 to {MAX_FRAME_LEN}"
    if header[2] & 0xFC:
        return 2, f"header version {header[2] >> 2}, not 0"
    if header[3] & 0xC0:
        return 3, "reserved bits 6-7 of the session byte are set"
    for i in (5, 6, 7):
        if header[i]:
            return i, "reserved header byte is not 0"
    if crc16(header[:HEADER_LEN]) != 0:
        want = crc16(header[:10])
        got = header[10] | header[11] << 8
        return 10, f"CRC16 0x{got:04x}, the header's is 0x{want:04x}"
    return None


def frame_length(header: bytes | bytearray | memoryview) -> int:
    """LEN of a header: the whole frame's bytes."""
    return header[1] | (header[2] & 0x03) << 8


def _open(
    raw: bytes | bytearray | memoryview, cipher: FrameCipher | None
) -> tuple[Frame | None, int, str]:
    """The frame of checked bytes `raw` (header and CRCs good): (frame, 0, "") or, when its
    DATA cannot be used, (None, offset, why)."""
    session = raw[3] & 0x1F
    ack = bool(raw[3] & 0x20)
    seq = raw[8] | raw[9] << 8
    enc = raw[4] >> 5
    pad = raw[4] & 0x1F
    data = bytes(raw[HEADER_LEN : len(raw) - CRC32_LEN]) if len(raw) > HEADER_LEN else b""
    if enc == ENC_NONE:
        return Frame(session, ack, seq, data), 0, ""
    if enc != ENC_AES:
        return None, 4, f"unknown encryption {enc} (0 plain, 1 AES)"
    if not data or len(data) % BLOCK:
        return None, 1, f"encrypted data of {len(data)} bytes, not whole 16-byte blocks"
    if not 1 <= pad <= min(BLOCK, len(data)):
        return None, 4, f"padding {pad} of an encrypted frame, not 1..16"
    if cipher is None:
        return Frame(session, ack, seq, data, enc=True, readable=False), 0, ""
    plain = cipher.decrypt(data)
    return Frame(session, ack, seq, plain[: len(plain) - pad], enc=True), 0, ""


def decode(raw: bytes | bytearray | memoryview, cipher: FrameCipher | None = None) -> Frame:
    """Exactly one frame; FrameError naming the first bad byte if it is not one.

    An encrypted frame is decrypted with `cipher`; without one it comes back unreadable
    (ciphertext in `data`).
    """
    raw = bytes(raw)
    if len(raw) < HEADER_LEN:
        if raw and raw[0] != SOF:
            raise FrameError(f"start of frame 0x{raw[0]:02x}, not 0xaa", 0)
        raise FrameError(f"{len(raw)} bytes: a frame has a 12-byte header", len(raw))
    problem = header_problem(raw)
    if problem is not None:
        raise FrameError(problem[1], problem[0])
    length = frame_length(raw)
    if len(raw) < length:
        raise FrameError(f"truncated: {len(raw)} bytes of a {length}-byte frame", len(raw))
    if len(raw) > length:
        raise FrameError(f"{len(raw) - length} bytes after the {length}-byte frame", length)
    if length > HEADER_LEN and crc32(raw) != 0:
        want = crc32(raw[: length - CRC32_LEN])
        got = int.from_bytes(raw[length - CRC32_LEN :], "little")
        raise FrameError(f"CRC32 0x{got:08x}, the frame's is 0x{want:08x}", length - CRC32_LEN)
    frame, offset, why = _open(raw, cipher)
    if frame is None:
        raise FrameError(why, offset)
    return frame


def describe_frame(raw: bytes, cipher: FrameCipher | None = None) -> dict[str, Any]:
    """`fieldkit frames decode dji`: the fields of exactly one frame (`Frame.describe`), an
    encrypted one decrypted with `cipher` if given; FrameError naming the first bad byte."""
    return decode(raw, cipher).describe()


def deframe(
    chunks: Iterable[bytes], stats: Counter[str], cipher: FrameCipher | None = None
) -> Iterator[bytes]:
    """The bytes of every frame `FrameReader` finds in a byte stream (encrypted ones too,
    readable or not: `describe_frame` shows them); stats["bad_frames"] counts the frames
    rejected: a good header with a bad CRC32, or one the stream ended inside."""
    reader = FrameReader(cipher)
    for chunk in chunks:
        seen = reader.crc_errors
        found = reader.feed_raw(chunk)
        stats["bad_frames"] += reader.crc_errors - seen
        yield from found
    if reader.pending >= HEADER_LEN:  # a good header whose frame never ended
        stats["bad_frames"] += 1


class FrameReader:
    """Frames out of a byte stream cut anywhere; noise and broken frames only cost counters.

    Counters: `frames` delivered; `bad_frames`, the runs of bytes that were not part of a
    frame (noise, a broken frame) plus the frames whose DATA could not be used; within those,
    `garbage_bytes`, `crc_errors` (a good header, a bad CRC32) and `undecryptable` (encrypted
    without the key, or with an impossible layout). At most one frame's bytes wait between
    calls (`pending`).
    """

    def __init__(self, cipher: FrameCipher | None = None) -> None:
        """A reader that decrypts AES frames with `cipher` (settable later: `reader.cipher`)."""
        self.cipher = cipher
        self.frames = 0
        self.bad_frames = 0
        self.garbage_bytes = 0
        self.crc_errors = 0
        self.undecryptable = 0
        self._buf = bytearray()
        self._in_garbage = False

    @property
    def pending(self) -> int:
        """Bytes held back: the start of a frame not complete yet."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget a partial frame: the line was reopened and its rest will never come (the
        next bytes are another frame's, which the stale half would swallow). Counters stay."""
        self._buf.clear()
        self._in_garbage = False

    def feed(self, data: bytes | bytearray | memoryview) -> list[Frame]:
        """The frames completed by `data`, in order."""
        out: list[Frame] = []
        for raw in self.feed_raw(data):
            frame, _, _ = _open(raw, self.cipher)
            if frame is None or not frame.readable:
                self.undecryptable += 1
                self.bad_frames += 1
                continue
            self.frames += 1
            out.append(frame)
        return out

    def feed_raw(self, data: bytes | bytearray | memoryview) -> list[bytes]:
        """The bytes of each frame completed by `data` whose header and CRCs pass, in order,
        its DATA not opened (`feed` opens it and counts the frames; this counts the noise)."""
        buf = self._buf
        buf += data
        out: list[bytes] = []
        n = len(buf)
        pos = 0
        while pos < n:
            i = buf.find(SOF, pos)
            if i < 0:
                self._discard(n - pos)
                pos = n
                break
            if i > pos:
                self._discard(i - pos)
                pos = i
            if n - pos < HEADER_LEN:
                break
            b2 = buf[pos + 2]
            length = buf[pos + 1] | (b2 & 0x03) << 8
            if (
                b2 & 0xFC
                or buf[pos + 3] & 0xC0
                or buf[pos + 5]
                or buf[pos + 6]
                or buf[pos + 7]
                or length < HEADER_LEN
                or HEADER_LEN < length < MIN_DATA_FRAME
                or crc16(memoryview(buf)[pos : pos + HEADER_LEN]) != 0
            ):
                self._discard(1)
                pos += 1
                continue
            if n - pos < length:
                break  # the rest of the frame is still on its way
            raw = bytes(buf[pos : pos + length])
            if length > HEADER_LEN and crc32(raw) != 0:
                self.crc_errors += 1
                # Drop only the first byte: a real frame may start inside this one.
                self._discard(1)
                pos += 1
                continue
            pos += length
            self._in_garbage = False
            out.append(raw)
        del buf[:pos]
        return out

    def _discard(self, count: int) -> None:
        self.garbage_bytes += count
        if not self._in_garbage:
            self._in_garbage = True
            self.bad_frames += 1


__all__ = [
    "CRC32_LEN",
    "ENC_AES",
    "ENC_NONE",
    "Frame",
    "FrameError",
    "FrameReader",
    "HEADER_LEN",
    "MAX_DATA",
    "MAX_FRAME_LEN",
    "MAX_SESSION",
    "MIN_DATA_FRAME",
    "SOF",
    "ack_frame",
    "command_frame",
    "decode",
    "deframe",
    "describe_frame",
    "encode",
    "frame_length",
    "header_problem",
]
