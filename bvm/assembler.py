"""Buzz assembler: .basm text -> (.bo, .bdb) bytes, byte-identical to the reference `bzzasm`.

Reference rules (docs/bytecode.md#basm-text), line by line, after skipping leading whitespace:
empty and `#` lines are ignored; `'text` appends a string (the line minus its
last character) and a NUL; `!N` appends a u16; `@name[|dbg]` defines a label;
anything else is `name[ arg][|dbg]`. `|line,col,file` debug info is attached to
the offset of the next byte. Numbers follow C's strtoul/strtof/strtol.

fieldkit superset, used by the disassembler for arbitrary .bo files (the
reference rejects all of these forms, so no reference .basm changes meaning):
* `"escaped"` line: a string with `\\\\ \\" \\n \\r \\t \\xHH` escapes (+ NUL);
* `.bytes HH HH ...[|dbg]`: raw bytes;
* `pushf bits:0xHHHHHHHH`: a float32 by its bit pattern (NaN payloads);
* `jump/jumpz/jumpnz N` with a decimal N: an absolute address, like pushcn;
* `|line,col,"escaped file"`: a debug file name containing `,` `|` or odd bytes.
"""

from __future__ import annotations

import re
import struct
import warnings
from dataclasses import dataclass, field

from bvm.errors import BuzzAsmError
from bvm.opcodes import LABEL_ONLY_OPS, NAME_TO_OP, Op

_C_SPACE = b" \t\n\v\f\r"
_U64 = (1 << 64) - 1

# -- C number parsing --------------------------------------------------------------


def _skip_space(text: bytes, i: int = 0) -> int:
    while i < len(text) and text[i] in _C_SPACE:
        i += 1
    return i


def _digits_end(text: bytes, i: int, alphabet: bytes = b"0123456789") -> int:
    while i < len(text) and text[i] in alphabet:
        i += 1
    return i


def _c_int(text: bytes, base: int, limit: int) -> int:
    """int(text, base), treating more digits than a 64-bit value can need as overflow."""
    stripped = text.lstrip(b"0")
    if len(stripped) > 64:  # never parse huge digit strings (and dodge int's digit limit)
        return limit + 1
    return int(stripped or b"0", base)


def strtoul(text: bytes) -> tuple[int, bool]:
    """C `strtoul(text, &end, 10)` on a 64-bit machine: (value, whether a digit was read)."""
    i = _skip_space(text)
    negative = i < len(text) and text[i] == 0x2D
    if i < len(text) and text[i] in b"+-":
        i += 1
    end = _digits_end(text, i)
    if end == i:
        return 0, False
    value = _c_int(text[i:end], 10, _U64)
    if value > _U64:
        return _U64, True
    return (-value & _U64) if negative else value, True


def strtol(text: bytes) -> int:
    """C `strtol(text, NULL, 10)` on a 64-bit machine (saturating)."""
    i = _skip_space(text)
    negative = i < len(text) and text[i] == 0x2D
    if i < len(text) and text[i] in b"+-":
        i += 1
    end = _digits_end(text, i)
    value = _c_int(text[i:end], 10, 1 << 63) if end > i else 0
    return max(-value, -(1 << 63)) if negative else min(value, (1 << 63) - 1)


def _strtoull_base0_whole(text: bytes) -> int | None:
    """C `strtoull(text, &end, 0)` if it consumes all of `text`, else None."""
    if text[:2].lower() == b"0x" and len(text) > 2:
        digits, base = text[2:], 16
        alphabet = b"0123456789abcdefABCDEF"
    elif text[:1] == b"0":
        digits, base, alphabet = text[1:], 8, b"01234567"
    else:
        digits, base, alphabet = text, 10, b"0123456789"
    if _digits_end(digits, 0, alphabet) != len(digits):
        return None
    return min(_c_int(digits, base, _U64), _U64) if digits else 0


def _round_f32(num: int, den: int) -> int:
    """Bits (sign excluded) of the binary32 nearest to num/den > 0, ties to even."""
    exp = num.bit_length() - den.bit_length()
    if (num << max(0, -exp)) < (den << max(0, exp)):
        exp -= 1  # now 2**exp <= num/den < 2**(exp+1)
    shift = -149 if exp < -126 else exp - 23
    n, d = (num, den << shift) if shift >= 0 else (num << -shift, den)
    mant, rem = divmod(n, d)
    if 2 * rem > d or (2 * rem == d and mant & 1):
        mant += 1
    if exp < -126:
        return mant  # subnormal; 2**23 is exactly the smallest normal's bit pattern
    if mant == 1 << 24:
        mant >>= 1
        exp += 1
    if exp > 127:
        return 0x7F800000
    return ((exp + 127) << 23) | (mant - (1 << 23))


