"""Assembler: parsing rules, .bo bytes, .bdb layout, C number conversions (docs/bytecode.md)."""

from __future__ import annotations

import ctypes
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bvm.assembler import DebugEntry, DebugMap, assemble, parse_bdb, strtof_bits, strtoul
from bvm.compiler import compile_asm
from bvm.errors import BuzzAsmError

P = "/nonexistent/dir/prog.bzz"


def bo_of(basm: str) -> bytes:
    return assemble(basm)[0]


def code_of(lines: str) -> bytes:
    """Bytes after a `!0` header for some instruction lines."""
    return bo_of("!0\n" + lines)[2:]


# -- worked examples (docs/bytecode.md#bo-layout) -----------------------------------------


def test_worked_example_bytes() -> None:
    bo, _ = assemble(compile_asm(b"x = 3.14\ny = -0.5\nz = 1.", P))
    assert bo == bytes.fromhex(
        "0300 7800 7900 7a00"
        "00"
        "25 00000000 23 c3f54840 1d"
        "25 01000000 23 000000bf 1d"
        "25 02000000 23 0000803f 1d"
        "01"
    )


def test_closure_prefix_points_at_the_function() -> None:
    # Shaped like testclosure.bzz: 3 strings f, t, x and f's chunk at offset 80.
    src = b"function f() {return self}\nt = {.f = f}\nx = t.f()\nx = nil\nx = nil\n"
    bo, _ = assemble(compile_asm(src, P))
    assert bo[:20] == bytes.fromhex("0300 6600 7400 7800 25 00000000 26 50000000 1d 00")
    assert bo[80:82] == bytes.fromhex("29 00")  # lload 0: first instruction of f


def test_empty_program_is_three_bytes() -> None:
    bo, bdb = assemble(compile_asm(b"", P))
    assert (bo, bdb) == (b"\x00\x00\x00", b"")


# -- line rules (docs/bytecode.md#basm-text) ---------------------------------------------


def test_strings_keep_everything_but_the_last_character() -> None:
    assert bo_of("!2\n'a b  \n  'x|y,#\n") == b"\x02\x00a b  \x00x|y,#\x00"
    assert bo_of("!1\r\n'a\r\n") == b"\x01\x00a\r\x00"  # CR stays, C strtol stops at it
    assert bo_of("!1\n'abc") == b"\x01\x00ab\x00"  # no final newline: a real byte goes


def test_comments_blank_lines_and_whitespace() -> None:
    assert code_of("# comment\n\n   \n\t  # indented comment\n\tnop  \t\n") == b"\x00"


def test_string_count_is_strtol_truncated_to_16_bits() -> None:
    assert bo_of("!65537\n") == b"\x01\x00"
    assert bo_of("!-1\n") == b"\xff\xff"
    assert bo_of("!junk\n") == b"\x00\x00"
    assert bo_of("! 7x\n") == b"\x07\x00"


@pytest.mark.parametrize(
    ("arg", "value"),
    [
        ("-5", 0xFFFFFFFB),
        ("3000000000", 3000000000),
        ("+5", 5),
        ("007", 7),
        ("4294967296", 0),
        ("99999999999999999999999", 0xFFFFFFFF),
        ("-99999999999999999999999", 0xFFFFFFFF),
        ("12abc", 12),
        ("0", 0),
    ],
)
def test_int_arguments_follow_strtoul(arg: str, value: int) -> None:
    assert code_of(f"\tpushi {arg}\n") == b"\x24" + struct.pack("<I", value)


@pytest.mark.parametrize(
    ("arg", "value"),
    [("3.14", 3.14), ("1.", 1.0), ("1..2", 1.0), ("1.2.3", 1.2), ("-0.5", -0.5), ("+2", 2.0)],
)
def test_float_arguments_follow_strtof(arg: str, value: float) -> None:
    assert code_of(f"\tpushf {arg}\n") == b"\x23" + struct.pack("<f", value)


def test_float_rounding_is_direct_to_binary32() -> None:
    # 1 + 2**-24 + 2**-60: a double holds 1 + 2**-24 (a tie, rounding down to 1.0),
    # but the decimal value is just above the tie and must round up.
    text = "1.00000005960464477539929117858"
    assert strtof_bits(text.encode()) == 0x3F800001
    assert struct.unpack("<I", struct.pack("<f", float(text)))[0] == 0x3F800000


def test_labels_and_references() -> None:
    out = code_of("@a\n\tjump @b\n@b|1,2,f\n\tpushcn @a\n\tpushl @b\n\tpushi @a\n")
    assert out == bytes.fromhex("2c 07000000 26 02000000 28 07000000 24 02000000")


def test_label_redefinition_last_one_wins() -> None:
    out = code_of("@x\n\tnop\n@x\n\tjump @x\n")
    assert out == bytes.fromhex("00 2c 03000000")


