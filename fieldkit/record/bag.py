"""A robot's flight recording as a rosbag: `BagWriter` writes one, `BagReader` reads one back.

This module owns the bag's layout: its topics and their types (the table in
docs/recording.md), the storage (a ROS 2 bag with MCAP storage, a directory, unless the path
ends in `.bag`, which makes a ROS 1 bag), how a recording survives being killed, and how it
is split into parts. rosbags does the container formats; the writer reaches into its MCAP and
ROS 1 writers only to close a chunk on demand, which is what crash survival rests on.

    with BagWriter("flight") as w:            # BagError on an unusable path
        w.meta(Meta(robot_id=3, ...))          # first, once
        w.autopilot_rx(tick, data, unix_ns)    # each read; also writes /mavlink/from
        w.tick(TickRow(...))                   # each tick, after it ran; also /fix, /battery

    r = BagReader("flight")                    # every part, damaged ones repaired on the fly
    r.meta; r.topics(); r.duration_s
    for row in r.ticks(): ...

Crash survival: rosbags' writers keep up to 1 MiB in memory before they write a chunk, and
write the index only at close. `BagWriter` closes the open chunk and hands it to the OS at
the first tick boundary once `flush_s` has passed (at any message in a bag without ticks);
a background thread then syncs it to the disk. A kill -9 loses at most the data since that
flush. `BagReader` reads a bag without its index by scanning its records
(fieldkit.record.scan) up to the last whole chunk.

Message stamps are the wall time (ns) of each record, made strictly increasing by the writer
(a wall clock stepped back by NTP cannot reorder a recording): ROS tools sort by stamp, so
stamp order is write order. The tick fields, not the stamps, are what replay goes by.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import threading
import time
import zlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

import numpy as np
from rosbags import rosbag1, rosbag2
from rosbags.rosbag2.storage_mcap import McapWriter
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

import fieldkit
from fieldkit.errors import FieldkitError
from fieldkit.record import scan as scanning
from fieldkit.record.types import (
    BATTERY_STATE,
    MAVLINK,
    META,
    NAV_SAT_FIX,
    OUTBOX_PATCH,
    RADIO_FRAME,
    SERIAL_CHUNK,
    STREAM_SEND,
    TICK,
    typestore,
)
from fieldkit.vehicle.mavlink import FrameReader, new_codec

TOPIC_META = "/fieldkit/meta"
TOPIC_TICK = "/fieldkit/tick"
TOPIC_RX = "/autopilot/rx"
TOPIC_TX = "/autopilot/tx"
TOPIC_STREAM = "/autopilot/stream"
TOPIC_GPS_RX = "/gps/rx"
TOPIC_MAVLINK_FROM = "/mavlink/from"
TOPIC_MAVLINK_TO = "/mavlink/to"
TOPIC_RADIO_IN = "/radio/in"
TOPIC_RADIO_OUT = "/radio/out"
TOPIC_FIX = "/fix"
TOPIC_BATTERY = "/battery"
TOPIC_OUTBOX = "/update/outbox"

TOPIC_TYPES: dict[str, str] = {
    TOPIC_META: META,
    TOPIC_RX: SERIAL_CHUNK,
    TOPIC_TX: SERIAL_CHUNK,
    TOPIC_MAVLINK_FROM: MAVLINK,
    TOPIC_MAVLINK_TO: MAVLINK,
    TOPIC_RADIO_IN: RADIO_FRAME,
    TOPIC_RADIO_OUT: RADIO_FRAME,
    TOPIC_FIX: NAV_SAT_FIX,
    TOPIC_BATTERY: BATTERY_STATE,
    TOPIC_OUTBOX: OUTBOX_PATCH,
    TOPIC_TICK: TICK,
    TOPIC_GPS_RX: SERIAL_CHUNK,
    TOPIC_STREAM: STREAM_SEND,
}
"""Every topic of a fieldkit bag and its type, in the order the writer declares them."""

REQUIRED_TOPICS = (TOPIC_META, TOPIC_RX)
"""What every fieldkit bag has, and the least a replay needs: the meta and the autopilot's bytes."""

DEFAULT_MAX_BYTES = 64 * 1024 * 1024
"""A part's size before the writer starts the next one."""
MIN_MAX_BYTES = 64 * 1024
"""The smallest part size allowed: a part holds at least its meta and a few chunks."""

_HINT_FOREIGN = "this bag was not written by fieldkit (`fieldkit node --record`, `bag from-tlog`)"
_HINT_CORRUPT = "its bytes changed after it was recorded (a disk or copy fault?): copy it again"

_FINGERPRINT = re.compile(r"[0-9a-fA-F]{8,32}")
#: Text that only a secret holds: a swarm key file's tag, a PEM private key.
_SECRET_MARKS = ("fieldkit-swarm-key-v1", "PRIVATE KEY")


class BagError(FieldkitError):
    """A bag that cannot be written or read: the file, the problem, and a hint."""

    def __init__(self, file: str | Path, problem: str, hint: str) -> None:
        self.file = Path(file)
        self.problem = problem
        self.hint = hint
        super().__init__(f"{file}: {problem}\nhint: {hint}")

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickle with all three arguments."""
        return (BagError, (self.file, self.problem, self.hint))


# ------------------------------------------------------------------------------------- rows


@dataclass(frozen=True)
class Meta:
    """What a recording holds once, at the head of each part: enough to replay it alone."""

    robot_id: int
    seed: int = 0
    profile_toml: str = ""
    #: The node's options as JSON: script name, --set globals, commands, security mode...
    config_json: str = "{}"
    script_name: str = ""
    bo: bytes = b""
    bdb: bytes = b""
    bpos: bytes = b""
    #: The swarm key's fingerprint ("" without keys): never a key itself.
    key_fingerprint: str = ""
    fieldkit_version: str = fieldkit.__version__
    started_unix_ns: int = 0

    @property
    def script_sha256(self) -> str:
        """SHA-256 of the recorded bytecode (hex); "" when the bag holds no script."""
        return hashlib.sha256(self.bo).hexdigest() if self.bo else ""

    def config(self) -> dict[str, Any]:
        """`config_json` parsed ({} when it is not a JSON object)."""
        try:
            value = json.loads(self.config_json)
        except ValueError:
            return {}
        return value if isinstance(value, dict) else {}


@dataclass(frozen=True)
class TickRow:
    """One tick of the node, written after it ran: what the script saw, did and became."""

    tick: int
    #: The node's monotonic clock, seconds since it started.
    clock_s: float
    #: The wall time the tick's bundle carried (ns since the epoch).
    unix_ns: int
    lat: float
    lon: float
    alt: float
    north: float
    east: float
    yaw: float
    voltage: float
    battery_percent: float
    status: str = ""
    armed: bool = False
    rc_cmd: int = 0
    #: The order sent to the vehicle ("" for none) and its arguments.
    order_kind: str = ""
    order_args: tuple[float, ...] = ()
    #: The safety supervisor's decisions this tick.
    events: tuple[str, ...] = ()
    #: BVMSTATE ("" if none).
    state: str = ""
    #: The script state's digest (32 bytes).
    digest: bytes = b""
    #: The script's log lines of this tick.
    log: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        # Callers hand lists; rows compare equal to what a reader gives back only as tuples.
        for name in ("order_args", "events", "log"):
            value = getattr(self, name)
            if not isinstance(value, tuple):
                object.__setattr__(self, name, tuple(value))
        if not isinstance(self.digest, bytes):
            object.__setattr__(self, "digest", bytes(self.digest))


@dataclass(frozen=True)
class SerialChunk:
    """Bytes of one read from (or write to) the autopilot, as they moved on the line."""

    tick: int
    data: bytes
    unix_ns: int


@dataclass(frozen=True)
class StreamSend:
    """A frame the link's own thread sent between two polls: its tick, and when (clock_s)."""

    tick: int
    clock_s: float
    unix_ns: int


