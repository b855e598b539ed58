"""The update frame: how robots gossip versions and pass patches on, byte for byte.

One module owns these bytes (docs/update.md#on-air-format). A frame travels in the same
container as a ROSBuzz bundle, so XbeeMav and the XBee carry it unchanged: a memory image of
little-endian fields, zero padded to whole 8-byte words, each word serialized big-endian on
the air (every 8-byte group reversed). Its first word holds the frame type UPDATE_FRAME (16),
which ROSBuzz robots ignore (they act on type 1, their own OTA message, and type 2, a
bundle):

    word 0      u16 type = 16 | u8 format = 1 | u8 records | u16 sender | u16 zero
    records     u8 kind | u8 body length | body, as many as `records` says
    padding     zeros up to a whole word, fewer than 8

Record bodies (all little-endian):

    STATUS   u32 version | 8 B running hash | u8 phase | u32 target | u32 bad | u16 heartbeat
    OFFER    8 B digest | u32 version | u32 total bytes | 8 B base hash
    WANT     8 B digest | u16 first chunk | 8 B bitmap of chunks first..first+63
    CHUNK    8 B digest | u16 index | 1..CHUNK_BYTES bytes
    ENTRIES  u8 n | n x (u16 robot | u16 heartbeat | u8 phase | u32 version)
    VERDICT  u32 version | u8 reason

Hashes are the first 8 bytes of a SHA-256 (a version's bytecode, a patch's bytes): enough to
tell versions and patches apart; what a robot runs is checked in full against the signed
patch header before it runs. The decoder takes hostile bytes and raises `FrameError` naming
what is wrong and where; it never raises anything else.
"""

from __future__ import annotations

import hashlib
import hmac
import struct
from dataclasses import dataclass
from enum import IntEnum
from typing import ClassVar

from fieldkit.errors import FieldkitError

#: payload64 type of an update frame (ROSBuzz knows 1, UPDATER_MESSAGE, and 2, BUZZ_MESSAGE).
UPDATE_FRAME = 16
#: ROSBuzz's own OTA message type: recognised, counted and refused.
ROSBUZZ_OTA = 1
FORMAT = 1
#: Largest frame on the air: what a bundle may take, within one XBee frame with XbeeMav's prefix.
MAX_FRAME_BYTES = 232
#: Patch bytes one CHUNK carries (the last chunk of a patch may be shorter).
CHUNK_BYTES = 96
#: Chunks one WANT can ask for, from its first.
WANT_WINDOW = 64
#: Bytes of a truncated hash or digest on the air.
SHORT = 8

#: Bytes of the authentication tag a sealed frame ends with (one word).
TAG_BYTES = 8

_WORD0 = struct.Struct("<HBBHH")
_REC = struct.Struct("<BB")


class FrameError(FieldkitError, ValueError):
    """Bytes that are not an update frame: what is wrong and at which byte of the memory image."""

    def __init__(self, what: str, offset: int) -> None:
        super().__init__(f"{what} (at byte {offset})")
        self.what = what
        self.offset = offset


class Phase(IntEnum):
    """Where a robot is in an update, as its STATUS and barrier entries say."""

    RUNNING = 0  # running its version, nothing pending
    STANDBY = 1  # holds a verified patch for `target`, waiting for the swarm to agree
    GRACE = 2  # switched to `target` recently: an error now rolls the swarm back
    OPERATOR = 3  # a ground station: serves patches, never counted in a barrier


class Reason(IntEnum):
    """Why a version was rolled back (VERDICT)."""

    BARRIER_TIMEOUT = 1
    SCRIPT_ERROR = 2
    OPERATOR = 3
    BAD_PATCH = 4


@dataclass(frozen=True)
class Status:
    """A robot's version, its place in an update and its heartbeat."""

    KIND: ClassVar[int] = 1
    FMT: ClassVar[struct.Struct] = struct.Struct("<I8sBIIH")
    version: int
    running: bytes  # SHORT bytes of its bytecode's SHA-256
    phase: Phase
    target: int  # the version being agreed or in grace; 0 otherwise
    bad: int  # the highest version this robot knows was rolled back; 0 none
    heartbeat: int


