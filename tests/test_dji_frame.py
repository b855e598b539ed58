"""The DJI OPEN protocol codec (fieldkit.vehicle.dji): the spec's worked frames byte for byte,
the CRCs, AES, the message layouts, and the de-framer on noisy streams."""

from __future__ import annotations

import math
import struct

import pytest

from fieldkit.vehicle.dji import messages as M
from fieldkit.vehicle.dji.crc import crc16, crc32
from fieldkit.vehicle.dji.crypto import AppKeyError, FrameCipher, parse_app_key
from fieldkit.vehicle.dji.frame import (
    Frame,
    FrameError,
    FrameReader,
    ack_frame,
    command_frame,
    decode,
    encode,
)

KEY = "0123456789abcdef" * 4

# ---------------------------------------------------------------------------- spec §13


@pytest.mark.parametrize(
    ("data", "c16", "c32"),
    [
        (b"123456789", 0x2752, 0xE4D9DC14),
        (b"\xaa", 0x06FA, 0x79DCB89E),
        (bytes(4), 0x4902, 0x7622D6AD),
        (b"", 0x3AA3, 0x00003AA3),
    ],
)
def test_crc_vectors(data: bytes, c16: int, c32: int) -> None:
    assert crc16(data) == c16
    assert crc32(data) == c32
    assert crc32(b"123456789") != 0xCBF43926  # not zlib's CRC-32


def test_worked_version_query() -> None:
    want = bytes.fromhex("aa 13 00 02 00 00 00 00 01 00 01 ee 00 00 00 67 1a cc 54")
    assert command_frame(2, 1, 0x00, 0x00, b"\x00") == want
    f = decode(want)
    assert f.describe() == {
        "session": 2, "ack": 0, "seq": 1, "enc": 0, "cmd_set": 0, "cmd_id": 0, "data": "00",
    }  # fmt: skip


def test_worked_obtain_control() -> None:
    want = bytes.fromhex("aa 13 00 02 00 00 00 00 04 00 02 be 01 00 01 13 1a 9c fc")
    assert command_frame(2, 4, *M.CMD_CONTROL, b"\x01") == want
    assert decode(want) == Frame(2, False, 4, b"\x01\x00\x01")


def test_worked_movement_control() -> None:
    want = bytes.fromhex(
        "aa 23 00 00 00 00 00 00 05 00 74 ef 01 03 48 00 00 80 3f 00 00 00 bf"
        " 00 00 80 3e 00 00 20 41 04 72 38 b2"
    )
    value = M.Movement(M.HORI_VEL | M.VERT_VEL | M.YAW_RATE, 1.0, -0.5, 0.25, 10.0).encode()
    assert command_frame(0, 5, *M.CMD_MOVEMENT, value) == want
    m = M.parse_movement(decode(want).value)
    assert (m.flag, m.x, m.y, m.z, m.yaw) == (0x48, 1.0, -0.5, 0.25, 10.0)
    assert m.control_mode == 4  # VEL/VEL/RATE (spec §8.2)


# ---------------------------------------------------------------------------- frames


def test_ack_and_header_only_frames() -> None:
    ack = ack_frame(2, 1, b"\x02\x00")
    assert ack[3] == 0x22 and len(ack) == 18  # session 2 | ACK bit 5
    f = decode(ack)
    assert f.ack and f.value == b"\x02\x00" and f.cmd_set is None
    assert f.describe()["cmd_id"] is None and f.describe()["data"] == "0200"
    bare = encode(0, False, 7, b"")
    assert len(bare) == 12 and bare[1] == 12  # no CRC32 without data
    assert decode(bare) == Frame(0, False, 7, b"")


def test_aes_is_standard_aes256_ecb() -> None:
    # FIPS-197 appendix C.3: an independent check that the cipher is plain AES-256.
    cipher = FrameCipher(bytes(range(32)))
    plain = bytes.fromhex("00112233445566778899aabbccddeeff")
    assert cipher.encrypt(plain).hex() == "8ea2b7ca516745bfeafc49904b496089"
    assert cipher.decrypt(cipher.encrypt(plain * 2)) == plain * 2