@dataclass(frozen=True)
class RadioFrame:
    """One radio frame in or out: the sender's robot id and the air bytes."""

    tick: int
    sender: int
    data: bytes
    unix_ns: int
    #: Where the sender was (east, north; the simulator's), NaN from a real radio.
    east: float = math.nan
    north: float = math.nan


@dataclass(frozen=True)
class OutboxPatch:
    """A patch the node read from its outbox (/update/outbox): an input of its tick."""

    tick: int
    data: bytes
    unix_ns: int


@dataclass(frozen=True)
class MavlinkFrame:
    """One MAVLink frame of /mavlink/from or /mavlink/to: its bytes and pymavlink's decoding."""

    unix_ns: int
    frame: bytes
    #: The pymavlink message (`.get_type()`, fields as attributes); None if it does not decode.
    message: Any = field(compare=False)


@dataclass(frozen=True)
class Fix:
    """A position of /fix: degrees, metres above home; `has_fix` False where GPS had none."""

    unix_ns: int
    lat: float
    lon: float
    alt: float
    has_fix: bool


@dataclass(frozen=True)
class Battery:
    """A battery reading of /battery: volts and percent (NaN where unknown)."""

    unix_ns: int
    voltage: float
    percent: float


@dataclass(frozen=True)
class TopicInfo:
    """A topic of a bag: its name, its type, and how many messages it holds."""

    name: str
    type: str
    count: int


Row = (
    Meta
    | TickRow
    | SerialChunk
    | StreamSend
    | RadioFrame
    | OutboxPatch
    | MavlinkFrame
    | Fix
    | Battery
)
"""Anything `BagReader.rows` yields."""


def part_path(path: str | Path, index: int) -> Path:
    """Part `index` of the recording at `path`: the path itself, then `PATH_1`, `PATH_2`...
    (`NAME_1.bag`, `NAME_2.bag`... for a ROS 1 bag)."""
    path = Path(path)
    if index == 0:
        return path
    base = path if path.name else path.resolve()
    if base.suffix == ".bag":
        return base.with_name(f"{base.stem}_{index}.bag")
    return base.with_name(f"{base.name}_{index}")


def part_paths(path: str | Path) -> list[Path]:
    """The parts of the recording at `path` that exist, in order (stops at the first gap)."""
    parts: list[Path] = []
    while part_path(path, len(parts)).exists():
        parts.append(part_path(path, len(parts)))
    return parts


# --------------------------------------------------------------------------- MAVLink frames


def mavlink_fields(frame: bytes) -> dict[str, Any]:
    """The `mavros_msgs/Mavlink` fields of one whole MAVLink 1 or 2 frame (header excluded)."""
    n = frame[1]
    if frame[0] == 0xFE:
        incompat = compat = 0
        seq, sysid, compid, msgid = frame[2], frame[3], frame[4], frame[5]
        start = 6
    else:
        incompat, compat, seq, sysid, compid = frame[2], frame[3], frame[4], frame[5], frame[6]
        msgid = int.from_bytes(frame[7:10], "little")
        start = 10
    payload = bytes(frame[start : start + n])
    checksum = int.from_bytes(frame[start + n : start + n + 2], "little")
    signature = bytes(frame[start + n + 2 :])
    # mavros packs the payload into little-endian uint64 words, the last one zero-padded.
    padded = payload + bytes(-len(payload) % 8)
    return {
        "framing_status": 1,  # FRAMING_OK: only frames pymavlink accepted are recorded
        "magic": frame[0],
        "len": n,
        "incompat_flags": incompat,
        "compat_flags": compat,
        "seq": seq,
        "sysid": sysid,
        "compid": compid,
        "msgid": msgid,
        "checksum": checksum,
        "payload64": np.frombuffer(padded, dtype="<u8").astype(np.uint64),
        "signature": np.frombuffer(signature, dtype=np.uint8),
    }


def mavlink_frame(msg: Any) -> bytes:
    """The frame bytes a `mavros_msgs/Mavlink` message describes (inverse of mavlink_fields)."""
    n = int(msg.len)
    payload = np.asarray(msg.payload64, dtype="<u8").tobytes()[:n]
    if len(payload) != n:
        raise ValueError(f"len {n} but {len(payload)} payload bytes")
    ids = [int(msg.seq), int(msg.sysid), int(msg.compid)]
    if int(msg.magic) == 0xFE:
        head = bytes([0xFE, n, *ids, int(msg.msgid) & 0xFF])
    else:
        flags = [int(msg.incompat_flags), int(msg.compat_flags)]
        head = bytes([0xFD, n, *flags, *ids]) + (int(msg.msgid) & 0xFFFFFF).to_bytes(3, "little")
    signature = bytes(np.asarray(msg.signature, dtype=np.uint8).tobytes())
    return head + payload + (int(msg.checksum) & 0xFFFF).to_bytes(2, "little") + signature


def _decode_frame(frame: bytes) -> Any:
    """pymavlink's decoding of one frame, or None."""
    try:
        decoded = FrameReader(new_codec(None, 255, 0)).feed(frame)
    except Exception:  # noqa: BLE001 - a frame from a file is data, never a crash
        return None
    return decoded[0] if len(decoded) == 1 else None


# ----------------------------------------------------------------------------- the writer


class _Part(Protocol):
    """One part being written, whatever its storage."""

    path: Path

    def write(self, topic: str, stamp: int, raw: bytes) -> None:
        """Add one serialized message."""

    def flush(self) -> None:
        """Close the open chunk and hand everything written so far to the OS."""

    def size(self) -> int:
        """Bytes the part holds, written or pending."""

    def fileno(self) -> int:
        """The open file's descriptor (for syncing)."""

    def close(self) -> None:
        """Write the index and close."""


#: Where a chunk record's CRC field is: after its opcode and length (9 bytes), then its start
#: time, end time and uncompressed size (8 bytes each). https://mcap.dev/spec#chunk-op0x06
_CHUNK_CRC_AT = 9 + 24


