"""Reading a bag cut short: MCAP and ROS 1 files scanned record by record, up to the cut.

A bag's index is written when its writer closes: an MCAP file's summary and footer (and the
rosbag2 directory's `metadata.yaml`), a ROS 1 bag's index records and the `index_pos` in its
header. A recording killed with -9, or a robot whose power went, leaves a file without them,
which rosbags (and ROS tools) refuse to open. Everything before the cut is still there, in
records that each say their own length: these scanners walk them from the start, keep every
record that is whole, and stop at the first one that is not (cut short, or bytes that are no
record at all). They read only what our writers write (uncompressed chunks; bz2, lz4 and zstd
are handled too where the format allows) and never modify the file.

`scan_mcap(path)` and `scan_ros1(path)` return a `Scan`: the connections found, the messages'
positions, and where and why the scan stopped; `Scan.messages()` reads the messages back.
Problems are `ScanError` (the caller turns them into a `BagError` naming the file).
"""

from __future__ import annotations

import bz2
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from rosbags.rosbag2.storage_mcap import decompress as mcap_decompress
from rosbags.typesys.msg import normalize_msgtype

MCAP_MAGIC = b"\x89MCAP0\r\n"
ROS1_MAGIC = b"#ROSBAG V2.0\n"

# MCAP opcodes (https://mcap.dev/spec).
_OP_HEADER = 0x01
_OP_FOOTER = 0x02
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_DATA_END = 0x0F

# ROS 1 record ops.
_R1_MSGDATA = 2
_R1_BAGHEADER = 3
_R1_CHUNK = 5
_R1_CONNECTION = 7

#: A record longer than this is damage, not data (our chunks are a few kB to 1 MiB).
MAX_RECORD_BYTES = 1 << 30

_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")


class ScanError(ValueError):
    """The file is not a bag of the expected kind, or nothing of it can be read."""


@dataclass(frozen=True)
class ScannedConnection:
    """A topic as the file declares it: its type and the definition embedded with it."""

    id: int
    topic: str
    msgtype: str
    #: The embedded definition (ROS 1 `.msg` text with dependencies, or ROS 2 `ros2msg`).
    msgdef: str
    #: "ros2msg", "ros2idl" (MCAP schemas) or "msg" (ROS 1).
    encoding: str
    #: The ROS 1 md5sum ("" for MCAP).
    md5sum: str = ""


@dataclass
class Scan:
    """What a record-by-record scan of one file found."""

    path: Path
    connections: dict[int, ScannedConnection] = field(default_factory=dict)
    #: Messages per connection id.
    counts: dict[int, int] = field(default_factory=dict)
    start_ns: int = 0
    end_ns: int = 0
    #: Where the readable part ends (bytes), and the file's size.
    good_bytes: int = 0
    size: int = 0
    #: Why the scan stopped before the end ("" when the file was complete).
    stopped: str = ""
    #: The top-level records holding messages: (op, offset, length) of what to read again.
    _records: list[tuple[int, int, int]] = field(default_factory=list)
    _ros1: bool = False
    #: MCAP schemas seen so far: id -> (name, encoding, text).
    _schemas: dict[int, tuple[str, str, str]] = field(default_factory=dict)

    @property
    def message_count(self) -> int:
        """Messages found in the readable part."""
        return sum(self.counts.values())

    def messages(self, ids: set[int]) -> Iterator[tuple[int, int, bytes]]:
        """(connection id, time ns, raw message) of the readable part, in file order."""
        with self.path.open("rb") as f:
            for op, offset, length in self._records:
                f.seek(offset)
                content = _read_exact(f, length)
                if self._ros1:
                    yield from _ros1_chunk_messages(content, ids)
                elif op == _OP_CHUNK:
                    for rop, body in _mcap_chunk_records(content):
                        if rop == _OP_MESSAGE:
                            cid, t, data = _mcap_message(body)
                            if cid in ids:
                                yield cid, t, data
                elif op == _OP_MESSAGE:
                    cid, t, data = _mcap_message(content)
                    if cid in ids:
                        yield cid, t, data

    def _count(self, cid: int, t: int) -> None:
        """Count one message of connection `cid` at time `t`."""
        if cid not in self.connections:
            raise ScanError(f"a message on connection {cid}, which no record declared")
        first = not self.counts
        self.counts[cid] = self.counts.get(cid, 0) + 1
        self.start_ns = t if first else min(self.start_ns, t)
        self.end_ns = t if first else max(self.end_ns, t)


