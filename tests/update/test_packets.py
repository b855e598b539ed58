"""The update frame's bytes (fieldkit.update.packets, docs/update.md#on-air-format).

Round trips of every record kind and of whole frames, the worked example of the doc byte
for byte (built here with struct, word by word, independently of the encoder), every
malformation the decoder refuses with the offset it names, and how an update frame, a
ROSBuzz bundle and a ROSBuzz OTA message are told apart, down to the robot's host.
"""

from __future__ import annotations

import struct

import bsdiff4
import pytest
from hypothesis import given
from hypothesis import strategies as st
from rigs import RIG_HOME

import bvm
from fieldkit.robot import RobotRuntime, ScriptStatus, Sensors, geo
from fieldkit.robot import bundle as wirebundle
from fieldkit.robot.profiles import load_profile
from fieldkit.update import packets as pk
from fieldkit.update.agent import AgentConfig, UpdateAgent
from fieldkit.update.host import RobotUpdater
from fieldkit.update.packets import Phase, Reason
from fieldkit.update.release import Release

from .test_agent import V0, V1, stand_in_patch, stand_in_verify

# ---------------------------------------------------------------- strategies

u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFF_FFFF)
short_hash = st.binary(min_size=pk.SHORT, max_size=pk.SHORT)
phases = st.sampled_from(Phase)

statuses = st.builds(pk.Status, u32, short_hash, phases, u32, u32, u16)
offers = st.builds(pk.Offer, short_hash, u32, u32, short_hash)
wants = st.builds(pk.Want, short_hash, u16, st.integers(0, (1 << 64) - 1))
chunks = st.builds(pk.Chunk, short_hash, u16, st.binary(min_size=1, max_size=pk.CHUNK_BYTES))
#: ENTRIES as large as a frame holds: 8 + 3 + 24 * 9 = 227 bytes.
entries = st.builds(
    pk.Entries, st.lists(st.builds(pk.Entry, u16, u16, phases, u32), max_size=24).map(tuple)
)
verdicts = st.builds(pk.Verdict, u32, st.sampled_from(Reason))
RECORDS: dict[str, st.SearchStrategy[pk.Record]] = {
    "STATUS": statuses,
    "OFFER": offers,
    "WANT": wants,
    "CHUNK": chunks,
    "ENTRIES": entries,
    "VERDICT": verdicts,
}
records = st.one_of(*RECORDS.values())


@st.composite
def frames(draw: st.DrawFn) -> pk.Frame:
    """A frame of any records that fit MAX_FRAME_BYTES, in the order drawn."""
    chosen: list[pk.Record] = []
    for r in draw(st.lists(records, max_size=12)):
        if pk.image_size([*chosen, r]) <= pk.MAX_FRAME_BYTES:
            chosen.append(r)
    return pk.Frame(draw(u16), tuple(chosen))


# ---------------------------------------------------------------- round trips


@pytest.mark.parametrize("kind", list(RECORDS))
@given(data=st.data())
def test_every_record_kind_round_trips_alone(kind: str, data: st.DataObject) -> None:
    record = data.draw(RECORDS[kind])
    frame = pk.Frame(data.draw(u16), (record,))
    air = pk.encode(frame)
    assert pk.decode(air) == frame
    assert pk.encode(pk.decode(air)) == air
    assert len(air) == pk.image_size([record])


@given(frames())
def test_whole_frames_round_trip_within_the_frame_limit(frame: pk.Frame) -> None:
    air = pk.encode(frame)
    assert len(air) % 8 == 0 and 8 <= len(air) <= pk.MAX_FRAME_BYTES
    assert len(air) == pk.image_size(frame.records)
    assert pk.decode(air) == frame
    assert pk.frame_type(air) == pk.UPDATE_FRAME
    with pytest.raises(wirebundle.BundleError):
        wirebundle.decode(air)