def _decimal_bits(digits: bytes, exp10: int) -> int:
    digits = digits.lstrip(b"0")
    if not digits:
        return 0
    if len(digits) > 200:
        # Keep enough digits to decide any binary32 rounding; a sticky 1 stands
        # for the nonzero tail, so ties are never invented or lost.
        sticky = b"1" if digits[200:].strip(b"0") else b"0"
        exp10 += len(digits) - 201
        digits = digits[:200] + sticky
    k = len(digits)
    if k + exp10 <= -46:
        return 0
    if k - 1 + exp10 >= 39:
        return 0x7F800000
    mant = int(digits)
    if exp10 >= 0:
        return _round_f32(mant * 10**exp10, 1)
    return _round_f32(mant, 10**-exp10)


def _binary_bits(mant: int, exp2: int) -> int:
    if mant == 0:
        return 0
    magnitude = mant.bit_length() + exp2
    if magnitude > 129:
        return 0x7F800000
    if magnitude < -151:
        return 0
    if exp2 >= 0:
        return _round_f32(mant << exp2, 1)
    return _round_f32(mant, 1 << -exp2)


def _exponent(text: bytes, i: int, marker: bytes) -> tuple[int, int]:
    """Parse an optional `e-12` / `p+3` exponent at i: (value, index after it)."""
    if i >= len(text) or text[i] not in marker:
        return 0, i
    j = i + 1
    negative = j < len(text) and text[j] == 0x2D
    if j < len(text) and text[j] in b"+-":
        j += 1
    end = _digits_end(text, j)
    if end == j:
        return 0, i
    value = min(_c_int(text[j:end], 10, 1 << 40), 1 << 40)
    return (-value if negative else value), end


def strtof_bits(text: bytes) -> int:
    """C `strtof` (glibc) on the longest valid prefix, as float32 bits; no number -> +0.0."""
    i = _skip_space(text)
    negative = i < len(text) and text[i] == 0x2D
    if i < len(text) and text[i] in b"+-":
        i += 1
    rest = text[i:]
    lower = rest[:3].lower()
    hexdigits = b"0123456789abcdefABCDEF"
    if lower == b"inf":
        bits = 0x7F800000
    elif lower == b"nan":
        bits = 0x7FC00000
        m = re.match(rb"\(([0-9A-Za-z_]*)\)", rest[3:])
        if m:
            payload = _strtoull_base0_whole(m.group(1))
            if payload is not None:
                bits |= payload & 0x3FFFFF
    elif rest[:2].lower() == b"0x" and (
        rest[2:3]
        and rest[2] in hexdigits
        or rest[2:3] == b"."
        and rest[3:4]
        and rest[3] in hexdigits
    ):
        int_end = _digits_end(rest, 2, hexdigits)
        frac = b""
        end = int_end
        if rest[int_end : int_end + 1] == b".":
            end = _digits_end(rest, int_end + 1, hexdigits)
            frac = rest[int_end + 1 : end]
        exp2, _ = _exponent(rest, end, b"pP")
        mant = int((rest[2:int_end] + frac) or b"0", 16)
        bits = _binary_bits(mant, exp2 - 4 * len(frac))
    else:
        int_end = _digits_end(rest, 0)
        end = int_end
        frac = b""
        if rest[int_end : int_end + 1] == b".":
            end = _digits_end(rest, int_end + 1)
            frac = rest[int_end + 1 : end]
        if int_end == 0 and not frac:
            return 0  # no conversion: +0.0 whatever the sign
        exp10, _ = _exponent(rest, end, b"eE")
        bits = _decimal_bits(rest[:int_end] + frac, exp10 - len(frac))
    return bits | (0x80000000 if negative else 0)


def strtoull(text: bytes) -> int:
    """C `strtoull(text, NULL, 10)`: used for debug line and column numbers."""
    return strtoul(text)[0]


# -- escaped strings (superset) ----------------------------------------------------

_UNESCAPE = {ord("\\"): 0x5C, ord('"'): 0x22, ord("n"): 0x0A, ord("r"): 0x0D, ord("t"): 0x09}


