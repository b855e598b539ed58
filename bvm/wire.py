"""The Buzz message wire format: what robots put on the air.

Facts: docs/wire-format.md#objects, #message-types.

A Buzz message is one payload whose length the transport supplies (there is no length
field, sender id or checksum inside). All integers are big-endian.

Message = u8 type + body::

    0 BROADCAST    topic object (a string, tag 3), value object
    1 SWARM_LIST   u16 n, n x u16 swarm id
    2 VSTIG_PUT    u16 vstig id, key object, value object, u16 timestamp, u16 robot
    3 VSTIG_QUERY  same as VSTIG_PUT
    4 SWARM_JOIN   u16 swarm id
    5 SWARM_LEAVE  u16 swarm id

Object = u8 tag + payload::

    0 nil      -
    1 int      int32 as u32 (two's complement)
    2 float    int32 mantissa, int32 exponent (below)
    3 string   u16 length, that many bytes (latin-1: one char per byte)
    4 table    u8 count, count x (key object, value object), in the Table's iteration order
    5 closure  u8 flag (1 = bytecode closure, 0 = C/host closure), u32 ref
    6 userdata never valid on the wire

Float: for x != 0, frexp(x) = (f, e) with |f| in [0.5, 1); mant = +-(frac23 * 256 + 1) where
frac23 are the 23 fraction bits of f, exp = e; 0 and -0.0 are mant = 0, exp = 0. The receiver
computes v = (|mant| - 1) / 2**32 + 0.5 in binary32 arithmetic, then ldexpf(v, exp), negated
if mant < 0. Every finite binary32 value round-trips bit-exactly (-0.0 arrives as 0.0).

fieldkit policies (where C is undefined or corrupts the stream; docs/compat.md copies this):

* +inf/-inf encode as mant +1/-1 (00000001 / ffffffff) with exp 129: the C decoder computes
  ldexpf(0.5, 129), which overflows to +-inf, so C peers receive the infinity too.
* NaN encodes as 80000001 00000000, the bytes the C VM produces on x86 (C peers decode it
  as -1.0). No finite value produces that pattern, so we decode exactly it as NaN. Any other
  pattern is decoded with C's binary32 arithmetic: huge exponents overflow to +-inf, tiny
  ones underflow to (+-)0 or a subnormal, never an exception.
* Encoding refuses, with EncodeError, what C would send as a corrupt stream: strings over
  65535 bytes, tables over 255 entries, userdata, closures whose activation record is not
  exactly one element (C writes a lone tag). Also refused: ints outside int32, strings
  with characters above U+00FF, table keys that are not int, float (not NaN) or string,
  tables nested deeper than MAX_DEPTH (this includes every cyclic table), u16 message
  fields outside 0..65535, vstig keys that are not valid table keys. A failed
  encode_value leaves `out` as it was.
* Table entries whose value is None are skipped (Buzz tables do not hold nil). Strings
  with NUL bytes are sent whole; a C receiver truncates them at the first NUL.
* Decoding is for hostile input: anything malformed raises DecodeError naming the problem
  and its byte offset, never another exception. Tables may nest at most MAX_DEPTH deep;
  userdata (tag 6) and unknown tags, truncation, bad table or vstig keys (not int, non-NaN
  float or string) and trailing bytes after a message are errors; a table entry with a nil
  value is dropped; unknown message types (>= 6) are reported as errors (the VM ignores
  them, as C does). A closure flag byte other than 0 means a bytecode closure, as in C.
  Work is linear in the payload length: every object consumes at least one byte.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from dataclasses import dataclass, fields
from enum import IntEnum
from typing import Any, ClassVar

from bvm.errors import BvmError
from bvm.values import Closure, Table, Userdata

__all__ = [
    "MAX_DEPTH",
    "MAX_STRING",
    "MAX_TABLE",
    "Broadcast",
    "DecodeError",
    "EncodeError",
    "Message",
    "MsgType",
    "SwarmJoin",
    "SwarmLeave",
    "SwarmList",
    "VstigPut",
    "VstigQuery",
    "WireClosure",
    "decode",
    "decode_value",
    "encode",
    "encode_value",
]

#: Deepest table nesting accepted on encode and decode (a table at top level is depth 1).
MAX_DEPTH = 32
#: Longest string the u16 length field can describe.
MAX_STRING = 0xFFFF
#: Most entries the u8 table count can describe.
MAX_TABLE = 0xFF


class DecodeError(BvmError, ValueError):
    """A payload that is not a valid Buzz message or object (says what, and at which byte)."""


class EncodeError(BvmError, ValueError):
    """A value or message that cannot be put on the wire without corrupting the stream."""


class MsgType(IntEnum):
    """Buzz message type codes (the first payload byte); lower is higher priority."""

    BROADCAST = 0
    SWARM_LIST = 1
    VSTIG_PUT = 2
    VSTIG_QUERY = 3
    SWARM_JOIN = 4
    SWARM_LEAVE = 5


@dataclass(frozen=True, slots=True)
class WireClosure:
    """A closure as received, when decoding without a closure factory."""

    native: bool
    ref: int


# ---------------------------------------------------------------- value equality


def _same(a: Any, b: Any, depth: int = 0) -> bool:
    """Structural equality of Buzz values: tables by content, floats by value (NaN == NaN).

    Table's own == is identity (as in Buzz), which would make every decoded message unequal
    to the one encoded; messages compare their values with this instead.
    """
    if a is b:
        return True
    cls = a.__class__
    if cls is not b.__class__:
        return False
    if cls is float:
        return a == b or (a != a and b != b)
    if cls is Table:
        if len(a) != len(b) or depth > MAX_DEPTH:  # past MAX_DEPTH: cyclic, compare by identity
            return False
        for k, v in a.items():
            w = b.get(k, None)
            if w is None and v is not None:
                return False
            if not _same(v, w, depth + 1):
                return False
        return True
    return a == b


# ---------------------------------------------------------------- messages


class Message:
    """Base class of the six messages: structural equality, hash on the scalar fields."""

    __slots__: tuple[str, ...] = ()
    type: ClassVar[MsgType]

    def __eq__(self, other: object) -> bool:
        if other.__class__ is not self.__class__:
            return NotImplemented
        return all(_same(getattr(self, f), getattr(other, f)) for f in self.__slots__)

    def __ne__(self, other: object) -> bool:
        eq = self.__eq__(other)
        return eq if eq is NotImplemented else not eq

    def __hash__(self) -> int:
        # Only int and str fields: equal messages have them equal, while equal tables and
        # floats (0.0 and -0.0, NaNs) need not hash alike.
        vals = (getattr(self, f) for f in self.__slots__)
        return hash((self.type, *(v for v in vals if v.__class__ in (int, str))))


@dataclass(frozen=True, slots=True, eq=False)
class Broadcast(Message):
    """BROADCAST: `neighbors.broadcast(topic, value)`."""

    type: ClassVar[MsgType] = MsgType.BROADCAST
    topic: str
    value: Any


@dataclass(frozen=True, slots=True, eq=False)
class SwarmList(Message):
    """SWARM_LIST: the ids of the swarms the sender is a member of."""

    type: ClassVar[MsgType] = MsgType.SWARM_LIST
    ids: tuple[int, ...]


@dataclass(frozen=True, slots=True, eq=False)
class VstigPut(Message):
    """VSTIG_PUT: element (value, timestamp, robot = owner) of `key` in stigmergy `vstig`."""

    type: ClassVar[MsgType] = MsgType.VSTIG_PUT
    vstig: int
    key: Any
    value: Any
    timestamp: int
    robot: int


@dataclass(frozen=True, slots=True, eq=False)
class VstigQuery(Message):
    """VSTIG_QUERY: same fields as VSTIG_PUT, carrying the querier's local element."""

    type: ClassVar[MsgType] = MsgType.VSTIG_QUERY
    vstig: int
    key: Any
    value: Any
    timestamp: int
    robot: int


