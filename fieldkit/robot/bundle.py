"""The ROSBuzz bundle: how one robot's Buzz messages of one step travel, byte for byte.

Three layers, all byte-compatible with unmodified ROSBuzz + XbeeMav robots (docs/bundle.md#layers,
docs/bundle.md#bundle, #mavlink-message, #receive-path, #xbeemav-packet, #worked-example):

* L1, the bundle (`pack_bundle` / `unpack_bundle`): ``[u16 nwords][u16 robot]`` then
  ``[u16 len | len bytes]`` per Buzz message, zero padded to a multiple of 8 bytes; every
  field little-endian. ROSBuzz's `obt_out_msg` adds a message while
  ``current_size + 2 + len <= MAX_MSG_SIZE`` with `current_size` starting at 4, so the 190
  bytes cover the 4-byte header and every length prefix, but not the padding: at most 190
  bytes of content, 192 bytes (24 words) with padding.
* L2, the Mavlink container (`to_payload64` / `from_payload64`): ``payload64`` = word 0
  (u16 type 2 = BUZZ_MESSAGE, u16 message number, 4 junk bytes we send as zeros), word 1
  send time in ns, words 2-4 latitude, longitude and relative altitude (IEEE-754 double bit
  patterns), then the bundle's bytes as little-endian u64 words: 6 to 29 words.
* On the air (`encode` / `decode`): the payload64 words, each serialized big-endian as
  XbeeMav does, so every 8-byte group of the bundle appears byte-reversed; 48 to 232 bytes.
  XbeeMav sends them as the RF data ``'S' | sysid | msgid | words`` (`to_rf_data`), 3 more
  bytes, within the XBee's 250-byte frame.

Filling a bundle from a VM, one step (`fill` does exactly this and checks the result):

    messages = vm.drain_outbox(budget_bytes=MAX_BUZZ_BYTES, overhead=MSG_OVERHEAD)  # 186, 2
    bundle = Bundle(robot, tuple(messages), lat, lon, alt, number)

Each message then costs its length plus its 2-byte length prefix, and the 186-byte budget
is what the 190 bytes leave after the 4-byte header, so the bundle never exceeds ROSBuzz's
limit; `drain_budget(air_bytes)` gives the budget for a smaller per-step air allowance.

Decoders take hostile bytes: anything that is not a bundle this module could have built
(apart from the ignored junk bytes of word 0, which real ROSBuzz robots fill with garbage)
raises `BundleError` naming what is wrong and at which byte offset, never another
exception. They are stricter than ROSBuzz's receiver, which reads whatever the length fields
point at: nwords must match the size, padding must be zero and shorter than a word, no
message may be empty or overrun, the content must fit in 190 bytes, and the position must
be finite (a NaN or infinite latitude, longitude or altitude would poison every range and
bearing computed from it, so the whole container is rejected).
"""

from __future__ import annotations

import math
import struct
from array import array
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from bvm import wire
from fieldkit.errors import FieldkitError, FrameError

#: Mavlink payload64[0] message types (ROSBuzz include/rosbuzz/roscontroller.h).
UPDATER_MESSAGE = 1
BUZZ_MESSAGE = 2

