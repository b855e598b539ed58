"""The recording format: bags written by `BagWriter` read back by `BagReader` and by rosbags'
own reader (as ROS tools would), cut short anywhere, rotated, and refused when they are not
fieldkit bags. Real files throughout (tests/bagdata.py makes the recordings)."""

from __future__ import annotations

import json
import random
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from bagdata import ROBOT, T0_NS, TICK_S, Sample, check_prefix, expected, record
from pymavlink.dialects.v20 import all as mavlink2
from rosbags import rosbag1, rosbag2
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from fieldkit.record import bag as B
from fieldkit.record.bag import BagError, BagReader, BagWriter, Meta
from fieldkit.record.types import MAVLINK, TICK, msg_definitions, typestore

STORAGES = ["rec", "rec.bag"]  # a ROS 2 bag (MCAP) and a ROS 1 bag


def fake_clock() -> tuple[list[float], Callable[[], float]]:
    """A clock the test moves: [now] and the function reading it."""
    now = [0.0]
    return now, lambda: now[0]


def write_sample(path: Path, ticks: int, seed: str = "t", **kw: object) -> Sample:
    """The sample's ticks 0..ticks-1 recorded at `path`, closed."""
    sample = Sample(seed)
    with BagWriter(path, fsync=False, **kw) as w:  # type: ignore[arg-type]
        record(w, sample, ticks)
    return sample


# ------------------------------------------------------------------------------ round trips


@pytest.mark.parametrize("name", STORAGES)
def test_outbox_patches_round_trip_in_their_ticks(tmp_path: Path, name: str) -> None:
    """/update/outbox: an originator's patches, each with its tick, read back as written and
    by rosbags' own reader as fieldkit_msgs/msg/OutboxPatch."""
    path = tmp_path / name
    sample = Sample("o")
    patches = {3: random.Random(1).randbytes(700), 7: b"FKUP" + bytes(range(256))}
    with BagWriter(path, fsync=False) as w:
        w.meta(sample.meta)
        for k in range(10):
            if k in patches:
                w.outbox(k, patches[k], T0_NS + k)
            sample.write_tick(w, k)
    r = BagReader(path)
    assert [(p.tick, p.data) for p in r.outbox()] == sorted(patches.items())
    assert r.count(B.TOPIC_OUTBOX) == 2
    with AnyReader([path]) as any_reader:  # the definition the bag embeds
        conns = [c for c in any_reader.connections if c.topic == B.TOPIC_OUTBOX]
        assert [c.msgtype for c in conns] == ["fieldkit_msgs/msg/OutboxPatch"]
        got = [any_reader.deserialize(raw, c.msgtype) for c, _, raw in any_reader.messages(conns)]
    assert [(m.tick, bytes(m.data)) for m in got] == sorted(patches.items())


