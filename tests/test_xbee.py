"""XBee API frames: documented golden bytes, digi-xbee agreement, the streaming de-framer."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace

import pytest
from digi.xbee.models.address import XBee16BitAddress, XBee64BitAddress
from digi.xbee.models.mode import OperatingMode
from digi.xbee.models.status import DiscoveryStatus
from digi.xbee.models.status import ModemStatus as DigiModem
from digi.xbee.models.status import TransmitStatus as DigiStatus
from digi.xbee.packets.base import XBeePacket
from digi.xbee.packets.common import ModemStatusPacket, TransmitStatusPacket
from digi.xbee.packets.common import ReceivePacket as DigiReceive
from digi.xbee.packets.common import TransmitPacket as DigiTransmit
from digi.xbee.packets.factory import build_frame
from fuzz import bundle_fuzz
from hypothesis import given, settings
from hypothesis import strategies as st

from fieldkit.radio import xbee as X
from fieldkit.robot import bundle as B

#: The worked example (docs/bundle.md#worked-example): robot 7, number 1, BROADCAST "cmd"=22 +
#: JOIN 3.
TIME_NS = 0x1122334455667788
EXAMPLE = replace(bundle_fuzz.EXAMPLE, time_ns=TIME_NS)
#: docs/bundle.md#worked-example's XBee RF data, with the 8 time bytes filled in.
SPEC_RF = bytes.fromhex(
    "53 07 01 | 00 00 00 00 00 01 00 02 | 11 22 33 44 55 66 77 88 | 40 46 c0 00 00 00 00 00 |"
    " c0 52 66 66 66 66 66 66 | 40 24 00 00 00 00 00 00 | 03 00 00 0c 00 07 00 03 |"
    " 00 00 01 64 6d 63 03 00 | 00 03 00 04 00 03 16 00".replace("|", "")
)
#: The worked example's API frame head: start, length 0x51, 0x10, frame id 1, broadcast, FF FF,
#: radius, options.
SPEC_HEAD = bytes.fromhex("7e 00 51 10 01 00 00 00 00 00 00 ff ff ff ff 00 00")
SERIAL = 0x0013A20040A1B2C3


def spec_frame() -> bytes:
    """The worked example's API frame: the head, the RF data, and the checksum computed by hand."""
    frame_data = SPEC_HEAD[3:] + SPEC_RF
    return SPEC_HEAD + SPEC_RF + bytes(((0xFF - sum(frame_data)) & 0xFF,))


def digi_unescape(raw: bytes, api_mode: int) -> bytearray:
    """digi-xbee's parse input: unescaped bytes (docs/third-party.md#digi-xbee), as a bytearray."""
    return bytearray(XBeePacket.unescape_data(raw) if api_mode == 2 else raw)


def digi_mode(api_mode: int) -> OperatingMode:
    """digi-xbee's name for an API mode."""
    return OperatingMode.ESCAPED_API_MODE if api_mode == 2 else OperatingMode.API_MODE


# ---------------------------------------------------------------- golden bytes


def test_spec_rf_data_and_frame_byte_for_byte() -> None:
    """The bundle's RF data and our 0x10 frame are the worked example's bytes (length 0x51 = 81)."""
    assert B.to_rf_data(EXAMPLE) == SPEC_RF
    frame = X.transmit_request(SPEC_RF)
    assert frame == spec_frame()
    assert frame[:17] == SPEC_HEAD
    assert len(frame) == 4 + 0x51


def test_spec_frame_in_api_mode_2() -> None:
    """Escaped, the worked example's frame differs only at special bytes; it de-frames the same."""
    esc = X.transmit_request(SPEC_RF, api_mode=2)
    plain = spec_frame()
    # 0x11 (in the time bytes) is the only special byte after the start delimiter
    assert esc == plain.replace(b"\x11", b"\x7d\x31")
    (frame,) = X.FrameReader(2).feed(esc)
    assert frame == X.TransmitRequest(SPEC_RF)


