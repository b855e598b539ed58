"""`fieldkit frames decode`: the protocol inspector (fieldkit.frames) on every registered codec.

Good frames come from the specs and docs (the docs/bundle.md worked example, the NMEA vectors
of ../shared/spec/clearpath-husky.md §11, its worked MCU frames of §10, the DJI worked frames
of ../shared/spec/dji-osdk-m100.md §13) or from the codecs themselves; each is decoded
through the command line, changed by one byte (the error names the byte), fed as a noisy
stream, and fuzzed: whatever the bytes, a JSON object or a FrameError inside the frame.
"""

from __future__ import annotations

import io
import json
import math
import subprocess
import sys
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from fieldkit import frames
from fieldkit.cli import app
from fieldkit.errors import FrameError
from fieldkit.radio import xbee as X
from fieldkit.radio import xbeemav as M
from fieldkit.robot import bundle as B
from fieldkit.vehicle.clearpath import frame as CP
from fieldkit.vehicle.dji import frame as DJI
from fieldkit.vehicle.dji.crc import crc16, crc32
from fieldkit.vehicle.dji.crypto import FrameCipher, parse_app_key
from fieldkit.vehicle.mavlink import new_codec
from fieldkit.vehicle.sim.dji import TEST_APP_KEY

runner = CliRunner()

# docs/bundle.md#worked-example: robot 7, number 1, BROADCAST "cmd" = 22 and JOIN 3, at
# 45.5, -73.6, 10.0 m, its time bytes zero here. The XBee RF data, as the page writes it:
WORKED_RF = bytes.fromhex(
    "53 07 01  00 00 00 00 00 01 00 02  00 00 00 00 00 00 00 00  40 46 c0 00 00 00 00 00"
    "c0 52 66 66 66 66 66 66  40 24 00 00 00 00 00 00  03 00 00 0c 00 07 00 03"
    "00 00 01 64 6d 63 03 00  00 03 00 04 00 03 16 00"
)
WORKED_AIR = WORKED_RF[3:]
WORKED_FRAME = X.transmit_request(WORKED_RF)
# ../shared/spec/dji-osdk-m100.md §13.2-13.4: version query, obtain control, movement.
DJI_VERSION = bytes.fromhex("aa 13 00 02 00 00 00 00 01 00 01 ee 00 00 00 67 1a cc 54")
DJI_CONTROL = bytes.fromhex("aa 13 00 02 00 00 00 00 04 00 02 be 01 00 01 13 1a 9c fc")
DJI_MOVEMENT = bytes.fromhex(
    "aa 23 00 00 00 00 00 00 05 00 74 ef 01 03 48 00 00 80 3f 00 00 00 bf"
    "00 00 80 3e 00 00 20 41 04 72 38 b2"
)
# ../shared/spec/clearpath-husky.md §10: encoder data, a drive order, its acknowledgement.
HUSKY_ENCODERS = bytes.fromhex(
    "AA 18 E7 00 40 E2 01 00 00 00 88 55 02 39 30 00 00 0C FE FF FF F4 01 06 FF 19 4F"
)
HUSKY_DRIVE = bytes.fromhex("AA 13 EC 00 00 00 00 00 00 00 02 55 32 00 32 00 F4 01 F4 01 8F 53")
HUSKY_ACK = bytes.fromhex("AA 0D F2 00 4E E2 01 00 00 00 02 55 00 00 86 C8")
GGA = "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47"
VTG = "$GPVTG,054.7,T,034.4,M,005.5,N,010.2,K*48"


def _heartbeat(**kw: Any) -> bytes:
    """A HEARTBEAT frame as the autopilot link's codec packs it."""
    mav = new_codec(io.BytesIO(), 1, 1)
    return bytes(mav.heartbeat_encode(2, 3, 81, 4, 4).pack(mav, **kw))


HEARTBEAT = _heartbeat()