def parse_escaped(text: bytes, start: int) -> tuple[bytes, int] | None:
    """Parse `"..."` at text[start]; returns (value, index after the quote) or None."""
    out = bytearray()
    i = start + 1
    while i < len(text):
        c = text[i]
        if c == 0x22:
            return bytes(out), i + 1
        if c == 0x5C:
            nxt = text[i + 1 : i + 2]
            if nxt and nxt[0] in _UNESCAPE:
                out.append(_UNESCAPE[nxt[0]])
                i += 2
                continue
            if nxt == b"x" and re.fullmatch(rb"[0-9a-fA-F]{2}", text[i + 2 : i + 4]):
                out.append(int(text[i + 2 : i + 4], 16))
                i += 4
                continue
            return None
        out.append(c)
        i += 1
    return None


# -- debug info --------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class DebugEntry:
    """Source position of the instruction at one bytecode offset."""

    line: int
    col: int
    file: bytes


@dataclass
class DebugMap:
    """The reference's 100-bucket offset map: its iteration order is the .bdb order."""

    entries: dict[int, DebugEntry] = field(default_factory=dict)
    buckets: list[list[int]] = field(default_factory=lambda: [[] for _ in range(100)])

    def set(self, offset: int, entry: DebugEntry) -> None:
        """Add or replace; a replaced entry moves to the end of its bucket."""
        bucket = self.buckets[offset % 100]
        if offset in self.entries:
            bucket.remove(offset)
        bucket.append(offset)
        self.entries[offset] = entry

    def ordered(self) -> list[tuple[int, DebugEntry]]:
        """Entries in .bdb record order."""
        return [(off, self.entries[off]) for bucket in self.buckets for off in bucket]

    def to_bytes(self) -> bytes:
        """Serialize: u32 offset, u64 line, u64 col, u16 name length, name (all LE)."""
        out = bytearray()
        for offset, e in self.ordered():
            out += struct.pack("<IQQH", offset, e.line, e.col, len(e.file)) + e.file
        return bytes(out)


def parse_bdb(bdb: bytes) -> list[tuple[int, DebugEntry]]:
    """Records of a .bdb file in file order; raises ValueError when truncated."""
    records = []
    pos = 0
    while pos < len(bdb):
        if pos + 22 > len(bdb):
            raise ValueError(f"truncated .bdb record at byte {pos}")
        offset, line, col, size = struct.unpack_from("<IQQH", bdb, pos)
        pos += 22
        if pos + size > len(bdb):
            raise ValueError(f"truncated .bdb file name at byte {pos}")
        records.append((offset, DebugEntry(line, col, bdb[pos : pos + size])))
        pos += size
    return records


_SUPERSET_DBG = re.compile(rb"([^,|]*),([^,|]*),(?=\")")


def _parse_debug(text: bytes) -> DebugEntry | None:
    """`line,col,file` after the first `|` (reference: strtok on `|` then `,`)."""
    m = _SUPERSET_DBG.match(text)
    if m:
        parsed = parse_escaped(text, m.end())
        if parsed is not None and parsed[1] == len(text):
            return DebugEntry(strtoull(m.group(1)), strtoull(m.group(2)), parsed[0])
    fields = [f for f in text.split(b"|", 1)[0].split(b",") if f]
    if len(fields) < 3:
        return None
    return DebugEntry(strtoull(fields[0]), strtoull(fields[1]), fields[2])


# -- the assembler -----------------------------------------------------------------