@dataclass(frozen=True, slots=True, eq=False)
class SwarmJoin(Message):
    """SWARM_JOIN: the sender joined swarm `swarm`."""

    type: ClassVar[MsgType] = MsgType.SWARM_JOIN
    swarm: int


@dataclass(frozen=True, slots=True, eq=False)
class SwarmLeave(Message):
    """SWARM_LEAVE: the sender left swarm `swarm`."""

    type: ClassVar[MsgType] = MsgType.SWARM_LEAVE
    swarm: int


# ---------------------------------------------------------------- encoding

# Precompiled packers: one C call writes a tag and its fixed-size payload.
_PACK_INT = struct.Struct(">Bi").pack
_PACK_FLOAT = struct.Struct(">Bii").pack
_PACK_STR = struct.Struct(">BH").pack
_PACK_CLOSURE = struct.Struct(">BBI").pack
_PACK_TYPE_U16 = struct.Struct(">BH").pack
_PACK_U16_U16 = struct.Struct(">HH").pack

_FLOAT_ZERO = bytes.fromhex("02 00000000 00000000")
_FLOAT_NAN = bytes.fromhex("02 80000001 00000000")
_FLOAT_PINF = bytes.fromhex("02 00000001 00000081")
_FLOAT_NINF = bytes.fromhex("02 ffffffff 00000081")

