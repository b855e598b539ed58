"""The Buzz message wire format (bvm.wire) against docs/wire-format.md#objects, #message-types
and docs/bundle.md#worked-example.

Golden vectors are the bytes the reference C VM produced (robot 7:
docs/wire-format.md#message-types, docs/bundle.md#worked-example);
the float codec is checked against an independent numpy float32 transcription of the C
code; hypothesis checks round trips; hostile input must only ever raise DecodeError.
"""

from __future__ import annotations

import math
import struct
from dataclasses import FrozenInstanceError

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bvm import wire
from bvm.values import Closure, Table, Userdata, f32
from bvm.wire import (
    Broadcast,
    DecodeError,
    EncodeError,
    MsgType,
    SwarmJoin,
    SwarmLeave,
    SwarmList,
    VstigPut,
    VstigQuery,
    WireClosure,
    decode,
    decode_value,
    encode,
    encode_value,
)


def h(text: str) -> bytes:
    """Bytes from spaced hex as the docs write them."""
    return bytes.fromhex(text)


def value_bytes(v: object) -> bytes:
    out = bytearray()
    encode_value(v, out)
    return bytes(out)


def value_of(data: bytes) -> object:
    """Decode one whole object (all bytes consumed)."""
    v, pos = decode_value(data)
    assert pos == len(data)
    return v


# ---------------------------------------------------------------- independent references


def c_encode_float(x: float) -> tuple[int, int]:
    """The C encoder (docs/wire-format.md#objects) in numpy float32 arithmetic (not the recipe)."""
    v = np.float32(x)
    if v == 0:
        return 0, 0
    f, e = np.frexp(v)  # float32 in, float32 fraction out
    two = np.float32(2.0)
    big = np.float32(2147483646.0)  # rounds to 2**31 in float32, as in C
    mant = int(np.int32((np.abs(f) - np.float32(0.5)) * two * big)) + 1
    return (-mant if v < 0 else mant), int(e)


def c_decode_float(mant: int, exp: int) -> float:
    """The C decoder (docs/wire-format.md#objects) in numpy float32 (ldexpf overflows to inf)."""
    if mant == 0:
        return 0.0
    with np.errstate(all="ignore"):
        v = np.float32(abs(mant) - 1) / np.float32(4294967296.0) + np.float32(0.5)
        v = np.ldexp(v, np.int32(exp))
        if mant < 0:
            v = -v
    return float(v)


def bits(x: float) -> int:
    return struct.unpack(">I", struct.pack(">f", x))[0]


def from_bits(b: int) -> float:
    return struct.unpack(">f", struct.pack(">I", b))[0]


def norm(v: object) -> object:
    """A plain comparable form: floats by binary32 bits (NaN canonical), tables as dicts."""
    cls = v.__class__
    if cls is float:
        return ("float", "nan" if v != v else bits(v))
    if cls is int:
        return ("int", v)
    if cls is Table:
        return ("table", {norm(k): norm(x) for k, x in v.items()})
    return v


# ---------------------------------------------------------------- golden vectors

GOLDEN_MESSAGES = [
    ('broadcast("cmd", 22)', Broadcast("cmd", 22), "00 03 0003 636d64 01 00000016"),
    ('broadcast("f", -0.1)', Broadcast("f", f32(-0.1)), "00 03 0001 66 02 b33332ff fffffffd"),
    ('broadcast("f", nil)', Broadcast("f", None), "00 03 0001 66 00"),
    ("SWARM_LIST [3]", SwarmList((3,)), "01 0001 0003"),
    ("SWARM_LIST []", SwarmList(()), "01 0000"),
    ("SWARM_LIST [1, 3, 9]", SwarmList((1, 3, 9)), "01 0003 0001 0003 0009"),
    ('put("k", 42)', VstigPut(5, "k", 42, 1, 7), "02 0005 03 0001 6b 01 0000002a 0001 0007"),
    (
        "put(7, 1.5)",
        VstigPut(5, 7, 1.5, 1, 7),
        "02 0005 01 00000007 02 40000001 00000001 0001 0007",
    ),
    (
        'put("t", {.a=1})',
        VstigPut(5, "t", Table(a=1), 1, 7),
        "02 0005 03 0001 74 04 01 03 0001 61 01 00000001 0001 0007",
    ),
    (
        'get("missing")',
        VstigQuery(5, "missing", None, 0, 7),
        "03 0005 03 0007 6d697373696e67 00 0000 0007",
    ),
    ('delete put("k", nil)', VstigPut(5, "k", None, 2, 2), "02 0005 03 0001 6b 00 0002 0002"),
    ("SWARM_JOIN 3", SwarmJoin(3), "04 0003"),
    ("SWARM_LEAVE 3", SwarmLeave(3), "05 0003"),
]