@pytest.mark.parametrize("name", STORAGES)
def test_every_topic_round_trips(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    sample = write_sample(path, 30)
    r = BagReader(path)
    assert check_prefix(r, sample) == 29
    assert r.storage == ("ros1" if name.endswith(".bag") else "mcap")
    assert r.parts == [path] and r.repairs == []
    counts = {t.name: t.count for t in r.topics()}
    want = expected(sample, 30)
    assert counts == {
        B.TOPIC_META: 1,
        B.TOPIC_RX: len(want["rx"]),
        B.TOPIC_TX: 30,
        B.TOPIC_RADIO_IN: 60,
        B.TOPIC_RADIO_OUT: 30,
        B.TOPIC_TICK: 30,
        B.TOPIC_FIX: 30,
        B.TOPIC_BATTERY: 30,
        # Every whole frame of the autopilot's reads, however they were split and noised.
        B.TOPIC_MAVLINK_FROM: sum(len(sample.frames(k)) for k in range(30)),
        B.TOPIC_MAVLINK_TO: 30,
        B.TOPIC_GPS_RX: 0,  # a MAVLink flight's: declared, empty
        B.TOPIC_STREAM: 0,
        B.TOPIC_OUTBOX: 0,  # an originator's alone
    }
    assert {t.name: t.type for t in r.topics()} == B.TOPIC_TYPES
    assert r.duration_s == pytest.approx(29 * TICK_S, abs=1e-3)
    assert r.start_ns == T0_NS
    # /mavlink/from: the frames themselves, decoded by pymavlink.
    frames = [f for k in range(30) for f in sample.frames(k)]
    got = list(r.mavlink_from())
    assert [f.frame for f in got] == frames
    assert [f.message.get_type() for f in got[:3]] == [
        "GLOBAL_POSITION_INT",
        "SYS_STATUS",
        "HEARTBEAT",
    ]
    assert got[0].message.lat == -353_623_344
    to = list(r.mavlink_to())
    assert to[0].message.get_type() == "HEARTBEAT" and to[0].message.get_srcSystem() == 255
    # /fix and /battery: each tick's sensors.
    rows = list(r.ticks())
    fixes, batteries = list(r.fixes()), list(r.batteries())
    assert [(f.lat, f.lon, f.alt) for f in fixes] == [(t.lat, t.lon, t.alt) for t in rows]
    assert all(f.has_fix for f in fixes)
    assert [b.voltage for b in batteries] == pytest.approx([t.voltage for t in rows], rel=1e-6)
    assert [b.percent for b in batteries] == pytest.approx(
        [t.battery_percent for t in rows], rel=1e-6
    )


@pytest.mark.parametrize("name", STORAGES)
def test_rows_come_in_recorded_order_across_topics(tmp_path: Path, name: str) -> None:
    """What replay merges: rx chunks, radio frames and tick rows in the order they were
    written, even when the wall clock steps back (stamps are kept increasing)."""
    path = tmp_path / name
    sample = Sample("order")
    with BagWriter(path, fsync=False) as w:
        w.meta(sample.meta)
        w.autopilot_rx(0, b"a", T0_NS + 500)
        w.radio_in(0, 2, b"b", T0_NS + 100)  # the clock stepped back
        w.autopilot_rx(0, b"c", T0_NS + 100)
        w.tick(sample.tick_data(0).row)
    r = BagReader(path)
    order = [
        (t, getattr(row, "data", None))
        for t, row in r.rows(B.TOPIC_RX, B.TOPIC_RADIO_IN, B.TOPIC_TICK)
    ]
    assert order == [
        (B.TOPIC_RX, b"a"),
        (B.TOPIC_RADIO_IN, b"b"),
        (B.TOPIC_RX, b"c"),
        (B.TOPIC_TICK, None),
    ]
    stamps = [row.unix_ns for _, row in r.rows(B.TOPIC_RX, B.TOPIC_RADIO_IN)]
    assert stamps == sorted(stamps) and len(set(stamps)) == 3


def test_mavlink_fields_round_trip_every_frame_shape() -> None:
    """v1, v2, v2 with a trailing-zero-truncated payload, v2 signed: fields and back."""
    v2 = mavlink2.MAVLink(None, srcSystem=7, srcComponent=1)
    v1 = mavlink2.MAVLink(None, srcSystem=7, srcComponent=1)
    v1.WIRE_PROTOCOL_VERSION = "1.0"
    signed = mavlink2.MAVLink(None, srcSystem=7, srcComponent=1)
    signed.signing.secret_key = bytes(range(32))
    signed.signing.sign_outgoing = True
    signed.signing.timestamp = 1
    frames = [
        bytes(v2.heartbeat_encode(2, 3, 0, 0, 4).pack(v2)),
        bytes(v2.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0).pack(v2)),
        bytes(signed.heartbeat_encode(2, 3, 0, 0, 4).pack(signed)),
        bytes(mavlink2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3).pack(v1, force_mavlink1=True)),
    ]
    assert frames[3][0] == 0xFE and frames[2][2] & 1 and len(frames[2]) == frames[2][1] + 25
    Mav = typestore(False).types[MAVLINK]
    header = typestore(False).types["std_msgs/msg/Header"]
    stamp = typestore(False).types["builtin_interfaces/msg/Time"](0, 0)
    for frame in frames:
        fields = B.mavlink_fields(frame)
        assert fields["len"] == frame[1] and len(fields["payload64"]) == (frame[1] + 7) // 8
        assert fields["sysid"] == 7 and fields["framing_status"] == Mav.FRAMING_OK
        msg = Mav(header=header(stamp, ""), **fields)
        assert B.mavlink_frame(msg) == frame
        # ...and the ROS message survives its own serialization.
        raw = typestore(False).serialize_cdr(msg, MAVLINK)
        back = typestore(False).deserialize_cdr(raw, MAVLINK)
        assert B.mavlink_frame(back) == frame


