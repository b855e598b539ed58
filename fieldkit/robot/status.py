"""Status frames: each robot's state, battery, position and last operator command acted on,
passed robot to robot so that a ground station hears the whole swarm (docs/ground.md).

A ROSBuzz bundle carries its sender's position and Buzz messages, nothing a ground station
can read a robot's state, battery or command acknowledgements from; and it reaches only the
robots in range. A **status frame** (type 18, which ROSBuzz robots ignore as they ignore 16
and 17) carries up to five **records**, one per robot, and every robot passes on the records
it hears: its own first, then those that changed (an acknowledgement), then the others in
turn. A ground station beside one robot so learns every robot's record, hop by hop.

Nothing is sent until a ground station is around: a robot reports only while it holds a
fresh record of a ground station (flag GROUND), which the ground station's own frames bring
and the robots pass on. A swarm without a ground station sends exactly what it sent before.

Same container as bundles, update frames and command frames: a memory image of little-endian
fields in whole 8-byte words, each word big-endian on the air (air bytes 6-7: the type).

    word 0         u16 type = 18 | u8 format = 1 | u8 n records (1..5) | u16 sender | u16 0
    records        n x 40 bytes:
      0-1   u16 robot
      2-3   u16 heartbeat: advances at each record the robot issues (serial arithmetic)
      4     u8 battery percent, 255 unknown
      5     u8 flags: bits 0-2 flight status (0..4), bits 3-4 script (0 idle, 1 running,
            2 standby, 3 failed), bit 7 a ground station
      6-7   i16 altitude, decimetres above the takeoff ground
      8-15  u64 the last operator command sequence number acted on (48 bits)
      16-19 i32 latitude, 1e-7 degree
      20-23 i32 longitude, 1e-7 degree
      24-39 the script's BVMSTATE, latin-1, at most 16 bytes, zero padded
    tag            8 bytes, in `signed` swarms: the first 8 bytes of HMAC-SHA256 over the air
                   bytes under HKDF-SHA256(bundle key, info "fieldkit-status-v1")

So 48 to 208 bytes plain, 56 to 216 sealed: inside one XBee frame, never fragmented.
"""

from __future__ import annotations

import hashlib
import hmac
import math
import struct
from collections.abc import Iterable
from dataclasses import dataclass, replace

from fieldkit.errors import FieldkitError

#: payload64 type of a status frame (1 ROSBuzz's OTA, 2 a bundle, 16 update, 17 command).
STATUS_FRAME = 18
FORMAT = 1
RECORD_BYTES = 40
MAX_RECORDS = 5
TAG_BYTES = 8
#: Flags byte: the script's state (bits 3-4) and a ground station's record (bit 7).
SCRIPT_STATES = ("idle", "running", "standby", "failed")
GROUND_FLAG = 0x80
STATE_BYTES = 16
#: Ticks between two frames of a quiet robot (1 s at 10 Hz).
PERIOD_TICKS = 10
#: A record whose heartbeat has not advanced for this long is forgotten (60 s).
TTL_TICKS = 600
#: Robots a table keeps at most (the oldest news is evicted first).
MAX_ROBOTS = 1024

_HEAD = struct.Struct("<HBBHH")
_REC = struct.Struct("<HHBBhQii16s")
assert _REC.size == RECORD_BYTES


class StatusError(FieldkitError, ValueError):
    """Bytes that are not a status frame, naming what is wrong."""


@dataclass(frozen=True)
class StatusRecord:
    """One robot's status as a status frame carries it."""

    robot: int
    heartbeat: int
    battery: int | None  # percent
    flight_status: int  # 1 on ground, 2 in air, 3 taking off, 4 landing (0 unknown)
    script: str  # one of SCRIPT_STATES
    alt: float  # metres above the takeoff ground (decimetres on the air)
    acked: int  # the last operator command acted on
    lat: float
    lon: float
    state: str | None  # BVMSTATE
    ground: bool = False  # a ground station's own record


def status_key(bundle_secret: bytes) -> bytes:
    """The key that seals status frames, from the swarm's bundle key (`BundleKey.secret`):
    a key of its own, so a status tag is never a bundle's or an update frame's."""
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.kdf.hkdf import HKDF

    kdf = HKDF(algorithm=hashes.SHA256(), length=32, salt=None, info=b"fieldkit-status-v1")
    return kdf.derive(bundle_secret)


def _swap(data: bytes) -> bytes:
    """Every 8-byte word reversed: memory image <-> air bytes."""
    return b"".join(data[i : i + 8][::-1] for i in range(0, len(data), 8))


def is_status(data: bytes) -> bool:
    """Whether air bytes are a status frame (air bytes 6-7 hold the type, big-endian)."""
    return len(data) >= 8 and data[6] == 0 and data[7] == STATUS_FRAME


