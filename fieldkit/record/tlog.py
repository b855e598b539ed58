"""A MAVLink telemetry log (`.tlog`) as a fieldkit bag: `fieldkit bag from-tlog`.

Mission Planner and MAVProxy log every MAVLink frame they see as a record: an 8-byte
big-endian timestamp (microseconds since the epoch), then the frame. Real logs are not clean:
radio noise leaves frames that fail their CRC (pymavlink's BAD_DATA: thousands in a long
flight), a frame's length byte can be hit so that it claims more or fewer bytes than it has,
and a log cut by a crash ends inside a record. So the records are found by their timestamps,
not by trusting each frame's length: a record starts where 8 bytes read as a time close to
the previous record's and a MAVLink start byte follows. Bytes that belong to no record are
skipped and counted.

The bag gets what the log knows: a meta without a script (robot id: the vehicle's system
id), each record's bytes on /autopilot/rx at its time (tick: 10 Hz ticks since the first
record), so that `fieldkit replay` can feed them to a node; the frames that decode on
/mavlink/from; /fix from the vehicle's GLOBAL_POSITION_INT (GPS_RAW_INT until one comes);
/battery from its SYS_STATUS and BATTERY_STATUS. Frames from every system in the log are
kept, the ground station's too: a node listens only to its autopilot's system.
"""

from __future__ import annotations

import hashlib
import json
import math
import mmap
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fieldkit.errors import FieldkitError
from fieldkit.record.bag import DEFAULT_MAX_BYTES, BagWriter, Meta
from fieldkit.vehicle.mavlink import FrameReader, new_codec

#: Record times outside these (1990..2100, microseconds) are not times: the bytes are garbage.
MIN_TIME_US = 631_152_000 * 10**6
MAX_TIME_US = 4_102_444_800 * 10**6
#: A record's time may step back this much (clock adjustments) or jump ahead this much (a
#: log paused and resumed) from the previous record's; outside, it is not a record boundary.
MAX_BACK_US = 60 * 10**6
MAX_GAP_US = 24 * 3600 * 10**6
#: The shortest frame: a MAVLink 1 frame with an empty payload.
MIN_FRAME = 8
#: The tick of a record: 10 Hz, as a node runs.
TICK_US = 100_000
#: Systems that are ground stations, not vehicles (MAV_TYPE_GCS) and invalid autopilots.
_GCS_TYPE = 6
_NO_AUTOPILOT = 8


class TlogError(FieldkitError):
    """A tlog that cannot be converted: the file, the problem, and a hint."""

    def __init__(self, file: str | Path, problem: str, hint: str) -> None:
        self.file = Path(file)
        self.problem = problem
        self.hint = hint
        super().__init__(f"{file}: {problem}\nhint: {hint}")


@dataclass
class TlogScan:
    """How the records of a log were found."""

    records: int = 0
    #: Bytes outside any record (before the first, between two, after the last), and the
    #: places where such bytes were skipped.
    garbage_bytes: int = 0
    garbage_runs: int = 0
    #: Records whose frame length did not lead to the next record (a damaged length byte).
    resynced: int = 0


def frame_length(data: bytes | mmap.mmap, j: int) -> int:
    """The length a MAVLink frame starting at `j` claims (0 if its header is cut short)."""
    if j + 3 > len(data):
        return 0
    n = data[j + 1]
    if data[j] == 0xFE:
        return n + 8
    return n + 12 + (13 if data[j + 2] & 1 else 0)


def _time(data: bytes | mmap.mmap, i: int) -> int:
    return int.from_bytes(data[i : i + 8], "big")


def _plausible(data: bytes | mmap.mmap, i: int, last: int | None) -> bool:
    """Whether a record can start at `i`: a time near `last`, then a MAVLink start byte."""
    if i + 8 + MIN_FRAME > len(data) or data[i + 8] not in (0xFE, 0xFD):
        return False
    t = _time(data, i)
    if last is None:
        return MIN_TIME_US <= t <= MAX_TIME_US
    return last - MAX_BACK_US <= t <= last + MAX_GAP_US