def test_the_worked_example_is_what_the_codecs_build() -> None:
    """The constants above are the docs' bytes and the codecs' bytes at once."""
    example = B.Bundle(
        7, (bytes.fromhex("00030003636d640100000016"), bytes.fromhex("040003")), 45.5, -73.6,
        10.0, number=1,
    )  # fmt: skip
    assert B.to_rf_data(example) == WORKED_RF
    assert WORKED_FRAME[:17].hex(" ") == "7e 00 51 10 01 00 00 00 00 00 00 ff ff ff ff 00 00"
    assert HEARTBEAT.hex(" ") == "fd 09 00 00 00 01 01 00 00 00 04 00 00 00 02 03 51 04 03 7b ae"


# protocol: (a good frame as typed, fields it must decode to, a byte to change, where the
# error then points: the changed byte, or the checksum that catches it)
GOOD: dict[str, tuple[str, dict[str, Any], int, int]] = {
    "mavlink": (
        HEARTBEAT.hex(" "),
        {
            "magic": 0xFD, "version": 2, "len": 9, "incompat_flags": 0, "compat_flags": 0,
            "seq": 0, "sysid": 1, "compid": 1, "msgid": 0, "name": "HEARTBEAT", "crc": 0xAE7B,
            "fields": {
                "type": 2, "autopilot": 3, "base_mode": 81, "custom_mode": 4,
                "system_status": 4, "mavlink_version": 3,
            },
        },
        12, 19,  # a payload byte: the CRC at 10 + 9 fails
    ),
    "xbee": (
        WORKED_FRAME.hex(":"),
        {
            "api_mode": 1, "length": 0x51, "frame_type": 0x10, "name": "transmit_request",
            "frame_id": 1, "dest64": "000000000000ffff", "dest16": "ffff", "radius": 0,
            "options": 0, "rf_data": WORKED_RF.hex(), "checksum": WORKED_FRAME[-1],
        },
        40, 84,  # an RF data byte: the checksum, the 85th byte, fails
    ),
    "xbeemav": (
        WORKED_RF.hex(),
        {
            "type": "S", "sysid": 7, "msgid": 1,
            "payload64": [
                "0000000000010002", "0000000000000000", "4046c00000000000",
                "c052666666666666", "4024000000000000", "0300000c00070003",
                "000001646d630300", "0003000400031600",
            ],
        },
        0, 0,  # the packet type
    ),
    "bundle": (
        WORKED_AIR.hex(" "),
        {
            "robot": 7, "number": 1, "time_ns": 0, "lat": 45.5, "lon": -73.6, "alt": 10.0,
            "messages": [
                {"hex": "00030003636d640100000016", "type": "BROADCAST"},
                {"hex": "040003", "type": "SWARM_JOIN"},
            ],
        },
        7, 7,  # word 0's low byte on the air: the message type, 2
    ),
    "nmea": (
        GGA,
        {
            "talker": "GP", "sentence_type": "GGA", "checksum": 0x47,
            "latitude": pytest.approx(48.1173), "longitude": pytest.approx(11.516667),
        },
        20, GGA.index("*"),  # a digit of the longitude: the checksum after '*' fails
    ),
    "dji": (
        DJI_VERSION.hex(" "),
        {"session": 2, "ack": 0, "seq": 1, "enc": 0, "cmd_set": 0, "cmd_id": 0, "data": "00"},
        13, 15,  # CMD ID: the CRC32 at 19 - 4 fails
    ),
    "clearpath": (
        HUSKY_ENCODERS.hex(" "),
        {
            "type": "0x8800", "name": "ENCODERS", "flags": 0, "timestamp": 123456,
            "payload": {"travel": [12.345, -0.5], "speed": [0.5, -0.25]},
        },
        13, 25,  # a travel byte: the CRC at 27 - 2 fails
    ),
}  # fmt: skip


def _decode(*args: str, stdin: bytes | None = None) -> Any:
    return runner.invoke(app, ["frames", "decode", *args], input=stdin)


def _objects(stdout: str) -> list[dict[str, Any]]:
    lines = stdout.splitlines()
    return [json.loads(line) for line in lines]


def _changed(text: str, protocol: str, at: int) -> str:
    """The frame `text` with its byte `at` changed, typed the same way."""
    if protocol == "nmea":
        c = text[at]
        return text[:at] + ("7" if c != "7" else "8") + text[at + 1 :]
    data = bytearray(bytes.fromhex(text.replace(":", "").replace(" ", "")))
    data[at] ^= 0x01
    return data.hex()