GOLDEN_VALUES = [
    (None, "00"),
    (22, "01 00000016"),
    (-1, "01 ffffffff"),
    (-0x80000000, "01 80000000"),
    (0x7FFFFFFF, "01 7fffffff"),
    (1.0, "02 00000001 00000001"),
    (0.5, "02 00000001 00000000"),
    (1.5, "02 40000001 00000001"),
    (-1.0, "02 ffffffff 00000001"),
    (f32(-0.1), "02 b33332ff fffffffd"),
    (0.0, "02 00000000 00000000"),
    ("cmd", "03 0003 636d64"),
    ("", "03 0000"),
    ("\xe9\x00", "03 0002 e9 00"),
    (Table(a=1), "04 01 03 0001 61 01 00000001"),
    (Table(), "04 00"),
    (WireClosure(False, 0x98), "05 01 00000098"),  # observed: a bytecode closure
    (WireClosure(True, 3), "05 00 00000003"),
]


@pytest.mark.parametrize(
    ("name", "msg", "hexbytes"), GOLDEN_MESSAGES, ids=[g[0] for g in GOLDEN_MESSAGES]
)
def test_golden_message(name: str, msg: wire.Message, hexbytes: str) -> None:
    assert encode(msg).hex() == h(hexbytes).hex()
    got = decode(h(hexbytes))
    assert got.__class__ is msg.__class__
    assert got == msg
    assert got.type == msg.type
    assert encode(got) == h(hexbytes)


@pytest.mark.parametrize(("value", "hexbytes"), GOLDEN_VALUES, ids=[g[1] for g in GOLDEN_VALUES])
def test_golden_value(value: object, hexbytes: str) -> None:
    assert value_bytes(value).hex() == h(hexbytes).hex()
    assert norm(value_of(h(hexbytes))) == norm(value)


def test_bundle_example_messages() -> None:
    """The worked example's bundle holds BROADCAST "cmd"=22 (12 bytes), JOIN 3 (docs/bundle.md)."""
    bundle = h("03 00 07 00 0c 00 00 03 00 03 63 6d 64 01 00 00 00 16 03 00 04 00 03 00")
    first = bundle[6 : 6 + 12]
    second = bundle[6 + 12 + 2 : 6 + 12 + 2 + 3]
    assert decode(first) == Broadcast("cmd", 22)
    assert decode(second) == SwarmJoin(3)


def test_closures_from_the_vm() -> None:
    """Flag 1 on the wire is a bytecode closure (native=False), 0 a host function."""
    plain = Closure(0x98, False, (None,), lambda *a: None)
    host = Closure(7, True, (None,), lambda *a: None)
    assert value_bytes(plain) == h("05 01 00000098")
    assert value_bytes(host) == h("05 00 00000007")
    made: list[tuple[bool, int]] = []
    v, _ = decode_value(h("05 01 00000098"), 0, lambda native, ref: made.append((native, ref)))
    v, _ = decode_value(h("05 00 00000007"), 0, lambda native, ref: made.append((native, ref)))
    assert made == [(False, 0x98), (True, 7)]
    assert value_of(h("05 02 00000001")) == WireClosure(False, 1)  # any non-zero: bytecode
    msg = decode(h("00 03 0001 66 05 00 00000004"), closure=lambda n, r: ("fn", n, r))
    assert msg.value == ("fn", True, 4)