def _next_record(data: bytes | mmap.mmap, start: int, last: int | None, stop: int = -1) -> int:
    """The first position in [start, stop) where a record can start (`stop`, or len(data) if
    stop is -1, when there is none)."""
    n = len(data)
    stop = n if stop < 0 else min(stop, n)
    pos = start
    while pos < stop:
        # Candidates are 8 bytes before a start byte: find the nearest of either.
        end = stop + 8
        found = (data.find(b"\xfe", pos + 8, end), data.find(b"\xfd", pos + 8, end))
        hits = [h for h in found if h >= 0]
        if not hits:
            return stop
        i = min(hits) - 8
        if _plausible(data, i, last):
            return i
        pos = i + 1
    return stop


def tlog_records(
    data: bytes | mmap.mmap, scan: TlogScan | None = None
) -> Iterator[tuple[int, bytes]]:
    """(time in microseconds, frame bytes) of each record of a tlog's bytes, in order.

    A record's bytes run to the next record: a frame with a damaged length byte is yielded
    with the bytes it really has (and any noise up to the next record), which is what the
    link carried. `scan` (if given) counts what was found.
    """
    stats = scan if scan is not None else TlogScan()
    n = len(data)
    i = _next_record(data, 0, None)
    if i:
        stats.garbage_bytes += i
        stats.garbage_runs += 1
    while i < n:
        t = _time(data, i)
        j = i + 8
        end = j + frame_length(data, j)
        # A record ends where the next one starts. Its frame's length says where, unless a
        # hit length byte lies: a record found before that point ends it (no real payload
        # holds a big-endian time of the log followed by a start byte)...
        nxt = _next_record(data, j + 1, t, end)
        if nxt < min(end, n):
            stats.resynced += 1
        elif end < n and not _plausible(data, end, t):
            # ...and one that does not start right after it is further on (a length that
            # claims too little, or noise after the frame), or nowhere: garbage to the end.
            nxt = _next_record(data, end, t)
            if nxt < n:
                stats.resynced += 1
            else:
                stats.garbage_bytes += n - end
                stats.garbage_runs += 1
                stats.records += 1
                yield t, bytes(data[j:end])
                return
        else:
            nxt = min(end, n)  # the usual case (or the last record, cut short)
        stats.records += 1
        yield t, bytes(data[j:nxt])
        i = nxt


@dataclass
class TlogReport:
    """What a conversion wrote."""

    bag: Path
    parts: list[Path]
    scan: TlogScan
    robot_id: int
    #: Frames that decoded (all systems), and records that held none.
    messages: int = 0
    undecoded: int = 0
    fixes: int = 0
    batteries: int = 0
    duration_s: float = 0.0
    counts: dict[str, int] = field(default_factory=dict)


def _vehicle(data: bytes | mmap.mmap) -> int | None:
    """The system id of the log's vehicle: the first HEARTBEAT that is not a ground station."""
    reader = FrameReader(new_codec(None, 255, 0))
    for _, frame in tlog_records(data):
        for m in reader.feed(frame):
            if m.get_type() == "HEARTBEAT" and m.type != _GCS_TYPE:
                if m.autopilot != _NO_AUTOPILOT:
                    return int(m.get_srcSystem())
    return None


def tlog_to_bag(
    tlog: str | Path, bag: str | Path, *, max_bytes: int = DEFAULT_MAX_BYTES
) -> TlogReport:
    """Convert the log at `tlog` into a new bag at `bag` (ROS 1 if it ends in .bag).

    TlogError for a file that cannot be read or holds no MAVLink record; BagError for a bag
    path that cannot be written.
    """
    tlog = Path(tlog)
    try:
        with tlog.open("rb") as f:
            size = f.seek(0, 2)
            if size == 0:
                raise TlogError(tlog, "empty file", "give a MAVLink telemetry log (.tlog)")
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
                return _convert(tlog, data, Path(bag), max_bytes)
    except OSError as e:
        raise TlogError(tlog, f"cannot read: {e.strerror or e}", "check the path") from None