def test_every_registered_protocol_is_tested() -> None:
    assert set(GOOD) == set(frames.names())


@pytest.mark.parametrize("protocol", list(GOOD))
def test_a_known_frame_decodes_to_its_fields(protocol: str) -> None:
    text, fields, _, _ = GOOD[protocol]
    result = _decode(protocol, text)
    assert result.exit_code == 0, result.output
    [described] = _objects(result.stdout)
    assert {k: described[k] for k in fields} == fields
    json.dumps(described, allow_nan=False)  # strict JSON


@pytest.mark.parametrize("protocol", list(GOOD))
def test_one_byte_changed_names_that_byte_or_its_checksum(protocol: str) -> None:
    """Frame 2 is bad: frame 1 is still printed, the error names frame 2 and the byte."""
    text, _, at, offset = GOOD[protocol]
    result = _decode(protocol, text, _changed(text, protocol, at), text)
    assert result.exit_code == 1, result.output
    assert len(_objects(result.stdout)) == 1
    [line] = [x for x in result.stderr.splitlines() if x.startswith("error: ")]
    assert line.startswith("error: frame 2: ") and line.endswith(f" at byte {offset}"), line
    assert "Traceback" not in result.output


def test_mavlink_v1_and_signed_frames() -> None:
    mav = new_codec(io.BytesIO(), 3, 4)
    v1 = mav.global_position_int_encode(1, 2, 3, 4, 5, 6, 7, 8, 9).pack(mav, force_mavlink1=True)
    mav.signing.secret_key = bytes(32)
    mav.signing.link_id, mav.signing.timestamp, mav.signing.sign_outgoing = 5, 1234, True
    signed = mav.attitude_encode(1, math.nan, 0.5, 0, 0, 0, 0).pack(mav)
    result = _decode("mavlink", v1.hex(), signed.hex())
    assert result.exit_code == 0, result.output
    one, two = _objects(result.stdout)
    assert (one["magic"], one["version"], one["name"], one["sysid"]) == (
        0xFE,
        1,
        "GLOBAL_POSITION_INT",
        3,
    )
    assert "incompat_flags" not in one and one["fields"]["hdg"] == 9
    assert two["incompat_flags"] == 1 and two["signature"]["link_id"] == 5
    assert two["signature"]["timestamp"] == 1234 and len(two["signature"]["value"]) == 12
    assert two["fields"]["roll"] == "nan"  # JSON has no NaN: pymavlink's value by name


@pytest.mark.parametrize(
    ("frame", "offset", "what"),
    [
        (b"\x00" + HEARTBEAT[1:], 0, "magic"),
        (HEARTBEAT[:15], 15, "truncated"),
        (HEARTBEAT + b"\x00", len(HEARTBEAT), "after the frame"),
        (HEARTBEAT[:7] + b"\xff\xff\xff" + HEARTBEAT[10:], 7, "not in the dialect"),
        (HEARTBEAT[:2] + b"\x80" + HEARTBEAT[3:], 2, "incompat_flags"),
    ],
)
def test_mavlink_layout_errors(frame: bytes, offset: int, what: str) -> None:
    with pytest.raises(FrameError, match=what) as e:
        frames.PROTOCOLS["mavlink"].describe(frame, frames.Options())
    assert e.value.offset == offset


def test_xbee_api_mode_2_frames_unescape_and_name_raw_bytes() -> None:
    """Escaped bytes count as on the wire: the checksum is named where it really is."""
    frame = X.receive_packet(0x0013A20040000011, b"\x7e\x7d\x11\x13ok", api_mode=2)
    result = _decode("xbee", "--api-mode", "2", frame.hex())
    assert result.exit_code == 0, result.output
    [d] = _objects(result.stdout)
    assert d["name"] == "receive_packet" and d["source64"] == "0013a20040000011"
    assert d["rf_data"] == "7e7d11136f6b" and d["api_mode"] == 2
    bad = bytearray(frame)
    bad[-2] ^= 1  # the last RF byte, 'k'
    result = _decode("xbee", "--api-mode", "2", bad.hex())
    assert result.exit_code == 1
    assert result.stderr.strip().endswith(f"at byte {len(frame) - 1}"), result.stderr
    # The same bytes in API mode 1 are a different, valid-length but mis-summed frame.
    assert _decode("xbee", frame.hex()).exit_code == 1