# A binary32 cell: storing a double rounds it as C's (float) cast does (overflow -> inf,
# no exception). Private to this module; the store and the load are adjacent statements,
# which the GIL does not split between threads.
_F32 = memoryview(bytearray(4)).cast("f")

_frexp = math.frexp
_ldexp = math.ldexp
_INF = math.inf
_NAN = math.nan
_TWO_POW_24 = 16777216.0
_TWO_POW_M32 = 2.0**-32


def _type_name(v: Any) -> str:
    """A short description of a value's type for error messages."""
    names = {type(None): "nil", int: "int", float: "float", str: "string", Table: "table"}
    return names.get(v.__class__, v.__class__.__name__)


def _is_key(k: Any) -> bool:
    """Whether `k` may be a table or vstig key: int, float other than NaN, or str."""
    cls = k.__class__
    return cls is str or cls is int or (cls is float and k == k)


def _string_error(s: str) -> EncodeError:
    """The EncodeError for a string that is too long or not made of bytes."""
    if len(s) > MAX_STRING:
        return EncodeError(f"string of {len(s)} bytes: the wire length field holds at most 65535")
    i = next(i for i, c in enumerate(s) if ord(c) > 0xFF)
    return EncodeError(
        f"string has a character above U+00FF at index {i}: "
        "Buzz strings hold bytes (one latin-1 character per byte)"
    )


def _enc(v: Any, out: bytearray, depth: int) -> None:
    """Append object `v`; `depth` = number of tables enclosing it."""
    cls = v.__class__
    if cls is int:
        if -0x80000000 <= v <= 0x7FFFFFFF:
            out += _PACK_INT(1, v)
        else:
            raise EncodeError(f"int {v} is outside int32")
    elif cls is float:
        _F32[0] = v  # Buzz floats are binary32: a float64 would reach C peers altered
        x = _F32[0]
        if x == 0.0:
            out += _FLOAT_ZERO  # also -0.0, as C does
        elif x - x == 0.0:  # finite
            m, e = _frexp(x)
            # m has 24 significant bits, so (|m| - 0.5) * 2**24 is exactly frac23.
            if m > 0.0:
                out += _PACK_FLOAT(2, int((m - 0.5) * _TWO_POW_24) * 256 + 1, e)
            else:
                out += _PACK_FLOAT(2, -int((-m - 0.5) * _TWO_POW_24) * 256 - 1, e)
        elif x != x:
            out += _FLOAT_NAN
        else:
            out += _FLOAT_PINF if x > 0.0 else _FLOAT_NINF
    elif cls is str:
        n = len(v)  # a latin-1 str has one char per byte
        if n > MAX_STRING:
            raise _string_error(v)
        try:
            b = v.encode("latin-1")
        except UnicodeEncodeError:
            raise _string_error(v) from None
        out += _PACK_STR(3, n)
        out += b
    elif v is None:
        out.append(0)
    elif cls is Table:
        _enc_table(v, out, depth)
    elif cls is Closure:
        if len(v.actrec) != 1:
            raise EncodeError(
                f"closure @{v.ref} has an activation record of {len(v.actrec)} elements: only "
                "plain functions (one element) can be sent"
            )
        _enc_closure(v.native, v.ref, out)
    elif cls is WireClosure:
        _enc_closure(v.native, v.ref, out)
    elif cls is Userdata:
        raise EncodeError("userdata cannot be sent")
    else:
        raise EncodeError(f"a Python {cls.__name__} is not a Buzz value (see values.to_buzz)")