def test_the_mavros_type_is_mavros_own() -> None:
    """ROS 1 tools match types by md5: ours must be mavros 1.x/2.x's (and the standard
    sensor types ROS's), or a mavros or ROSBuzz node would not take our topics."""
    ts1 = typestore(True)
    assert ts1.generate_msgdef(MAVLINK)[1] == "41093e1fd0f3eea1da2aa33a177e5ba6"
    assert ts1.generate_msgdef("sensor_msgs/msg/NavSatFix")[1] == (
        "2d3a8cd499b9b4a0249fb98fd05cfa48"
    )
    Mav = ts1.types[MAVLINK]
    assert (Mav.FRAMING_OK, Mav.FRAMING_BAD_CRC, Mav.FRAMING_BAD_SIGNATURE) == (1, 2, 3)
    assert (Mav.MAVLINK_V10, Mav.MAVLINK_V20) == (254, 253)
    assert set(msg_definitions()) == {
        MAVLINK,
        "fieldkit_msgs/msg/Meta",
        "fieldkit_msgs/msg/SerialChunk",
        "fieldkit_msgs/msg/RadioFrame",
        "fieldkit_msgs/msg/StreamSend",
        "fieldkit_msgs/msg/OutboxPatch",
        TICK,
    }


@pytest.mark.parametrize("name", STORAGES)
def test_ros_tools_read_our_bags_without_our_types(tmp_path: Path, name: str) -> None:
    """rosbags' AnyReader, given no typestore, reads every topic from the definitions the
    bag embeds: what Foxglove and the ROS tools do."""
    path = tmp_path / name
    sample = write_sample(path, 12)
    seen: dict[str, int] = {}
    with AnyReader([path]) as reader:
        assert "fieldkit_msgs/msg/Tick" in reader.typestore.types
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            seen[conn.topic] = seen.get(conn.topic, 0) + 1
            if conn.topic == B.TOPIC_FIX and seen[conn.topic] == 1:
                assert msg.latitude == sample.tick_data(0).row.lat  # type: ignore[attr-defined]
            if conn.topic == B.TOPIC_META:
                assert msg.robot_id == ROBOT  # type: ignore[attr-defined]
                assert bytes(msg.bo) == sample.meta.bo  # type: ignore[attr-defined]
            if conn.topic == B.TOPIC_MAVLINK_FROM and seen[conn.topic] == 1:
                assert msg.msgid == 33 and msg.sysid == 1  # type: ignore[attr-defined]
    empty = {B.TOPIC_GPS_RX, B.TOPIC_STREAM, B.TOPIC_OUTBOX}  # none here
    assert seen[B.TOPIC_TICK] == 12 and set(seen) == set(B.TOPIC_TYPES) - empty


@pytest.mark.parametrize("name", STORAGES)
def test_a_gps_of_its_own_and_stream_sends_round_trip(tmp_path: Path, name: str) -> None:
    """/gps/rx (a Husky's receiver) and /autopilot/stream (an M100's thread's sends) read
    back through BagReader, and through rosbags' AnyReader from the embedded definitions."""
    path = tmp_path / name
    sample = Sample("gps")
    with BagWriter(path, fsync=False) as w:
        w.meta(sample.meta)
        w.gps_rx(0xFFFFFFFF, b"$GPGGA,start-up*00\r\n", T0_NS)
        for k in range(5):
            w.stream_send(k, 10.0 + k * 0.1 - 0.02, T0_NS + k)
            w.stream_send(k, 10.0 + k * 0.1 - 0.01, T0_NS + k)
            w.autopilot_rx(k, bytes([k]) * 3, T0_NS + k)
            w.gps_rx(k, f"$GPRMC,{k}*00\r\n".encode(), T0_NS + k)
            w.tick(sample.tick_data(k).row)
    r = BagReader(path)
    gps = [(c.tick, c.data) for c in r.gps_rx()]
    assert gps[0] == (0xFFFFFFFF, b"$GPGGA,start-up*00\r\n")
    assert gps[1:] == [(k, f"$GPRMC,{k}*00\r\n".encode()) for k in range(5)]
    sends = [(s.tick, s.clock_s) for s in r.stream_sends()]
    assert sends == [(k, 10.0 + k * 0.1 - d) for k in range(5) for d in (0.02, 0.01)]
    with AnyReader([path]) as reader:
        counts: dict[str, int] = {}
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            if conn.topic == B.TOPIC_STREAM and counts[conn.topic] == 1:
                assert msg.tick == 0 and msg.clock_s == pytest.approx(9.98)  # type: ignore[attr-defined]
    assert counts[B.TOPIC_GPS_RX] == 6 and counts[B.TOPIC_STREAM] == 10