def test_xbee_knows_status_and_at_frames() -> None:
    status = X.TransmitStatus(1, delivery_status=0x21).encode()
    at_cmd = X.frame_bytes(bytes((X.AT_QUEUE, 1)) + b"SL")
    unknown = X.frame_bytes(b"\x95\x01\x02")
    result = _decode("xbee", status.hex(), at_cmd.hex(), unknown.hex())
    assert result.exit_code == 0, result.output
    s, a, u = _objects(result.stdout)
    assert s["name"] == "transmit_status" and s["delivery_status"] == 0x21
    assert (a["name"], a["command"], a["parameter"]) == ("at_command_queue", "SL", "")
    assert (u["name"], u["frame_type"], u["data"]) == (None, 0x95, "0102")


def test_xbeemav_fragments_pings_acks_and_whole_frames() -> None:
    engine = M.XbeeMav(5, interframe_s=0)
    engine.submit(bytes(8 * 40), 0x42)
    fragment, _, ping = engine.pump()
    ack = b"A\x42\x09\x01"
    framed = X.receive_packet(0x0013A20040000009, ack)
    result = _decode("xbeemav", fragment.hex(), ping.hex(), framed.hex())
    assert result.exit_code == 0, result.output
    f, p, a = _objects(result.stdout)
    assert (f["type"], f["packet_id"], f["address"], f["index"], f["offset"]) == (
        "F",
        0x42,
        5,
        0,
        0,
    )
    assert len(f["data"]) == 2 * 250
    assert (p["type"], p["count"]) == ("P", 2)
    assert (a["type"], a["address"], a["missing"]) == ("A", 9, [1])
    assert a["xbee"]["name"] == "receive_packet"
    # A ping for 0 fragments inside a frame: the count byte, counted in the frame.
    bad = X.receive_packet(9, b"P\x42\x09\x00")
    result = _decode("xbeemav", bad.hex())
    assert result.exit_code == 1 and result.stderr.strip().endswith("at byte 18")


def test_bundle_as_rf_data_and_as_an_xbee_frame() -> None:
    """The changed type byte is named in each wrapping: air 7, RF data 10, frame 27."""
    result = _decode("bundle", WORKED_RF.hex(), WORKED_FRAME.hex())
    assert result.exit_code == 0, result.output
    rf, framed = _objects(result.stdout)
    assert rf["sysid"] == 7 and rf["msgid"] == 1 and rf["lat"] == 45.5
    assert framed["xbee"]["frame_type"] == 0x10 and framed["messages"] == rf["messages"]
    for data, offset in ((WORKED_RF, 10), (WORKED_FRAME, 27)):
        bad = bytearray(data)
        bad[offset] = 3
        if data is WORKED_FRAME:
            bad[-1] = X.checksum(bytes(bad[3:-1]))  # a valid frame with a bad bundle
        result = _decode("bundle", bad.hex())
        assert result.exit_code == 1
        assert result.stderr.strip().endswith(
            f"message type 3, not BUZZ_MESSAGE (2) at byte {offset}"
        )


def test_bundle_messages_that_are_not_buzz_are_shown_as_such() -> None:
    air = B.encode(B.Bundle(2, (b"\x09\x00",), 1.0, 2.0, 3.0))
    result = _decode("bundle", air.hex())
    assert result.exit_code == 0, result.output
    [d] = _objects(result.stdout)
    assert (
        d["messages"][0]["type"] is None and "unknown message type 9" in d["messages"][0]["error"]
    )