def test_record_sizes_are_the_documented_ones() -> None:
    """The table of docs/update.md#on-air-format: bytes in a frame, the 2-byte head included."""
    assert (pk.STATUS_BYTES, pk.OFFER_BYTES, pk.WANT_BYTES, pk.VERDICT_BYTES) == (25, 26, 20, 7)
    assert pk.ENTRY_BYTES == 9 and pk.entries_bytes(0) == 3 and pk.entries_bytes(12) == 111
    assert pk.chunk_bytes(1) == 13 and pk.chunk_bytes(pk.CHUNK_BYTES) == 108
    # The fullest frames of each kind still fit one frame.
    full_chunk = pk.Chunk(bytes(8), 0, bytes(pk.CHUNK_BYTES))
    assert pk.image_size([full_chunk, full_chunk]) == 224 <= pk.MAX_FRAME_BYTES
    most = pk.Entries(tuple(pk.Entry(i, 0, Phase.RUNNING, 0) for i in range(24)))
    assert pk.image_size([most]) == 232 == pk.MAX_FRAME_BYTES
    with pytest.raises(ValueError, match="more than 232"):
        pk.encode(pk.Frame(1, (pk.Entries((*most.entries, most.entries[0])),)))


# ---------------------------------------------------------------- the worked example

#: docs/update.md#worked-example: robot 7 stands by for version 4 (it runs version 3,
#: heartbeat 0x0102) and asks for chunks 2 and 4 of patch de ad be ef 00 11 22 33.
EXAMPLE = pk.Frame(
    7,
    (
        pk.Status(3, bytes.fromhex("a1b2c3d4e5f60718"), Phase.STANDBY, 4, 0, 0x0102),
        pk.Want(bytes.fromhex("deadbeef00112233"), 2, 0b101),
    ),
)
#: Its 56 bytes on the air, written out by hand (one 8-byte word a line).
EXAMPLE_AIR = bytes.fromhex(
    "00 00 00 07 02 01 00 10"
    "b2 a1 00 00 00 03 17 01"
    "04 01 18 07 f6 e5 d4 c3"
    "02 00 00 00 00 00 00 00"
    "00 ef be ad de 12 03 01"
    "00 00 05 00 02 33 22 11"
    "00 00 00 00 00 00 00 00"
)


def air(image: bytes) -> bytes:
    """The air bytes of a memory image, as XbeeMav sends payload64: each little-endian u64
    word written most significant byte first (a partial last word is left as it is)."""
    out = b""
    whole = len(image) - len(image) % 8
    for i in range(0, whole, 8):
        (word,) = struct.unpack_from("<Q", image, i)
        out += struct.pack(">Q", word)
    return out + image[whole:]


def example_image() -> bytes:
    """The example's memory image, field by field (docs/update.md's tables)."""
    word0 = struct.pack("<HBBHH", 16, 1, 2, 7, 0)
    status = struct.pack("<BB", 1, 23) + struct.pack(
        "<I8sBIIH", 3, bytes.fromhex("a1b2c3d4e5f60718"), 1, 4, 0, 0x0102
    )
    want = struct.pack("<BB", 3, 18) + struct.pack("<8sHQ", bytes.fromhex("deadbeef00112233"), 2, 5)
    image = word0 + status + want
    assert len(image) == 53
    return image + bytes(3)


def test_the_worked_example_byte_for_byte() -> None:
    assert air(example_image()) == EXAMPLE_AIR
    assert pk.encode(EXAMPLE) == EXAMPLE_AIR
    assert pk.decode(EXAMPLE_AIR) == EXAMPLE
    assert EXAMPLE.records[1].chunks() == [2, 4]  # type: ignore[union-attr]
    # Word 0 as a payload64 word: type 16 in its low 16 bits, neither 1 nor 2.
    assert int.from_bytes(EXAMPLE_AIR[:8], "big") == 0x0000_0007_0201_0010
    assert pk.frame_type(EXAMPLE_AIR) == 16