#: ROSBuzz's limit on a bundle's content: header + length prefixes + messages, no padding.
MAX_MSG_SIZE = 190
#: The bundle header: u16 nwords, u16 robot.
BUNDLE_HEADER = 4
#: The per-message cost beyond its bytes: its u16 length prefix (`overhead` for drain_outbox).
MSG_OVERHEAD = 2
#: Another name for MSG_OVERHEAD.
#: The `budget_bytes` for drain_outbox: the content limit less the header.
MAX_BUZZ_BYTES = MAX_MSG_SIZE - BUNDLE_HEADER
#: The longest Buzz message a bundle can carry (a longer one can never be sent).
MAX_MESSAGE = MAX_BUZZ_BYTES - MSG_OVERHEAD
#: Bundle words at most: 190 bytes rounded up to a whole word.
MAX_BUNDLE_WORDS = -(-MAX_MSG_SIZE // 8)
#: Words before the bundle in payload64: type/number, time, lat, lon, alt.
HEADER_WORDS = 5
#: payload64 length bounds of a BUZZ_MESSAGE.
MIN_PAYLOAD_WORDS = HEADER_WORDS + 1
MAX_PAYLOAD_WORDS = HEADER_WORDS + MAX_BUNDLE_WORDS
#: Bytes on the air (`encode`) at least (an empty step: a position heartbeat) and at most.
MIN_AIR_BYTES = 8 * MIN_PAYLOAD_WORDS
MAX_AIR_BYTES = 8 * MAX_PAYLOAD_WORDS
#: XbeeMav's standard-message prefix ('S', sysid, msgid) before the words
#: (docs/bundle.md#xbeemav-packet).
RF_PREFIX = 3
#: The largest RF data of a standard (unfragmented) XBee frame.
XBEE_MAX_RF = 250

_U16 = struct.Struct("<H")
_HEAD = struct.Struct("<HH")
_DOUBLE = struct.Struct("<d")
_U64 = struct.Struct("<Q")
_IMAGE_HEAD = struct.Struct("<QQddd")  # the payload64 header words: type/number, time, position
_FIELDS = ("latitude", "longitude", "altitude")


class BundleError(FieldkitError, ValueError):
    """Bytes or words that are not a valid bundle: what is wrong and at which byte offset."""

    def __init__(self, what: str, offset: int) -> None:
        super().__init__(f"{what} (at byte {offset})")
        self.what = what
        self.offset = offset


@dataclass(frozen=True)
class Bundle:
    """One robot's BUZZ_MESSAGE of one step: its Buzz messages and its position.

    `robot` is the bundle's u16 sender id (ROSBuzz robots use 0..255); `number` the message
    counter, of which only the low 16 bits are kept, as the header carries them; `time_ns`
    the sender's clock (receivers only log it); lat/lon in degrees, alt in metres, finite.
    """

    robot: int
    messages: tuple[bytes, ...]
    lat: float
    lon: float
    alt: float
    number: int = 0
    time_ns: int = 0

    def __post_init__(self) -> None:
        # Checked here so that every Bundle encodes: decoders build only valid ones.
        _check_u(self.robot, 16, "robot")
        if not isinstance(self.number, int) or isinstance(self.number, bool) or self.number < 0:
            raise ValueError(f"number must be an int >= 0, got {self.number!r}")
        # ROSBuzz's message counter is an int of which the header carries the low 16 bits.
        object.__setattr__(self, "number", self.number & 0xFFFF)
        _check_u(self.time_ns, 64, "time_ns")
        messages = tuple(bytes(m) for m in self.messages)
        _check_messages(messages)
        object.__setattr__(self, "messages", messages)
        for name in ("lat", "lon", "alt"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ValueError(f"{name} must be finite, got {value}")
            object.__setattr__(self, name, value)


def _check_u(value: int, bits: int, name: str) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value < 1 << bits:
        raise ValueError(f"{name} must be an int in 0..{(1 << bits) - 1}, got {value!r}")


def _check_messages(messages: Sequence[bytes]) -> None:
    size = BUNDLE_HEADER
    for i, m in enumerate(messages):
        if not m:
            # A zero length prefix is the receiver's end marker: the rest would be lost.
            raise ValueError(f"message {i} is empty")
        size += MSG_OVERHEAD + len(m)
    if size > MAX_MSG_SIZE:
        raise ValueError(f"bundle content is {size} bytes, more than MAX_MSG_SIZE={MAX_MSG_SIZE}")


def block_size(messages: Sequence[bytes]) -> int:
    """Bytes of bundle content (header + prefixed messages, no padding): what 190 limits."""
    return BUNDLE_HEADER + MSG_OVERHEAD * len(messages) + sum(map(len, messages))


def air_size(messages: Sequence[bytes]) -> int:
    """Bytes `encode` puts on the air for a bundle of these messages."""
    return 8 * (HEADER_WORDS + -(-block_size(messages) // 8))


def drain_budget(air_bytes: int = MAX_AIR_BYTES) -> int:
    """The drain_outbox budget (with overhead=MSG_OVERHEAD) whose bundle encodes in `air_bytes`.

    Padding rounds the content up to whole words, so the content may use only the whole
    words left after the 5 header words, and never more than MAX_MSG_SIZE.
    """
    content = min(8 * ((air_bytes - 8 * HEADER_WORDS) // 8), MAX_MSG_SIZE)
    if content < 8:
        raise ValueError(f"{air_bytes} bytes cannot carry even an empty bundle ({MIN_AIR_BYTES})")
    return content - BUNDLE_HEADER


def fill(
    drain: Callable[[int, int], list[bytes]], budget_bytes: int = MAX_BUZZ_BYTES
) -> tuple[bytes, ...]:
    """One step's messages: `drain(budget_bytes, MSG_OVERHEAD)` (e.g. vm.drain_outbox), checked.

    The result always fits a bundle; a drain that overspends its budget is a bug and raises
    ValueError rather than producing a bundle ROSBuzz robots would not produce.
    """
    if not 0 <= budget_bytes <= MAX_BUZZ_BYTES:
        raise ValueError(f"budget_bytes must be in 0..{MAX_BUZZ_BYTES}, got {budget_bytes}")
    messages = tuple(drain(budget_bytes, MSG_OVERHEAD))
    used = block_size(messages) - BUNDLE_HEADER
    if used > budget_bytes:
        raise ValueError(f"drain returned {used} bytes for a budget of {budget_bytes}")
    _check_messages(messages)
    return messages


# ------------------------------------------------------------------------------ L1


def pack_bundle(robot: int, messages: Sequence[bytes]) -> bytes:
    """The L1 bundle bytes: header, length-prefixed messages, zero padding to 8 bytes."""
    _check_u(robot, 16, "robot")
    _check_messages(messages)
    return _l1(robot, messages)


def _l1(robot: int, messages: Sequence[bytes]) -> bytes:
    """`pack_bundle` without its checks."""
    parts = [b""]  # the header, once the size is known
    size = BUNDLE_HEADER
    for m in messages:
        parts.append(_U16.pack(len(m)))
        parts.append(m)
        size += MSG_OVERHEAD + len(m)
    words = -(-size // 8)
    parts[0] = _HEAD.pack(words, robot)
    parts.append(bytes(8 * words - size))
    return b"".join(parts)


def unpack_bundle(data: bytes) -> tuple[int, tuple[bytes, ...]]:
    """(robot, messages) of L1 bundle bytes; BundleError with a bundle byte offset if invalid."""
    if not isinstance(data, bytes | bytearray | memoryview):
        raise BundleError(f"a bundle is bytes, not {type(data).__name__}", 0)
    data = bytes(data)
    n = len(data)
    if n < 8:
        raise BundleError(f"bundle of {n} bytes, shorter than one 8-byte word", n)
    if n % 8:
        raise BundleError(f"bundle of {n} bytes, not a whole number of 8-byte words", n - n % 8)
    nwords, robot = _HEAD.unpack_from(data, 0)
    if nwords * 8 != n:
        raise BundleError(f"header says {nwords} words, the bundle has {n // 8}", 0)
    if nwords > MAX_BUNDLE_WORDS:
        raise BundleError(f"{nwords} words, more than a bundle's {MAX_BUNDLE_WORDS}", 0)
    messages = []
    pos = BUNDLE_HEADER
    while pos + MSG_OVERHEAD <= n:
        (length,) = _U16.unpack_from(data, pos)
        if length == 0:
            break  # the padding, or an empty message if anything but zeros follows
        end = pos + MSG_OVERHEAD + length
        if end > n:
            raise BundleError(
                f"message length {length} overruns the bundle ({n - pos - MSG_OVERHEAD} left)",
                pos,
            )
        if end > MAX_MSG_SIZE:
            raise BundleError(
                f"message of {length} bytes ends at byte {end}, past MAX_MSG_SIZE={MAX_MSG_SIZE}",
                pos,
            )
        messages.append(data[pos + MSG_OVERHEAD : end])
        pos = end
    if any(data[pos:]):
        if pos + MSG_OVERHEAD <= n:
            raise BundleError("zero-length message before more data", pos)
        raise BundleError("non-zero padding byte", pos)
    if n - pos >= 8:
        raise BundleError(f"{nwords} words for {pos} bytes of content: a whole word of padding", 0)
    return robot, tuple(messages)


# ------------------------------------------------------------------------------ L2


def to_payload64(bundle: Bundle) -> list[int]:
    """The Mavlink payload64 words of a BUZZ_MESSAGE carrying `bundle` (header bytes 4-7 zero)."""
    body = pack_bundle(bundle.robot, bundle.messages)
    return [
        BUZZ_MESSAGE | bundle.number << 16,
        bundle.time_ns,
        *(_U64.unpack(_DOUBLE.pack(x))[0] for x in (bundle.lat, bundle.lon, bundle.alt)),
        *struct.unpack(f"<{len(body) // 8}Q", body),
    ]


def _identity(offset: int) -> int:
    return offset


def _air(offset: int) -> int:
    """Where byte `offset` of the payload64 memory image sits on the air (words reversed)."""
    return offset - offset % 8 + 7 - offset % 8


def _from_words(words: Sequence[int], where: Callable[[int], int]) -> Bundle:
    """A Bundle from checked u64 words; `where` maps memory offsets to reported offsets."""
    n = len(words)
    if n < MIN_PAYLOAD_WORDS:
        raise BundleError(f"{n} words, a BUZZ_MESSAGE has at least {MIN_PAYLOAD_WORDS}", 8 * n)
    if n > MAX_PAYLOAD_WORDS:
        raise BundleError(f"{n} words, a BUZZ_MESSAGE has at most {MAX_PAYLOAD_WORDS}", 8 * n)
    head = words[0]
    if head == UPDATER_MESSAGE:
        raise BundleError("an updater (OTA) message, not a Buzz bundle", where(0))
    kind = head & 0xFFFF
    if kind != BUZZ_MESSAGE:
        raise BundleError(f"message type {kind}, not BUZZ_MESSAGE ({BUZZ_MESSAGE})", where(0))
    position = []
    for i, name in enumerate(_FIELDS):
        (value,) = _DOUBLE.unpack(_U64.pack(words[2 + i]))
        if not math.isfinite(value):
            raise BundleError(f"{name} is {value}", where(8 * (2 + i)))
        position.append(value)
    body = struct.pack(f"<{n - HEADER_WORDS}Q", *words[HEADER_WORDS:])
    try:
        robot, messages = unpack_bundle(body)
    except BundleError as e:
        raise BundleError(e.what, where(8 * HEADER_WORDS + e.offset)) from None
    lat, lon, alt = position
    return Bundle(robot, messages, lat, lon, alt, number=head >> 16 & 0xFFFF, time_ns=words[1])


def from_payload64(words: Sequence[int]) -> Bundle:
    """The Bundle in Mavlink payload64 words; BundleError (payload64 byte offset) if invalid."""
    if not isinstance(words, list | tuple):
        raise BundleError(f"payload64 is a list of ints, not {type(words).__name__}", 0)
    for i, w in enumerate(words):
        if type(w) is not int or not 0 <= w < 1 << 64:
            raise BundleError(f"payload64[{i}] = {w!r:.40} is not a u64", 8 * i)
    return _from_words(words, _identity)


# ------------------------------------------------------------------------------ air


def encode(bundle: Bundle) -> bytes:
    """The bytes on the air: payload64 words, each big-endian as XbeeMav serializes them."""
    return encode_fields(
        bundle.robot,
        bundle.messages,
        bundle.lat,
        bundle.lon,
        bundle.alt,
        bundle.number,
        bundle.time_ns,
    )


def encode_fields(
    robot: int,
    messages: Sequence[bytes],
    lat: float,
    lon: float,
    alt: float,
    number: int = 0,
    time_ns: int = 0,
) -> bytes:
    """`encode(Bundle(robot, messages, ...))` without building and re-checking a Bundle: for
    messages that are known to fit, such as a drained outbox (the simulator sends one
    bundle per robot per tick)."""
    # The payload64 memory image (little-endian words), then every 8-byte word reversed in
    # place (byteswap reverses each item's bytes on any host).
    parts = [
        _IMAGE_HEAD.pack(BUZZ_MESSAGE | (number & 0xFFFF) << 16, time_ns, lat, lon, alt),
        _l1(robot, messages),
    ]
    image = array("Q", b"".join(parts))
    image.byteswap()
    return image.tobytes()


def decode(data: bytes) -> Bundle:
    """The Bundle of `encode`d bytes; BundleError with the offset in `data` if invalid."""
    if not isinstance(data, bytes | bytearray | memoryview):
        raise BundleError(f"air data is bytes, not {type(data).__name__}", 0)
    n = len(data)
    if n % 8:
        raise BundleError(f"{n} bytes, not a whole number of 8-byte words", n - n % 8)
    if n > MAX_AIR_BYTES:
        # Checked before unpacking so that a huge hostile input costs nothing.
        raise BundleError(f"{n} bytes, a BUZZ_MESSAGE has at most {MAX_AIR_BYTES}", MAX_AIR_BYTES)
    return _from_words(struct.unpack(f">{n // 8}Q", data), _air)


def to_rf_data(bundle: Bundle) -> bytes:
    """XbeeMav's standard-message RF data: 'S', sysid (u8 robot), msgid (u8 number), words."""
    return b"S" + bytes((bundle.robot & 0xFF, bundle.number & 0xFF)) + encode(bundle)


def from_rf_data(data: bytes) -> Bundle:
    """The Bundle in standard-message RF data; sysid and msgid are ignored, as ROSBuzz does."""
    if not isinstance(data, bytes | bytearray | memoryview):
        raise BundleError(f"RF data is bytes, not {type(data).__name__}", 0)
    if len(data) < RF_PREFIX or data[0] != ord("S"):
        raise BundleError("not an XbeeMav standard message ('S', sysid, msgid, words)", 0)
    try:
        return decode(data[RF_PREFIX:])
    except BundleError as e:
        raise BundleError(e.what, RF_PREFIX + e.offset) from None


# ------------------------------------------------------------------------------ inspector


def describe(data: bytes) -> dict[str, Any]:
    """The fields of one bundle as JSON values (`fieldkit frames decode bundle`).

    `data` is the air bytes (`encode`, a whole number of words), or XbeeMav standard-packet
    RF data (`to_rf_data`: 'S', sysid, msgid, words; then sysid and msgid are shown too).
    Keys: robot, number, time_ns, lat, lon, alt, messages: each {"hex", "type"} with the
    Buzz message type's name (bvm.wire.MsgType), or type None and "error" for bytes that do
    not decode as a Buzz message (the bundle itself is still valid). FrameError with the
    BundleError's offset in `data`.
    """
    data = bytes(data)
    head: dict[str, Any] = {}
    try:
        if len(data) % 8 == RF_PREFIX and data[:1] == b"S":
            head = {"sysid": data[1], "msgid": data[2]}
            bundle = from_rf_data(data)
        else:
            bundle = decode(data)
    except BundleError as e:
        raise FrameError(e.what, e.offset) from None
    return {
        **head,
        "robot": bundle.robot,
        "number": bundle.number,
        "time_ns": bundle.time_ns,
        "lat": bundle.lat,
        "lon": bundle.lon,
        "alt": bundle.alt,
        "messages": [_describe_message(m) for m in bundle.messages],
    }


def _describe_message(message: bytes) -> dict[str, Any]:
    """{"hex", "type"} of one message of a bundle (type None and "error" if not Buzz)."""
    try:
        kind = wire.decode(message).type
    except wire.DecodeError as e:
        return {"hex": message.hex(), "type": None, "error": str(e)}
    return {"hex": message.hex(), "type": kind.name}