def test_nmea_takes_text_or_hex_and_names_the_star() -> None:
    result = _decode("nmea", VTG, (VTG + "\r\n").encode().hex(" "))
    assert result.exit_code == 0, result.output
    text, hexed = _objects(result.stdout)
    assert text == hexed and text["fields"]["true_track"] == 54.7
    bad = VTG[:-1] + "9"
    result = _decode("nmea", bad)
    assert result.exit_code == 1
    assert result.stderr.strip().endswith(f"at byte {VTG.index('*')}"), result.stderr
    result = _decode("nmea", "$GPGGA,1")
    assert result.exit_code == 1 and "no checksum" in result.stderr


def _encrypted() -> bytes:
    """An obtain-control command encrypted with the simulator's test app key."""
    cipher = FrameCipher.from_app_key(TEST_APP_KEY)
    return DJI.command_frame(2, 9, 0x01, 0x00, b"\x01", cipher=cipher)


def test_dji_worked_frames_and_an_ack() -> None:
    ack = DJI.ack_frame(2, 4, b"\x02\x00")
    result = _decode("dji", DJI_CONTROL.hex(), DJI_MOVEMENT.hex(":"), ack.hex())
    assert result.exit_code == 0, result.output
    control, movement, a = _objects(result.stdout)
    assert (control["cmd_set"], control["cmd_id"], control["data"], control["seq"]) == (
        1,
        0,
        "01",
        4,
    )
    assert movement["session"] == 0 and movement["data"] == "480000803f000000bf0000803e00002041"
    assert (a["ack"], a["cmd_set"], a["data"]) == (1, None, "0200")
    assert "decrypted" not in control


@pytest.mark.parametrize(
    ("frame", "offset", "what"),
    [
        (DJI_VERSION[:1] + b"\x13\x04" + DJI_VERSION[3:], 2, "header version 1"),
        (DJI_VERSION[:10] + b"\x00\x00" + DJI_VERSION[12:], 10, "CRC16 0x0000"),
        (DJI_VERSION[:-2], 17, "truncated"),
        (DJI_VERSION[:5], 5, "12-byte header"),
    ],
)
def test_dji_layout_errors(frame: bytes, offset: int, what: str) -> None:
    result = _decode("dji", frame.hex())
    assert result.exit_code == 1
    assert what in result.stderr and result.stderr.strip().endswith(f"at byte {offset}")