def test_message_types() -> None:
    assert [m.value for m in MsgType] == [0, 1, 2, 3, 4, 5]
    classes = [Broadcast, SwarmList, VstigPut, VstigQuery, SwarmJoin, SwarmLeave]
    assert [c.type for c in classes] == list(MsgType)
    for _, msg, hexbytes in GOLDEN_MESSAGES:
        assert h(hexbytes)[0] == msg.type


# ---------------------------------------------------------------- floats


def test_float_recipe_matches_c_on_boundaries() -> None:
    specials = [
        1,  # smallest subnormal
        0x007FFFFF,  # largest subnormal
        0x00800000,  # smallest normal
        0x7F7FFFFF,  # largest finite
        0x3F800000,
        0x3F800001,
        0x3DCCCCCD,
        0x00000003,
        0x00400000,
    ]
    for b in specials + [b | 0x80000000 for b in specials]:
        x = from_bits(b)
        mant, exp = c_encode_float(x)
        assert value_bytes(x) == struct.pack(">Bii", 2, mant, exp), hex(b)
        assert bits(value_of(value_bytes(x))) == b, hex(b)


def test_many_float32_bit_patterns_round_trip_bit_exactly() -> None:
    """200k random finite float32 patterns (incl. subnormals): C's bytes, exact round trip."""
    rng = np.random.default_rng(20240611)
    pats = rng.integers(0, 2**32, size=200_000, dtype=np.uint64).astype(np.uint32)
    pats[:1000] &= np.uint32(0x807FFFFF)  # force some subnormals (and zeros)
    xs = pats.view(np.float32)
    xs = xs[np.isfinite(xs)]
    # The C encoder, vectorized in float32 (docs/wire-format.md#objects):
    # mant = (|f| - 0.5) * 2.0f * 2147483646.0f
    f, e = np.frexp(xs)
    with np.errstate(all="ignore"):
        m = ((np.abs(f) - np.float32(0.5)) * np.float32(2.0) * np.float32(2147483646.0)).astype(
            np.int64
        ) + 1
    m = np.where(xs < 0, -m, m)
    m = np.where(xs == 0, 0, m)
    e = np.where(xs == 0, 0, e)
    for x, mant, exp in zip(xs.tolist(), m.tolist(), e.tolist(), strict=True):
        data = value_bytes(x)
        assert data == struct.pack(">Bii", 2, mant, exp)
        y = value_of(data)
        if x == 0:
            assert bits(y) == 0  # -0.0 arrives as 0.0
        else:
            assert bits(y) == bits(x)


@given(st.integers(0, 2**32 - 1))
def test_every_finite_float32_round_trips(b: int) -> None:
    x = from_bits(b)
    if not math.isfinite(x):
        return
    data = value_bytes(x)
    assert data == struct.pack(">Bii", 2, *c_encode_float(x))
    y = value_of(data)
    assert bits(y) == (0 if x == 0 else b)


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_float64_is_rounded_to_float32_first(x: float) -> None:
    y = value_of(value_bytes(x))
    assert bits(y) == bits(f32(x) + 0.0)  # + 0.0 maps -0.0 to 0.0


def canonical(f: int) -> int:
    """The mantissa C sends for 23 fraction bits |f| and the sign of f."""
    return abs(f) * 256 + 1 if f >= 0 else -(abs(f) * 256 + 1)


@given(
    st.one_of(
        st.integers(-(2**31), 2**31 - 1), st.integers(-(2**23) + 1, 2**23 - 1).map(canonical)
    ),
    st.one_of(st.integers(-160, 140), st.integers(-(2**31), 2**31 - 1)),
)
def test_any_mantissa_exponent_decodes_as_c_does(mant: int, exp: int) -> None:
    data = struct.pack(">Bii", 2, mant, exp)
    got = value_of(data)
    if mant == -0x7FFFFFFF and exp == 0:
        assert math.isnan(got)  # our NaN policy
        return
    want = c_decode_float(mant, exp)
    assert math.copysign(1.0, got) == math.copysign(1.0, want)
    assert got == want