@pytest.mark.parametrize("api_mode", [1, 2])
def test_digi_xbee_builds_the_same_transmit_request(api_mode: int) -> None:
    """digi-xbee's TransmitPacket with XbeeMav's FF FF 16-bit address gives the same bytes."""
    digi = DigiTransmit(
        1,
        XBee64BitAddress.BROADCAST_ADDRESS,
        XBee16BitAddress.from_hex_string("FFFF"),
        0,
        0,
        rf_data=SPEC_RF,
    )
    assert X.transmit_request(SPEC_RF, api_mode=api_mode) == digi.output(escaped=api_mode == 2)


def test_dest16_and_frame_id_are_options() -> None:
    """Digi's documented FF FE and frame id 0 (no status frames) are available."""
    digi = DigiTransmit(
        0, XBee64BitAddress.BROADCAST_ADDRESS, XBee16BitAddress.UNKNOWN_ADDRESS, 0, 0, rf_data=b"x"
    )
    assert X.transmit_request(b"x", frame_id=0, dest16=X.UNKNOWN16) == digi.output()


@pytest.mark.parametrize("special", [0x7E, 0x7D, 0x11, 0x13])
def test_escaping_of_every_special_byte(special: int) -> None:
    """Each special byte is escaped wherever it is: RF data, length, checksum."""
    esc = bytes((0x7D, special ^ 0x20))
    frame = X.transmit_request(bytes((1, special, 2)), api_mode=2)
    assert esc in frame and frame.count(0x7E) == 1
    # the length field: 14 header bytes + n RF bytes = special
    n = special - 14 if special > 14 else None
    if n is not None:
        by_length = X.transmit_request(bytes(n), api_mode=2)
        assert by_length[1:4] == b"\x00" + esc
    # the checksum: pick the last RF byte so the checksum comes out special
    base = X.TransmitRequest(b"\x00").frame_data()
    last = (0xFF - special - sum(base[:-1])) & 0xFF
    frame = X.TransmitRequest(bytes((last,))).encode(2)
    assert frame.endswith(esc)
    assert X.FrameReader(2).feed(frame) == [X.TransmitRequest(bytes((last,)))]
    assert X.escape(bytes((special,))) == esc


def test_frame_bytes_refuses_what_no_reader_takes() -> None:
    """Empty frames and frames over MAX_FRAME_DATA (270) raise; 270 is fine."""
    with pytest.raises(ValueError):
        X.frame_bytes(b"")
    with pytest.raises(ValueError):
        X.transmit_request(bytes(257))  # 14 + 257 = 271
    with pytest.raises(ValueError):
        X.frame_bytes(b"\x8a\x00", api_mode=3)
    assert X.FrameReader().feed(X.transmit_request(bytes(256))) == [X.TransmitRequest(bytes(256))]


# ---------------------------------------------------------------- parsing digi-xbee's frames


@pytest.mark.parametrize("api_mode", [1, 2])
def test_reads_frames_digi_xbee_builds(api_mode: int) -> None:
    """0x90, 0x8B and 0x8A frames from digi-xbee come out with their fields."""
    escaped = api_mode == 2
    rf = bytes(range(0x70, 0x90)) + b"\x11\x13"
    rx = DigiReceive(
        XBee64BitAddress.from_hex_string("0013A2007E7D1113"),
        XBee16BitAddress.from_hex_string("FFFE"),
        2,
        rf_data=rf,
    )
    status = TransmitStatusPacket(
        1,
        XBee16BitAddress.from_hex_string("FFFE"),
        0,
        DigiStatus.get(0x21),
        DiscoveryStatus.get(0),
    )
    modem = ModemStatusPacket(DigiModem.get(0))
    stream = b"".join(p.output(escaped=escaped) for p in (rx, status, modem))
    reader = X.FrameReader(api_mode)
    assert reader.feed(stream) == [
        X.ReceivePacket(0x0013A2007E7D1113, rf, 0xFFFE, 2),
        X.TransmitStatus(1, 0xFFFE, 0, 0x21, 0),
        X.ModemStatus(0),
    ]
    assert reader.stats == Counter(frames_in=3)


