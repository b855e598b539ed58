"""A real MAVLink tlog as a bag: the 23-minute ArduCopter flight of tests/data/tlogs (1,314
frames that fail their CRC, a last record cut short), converted and checked against what
pymavlink's own tlog reader makes of the file; and logs damaged on purpose (garbage between
records, lying length bytes, a cut end), which must convert without losing a good record."""

from __future__ import annotations

import json
import random
from collections import Counter
from pathlib import Path

import pytest
from pymavlink import mavutil

from fieldkit.record import bag as B
from fieldkit.record.bag import BagError, BagReader
from fieldkit.record.tlog import TlogError, TlogReport, tlog_records, tlog_to_bag

TLOGS = Path(__file__).resolve().parent / "data" / "tlogs"  # with their licences
FLIGHT = TLOGS / "quad-flight-arducopter.tlog"
#: The flight's field (CMAC, Canberra): every GPS fix of the log is inside this box.
FIELD_LAT = (-35.3640, -35.3600)
FIELD_LON = (149.1630, 149.1680)


def simple_records(data: bytes) -> list[tuple[int, bytes]]:
    """The records of a clean tlog, trusting every frame's length (an independent parse)."""
    out, i = [], 0
    while i + 10 < len(data):
        j = i + 8
        n = data[j + 1] + 8 if data[j] == 0xFE else data[j + 1] + 12 + 13 * (data[j + 2] & 1)
        out.append((int.from_bytes(data[i:j], "big"), data[j : j + n]))
        i = j + n
    return out


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> tuple[TlogReport, BagReader]:
    """The real flight converted (once for the module) and opened."""
    out = tmp_path_factory.mktemp("tlog") / "flight"
    report = tlog_to_bag(FLIGHT, out)
    return report, BagReader(out)


@pytest.fixture(scope="module")
def pymavlink_view() -> Counter[tuple[str, int]]:
    """(message type, system) counts of the flight as pymavlink's tlog reader sees it."""
    conn = mavutil.mavlink_connection(str(FLIGHT), dialect="all")
    counts: Counter[tuple[str, int]] = Counter()
    while (m := conn.recv_msg()) is not None:
        counts[(m.get_type(), m.get_srcSystem())] += 1
    return counts