def _enc_closure(native: bool, ref: int, out: bytearray) -> None:
    """Append a closure object; the wire flag is 1 for bytecode, 0 for host functions."""
    if ref.__class__ is not int or not 0 <= ref <= 0xFFFFFFFF:
        raise EncodeError(f"closure ref {ref!r} is not a u32")
    out += _PACK_CLOSURE(5, 0 if native else 1, ref)


def _enc_table(t: Table, out: bytearray, depth: int) -> None:
    """Append a table object (entries with a nil value are skipped)."""
    if depth >= MAX_DEPTH:
        raise EncodeError(f"table nested deeper than {MAX_DEPTH} levels (or cyclic)")
    if len(t) > MAX_TABLE:
        n = sum(1 for x in t.values() if x is not None)
        if n > MAX_TABLE:
            raise EncodeError(f"table of {n} entries: the wire count holds at most 255")
    out.append(4)
    at = len(out)
    out.append(0)  # count, patched below: nil values are skipped
    count = 0
    depth += 1
    for k, x in t.items():
        if x is None:
            continue
        kc = k.__class__
        if kc is str:  # the usual key, inlined (this loop is the encoder's hot path)
            n = len(k)
            if n > MAX_STRING:
                raise _string_error(k)
            try:
                b = k.encode("latin-1")
            except UnicodeEncodeError:
                raise _string_error(k) from None
            out += _PACK_STR(3, n)
            out += b
        elif kc is int or (kc is float and k == k):
            _enc(k, out, depth)
        else:
            raise EncodeError(f"table key {k!r} ({_type_name(k)}): keys are int, float, string")
        _enc(x, out, depth)
        count += 1
    out[at] = count


def encode_value(v: Any, out: bytearray) -> None:
    """Append the wire form of Buzz value `v` to `out` (raises EncodeError, `out` unchanged)."""
    start = len(out)
    try:
        _enc(v, out, 0)
    except Exception:
        del out[start:]
        raise


def _u16_error(msg: Message, names: tuple[str, ...]) -> EncodeError:
    """The EncodeError for the first u16 field of `msg` out of range."""
    for name in names:
        x = getattr(msg, name)
        if x.__class__ is not int or not 0 <= x <= 0xFFFF:
            return EncodeError(f"{msg.type.name} {name} must be an int in 0..65535, got {x!r}")
    return EncodeError(f"{msg.type.name}: u16 field out of range")  # not reached


def _enc_vstig(msg: VstigPut | VstigQuery, t: int) -> bytes:
    """Encode a VSTIG_PUT (t = 2) or VSTIG_QUERY (t = 3)."""
    key = msg.key
    if not _is_key(key):
        raise EncodeError(
            f"{msg.type.name} key {key!r} ({_type_name(key)}): keys are int, float, string"
        )
    try:
        out = bytearray(_PACK_TYPE_U16(t, msg.vstig))
        _enc(key, out, 0)
        _enc(msg.value, out, 0)
        out += _PACK_U16_U16(msg.timestamp, msg.robot)
    except struct.error:
        raise _u16_error(msg, ("vstig", "timestamp", "robot")) from None
    return bytes(out)