@pytest.mark.parametrize("api_mode", [1, 2])
def test_digi_xbee_reads_our_receive_packets(api_mode: int) -> None:
    """Our 0x90 frames (used by the test relay) parse in digi-xbee to the same fields."""
    rf = b"F\x01\x07\x00\x00\x00" + bytes(range(250))
    raw = X.receive_packet(SERIAL, rf, api_mode=api_mode)
    packet = build_frame(digi_unescape(raw, api_mode), digi_mode(api_mode))
    assert isinstance(packet, DigiReceive)
    assert packet.x64bit_source_addr == XBee64BitAddress.from_hex_string(f"{SERIAL:016X}")
    assert bytes(packet.rf_data) == rf


# ---------------------------------------------------------------- round trips


def frames() -> st.SearchStrategy[X.Frame]:
    """Any frame the reader returns."""
    u8, u16, u64 = st.integers(0, 255), st.integers(0, 0xFFFF), st.integers(0, 2**64 - 1)
    rf = st.binary(max_size=256)
    return st.one_of(
        st.builds(X.ReceivePacket, u64, rf, u16, u8),
        st.builds(X.TransmitRequest, rf, u8, u64, u16, u8, u8),
        st.builds(X.TransmitStatus, u8, u16, u8, u8, u8),
        st.builds(X.ModemStatus, u8),
        st.builds(X.AtResponse, u8, st.binary(min_size=2, max_size=2), u8, st.binary(max_size=8)),
    )


@given(st.lists(frames(), max_size=6), st.sampled_from([1, 2]), st.data())
@settings(max_examples=300, deadline=None)
def test_frames_round_trip_in_any_pieces(
    fs: list[X.Frame], api_mode: int, data: st.DataObject
) -> None:
    """Encoded frames, cut anywhere, come back equal; only frames_in counts."""
    stream = b"".join(f.encode(api_mode) for f in fs)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=8)))
    reader = X.FrameReader(api_mode)
    got = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        got += reader.feed(stream[a:b])
    assert got == fs
    assert reader.pending == 0
    assert reader.stats == Counter(frames_in=len(fs)) if fs else not reader.stats


VALID = [
    X.ReceivePacket(SERIAL, b"S\x07\x01" + bytes(48)),
    X.TransmitStatus(1),
    X.ReceivePacket(SERIAL + 1, bytes((0x7E, 0x7D, 0x11, 0x13)) * 10),
    X.ModemStatus(6),
    X.ReceivePacket(SERIAL + 2, b"P\x05\x02\x03"),
]


@pytest.mark.parametrize("api_mode", [1, 2])
def test_every_split_point_of_a_valid_stream(api_mode: int) -> None:
    """Two pieces, cut at every byte: the same five frames every time."""
    stream = b"".join(f.encode(api_mode) for f in VALID)
    for cut in range(len(stream) + 1):
        reader = X.FrameReader(api_mode)
        assert reader.feed(stream[:cut]) + reader.feed(stream[cut:]) == VALID, cut
        assert reader.stats == Counter(frames_in=5)


def hostile_stream(api_mode: int) -> tuple[bytes, Counter[str]]:
    """Valid frames with garbage, a truncated frame, a bad checksum, bad lengths and an
    unknown type between them; and the counters that must result."""
    enc = [f.encode(api_mode) for f in VALID]
    bad_sum = bytearray(X.ReceivePacket(SERIAL, b"hello").encode(api_mode))
    bad_sum[-1] ^= 0x01
    truncated = X.ReceivePacket(SERIAL, bytes(100)).encode(api_mode)[:40]
    too_long = b"\x7e\x01\x0f" + bytes(20)  # length 271 > 270
    zero = b"\x7e\x00\x00"
    unknown = X.frame_bytes(b"\x95" + bytes(10), api_mode)
    short = X.frame_bytes(b"\x90\x00\x13", api_mode)  # a 0x90 needs 12 bytes
    garbage = b"\x01\x02\x03garbage\xff"
    stream = (
        garbage + enc[0] + truncated + enc[1] + bytes(bad_sum) + enc[2]
        + too_long + zero + enc[3] + unknown + short + enc[4]
    )  # fmt: skip
    want = Counter(frames_in=5, bad_length=2, bad_checksum=1, unknown_type=1, short_frame=1)
    # In API mode 2 the truncated frame ends at the next frame's raw 0x7E; in API mode 1 the
    # reader takes the next bytes as its rest and the checksum fails.
    want["truncated" if api_mode == 2 else "bad_checksum"] += 1
    want["bad_frames"] = 6
    # skipped: the garbage, the insides of the rejected frames (not of checksummed ones)
    want["garbage_bytes"] = (
        len(garbage) + len(truncated) - 1 + len(bad_sum) - 1 + len(too_long) - 1 + len(zero) - 1
    )
    return stream, want