def _convert(tlog: Path, data: mmap.mmap, bag: Path, max_bytes: int) -> TlogReport:
    """The conversion proper, over the log's bytes."""
    first = next(iter(tlog_records(data)), None)
    if first is None:
        raise TlogError(
            tlog,
            "no MAVLink record found (each is an 8-byte time, then a frame)",
            "give a .tlog as Mission Planner or MAVProxy write them (a dataflash .bin is not one)",
        )
    t0 = first[0]
    vehicle = _vehicle(data)
    config = {
        "source": "tlog",
        "tlog": tlog.name,
        "tlog_sha256": hashlib.sha256(data).hexdigest(),
        "vehicle_system": vehicle,
    }
    meta = Meta(
        robot_id=vehicle if vehicle is not None else 0,
        config_json=json.dumps(config, sort_keys=True),
        started_unix_ns=t0 * 1000,
    )
    scan = TlogScan()
    report = TlogReport(bag, [], scan, meta.robot_id)
    counts: dict[str, int] = {}
    position_seen = False
    last_t = t0
    with BagWriter(bag, max_bytes=max_bytes, flush_s=None, fsync=False) as w:
        w.meta(meta)
        for t, frame in tlog_records(data, scan):
            ns = t * 1000
            tick = max(0, (t - t0) // TICK_US)
            messages = w.autopilot_rx(tick, frame, ns)
            last_t = max(last_t, t)
            if not messages:
                report.undecoded += 1
            for m in messages:
                name = m.get_type()
                counts[name] = counts.get(name, 0) + 1
                report.messages += 1
                if vehicle is not None and m.get_srcSystem() != vehicle:
                    continue
                if name == "GLOBAL_POSITION_INT":
                    position_seen = True
                    report.fixes += _position(w, m, ns)
                elif name == "GPS_RAW_INT" and not position_seen:
                    report.fixes += _gps_raw(w, m, ns)
                elif name in ("SYS_STATUS", "BATTERY_STATUS"):
                    report.batteries += _battery(w, m, ns)
        report.parts = list(w.parts)
    report.duration_s = (last_t - t0) / 1e6
    report.counts = dict(sorted(counts.items()))
    return report


def _position(w: BagWriter, m: Any, ns: int) -> int:
    """/fix from GLOBAL_POSITION_INT (0, 0 means no position yet)."""
    has = (m.lat, m.lon) != (0, 0)
    lat, lon = (m.lat * 1e-7, m.lon * 1e-7) if has else (math.nan, math.nan)
    w.fix(lat, lon, m.relative_alt * 1e-3, ns, has_fix=has)
    return 1


def _gps_raw(w: BagWriter, m: Any, ns: int) -> int:
    """/fix from GPS_RAW_INT (no altitude above home in it)."""
    has = m.fix_type >= 2 and (m.lat, m.lon) != (0, 0)
    lat, lon = (m.lat * 1e-7, m.lon * 1e-7) if has else (math.nan, math.nan)
    w.fix(lat, lon, math.nan, ns, has_fix=has)
    return 1


def _battery(w: BagWriter, m: Any, ns: int) -> int:
    """/battery from SYS_STATUS or BATTERY_STATUS (of battery 0)."""
    if m.get_type() == "SYS_STATUS":
        volts = m.voltage_battery * 1e-3 if m.voltage_battery != 0xFFFF else math.nan
    else:
        if m.id != 0:
            return 0
        cells = [v for v in m.voltages if v != 0xFFFF]
        volts = sum(cells) * 1e-3 if cells else math.nan
    percent = float(m.battery_remaining) if m.battery_remaining >= 0 else math.nan
    w.battery(volts, percent, ns)
    return 1


__all__ = [
    "TICK_US",
    "TlogError",
    "TlogReport",
    "TlogScan",
    "frame_length",
    "tlog_records",
    "tlog_to_bag",
]
