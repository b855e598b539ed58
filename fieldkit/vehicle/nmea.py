"""NMEA 0183 sentences, as a GPS receiver sends them: the inspector's view of one, and the
de-framer that finds them in a raw serial byte stream.

A sentence is ``$`` + address (talker and type, e.g. ``GPGGA``) + ``,``-separated fields +
``*hh`` (the XOR of every character between ``$`` and ``*``, two hex digits) + CR LF
(../shared/spec/clearpath-husky.md §11). Parsing, the checksum test and the typed fields are
pynmea2's (`pynmea2.parse(..., check=True)`), a maintained parser, not ours; this module adds
what pynmea2 does not say: which byte is bad. pynmea2's own `NMEAStreamReader` is not the
de-framer because it keeps an unbounded line, parses without the checksum check and cannot
resynchronise inside a line (``noise$GPGGA,...`` is one failed line to it). `cut_sentence`
is: a ``$`` up to the LF, restarting at a later ``$``, bounded; the Husky's GPS input cuts
its stream with it too.

`describe_sentence` checks the layout itself first (printable ASCII, the ``$``, the address,
the ``*hh``) so that each failure names its byte, then lets pynmea2 compare the checksum (a
mismatch names the ``*``) and decode the fields. Only ``$`` sentences are taken: pynmea2
does not parse ``!`` (AIS) ones.
"""

from __future__ import annotations

import datetime
import decimal
import math
from collections import Counter
from collections.abc import Iterable, Iterator
from typing import Any

import pynmea2

from fieldkit.errors import FrameError

#: The longest line the de-framer looks for a sentence in: NMEA allows 82 characters, CR LF
#: included; receivers' proprietary sentences run longer, and noise must not hold memory.
MAX_LINE = 256
_HEX = frozenset(b"0123456789abcdefABCDEF")


def _json_value(value: Any) -> Any:
    """A pynmea2 field value as JSON: times and dates in ISO 8601, decimals as numbers."""
    if isinstance(value, (datetime.time, datetime.date)):
        return value.isoformat()
    if isinstance(value, decimal.Decimal):
        value = float(value)
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def _check_layout(body: bytes) -> int:
    """The offset of the ``*`` of a sentence without its line end; FrameError where its
    layout is bad (pynmea2 would only say "could not parse")."""
    if not body:
        raise FrameError("empty sentence", 0)
    for i, b in enumerate(body):
        if not 0x20 <= b < 0x7F:
            raise FrameError(f"byte 0x{b:02x} is not printable ASCII", i)
    if body[0] != ord("$"):
        raise FrameError(f"a sentence starts with '$', not {chr(body[0])!r}", 0)
    star = body.find(b"*")
    if star < 0:
        raise FrameError("no checksum: a sentence ends in *hh", len(body))
    if len(body) - star != 3 or not _HEX.issuperset(body[star + 1 :]):
        raise FrameError("the checksum after '*' is not two hex digits", star + 1)
    proprietary = body[1:2] == b"P"
    # The address: P + 3 characters (proprietary), else 5 (talker + type) and a ','.
    for i in range(1, 5 if proprietary else 6):
        if i >= star or not (chr(body[i]).isalnum() or body[i] == ord("_")):
            raise FrameError("the address is 5 letters or digits after '$'", i)
    if not proprietary and body[6:7] != b",":
        raise FrameError("a ',' follows the 5-character address", 6)
    return star