def _read_exact(f: BinaryIO, n: int) -> bytes:
    """`n` bytes from `f`, or ScanError when the file ends first."""
    data = f.read(n)
    if len(data) != n:
        raise ScanError(f"{n} bytes expected, {len(data)} found")
    return data


class _Cursor:
    """Bounds-checked little-endian fields out of one record's bytes."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.pos = 0

    def take(self, n: int) -> bytes:
        """The next `n` bytes."""
        if n < 0 or self.pos + n > len(self.data):
            raise ScanError("a record's field runs past its end")
        out = self.data[self.pos : self.pos + n]
        self.pos += n
        return out

    def u16(self) -> int:
        """The next uint16."""
        return int(_U16.unpack(self.take(2))[0])

    def u32(self) -> int:
        """The next uint32."""
        return int(_U32.unpack(self.take(4))[0])

    def u64(self) -> int:
        """The next uint64."""
        return int(_U64.unpack(self.take(8))[0])

    def text(self) -> str:
        """The next MCAP string (uint32 length, UTF-8)."""
        try:
            return self.take(self.u32()).decode("utf-8")
        except UnicodeDecodeError:
            raise ScanError("a string that is not UTF-8") from None

    def rest(self) -> bytes:
        """Everything left."""
        return self.take(len(self.data) - self.pos)


# ------------------------------------------------------------------------------------ MCAP


def scan_mcap(path: Path) -> Scan:
    """Scan an MCAP file (ROS 2 profile) from its start to its end or its first bad record."""
    scan = Scan(path)
    with path.open("rb") as f:
        size = scan.size = f.seek(0, 2)
        f.seek(0)
        magic = f.read(len(MCAP_MAGIC))
        if magic != MCAP_MAGIC:
            raise ScanError("empty file" if not magic else "not an MCAP file (no MCAP magic)")
        pos = len(MCAP_MAGIC)
        first = True
        while True:
            scan.good_bytes = pos
            head = f.read(9)
            if len(head) < 9:
                scan.stopped = "" if not head else f"a record cut short at byte {pos}"
                break
            op, length = head[0], int(_U64.unpack(head[1:])[0])
            if op == 0:  # never a record: zeros a power cut left, or garbage
                scan.stopped = f"bytes that are no MCAP record at byte {pos}"
                break
            if length > MAX_RECORD_BYTES or pos + 9 + length > size:
                scan.stopped = f"a record cut short at byte {pos}"
                break
            if first:
                if op != _OP_HEADER:
                    raise ScanError("the MCAP file does not start with a header record")
                content = _read_exact(f, length)
                profile = _Cursor(content).text()
                if profile != "ros2":
                    raise ScanError(f"an MCAP file of profile {profile!r}, not a ROS 2 bag")
                first = False
            elif op in (_OP_DATA_END, _OP_FOOTER):
                scan.good_bytes = pos
                break
            elif op in (_OP_CHUNK, _OP_MESSAGE, _OP_SCHEMA, _OP_CHANNEL):
                content = _read_exact(f, length)
                try:
                    _mcap_take(scan, op, pos + 9, content)
                except ScanError as e:
                    scan.stopped = f"a damaged record at byte {pos}: {e}"
                    break
            else:
                # Indexes and statistics (rebuilt from the records themselves), and record
                # kinds of later MCAP versions or private ones, which readers skip.
                f.seek(length, 1)
            pos += 9 + length
    if first:
        raise ScanError("an MCAP file without its header record")
    return scan


def _mcap_take(scan: Scan, op: int, offset: int, content: bytes) -> None:
    """Account for one whole top-level record (a chunk, or a record outside chunks)."""
    schemas = scan._schemas
    records = _mcap_chunk_records(content) if op == _OP_CHUNK else [(op, content)]
    # Validate the whole chunk before counting any of it: a chunk is kept whole or not at all.
    found: list[tuple[int, int]] = []
    declared: dict[int, ScannedConnection] = {}
    for rop, body in records:
        c = _Cursor(body)
        if rop == _OP_SCHEMA:
            sid, name, encoding = c.u16(), c.text(), c.text()
            data = c.take(c.u32())
            try:
                schemas[sid] = (name, encoding, data.decode("utf-8"))
            except UnicodeDecodeError:
                raise ScanError("a schema that is not UTF-8") from None
        elif rop == _OP_CHANNEL:
            cid, sid, topic, encoding = c.u16(), c.u16(), c.text(), c.text()
            if encoding != "cdr":
                raise ScanError(f"channel {topic!r} is encoded {encoding!r}, not CDR")
            if sid not in schemas:
                raise ScanError(f"channel {topic!r} names schema {sid}, which is not declared")
            name, schema_encoding, data_text = schemas[sid]
            declared[cid] = ScannedConnection(
                cid, topic, normalize_msgtype(name), data_text, schema_encoding
            )
        elif rop == _OP_MESSAGE:
            cid, _, t = c.u16(), c.u32(), c.u64()
            if cid not in scan.connections and cid not in declared:
                raise ScanError(f"a message on channel {cid}, which no record declared")
            found.append((cid, t))
    scan.connections.update(declared)
    for cid, t in found:
        scan._count(cid, t)
    if found or op == _OP_CHUNK:
        scan._records.append((op, offset, len(content)))


def _mcap_chunk_records(content: bytes) -> list[tuple[int, bytes]]:
    """The records inside a chunk record, decompressed and split (ScanError if damaged)."""
    c = _Cursor(content)
    c.u64()  # message start time
    c.u64()  # message end time
    usize, crc = c.u64(), c.u32()
    compression = c.text()
    data = c.take(c.u64())
    if usize > MAX_RECORD_BYTES:
        raise ScanError(f"a chunk claims {usize} bytes uncompressed")
    try:
        raw = mcap_decompress(data, compression, usize, crc)
    except Exception as e:  # noqa: BLE001 - any codec failure means a damaged chunk
        raise ScanError(f"a chunk that does not decode ({e})") from None
    out: list[tuple[int, bytes]] = []
    pos = 0
    while pos < len(raw):
        if pos + 9 > len(raw):
            raise ScanError("a chunk ends inside a record")
        op, length = raw[pos], int(_U64.unpack_from(raw, pos + 1)[0])
        end = pos + 9 + length
        if end > len(raw):
            raise ScanError("a record runs past the end of its chunk")
        out.append((op, raw[pos + 9 : end]))
        pos = end
    return out


def _mcap_message(body: bytes) -> tuple[int, int, bytes]:
    """(channel id, log time, data) of a message record."""
    c = _Cursor(body)
    cid, _, t, _ = c.u16(), c.u32(), c.u64(), c.u64()
    return cid, t, c.rest()


# ------------------------------------------------------------------------------------ ROS 1


def _ros1_header(data: bytes) -> dict[str, bytes]:
    """A ROS 1 record header's fields (`name=value`, each behind a uint32 length)."""
    fields: dict[str, bytes] = {}
    pos = 0
    while pos < len(data):
        if pos + 4 > len(data):
            raise ScanError("a record header ends inside a field length")
        n = int(_U32.unpack_from(data, pos)[0])
        pos += 4
        if pos + n > len(data):
            raise ScanError("a record header field runs past its header")
        name, sep, value = data[pos : pos + n].partition(b"=")
        if not sep:
            raise ScanError("a record header field without '='")
        try:
            fields[name.decode("ascii")] = value
        except UnicodeDecodeError:
            raise ScanError("a record header field name that is not ASCII") from None
        pos += n
    return fields


