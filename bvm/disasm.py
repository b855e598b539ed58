"""Disassembler: any .bo (+ optional .bdb) -> .basm text that `assemble` turns back into it.

The output is reference .basm whenever the input allows (so a compiled program
disassembles to text the reference `bzzasm` also accepts), with labels
`@L<offset>` at jump/closure targets and `|line,col,file` from the .bdb. The
text is pure ASCII. Hostile input uses the assembler's documented superset:
`.bytes` for bytes that do not decode, `"escaped"` strings, `pushf bits:0x...`
for NaNs, numeric jump targets, and escaped debug file names.
`assemble(disassemble(bo))[0] == bo` for every byte string `bo`.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from bvm.assembler import DebugEntry, parse_bdb, strtof_bits
from bvm.errors import BuzzLoadError
from bvm.opcodes import ADDRESS_OPS, OP_TO_NAME, Op


@dataclass(frozen=True, slots=True)
class _Unit:
    """A decoded instruction (op set) or a run of raw bytes (op None)."""

    offset: int
    size: int
    op: Op | None
    arg: int = 0


def _escape(raw: bytes) -> str:
    """`"..."` with escapes for every byte that is not printable ASCII."""
    out = ['"']
    for b in raw:
        if b in _NAMED_ESCAPES:
            out.append(_NAMED_ESCAPES[b])
        elif 0x20 <= b < 0x7F:
            out.append(chr(b))
        else:
            out.append(f"\\x{b:02x}")
    out.append('"')
    return "".join(out)


_NAMED_ESCAPES = {0x5C: "\\\\", 0x22: '\\"', 0x0A: "\\n", 0x0D: "\\r", 0x09: "\\t"}


def _plain(raw: bytes) -> bool:
    """True when bytes can be written verbatim: printable ASCII, no edge spaces."""
    return all(0x20 <= b < 0x7F for b in raw) and raw == raw.strip()


def _string_line(raw: bytes) -> str:
    return f"'{raw.decode('ascii')}" if _plain(raw) else _escape(raw)


def _debug_suffix(entry: DebugEntry) -> str:
    name = entry.file
    plain = _plain(name) and b"," not in name and b"|" not in name and not name.startswith(b'"')
    shown = name.decode("ascii") if plain and name else _escape(name)
    return f"\t|{entry.line},{entry.col},{shown}"


def _raw_line(raw: bytes, entry: DebugEntry | None) -> str:
    suffix = _debug_suffix(entry) if entry else ""
    return f"\t.bytes {' '.join(f'{b:02x}' for b in raw)}{suffix}"


def _float_text(bits: int) -> str:
    """Shortest decimal that strtof maps back to exactly these bits."""
    value = struct.unpack("<f", struct.pack("<I", bits))[0]
    if value != value:
        return f"bits:0x{bits:08x}"
    if value in (float("inf"), float("-inf")):
        return "inf" if value > 0 else "-inf"
    for digits in range(1, 10):
        text = f"{value:.{digits}g}"
        if strtof_bits(text.encode()) == bits:
            return text
    return f"bits:0x{bits:08x}"  # unreachable: 9 digits always round-trip


def _decode(bo: bytes, start: int, cuts: set[int]) -> list[_Unit]:
    """Instructions from `start`; bytes that cannot decode (or that straddle a
    debug offset in `cuts`) become raw runs."""
    units: list[_Unit] = []
    pos = start
    while pos < len(bo):
        code = bo[pos]
        size = 5 if code >= Op.PUSHF else 1
        inner_cut = next((c for c in range(pos + 1, pos + size) if c in cuts), None)
        if code > max(Op) or pos + size > len(bo) or inner_cut is not None:
            end = min(inner_cut or len(bo), pos + size) if code <= max(Op) else pos + 1
            units.append(_Unit(pos, end - pos, None))
            pos = end
            continue
        arg = struct.unpack_from("<I", bo, pos + 1)[0] if size == 5 else 0
        units.append(_Unit(pos, size, Op(code), arg))
        pos += size
    return units


def _strings(bo: bytes) -> tuple[list[str], int]:
    """Header lines (`!N` and strings) and the offset where code starts."""
    if len(bo) < 2:
        return [], 0
    count = struct.unpack_from("<H", bo)[0]
    lines = [f"!{count}"]
    pos = 2
    for _ in range(count):
        end = bo.find(b"\0", pos)
        if end < 0:
            break  # truncated table: the rest comes out as raw bytes
        lines.append(_string_line(bo[pos:end]))
        pos = end + 1
    return lines, pos


def _operand(unit: _Unit, labelled: set[int]) -> str:
    op, arg = unit.op, unit.arg
    if op is Op.PUSHF:
        return _float_text(arg)
    if op is Op.PUSHI:
        return str(arg - (1 << 32) if arg & 0x80000000 else arg)
    if op in ADDRESS_OPS and arg in labelled:
        return f"@L{arg}"
    return str(arg)


def disassemble(bo: bytes, bdb: bytes | None = None) -> str:
    """Readable .basm for a .bo; `assemble` of it gives back the same .bo bytes."""
    debug: dict[int, DebugEntry] = {}
    if bdb:
        try:
            records = parse_bdb(bdb)
        except ValueError as exc:
            raise BuzzLoadError(f"corrupted .bdb: {exc}") from None
        for offset, entry in records:
            debug[offset] = entry
    lines = [f"# fieldkit disassembly: {len(bo)} bytes"]
    header, code_start = _strings(bo)
    if header:
        lines += header + [""]
    units = _decode(bo, code_start, {o for o in debug if o > code_start})
    if len(header) - 1 < (struct.unpack_from("<H", bo)[0] if header else 0):
        units = [_Unit(code_start, len(bo) - code_start, None)] if code_start < len(bo) else []
    starts = {u.offset for u in units}
    targets = {u.arg for u in units if u.op in ADDRESS_OPS}
    labelled = {t for t in targets if t in starts}  # a label must lie before the end
    run_start: int | None = None  # first offset of the pending raw-byte run
    for i, unit in enumerate(units):
        if unit.offset in labelled:
            lines += ["", f"@L{unit.offset}"]
        if unit.op is None:
            run_start = unit.offset if run_start is None else run_start
            nxt = units[i + 1] if i + 1 < len(units) else None
            if nxt is None or nxt.op is not None or nxt.offset in labelled or nxt.offset in debug:
                end = unit.offset + unit.size
                lines.append(_raw_line(bo[run_start:end], debug.get(run_start)))
                run_start = None
            continue
        found = debug.get(unit.offset)
        suffix = _debug_suffix(found) if found else ""
        text = OP_TO_NAME[unit.op]
        if unit.op.has_arg:
            text += f" {_operand(unit, labelled)}"
        lines.append(f"\t{text}{suffix}")
    for offset in sorted(debug):
        entry = debug[offset]
        if offset == len(bo) and offset >= code_start:
            lines.append(f"@__end{_debug_suffix(entry)}")
        elif offset not in starts:
            lines.append(
                f"# .bdb entry dropped (offset {offset} starts no instruction): "
                f"{entry.line},{entry.col},{entry.file!r}"
            )
    return "\n".join(lines) + "\n"