def _clamp_int(value: float, low: int, high: int) -> int:
    if not math.isfinite(value):
        return 0
    return max(low, min(high, round(value)))


def _pack_record(r: StatusRecord) -> bytes:
    flags = (r.flight_status & 7) | (SCRIPT_STATES.index(r.script) << 3)
    if r.ground:
        flags |= GROUND_FLAG
    state = (r.state or "").encode("latin-1", "replace")[:STATE_BYTES]
    return _REC.pack(
        r.robot,
        r.heartbeat & 0xFFFF,
        255 if r.battery is None else max(0, min(254, r.battery)),
        flags,
        _clamp_int(r.alt * 10, -32768, 32767),
        r.acked & ((1 << 48) - 1),
        _clamp_int(r.lat * 1e7, -900_000_000, 900_000_000),
        _clamp_int(r.lon * 1e7, -1_800_000_000, 1_800_000_000),
        state,
    )


def encode(sender: int, records: Iterable[StatusRecord], key: bytes | None = None) -> bytes:
    """A status frame's air bytes (sealed under `key` if given)."""
    body = [_pack_record(r) for r in records]
    if not 1 <= len(body) <= MAX_RECORDS:
        raise ValueError(f"a status frame carries 1..{MAX_RECORDS} records, not {len(body)}")
    air = _swap(_HEAD.pack(STATUS_FRAME, FORMAT, len(body), sender, 0) + b"".join(body))
    if key is not None:
        air += hmac.new(key, air, hashlib.sha256).digest()[:TAG_BYTES]
    return air


def decode(data: bytes, key: bytes | None = None) -> tuple[int, list[StatusRecord]]:
    """(sender, records) of a status frame; with `key`, only one sealed under it.
    StatusError names what is wrong (hostile bytes never raise anything else)."""
    if not isinstance(data, bytes | bytearray):
        raise StatusError(f"a status frame is bytes, not {type(data).__name__}")
    n = len(data)
    if n < 8 or n % 8 or not is_status(data):
        raise StatusError(f"{n} bytes: not a status frame (type {STATUS_FRAME}, whole words)")
    head = _swap(bytes(data[:8]))
    _type, fmt, count, sender, reserved = _HEAD.unpack(head)
    if fmt != FORMAT:
        raise StatusError(f"status frame format {fmt}, this station reads {FORMAT}")
    if not 1 <= count <= MAX_RECORDS or reserved:
        raise StatusError(
            f"status frame of {count} records (1..{MAX_RECORDS}), reserved {reserved}"
        )
    plain = 8 + RECORD_BYTES * count
    if key is None:
        if n != plain:
            what = "sealed (this station has no swarm key)" if n == plain + TAG_BYTES else "cut"
            raise StatusError(f"{n} bytes for {count} records, {plain} expected: {what}")
        air = bytes(data)
    else:
        if n != plain + TAG_BYTES:
            raise StatusError(f"{n} bytes for {count} sealed records, {plain + TAG_BYTES} expected")
        air, tag = bytes(data[:plain]), bytes(data[plain:])
        if not hmac.compare_digest(tag, hmac.new(key, air, hashlib.sha256).digest()[:TAG_BYTES]):
            raise StatusError("its tag does not check out: not sealed with this swarm's key")
    image = _swap(air)
    records = []
    for k in range(count):
        robot, beat, battery, flags, alt_dm, acked, lat, lon, state = _REC.unpack_from(
            image, 8 + RECORD_BYTES * k
        )
        if abs(lat) > 900_000_000 or abs(lon) > 1_800_000_000 or acked >> 48:
            raise StatusError(f"record {k} of robot {robot}: a position or number out of range")
        text = state.rstrip(b"\0").decode("latin-1")
        records.append(
            StatusRecord(
                robot=robot,
                heartbeat=beat,
                battery=None if battery == 255 else battery,
                flight_status=flags & 7,
                script=SCRIPT_STATES[(flags >> 3) & 3],
                alt=alt_dm / 10,
                acked=acked,
                lat=lat / 1e7,
                lon=lon / 1e7,
                state=text or None,
                ground=bool(flags & GROUND_FLAG),
            )
        )
    return sender, records


def newer(a: int, b: int) -> bool:
    """Whether heartbeat `a` is after `b` (u16 serial-number arithmetic)."""
    return a != b and (a - b) & 0xFFFF < 0x8000


@dataclass
class _Entry:
    record: StatusRecord
    changed: int  # tick its heartbeat last advanced
    urgent: bool  # news to pass on at once (an acknowledgement)
    sent: int  # tick it was last passed on