def test_label_trailing_whitespace_is_trimmed() -> None:
    assert code_of("@x \t|1,2,f\n\tjump @x\t|1,2,f\n") == bytes.fromhex("2c 02000000")


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        ("!0\n\tfoo\n", 2, 'unknown instruction "foo"'),
        ("!0\n\tpushi\n", 2, "missing argument for pushi"),
        ("!0\n\tpushi  5\n", 2, "missing argument for pushi"),
        ("!0\n\tnop\n\tjump @nowhere\n", 3, 'unknown label "@nowhere"'),
        ("!0\n\tjump @end\n@end\n", 2, 'label "@end" is at the end of the code'),
        ("!0\n\tjump 5x\n", 2, 'unknown label "5x"'),
        ("!0\n\tnop|1\n", 2, "malformed debug information (expected |line,col,file)"),
        ("!0\n\t.bytes 1 zz\n", 2, 'bad byte "zz" in .bytes'),
        ('!1\n"abc\n', 2, "malformed escaped string"),
    ],
)
def test_errors(text: str, line: int, message: str) -> None:
    with pytest.raises(BuzzAsmError) as info:
        assemble(text, "x.basm")
    assert (info.value.path, info.value.line, info.value.message) == ("x.basm", line, message)
    assert str(info.value) == f"x.basm:{line}: {message}"


def test_argument_on_a_no_argument_opcode_only_warns() -> None:
    with pytest.warns(UserWarning, match="nop takes no argument"):
        assert code_of("\tnop 5\n") == b"\x00"


def test_jump_argument_is_always_a_label_in_reference_forms() -> None:
    # `@5` is a label name even though pushi would read a number from `5`.
    assert code_of("@5\n\tjump @5\n") == bytes.fromhex("2c 02000000")


# -- debug info (docs/bytecode.md#bdb-layout) --------------------------------------------


def test_bdb_record_layout() -> None:
    _, bdb = assemble("!0\n\tnop\t|7,3,/a/b.bzz\n")
    assert bdb == struct.pack("<IQQH", 2, 7, 3, 8) + b"/a/b.bzz"
    assert parse_bdb(bdb) == [(2, DebugEntry(7, 3, b"/a/b.bzz"))]


def test_bdb_bucket_order() -> None:
    # Offsets 2..106 (nop each): records come out by offset % 100, then insertion.
    lines = "".join(f"\tnop\t|{i},0,f\n" for i in range(105))
    _, bdb = assemble("!0\n" + lines)
    offsets = [off for off, _ in parse_bdb(bdb)]
    assert offsets[:4] == [100, 101, 2, 102]
    assert offsets == sorted(range(2, 107), key=lambda o: (o % 100, o))


def test_label_debug_info_is_replaced_by_the_instruction() -> None:
    _, bdb = assemble("!0\n@l\t|1,1,label\n\tdone\t|2,2,instr\n@end\t|3,3,end\n")
    assert parse_bdb(bdb) == [(2, DebugEntry(2, 2, b"instr")), (3, DebugEntry(3, 3, b"end"))]


def test_debug_map_reinsert_moves_to_bucket_end() -> None:
    dm = DebugMap()
    for off in (5, 105, 205):
        dm.set(off, DebugEntry(off, 0, b"f"))
    dm.set(5, DebugEntry(9, 9, b"g"))
    assert [o for o, _ in dm.ordered()] == [105, 205, 5]
    assert dm.entries[5] == DebugEntry(9, 9, b"g")


def test_debug_field_rules() -> None:
    # Split on `,` and the next `|`: a file name with either is truncated (reference).
    _, bdb = assemble("!0\n\tnop\t|1,2,/a,b|c\n\tnop\t| 3 , 4,(null)\n")
    assert parse_bdb(bdb) == [(2, DebugEntry(1, 2, b"/a")), (3, DebugEntry(3, 4, b"(null)"))]


def test_compiled_program_debug_info() -> None:
    _, bdb = assemble(compile_asm(b"x = 3.14\ny = -0.5\nz = 1.", P))
    records = parse_bdb(bdb)
    assert records[0] == (9, DebugEntry(1, 2, P.encode()))
    assert records[-2:] == [(41, DebugEntry(0, 1, b"(null)")), (42, DebugEntry(0, 1, b"(null)"))]
    assert len(records) == 10


# -- fieldkit superset ---------------------------------------------------------------


def test_superset_forms() -> None:
    bo, bdb = assemble(
        '!2\n"a\\n\\x00\\xff\\"\\\\"\n  "t\\tr\\r"\n'
        '\t.bytes 2f ff 0\t|1,2,"odd,|\\x01name"\n'
        "\tpushf bits:0x7fc00001\n\tjump 7\n\tjumpz 0\n"
    )
    assert bo == (
        b'\x02\x00a\n\x00\xff"\\\x00t\tr\r\x00'
        + bytes.fromhex("2f ff 00 23 0100c07f 2c 07000000 2d 00000000")
    )
    assert parse_bdb(bdb) == [(14, DebugEntry(1, 2, b"odd,|\x01name"))]