def _u32_field(fields: dict[str, bytes], name: str) -> int:
    """A uint32 header field."""
    value = fields.get(name)
    if value is None or len(value) != 4:
        raise ScanError(f"a record without a proper {name!r} field")
    return int(_U32.unpack(value)[0])


def _text_field(fields: dict[str, bytes], name: str) -> str:
    """A string header field."""
    value = fields.get(name)
    if value is None:
        raise ScanError(f"a record without its {name!r} field")
    try:
        return value.decode("utf-8")
    except UnicodeDecodeError:
        raise ScanError(f"a {name!r} field that is not UTF-8") from None


def _ros1_records(data: bytes) -> Iterator[tuple[dict[str, bytes], bytes]]:
    """(header fields, data) of each record in `data` (a chunk's content)."""
    pos = 0
    while pos < len(data):
        if pos + 4 > len(data):
            raise ScanError("a chunk ends inside a record")
        hlen = int(_U32.unpack_from(data, pos)[0])
        hend = pos + 4 + hlen
        if hend + 4 > len(data):
            raise ScanError("a record header runs past the end of its chunk")
        dlen = int(_U32.unpack_from(data, hend)[0])
        dend = hend + 4 + dlen
        if dend > len(data):
            raise ScanError("a record runs past the end of its chunk")
        yield _ros1_header(data[pos + 4 : hend]), data[hend + 4 : dend]
        pos = dend