class StatusGossip:
    """One station's table of status records: what it hears, what it passes on (sans-I/O:
    fed frames and ticks, it returns frames). A robot's runtime holds one; so does a ground
    station (`ground=True`: it always reports, and its record wakes the robots up)."""

    def __init__(
        self,
        robot_id: int,
        key: bytes | None = None,
        *,
        ground: bool = False,
        period: int = PERIOD_TICKS,
        ttl: int = TTL_TICKS,
        max_robots: int = MAX_ROBOTS,
    ) -> None:
        """`key` seals what is sent and is required of what is heard (None: plain frames)."""
        self.id = robot_id
        self.key = key
        self.ground = ground
        self.period = period
        self.ttl = ttl
        self.max_robots = max_robots
        self.table: dict[int, _Entry] = {}
        # The last heartbeat of robots forgotten (expired or evicted): a neighbour that still
        # passes on such a stale record must not bring it back, or it would circle forever.
        self._gone: dict[int, int] = {}
        self.own: StatusRecord | None = None
        self._own_urgent = False
        self._last_frame = -(10**9)
        self._active = ground
        #: frames heard and sent, refused frames by reason.
        self.counters: dict[str, int] = {}

    def _count(self, name: str) -> None:
        self.counters[name] = self.counters.get(name, 0) + 1

    @property
    def active(self) -> bool:
        """Whether this station reports: a ground station always; a robot while it holds a
        ground station's record that advanced in the last `ttl` ticks."""
        return self._active

    def receive(self, data: bytes, now: int) -> list[StatusRecord]:
        """A status frame heard at tick `now`: the records that were news (empty if none, or
        if the frame is refused, counted under `refused`)."""
        try:
            _sender, records = decode(data, self.key)
        except StatusError:
            self._count("refused")
            return []
        self._count("heard")
        news = []
        for r in records:
            if r.robot == self.id:
                continue
            e = self.table.get(r.robot)
            if e is None:
                gone = self._gone.get(r.robot)
                if gone is not None and not newer(r.heartbeat, gone):
                    continue
                self._gone.pop(r.robot, None)
                if len(self.table) >= self.max_robots:
                    oldest = min(self.table, key=lambda rid: self.table[rid].changed)
                    self._forget(oldest)
                self.table[r.robot] = _Entry(r, now, True, -(10**9))
                news.append(r)
            elif newer(r.heartbeat, e.record.heartbeat):
                urgent = e.urgent or r.acked != e.record.acked or r.ground != e.record.ground
                self.table[r.robot] = _Entry(r, now, urgent, e.sent)
                news.append(r)
            if r.ground and not self._active:
                self._active = True
                self._own_urgent = True  # a ground station appeared: say who we are now
        return news

    def set_own(self, record: StatusRecord) -> None:
        """This station's own record now (its heartbeat is set when it is sent); a change
        of acknowledgement goes out at once."""
        if self.own is not None and record.acked != self.own.acked:
            self._own_urgent = True
        beat = 0 if self.own is None else self.own.heartbeat
        self.own = replace(record, robot=self.id, heartbeat=beat, ground=self.ground)

    def _forget(self, rid: int) -> None:
        e = self.table.pop(rid)
        if len(self._gone) >= self.max_robots:
            self._gone.pop(next(iter(self._gone)))
        self._gone[rid] = e.record.heartbeat

    def _expire(self, now: int) -> None:
        table = self.table
        for rid in [rid for rid, e in table.items() if now - e.changed > self.ttl]:
            self._forget(rid)
        if not self.ground:
            self._active = any(e.record.ground for e in table.values())

    def frame(self, now: int) -> bytes | None:
        """The frame to send at tick `now`, if any: once a period, and at once when there is
        news to pass on (at most one a tick)."""
        if now - self._last_frame >= self.period:
            self._expire(now)
        if not self._active or self.own is None:
            return None
        urgent = [e for e in self.table.values() if e.urgent]
        if not urgent and not self._own_urgent and now - self._last_frame < self.period:
            return None
        self.own = replace(self.own, heartbeat=(self.own.heartbeat + 1) & 0xFFFF)
        self._own_urgent = False
        self._last_frame = now
        picked = sorted(urgent, key=lambda e: e.changed)[: MAX_RECORDS - 1]
        if len(picked) < MAX_RECORDS - 1:
            rest = sorted((e for e in self.table.values() if not e.urgent), key=lambda e: e.sent)
            picked += rest[: MAX_RECORDS - 1 - len(picked)]
        for e in picked:
            e.urgent = False
            e.sent = now
        self._count("sent")
        return encode(self.id, [self.own, *(e.record for e in picked)], self.key)


__all__ = [
    "GROUND_FLAG",
    "MAX_RECORDS",
    "PERIOD_TICKS",
    "RECORD_BYTES",
    "SCRIPT_STATES",
    "STATUS_FRAME",
    "StatusError",
    "StatusGossip",
    "StatusRecord",
    "TTL_TICKS",
    "decode",
    "encode",
    "is_status",
    "newer",
    "status_key",
]