@pytest.mark.parametrize("api_mode", [1, 2])
def test_hostile_stream_only_moves_counters(api_mode: int) -> None:
    """Every valid frame comes through; each kind of damage is counted once."""
    stream, want = hostile_stream(api_mode)
    for cut in range(len(stream) + 1):
        reader = X.FrameReader(api_mode)
        got = reader.feed(stream[:cut]) + reader.feed(stream[cut:])
        assert got == VALID, cut
        assert reader.stats == want, cut


@pytest.mark.parametrize("api_mode", [1, 2])
def test_a_truncated_frame_does_not_hold_back_the_next_after_flush(api_mode: int) -> None:
    """A frame cut short at the end of a burst: flush() abandons it, the frames inside the
    bytes it claimed come out (API mode 1: a stray 0x7E must not swallow real frames)."""
    reader = X.FrameReader(api_mode)
    head = b"\x7e\x00\x60\x90"  # claims 96 bytes
    assert reader.feed(head + VALID[1].encode(api_mode)) == ([] if api_mode == 1 else [VALID[1]])
    got = reader.flush()
    assert got == ([VALID[1]] if api_mode == 1 else [])
    assert reader.stats["truncated"] == 1
    assert reader.pending == 0


def test_api1_stray_start_byte_inside_garbage() -> None:
    """A 0x7E in garbage whose claimed length covers a real frame: the real frame survives."""
    stream = b"\x7e\x00\x05\x01\x02" + VALID[0].encode(1) + VALID[1].encode(1)
    reader = X.FrameReader(1)
    assert reader.feed(stream) == VALID[:2]
    assert reader.stats["bad_checksum"] == 1


def test_bad_escape_is_counted() -> None:
    """API mode 2: 0x7D followed by a byte that is not an escaped special byte."""
    frame = bytearray(X.ModemStatus(1).encode(2))
    frame[4:4] = b"\x7d\x41"
    reader = X.FrameReader(2)
    assert reader.feed(bytes(frame) + VALID[1].encode(2)) == [VALID[1]]
    assert reader.stats["bad_escape"] == 1


def test_max_length_is_configurable() -> None:
    """A reader with a lower cap refuses longer frames as bad lengths."""
    reader = X.FrameReader(1, max_length=20)
    assert reader.feed(VALID[0].encode(1) + VALID[1].encode(1)) == [VALID[1]]
    assert reader.stats["bad_length"] == 1


@given(st.binary(max_size=2000), st.sampled_from([1, 2]), st.data())
@settings(max_examples=400, deadline=None)
def test_any_bytes_in_any_pieces(blob: bytes, api_mode: int, data: st.DataObject) -> None:
    """Never raises; the pieces do not matter; the buffer stays within one escaped frame."""
    whole = X.FrameReader(api_mode)
    want = whole.feed(blob) + whole.flush()
    cuts = sorted(data.draw(st.lists(st.integers(0, len(blob)), max_size=10)))
    reader = X.FrameReader(api_mode)
    got = []
    for a, b in zip([0, *cuts], [*cuts, len(blob)], strict=True):
        got += reader.feed(blob[a:b])
        assert reader.pending <= 2 * (X.MAX_FRAME_DATA + 3) + 1
    got += reader.flush()
    assert got == want
    assert reader.stats == whole.stats
