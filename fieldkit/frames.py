"""The protocol inspector's registry: the byte formats `fieldkit frames decode` knows.

One module owns each byte format: its codec, and beside the codec the two functions the
inspector needs, a describe function (one frame's fields: `describe_frame`, or the bundle's
`describe`, NMEA's `describe_sentence`) and `deframe` (the frames of a raw byte stream,
found by the protocol's own streaming reader). This registry only maps a
protocol's name to those two, through small adapters that import the codec when it is
used (so that `fieldkit --help` loads none of them), and composes them for a stream
(`decode_stream`, with the counts the command line's summary prints).

Protocols now: mavlink (fieldkit.vehicle.mavlink), xbee (fieldkit.radio.xbee), xbeemav
(fieldkit.radio.xbeemav), bundle (fieldkit.robot.bundle, inside XbeeMav standard packets
and XBee frames), nmea (fieldkit.vehicle.nmea, parsed by pynmea2), dji
(fieldkit.vehicle.dji.frame, decrypted with --app-key), clearpath
(fieldkit.vehicle.clearpath.frame, its payloads by .messages).

To add a protocol:

1. Beside its codec, write
   ``describe_frame(frame: bytes) -> dict[str, Any]``: the fields of exactly one frame as
   JSON values (int, float, str, None, lists, dicts; byte strings as hex), named as in the
   protocol's spec. For bytes that are not exactly one valid frame, raise
   ``fieldkit.errors.FrameError(what, offset)`` with the offset of the first bad byte (a
   checksum that fails: the checksum's first byte; a frame that ends too soon: its
   length) and never another exception, whatever the bytes;
   ``deframe(chunks: Iterable[bytes], stats: Counter[str]) -> Iterator[bytes]``: the bytes
   of each frame that the protocol's streaming reader (the one the robot itself runs) finds
   in a raw byte stream, resynchronising over noise; it adds the frame candidates it
   rejects to ``stats["bad_frames"]``. The end of `chunks` is the end of the stream.
2. Register it at the end of this module: two adapters taking `Options` (importing the
   codec inside them; ``_plain("module:describe_frame", "module:deframe")`` makes them for
   a codec that takes no option), and ``register(Protocol("name", "one line for --help",
   describe, deframe))``; `text=True` if a frame may also be typed as text, `api_mode=True` if it
   travels in XBee frames and takes --api-mode, `app_key=True` if it takes --app-key.
3. Add a known good frame to GOOD in tests/test_frames_cli.py (the command-line tests and
   the fuzz test then cover the protocol), and an example to docs/cli.md.
"""

from __future__ import annotations

import importlib
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

from fieldkit.errors import FrameError


@dataclass(frozen=True)
class Options:
    """What a frame's bytes do not say and the command line does."""

    api_mode: int = 1
    """XBee API mode of frames that travel on an XBee serial line: 1 (XbeeMav's) or 2."""
    app_key: bytes | None = field(default=None, repr=False)
    """The 32 bytes of a DJI app key, to decrypt encrypted frames (never shown)."""


Describe = Callable[[bytes, Options], dict[str, Any]]
"""One frame's fields as JSON values; FrameError with the first bad byte."""
Deframe = Callable[[Iterable[bytes], Options, Counter[str]], Iterator[bytes]]
"""The bytes of each frame found in a stream; rejected candidates in stats["bad_frames"]."""


@dataclass(frozen=True)
class Protocol:
    """A protocol the inspector decodes: its name, a line of help, its two functions."""

    name: str
    summary: str
    describe: Describe
    deframe: Deframe
    text: bool = False
    """Frames may be typed as text (a NMEA sentence) where they are not hex."""
    api_mode: bool = False
    """Frames travel in XBee API frames: --api-mode applies."""
    app_key: bool = False
    """Frames may be AES-encrypted with a DJI app key: --app-key applies."""


PROTOCOLS: dict[str, Protocol] = {}
"""Every registered protocol by name, in the order registered."""


def register(protocol: Protocol) -> Protocol:
    """Add `protocol` to PROTOCOLS; ValueError if its name is taken."""
    if protocol.name in PROTOCOLS:
        raise ValueError(f"protocol {protocol.name!r} is already registered")
    PROTOCOLS[protocol.name] = protocol
    return protocol


def names() -> list[str]:
    """The registered protocols' names."""
    return list(PROTOCOLS)


@dataclass
class StreamCounts:
    """What `decode_stream` found: frames shown, frames rejected, bytes read and framed."""

    frames: int = 0
    bad: int = 0
    bytes_in: int = 0
    frame_bytes: int = 0

    @property
    def garbage_bytes(self) -> int:
        """Bytes read that are in no frame shown (noise, rejected and unfinished frames)."""
        return self.bytes_in - self.frame_bytes

    def summary(self) -> str:
        """`N frames, M bad, K garbage bytes`."""
        return f"{self.frames} frames, {self.bad} bad, {self.garbage_bytes} garbage bytes"