@pytest.mark.parametrize(("w", "pad"), [(3, 13), (15, 1), (16, 16), (19, 13)])
def test_encrypted_frames(w: int, pad: int) -> None:
    cipher = FrameCipher.from_app_key(KEY)
    data = bytes(range(1, w + 1))
    raw = encode(3, False, 9, data, cipher=cipher)
    assert len(raw) == 12 + w + pad + 4
    assert raw[4] == pad | 1 << 5  # PADDING, ENC = 1
    body = raw[12:-4]
    assert body != data[: len(body)]
    assert cipher.decrypt(body) == data + bytes(pad)  # zeros for padding
    assert crc32(raw[:-4]) == int.from_bytes(raw[-4:], "little")  # over the ciphertext
    assert decode(raw, cipher) == Frame(3, False, 9, data, enc=True)
    unread = decode(raw)  # no key: the ciphertext, marked unreadable
    assert unread.enc and not unread.readable and unread.cmd_set is None


def test_app_key_checks_never_echo_the_key() -> None:
    assert parse_app_key(KEY.upper()) == bytes.fromhex(KEY)
    with pytest.raises(AppKeyError, match="64 hex digits") as e:
        parse_app_key("deadbeef")
    bad = "z" + KEY[1:]
    with pytest.raises(AppKeyError, match="character 1 is not") as e:
        parse_app_key(bad)
    assert bad not in str(e.value)


@pytest.mark.parametrize(
    ("mutate", "offset", "text"),
    [
        (lambda b: b"\x55" + b[1:], 0, "start of frame 0x55"),
        (lambda b: b[:1] + b"\x0d" + b[2:], 1, "length 13"),
        (lambda b: b[:2] + b"\x04" + b[3:], 2, "header version 1"),
        (lambda b: b[:6] + b"\x01" + b[7:], 6, "reserved header byte"),
        (lambda b: b[:10] + b"\x00\x00" + b[12:], 10, "CRC16 0x0000, the header's is 0xee01"),
        (lambda b: b[:-1] + b"\x00", 15, "CRC32 0x00cc1a67, the frame's is 0x54cc1a67"),
        (lambda b: b[:-2], 17, "truncated"),
        (lambda b: b + b"\xaa", 19, "1 bytes after"),
    ],
)
def test_decode_names_the_first_bad_byte(mutate: object, offset: int, text: str) -> None:
    good = bytes.fromhex("aa 13 00 02 00 00 00 00 01 00 01 ee 00 00 00 67 1a cc 54")
    with pytest.raises(FrameError) as e:
        decode(mutate(good))  # type: ignore[operator]
    assert e.value.offset == offset
    assert text in e.value.what and str(e.value) == f"{e.value.what} at byte {offset}"


# ---------------------------------------------------------------------------- messages


def test_full_broadcast_layout() -> None:
    b = M.Broadcast(
        timestamp=(400, 5, 0),
        quaternion=(1.0, 0.0, 0.0, 0.0),
        acceleration=(0.0, 0.0, 9.75),
        velocity=(1.0, 2.0, 3.0, 1),
        angular_rate=(0.0, 0.0, 0.0),
        position=(0.79, -1.28, 52.5, 2.5, 5),
        magnetometer=(1200, 0, 0),
        rc=(0, 0, 0, 0, M.RC_F, -4545),
        gimbal=(0.0, 0.0, 0.0, 0),
        flight_status=(3,),
        battery=(87,),
        control=(12, 2 | 8),
    )
    value = b.encode()
    assert b.flag == 0x0FFF and len(value) == 2 + 122
    assert len(command_frame(0, 1, *M.PUSH_BROADCAST, value)) == 142
    items = value[2:]
    assert struct.unpack_from("<dd", items, 62) == (0.79, -1.28)  # latitude first
    assert items[118:122] == bytes((3, 87, 12, 10))
    assert M.parse_broadcast(value) == b