def encode(msg: Message) -> bytes:
    """The payload of one Buzz message (raises EncodeError)."""
    cls = msg.__class__
    # Class identity tests (the fastest dispatch) do not narrow for mypy: each branch
    # re-binds the message under its class, without a run-time cast.
    if cls is Broadcast:
        bcast: Broadcast = msg  # type: ignore[assignment]  # narrowed by the class test above
        topic = bcast.topic
        if topic.__class__ is not str:
            raise EncodeError(f"BROADCAST topic must be a string, got {_type_name(topic)}")
        out = bytearray(b"\x00")
        _enc(topic, out, 0)
        _enc(bcast.value, out, 0)
        return bytes(out)
    if cls is VstigPut or cls is VstigQuery:
        vstig: VstigPut | VstigQuery = msg  # type: ignore[assignment]  # narrowed by the class test above
        return _enc_vstig(vstig, 2 if cls is VstigPut else 3)
    if cls is SwarmJoin or cls is SwarmLeave:
        change: SwarmJoin | SwarmLeave = msg  # type: ignore[assignment]  # narrowed by the class test above
        try:
            return _PACK_TYPE_U16(msg.type, change.swarm)
        except struct.error:
            raise _u16_error(msg, ("swarm",)) from None
    if cls is SwarmList:
        ids = msg.ids  # type: ignore[attr-defined]  # narrowed by the class test above
        n = len(ids)
        if n > 0xFFFF:
            raise EncodeError(f"SWARM_LIST of {n} ids: the wire count holds at most 65535")
        try:
            return struct.pack(f">BH{n}H", 1, n, *ids)
        except struct.error:
            bad = next(x for x in ids if x.__class__ is not int or not 0 <= x <= 0xFFFF)
            raise EncodeError(f"SWARM_LIST id must be an int in 0..65535, got {bad!r}") from None
    raise EncodeError(f"not a Buzz message: {msg!r}")


# ---------------------------------------------------------------- decoding


def _builder(cls: type[Message]) -> Callable[..., Any]:
    """A positional constructor for `cls` that sets the slots directly.

    A frozen dataclass's __init__ goes through object.__setattr__ per field, about half the
    cost of decoding a small VSTIG_PUT; the decoder builds messages with this instead.
    """
    new = object.__new__
    dataclass_fields = fields(cls)  # type: ignore[arg-type]  # every concrete message is one
    setters = tuple(getattr(cls, f.name).__set__ for f in dataclass_fields)
    if len(setters) == 2:
        s0, s1 = setters

        def make2(a: Any, b: Any) -> Any:
            o = new(cls)
            s0(o, a)
            s1(o, b)
            return o

        return make2
    s0, s1, s2, s3, s4 = setters

    def make5(a: Any, b: Any, c: Any, d: Any, e: Any) -> Any:
        o = new(cls)
        s0(o, a)
        s1(o, b)
        s2(o, c)
        s3(o, d)
        s4(o, e)
        return o

    return make5


_new_broadcast = _builder(Broadcast)
_new_put = _builder(VstigPut)
_new_query = _builder(VstigQuery)

_UNPACK_I32 = struct.Struct(">i").unpack_from
_UNPACK_U32 = struct.Struct(">I").unpack_from
_UNPACK_FLOAT = struct.Struct(">ii").unpack_from
_UNPACK_U16 = struct.Struct(">H").unpack_from
_UNPACK_U16_U16 = struct.Struct(">HH").unpack_from

_TAG_NAMES = {0: "nil", 1: "int", 2: "float", 3: "string", 4: "table", 5: "closure"}


def _tag_name(tag: int) -> str:
    """How an error message names an object tag."""
    if tag == 6:
        return "userdata (tag 6)"
    return _TAG_NAMES.get(tag, f"unknown tag {tag}")