# ---------------------------------------------------------------- malformations


def frame_image(*records: bytes, count: int | None = None, head: bytes | None = None) -> bytes:
    """A memory image: word 0 (type 16, format 1, `count` records, sender 9), then records
    (each already `kind | length | body`), zero padded to whole words."""
    if head is None:
        head = struct.pack("<HBBHH", 16, 1, len(records) if count is None else count, 9, 0)
    image = head + b"".join(records)
    return image + bytes(-len(image) % 8)


def rec(kind: int, body: bytes, length: int | None = None) -> bytes:
    """A record: kind, body length (or a lie), body."""
    return bytes([kind, len(body) if length is None else length]) + body


STATUS_BODY = struct.pack("<I8sBIIH", 1, bytes(8), 0, 0, 0, 1)
WANT_BODY = struct.pack("<8sHQ", bytes(8), 0, 1)
ENTRY = struct.pack("<HHBI", 2, 1, 0, 1)
VERDICT_BODY = struct.pack("<IB", 2, 1)

MALFORMED = [
    # (name, air bytes, what the error says, offset it names in the memory image)
    ("empty", b"", "0 bytes, not a whole number", 0),
    ("seven bytes", bytes(7), "7 bytes, not a whole number", 0),
    ("a word and a half", air(frame_image())[:8] + bytes(4), "12 bytes", 0),
    ("too long", air(frame_image(*[rec(6, VERDICT_BODY)] * 33)), "240 bytes, more than", 232),
    ("a bundle's type", air(struct.pack("<HBBHH", 2, 1, 0, 9, 0)), "frame type 2", 0),
    ("format 2", air(struct.pack("<HBBHH", 16, 2, 0, 9, 0)), "format 2", 2),
    ("reserved bytes", air(struct.pack("<HBBHH", 16, 1, 0, 9, 1)), "reserved bytes", 6),
    ("count too high", air(frame_image(rec(6, VERDICT_BODY), count=2)), "2 records announced", 15),
    ("count too low", air(frame_image(rec(6, VERDICT_BODY), count=0)), "padding", 8),
    ("record overruns", air(frame_image(rec(1, STATUS_BODY, 200))), "overruns", 8),
    ("unknown kind", air(frame_image(rec(9, bytes(5)))), "record kind 9", 8),
    ("kind zero", air(frame_image(rec(0, b""))), "record kind 0", 8),
    ("short STATUS", air(frame_image(rec(1, STATUS_BODY[:-1]))), "STATUS of 22 bytes", 10),
    ("long STATUS", air(frame_image(rec(1, STATUS_BODY + b"\0"))), "STATUS of 24 bytes", 10),
    (
        "STATUS phase",
        air(frame_image(rec(1, STATUS_BODY[:12] + b"\x04" + STATUS_BODY[13:]))),
        "phase 4",
        22,
    ),
    ("OFFER size", air(frame_image(rec(2, bytes(23)))), "OFFER of 23 bytes, not 24", 10),
    ("WANT size", air(frame_image(rec(3, WANT_BODY[:17]))), "WANT of 17 bytes, not 18", 10),
    ("empty CHUNK", air(frame_image(rec(4, bytes(10)))), "CHUNK of 10 bytes, not 11..106", 10),
    ("CHUNK too big", air(frame_image(rec(4, bytes(107)))), "CHUNK of 107 bytes", 10),
    ("ENTRIES empty", air(frame_image(rec(5, b""))), "ENTRIES of 0 bytes", 10),
    ("ENTRIES count", air(frame_image(rec(5, b"\x02" + ENTRY))), "does not hold its count", 10),
    (
        "entry phase",
        air(frame_image(rec(5, b"\x02" + ENTRY + ENTRY[:4] + b"\x09" + ENTRY[5:]))),
        "entry phase 9",
        10 + 1 + 9 + 4,
    ),
    ("VERDICT size", air(frame_image(rec(6, bytes(6)))), "VERDICT of 6 bytes, not 5", 10),
    ("VERDICT reason", air(frame_image(rec(6, struct.pack("<IB", 2, 0)))), "reason 0", 14),
    (
        "second record",
        air(frame_image(rec(3, WANT_BODY), rec(6, struct.pack("<IB", 2, 5)))),
        "reason 5",
        8 + 20 + 2 + 4,
    ),
    ("padding junk", air(frame_image(rec(6, VERDICT_BODY))[:-1] + b"\x01"), "padding", 15),
    ("a word of padding", air(frame_image(rec(6, VERDICT_BODY))) + bytes(8), "padding", 15),
]