# ------------------------------------------------------------------------------ rotation


@pytest.mark.parametrize("name", STORAGES)
def test_rotation_makes_complete_parts_read_as_one(tmp_path: Path, name: str) -> None:
    path = tmp_path / name
    now, clock = fake_clock()
    sample = Sample("rot")
    with BagWriter(path, max_bytes=B.MIN_MAX_BYTES, fsync=False, clock=clock) as w:
        w.meta(sample.meta)
        for k in range(300):
            sample.write_tick(w, k)
            now[0] = (k + 1) * TICK_S
    assert len(w.parts) >= 4
    assert w.parts == [B.part_path(path, i) for i in range(len(w.parts))]
    r = BagReader(path)
    assert r.parts == w.parts and r.repairs == []
    assert check_prefix(r, sample) == 299
    assert r.count(B.TOPIC_META) == len(w.parts)  # the meta heads every part
    ticks_seen = len(list(BagReader(path).ticks())) - sum(
        len(list(BagReader(part).ticks())) for part in w.parts[1:]
    )
    for part in w.parts:
        size = sum(f.stat().st_size for f in ([part] if part.is_file() else part.iterdir()))
        assert size < 2 * B.MIN_MAX_BYTES
        # Each part is a whole bag of its own for rosbags, the meta first.
        with AnyReader([part]) as reader:
            conn, _, raw = next(reader.messages())
            assert conn.topic == B.TOPIC_META
            assert reader.deserialize(raw, conn.msgtype).robot_id == ROBOT  # type: ignore[attr-defined]
        if part == path:
            continue  # the first part's path names the whole recording
        alone = BagReader(part)  # a later part, read on its own: the meta, then its ticks
        assert alone.parts == [part] and alone.meta == sample.meta
        assert next(alone.rows())[0] == B.TOPIC_META
        ticks = [t.tick for t in alone.ticks()]
        assert ticks == list(range(ticks_seen, ticks_seen + len(ticks)))
        ticks_seen += len(ticks)
    assert ticks_seen == 300


def test_a_part_of_another_recording_is_refused(tmp_path: Path) -> None:
    write_sample(tmp_path / "a", 3, seed="one")
    other = tmp_path / "b"
    sample = Sample("two")
    with BagWriter(other, fsync=False) as w:
        w.meta(Meta(robot_id=9, started_unix_ns=5))
        sample.write_tick(w, 0)
    shutil.move(other, tmp_path / "a_1")
    with pytest.raises(BagError) as e:
        BagReader(tmp_path / "a")
    assert e.value.file == tmp_path / "a_1" and "another recording" in e.value.problem


# ------------------------------------------------------------------------------ cut short


def _record_open(path: Path, ticks: int) -> tuple[Path, list[int], Sample, BagWriter, int]:
    """Record `ticks` ticks (flushing every second: 10 ticks) without closing: the file on
    disk is what a kill -9 would leave. Returns the file, its size after each tick, the
    sample, the writer, and its size after the meta."""
    now, clock = fake_clock()
    sample = Sample("cut")
    w = BagWriter(path, fsync=False, clock=clock)
    w.meta(sample.meta)
    file = path if path.suffix == ".bag" else path / f"{path.name}.mcap"
    sizes = [file.stat().st_size]  # the meta, flushed at once
    for k in range(ticks):
        sample.write_tick(w, k)
        now[0] = (k + 1) * TICK_S
        sizes.append(file.stat().st_size)
    return file, sizes[1:], sample, w, sizes[0]