def _truncated(what: str, pos: int, need: int, left: int) -> DecodeError:
    """The DecodeError for a fixed-size field that runs past the end."""
    return DecodeError(f"truncated {what} at byte {pos}: needs {need} bytes, {left} left")


def _decode_float(mant: int, exp: int) -> float:
    """The float C's decoder computes from (mant, exp), in binary32 arithmetic."""
    if mant == 0:
        return 0.0
    if mant == -0x7FFFFFFF and exp == 0:
        return _NAN  # our NaN policy: the x86 encoding of NaN, never produced by a finite value
    # C: (float)(|mant| - 1) rounds to 24 bits, / 2**32 is exact, + 0.5f rounds again
    # (the double sum is exact, so rounding it once is the binary32 addition).
    _F32[0] = (mant if mant > 0 else -mant) - 1
    _F32[0] = _F32[0] * _TWO_POW_M32 + 0.5
    try:
        # ldexpf rounds once: the double result is exact (it has the range), then rounded.
        _F32[0] = _ldexp(_F32[0], exp)
    except OverflowError:  # beyond even double range (exp in the thousands): ldexpf gives inf
        _F32[0] = _INF
    r = _F32[0]
    return r if mant > 0 else -r


def _obj(buf: bytes, pos: int, end: int, depth: int, closure: Callable | None) -> tuple[Any, int]:
    """Decode the object at `pos` (`depth` = enclosing tables): (value, position after it)."""
    if pos >= end:
        raise DecodeError(f"truncated object at byte {pos}: expected a type tag, no bytes left")
    tag = buf[pos]
    if tag == 1:
        if pos + 5 > end:
            raise _truncated("int", pos, 5, end - pos)
        return _UNPACK_I32(buf, pos + 1)[0], pos + 5
    if tag == 3:
        p = pos + 3
        if p > end:
            raise _truncated("string length", pos, 3, end - pos)
        q = p + ((buf[pos + 1] << 8) | buf[pos + 2])
        if q > end:
            raise DecodeError(
                f"truncated string at byte {pos}: length {q - p} but {end - p} bytes left"
            )
        return buf[p:q].decode("latin-1"), q
    if tag == 2:
        if pos + 9 > end:
            raise _truncated("float", pos, 9, end - pos)
        mant, exp = _UNPACK_FLOAT(buf, pos + 1)
        a1 = mant - 1 if mant > 0 else -mant - 1
        if a1 & 0xFF == 0 and -125 <= exp <= 128 and mant:
            # Canonical mantissa (what C sends) and a normal result: every binary32 step
            # of C's decoder is exact, so plain double arithmetic gives its result.
            r = _ldexp(a1 * _TWO_POW_M32 + 0.5, exp)
            return (r if mant > 0 else -r), pos + 9
        return _decode_float(mant, exp), pos + 9
    if tag == 4:
        if depth >= MAX_DEPTH:
            raise DecodeError(f"table at byte {pos} nested deeper than {MAX_DEPTH} levels")
        if pos + 2 > end:
            raise _truncated("table count", pos, 2, end - pos)
        t = Table()
        p = pos + 2
        depth += 1
        for _ in range(buf[pos + 1]):
            if p + 3 <= end and buf[p] == 3:  # a string key, the usual case, inlined
                q = p + 3 + ((buf[p + 1] << 8) | buf[p + 2])
                if q > end:
                    raise DecodeError(
                        f"truncated string at byte {p}: length {q - p - 3} but {end - p - 3} "
                        "bytes left"
                    )
                k = buf[p + 3 : q].decode("latin-1")
                p = q
            else:
                k, p = _key(buf, p, end, closure)
            v, p = _obj(buf, p, end, depth, closure)
            if v is not None:  # Buzz tables hold no nil: the entry is dropped
                t[k] = v
        return t, p
    if tag == 0:
        return None, pos + 1
    if tag == 5:
        if pos + 6 > end:
            raise _truncated("closure", pos, 6, end - pos)
        native = buf[pos + 1] == 0  # flag 0 = C closure; any other value is bytecode, as in C
        ref = _UNPACK_U32(buf, pos + 2)[0]
        return (WireClosure(native, ref) if closure is None else closure(native, ref)), pos + 6
    raise DecodeError(f"{_tag_name(tag)} at byte {pos} cannot be received")