@pytest.mark.parametrize(
    ("data", "what", "offset"), [m[1:] for m in MALFORMED], ids=[m[0] for m in MALFORMED]
)
def test_the_decoder_names_each_malformation_and_where(data: bytes, what: str, offset: int) -> None:
    with pytest.raises(pk.FrameError, match=what) as info:
        pk.decode(data)
    assert info.value.offset == offset
    assert f"(at byte {offset})" in str(info.value)


def test_the_decoder_refuses_what_is_not_bytes() -> None:
    with pytest.raises(pk.FrameError, match="not str"):
        pk.decode("0" * 16)  # type: ignore[arg-type]


def test_the_malformed_frames_differ_from_a_good_one_only_where_they_say() -> None:
    """The table's images are real frames but for their one defect: fixed, they decode."""
    good = air(frame_image(rec(1, STATUS_BODY), rec(6, struct.pack("<IB", 2, 1))))
    frame = pk.decode(good)
    assert frame.sender == 9
    assert frame.records == (
        pk.Status(1, bytes(8), Phase.RUNNING, 0, 0, 1),
        pk.Verdict(2, Reason.BARRIER_TIMEOUT),
    )


@pytest.mark.parametrize(
    ("record", "what"),
    [
        (pk.Status(1, bytes(7), Phase.RUNNING, 0, 0, 0), "running of 7 bytes"),
        (pk.Status(-1, bytes(8), Phase.RUNNING, 0, 0, 0), "Status"),
        (pk.Status(1, bytes(8), 7, 0, 0, 0), "phase 7"),  # type: ignore[arg-type]
        (pk.Offer(bytes(8), 1, 1 << 32, bytes(8)), "Offer"),
        (pk.Want(bytes(9), 0, 0), "digest of 9 bytes"),
        (pk.Chunk(bytes(8), 0, b""), "a chunk of 0 bytes"),
        (pk.Chunk(bytes(8), 0, bytes(97)), "a chunk of 97 bytes"),
        (pk.Chunk(bytes(8), 1 << 16, b"x"), "Chunk"),
        (pk.Entries((pk.Entry(1, 1, 5, 1),)), "phase 5"),  # type: ignore[arg-type]
        (pk.Entries(tuple(pk.Entry(i, 0, Phase.RUNNING, 0) for i in range(29))), "Entries of 262"),
        (pk.Verdict(1, 0), "reason 0"),  # type: ignore[arg-type]
    ],
)
def test_the_encoder_refuses_what_the_decoder_would(record: pk.Record, what: str) -> None:
    with pytest.raises(ValueError, match=what):
        pk.encode(pk.Frame(1, (record,)))


def test_the_encoder_refuses_a_bad_sender_and_too_many_records() -> None:
    with pytest.raises(ValueError, match="sender 65536"):
        pk.encode(pk.Frame(1 << 16, ()))
    with pytest.raises(ValueError, match="255 records"):
        pk.encode(pk.Frame(1, (pk.Verdict(1, Reason.OPERATOR),) * 256))


# ---------------------------------------------------------------- telling frames apart