@pytest.mark.parametrize("name", STORAGES)
def test_a_bag_cut_anywhere_reads_up_to_its_last_whole_chunk(tmp_path: Path, name: str) -> None:
    """The file of a recording that was never closed, cut at 60 random places (and at its
    end): each reads back exactly ticks 0..K, where K is the last tick flushed before the
    cut, give or take the flush the cut fell into; before the first flush, a BagError."""
    file, sizes, sample, w, meta_end = _record_open(tmp_path / name, 95)
    data = file.read_bytes()
    assert len(data) == sizes[-1] and meta_end > 0
    # The ticks whose end flushed (the size grew), and the file's size after.
    flushes = [(k, s) for k, s in enumerate(sizes) if s > (sizes[k - 1] if k else meta_end)]
    # Once a second: at the first tick's end 1 s (10 ticks) after the last flush.
    assert [k for k, _ in flushes] == list(range(10, 95, 10))
    rng = random.Random(7)
    cuts = sorted({len(data), *(rng.randrange(len(data)) for _ in range(60))})
    for cut in cuts:
        target = tmp_path / f"cut{cut}" / name
        target.parent.mkdir()
        if name.endswith(".bag"):
            target.write_bytes(data[:cut])
        else:
            target.mkdir()
            (target / file.name).write_bytes(data[:cut])
        flushed = [k for k, s in flushes if s <= cut]
        started = [k for k, s in [(-1, meta_end), *flushes] if s < cut]
        try:
            r = BagReader(target)
        except BagError as e:
            assert cut < meta_end, f"cut at {cut}: {e}"
            continue
        last = check_prefix(r, sample)
        assert (flushed[-1] if flushed else -1) <= last, f"cut at {cut}"
        following = [k for k, _ in flushes if k > (started[-1] if started else -1)]
        assert last <= (following[0] if following else 94), f"cut at {cut}"
        assert r.repairs and "not closed" in r.repairs[0]
    w.close()
    assert check_prefix(BagReader(tmp_path / name), sample) == 94


@pytest.mark.parametrize("name", STORAGES)
def test_garbage_after_the_cut_is_not_read(tmp_path: Path, name: str) -> None:
    """A power cut can leave zeros or junk after the last write: the scan stops there."""
    file, _, sample, w, _ = _record_open(tmp_path / name, 40)
    data = file.read_bytes()
    for tail, label in ((bytes(5000), "zeros"), (random.Random(1).randbytes(5000), "junk")):
        target = tmp_path / label / name
        target.parent.mkdir()
        if name.endswith(".bag"):
            target.write_bytes(data + tail)
        else:
            target.mkdir()
            (target / file.name).write_bytes(data + tail)
        r = BagReader(target)
        assert check_prefix(r, sample) == 30, label  # the last flush: after tick 30
        assert "then" in r.repairs[0], r.repairs
    w.close()


# ------------------------------------------------------------------------------ refusals


def _bag_error(path: Path) -> BagError:
    with pytest.raises(BagError) as e:
        BagReader(path)
    return e.value


def _write_raw(path: Path, topics: dict[str, str], ts: object, ros1: bool, msgs: dict) -> None:
    """A bag written with rosbags directly: `topics` {name: type}, `msgs` {name: message}."""
    store = ts
    path.parent.mkdir(parents=True, exist_ok=True)
    if ros1:
        w1 = rosbag1.Writer(path)
        w1.open()
        for topic, msgtype in topics.items():
            conn = w1.add_connection(topic, msgtype, typestore=store)  # type: ignore[arg-type]
            if topic in msgs:
                raw = store.serialize_ros1(msgs[topic], msgtype)  # type: ignore[attr-defined]
                w1.write(conn, T0_NS, raw)
        w1.close()
        return
    w2 = rosbag2.Writer(path, version=9, storage_plugin=rosbag2.StoragePlugin.MCAP)
    w2.open()
    for topic, msgtype in topics.items():
        conn = w2.add_connection(topic, msgtype, typestore=store)  # type: ignore[arg-type]
        if topic in msgs:
            w2.write(conn, T0_NS, store.serialize_cdr(msgs[topic], msgtype))  # type: ignore[attr-defined]
    w2.close()


def _meta_msg(ros1: bool) -> object:
    u8 = np.zeros(0, dtype=np.uint8)
    return typestore(ros1).types["fieldkit_msgs/msg/Meta"](
        1, 0, "", "{}", "", u8, u8, u8, "", "0", T0_NS
    )