def _ros1_time(fields: dict[str, bytes]) -> int:
    """The `time` field (uint32 seconds, uint32 nanoseconds) in ns."""
    value = fields.get("time")
    if value is None or len(value) != 8:
        raise ScanError("a message record without a proper time")
    sec, nsec = struct.unpack("<II", value)
    return int(sec) * 1_000_000_000 + int(nsec)


def _ros1_op(fields: dict[str, bytes]) -> int:
    """A record's op code."""
    op = fields.get("op")
    if op is None or len(op) != 1:
        raise ScanError("a record without its op code")
    return op[0]


def _ros1_chunk_data(fields: dict[str, bytes], data: bytes) -> bytes:
    """A chunk record's records, decompressed."""
    compression = _text_field(fields, "compression")
    size = _u32_field(fields, "size")
    if compression == "none":
        raw = data
    elif compression == "bz2":
        try:
            raw = bz2.decompress(data)
        except (OSError, ValueError, EOFError):
            raise ScanError("a bz2 chunk that does not decompress") from None
    else:
        raise ScanError(f"a chunk compressed with {compression!r}, which a scan cannot read")
    if len(raw) != size:
        raise ScanError(f"a chunk of {len(raw)} bytes that says it holds {size}")
    return raw


def _ros1_chunk_messages(content: bytes, ids: set[int]) -> Iterator[tuple[int, int, bytes]]:
    """The messages of a chunk record (`content`: header and data of the record)."""
    fields, data = _ros1_split(content)
    for rfields, rdata in _ros1_records(_ros1_chunk_data(fields, data)):
        if _ros1_op(rfields) == _R1_MSGDATA:
            cid = _u32_field(rfields, "conn")
            if cid in ids:
                yield cid, _ros1_time(rfields), rdata


def _ros1_split(content: bytes) -> tuple[dict[str, bytes], bytes]:
    """A whole record's bytes as (header fields, data)."""
    hlen = int(_U32.unpack_from(content, 0)[0])
    return _ros1_header(content[4 : 4 + hlen]), content[4 + hlen + 4 :]