class _McapPart:
    """A ROS 2 bag directory with MCAP storage, through rosbags' writer."""

    def __init__(self, path: Path) -> None:
        self.writer = rosbag2.Writer(path, version=9, storage_plugin=rosbag2.StoragePlugin.MCAP)
        self.writer.open()
        ts = typestore(False)
        # All connections first, so that every schema and channel is in the first chunk.
        self.conns = {
            topic: self.writer.add_connection(topic, msgtype, typestore=ts)
            for topic, msgtype in TOPIC_TYPES.items()
        }
        storage = self.writer.storage
        if not isinstance(storage, McapWriter):  # pragma: no cover - rosbags changed
            raise TypeError("rosbags' MCAP writer is not where it used to be")
        self.storage = storage
        self.path = path

    def write(self, topic: str, stamp: int, raw: bytes) -> None:
        """Add one CDR message."""
        self.writer.write(self.conns[topic], stamp, raw)

    def flush(self) -> None:
        """Close the pending chunk (rosbags would wait for 1 MiB) and push it to the OS."""
        storage = self.storage
        if storage.chunk.bio.tell():
            crc = zlib.crc32(storage.chunk.bio.getbuffer())
            start = storage.bio.tell()
            storage.close_chunk()
            # rosbags leaves the chunk's CRC at 0 ("none"); with one, a damaged chunk is an
            # error (rosbags and the scan check it) instead of wrong values read back.
            end = storage.bio.tell()
            storage.bio.seek(start + _CHUNK_CRC_AT)
            storage.bio.write(crc.to_bytes(4, "little"))
            storage.bio.seek(end)
        storage.bio.flush()

    def size(self) -> int:
        """File bytes plus the pending chunk."""
        return self.storage.bio.tell() + self.storage.chunk.bio.tell()

    def fileno(self) -> int:
        """The .mcap file's descriptor."""
        return self.storage.bio.fileno()

    def close(self) -> None:
        """Summary, footer, metadata.yaml."""
        self.flush()  # the last chunk with its CRC too
        self.writer.close()


class _Ros1Part:
    """A ROS 1 bag file, through rosbags' writer."""

    def __init__(self, path: Path) -> None:
        self.writer = rosbag1.Writer(path)
        self.writer.open()
        ts = typestore(True)
        self.conns = {
            topic: self.writer.add_connection(topic, msgtype, typestore=ts)
            for topic, msgtype in TOPIC_TYPES.items()
        }
        self.path = path

    def _bio(self) -> Any:
        """The open file."""
        if self.writer.bio is None:  # pragma: no cover - only after close
            raise ValueError("closed")
        return self.writer.bio

    def write(self, topic: str, stamp: int, raw: bytes) -> None:
        """Add one ROS 1 message."""
        self.writer.write(self.conns[topic], stamp, raw)

    def flush(self) -> None:
        """Write the open chunk (rosbags would wait for 1 MiB) and push it to the OS."""
        chunk = self.writer.chunks[-1]
        if chunk.data.tell():
            self.writer.write_chunk(chunk)
            # rosbags keeps each written chunk's (time, offset) per message until close, for
            # the index, which needs only their number: keep a cheap list of that length.
            for cid, items in chunk.connections.items():
                chunk.connections[cid] = [items[0]] * len(items)
        self._bio().flush()

    def size(self) -> int:
        """File bytes plus the pending chunk."""
        return int(self._bio().tell()) + self.writer.chunks[-1].data.tell()

    def fileno(self) -> int:
        """The .bag file's descriptor."""
        return int(self._bio().fileno())

    def close(self) -> None:
        """Index records and the header's index position."""
        self.writer.close()


class _Syncer:
    """Syncs the part being written to the disk in the background, after each flush.

    A flush hands the data to the OS, which survives a kill -9; only a sync survives a power
    cut. A sync can take tens of milliseconds on an SD card, too long for the tick loop, so a
    thread does it, on a duplicate of the file's descriptor: the writer never waits for it
    (not even to close the file), and a descriptor number reused after a close is never synced
    by mistake.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()  # held only to hand work over, never across a sync
        self._wake = threading.Event()
        self._pending: int | None = None
        self._dirs: list[Path] = []
        self._stop = False
        self.syncs = 0
        self._thread = threading.Thread(target=self._run, name="bag-sync", daemon=True)
        self._thread.start()

    def request(self, fd: int, new_dir: Path | None = None) -> None:
        """Sync `fd`'s file soon (and `new_dir`, whose new entry must survive too)."""
        dup = os.dup(fd)
        with self._lock:
            old, self._pending = self._pending, dup
            if new_dir is not None:
                self._dirs.append(new_dir)
        if old is not None:
            os.close(old)  # a newer flush supersedes a sync that has not started
        self._wake.set()

    def stop(self) -> None:
        """Finish the sync in hand, then end the thread."""
        self._stop = True
        self._wake.set()
        self._thread.join()

    def _run(self) -> None:
        while True:
            self._wake.wait()
            self._wake.clear()
            with self._lock:
                fd, self._pending = self._pending, None
                dirs, self._dirs = self._dirs, []
            try:
                if fd is not None:
                    os.fdatasync(fd)
                for folder in dirs:
                    _sync_dir(folder)
            except OSError:
                pass  # a failing disk shows up in the writes, which raise
            finally:
                if fd is not None:
                    os.close(fd)
            self.syncs += 1
            if self._stop:
                return