def test_broadcast_items_follow_the_flag() -> None:
    value = M.Broadcast(flight_status=(1,), battery=(50,)).encode()
    assert value == b"\x00\x06\x01\x32"
    assert M.parse_broadcast(value).battery == (50,)
    with pytest.raises(ValueError, match="wants item battery"):
        M.parse_broadcast(value[:-1])
    # Reserved bits 12..15: nothing behind them is read.
    assert M.parse_broadcast(b"\x00\xf2\x01").flight_status == (1,)


def test_version_ack_reads_the_m100_firmware() -> None:
    value = M.version_ack_value(M.NO_AUTHORIZATION, serial="041D492163")
    info = M.parse_version_ack(value)
    assert info.code == 0xFF01 and info.crc == 0xA6453AAC and info.serial == "041D492163"
    assert info.hardware == "M100" and info.firmware == (3, 1, 10, 0)
    assert info.firmware_word == M.M100_FIRMWARE == 0x03010A00
    with pytest.raises(ValueError):
        M.parse_version_ack(b"\x00\x00ab")


def test_activation_and_task_values() -> None:
    value = M.activation_value(1234567)
    assert len(value) == 44 and value[4:12] == bytes.fromhex("02000000 000a0103")
    assert M.parse_activation(value) == (1234567, 2, 0x03010A00)
    assert M.frequency_value([1, 2, 3]) == bytes((1, 2, 3)) + bytes(13)
    assert M.code_text(0x0003, M.ACTIVATION_CODES).startswith("0x0003 NEW_DEVICE")
    assert M.code_text(0xFF00, M.CONTROL_CODES).startswith("0xFF00 KEY_ERROR")


def test_yaw_from_the_quaternion() -> None:
    for yaw in (0.0, 0.5, math.pi / 2, -2.0, 3.0):
        assert M.quaternion_yaw(*M.yaw_quaternion(yaw)) == pytest.approx(yaw)


# ---------------------------------------------------------------------------- de-framer


def _frames() -> list[bytes]:
    cipher = FrameCipher.from_app_key(KEY)
    return [
        command_frame(2, 1, 0, 0, b"\x00"),
        ack_frame(2, 1, b"\x00\x00"),
        command_frame(0, 5, *M.CMD_MOVEMENT, bytes(17), cipher=cipher),
        encode(0, False, 9, b""),
        command_frame(0, 2, *M.PUSH_BROADCAST, M.Broadcast(battery=(9,)).encode()),
    ]


def test_reader_takes_a_stream_cut_anywhere() -> None:
    stream = b"".join(_frames())
    want = [decode(f, FrameCipher.from_app_key(KEY)) for f in _frames()]
    for cut in range(len(stream) + 1):
        r = FrameReader(FrameCipher.from_app_key(KEY))
        got = r.feed(stream[:cut]) + r.feed(stream[cut:])
        assert got == want, cut
        assert r.bad_frames == 0 and r.pending == 0
    r = FrameReader(FrameCipher.from_app_key(KEY))
    assert [f for b in stream for f in r.feed(bytes((b,)))] == want


def test_noise_only_costs_counters() -> None:
    frames = _frames()
    noise = b"\xaa\x13\x00\x02\x00\xaa\xaa\x01"
    stream = noise + frames[0] + noise + frames[1] + frames[4]
    r = FrameReader()
    got = r.feed(stream)
    assert [f.seq for f in got] == [1, 1, 2]
    assert r.bad_frames == 2 and r.garbage_bytes == 2 * len(noise)


def test_a_frame_inside_a_broken_one_is_found() -> None:
    inner = command_frame(2, 7, 1, 0, b"\x01")
    outer = bytearray(command_frame(0, 3, *M.PUSH_BROADCAST, bytes(2) + inner + bytes(8)))
    outer[-1] ^= 0xFF  # the outer frame fails its CRC32...
    r = FrameReader()
    got = r.feed(bytes(outer))
    assert [f.seq for f in got] == [7]  # ...the real one inside it is still delivered
    # Its bytes before and after the real frame: two runs of noise.
    assert r.crc_errors == 1 and r.bad_frames == 2


def test_encrypted_without_the_key_is_counted() -> None:
    frames = _frames()
    r = FrameReader()
    assert len(r.feed(b"".join(frames))) == 4
    assert r.undecryptable == 1 and r.bad_frames == 1