def test_every_record_goes_to_autopilot_rx_at_its_time(
    flight: tuple[TlogReport, BagReader],
) -> None:
    report, r = flight
    records = simple_records(FLIGHT.read_bytes())
    assert len(records) == 76_792 == report.scan.records
    chunks = list(r.autopilot_rx())
    # Byte for byte, in order (the last record is cut short in the file: its bytes as they are).
    assert [c.data for c in chunks[:-1]] == [f for _, f in records[:-1]]
    assert records[-1][1].startswith(chunks[-1].data) and len(chunks[-1].data) < 40
    t0 = records[0][0]
    assert [c.tick for c in chunks] == [(t - t0) // 100_000 for t, _ in records]
    assert [c.unix_ns // 1000 for c in chunks] == [t for t, _ in records]
    assert r.duration_s == pytest.approx(report.duration_s, abs=0.01)
    assert report.duration_s == pytest.approx(1378.0, abs=1.0)
    assert report.scan.garbage_bytes == 0 and report.scan.resynced == 0


def test_meta_says_what_is_known(flight: tuple[TlogReport, BagReader]) -> None:
    report, r = flight
    assert r.meta.robot_id == 1 == report.robot_id  # the ArduCopter's system id
    assert r.meta.bo == b"" and r.meta.script_name == "" and r.meta.key_fingerprint == ""
    config = r.meta.config()
    assert config["source"] == "tlog" and config["tlog"] == FLIGHT.name
    assert len(config["tlog_sha256"]) == 64
    assert r.meta.started_unix_ns == simple_records(FLIGHT.read_bytes()[:200])[0][0] * 1000
    assert r.count(B.TOPIC_TICK) == 0 and r.count(B.TOPIC_TX) == 0  # no node outputs


def test_decoded_frames_match_pymavlink(
    flight: tuple[TlogReport, BagReader], pymavlink_view: Counter[tuple[str, int]]
) -> None:
    """/mavlink/from holds the frames that pass their CRC: what pymavlink reads, BAD_DATA
    aside (our parser resynchronises inside bad frames, so it may recover a few more)."""
    report, r = flight
    ours = Counter(report.counts)
    theirs: Counter[str] = Counter()
    for (name, _), n in pymavlink_view.items():
        theirs[name] += n
    assert theirs["BAD_DATA"] == 1314
    del theirs["BAD_DATA"]
    assert r.count(B.TOPIC_MAVLINK_FROM) == report.messages == sum(ours.values())
    assert sum(theirs.values()) - 10 <= report.messages <= sum(theirs.values()) + 10
    for name, n in theirs.items():
        assert abs(ours[name] - n) <= max(3, n // 500), name
    assert report.undecoded >= 1314 - 10
    # The decoded frames themselves: the first few, field by field.
    frames = list(r.mavlink_from())
    assert len(frames) == report.messages
    vehicle = next(
        f.message
        for f in frames
        if f.message.get_srcSystem() == 1 and f.message.get_type() == "HEARTBEAT"
    )
    assert vehicle.type == 2 and vehicle.autopilot == 3  # a quadrotor, ArduPilot
    assert frames[0].message.get_srcSystem() == 255  # the ground station's frames are kept


def test_fixes_are_the_flights_gps_in_its_field(
    flight: tuple[TlogReport, BagReader], pymavlink_view: Counter[tuple[str, int]]
) -> None:
    report, r = flight
    fixes = list(r.fixes())
    assert len(fixes) == report.fixes == r.count(B.TOPIC_FIX)
    assert abs(len(fixes) - pymavlink_view[("GLOBAL_POSITION_INT", 1)]) <= 3
    located = [f for f in fixes if f.has_fix]
    assert len(located) > 2500  # no position for the first minute (no 3D fix yet)
    assert all(FIELD_LAT[0] < f.lat < FIELD_LAT[1] for f in located)
    assert all(FIELD_LON[0] < f.lon < FIELD_LON[1] for f in located)
    # It flew: altitude above home reached more than 10 m.
    assert max(f.alt for f in located) > 10.0
    batteries = list(r.batteries())
    assert abs(len(batteries) - pymavlink_view[("SYS_STATUS", 1)]) <= 3
    # A 3S LiPo drained by the flight: 12.3 V and 99 % at the start, 10.6 V and 20 % at the end.
    assert batteries[0].voltage == pytest.approx(12.277, abs=1e-3)
    assert batteries[-1].voltage == pytest.approx(10.617, abs=1e-3)
    assert (round(batteries[0].percent), round(batteries[-1].percent)) == (99, 20)


# ------------------------------------------------------------------------------ damaged logs


def _damage(records: list[tuple[int, bytes]], seed: int) -> tuple[bytes, list[int]]:
    """The log of `records` with garbage between records, some frames' length byte changed
    and the end cut; returns the bytes and the indexes of the records left intact."""
    rng = random.Random(seed)
    out = bytearray(rng.randbytes(37))  # junk before the first record
    intact = []
    last = 0
    for i, (t, frame) in enumerate(records):
        last = len(out)
        out += t.to_bytes(8, "big")
        if rng.random() < 0.03:
            f = bytearray(frame)
            f[1] = rng.randrange(256)  # a lying length
            out += f
        else:
            out += frame
            intact.append(i)
        if rng.random() < 0.03:
            out += rng.randbytes(rng.randint(1, 300))  # noise between records
    cut = rng.randrange(last + 1, len(out))  # the log ends inside its last record
    if intact and intact[-1] == len(records) - 1:
        intact.pop()
    return bytes(out[:cut]), intact


@pytest.mark.parametrize("seed", range(3))
def test_a_damaged_log_loses_no_good_record(tmp_path: Path, seed: int) -> None:
    records = simple_records(FLIGHT.read_bytes())[20_000:23_000]
    data, intact = _damage(records, seed)
    (tmp_path / "d.tlog").write_bytes(data)
    found = list(tlog_records(data))
    at = 0  # every intact record is found, in order, with its frame whole
    for i in intact:
        t, frame = records[i]
        while at < len(found) and not (found[at][0] == t and found[at][1].startswith(frame)):
            at += 1
        assert at < len(found), f"record {i} lost"
    report = tlog_to_bag(tmp_path / "d.tlog", tmp_path / "d.bag")
    assert report.scan.garbage_bytes >= 37 and report.scan.resynced > 0
    r = BagReader(tmp_path / "d.bag")
    assert r.count(B.TOPIC_RX) == report.scan.records >= len(intact)
    assert report.messages >= len(intact) * 0.97  # noise can hide a neighbour, rarely


def test_what_is_not_a_tlog_is_refused(tmp_path: Path) -> None:
    empty = tmp_path / "empty.tlog"
    empty.write_bytes(b"")
    with pytest.raises(TlogError, match="empty"):
        tlog_to_bag(empty, tmp_path / "a")
    junk = tmp_path / "junk.tlog"
    junk.write_bytes(random.Random(0).randbytes(50_000))
    with pytest.raises(TlogError) as e:
        tlog_to_bag(junk, tmp_path / "b")
    assert "no MAVLink record" in e.value.problem and e.value.file == junk
    with pytest.raises(TlogError, match="cannot read"):
        tlog_to_bag(tmp_path / "missing.tlog", tmp_path / "c")
    small = tmp_path / "small.tlog"
    small.write_bytes(FLIGHT.read_bytes()[:5000])
    (tmp_path / "exists").mkdir()
    with pytest.raises(BagError, match="exists already"):
        tlog_to_bag(small, tmp_path / "exists")
    report = tlog_to_bag(small, tmp_path / "ros1.bag")  # ROS 1 works the same
    assert report.parts == [tmp_path / "ros1.bag"]
    assert json.loads(BagReader(tmp_path / "ros1.bag").meta.config_json)["source"] == "tlog"


def test_a_long_log_rotates_into_parts_read_as_one(tmp_path: Path) -> None:
    prefix = tmp_path / "p.tlog"
    prefix.write_bytes(FLIGHT.read_bytes()[:400_000])
    report = tlog_to_bag(prefix, tmp_path / "b", max_bytes=B.MIN_MAX_BYTES)
    assert len(report.parts) >= 5
    r = BagReader(tmp_path / "b")
    assert r.parts == report.parts and r.repairs == []
    chunks = list(r.autopilot_rx())
    assert len(chunks) == report.scan.records
    assert b"".join(c.data for c in chunks) == b"".join(
        f for _, f in tlog_records(prefix.read_bytes())
    )
    assert r.count(B.TOPIC_META) == len(report.parts)