def _sync_dir(folder: Path) -> None:
    """fsync a directory, so that a file created in it survives a power cut."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class BagWriter:
    """Records one robot's flight into a bag (see the module's docstring)."""

    def __init__(
        self,
        path: str | Path,
        *,
        max_bytes: int = DEFAULT_MAX_BYTES,
        flush_s: float | None = 1.0,
        fsync: bool = True,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """Create the bag's first part at `path` (a directory; a `.bag` file for ROS 1).

        `max_bytes`: start a new part when one reaches this size. `flush_s`: the most data, in
        seconds of `clock`, a crash may lose (None: no timed flush, only rosbags' own at 1 MiB
        chunks and the close: for conversions). `fsync`: also sync each flush to the disk (a
        power cut), in a background thread. Close it (or use `with`): a writer never closed
        is a bag cut short.
        """
        self.path = Path(path)
        self.ros1 = self.path.suffix == ".bag"
        if max_bytes < MIN_MAX_BYTES:
            raise BagError(path, f"max_bytes {max_bytes} is too small", f"{MIN_MAX_BYTES} or more")
        self.max_bytes = max_bytes
        self.flush_s = flush_s
        self._clock = clock
        self._store = typestore(self.ros1)
        self._serialize = self._store.serialize_ros1 if self.ros1 else self._store.serialize_cdr
        self._types = self._store.types
        for old in (part_path(self.path, 0), part_path(self.path, 1)):
            if old.exists():
                raise BagError(
                    old, "exists already", "record to a new path, or move the old recording away"
                )
        #: The parts written so far, in order.
        self.parts: list[Path] = []
        #: Messages written (all topics).
        self.messages = 0
        self._syncer = _Syncer() if fsync else None
        self._part: _Part | None = None
        try:
            self._open_part()
        except BagError:
            if self._syncer is not None:
                self._syncer.stop()
            raise
        self._meta: Meta | None = None
        self._last_stamp = 0
        self._last_flush = clock()
        self._ticked = False  # whether tick rows come: then flushes and rotations wait for them
        self._rx = FrameReader(new_codec(None, 255, 0))
        self._tx = FrameReader(new_codec(None, 255, 0))

    # ------------------------------------------------------------------ public

    def meta(self, meta: Meta) -> None:
        """Write the recording's meta: first, once. Refuses anything that looks like a secret."""
        if self._meta is not None:
            raise BagError(self.path, "meta written twice", "call meta() once, first")
        self._check_no_secret(meta)
        self._meta = meta
        self._write_meta(meta.started_unix_ns or time.time_ns())
        self.flush()  # a bag cut at any later point still says what it is

    def autopilot_rx(self, tick: int, data: bytes, unix_ns: int) -> list[Any]:
        """Bytes read from the autopilot; returns the MAVLink messages they completed (each
        also goes to /mavlink/from)."""
        stamp = self._stamp(unix_ns)
        self._put(TOPIC_RX, self._chunk(tick, data), stamp)
        return self._frames(self._rx, data, TOPIC_MAVLINK_FROM, stamp)

    def autopilot_tx(self, tick: int, data: bytes, unix_ns: int) -> list[Any]:
        """Bytes written to the autopilot; returns their messages (each also on /mavlink/to)."""
        stamp = self._stamp(unix_ns)
        self._put(TOPIC_TX, self._chunk(tick, data), stamp)
        return self._frames(self._tx, data, TOPIC_MAVLINK_TO, stamp)

    def gps_rx(self, tick: int, data: bytes, unix_ns: int) -> None:
        """Bytes read from a GPS receiver of its own (a Clearpath base's), on /gps/rx."""
        self._put(TOPIC_GPS_RX, self._chunk(tick, data), self._stamp(unix_ns))

    def stream_send(self, tick: int, clock_s: float, unix_ns: int) -> None:
        """A frame the link's thread sent at `clock_s` (its bytes go to `autopilot_tx`)."""
        msg = self._types[STREAM_SEND](tick=tick, clock_s=float(clock_s))
        self._put(TOPIC_STREAM, msg, self._stamp(unix_ns))

    def radio_in(
        self,
        tick: int,
        sender: int,
        data: bytes,
        unix_ns: int,
        where: tuple[float, float] | None = None,
    ) -> None:
        """A frame the radio returned (`where` the sender was, if the host knows: east, north)."""
        self._put(TOPIC_RADIO_IN, self._radio(tick, sender, data, where), self._stamp(unix_ns))

    def radio_out(self, tick: int, sender: int, data: bytes, unix_ns: int) -> None:
        """A frame the node sent (`sender`: this robot)."""
        self._put(TOPIC_RADIO_OUT, self._radio(tick, sender, data), self._stamp(unix_ns))

    def outbox(self, tick: int, data: bytes, unix_ns: int) -> None:
        """A patch the node read from its outbox at the start of `tick`."""
        msg = self._types[OUTBOX_PATCH](tick=tick, data=np.frombuffer(data, dtype=np.uint8))
        self._put(TOPIC_OUTBOX, msg, self._stamp(unix_ns))

    def fix(self, lat: float, lon: float, alt: float, unix_ns: int, has_fix: bool = True) -> None:
        """A position on /fix (`tick` writes one each tick; a tlog conversion calls this)."""
        stamp = self._stamp(unix_ns)
        Status = self._types["sensor_msgs/msg/NavSatStatus"]
        msg = self._types[NAV_SAT_FIX](
            header=self._header(stamp),
            status=Status(status=0 if has_fix else -1, service=1),  # STATUS_FIX, SERVICE_GPS
            latitude=float(lat),
            longitude=float(lon),
            altitude=float(alt),
            position_covariance=np.zeros(9, dtype=np.float64),
            position_covariance_type=0,  # COVARIANCE_TYPE_UNKNOWN
        )
        self._put(TOPIC_FIX, msg, stamp)

    def battery(self, voltage: float, percent: float, unix_ns: int) -> None:
        """A battery reading on /battery (percent 0-100, NaN where unknown)."""
        stamp = self._stamp(unix_ns)
        nan = math.nan
        msg = self._types[BATTERY_STATE](
            header=self._header(stamp),
            voltage=float(voltage),
            temperature=nan,
            current=nan,
            charge=nan,
            capacity=nan,
            design_capacity=nan,
            percentage=float(percent) / 100.0,
            power_supply_status=0,
            power_supply_health=0,
            power_supply_technology=0,
            present=True,
            cell_voltage=np.zeros(0, dtype=np.float32),
            cell_temperature=np.zeros(0, dtype=np.float32),
            location="",
            serial_number="",
        )
        self._put(TOPIC_BATTERY, msg, stamp)

    def tick(self, row: TickRow) -> None:
        """The tick's row (with /fix and /battery from its sensors); the tick's data is then
        complete, so this is where the writer flushes and starts a new part."""
        self.fix(row.lat, row.lon, row.alt, row.unix_ns, has_fix=not math.isnan(row.lat))
        self.battery(row.voltage, row.battery_percent, row.unix_ns)
        msg = self._types[TICK](
            tick=row.tick,
            clock_s=float(row.clock_s),
            unix_ns=row.unix_ns,
            lat=float(row.lat),
            lon=float(row.lon),
            alt=float(row.alt),
            north=float(row.north),
            east=float(row.east),
            yaw=float(row.yaw),
            voltage=float(row.voltage),
            battery_percent=float(row.battery_percent),
            status=row.status,
            armed=bool(row.armed),
            rc_cmd=row.rc_cmd,
            order_kind=row.order_kind,
            order_args=np.asarray(row.order_args, dtype=np.float64),
            events=list(row.events),
            state=row.state,
            digest=np.frombuffer(row.digest, dtype=np.uint8),
            log=list(row.log),
        )
        self._put(TOPIC_TICK, msg, self._stamp(row.unix_ns), boundary=True)

    def flush(self) -> None:
        """Hand everything recorded so far to the OS (and have it synced to the disk)."""
        part = self._open()
        try:
            part.flush()
        except OSError as e:
            raise self._os_error(e) from None
        self._last_flush = self._clock()
        if self._syncer is not None:
            self._syncer.request(part.fileno())

    def close(self) -> None:
        """Write the last part's index and close it (a second call does nothing)."""
        part, self._part = self._part, None
        if part is None:
            return
        try:
            part.close()
        except OSError as e:
            raise self._os_error(e) from None
        finally:
            if self._syncer is not None:
                self._syncer.stop()

    def __enter__(self) -> BagWriter:
        """The writer itself."""
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Close, also after an error: what was recorded stays readable."""
        self.close()

    # ------------------------------------------------------------------ inside

    def _open(self) -> _Part:
        """The part being written (BagError once closed)."""
        if self._part is None:
            raise BagError(self.path, "written after close", "a closed BagWriter takes no data")
        return self._part

    def _open_part(self) -> None:
        """Create the next part."""
        path = part_path(self.path, len(self.parts))
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self._part = _Ros1Part(path) if self.ros1 else _McapPart(path)
        except (OSError, rosbag1.WriterError, rosbag2.WriterError) as e:
            reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
            raise BagError(
                path, f"cannot create the bag: {reason}", "record to a writable, new path"
            ) from None
        self.parts.append(path)
        if self._syncer is not None:
            self._syncer.request(self._part.fileno(), path.parent)

    def _rotate(self) -> None:
        """Close the full part and go on in the next one, which starts with the meta again."""
        part = self._open()
        try:
            part.close()
        except OSError as e:
            raise self._os_error(e) from None
        self._part = None
        self._open_part()
        if self._meta is not None:
            self._write_meta(self._last_stamp + 1)
            self.flush()

    def _write_meta(self, unix_ns: int) -> None:
        """The meta message."""
        meta = self._meta
        assert meta is not None
        u8 = np.uint8
        msg = self._types[META](
            robot_id=meta.robot_id,
            seed=meta.seed,
            profile_toml=meta.profile_toml,
            config_json=meta.config_json,
            script_name=meta.script_name,
            bo=np.frombuffer(meta.bo, dtype=u8),
            bdb=np.frombuffer(meta.bdb, dtype=u8),
            bpos=np.frombuffer(meta.bpos, dtype=u8),
            key_fingerprint=meta.key_fingerprint,
            fieldkit_version=meta.fieldkit_version,
            started_unix_ns=meta.started_unix_ns,
        )
        self._put(TOPIC_META, msg, self._stamp(unix_ns), first=True)

    def _check_no_secret(self, meta: Meta) -> None:
        """BagError if the meta carries what looks like a key rather than its fingerprint."""
        hint = "a recording holds the key's fingerprint only, never key material"
        if meta.key_fingerprint and not _FINGERPRINT.fullmatch(meta.key_fingerprint):
            raise BagError(self.path, "key_fingerprint is not a fingerprint (8-32 hex)", hint)
        for name in ("config_json", "profile_toml", "script_name"):
            text = getattr(meta, name)
            if any(mark in text for mark in _SECRET_MARKS):
                raise BagError(self.path, f"refusing to record a secret found in {name}", hint)

    def _stamp(self, unix_ns: int) -> int:
        """The message's stamp: its wall time, but always after the previous stamp."""
        stamp = max(int(unix_ns), self._last_stamp + 1)
        self._last_stamp = stamp
        return stamp

    def _header(self, stamp: int) -> Any:
        """A std_msgs/Header at `stamp`."""
        Time = self._types["builtin_interfaces/msg/Time"]
        t = Time(sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000)
        frame = f"robot{self._meta.robot_id}" if self._meta is not None else ""
        Header = self._types["std_msgs/msg/Header"]
        return Header(seq=0, stamp=t, frame_id=frame) if self.ros1 else Header(t, frame)

    def _chunk(self, tick: int, data: bytes) -> Any:
        """A SerialChunk message."""
        return self._types[SERIAL_CHUNK](tick=tick, data=np.frombuffer(data, dtype=np.uint8))

    def _radio(
        self, tick: int, sender: int, data: bytes, where: tuple[float, float] | None = None
    ) -> Any:
        """A RadioFrame message."""
        arr = np.frombuffer(data, dtype=np.uint8)
        east, north = (math.nan, math.nan) if where is None else where
        return self._types[RADIO_FRAME](
            tick=tick, sender=sender, data=arr, east=float(east), north=float(north)
        )

    def _frames(self, reader: FrameReader, data: bytes, topic: str, stamp: int) -> list[Any]:
        """Parse `data` on (rx or tx) and record each whole frame on `topic`."""
        messages = reader.feed(bytes(data))
        for m in messages:
            fields = mavlink_fields(bytes(m.get_msgbuf()))
            msg = self._types[MAVLINK](header=self._header(stamp), **fields)
            self._put(topic, msg, self._stamp(stamp))
        return messages

    def _put(
        self, topic: str, msg: Any, stamp: int, *, boundary: bool = False, first: bool = False
    ) -> None:
        """Serialize and write one message; flush and rotate when due."""
        if self._meta is None:
            raise BagError(self.path, f"{topic} before the meta", "call meta() first")
        part = self._open()
        try:
            raw = self._serialize(msg, TOPIC_TYPES[topic])
        except Exception as e:  # noqa: BLE001 - rosbags reports a bad value many ways
            raise BagError(
                self.path, f"cannot record {topic}: {e}", "a value is out of its field's range"
            ) from None
        try:
            part.write(topic, stamp, bytes(raw))
        except OSError as e:
            raise self._os_error(e) from None
        self.messages += 1
        if first:
            return
        # In a recording with ticks, a flush and a new part wait for the tick's end, so that a
        # cut bag holds whole ticks (a flush does not wait past twice flush_s, though: a node
        # stalled inside a tick); without ticks (a tlog), they come at any message.
        self._ticked = self._ticked or boundary
        at_end = boundary or not self._ticked
        if self.flush_s is not None:
            waited = self._clock() - self._last_flush
            if waited >= self.flush_s * (1 if at_end else 2):
                self.flush()
        if at_end and part.size() >= self.max_bytes:
            self._rotate()

    def _os_error(self, e: OSError) -> BagError:
        """A write that failed, as a BagError."""
        where = self.parts[-1] if self.parts else self.path
        return BagError(where, f"cannot write: {e.strerror or e}", "check the disk (full?)")


