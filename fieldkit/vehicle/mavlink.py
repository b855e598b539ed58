"""MAVLink on a byte stream: our per-link codec, and `FrameReader`, the resynchronising parser.

The bytes on the line are decoded by `FrameReader`: pymavlink's parser, plus a rescan after
each rejected frame. Plain pymavlink drops a whole "frame" when a stray magic byte in line noise
announces one, losing up to 280 bytes of good frames behind it; the rescan recovers them, so
garbage costs only the `bad_frames` counter. Both the autopilot link and the simulated
vehicles parse with it.

`describe_frame` is the inspector's view of one frame (`fieldkit frames decode mavlink`):
every header field, the message's fields as pymavlink decodes them, and for a frame that is
not valid the first bad byte; `deframe` finds the frames of a byte stream with `FrameReader`.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Iterator
from typing import Any

from pymavlink.dialects.v20 import all as mavlink2

from fieldkit.errors import FrameError


def new_codec(sink: Any, source_system: int, source_component: int) -> Any:
    """A MAVLink 2 codec of our own (it parses v1 frames too) that writes through `sink.write`.

    pymavlink picks its codec from process-wide state (the MAVLINK20 variable at import) and
    swaps it when the first v2 byte arrives; a stream that starts with v1 frames and later
    carries v2 would then be lost. A codec of our own per link avoids both problems.
    """
    mav = mavlink2.MAVLink(sink, srcSystem=source_system, srcComponent=source_component)
    mav.robust_parsing = True
    return mav


def adopt_codec(conn: Any, mav: Any) -> None:
    """Make `mav` the codec of the pymavlink connection `conn`, with no protocol switching."""
    conn.mav = mav
    conn.first_byte = False  # no automatic protocol switch: we already speak both
    conn.WIRE_PROTOCOL_VERSION = "2.0"


def use_mavlink2(conn: Any, source_system: int, source_component: int) -> Any:
    """Give a pymavlink connection our own MAVLink 2 codec (see `new_codec`); returns it."""
    mav = new_codec(conn, source_system, source_component)
    adopt_codec(conn, mav)
    return mav


class FrameReader:
    """MAVLink frames out of a byte stream, resynchronising after every rejected frame."""

    def __init__(self, mav: Any) -> None:
        """Decode with `mav`, a pymavlink `MAVLink` codec (robust parsing is switched on)."""
        mav.robust_parsing = True
        self.mav = mav
        self.messages = 0  # frames decoded into known messages
        self.bad_frames = 0  # runs of bytes outside frames, and frames that failed their checks
        self.rejected_frames = 0  # of bad_frames: the frames that failed their checks
        self.unknown_frames = 0  # frames of ids the dialect does not know (no CRC check)

    def feed(self, data: bytes) -> list[Any]:
        """Decode `data` (appended to what came before); returns the good messages in order."""
        mav = self.mav
        out: list[Any] = []
        chunk = data
        while True:
            try:
                m = mav.parse_char(chunk)
            except Exception:  # a hostile frame must not stop the link
                # pymavlink moved past the frame before decoding it: count it and go on.
                self.bad_frames += 1
                self.rejected_frames += 1
                chunk = b""
                continue
            chunk = b""
            if m is None:
                return out
            msg_id = m.get_msgId()
            if msg_id == mavlink2.MAVLINK_MSG_ID_BAD_DATA:
                self.bad_frames += 1
                if not str(m.reason).startswith("Bad prefix"):
                    self.rejected_frames += 1
                    # A stray magic byte made pymavlink swallow the bytes of a "frame": good
                    # frames may start anywhere after that byte, so look again from there.
                    self._rescan(m.get_msgbuf())
            elif msg_id == mavlink2.MAVLINK_MSG_ID_UNKNOWN:
                # No CRC check is possible without the message definition: it may be noise
                # hiding good frames, so rescan its bytes as well.
                self.unknown_frames += 1
                self._rescan(m.get_msgbuf())
            else:
                self.messages += 1
                out.append(m)

    def reset(self) -> None:
        """Forget a partial frame: the line was reopened and its rest will never come (the
        next bytes are another frame's, which the stale half would swallow). Counters stay."""
        mav = self.mav
        mav.buf = bytearray()
        mav.buf_index = 0
        mav.expected_length = mavlink2.HEADER_LEN_V1 + 2
        mav.have_prefix_error = False

    def flush(self) -> list[Any]:
        """End of the stream: the frame pymavlink still waits for will never complete (a
        stray magic byte announced it), so search its bytes but the first again; returns the
        good messages found there. Each abandoned frame counts as rejected."""
        mav = self.mav
        out: list[Any] = []
        while rest := bytes(mav.buf[mav.buf_index :]):
            self.bad_frames += 1
            self.rejected_frames += 1
            mav.buf = bytearray()
            mav.buf_index = 0
            mav.expected_length = mavlink2.HEADER_LEN_V1 + 2
            out += self.feed(rest[1:])
        return out

    def _rescan(self, frame: bytes | bytearray) -> None:
        """Put a rejected frame's bytes, but its first, back in front of the parser."""
        mav = self.mav
        rest = mav.buf[mav.buf_index :]
        mav.buf = bytearray(frame[1:]) + rest
        mav.buf_index = 0
        mav.expected_length = mavlink2.HEADER_LEN_V1 + 2


def _json_value(value: Any) -> Any:
    """A pymavlink field value as JSON: lists kept, bytes as hex, NaN and infinities as
    their names (JSON has no such numbers)."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).hex()
    if isinstance(value, list):
        return [_json_value(v) for v in value]
    return value


def describe_frame(frame: bytes) -> dict[str, Any]:
    """The fields of exactly one MAVLink 1 or 2 frame, as JSON values.

    Keys: magic, version, len, incompat_flags and compat_flags (version 2), seq, sysid,
    compid, msgid, name, fields (name: value as pymavlink decodes them), crc, and signature
    ({link_id, timestamp, value}) when the frame is signed (not verified: that needs the
    key). FrameError names the first bad byte: the magic, an unknown incompat flag, the
    frame's end against its length field, an id the dialect does not know (its CRC cannot
    be checked), the CRC's first byte when it does not match.
    """
    frame = bytes(frame)
    n = len(frame)
    if n == 0:
        raise FrameError("empty frame", 0)
    magic = frame[0]
    if magic == mavlink2.PROTOCOL_MARKER_V2:
        version, head = 2, mavlink2.HEADER_LEN_V2
    elif magic == mavlink2.PROTOCOL_MARKER_V1:
        version, head = 1, mavlink2.HEADER_LEN_V1
    else:
        raise FrameError(f"0x{magic:02x} is not a MAVLink magic (0xfd v2, 0xfe v1)", 0)
    if n < head:
        raise FrameError(f"the frame ends inside its {head}-byte MAVLink {version} header", n)
    length = frame[1]
    out: dict[str, Any] = {"magic": magic, "version": version, "len": length}
    signature = 0
    if version == 2:
        incompat, compat = frame[2], frame[3]
        if incompat & ~mavlink2.MAVLINK_IFLAG_SIGNED:
            raise FrameError(f"incompat_flags 0x{incompat:02x}: unknown flags", 2)
        if incompat & mavlink2.MAVLINK_IFLAG_SIGNED:
            signature = mavlink2.MAVLINK_SIGNATURE_BLOCK_LEN
        out["incompat_flags"], out["compat_flags"] = incompat, compat
        seq, sysid, compid = frame[4:7]
        msgid, msgid_at = int.from_bytes(frame[7:10], "little"), 7
    else:
        seq, sysid, compid, msgid = frame[2:6]
        msgid_at = 5
    crc_at = head + length
    total = crc_at + 2 + signature
    if n < total:
        raise FrameError(f"truncated: len {length} makes a {total}-byte frame", n)
    if n > total:
        raise FrameError(f"{n - total} bytes after the frame's end (len {length})", total)
    kind = mavlink2.mavlink_map.get(msgid)
    if kind is None:
        raise FrameError(f"message id {msgid} is not in the dialect: no CRC to check", msgid_at)
    crc = int.from_bytes(frame[crc_at : crc_at + 2], "little")
    want = mavlink2.x25crc(frame[1:crc_at] + bytes((kind.crc_extra,))).crc
    if crc != want:
        raise FrameError(f"CRC 0x{crc:04x}, {kind.msgname}'s is 0x{want:04x}", crc_at)
    try:
        message = new_codec(None, 255, 0).decode(bytearray(frame))
    except mavlink2.MAVError as e:  # checked above: only a dialect pymavlink cannot unpack
        raise FrameError(f"pymavlink cannot decode the payload: {e}", head) from None
    fields = message.to_dict()
    del fields["mavpackettype"]
    out.update(
        seq=seq,
        sysid=sysid,
        compid=compid,
        msgid=msgid,
        name=kind.msgname,
        fields={k: _json_value(v) for k, v in fields.items()},
        crc=crc,
    )
    if signature:
        block = frame[crc_at + 2 :]
        out["signature"] = {
            "link_id": block[0],
            "timestamp": int.from_bytes(block[1:7], "little"),
            "value": block[7:].hex(),
        }
    return out


def deframe(chunks: Iterable[bytes], stats: Counter[str]) -> Iterator[bytes]:
    """Every good frame of a byte stream, as its bytes, found by `FrameReader` (resynchronising
    after each rejected frame; the end of `chunks` is the end of the stream, flushed);
    stats["bad_frames"] counts the frames rejected on the way (a failed check, an id the
    dialect does not know, a frame the stream ended inside), not the runs of noise."""
    reader = FrameReader(new_codec(None, 255, 0))
    seen = 0
    pending = iter(chunks)
    while True:
        chunk = next(pending, None)
        messages = reader.flush() if chunk is None else reader.feed(chunk)
        now = reader.rejected_frames + reader.unknown_frames
        stats["bad_frames"] += now - seen
        seen = now
        for m in messages:
            yield bytes(m.get_msgbuf())
        if chunk is None:
            return