def sent_code(update_no: int, patch: bytes) -> bytes:
    """A ROSBuzz SENT_CODE updater message on the air, built as buzz_update.cpp builds it
    (spec buzz-wire-formats.md §8.5): payload64 word 0 == 1, then the words of
    u16 size | body, the body u8 kind 0 | u16 update_no | u16 patch size | patch, zero
    padded to 251 bytes at least, the buffer zero padded to whole words."""
    body = struct.pack("<BHH", 0, update_no, len(patch)) + patch
    body += bytes(max(0, 251 - len(body)))
    buffer = struct.pack("<H", len(body)) + body
    buffer += bytes(-len(buffer) % 8)
    words = [1, *struct.unpack(f"<{len(buffer) // 8}Q", buffer)]
    return b"".join(struct.pack(">Q", w) for w in words)


def test_frame_type_tells_bundles_ota_messages_and_update_frames_apart() -> None:
    bundle = wirebundle.encode_fields(3, [b"\x00\x01\x00\x03abc"], 45.5, -73.6, 10.0, number=9)
    ota = sent_code(5, b"BSDIFF40" + bytes(40))
    assert pk.frame_type(bundle) == wirebundle.BUZZ_MESSAGE == 2
    assert pk.frame_type(ota) == pk.ROSBUZZ_OTA == wirebundle.UPDATER_MESSAGE == 1
    assert pk.frame_type(EXAMPLE_AIR) == pk.UPDATE_FRAME == 16
    assert pk.frame_type(pk.encode(pk.Frame(0xFFFF, ()))) == 16
    assert pk.frame_type(bytes(7)) is None
    # ROSBuzz tells its OTA message by the whole word; type 1 with a message number in the
    # word is nothing ROSBuzz acts on, and is refused here as an OTA message all the same.
    assert pk.frame_type(struct.pack(">Q", 1 | 5 << 16)) == pk.ROSBUZZ_OTA
    assert pk.frame_type(struct.pack(">Q", 2 | 5 << 16)) == 2
    # Each decoder refuses the others' frames cleanly.
    with pytest.raises(pk.FrameError, match="frame type 2") as info:
        pk.decode(bundle)
    assert info.value.offset == 0
    with pytest.raises(pk.FrameError, match="more than"):
        pk.decode(ota)
    with pytest.raises(pk.FrameError, match="frame type 1"):
        pk.decode(ota[:16])
    with pytest.raises(wirebundle.BundleError, match="updater"):
        wirebundle.decode(ota[:232])


@pytest.mark.parametrize(
    "frame",
    [
        pk.Frame(1, ()),
        EXAMPLE,
        pk.Frame(2, (pk.Chunk(bytes(8), 0, bytes(96)), pk.Chunk(bytes(8), 1, bytes(96)))),
        pk.Frame(3, (pk.Entries(tuple(pk.Entry(i, 0, Phase.RUNNING, 0) for i in range(24))),)),
    ],
    ids=["one word", "example", "two chunks", "largest"],
)
def test_a_bundle_decoder_refuses_an_update_frame_cleanly(frame: pk.Frame) -> None:
    data = pk.encode(frame)
    with pytest.raises(wirebundle.BundleError) as info:
        wirebundle.decode(data)
    assert 0 <= info.value.offset <= len(data)
    with pytest.raises(wirebundle.BundleError):
        wirebundle.from_rf_data(b"S\x07\x01" + data)


# ---------------------------------------------------------------- on a robot

SCRIPT = "function init() { n = 0 }\nfunction step() { n = n + 1 }\n"
OTHER = 'function init() { n = 1000 }\nfunction step() { log("pwned") }\n'


def sensors() -> Sensors:
    return Sensors(lat=RIG_HOME[0], lon=RIG_HOME[1], alt=0.0, north=0.0, east=0.0)