@pytest.mark.parametrize(
    ("mant", "exp"),
    [
        (0x00000101, 0),  # canonical
        (0x000001FF, 3),  # non-canonical low bits
        (0x7FFFFFFF, 0),  # |mant| - 1 rounds up in float32
        (-0x80000000, 5),
        (0x40000142, 0),  # float32 rounds |mant| - 1 to a tie, then + 0.5 rounds to even
        (0x20000165, -3),  # the same double rounding one binade lower
        (0x7FFFFF01, -140),  # canonical mantissa, subnormal result: rounds
        (0x12345701, -126),  # canonical, just below the normal range
        (0x12345701, -125),  # canonical, smallest normal exponent
        (0x7FFFFF81, -140),  # non-canonical, subnormal result
        (0x12345679, -149),
        (1, 128),  # largest finite exponent
        (1, 129),  # overflow -> inf
        (-3, 2**31 - 1),  # beyond double range
        (5, -(2**31)),  # underflow to 0
        (-5, -(2**31)),  # underflow to -0
        (0, 77),  # mant 0 ignores the exponent
    ],
)
def test_edge_mantissas_decode_as_c_does(mant: int, exp: int) -> None:
    got = value_of(struct.pack(">Bii", 2, mant, exp))
    want = c_decode_float(mant, exp)
    assert (got, math.copysign(1.0, got)) == (want, math.copysign(1.0, want))


def test_inf_and_nan_policy() -> None:
    inf = math.inf
    assert value_bytes(inf) == h("02 00000001 00000081")
    assert value_bytes(-inf) == h("02 ffffffff 00000081")
    assert value_bytes(math.nan) == h("02 80000001 00000000")  # what the C VM sends on x86
    assert value_bytes(-math.nan) == h("02 80000001 00000000")
    assert value_bytes(1e39) == value_bytes(inf)  # rounds to binary32 inf first
    assert value_of(h("02 00000001 00000081")) == inf
    assert value_of(h("02 ffffffff 00000081")) == -inf
    assert math.isnan(value_of(h("02 80000001 00000000")))
    # What a C peer makes of our bytes: the infinities survive; NaN is x86's -1.0.
    assert c_decode_float(1, 129) == inf
    assert c_decode_float(-1, 129) == -inf
    assert c_decode_float(-0x7FFFFFFF, 0) == -1.0
    # No finite value encodes to the NaN pattern: the largest |mant| is 2**31 - 255.
    assert value_bytes(from_bits(0xFF7FFFFF)) == h("02 800000ff 00000080")
    assert value_bytes(from_bits(0x7F7FFFFF)) == h("02 7fffff01 00000080")
    # Exponent overflow anywhere decodes to inf, as ldexpf does.
    assert value_of(h("02 00000001 00000200")) == inf
    assert value_of(h("02 c0000001 7fffffff")) == -inf


# ---------------------------------------------------------------- round trips

int32s = st.integers(-(2**31), 2**31 - 1)
f32s = st.floats(width=32)
latin1 = st.text(alphabet=st.characters(max_codepoint=255), max_size=20)
keys = st.one_of(int32s, st.floats(width=32, allow_nan=False), latin1)
scalars = st.one_of(
    st.none(),
    int32s,
    f32s,
    latin1,
    st.builds(WireClosure, st.booleans(), st.integers(0, 2**32 - 1)),
)


def tables(children: st.SearchStrategy) -> st.SearchStrategy:
    return st.dictionaries(keys, children, max_size=6).map(Table)


