"""The Clearpath MCU codec (fieldkit.vehicle.clearpath.frame, .messages) against the spec.

Every worked frame of /shared/spec/clearpath-husky.md section 10 is built by our encoder and
parsed by our decoder, byte for byte; the CRC test vectors of section 3 and the truncation
rule of section 4 are checked as given there.
"""

from __future__ import annotations

import random

import pytest

from fieldkit.vehicle.clearpath import messages as M
from fieldkit.vehicle.clearpath.frame import (
    MAX_FRAME,
    Frame,
    FrameError,
    FrameReader,
    crc16,
    parse_frame,
)


def h(text: str) -> bytes:
    """Spec hex ("AA 13 EC ...") to bytes."""
    return bytes.fromhex(text)


# Section 10, verbatim.
WORKED = {
    "set_diff_speed_fwd_0.5": "AA 13 EC 00 00 00 00 00 00 00 02 55 32 00 32 00 F4 01 F4 01 8F 53",
    "set_diff_speed_stop": "AA 13 EC 00 00 00 00 00 00 00 02 55 00 00 00 00 F4 01 F4 01 39 3E",
    "set_max_accel": "AA 0F F0 00 00 00 00 00 00 11 02 55 F4 01 F4 01 3F 92",
    "req_encoders_once": "AA 0D F2 00 00 00 00 00 00 00 48 55 00 00 7C 43",
    "sub_system_status_10hz": "AA 0D F2 00 00 00 00 00 00 04 40 55 0A 00 72 A0",
    "req_power_once": "AA 0D F2 00 00 00 00 00 00 05 40 55 00 00 E8 E5",
    "data_encoders": "AA 18 E7 00 40 E2 01 00 00 00 88 55 02 39 30 00 00 0C FE FF FF F4 01 06 "
    "FF 19 4F",
    "data_system_status": "AA 26 D9 00 80 EE 36 00 00 04 80 55 80 EE 36 00 03 00 0A EC 09 F6 09 "
    "03 78 00 54 01 4A 01 04 EA 0B 1C 0C C5 0D 10 0E 30 D1",
    "data_safety_estop": "AA 0D F2 00 48 EF 36 00 00 10 80 55 08 00 6D D9",
    "data_platform_info": "AA 15 EA 00 0A 00 00 00 00 01 80 55 04 41 32 30 30 01 D2 04 00 00 B6 C2",
    "ack_set_diff_speed_ok": "AA 0D F2 00 4E E2 01 00 00 00 02 55 00 00 86 C8",
}

# What our encoders make for each: the same frames, from their meaning.
BUILT = {
    "set_diff_speed_fwd_0.5": lambda: M.set_diff_speed(0.5, 0.5, 5.0, 5.0),
    "set_diff_speed_stop": lambda: M.set_diff_speed(0.0, 0.0, 5.0, 5.0),
    "set_max_accel": lambda: M.set_max_accel(5.0, 5.0),
    "req_encoders_once": lambda: M.request(M.MsgType.ENCODERS, M.ONCE),
    "sub_system_status_10hz": lambda: M.request(M.MsgType.SYSTEM_STATUS, 10),
    "req_power_once": lambda: M.request(M.MsgType.REQ_POWER_SYSTEM, 0),
    "data_encoders": lambda: M.encoders((12.345, -0.5), (0.5, -0.25), 123456),
    "data_system_status": lambda: M.system_status(
        M.SystemStatus(3_600_000, (25.6, 25.4, 25.5), (1.2, 3.4, 3.3), (30.5, 31.0, 35.25, 36.0)),
        3_600_000,
    ),
    "data_safety_estop": lambda: M.safety_status(M.SAFETY_ESTOP, 0x0036EF48),
    "data_platform_info": lambda: M.platform_info(M.PlatformInfo("A200", 1, 1234), 10),
    "ack_set_diff_speed_ok": lambda: M.ack(M.MsgType.SET_DIFF_SPEED, 0, 0x0001E24E),
}


@pytest.mark.parametrize("name", sorted(WORKED))
def test_worked_frames_byte_for_byte(name: str) -> None:
    wire = h(WORKED[name])
    assert BUILT[name]().encode() == wire
    assert parse_frame(wire) == BUILT[name]()
    assert parse_frame(wire).encode() == wire


def test_crc_vectors() -> None:
    assert crc16(b"123456789") == 0x29B1
    assert crc16(b"A") == 0xB915
    assert crc16(b"") == 0xFFFF
    assert crc16(b"\x00") == 0xE1F0
    assert crc16(h("AA 16 E9 00 00 00 00 00 00 00 02 55")) == 0x1F6C


def test_scaled_values_truncate_toward_zero_and_clamp() -> None:
    assert M.raw(0.29, 100) == 28 and M.raw(-0.29, 100) == -28  # not 29: the C cast
    assert M.set_diff_speed(0.29, -0.29, 0, 0).payload[:4] == h("1C 00 E4 FF")
    # The reference wraps; we clamp, so 400 m/s cannot turn into -255 m/s.
    assert M.raw(400.0, 100) == 32767 and M.raw(-400.0, 100) == -32768
    assert M.raw(float("nan"), 100) == 0