def test_unencodable_text_is_an_asm_error() -> None:
    with pytest.raises(BuzzAsmError) as info:
        assemble("!1\n'\ud800\n")
    assert info.value.line == 2


BASM_PIECES = st.sampled_from(
    ["!", "'", '"', "@", "|", ",", " ", "\t", "\n", "#", "\\", "x", "0", "-", "1.5", "nan",
     "@a", "pushi", "pushf", "jump", "jumpz", "pushcn", "nop", "done", ".bytes", "ff", "bits:",
     "\xff", "\ud800", "\r"]
)  # fmt: skip


@settings(max_examples=300, deadline=None)
@given(st.lists(BASM_PIECES, max_size=30).map("".join))
def test_malformed_basm_only_raises_asm_errors(text: str) -> None:
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            bo, bdb = assemble(text)
        except BuzzAsmError:
            return
    assert parse_bdb(bdb) is not None and isinstance(bo, bytes)


def test_str_input_is_one_char_per_byte() -> None:
    text = "!1\n'\xff\xc3\xa9\n"
    assert bo_of(text) == b"\x01\x00\xff\xc3\xa9\x00"
    assert assemble(b"!1\n'\xff\n")[0] == b"\x01\x00\xff\x00"


# -- C conversions against the C library ------------------------------------------------

try:
    _libc = ctypes.CDLL(None)
    _libc.strtof.restype = ctypes.c_float
    _libc.strtof.argtypes = [ctypes.c_char_p, ctypes.c_void_p]
    _libc.strtoul.restype = ctypes.c_ulong
    _libc.strtoul.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_void_p), ctypes.c_int]
    _libc.strtof(b"1", None)
    HAVE_LIBC = ctypes.sizeof(ctypes.c_ulong) == 8
except (OSError, AttributeError):  # pragma: no cover - non-glibc platforms
    HAVE_LIBC = False

needs_libc = pytest.mark.skipif(not HAVE_LIBC, reason="needs a 64-bit C library via ctypes")


def c_strtof_bits(text: bytes) -> int:
    return struct.unpack("<I", struct.pack("<f", _libc.strtof(text, None)))[0]


number_text = st.one_of(
    st.from_regex(r"\A[ +-]?[0-9]{0,30}(\.[0-9]{0,30})?([eE][+-]?[0-9]{1,3})?[.0-9a-z]{0,3}\Z"),
    st.from_regex(r"\A-?0[xX][0-9a-fA-F]{0,12}(\.[0-9a-f]{0,6})?([pP][+-]?[0-9]{1,3})?\Z"),
    st.from_regex(r"\A-?(nan|NaN|inf|INFINITY)(\([0-9a-zA-Z_]{0,8}\))?\Z"),
    st.floats(width=32, allow_nan=False).map(lambda f: repr(f)),
    st.text(alphabet="0123456789.-+e ", max_size=12),
).map(str.encode)


@needs_libc
@settings(max_examples=400, deadline=None)
@given(number_text)
def test_strtof_matches_the_c_library(text: bytes) -> None:
    assert strtof_bits(text) == c_strtof_bits(text)


@needs_libc
@pytest.mark.parametrize(
    "text",
    [
        b"1e-45", b"7.006492321624085e-46", b"7.006492321624086e-46", b"3.4028235e38",
        b"3.40282356779733661637539395458142568448e38", b"1" + b"0" * 5000 + b"e-5000",
        b"0." + b"0" * 4000 + b"1e4000", b"1e-99999999999", b"1e99999999999", b"0x1p-150",
        b"0x1.000002p-150", b"0x1.fffffep127", b"0x1.ffffffp127", b"1.17549421e-38",
        b"1.1754942e-38", b"nan(0x3fffff)", b"nan(0777)", b"-nan(12)", b"nan(0x)",
    ],
)  # fmt: skip
def test_strtof_hard_cases(text: bytes) -> None:
    assert strtof_bits(text) == c_strtof_bits(text)


@needs_libc
@settings(max_examples=300, deadline=None)
@given(st.from_regex(r"\A[ \t]*[+-]?[0-9]{0,25}[a-z@_]{0,3}\Z").map(str.encode))
def test_strtoul_matches_the_c_library(text: bytes) -> None:
    buf = ctypes.create_string_buffer(text)
    end = ctypes.c_void_p()
    value = _libc.strtoul(ctypes.addressof(buf), ctypes.byref(end), 10)
    consumed = (end.value or 0) - ctypes.addressof(buf)
    ours, digits = strtoul(text)
    assert ours == value
    assert digits == (consumed != 0)