# ----------------------------------------------------------------------------- the reader


@dataclass
class _Conn:
    """A topic of one part: its type, its embedded definition, its message count."""

    topic: str
    msgtype: str
    msgdef: str
    md5sum: str
    count: int


class _Source(Protocol):
    """One part being read: rosbags' reader for a whole bag, a scan for a cut one."""

    path: Path
    storage: str
    conns: list[_Conn]
    start_ns: int
    end_ns: int
    #: "" for an intact part; else what was wrong and what was read.
    damage: str

    def messages(self, topics: set[str]) -> Iterator[tuple[str, int, bytes]]:
        """(topic, stamp, raw) of those topics, in recorded order."""
        ...


class _RosbagsSource:
    """An intact part, read with rosbags (any storage it knows: MCAP, sqlite3, ROS 1)."""

    def __init__(self, path: Path, ros1: bool) -> None:
        self.path = path
        self.ros1 = ros1
        self.damage = ""
        with self._reader() as r:
            # A ROS 2 bag's counts and times come from its metadata.yaml, which rosbags takes
            # as it is: text where a number belongs is a damaged file (and the scan's turn).
            self.conns = [
                _Conn(
                    str(c.topic),
                    str(c.msgtype),
                    str(c.msgdef.data),
                    str(c.digest) if ros1 else "",
                    _number(c.msgcount, "a message count"),
                )
                for c in r.connections
            ]
            count = _number(r.message_count, "the message count")
            self.start_ns = _number(r.start_time, "the start time") if count else 0
            self.end_ns = _number(r.end_time, "the end time") - 1 if count else 0
            if ros1:
                self.storage = "ros1"
            else:
                self.storage = _rosbag2_storage(path)

    def _reader(self) -> Any:
        """A rosbags reader of the part (a context manager)."""
        return rosbag1.Reader(self.path) if self.ros1 else rosbag2.Reader(self.path)

    def messages(self, topics: set[str]) -> Iterator[tuple[str, int, bytes]]:
        """Through rosbags, which yields in stamp order (= recorded order, see module doc)."""
        with self._reader() as r:
            wanted = [c for c in r.connections if c.topic in topics]
            if not wanted:
                return
            for c, t, raw in r.messages(connections=wanted):
                yield c.topic, t, bytes(raw)