def test_decoded_data_means_what_the_spec_says() -> None:
    enc = M.decode(parse_frame(h(WORKED["data_encoders"])))
    assert enc == M.Encoders((12.345, -0.5), (0.5, -0.25))
    safety = M.decode(parse_frame(h(WORKED["data_safety_estop"])))
    assert isinstance(safety, M.SafetyStatus) and safety.names == ["e_stop"]
    ack = M.decode(parse_frame(h(WORKED["ack_set_diff_speed_ok"])))
    assert ack == M.Ack(0x0200, 0) and ack.ok
    status = M.decode(parse_frame(h(WORKED["data_system_status"])))
    assert isinstance(status, M.SystemStatus) and status.voltages == (25.6, 25.4, 25.5)
    info = M.decode(parse_frame(h(WORKED["data_platform_info"])))
    assert info == M.PlatformInfo("A200", 1, 1234)
    req = M.decode_command(parse_frame(h(WORKED["sub_system_status_10hz"])))
    assert req == M.Request(0x8004, 10)
    refused = M.Ack(0x0210, M.ACK_RANGE | M.ACK_BAD_FORMAT)
    assert not refused.ok and refused.reason() == "bad message format, value out of range"


def test_inspector_fields_name_every_part() -> None:
    fields = M.fields(parse_frame(h(WORKED["data_safety_estop"])))
    assert fields["type"] == "0x8010" and fields["name"] == "SAFETY_SYSTEM"
    assert fields["timestamp"] == 0x0036EF48 and fields["flags"] == 0
    assert fields["payload"] == {"flags": 8, "names": ["e_stop"]}
    cmd = M.fields(parse_frame(h(WORKED["set_diff_speed_fwd_0.5"])), from_host=True)
    assert cmd["payload"] == {"left": 0.5, "right": 0.5, "left_accel": 5.0, "right_accel": 5.0}
    bad = M.fields(Frame(M.MsgType.ENCODERS, b"\x02\x00"))
    assert bad["payload"] is None and "encoders" in bad["error"]


@pytest.mark.parametrize(
    ("mutate", "offset", "reason"),
    [
        (lambda b: b"\x00" + b[1:], 0, "not the start of a frame"),
        (lambda b: b[:2] + b"\x00" + b[3:], 2, "not the complement of LEN"),
        (lambda b: b[:11] + b"\x54" + b[12:], 11, "STX"),
        (lambda b: b[:-1] + bytes([b[-1] ^ 1]), 20, "CRC 0x"),
        (lambda b: b[:10], 10, "truncated"),
        (lambda b: b + b"\x00", 22, "after the frame's end"),
        (lambda b: h("AA 01 FE") + b[3:], 1, "shorter than a header"),
    ],
)
def test_parse_frame_names_the_first_bad_byte(mutate, offset: int, reason: str) -> None:  # type: ignore[no-untyped-def]
    wire = mutate(h(WORKED["set_diff_speed_fwd_0.5"]))
    with pytest.raises(FrameError) as e:
        parse_frame(wire)
    assert e.value.offset == offset and reason in e.value.what


def test_payload_that_does_not_fit_its_type_is_refused() -> None:
    with pytest.raises(M.PayloadError, match="count 2 needs 12 bytes"):
        M.decode(Frame(M.MsgType.ENCODERS, b"\x02" + bytes(6)))
    with pytest.raises(M.PayloadError, match="3 payload bytes"):
        M.decode(Frame(M.MsgType.SAFETY_SYSTEM, b"\x00\x00\x00"))
    with pytest.raises(M.PayloadError, match="past its temperatures"):
        M.decode(Frame(M.MsgType.SYSTEM_STATUS, bytes(7) + b"\xff"))
    assert M.decode(Frame(M.MsgType.RAW_ENCODERS, b"\x00")) is None  # a kind not read


def test_deframer_takes_any_split_and_resyncs_after_noise() -> None:
    frames = [h(WORKED[k]) for k in sorted(WORKED)]
    noise = b"\xaa\x13\x00junk\xaa\xaa\x55"
    stream = noise + b"".join(f + noise for f in frames)
    rng = random.Random(1)
    for _ in range(20):
        reader = FrameReader()
        got = []
        i = 0
        while i < len(stream):
            j = i + rng.randint(1, 30)
            got += reader.feed(stream[i:j])
            i = j
        assert [f.encode() for f in got] == frames
        assert reader.frames == len(frames)
        assert reader.stats["garbage_bytes"] > 0 and reader.pending < MAX_FRAME


def test_deframer_finds_a_frame_hidden_in_a_bad_one() -> None:
    """The reference drops the bytes of a failed header unscanned; ours rescans them, so a
    frame starting inside a broken candidate is kept (and clean input is unchanged)."""
    good = h(WORKED["req_power_once"])
    broken = good[:5] + good  # a frame cut short by the next one
    reader = FrameReader()
    assert [f.encode() for f in reader.feed(broken)] == [good]
    assert reader.bad_frames == 1 and reader.stats["bad_crc"] + reader.stats["bad_stx"] == 1