values = st.recursive(scalars, tables, max_leaves=30)
u16 = st.integers(0, 0xFFFF)
messages = st.one_of(
    st.builds(Broadcast, latin1, values),
    st.builds(SwarmList, st.lists(u16, max_size=20).map(tuple)),
    st.builds(VstigPut, u16, keys, values, u16, u16),
    st.builds(VstigQuery, u16, keys, values, u16, u16),
    st.builds(SwarmJoin, u16),
    st.builds(SwarmLeave, u16),
)


def without_nil(v: object) -> object:
    """What a receiver sees: nil table entries are dropped."""
    if v.__class__ is Table:
        return Table({k: without_nil(x) for k, x in v.items() if x is not None})
    return v


@given(values)
def test_values_round_trip(v: object) -> None:
    data = value_bytes(v)
    got = value_of(data)
    assert norm(got) == norm(normalize_zero(without_nil(v)))
    assert value_bytes(got) == data or has_nil_entry(v)


def normalize_zero(v: object) -> object:
    """-0.0 travels as 0.0, in keys and values."""
    if v.__class__ is float and v == 0:
        return 0.0
    if v.__class__ is Table:
        return Table({normalize_zero(k): normalize_zero(x) for k, x in v.items()})
    return v


def has_nil_entry(v: object) -> bool:
    return v.__class__ is Table and any(x is None or has_nil_entry(x) for x in v.values())


@given(st.dictionaries(latin1, int32s, max_size=30))
def test_table_order_is_kept(d: dict) -> None:
    t = Table(d)
    got = value_of(value_bytes(t))
    assert list(got) == list(t)


@given(messages)
def test_messages_round_trip(msg: wire.Message) -> None:
    data = encode(msg)
    got = decode(data)
    assert got.__class__ is msg.__class__
    assert encode(got) == encode(decode(encode(got)))
    if not has_nil_entry(getattr(msg, "value", None)):
        assert encode(got) == data
    assert got == decode(data)
    assert hash(got) == hash(decode(data))


# ---------------------------------------------------------------- message behaviour


def test_message_equality_is_structural() -> None:
    assert Broadcast("a", Table(x=1)) == Broadcast("a", Table(x=1))
    assert Broadcast("a", Table(x=1)) != Broadcast("a", Table(x=2))
    assert Broadcast("a", Table(x=1)) != Broadcast("b", Table(x=1))
    assert Broadcast("a", 1) != Broadcast("a", 1.0)  # int and float differ on the wire
    assert Broadcast("a", math.nan) == Broadcast("a", math.nan)
    assert Broadcast("a", 0.0) == Broadcast("a", -0.0)
    assert VstigPut(1, "k", None, 1, 2) != VstigQuery(1, "k", None, 1, 2)
    assert SwarmJoin(3) != SwarmLeave(3)
    assert SwarmList((1, 2)) == SwarmList((1, 2))
    assert hash(Broadcast("a", Table(x=1))) == hash(Broadcast("a", Table(x=1)))
    assert len({SwarmJoin(3), SwarmJoin(3), SwarmLeave(3)}) == 2
    cyclic = Table()
    cyclic["me"] = cyclic
    other = Table()
    other["me"] = other
    assert Broadcast("a", cyclic) == Broadcast("a", cyclic)
    assert Broadcast("a", cyclic) != Broadcast("a", other)  # no infinite recursion
    with pytest.raises(FrozenInstanceError):
        SwarmJoin(3).swarm = 4  # type: ignore[misc]


def test_decoder_accepts_bytes_like() -> None:
    data = h("00 03 0003 636d64 01 00000016")
    assert decode(bytearray(data)) == decode(memoryview(data)) == Broadcast("cmd", 22)
    assert decode_value(memoryview(data), 1) == ("cmd", 7)


def test_nil_entries_and_duplicate_keys() -> None:
    # A nil value on the wire is dropped, as Buzz tables hold no nil.
    got = value_of(h("04 02 03 0001 61 00 03 0001 62 01 00000001"))
    assert list(got.items()) == [("b", 1)]
    # A repeated key: the later entry wins (C's table set does the same).
    got = value_of(h("04 02 03 0001 61 01 00000001 03 0001 61 01 00000002"))
    assert dict(got) == {"a": 2}
    # Entries holding None in a Table are skipped on encode (count counts what is written).
    assert value_bytes(Table(a=None, b=1)) == h("04 01 03 0001 62 01 00000001")