def _number(value: object, what: str) -> int:
    """`value` if it is a whole number of at least 0, else ValueError naming `what`."""
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"{what} is {value!r}, not a number")
    return value


def _rosbag2_storage(path: Path) -> str:
    """The storage a ROS 2 bag directory (or a bare storage file) uses."""
    if path.is_file():
        return path.suffix.lstrip(".")
    meta = (path / "metadata.yaml").read_text("utf-8", errors="replace")
    found = re.search(r"storage_identifier:\s*(\S+)", meta)
    return found.group(1) if found else "?"


class _ScanSource:
    """A part without its index (cut short), read by scanning its records."""

    def __init__(self, path: Path, file: Path, ros1: bool, why: str) -> None:
        self.path = path
        self.storage = "ros1" if ros1 else "mcap"
        self.scan = scanning.scan_ros1(file) if ros1 else scanning.scan_mcap(file)
        s = self.scan
        self.conns = [
            _Conn(c.topic, c.msgtype, c.msgdef, c.md5sum, s.counts.get(c.id, 0))
            for c in s.connections.values()
        ]
        self.start_ns = s.start_ns
        self.end_ns = s.end_ns
        self.damage = (
            f"{why}: read by scanning its records, up to byte {s.good_bytes} of {s.size}: "
            f"{s.message_count} messages" + (f"; then {s.stopped}" if s.stopped else "")
        )

    def messages(self, topics: set[str]) -> Iterator[tuple[str, int, bytes]]:
        """The scan's messages, in file order."""
        ids = {cid for cid, c in self.scan.connections.items() if c.topic in topics}
        names = {cid: c.topic for cid, c in self.scan.connections.items()}
        for cid, t, raw in self.scan.messages(ids):
            yield names[cid], t, raw


def _open_source(path: Path, ros1: bool) -> _Source:
    """Read part `path`: with rosbags if it is whole, else by scanning (BagError if neither)."""
    if not path.exists():
        raise BagError(path, "no such bag", "give the path `--record` wrote (a directory or .bag)")
    if ros1:
        if not path.is_file():
            raise BagError(path, "not a file", "a ROS 1 bag (.bag) is one file")
        file = path
    elif path.is_file():
        if path.suffix != ".mcap":
            hint = "a ROS 2 bag is a directory; a ROS 1 bag's name ends in .bag"
            if path.suffix == ".tlog":
                hint = f"convert a tlog first: fieldkit bag from-tlog {path} -o BAG"
            raise BagError(path, "not a bag directory", hint)
        file = path
    else:
        files = sorted(path.glob("*.mcap"))
        if not (path / "metadata.yaml").exists() and len(files) != 1:
            problem = "no metadata.yaml and no .mcap file" if not files else "several .mcap files"
            raise BagError(path, f"not a fieldkit bag: {problem}", _HINT_FOREIGN)
        file = files[0] if files else path
    try:
        return _RosbagsSource(path, ros1)
    except Exception as e:  # noqa: BLE001 - rosbags reports damage in many ways
        first = _describe(e)
    if file.is_dir():  # a metadata.yaml rosbags refused, and no MCAP file to scan
        raise BagError(path, f"unreadable: {first}", _HINT_FOREIGN)
    if ros1 and "not indexed" in first:
        why = "not closed (no index)"
    elif not ros1 and not (path / "metadata.yaml").exists():
        why = "not closed (no metadata.yaml)"
    else:
        why = f"unreadable by rosbags ({first})"
    try:
        return _ScanSource(path, file, ros1, why)
    except scanning.ScanError as e:
        raise BagError(file, f"unreadable: {e}", _HINT_FOREIGN) from None
    except OSError as e:
        raise BagError(file, f"cannot read: {e.strerror or e}", "check the path") from None


def _describe(e: BaseException) -> str:
    """A rosbags error as a short phrase."""
    text = str(e).strip().rstrip(".") or type(e).__name__
    return text[:1].lower() + text[1:]


@dataclass
class _Checked:
    """Our definitions, to compare embedded ones with (built once)."""

    md5: dict[str, str]
    text: dict[str, str]
    rihs: dict[str, str]


_checked: dict[bool, _Checked] = {}


def _ours(ros1: bool) -> _Checked:
    """Our types' ROS 1 md5s, ROS 2 definition texts and RIHS01 hashes."""
    if ros1 not in _checked:
        ts = typestore(ros1)
        types = set(TOPIC_TYPES.values())
        if ros1:
            _checked[ros1] = _Checked({t: ts.generate_msgdef(t)[1] for t in types}, {}, {})
        else:
            text = {t: ts.generate_msgdef(t, ros_version=2)[0] for t in types}
            _checked[ros1] = _Checked({}, text, {t: ts.hash_rihs01(t) for t in types})
    return _checked[ros1]


def _check_types(source: _Source, ros1: bool) -> None:
    """BagError unless every fieldkit topic of the part has fieldkit's type and definition."""
    ours = _ours(ros1)
    for c in source.conns:
        expected = TOPIC_TYPES.get(c.topic)
        if expected is None:
            continue  # a topic someone added: not ours to judge
        if c.msgtype != expected:
            problem = f"topic {c.topic} has type {c.msgtype}, where fieldkit records {expected}"
            raise BagError(source.path, problem, _HINT_FOREIGN)
        if ros1:
            same = not c.md5sum or c.md5sum == ours.md5[expected]
        else:
            same = not c.msgdef or c.msgdef == ours.text[expected]
            same = same or _rihs01(c.msgdef, expected) == ours.rihs[expected]
        if not same:
            problem = f"topic {c.topic}: {expected} is defined differently from fieldkit's"
            raise BagError(source.path, problem, _HINT_FOREIGN)