def scan_ros1(path: Path) -> Scan:
    """Scan a ROS 1 bag (v2.0) from its start to its end or its first bad record."""
    scan = Scan(path, _ros1=True)
    with path.open("rb") as f:
        size = scan.size = f.seek(0, 2)
        f.seek(0)
        magic = f.read(len(ROS1_MAGIC))
        if magic != ROS1_MAGIC:
            raise ScanError("empty file" if not magic else "not a ROS 1 bag (no #ROSBAG V2.0)")
        pos = len(ROS1_MAGIC)
        first = True
        while True:
            scan.good_bytes = pos
            head = f.read(4)
            if len(head) < 4:
                scan.stopped = "" if not head else f"a record cut short at byte {pos}"
                break
            hlen = int(_U32.unpack(head)[0])
            if hlen > MAX_RECORD_BYTES or pos + 4 + hlen + 4 > size:
                scan.stopped = f"a record cut short at byte {pos}"
                break
            header = f.read(hlen)
            dlen = int(_U32.unpack(_read_exact(f, 4))[0])
            end = pos + 4 + hlen + 4 + dlen
            if dlen > MAX_RECORD_BYTES or end > size:
                scan.stopped = f"a record cut short at byte {pos}"
                break
            try:
                fields = _ros1_header(header)
                op = _ros1_op(fields)
            except ScanError as e:
                if first:
                    raise
                scan.stopped = f"bytes that are no record at byte {pos} ({e})"
                break
            if first:
                if op != _R1_BAGHEADER:
                    raise ScanError("the bag does not start with its header record")
                first = False
                f.seek(dlen, 1)
            elif op == _R1_CHUNK:
                data = _read_exact(f, dlen)
                try:
                    _ros1_take_chunk(scan, fields, data)
                except ScanError as e:
                    scan.stopped = f"a damaged chunk at byte {pos}: {e}"
                    break
                scan._records.append((op, pos, end - pos))
            elif op == _R1_CONNECTION:
                try:
                    conn = _ros1_connection(fields, _read_exact(f, dlen))
                except ScanError as e:
                    scan.stopped = f"a damaged connection record at byte {pos}: {e}"
                    break
                scan.connections.setdefault(conn.id, conn)
            else:
                f.seek(dlen, 1)  # index records: rebuilt from the chunks
            pos = end
    if first:
        raise ScanError("a ROS 1 bag without its header record")
    return scan


def _ros1_connection(fields: dict[str, bytes], data: bytes) -> ScannedConnection:
    """The connection a connection record declares (its data holds the type fields)."""
    info = _ros1_header(data)
    return ScannedConnection(
        _u32_field(fields, "conn"),
        _text_field(fields, "topic"),
        normalize_msgtype(_text_field(info, "type")),
        _text_field(info, "message_definition"),
        "msg",
        _text_field(info, "md5sum"),
    )


def _ros1_take_chunk(scan: Scan, fields: dict[str, bytes], data: bytes) -> None:
    """Account for a whole chunk: its connections, then its messages (all or none)."""
    found: list[tuple[int, int]] = []
    declared: dict[int, ScannedConnection] = {}
    for rfields, rdata in _ros1_records(_ros1_chunk_data(fields, data)):
        op = _ros1_op(rfields)
        if op == _R1_CONNECTION:
            conn = _ros1_connection(rfields, rdata)
            declared[conn.id] = conn
        elif op == _R1_MSGDATA:
            cid = _u32_field(rfields, "conn")
            if cid not in scan.connections and cid not in declared:
                raise ScanError(f"a message on connection {cid}, which no record declared")
            found.append((cid, _ros1_time(rfields)))
    for cid, conn in declared.items():
        scan.connections.setdefault(cid, conn)
    for cid, t in found:
        scan._count(cid, t)


__all__ = [
    "MAX_RECORD_BYTES",
    "MCAP_MAGIC",
    "ROS1_MAGIC",
    "Scan",
    "ScanError",
    "ScannedConnection",
    "scan_mcap",
    "scan_ros1",
]