def test_dji_encrypted_frames_show_ciphertext_unless_the_key_is_given(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    frame = _encrypted()
    result = _decode("dji", frame.hex())
    assert result.exit_code == 0, result.output
    [d] = _objects(result.stdout)
    assert (d["enc"], d["decrypted"], d["cmd_set"]) == (1, False, None)
    assert d["data"] == frame[12:-4].hex()  # the ciphertext, a whole AES block
    result = _decode("dji", "--app-key", TEST_APP_KEY, frame.hex())
    [d] = _objects(result.stdout)
    assert (d["decrypted"], d["cmd_set"], d["cmd_id"], d["data"]) == (True, 1, 0, "01")
    assert TEST_APP_KEY not in result.output
    # A stream shows the encrypted frame too, as its argument does.
    result = _decode("dji", "--stdin", stdin=b"\x00" + frame + DJI_VERSION)
    assert [x["enc"] for x in _objects(result.stdout)] == [1, 0]
    monkeypatch.setenv("FIELDKIT_DJI_APP_KEY", TEST_APP_KEY.upper())
    result = _decode("dji", frame.hex())
    assert _objects(result.stdout)[0]["decrypted"] is True
    assert TEST_APP_KEY.upper() not in repr(frames.Options(app_key=bytes(32)))
    assert bytes(32).hex() not in repr(frames.Options(app_key=bytes(32)))


def test_dji_app_key_errors_never_repeat_the_key(monkeypatch: pytest.MonkeyPatch) -> None:
    bad = TEST_APP_KEY[:-1] + "g"
    result = _decode("dji", "--app-key", bad, DJI_VERSION.hex())
    assert result.exit_code == 2 and "--app-key:" in result.stderr and bad not in result.output
    result = _decode("clearpath", "--app-key", TEST_APP_KEY, HUSKY_ACK.hex())
    assert result.exit_code == 2 and "--app-key applies to dji" in result.stderr
    monkeypatch.setenv("FIELDKIT_DJI_APP_KEY", "abc")
    result = _decode("dji", DJI_VERSION.hex())
    assert result.exit_code == 1 and "FIELDKIT_DJI_APP_KEY: " in result.stderr
    assert _decode("clearpath", HUSKY_ACK.hex()).exit_code == 0  # not read for clearpath


def test_clearpath_payloads_by_type_raw_hex_beside() -> None:
    unknown = CP.Frame(0x8123, b"\x01\x02", timestamp=7).encode()
    malformed = CP.Frame(0x8800, b"\x02\x00").encode()  # 2 encoders announced, none sent
    result = _decode(
        "clearpath", HUSKY_DRIVE.hex(), HUSKY_ACK.hex(), unknown.hex(), malformed.hex()
    )
    assert result.exit_code == 0, result.output
    drive, ack, u, m = _objects(result.stdout)
    assert drive["name"] == "SET_DIFF_SPEED" and drive["payload"]["left_accel"] == 5.0
    assert ack["payload"]["accepted"] is True and ack["timestamp"] == 0x0001E24E
    assert (u["type"], u["name"], u["payload"], u["payload_hex"]) == (
        "0x8123",
        "0x8123",
        None,
        "0102",
    )
    assert m["payload"] is None and "encoders" in m["error"] and m["payload_hex"] == "0200"


@pytest.mark.parametrize(
    ("frame", "offset", "what"),
    [
        (HUSKY_ACK[:2] + b"\x00" + HUSKY_ACK[3:], 2, "complement of LEN"),
        (HUSKY_ACK[:11] + b"\x54" + HUSKY_ACK[12:], 11, "STX"),
        (HUSKY_ACK[:-3], 13, "truncated"),
        (HUSKY_ACK + b"\xaa", 16, "after the frame's end"),
    ],
)
def test_clearpath_layout_errors(frame: bytes, offset: int, what: str) -> None:
    result = _decode("clearpath", frame.hex())
    assert result.exit_code == 1
    assert what in result.stderr and result.stderr.strip().endswith(f"at byte {offset}")


@pytest.mark.parametrize("protocol", ["dji", "clearpath"])
def test_stdin_resyncs_inside_a_broken_frame(protocol: str) -> None:
    """A frame cut short by the next one, and one the stream ends inside, are bad frames;
    the frame that starts inside the broken one is found."""
    one, two, three = STREAMS[protocol]
    stream = one[:-3] + two + b"\xaa\xaa" + three + one[:14]
    result = _decode(protocol, "--stdin", stdin=stream)
    assert result.exit_code == 0, result.output
    assert _objects(result.stdout) == [
        _objects(_decode(protocol, f.hex()).stdout)[0] for f in (two, three)
    ]
    garbage = len(stream) - len(two) - len(three)
    assert result.stderr.strip().endswith(f" bad, {garbage} garbage bytes")
    bad = int(result.stderr.split(" frames, ")[1].split(" bad")[0])
    assert bad >= 2, result.stderr  # the cut frame and the unfinished one at least


# ------------------------------------------------------------------ the command line


@pytest.mark.parametrize(
    ("args", "text"),
    [
        (["dji2", "00"], "unknown protocol 'dji2'"),
        (["mavlink", "fd 0x"], "frame 1: 'fd 0x' is not hex"),
        (["xbee", "7e0"], "is not hex"),
        (["mavlink", HEARTBEAT.hex(), ":"], "frame 2 is empty"),
        (["mavlink"], "or --stdin"),
        (["mavlink", "--stdin", "00"], "not both"),
        (["mavlink", "--api-mode", "2", "00"], "--api-mode"),
        (["xbee", "--api-mode", "3", "00"], "--api-mode"),
    ],
)
def test_a_command_line_that_does_not_parse_exits_2(args: list[str], text: str) -> None:
    result = _decode(*args)
    assert result.exit_code == 2, result.output
    [line] = [x for x in result.stderr.splitlines() if x.startswith("error: ")]
    assert text in line, line
    assert result.stdout == ""


def _noisy(frames_: list[bytes]) -> bytes:
    """The frames with noise around and between them: bytes that look like frame starts."""
    noise = [b"\x00\xfd\x7e\x05", b"$GP\xfe\x7e", b"\xff" * 9, b"\x7e\x00\x03\x10"]
    out = b"zz"
    for i, f in enumerate(frames_):
        out += f + noise[i % len(noise)]
    return out


STREAMS: dict[str, list[bytes]] = {
    "mavlink": [HEARTBEAT, _heartbeat(force_mavlink1=True), HEARTBEAT],
    "xbee": [WORKED_FRAME, X.ModemStatus(0).encode(), X.TransmitStatus(1).encode()],
    "xbeemav": [X.receive_packet(7, WORKED_RF), X.receive_packet(8, b"A\x01\x08")],
    "bundle": [X.receive_packet(7, WORKED_RF), WORKED_FRAME],
    "nmea": [f"{GGA}\r\n".encode(), f"{VTG}\r\n".encode(), f"{GGA}\r\n".encode()],
    "dji": [DJI_VERSION, DJI_CONTROL, DJI_MOVEMENT],
    "clearpath": [HUSKY_ENCODERS, HUSKY_DRIVE, HUSKY_ACK],
}


@pytest.mark.parametrize("protocol", list(STREAMS))
def test_stdin_resyncs_over_garbage(protocol: str) -> None:
    good = STREAMS[protocol]
    stream = _noisy(good)
    result = _decode(protocol, "--stdin", stdin=stream)
    assert result.exit_code == 0, result.output
    found = _objects(result.stdout)
    one_by_one = [_objects(_decode(protocol, f.hex()).stdout)[0] for f in good]
    assert found == one_by_one
    summary = result.stderr.strip().splitlines()[-1]
    garbage = len(stream) - sum(map(len, good))
    assert summary.startswith(f"{len(good)} frames, ") and summary.endswith(
        f", {garbage} garbage bytes"
    ), summary


def test_stdin_with_no_frame_fails_after_its_summary() -> None:
    result = _decode("xbee", "--stdin", stdin=b"no frames here")
    assert result.exit_code == 1
    assert result.stderr.splitlines() == [
        "0 frames, 0 bad, 14 garbage bytes",
        "error: stdin: no xbee frame in 14 bytes (another protocol, API mode or baud rate?)",
    ]
    assert _decode("mavlink", "--stdin", stdin=b"").exit_code == 1


def test_stdin_counts_bad_frames() -> None:
    bad = bytearray(HEARTBEAT)
    bad[12] ^= 1
    result = _decode("mavlink", "--stdin", stdin=HEARTBEAT + bytes(bad) + HEARTBEAT)
    assert result.exit_code == 0
    assert result.stderr.strip() == f"2 frames, 1 bad, {len(bad)} garbage bytes"


def test_a_real_pipe_into_the_console_script() -> None:
    """stdin as a shell gives it (a pipe, read as it comes), not the test runner's buffer."""
    stream = _noisy(STREAMS["xbeemav"])
    proc = subprocess.run(
        [sys.executable, "-m", "fieldkit", "frames", "decode", "xbeemav", "--stdin"],
        input=stream, capture_output=True, check=False, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert [d["type"] for d in _objects(proc.stdout.decode())] == ["S", "A"]
    assert proc.stderr.decode().endswith(" garbage bytes\n")


def test_frames_split_across_reads_are_found_whole() -> None:
    """Frames split across reads are found whole (the de-framers keep partial frames)."""
    counts = frames.StreamCounts()
    data = _noisy(STREAMS["xbee"])
    pieces = [data[i : i + 3] for i in range(0, len(data), 3)]
    found = list(frames.decode_stream(frames.PROTOCOLS["xbee"], pieces, frames.Options(), counts))
    assert len(found) == counts.frames == 3 and counts.bytes_in == len(data)


# ------------------------------------------------------------------ fuzz


def _good_bytes(protocol: str) -> bytes:
    text = GOOD[protocol][0]
    return (
        text.encode()
        if protocol == "nmea"
        else bytes.fromhex(text.replace(":", "").replace(" ", ""))
    )


@st.composite
def _frames(draw: st.DrawFn, protocol: str) -> bytes:
    """Random bytes, or the good frame mutated: flipped, cut, grown, spliced."""
    if draw(st.booleans()):
        return draw(st.binary(max_size=300))
    data = bytearray(_good_bytes(protocol))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "cut", "grow", "set"]))
        at = draw(st.integers(0, max(0, len(data) - 1)))
        if op == "flip" and data:
            data[at] ^= 1 << draw(st.integers(0, 7))
        elif op == "cut":
            del data[at : at + draw(st.integers(1, 8))]
        elif op == "grow":
            data[at:at] = draw(st.binary(min_size=1, max_size=8))
        elif data:
            data[at] = draw(st.sampled_from([0x00, 0x7E, 0x7D, 0xFD, 0xFE, 0xFF, 0x24, 0x2A]))
    return bytes(data)