def _rihs01(msgdef: str, msgtype: str) -> str:
    """The RIHS01 hash of an embedded ROS 2 definition ("" if it does not parse)."""
    try:
        ts = get_typestore(Stores.EMPTY)
        ts.register(get_types_from_msg(msgdef, msgtype))
        return str(ts.hash_rihs01(msgtype))
    except Exception:  # noqa: BLE001 - a definition from a file may be anything
        return ""


class BagReader:
    """One recording, all its parts, read as one (see the module's docstring)."""

    def __init__(self, path: str | Path) -> None:
        """Open the recording at `path`; BagError for anything that is not a readable
        fieldkit bag holding at least its meta and /autopilot/rx."""
        self.path = Path(path)
        self.ros1 = self.path.suffix == ".bag"
        self._store = typestore(self.ros1)
        paths = part_paths(self.path) or [self.path]
        #: What was wrong with damaged parts, and what was read of them (one line each).
        self.repairs: list[str] = []
        self._sources: list[_Source] = []
        for i, p in enumerate(paths):
            try:
                source = _open_source(p, self.ros1)
            except BagError as e:
                if i and i == len(paths) - 1 and _empty_part(p):
                    # The last part, cut right after it was created: nothing in it to lose.
                    self.repairs.append(f"{p}: cut right after it was created; holds nothing")
                    break
                raise e from None
            _check_types(source, self.ros1)
            if not sum(c.count for c in source.conns) and i and i == len(paths) - 1:
                self.repairs.append(f"{p}: cut right after it was created; holds nothing")
                break
            self._sources.append(source)
            if source.damage:
                self.repairs.append(f"{p}: {source.damage}")
        self.parts = [s.path for s in self._sources]
        self.storage = self._sources[0].storage
        self.meta = self._first_meta(self._sources[0])
        for source in self._sources[1:]:
            other = self._first_meta(source)
            if (other.robot_id, other.started_unix_ns) != (
                self.meta.robot_id,
                self.meta.started_unix_ns,
            ):
                raise BagError(
                    source.path,
                    "a part of another recording (its meta differs from the first part's)",
                    f"move it away from {self.path}",
                )
        self.require(*REQUIRED_TOPICS)

    # ------------------------------------------------------------------ what it holds

    def topics(self) -> list[TopicInfo]:
        """Every topic with its type and message count over all parts, by name."""
        found: dict[str, list[Any]] = {}
        for source in self._sources:
            for c in source.conns:
                entry = found.setdefault(c.topic, [c.msgtype, 0])
                entry[1] += c.count
        return [TopicInfo(name, t, n) for name, (t, n) in sorted(found.items())]

    def count(self, topic: str) -> int:
        """Messages on `topic` (0 if the bag has no such topic)."""
        return sum(c.count for s in self._sources for c in s.conns if c.topic == topic)

    def require(self, *topics: str) -> None:
        """BagError naming the topics of `topics` the recording lacks (a replay's check)."""
        have = {c.topic for s in self._sources for c in s.conns}
        missing = [t for t in topics if t not in have]
        if TOPIC_META in topics and TOPIC_META in have and not self.count(TOPIC_META):
            missing.append(TOPIC_META)
        if missing:
            raise BagError(
                self.path,
                f"lacks {', '.join(missing)}: not a complete fieldkit recording",
                "record with `fieldkit node --record`, or convert a tlog with "
                "`fieldkit bag from-tlog`",
            )

    @property
    def start_ns(self) -> int:
        """Stamp of the first message (ns since the epoch)."""
        return min((s.start_ns for s in self._sources if _has_messages(s)), default=0)

    @property
    def end_ns(self) -> int:
        """Stamp of the last message."""
        return max((s.end_ns for s in self._sources if _has_messages(s)), default=0)

    @property
    def duration_s(self) -> float:
        """Seconds from the first message to the last."""
        return (self.end_ns - self.start_ns) / 1e9

    @property
    def message_count(self) -> int:
        """Messages in all parts."""
        return sum(c.count for s in self._sources for c in s.conns)

    # ------------------------------------------------------------------ rows

    def rows(self, *topics: str) -> Iterator[tuple[str, Row]]:
        """(topic, row) of the given topics (all if none), in recorded order across parts."""
        wanted = set(topics or TOPIC_TYPES)
        unknown = wanted - set(TOPIC_TYPES)
        if unknown:
            raise ValueError(f"not fieldkit topics: {', '.join(sorted(unknown))}")
        for source in self._sources:
            yield from self._rows_of(source, wanted)

    def ticks(self) -> Iterator[TickRow]:
        """/fieldkit/tick: one row per tick."""
        for _, row in self.rows(TOPIC_TICK):
            assert isinstance(row, TickRow)
            yield row

    def autopilot_rx(self) -> Iterator[SerialChunk]:
        """/autopilot/rx: the bytes read from the autopilot, chunk by chunk."""
        yield from self._serial(TOPIC_RX)

    def autopilot_tx(self) -> Iterator[SerialChunk]:
        """/autopilot/tx: the bytes written to the autopilot."""
        yield from self._serial(TOPIC_TX)

    def gps_rx(self) -> Iterator[SerialChunk]:
        """/gps/rx: the bytes read from a GPS receiver of its own (none in older bags)."""
        yield from self._serial(TOPIC_GPS_RX)

    def stream_sends(self) -> Iterator[StreamSend]:
        """/autopilot/stream: when the link's thread sent a frame (none in older bags)."""
        for _, row in self.rows(TOPIC_STREAM):
            assert isinstance(row, StreamSend)
            yield row

    def radio_in(self) -> Iterator[RadioFrame]:
        """/radio/in: the frames the radio returned."""
        yield from self._radio(TOPIC_RADIO_IN)

    def radio_out(self) -> Iterator[RadioFrame]:
        """/radio/out: the frames the node sent."""
        yield from self._radio(TOPIC_RADIO_OUT)

    def outbox(self) -> Iterator[OutboxPatch]:
        """/update/outbox: the patches the node read from its outbox."""
        for _, row in self.rows(TOPIC_OUTBOX):
            assert isinstance(row, OutboxPatch)
            yield row

    def mavlink_from(self) -> Iterator[MavlinkFrame]:
        """/mavlink/from: the autopilot's frames, decoded with pymavlink."""
        yield from self._mavlink(TOPIC_MAVLINK_FROM)

    def mavlink_to(self) -> Iterator[MavlinkFrame]:
        """/mavlink/to: the node's frames to the autopilot, decoded with pymavlink."""
        yield from self._mavlink(TOPIC_MAVLINK_TO)

    def fixes(self) -> Iterator[Fix]:
        """/fix: the positions (each tick's, or a tlog's GPS)."""
        for _, row in self.rows(TOPIC_FIX):
            assert isinstance(row, Fix)
            yield row

    def batteries(self) -> Iterator[Battery]:
        """/battery: the battery readings."""
        for _, row in self.rows(TOPIC_BATTERY):
            assert isinstance(row, Battery)
            yield row

    def _serial(self, topic: str) -> Iterator[SerialChunk]:
        for _, row in self.rows(topic):
            assert isinstance(row, SerialChunk)
            yield row

    def _radio(self, topic: str) -> Iterator[RadioFrame]:
        for _, row in self.rows(topic):
            assert isinstance(row, RadioFrame)
            yield row

    def _mavlink(self, topic: str) -> Iterator[MavlinkFrame]:
        for _, row in self.rows(topic):
            assert isinstance(row, MavlinkFrame)
            yield row

    def _first_meta(self, source: _Source) -> Meta:
        """The meta at the head of a part (BagError if it has none)."""
        for _, row in self._rows_of(source, {TOPIC_META}):
            assert isinstance(row, Meta)
            return row
        raise BagError(
            source.path,
            "holds no /fieldkit/meta: not a fieldkit bag, or cut before its first second",
            _HINT_FOREIGN,
        )

    def _rows_of(self, source: _Source, topics: set[str]) -> Iterator[tuple[str, Row]]:
        """Rows of some topics of one part, in recorded order."""
        try:
            for t, stamp, raw in source.messages(topics):
                yield t, self._row(source.path, t, stamp, raw)
        except BagError:
            raise
        except Exception as e:  # noqa: BLE001 - damage found while reading
            raise BagError(source.path, f"unreadable: {_describe(e)}", _HINT_CORRUPT) from None

    def _row(self, where: Path, topic: str, stamp: int, raw: bytes) -> Row:
        """Deserialize one message into its row (BagError if it does not deserialize)."""
        msgtype = TOPIC_TYPES[topic]
        try:
            if self.ros1:
                msg = self._store.deserialize_ros1(raw, msgtype)
            else:
                msg = self._store.deserialize_cdr(raw, msgtype)
            return _to_row(topic, msg, stamp)
        except Exception as e:  # noqa: BLE001 - bytes from a file may be anything
            raise BagError(
                where, f"a {topic} message does not decode ({_describe(e)})", _HINT_CORRUPT
            ) from None