def test_a_rosbuzz_ota_frame_is_counted_and_refused_never_applied() -> None:
    program = bvm.compile_source(SCRIPT)
    runtime = RobotRuntime(1, load_profile("solo"), geo.LocalFrame(*RIG_HOME))
    assert runtime.start(program, sensors())
    release = Release.from_program(program)
    agent = UpdateAgent(1, 1, release, stand_in_verify)
    lines: list[str] = []
    updater = RobotUpdater(runtime, agent, log=lines.append)
    # A real ROSBuzz update: a bsdiff patch of the running bytecode into another script's.
    patch = bsdiff4.diff(program.bytecode, bvm.compile_source(OTHER).bytecode)
    ota = sent_code(2, patch)
    assert pk.frame_type(ota) == pk.ROSBUZZ_OTA
    for _ in range(30):
        updater.before_step(sensors())
        runtime.tick(sensors())
        assert updater.receive(ota) is True  # the update's, never the runtime's
        updater.after_step()
    assert agent.counters["rosbuzz_ota_refused"] == 30
    assert agent.counters["bad_frames"] == 0  # recognised, not mistaken for a broken frame
    assert lines.count("a ROSBuzz OTA packet (unsigned) was refused") == 1
    # Never applied: same version, same bytecode, the script stepped through all 30 ticks.
    assert agent.version == 1 and agent.release == release and agent.staged is None
    assert not agent.transfers and updater.actions == []
    assert runtime.status is ScriptStatus.RUNNING and runtime.vm["n"] == 30
    # Bundles stay the host's; update frames go to the agent.
    bundle = wirebundle.encode_fields(2, [], *RIG_HOME, 0.0)
    assert updater.receive(bundle) is False
    assert updater.receive(EXAMPLE_AIR) is True and agent.peers[7].version == 4


# ---------------------------------------------------------------- the agent's frames


def busy_holder(config: AgentConfig) -> tuple[UpdateAgent, bytes]:
    """An agent serving a patch to a dozen neighbours that want it: its fullest frames."""
    a = UpdateAgent(1, 0, V0, stand_in_verify, config=config)
    patch = stand_in_patch(V0, V1, 1)
    assert a.inject(patch)
    digest = next(iter(a.transfers))
    for peer in range(2, 14):
        status = pk.Status(0, bytes.fromhex(V0.hash)[:8], Phase.RUNNING, 0, 0, 1)
        a.receive(pk.encode(pk.Frame(peer, (status,))))
    return a, digest


@pytest.mark.parametrize("budget", [150, 160, 231, 300, 1000])
def test_the_agent_keeps_every_frame_within_its_budget_and_a_frame(budget: int) -> None:
    """Padding counts (a budget that is not whole words), and a budget larger than a frame
    still gives frames (once, a frame of more than 232 bytes raised in `frame`)."""
    a, digest = busy_holder(AgentConfig(budget_bytes=budget))
    sizes = []
    for t in range(60):
        want = pk.Want(digest, 0, (1 << 64) - 1)
        a.receive(pk.encode(pk.Frame(2 + t % 12, (want,))))
        a.tick(t)
        frame = a.frame()
        if frame is not None:
            sizes.append(len(frame))
            assert pk.decode(frame).sender == 1
    assert max(sizes) <= min(budget, pk.MAX_FRAME_BYTES)
    if budget >= 200:
        assert max(sizes) > 160  # the room was used, not just kept


def test_a_bad_version_with_nothing_older_to_run_is_noted_once_not_every_tick() -> None:
    """A robot running version 5 with no older one, told 5 is bad, cannot roll back: it
    used to retry every tick, logging each time and bumping its heartbeat (a fuzz find)."""
    a = UpdateAgent(1, 5, V0, stand_in_verify)
    a.receive(pk.encode(pk.Frame(2, (pk.Verdict(5, Reason.OPERATOR),))))
    for t in range(1, 101):
        assert a.tick(t) is None
    stuck = [e for e in a.events if "nothing older" in e]
    assert len(stuck) == 1
    assert a.heartbeat <= 100 // a.config.heartbeat_every + 1
    assert a.version == 5 and a.release == V0