@pytest.mark.parametrize("ros1", [False, True], ids=["mcap", "ros1"])
def test_foreign_bags_are_refused_with_what_and_where(tmp_path: Path, ros1: bool) -> None:
    name = "x.bag" if ros1 else "x"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    # Another tool's bag: no fieldkit topic at all.
    text = store.types["std_msgs/msg/String"]("hello")
    _write_raw(tmp_path / "a" / name, {"/chatter": "std_msgs/msg/String"}, store, ros1, {})
    e = _bag_error(tmp_path / "a" / name)
    assert "no /fieldkit/meta" in e.problem and e.file == tmp_path / "a" / name
    # Our topic names with other types.
    _write_raw(
        tmp_path / "b" / name,
        {B.TOPIC_META: "std_msgs/msg/String"},
        store,
        ros1,
        {B.TOPIC_META: text},
    )
    e = _bag_error(tmp_path / "b" / name)
    assert "has type std_msgs/msg/String" in e.problem and "fieldkit" in e.hint
    # Our type names, defined otherwise (an older or another Tick).
    other = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types = {}
    for t, text in msg_definitions().items():
        types.update(get_types_from_msg(text.replace("float64 clock_s", "float32 clock_s"), t))
    other.register(types)
    _write_raw(tmp_path / "c" / name, {B.TOPIC_TICK: TICK}, other, ros1, {})
    e = _bag_error(tmp_path / "c" / name)
    assert "defined differently" in e.problem and TICK in e.problem
    # A fieldkit meta, but no /autopilot/rx: nothing a replay could feed.
    ours = typestore(ros1)
    _write_raw(
        tmp_path / "d" / name,
        {B.TOPIC_META: "fieldkit_msgs/msg/Meta"},
        ours,
        ros1,
        {B.TOPIC_META: _meta_msg(ros1)},
    )
    e = _bag_error(tmp_path / "d" / name)
    assert "lacks /autopilot/rx" in e.problem and "--record" in e.hint


@pytest.mark.parametrize("name", STORAGES)
def test_empty_missing_and_garbage_bags_are_refused(tmp_path: Path, name: str) -> None:
    ros1 = name.endswith(".bag")
    assert "no such bag" in _bag_error(tmp_path / name).problem
    garbage = random.Random(3).randbytes(20_000)
    for label, content in (("empty", b""), ("garbage", garbage)):
        target = tmp_path / label / name
        if ros1:
            target.parent.mkdir()
            target.write_bytes(content)
        else:
            target.mkdir(parents=True)
            (target / f"{name}.mcap").write_bytes(content)
        e = _bag_error(target)
        assert "unreadable" in e.problem and ("empty" in e.problem) == (label == "empty")
    if not ros1:
        (tmp_path / "nothing" / name).mkdir(parents=True)
        assert "no metadata.yaml" in _bag_error(tmp_path / "nothing" / name).problem
        (tmp_path / "t.tlog").write_bytes(b"x")
        assert "from-tlog" in _bag_error(tmp_path / "t.tlog").hint
    # A good magic, then garbage.
    head = (b"#ROSBAG V2.0\n" if ros1 else b"\x89MCAP0\r\n") + garbage
    target = tmp_path / "magic" / name
    if ros1:
        target.parent.mkdir()
        target.write_bytes(head)
    else:
        target.mkdir(parents=True)
        (target / f"{name}.mcap").write_bytes(head)
    assert _bag_error(target).file.name.startswith(name)


def test_a_changed_byte_in_an_mcap_chunk_is_an_error_not_a_wrong_value(tmp_path: Path) -> None:
    """Our chunks carry a CRC (rosbags leaves it 0): a flipped bit is found, not replayed."""
    sample = write_sample(tmp_path / "ok", 20)
    data = bytearray((tmp_path / "ok" / "ok.mcap").read_bytes())
    needle = sample.tick_data(15).radio_out
    data[data.index(needle)] ^= 0x01
    shutil.copytree(tmp_path / "ok", tmp_path / "bad")
    (tmp_path / "bad" / "ok.mcap").write_bytes(bytes(data))
    r = BagReader(tmp_path / "bad")  # the damage is in a later chunk than the meta
    with pytest.raises(BagError) as e:
        list(r.radio_out())
    assert "checksum" in e.value.problem and e.value.file == tmp_path / "bad"