def _has_messages(source: _Source) -> bool:
    """Whether a part holds any message."""
    return any(c.count for c in source.conns)


def _empty_part(path: Path) -> bool:
    """A part that holds no data at all: an empty directory or file, or headers only."""
    if path.is_dir():
        files = [f for f in path.iterdir() if f.is_file()]
        return all(f.stat().st_size < 4096 for f in files)
    return path.is_file() and path.stat().st_size <= 4096 + 13 + 64


def _text(value: Any) -> str:
    """A string field (rosbags gives str)."""
    return str(value)


def _to_row(topic: str, msg: Any, stamp: int) -> Row:
    """A deserialized message as the row of its topic."""
    if topic == TOPIC_META:
        return Meta(
            robot_id=int(msg.robot_id),
            seed=int(msg.seed),
            profile_toml=_text(msg.profile_toml),
            config_json=_text(msg.config_json),
            script_name=_text(msg.script_name),
            bo=bytes(msg.bo),
            bdb=bytes(msg.bdb),
            bpos=bytes(msg.bpos),
            key_fingerprint=_text(msg.key_fingerprint),
            fieldkit_version=_text(msg.fieldkit_version),
            started_unix_ns=int(msg.started_unix_ns),
        )
    if topic == TOPIC_TICK:
        return TickRow(
            tick=int(msg.tick),
            clock_s=float(msg.clock_s),
            unix_ns=int(msg.unix_ns),
            lat=float(msg.lat),
            lon=float(msg.lon),
            alt=float(msg.alt),
            north=float(msg.north),
            east=float(msg.east),
            yaw=float(msg.yaw),
            voltage=float(msg.voltage),
            battery_percent=float(msg.battery_percent),
            status=_text(msg.status),
            armed=bool(msg.armed),
            rc_cmd=int(msg.rc_cmd),
            order_kind=_text(msg.order_kind),
            order_args=tuple(float(x) for x in msg.order_args),
            events=tuple(_text(x) for x in msg.events),
            state=_text(msg.state),
            digest=bytes(msg.digest),
            log=tuple(_text(x) for x in msg.log),
        )
    if topic in (TOPIC_RX, TOPIC_TX, TOPIC_GPS_RX):
        return SerialChunk(int(msg.tick), bytes(msg.data), stamp)
    if topic == TOPIC_STREAM:
        return StreamSend(int(msg.tick), float(msg.clock_s), stamp)
    if topic in (TOPIC_RADIO_IN, TOPIC_RADIO_OUT):
        return RadioFrame(
            int(msg.tick), int(msg.sender), bytes(msg.data), stamp,
            float(msg.east), float(msg.north),
        )  # fmt: skip
    if topic == TOPIC_OUTBOX:
        return OutboxPatch(int(msg.tick), bytes(msg.data), stamp)
    if topic in (TOPIC_MAVLINK_FROM, TOPIC_MAVLINK_TO):
        frame = mavlink_frame(msg)
        return MavlinkFrame(stamp, frame, _decode_frame(frame))
    if topic == TOPIC_FIX:
        return Fix(
            stamp,
            float(msg.latitude),
            float(msg.longitude),
            float(msg.altitude),
            int(msg.status.status) >= 0,
        )
    if topic == TOPIC_BATTERY:
        return Battery(stamp, float(msg.voltage), float(msg.percentage) * 100.0)
    raise ValueError(f"no row for {topic}")  # pragma: no cover - TOPIC_TYPES is exhaustive


__all__ = [
    "DEFAULT_MAX_BYTES",
    "MIN_MAX_BYTES",
    "REQUIRED_TOPICS",
    "TOPIC_BATTERY",
    "TOPIC_FIX",
    "TOPIC_GPS_RX",
    "TOPIC_MAVLINK_FROM",
    "TOPIC_MAVLINK_TO",
    "TOPIC_META",
    "TOPIC_OUTBOX",
    "TOPIC_RADIO_IN",
    "TOPIC_RADIO_OUT",
    "TOPIC_RX",
    "TOPIC_STREAM",
    "TOPIC_TICK",
    "TOPIC_TX",
    "TOPIC_TYPES",
    "BagError",
    "BagReader",
    "BagWriter",
    "Battery",
    "Fix",
    "MavlinkFrame",
    "Meta",
    "OutboxPatch",
    "RadioFrame",
    "Row",
    "SerialChunk",
    "StreamSend",
    "TickRow",
    "TopicInfo",
    "mavlink_fields",
    "mavlink_frame",
    "part_path",
    "part_paths",
]