def _key(buf: bytes, pos: int, end: int, closure: Callable | None) -> tuple[Any, int]:
    """Decode a table or vstig key: an int, float (not NaN) or string object."""
    if pos < end:
        tag = buf[pos]
        if tag != 3 and tag != 1 and tag != 2:
            raise DecodeError(
                f"key at byte {pos} is {_tag_name(tag)}: keys must be int, float or string"
            )
    k, p = _obj(buf, pos, end, MAX_DEPTH, closure)
    if k != k:
        raise DecodeError(f"key at byte {pos} is NaN: keys must be int, float or string")
    return k, p


def decode_value(
    buf: bytes | bytearray | memoryview,
    pos: int = 0,
    closure: Callable[[bool, int], Any] | None = None,
) -> tuple[Any, int]:
    """Decode the object at `pos`: (Buzz value, position after it); raises DecodeError.

    Closures are built by `closure(native, ref)`, or as WireClosure without a factory.
    """
    if buf.__class__ is not bytes:
        buf = bytes(buf)
    if pos < 0:
        raise DecodeError(f"negative position {pos}")
    return _obj(buf, pos, len(buf), 0, closure)


def decode(
    payload: bytes | bytearray | memoryview, closure: Callable[[bool, int], Any] | None = None
) -> Message:
    """Decode one whole message payload (raises DecodeError); see decode_value for `closure`."""
    buf = payload if payload.__class__ is bytes else bytes(payload)
    end = len(buf)
    if end == 0:
        raise DecodeError("empty payload")
    t = buf[0]
    if t == 0:
        if end < 2:
            raise DecodeError("truncated BROADCAST at byte 1: no topic")
        if buf[1] != 3:
            raise DecodeError(
                f"BROADCAST topic at byte 1 is {_tag_name(buf[1])}: it must be a string (tag 3)"
            )
        topic, p = _obj(buf, 1, end, 0, closure)
        value, p = _obj(buf, p, end, 0, closure)
        msg: Message = _new_broadcast(topic, value)
    elif t == 2 or t == 3:
        if end < 3:
            raise _truncated(f"{MsgType(t).name} vstig id", 1, 2, end - 1)
        key, p = _key(buf, 3, end, closure)
        value, p = _obj(buf, p, end, 0, closure)
        if p + 4 > end:
            raise _truncated(f"{MsgType(t).name} timestamp and robot", p, 4, end - p)
        ts, robot = _UNPACK_U16_U16(buf, p)
        p += 4
        make = _new_put if t == 2 else _new_query
        msg = make(_UNPACK_U16(buf, 1)[0], key, value, ts, robot)
    elif t == 1:
        if end < 3:
            raise _truncated("SWARM_LIST count", 1, 2, end - 1)
        n = _UNPACK_U16(buf, 1)[0]
        p = 3 + 2 * n
        if p > end:
            raise DecodeError(
                f"truncated SWARM_LIST at byte 3: {n} ids need {2 * n} bytes, {end - 3} left"
            )
        msg = SwarmList(struct.unpack_from(f">{n}H", buf, 3))
    elif t == 4 or t == 5:
        if end < 3:
            raise _truncated(f"{MsgType(t).name} swarm id", 1, 2, end - 1)
        p = 3
        swarm = _UNPACK_U16(buf, 1)[0]
        msg = SwarmJoin(swarm) if t == 4 else SwarmLeave(swarm)
    else:
        raise DecodeError(f"unknown message type {t}")
    if p != end:
        raise DecodeError(
            f"trailing bytes: the {msg.type.name} message ends at byte {p} "
            f"but the payload has {end} bytes ({end - p} extra)"
        )
    return msg