# ---------------------------------------------------------------- encode errors


def nested(depth: int) -> Table:
    t: Table = Table(x=1)
    for _ in range(depth - 1):
        t = Table(x=t)
    return t


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ("x" * 65536, "65536 bytes"),
        (Table({i: 1 for i in range(256)}), "256 entries"),
        (Userdata(object()), "userdata"),
        (Closure(3, False, (None, 1), lambda *a: None), "activation record of 2"),
        (Closure(-1, False, (None,), lambda *a: None), "not a u32"),
        (Table({Table(): 1}), "key"),
        (Table({None: 1}), "key"),
        (Table({math.nan: 1}), "key"),
        (Table({"k": Userdata(1)}), "userdata"),
        (2**31, "outside int32"),
        (-(2**31) - 1, "outside int32"),
        (True, "bool"),
        ({"a": 1}, "dict"),
        ("caf\u00e9\u20ac", "index 4"),
        (Table({"\u20ac": 1}), "index 0"),
        (nested(33), "deeper than 32"),
    ],
)
def test_encode_errors(value: object, words: str) -> None:
    out = bytearray(b"prefix")
    with pytest.raises(EncodeError, match=words):
        encode_value(value, out)
    assert out == b"prefix"  # untouched on failure
    with pytest.raises(EncodeError, match=words):
        encode(Broadcast("t", value))


def test_encode_limits_are_inclusive() -> None:
    assert len(value_bytes("x" * 65535)) == 3 + 65535
    assert value_bytes(Table({i: 1 for i in range(255)}))[1] == 255
    almost = Table({i: 1 for i in range(255)})
    almost["nil"] = None  # 256 keys, 255 entries on the wire
    assert value_bytes(almost)[1] == 255
    assert value_of(value_bytes(nested(32))) is not None


def test_cyclic_table_is_refused() -> None:
    t = Table(a=1)
    t["self"] = t
    with pytest.raises(EncodeError, match="cyclic"):
        encode_value(t, bytearray())


@pytest.mark.parametrize(
    ("msg", "words"),
    [
        (SwarmJoin(65536), "swarm must be an int in 0..65535, got 65536"),
        (SwarmLeave(-1), "swarm .* got -1"),
        (SwarmList((1, 70000)), "id .* got 70000"),
        (SwarmList(tuple(range(65536))), "65536 ids"),
        (VstigPut(65536, "k", 1, 1, 1), "vstig .* 65536"),
        (VstigPut(1, "k", 1, 70000, 1), "timestamp .* 70000"),
        (VstigQuery(1, "k", 1, 1, -2), "robot .* -2"),
        (VstigPut(1, None, 1, 1, 1), "key None"),
        (VstigPut(1, Table(), 1, 1, 1), "key"),
        (VstigPut(1, math.nan, 1, 1, 1), "key nan"),
        (Broadcast(5, 1), "topic must be a string"),  # type: ignore[arg-type]
        (VstigPut(1, "k", Userdata(1), 1, 1), "userdata"),
        ("not a message", "not a Buzz message"),
    ],
)
def test_message_encode_errors(msg: wire.Message, words: str) -> None:
    with pytest.raises(EncodeError, match=words):
        encode(msg)


# ---------------------------------------------------------------- decode errors


