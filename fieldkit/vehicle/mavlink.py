"""MAVLink on a byte stream: our per-link codec, and `FrameReader`, the resynchronising parser.

The bytes on the line are decoded by `FrameReader`: pymavlink's parser, plus a rescan after
each rejected frame. Plain pymavlink drops a whole "frame" when a stray magic byte in line noise
announces one, losing up to 280 bytes of good frames behind it; the rescan recovers them, so
garbage costs only the `bad_frames` counter. Both the autopilot link and the simulated
vehicles parse with it.
"""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v20 import all as mavlink2


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
                chunk = b""
                continue
            chunk = b""
            if m is None:
                return out
            msg_id = m.get_msgId()
            if msg_id == mavlink2.MAVLINK_MSG_ID_BAD_DATA:
                self.bad_frames += 1
                if not str(m.reason).startswith("Bad prefix"):
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

    def _rescan(self, frame: bytes | bytearray) -> None:
        """Put a rejected frame's bytes, but its first, back in front of the parser."""
        mav = self.mav
        rest = mav.buf[mav.buf_index :]
        mav.buf = bytearray(frame[1:]) + rest
        mav.buf_index = 0
        mav.expected_length = mavlink2.HEADER_LEN_V1 + 2