@dataclass(frozen=True)
class Offer:
    """A patch this robot holds and can serve, whole or in part."""

    KIND: ClassVar[int] = 2
    FMT: ClassVar[struct.Struct] = struct.Struct("<8sII8s")
    digest: bytes
    version: int
    total: int  # bytes of the whole patch
    base: bytes  # SHORT bytes of the hash of the version it applies to


@dataclass(frozen=True)
class Want:
    """Chunks this robot still needs of a patch: bit k of `bitmap` is chunk first + k."""

    KIND: ClassVar[int] = 3
    FMT: ClassVar[struct.Struct] = struct.Struct("<8sHQ")
    digest: bytes
    first: int
    bitmap: int

    def chunks(self) -> list[int]:
        """The chunk indices asked for."""
        b, first = self.bitmap, self.first
        return [first + k for k in range(WANT_WINDOW) if b >> k & 1]


@dataclass(frozen=True)
class Chunk:
    """Part `index` of a patch: bytes index*CHUNK_BYTES onwards."""

    KIND: ClassVar[int] = 4
    HEAD: ClassVar[struct.Struct] = struct.Struct("<8sH")
    digest: bytes
    index: int
    data: bytes


@dataclass(frozen=True)
class Entry:
    """One robot's barrier entry as the swarm gossips it: newest heartbeat wins."""

    robot: int
    heartbeat: int
    phase: Phase
    version: int


@dataclass(frozen=True)
class Entries:
    """Barrier entries of other robots, passed on."""

    KIND: ClassVar[int] = 5
    ITEM: ClassVar[struct.Struct] = struct.Struct("<HHBI")
    entries: tuple[Entry, ...]


@dataclass(frozen=True)
class Verdict:
    """Version `version` was rolled back, and why: every robot leaves it and never returns."""

    KIND: ClassVar[int] = 6
    FMT: ClassVar[struct.Struct] = struct.Struct("<IB")
    version: int
    reason: Reason


Record = Status | Offer | Want | Chunk | Entries | Verdict

#: Bytes a record of each kind takes in a frame, its two-byte record head included.
STATUS_BYTES = 2 + Status.FMT.size
OFFER_BYTES = 2 + Offer.FMT.size
WANT_BYTES = 2 + Want.FMT.size
VERDICT_BYTES = 2 + Verdict.FMT.size
ENTRY_BYTES = Entries.ITEM.size


def chunk_bytes(data_len: int) -> int:
    """Bytes a CHUNK record of `data_len` patch bytes takes in a frame."""
    return 2 + Chunk.HEAD.size + data_len


def entries_bytes(n: int) -> int:
    """Bytes an ENTRIES record of `n` entries takes in a frame."""
    return 3 + n * ENTRY_BYTES


@dataclass(frozen=True)
class Frame:
    """One update frame: its sender and its records, in order."""

    sender: int
    records: tuple[Record, ...]


def _body(r: Record) -> bytes:
    if isinstance(r, Status):
        return Status.FMT.pack(r.version, r.running, r.phase, r.target, r.bad, r.heartbeat)
    if isinstance(r, Offer):
        return Offer.FMT.pack(r.digest, r.version, r.total, r.base)
    if isinstance(r, Want):
        return Want.FMT.pack(r.digest, r.first, r.bitmap)
    if isinstance(r, Chunk):
        return Chunk.HEAD.pack(r.digest, r.index) + r.data
    if isinstance(r, Entries):
        item = Entries.ITEM.pack
        return bytes([len(r.entries)]) + b"".join(
            item(e.robot, e.heartbeat, e.phase, e.version) for e in r.entries
        )
    return Verdict.FMT.pack(r.version, r.reason)