@pytest.mark.parametrize(
    ("hexbytes", "words"),
    [
        ("", "empty payload"),
        ("06", "unknown message type 6"),
        ("ff 0001", "unknown message type 255"),
        ("00", "truncated BROADCAST at byte 1"),
        ("00 01 00000001 00", "BROADCAST topic at byte 1 is int: it must be a string"),
        ("00 03 000c 616263", "truncated string at byte 1: length 12 but 3 bytes left"),
        ("00 03 00", "truncated string length at byte 1"),
        ("00 03 0001 61", "truncated object at byte 5"),
        ("00 03 0001 61 06", "userdata \\(tag 6\\) at byte 5"),
        ("00 03 0001 61 09", "unknown tag 9 at byte 5"),
        ("00 03 0001 61 01 0000", "truncated int at byte 5: needs 5 bytes, 3 left"),
        ("00 03 0001 61 02 00000001 0000", "truncated float at byte 5"),
        ("00 03 0001 61 05 01 0000", "truncated closure at byte 5"),
        ("00 03 0001 61 04", "truncated table count at byte 5"),
        ("00 03 0001 61 04 02 03 0001 62 00", "truncated object at byte 12"),
        ("00 03 0001 61 04 01 00 01 00000001", "key at byte 7 is nil"),
        ("00 03 0001 61 04 01 04 00 00", "key at byte 7 is table"),
        ("00 03 0001 61 04 01 02 80000001 00000000 00", "key at byte 7 is NaN"),
        ("00 03 0001 61 04 01 03 0005 62", "truncated string at byte 7: length 5 but 1"),
        ("00 03 0001 61 00 00", "trailing bytes: .* ends at byte 6 .* 7 bytes \\(1 extra\\)"),
        ("01", "truncated SWARM_LIST count at byte 1"),
        ("01 ffff 0001", "truncated SWARM_LIST at byte 3: 65535 ids need 131070 bytes, 2 left"),
        ("01 0001 0003 00", "trailing bytes"),
        ("02 00", "truncated VSTIG_PUT vstig id at byte 1"),
        ("02 0005", "truncated object at byte 3"),
        ("02 0005 03 0001 6b 00 0001", "truncated VSTIG_PUT timestamp and robot at byte 8"),
        ("03 0005 00 00 0000 0007", "key at byte 3 is nil"),
        ("03 0005 05 01 00000001 00 0000 0007", "key at byte 3 is closure"),
        ("04 00", "truncated SWARM_JOIN swarm id at byte 1"),
        ("05 0003 03", "trailing bytes: the SWARM_LEAVE message ends at byte 3"),
    ],
)
def test_decode_errors(hexbytes: str, words: str) -> None:
    with pytest.raises(DecodeError, match=words):
        decode(h(hexbytes))


def test_decode_nesting_limit() -> None:
    head = h("00 03 0001 61")
    deep32 = head + h("04 01 03 0001 78") * 31 + h("04 00")
    assert decode(deep32).topic == "a"
    deep33 = head + h("04 01 03 0001 78") * 32 + h("04 00")
    with pytest.raises(DecodeError, match=f"table at byte {5 + 32 * 6} nested deeper than 32"):
        decode(deep33)
    bomb = head + h("04 ff 03 0001 78") * 10_000  # each level claims 255 entries
    with pytest.raises(DecodeError, match="nested deeper than 32"):
        decode(bomb)


ALL_GOLDEN = [h(g[2]) for g in GOLDEN_MESSAGES] + [
    h("00 03 0001 61") + h(v) for _, v in GOLDEN_VALUES
]


def test_every_truncation_is_a_decode_error() -> None:
    for data in ALL_GOLDEN:
        decode(data)
        for n in range(len(data)):
            with pytest.raises(DecodeError) as info:
                decode(data[:n])
            text = str(info.value)
            assert "byte" in text or text == "empty payload", text


def test_every_single_byte_change_decodes_or_raises_decode_error() -> None:
    for data in ALL_GOLDEN:
        for i in range(len(data)):
            for b in (0x00, 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x7F, 0x80, 0xFF):
                mutated = data[:i] + bytes([b]) + data[i + 1 :]
                try:
                    msg = decode(mutated)
                except DecodeError:
                    continue
                assert encode(decode(encode(msg))) == encode(msg)


@settings(max_examples=300)
@given(st.binary(max_size=64))
def test_random_bytes_only_raise_decode_error(data: bytes) -> None:
    try:
        decode(data)
    except DecodeError:
        pass
