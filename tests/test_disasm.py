"""Disassembler: readable output and exact .bo round trips, for compiled and hostile input."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bvm.assembler import DebugEntry, DebugMap, assemble, parse_bdb
from bvm.compiler import build
from bvm.disasm import disassemble
from bvm.errors import BuzzLoadError

P = "/nonexistent/dir/prog.bzz"

PROGRAMS = [
    b"",
    b"x = 3.14\ny = -0.5\nz = 1.",
    b"function f() {return self}\nt = {.f = f}\nx = t.f()",
    b"""function fact(n) { if (n <= 1) { return 1 } else { return n * fact(n - 1) } }
t = {.a = 1, .b = "hi", .7 = 2.5, .f = function(y) { return self.a + y }}
i = 0
while (i < 3) { log(fact(i), t.f(i), t["b"]) i = i + 1 }
for (i = 0, i < 10, i = i + 1) log(!i, -i^2, i % 3, i << 2, (i == 2) and (not nil))
function g(a, b) "doc" { var c = function(d) { return a + d } return c(b) }
""",
    b'log("tab\\there", "\xc3\xa9t\xc3\xa9", "back\\\\slash", "comma,pipe|")',
]


def roundtrip(bo: bytes, bdb: bytes | None = None) -> tuple[bytes, bytes]:
    return assemble(disassemble(bo, bdb), "<disasm>")


@pytest.mark.parametrize("src", PROGRAMS)
def test_compiled_programs_round_trip_with_debug_info(src: bytes) -> None:
    bo, bdb = build(src, P)
    assert roundtrip(bo, bdb) == (bo, bdb)
    assert roundtrip(bo)[0] == bo


def test_readable_output() -> None:
    bo, bdb = build(b"function f() {return self}\nx = f()\nif (x) x = 1.5", P)
    text = disassemble(bo, bdb)
    lines = text.split("\n")
    assert lines[1:7] == ["!2", "'f", "'x", "", "\tpushs 0", "\tpushcn @L60"]
    assert f"\tpushf 1.5\t|3,11,{P}" in lines
    assert "@L60" in lines and "@L59" in lines and "\tjumpz @L59\t|3,7," + P in lines
    assert "\tdone\t|0,1,(null)" in lines


@given(st.binary(max_size=60))
def test_output_is_ascii(bo: bytes) -> None:
    assert disassemble(bo).isascii()


def test_compiled_disassembly_is_plain_reference_basm() -> None:
    # No superset form is needed for ordinary programs.
    bo, bdb = build(PROGRAMS[3], P)
    text = disassemble(bo, bdb)
    assert ".bytes" not in text and "bits:" not in text and '"' not in text.replace("'hi", "")


@pytest.mark.parametrize(
    ("bo", "expected"),
    [
        (b"", []),
        (b"\x05", ["\t.bytes 05"]),
        (b"\x00\x00\x2f\x00\xff", ["!0", "", "\t.bytes 2f", "\tnop", "\t.bytes ff"]),
        (b"\x00\x00\x24\x01\x02", ["!0", "", "\t.bytes 24 01 02"]),
        (b"\x01\x00a\nb\x00\xff\x00", ["!1", '"a\\nb"', "", "\t.bytes ff", "\tnop"]),
        (b"\x03\x00ab", ["!3", "", "\t.bytes 61 62"]),
        (b"\x02\x00\xe9\x00 x\x00", ["!2", '"\\xe9"', '" x"', ""]),
        (b"\x00\x00\x23\x01\x00\xc0\xff", ["!0", "", "\tpushf bits:0xffc00001"]),
        (b"\x00\x00\x23\x00\x00\x80\xff", ["!0", "", "\tpushf -inf"]),
        (b"\x00\x00\x23\x00\x00\x00\x80", ["!0", "", "\tpushf -0"]),
        (b"\x00\x00\x23\x01\x00\x00\x00", ["!0", "", "\tpushf 1e-45"]),
        (b"\x00\x00\x2c\x03\x00\x00\x00", ["!0", "", "\tjump 3"]),
        (b"\x00\x00\x26\x07\x00\x00\x00", ["!0", "", "\tpushcn 7"]),
        (b"\x00\x00\x24\xfb\xff\xff\xff", ["!0", "", "\tpushi -5"]),
        (b"\x00\x00\x25\xff\xff\xff\xff", ["!0", "", "\tpushs 4294967295"]),
    ],
)
def test_hostile_bytes(bo: bytes, expected: list[str]) -> None:
    text = disassemble(bo)
    assert text.split("\n")[1:-1] == expected
    assert assemble(text)[0] == bo


def test_jump_into_the_middle_of_an_instruction() -> None:
    bo = b"\x00\x00" + bytes.fromhex("2c 03000000") + bytes.fromhex("24 00000000")
    text = disassemble(bo)
    assert "\tjump 3" in text and "@L" not in text
    assert assemble(text)[0] == bo


def test_debug_entries_split_instructions_and_odd_names_are_escaped() -> None:
    bo = b"\x00\x00" + bytes.fromhex("24 01000000 00")
    dm = DebugMap()
    dm.set(2, DebugEntry(1, 2, b"a,b|c"))
    dm.set(4, DebugEntry(3, 4, b""))  # inside pushi: that becomes raw bytes
    dm.set(7, DebugEntry(5, 6, b"\xff\n"))
    dm.set(8, DebugEntry(7, 8, b" end"))  # at the end of the file
    dm.set(99, DebugEntry(9, 9, b"far"))  # beyond the file: dropped, noted
    text = disassemble(bo, dm.to_bytes())
    assert '\t.bytes 24 01\t|1,2,"a,b|c"' in text
    assert '\tnop\t|3,4,""' in text  # decoding resumes at the debug offset
    assert '\tnop\t|5,6,"\\xff\\n"' in text
    assert '@__end\t|7,8," end"' in text
    assert "# .bdb entry dropped (offset 99" in text
    new_bo, new_bdb = assemble(text)
    assert new_bo == bo
    assert dict(parse_bdb(new_bdb)) == {k: v for k, v in dm.entries.items() if k != 99}


def test_corrupted_bdb_is_a_load_error() -> None:
    with pytest.raises(BuzzLoadError):
        disassemble(b"\x00\x00\x00", b"\x01\x02")


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_any_bytes_round_trip(bo: bytes) -> None:
    assert roundtrip(bo)[0] == bo


opcode_soup = st.lists(
    st.one_of(
        st.sampled_from(range(47)).map(lambda op: bytes([op])),
        st.tuples(st.sampled_from(range(35, 47)), st.integers(0, 2**32 - 1)).map(
            lambda t: bytes([t[0]]) + struct.pack("<I", t[1])
        ),
        st.tuples(st.sampled_from([38, 40, 44, 45, 46]), st.integers(0, 80)).map(
            lambda t: bytes([t[0]]) + struct.pack("<I", t[1])
        ),
        st.binary(min_size=1, max_size=3),
    ),
    max_size=30,
).map(b"".join)


@st.composite
def bo_with_bdb(draw: st.DrawFn) -> tuple[bytes, bytes]:
    strings = draw(st.lists(st.binary(max_size=6).filter(lambda s: b"\0" not in s), max_size=4))
    bo = struct.pack("<H", len(strings)) + b"".join(s + b"\0" for s in strings) + draw(opcode_soup)
    dm = DebugMap()
    for _ in range(draw(st.integers(0, 12))):
        offset = draw(st.integers(0, len(bo) + 2))
        name = draw(st.one_of(st.just(P.encode()), st.just(b"(null)"), st.binary(max_size=8)))
        dm.set(offset, DebugEntry(draw(st.integers(0, 2**64 - 1)), draw(st.integers(0, 99)), name))
    return bo, dm.to_bytes()


@settings(max_examples=300, deadline=None)
@given(bo_with_bdb())
def test_structured_bytes_round_trip_with_debug_info(case: tuple[bytes, bytes]) -> None:
    bo, bdb = case
    new_bo, new_bdb = roundtrip(bo, bdb)
    assert new_bo == bo
    kept = dict(parse_bdb(new_bdb))
    original = dict(parse_bdb(bdb))
    assert kept.items() <= original.items()
    strings_end = _strings_end(bo)
    for offset in original:
        if strings_end <= offset <= len(bo):
            assert offset in kept


def _strings_end(bo: bytes) -> int:
    pos = 2
    for _ in range(struct.unpack_from("<H", bo)[0]):
        pos = bo.index(b"\0", pos) + 1
    return pos