def decode_stream(
    protocol: Protocol, chunks: Iterable[bytes], options: Options, counts: StreamCounts
) -> Iterator[dict[str, Any]]:
    """`describe` of each frame `deframe` finds in `chunks`, as they come; `counts` is kept
    up to date (a frame the de-framer passes but `describe` refuses counts as bad)."""
    stats: Counter[str] = Counter()
    refused = 0

    def read() -> Iterator[bytes]:
        for chunk in chunks:
            counts.bytes_in += len(chunk)
            yield chunk

    try:
        for frame in protocol.deframe(read(), options, stats):
            counts.bad = stats["bad_frames"] + refused
            try:
                described = protocol.describe(frame, options)
            except FrameError:
                refused += 1
                continue
            counts.frames += 1
            counts.frame_bytes += len(frame)
            yield described
    finally:
        counts.bad = stats["bad_frames"] + refused


# ------------------------------------------------------------------ the protocols


def _function(where: str) -> Callable[..., Any]:
    """The function `module:name`, its module imported now."""
    module, name = where.split(":")
    found: Callable[..., Any] = getattr(importlib.import_module(module), name)
    return found


def _plain(describe: str, deframe: str) -> tuple[Describe, Deframe]:
    """Adapters of a codec that takes no option: its `describe(frame)` and `deframe(chunks,
    stats)`, each given as `module:name` and imported when first called."""

    def describe_(frame: bytes, options: Options) -> dict[str, Any]:
        result: dict[str, Any] = _function(describe)(frame)
        return result

    def deframe_(chunks: Iterable[bytes], options: Options, stats: Counter[str]) -> Iterator[bytes]:
        frames: Iterator[bytes] = _function(deframe)(chunks, stats)
        return frames

    return describe_, deframe_


def _xbee_describe(frame: bytes, options: Options) -> dict[str, Any]:
    from fieldkit.radio import xbee

    return xbee.describe_frame(frame, options.api_mode)


def _xbee_deframe(
    chunks: Iterable[bytes], options: Options, stats: Counter[str]
) -> Iterator[bytes]:
    from fieldkit.radio import xbee

    return xbee.deframe(chunks, stats, options.api_mode)


def _xbeemav_describe(frame: bytes, options: Options) -> dict[str, Any]:
    from fieldkit.radio import xbeemav

    return xbeemav.describe_frame(frame, options.api_mode)


def _bundle_describe(frame: bytes, options: Options) -> dict[str, Any]:
    from fieldkit.radio import xbee
    from fieldkit.robot import bundle

    # Air bytes are whole 8-byte words, whatever their first (junk) byte; an unescaped XBee
    # frame carrying a bundle never is: 3 + 8k bytes of RF data after a 17-byte (0x10) or
    # 15-byte (0x90) head, and a checksum. Escapes change a frame's size: in API mode 2
    # a leading 0x7e always means a frame.
    framed = options.api_mode == 2 or len(frame) % 8 != 0
    if frame[:1] == bytes((xbee.START,)) and framed:
        return xbee.describe_inside(frame, bundle.describe, options.api_mode)
    return bundle.describe(frame)


def _dji_cipher(options: Options) -> Any:
    """The AES cipher of --app-key, or None (encrypted frames then show their ciphertext)."""
    from fieldkit.vehicle.dji.crypto import FrameCipher

    return None if options.app_key is None else FrameCipher(options.app_key)


def _dji_describe(frame: bytes, options: Options) -> dict[str, Any]:
    from fieldkit.vehicle.dji import frame as dji

    return dji.describe_frame(frame, _dji_cipher(options))


def _dji_deframe(chunks: Iterable[bytes], options: Options, stats: Counter[str]) -> Iterator[bytes]:
    from fieldkit.vehicle.dji import frame as dji

    return dji.deframe(chunks, stats, _dji_cipher(options))


register(
    Protocol("mavlink", "MAVLink 1 and 2 frames, pymavlink's 'all' dialect",
             *_plain("fieldkit.vehicle.mavlink:describe_frame", "fieldkit.vehicle.mavlink:deframe"))
)  # fmt: skip
register(
    Protocol("xbee", "XBee API frames", _xbee_describe, _xbee_deframe,
             api_mode=True)
)  # fmt: skip
register(
    Protocol("xbeemav", "XbeeMav packets S, F, P, A: RF data or whole XBee frames",
             _xbeemav_describe, _xbee_deframe, api_mode=True)
)  # fmt: skip
register(
    Protocol("bundle", "ROSBuzz bundles: air bytes, 'S' RF data or XBee frames",
             _bundle_describe, _xbee_deframe, api_mode=True)
)  # fmt: skip
register(
    Protocol("nmea", "NMEA 0183 sentences via pynmea2, as text or hex",
             *_plain("fieldkit.vehicle.nmea:describe_sentence", "fieldkit.vehicle.nmea:deframe"),
             text=True)
)  # fmt: skip
register(
    Protocol("dji", "DJI OPEN protocol frames (Onboard SDK, M100)", _dji_describe,
             _dji_deframe, app_key=True)
)  # fmt: skip
register(
    Protocol("clearpath", "Clearpath MCU frames (Husky), payloads decoded",
             *_plain("fieldkit.vehicle.clearpath.messages:describe_frame",
                     "fieldkit.vehicle.clearpath.frame:deframe"))
)  # fmt: skip


__all__ = [
    "PROTOCOLS",
    "Deframe",
    "Describe",
    "Options",
    "Protocol",
    "StreamCounts",
    "decode_stream",
    "names",
    "register",
]