def describe_sentence(data: bytes) -> dict[str, Any]:
    """The fields of one NMEA sentence (`fieldkit frames decode nmea`), as JSON values.

    `data` is the sentence's bytes; a trailing CR LF is allowed. Keys: talker and
    sentence_type (or manufacturer for a proprietary ``$P`` sentence; listener for a query),
    fields (pynmea2's attribute names and typed values: times and dates in ISO 8601), extra
    (data past the fields pynmea2 knows, if any), latitude and longitude in signed degrees
    for sentences with a position, checksum. FrameError names the first bad byte: a byte
    that is not printable ASCII, the ``$``, the address, the ``*`` of a checksum that does
    not match, a type pynmea2 does not know (its first letter).
    """
    data = bytes(data)
    body = data.rstrip(b"\r\n")
    star = _check_layout(body)
    text = body.decode("ascii")
    try:
        msg = pynmea2.parse(text, check=True)
    except pynmea2.ChecksumError:
        want = pynmea2.NMEASentence.checksum(text[1:star])
        given = text[star + 1 :]
        raise FrameError(
            f"checksum *{given} does not match the sentence's {want:02X}", star
        ) from None
    except pynmea2.SentenceTypeError:
        raise FrameError(f"sentence type {text[3:6]!r} is not one pynmea2 knows", 3) from None
    except pynmea2.ParseError as e:
        raise FrameError(f"pynmea2 cannot parse it ({e.args[0][0]})", 1) from None
    out: dict[str, Any] = {}
    for key in ("talker", "listener", "manufacturer", "sentence_type"):
        if key in vars(msg):
            out[key] = vars(msg)[key]
    known = type(msg).fields
    out["fields"] = {f[1]: _json_value(getattr(msg, f[1])) for f in known}
    if len(msg.data) > len(known):
        out["extra"] = msg.data[len(known) :]
    if isinstance(msg, pynmea2.nmea_utils.LatLonFix) and msg.lat and msg.lon:
        try:
            position = {"latitude": msg.latitude, "longitude": msg.longitude}
        except (ValueError, AttributeError, TypeError):
            position = {}  # the fields above show what the receiver sent
        out.update(position)
    out["checksum"] = int(text[star + 1 :], 16)
    return out


def cut_sentence(
    buf: bytes | bytearray, start: int, max_line: int = MAX_LINE
) -> tuple[int, bool] | None:
    """Where the candidate that starts with the ``$`` at ``buf[start]`` ends, and whether it
    is a whole line: ``(end, True)`` for ``buf[start:end]``, a line with its LF, to parse;
    ``(end, False)`` for bytes that are no sentence, to skip (no LF within `max_line` bytes,
    or another ``$`` before it: the sentence was cut short and the next may start there);
    None while the line end may still come.

    The one NMEA de-framer: `deframe` here and the Husky's GPS input
    (fieldkit.vehicle.clearpath.gps, which also cuts UBX frames between sentences) use it.
    """
    lf = buf.find(b"\n", start, start + max_line + 1)
    if lf < 0:
        return None if len(buf) - start <= max_line else (start + 1, False)
    other = buf.find(b"$", start + 1, lf)
    if other >= 0:
        return other, False
    return lf + 1, True


def _valid(sentence: bytes, stats: Counter[str]) -> bool:
    """Whether `sentence` is one valid sentence; a bad one counts in stats["bad_frames"]."""
    try:
        describe_sentence(sentence)
    except FrameError:
        stats["bad_frames"] += 1
        return False
    return True


def deframe(chunks: Iterable[bytes], stats: Counter[str]) -> Iterator[bytes]:
    """Every valid sentence of a raw byte stream, as its bytes with its line end.

    `cut_sentence` finds the candidates: from a ``$`` to the LF, restarting at a later ``$``
    (noise before a sentence, or a truncated one, costs nothing); a candidate that is not a
    valid sentence counts in stats["bad_frames"]. At most MAX_LINE bytes of a line are
    kept, whatever the noise; the end of the stream ends its last line.
    """
    buf = bytearray()
    for chunk in chunks:
        buf += chunk
        i = 0
        while (i := buf.find(b"$", i)) >= 0:
            cut = cut_sentence(buf, i)
            if cut is None:
                break  # the rest of the line is on its way
            end, whole = cut
            if whole and _valid(sentence := bytes(buf[i:end]), stats):
                yield sentence
            i = end
        del buf[: len(buf) if i < 0 else i]
    if buf:  # a last line without its line end: from its last '$', as a cut one would be
        if _valid(sentence := bytes(buf[buf.rfind(b"$") :]), stats):
            yield sentence