class _Assembler:
    def __init__(self, path: str) -> None:
        self.path = path
        self.out = bytearray()
        self.labels: dict[bytes, int] = {}
        self.fixups: list[tuple[int, bytes, int]] = []  # (slot offset, label, line)
        self.debug = DebugMap()
        self.lineno = 0
        self.op_at: dict[int, int] = {}  # .basm line number -> offset of its instruction

    def error(self, message: str, lineno: int | None = None) -> BuzzAsmError:
        return BuzzAsmError(self.path, self.lineno if lineno is None else lineno, message)

    def line(self, raw: bytes, had_newline: bool) -> None:
        text = raw[_skip_space(raw) :]
        if not text or text[0] == 0x23:
            return
        if text[0] == 0x27:  # "'": everything up to the line's last character
            self.out += (text[1:] if had_newline else text[1:-1]) + b"\0"
            return
        text = text.rstrip(_C_SPACE)
        if text[0] == 0x22:
            parsed = parse_escaped(text, 0)
            if parsed is None or parsed[1] != len(text):
                raise self.error("malformed escaped string")
            self.out += parsed[0] + b"\0"
            return
        if text[0] == 0x21:  # '!N': string count
            self.out += struct.pack("<H", strtol(text[1:]) & 0xFFFF)
            return
        head, bar, dbg_text = text.partition(b"|")
        head = head.rstrip(_C_SPACE)
        if bar:
            entry = _parse_debug(dbg_text)
            if entry is None:
                raise self.error("malformed debug information (expected |line,col,file)")
            self.debug.set(len(self.out), entry)
        if text[0] == 0x40:  # '@label'
            self.labels[head] = len(self.out)
            return
        # One space or tab separates name and argument: a second one empties the argument.
        name, _, arg_text = head.replace(b"\t", b" ").partition(b" ")
        arg = arg_text.split(b" ", 1)[0]
        if name == b".bytes":
            self.raw_bytes(arg_text)
            return
        op = NAME_TO_OP.get(name.decode("latin-1"))
        if op is None:
            raise self.error(f'unknown instruction "{name.decode("latin-1")}"')
        self.op_at[self.lineno] = len(self.out)
        self.out.append(op)
        if not op.has_arg:
            if arg:
                warnings.warn(
                    f"{self.path}:{self.lineno}: {op.mnemonic} takes no argument", stacklevel=3
                )
            return
        if not arg:
            raise self.error(f"missing argument for {op.mnemonic}")
        self.argument(op, arg)

    def argument(self, op: Op, arg: bytes) -> None:
        if op is Op.PUSHF:
            m = re.fullmatch(rb"bits:0x([0-9a-fA-F]{1,8})", arg)
            bits = int(m.group(1), 16) if m else strtof_bits(arg)
            self.out += struct.pack("<I", bits)
            return
        value, has_digits = strtoul(arg)
        if op in LABEL_ONLY_OPS and not arg.isdigit():
            has_digits = False  # reference: a jump argument is always a label name
        if not has_digits:
            self.fixups.append((len(self.out), arg, self.lineno))
            self.out += b"\0\0\0\0"
            return
        self.out += struct.pack("<I", value & 0xFFFFFFFF)

    def raw_bytes(self, text: bytes) -> None:
        for item in text.split():
            if not re.fullmatch(rb"[0-9a-fA-F]{1,2}", item):
                raise self.error(f'bad byte "{item.decode("latin-1")}" in .bytes')
            self.out.append(int(item, 16))

    def finish(self) -> tuple[bytes, bytes]:
        for slot, label, lineno in self.fixups:
            where = self.labels.get(label)
            shown = label.decode("latin-1")
            if where is None:
                raise self.error(f'unknown label "{shown}"', lineno)
            if where >= len(self.out):
                raise self.error(f'label "{shown}" is at the end of the code', lineno)
            self.out[slot : slot + 4] = struct.pack("<I", where)
        return bytes(self.out), self.debug.to_bytes()


def assemble(basm: str | bytes, path: str = "<asm>") -> tuple[bytes, bytes]:
    """Assemble .basm text into (.bo, .bdb) bytes exactly as the reference `bzzasm`.

    A `str` holds one character per byte (latin-1), the form
    `bvm.compiler.compile_asm` returns. Raises `BuzzAsmError` on bad input.
    """
    return _assembled(basm, path).finish()


def assemble_mapped(
    basm: str | bytes, path: str = "<asm>"
) -> tuple[bytes, bytes, dict[int, int], dict[str, int]]:
    """`assemble`, also returning the offset of each instruction by its .basm line number
    and the offset of each label (what the source map is made of, bvm/srcmap.py)."""
    asm = _assembled(basm, path)
    bytecode, debug = asm.finish()
    labels = {name.decode("latin-1"): where for name, where in asm.labels.items()}
    return bytecode, debug, asm.op_at, labels


def _assembled(basm: str | bytes, path: str) -> _Assembler:
    """An assembler that has read every line of `basm` (labels not yet resolved)."""
    if isinstance(basm, str):
        try:
            data = basm.encode("latin-1")
        except UnicodeEncodeError as exc:
            line = basm.count("\n", 0, exc.start) + 1
            raise BuzzAsmError(
                path, line, "character beyond U+00FF (text is one char a byte)"
            ) from None
    else:
        data = bytes(basm)
    asm = _Assembler(path)
    lines = data.split(b"\n")
    last_has_newline = lines[-1] == b""
    if last_has_newline:
        lines.pop()
    for number, raw in enumerate(lines, 1):
        asm.lineno = number
        asm.line(raw, had_newline=number < len(lines) or last_has_newline)
    return asm