def _check_any_bytes(protocol: str, data: bytes, api_mode: int = 1) -> None:
    try:
        described = frames.PROTOCOLS[protocol].describe(data, frames.Options(api_mode))
    except FrameError as e:
        assert 0 <= e.offset <= len(data), (e, len(data))
        return
    json.dumps(described, allow_nan=False)


@pytest.mark.parametrize("protocol", list(GOOD))
@settings(max_examples=300, deadline=None)
@given(data=st.data())
def test_fuzz_any_bytes_give_json_or_a_frame_error(protocol: str, data: st.DataObject) -> None:
    frame = data.draw(_frames(protocol))
    _check_any_bytes(protocol, frame)
    if frames.PROTOCOLS[protocol].api_mode:
        _check_any_bytes(protocol, frame, 2)


@pytest.mark.parametrize("protocol", list(GOOD))
@settings(max_examples=60, deadline=None)
@given(noise=st.lists(st.binary(max_size=40), max_size=6))
def test_fuzz_streams_never_raise(protocol: str, noise: list[bytes]) -> None:
    good = STREAMS[protocol]
    chunks = [c for pair in zip(noise, good + good, strict=False) for c in pair]
    counts = frames.StreamCounts()
    found = list(frames.decode_stream(frames.PROTOCOLS[protocol], chunks, frames.Options(), counts))
    assert counts.frames == len(found) and 0 <= counts.garbage_bytes <= counts.bytes_in