# ------------------------------------------------------------------------------ the writer


def test_the_writer_refuses_secrets_and_bad_uses(tmp_path: Path) -> None:
    with pytest.raises(BagError) as e:
        BagWriter(tmp_path / "small", max_bytes=1000)
    assert "too small" in e.value.problem
    w = BagWriter(tmp_path / "w", fsync=False)
    with pytest.raises(BagError, match="before the meta"):
        w.radio_in(0, 1, b"x", T0_NS)
    swarm_key = "ab" * 32
    for meta in (
        Meta(robot_id=1, key_fingerprint=swarm_key),
        Meta(robot_id=1, config_json=json.dumps({"k": f"fieldkit-swarm-key-v1 {swarm_key}"})),
        Meta(robot_id=1, profile_toml="-----BEGIN PRIVATE KEY-----"),
    ):
        with pytest.raises(BagError) as e:
            w.meta(meta)
        assert "fingerprint" in e.value.hint or "secret" in e.value.problem
    w.meta(Meta(robot_id=1, key_fingerprint="0123456789abcdef"))
    with pytest.raises(BagError, match="twice"):
        w.meta(Meta(robot_id=1))
    with pytest.raises(BagError, match="out of its field's range"):
        w.radio_in(0, 70_000, b"x", T0_NS)  # a sender id beyond uint16
    w.close()
    w.close()  # a second close does nothing
    with pytest.raises(BagError, match="after close"):
        w.radio_in(0, 1, b"x", T0_NS)
    # Never over an existing recording, nor beside an older one's parts.
    with pytest.raises(BagError) as e:
        BagWriter(tmp_path / "w")
    assert "exists already" in e.value.problem
    (tmp_path / "z_1").mkdir()
    with pytest.raises(BagError) as e:
        BagWriter(tmp_path / "z")
    assert e.value.file == tmp_path / "z_1"
    (tmp_path / "file").write_text("x")
    with pytest.raises(BagError) as e:
        BagWriter(tmp_path / "file" / "r.bag")
    assert "cannot create" in e.value.problem


def test_the_writer_syncs_each_flush_in_the_background(tmp_path: Path) -> None:
    now, clock = fake_clock()
    sample = Sample("sync")
    w = BagWriter(tmp_path / "s", clock=clock)  # fsync on: the default
    w.meta(sample.meta)
    for k in range(25):
        sample.write_tick(w, k)
        now[0] = (k + 1) * TICK_S
    syncer = w._syncer
    assert syncer is not None
    w.close()
    assert syncer.syncs >= 1 and not syncer._thread.is_alive()
    assert check_prefix(BagReader(tmp_path / "s"), sample) == 24


@pytest.mark.parametrize("name", STORAGES)
def test_flushes_wait_for_the_tick_end_but_not_forever(tmp_path: Path, name: str) -> None:
    """A flush comes at a tick's end once a second has passed, so a cut bag holds whole
    ticks; a node stalled inside a tick still flushes after two seconds."""
    now, clock = fake_clock()
    sample = Sample("stall")
    path = tmp_path / name
    w = BagWriter(path, fsync=False, clock=clock)
    w.meta(sample.meta)
    sample.write_tick(w, 0)
    file = path if name.endswith(".bag") else path / f"{name}.mcap"
    size = file.stat().st_size
    now[0] = 1.5
    w.autopilot_rx(1, b"x" * 100, T0_NS)  # a second and a half, inside tick 1: no flush yet
    assert file.stat().st_size == size
    now[0] = 2.0
    w.autopilot_rx(1, b"y", T0_NS)
    assert file.stat().st_size > size
    w.close()


def test_a_metadata_yaml_with_text_for_numbers_is_read_around(tmp_path: Path) -> None:
    """rosbags takes metadata.yaml's counts as they are; text there (a fuzz find) makes the
    reader scan the MCAP file instead, which has everything."""
    sample = write_sample(tmp_path / "m", 6)
    meta = tmp_path / "m" / "metadata.yaml"
    meta.write_text(meta.read_text().replace("message_count: 6", "message_count: '6'", 1))
    r = BagReader(tmp_path / "m")
    assert check_prefix(r, sample) == 5
    assert "a message count is '6', not a number" in r.repairs[0]