def image_size(records: tuple[Record, ...] | list[Record]) -> int:
    """Bytes on the air of a frame holding `records` (padding included)."""
    n = 8 + sum(2 + len(_body(r)) for r in records)
    return -(-n // 8) * 8


def encode(frame: Frame) -> bytes:
    """The frame's bytes on the air; ValueError if it cannot be one (too big, bad field)."""
    if not 0 <= frame.sender <= 0xFFFF:
        raise ValueError(f"sender {frame.sender} is not a u16")
    if len(frame.records) > 255:
        raise ValueError("more than 255 records")
    parts = [_WORD0.pack(UPDATE_FRAME, FORMAT, len(frame.records), frame.sender, 0)]
    for r in frame.records:
        try:
            body = _body(r)
        except struct.error as e:
            raise ValueError(f"{type(r).__name__}: {e}") from None
        _check_record(r, body)
        parts.append(_REC.pack(r.KIND, len(body)) + body)
    image = b"".join(parts)
    image += bytes(-len(image) % 8)
    if len(image) > MAX_FRAME_BYTES:
        raise ValueError(f"a frame of {len(image)} bytes, more than {MAX_FRAME_BYTES}")
    return _swap(image)


def _check_record(r: Record, body: bytes) -> None:
    if len(body) > 255:
        raise ValueError(f"{type(r).__name__} of {len(body)} bytes")
    if isinstance(r, Chunk) and not 1 <= len(r.data) <= CHUNK_BYTES:
        raise ValueError(f"a chunk of {len(r.data)} bytes")
    # What the decoder refuses, the encoder refuses too: every frame sent can be read.
    phases = [getattr(r, "phase", None)]
    if isinstance(r, Entries):
        phases = [e.phase for e in r.entries]
    for phase in phases:
        if phase is not None and phase not in Phase._value2member_map_:
            raise ValueError(
                f"{type(r).__name__}: phase {phase} is not one of {[int(p) for p in Phase]}"
            )
    if isinstance(r, Verdict) and r.reason not in Reason._value2member_map_:
        raise ValueError(f"VERDICT reason {r.reason} is not one of {[int(x) for x in Reason]}")
    for name in ("digest", "running", "base"):
        value = getattr(r, name, None)
        if value is not None and len(value) != SHORT:
            raise ValueError(f"{name} of {len(value)} bytes, not {SHORT}")


def _swap(data: bytes) -> bytes:
    """Memory image <-> air bytes: every 8-byte word reversed (its own inverse)."""
    return b"".join(data[i : i + 8][::-1] for i in range(0, len(data), 8))


def frame_key(swarm_key: bytes) -> bytes:
    """The key that seals update frames, derived from the swarm key every robot holds (a
    key of its own, so a tag can never be confused with a patch's encryption)."""
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.kdf.hkdf import HKDF

    kdf = HKDF(algorithm=hashes.SHA256(), length=32, salt=None, info=b"fieldkit-frames-v1")
    return kdf.derive(swarm_key)


def _tag(key: bytes, air: bytes) -> bytes:
    return hmac.new(key, air, hashlib.sha256).digest()[:TAG_BYTES]


def seal(air: bytes, key: bytes) -> bytes:
    """An encoded frame with its tag appended: HMAC-SHA256 under `key`, first 8 bytes."""
    if len(air) + TAG_BYTES > MAX_FRAME_BYTES:
        raise ValueError(
            f"a sealed frame of {len(air) + TAG_BYTES} bytes, more than {MAX_FRAME_BYTES}"
        )
    return air + _tag(key, air)


def unseal(data: bytes, key: bytes) -> bytes:
    """The encoded frame inside a sealed one; FrameError if the tag is not the swarm's (a
    radio in range without the swarm key, or a frame damaged on the way)."""
    n = len(data)
    if n < 8 + TAG_BYTES or n % 8:
        raise FrameError(f"{n} bytes, not a sealed frame (whole words, at least two)", 0)
    air, tag = data[:-TAG_BYTES], data[-TAG_BYTES:]
    if not hmac.compare_digest(tag, _tag(key, air)):
        raise FrameError(
            "its tag does not check out: not sealed with this swarm's key", n - TAG_BYTES
        )
    return air


def frame_type(data: bytes) -> int | None:
    """The payload64 type of air bytes (16 an update frame, 2 a bundle, 1 ROSBuzz's OTA
    message), or None if they are not even one word. ROSBuzz tells its OTA message by the
    whole first word being 1; every other type is the word's low 16 bits."""
    if len(data) < 8:
        return None
    word = int.from_bytes(data[:8], "big")
    return ROSBUZZ_OTA if word == ROSBUZZ_OTA else word & 0xFFFF


def decode(data: bytes) -> Frame:
    """The frame in air bytes; FrameError naming what is wrong and where."""
    if not isinstance(data, bytes | bytearray):
        raise FrameError(f"a frame is bytes, not {type(data).__name__}", 0)
    n = len(data)
    if n < 8 or n % 8:
        raise FrameError(f"{n} bytes, not a whole number of 8-byte words (at least one)", 0)
    if n > MAX_FRAME_BYTES:
        raise FrameError(f"{n} bytes, more than a frame's {MAX_FRAME_BYTES}", MAX_FRAME_BYTES)
    image = _swap(bytes(data))
    kind, fmt, count, sender, zero = _WORD0.unpack_from(image)
    if kind != UPDATE_FRAME:
        raise FrameError(f"frame type {kind}, not an update frame ({UPDATE_FRAME})", 0)
    if fmt != FORMAT:
        raise FrameError(f"format {fmt}, this robot reads format {FORMAT}", 2)
    if zero:
        raise FrameError("reserved bytes are not zero", 6)
    pos = 8
    records: list[Record] = []
    for _ in range(count):
        if pos + 2 > n:
            raise FrameError(f"{count} records announced, the frame ends after {len(records)}", pos)
        rkind, size = _REC.unpack_from(image, pos)
        start = pos + 2
        end = start + size
        if end > n:
            raise FrameError(f"a record of {size} bytes overruns the frame", pos)
        records.append(_record(rkind, image[start:end], start))
        pos = end
    if any(image[pos:]) or n - pos >= 8:
        raise FrameError("padding is not zeros shorter than a word", pos)
    return Frame(sender, tuple(records))


def _record(kind: int, body: bytes, at: int) -> Record:
    def exact(fmt: struct.Struct, name: str) -> tuple[object, ...]:
        if len(body) != fmt.size:
            raise FrameError(f"{name} of {len(body)} bytes, not {fmt.size}", at)
        return fmt.unpack(body)

    if kind == Status.KIND:
        version, running, phase, target, bad, hb = exact(Status.FMT, "STATUS")
        if phase not in Phase._value2member_map_:
            raise FrameError(f"phase {phase} is not one of {[int(p) for p in Phase]}", at + 12)
        return Status(version, running, Phase(phase), target, bad, hb)  # type: ignore[arg-type]
    if kind == Offer.KIND:
        return Offer(*exact(Offer.FMT, "OFFER"))  # type: ignore[arg-type]
    if kind == Want.KIND:
        return Want(*exact(Want.FMT, "WANT"))  # type: ignore[arg-type]
    if kind == Chunk.KIND:
        head = Chunk.HEAD.size
        if not head < len(body) <= head + CHUNK_BYTES:
            raise FrameError(
                f"CHUNK of {len(body)} bytes, not {head + 1}..{head + CHUNK_BYTES}", at
            )
        digest, index = Chunk.HEAD.unpack_from(body)
        return Chunk(digest, index, body[head:])
    if kind == Entries.KIND:
        if not body or len(body) != 1 + body[0] * ENTRY_BYTES:
            raise FrameError(f"ENTRIES of {len(body)} bytes does not hold its count", at)
        out = []
        for i in range(body[0]):
            robot, hb, phase, version = Entries.ITEM.unpack_from(body, 1 + i * ENTRY_BYTES)
            if phase not in Phase._value2member_map_:
                raise FrameError(f"entry phase {phase} unknown", at + 1 + i * ENTRY_BYTES + 4)
            out.append(Entry(robot, hb, Phase(phase), version))
        return Entries(tuple(out))
    if kind == Verdict.KIND:
        version, reason = exact(Verdict.FMT, "VERDICT")
        if reason not in Reason._value2member_map_:
            raise FrameError(f"verdict reason {reason} unknown", at + 4)
        return Verdict(version, Reason(reason))  # type: ignore[arg-type]
    raise FrameError(f"record kind {kind} unknown", at - 2)


__all__ = [
    "CHUNK_BYTES",
    "Chunk",
    "ENTRY_BYTES",
    "Entries",
    "Entry",
    "FORMAT",
    "Frame",
    "FrameError",
    "MAX_FRAME_BYTES",
    "OFFER_BYTES",
    "Offer",
    "Phase",
    "ROSBUZZ_OTA",
    "Reason",
    "Record",
    "SHORT",
    "TAG_BYTES",
    "STATUS_BYTES",
    "Status",
    "UPDATE_FRAME",
    "VERDICT_BYTES",
    "Verdict",
    "WANT_BYTES",
    "WANT_WINDOW",
    "Want",
    "chunk_bytes",
    "decode",
    "encode",
    "entries_bytes",
    "frame_key",
    "frame_type",
    "seal",
    "unseal",
    "image_size",
]