@settings(max_examples=300, deadline=None)
@given(data=st.data())
def test_fuzz_encrypted_dji_frames_with_and_without_the_key(data: st.DataObject) -> None:
    """The decrypting path too: mutated encrypted frames, with the key and without."""
    frame = bytearray(_encrypted())
    for _ in range(data.draw(st.integers(1, 3))):
        at = data.draw(st.integers(0, len(frame) - 1))
        frame[at] = data.draw(st.integers(0, 255))
    if data.draw(st.booleans()):  # good CRCs: the checks behind them (ENC, padding) run
        frame[10:12] = crc16(bytes(frame[:10])).to_bytes(2, "little")
        frame[-4:] = crc32(bytes(frame[:-4])).to_bytes(4, "little")
    key = parse_app_key(TEST_APP_KEY)
    for options in (frames.Options(), frames.Options(app_key=key)):
        try:
            described = frames.PROTOCOLS["dji"].describe(bytes(frame), options)
        except FrameError as e:
            assert 0 <= e.offset <= len(frame)
        else:
            json.dumps(described, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(rf=st.one_of(st.binary(max_size=20), st.binary(min_size=250, max_size=260)))
def test_xbeemav_describe_refuses_exactly_what_receive_counts_bad(rf: bytes) -> None:
    """describe_packet mirrors XbeeMav.receive's checks: they must not drift apart."""
    engine = M.XbeeMav(1)
    engine.receive(2, rf)
    bad = ("bad_packets", "bad_fragments", "bad_pings", "bad_acks", "unknown_packets",
           "empty_packets")  # fmt: skip
    counted = any(engine.stats[k] for k in bad)
    try:
        M.describe_packet(rf)
    except FrameError:
        assert counted
    else:
        assert not counted


def test_stream_counts_add_up() -> None:
    counts = frames.StreamCounts(frames=2, bad=1, bytes_in=50, frame_bytes=40)
    assert counts.summary() == "2 frames, 1 bad, 10 garbage bytes"
