"""The source map: the exact source position of each instruction, beside the .bo.

The reference's `.bdb` gives each instruction the position of the token *after* it
(docs/language.md#annotation-rule), 0-based columns, and a line count that misses the
newlines inside strings; the `.bdb` must keep those bytes, for C robots and tools read it.
So the compiler also writes a `.bpos` file (the "sidecar") with, for each instruction, the
true position of the operation it performs (the operator, the call, the index, 1-based
column), and the name and definition place of each function, for the call stack of a
runtime error. Its layout is in docs/bytecode.md#bpos-layout.

Only error reporting reads it, when an error happens: running costs nothing. A sidecar is
checked against the .bo it was made for (length and CRC-32); a stale or malformed one is
a `BuzzLoadError` here, which `Program.load` turns into a warning and no source map
(errors then point where the reference would).
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from bvm.errors import BuzzLoadError

#: The first bytes of a .bpos file, and the version of its layout.
MAGIC = b"BPOS"
VERSION = 1

#: A source position: (file, line, column), both numbers 1-based.
Position = tuple[str, int, int]

_HEAD = struct.Struct("<4sBII")  # magic, version, .bo length, .bo CRC-32
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_POS = struct.Struct("<IHII")  # offset, file index, line, column
_FUNC = struct.Struct("<IHIIH")  # address, file index, line, column, name length


@dataclass(frozen=True)
class Function:
    """A bytecode function: its name (None for an anonymous lambda) and where it is defined."""

    name: str | None
    where: Position | None


@dataclass
class SourceMap:
    """Exact positions by instruction offset, and functions by address."""

    positions: dict[int, Position] = field(default_factory=dict)
    functions: dict[int, Function] = field(default_factory=dict)

    def position(self, offset: int) -> Position | None:
        """Where the operation of the instruction at `offset` is written, if known."""
        return self.positions.get(offset)


def from_marks(
    marks_positions: Mapping[int, Position],
    marks_functions: Sequence[tuple[str, str | None, Position | None]],
    op_at: Mapping[int, int],
    labels: Mapping[str, int],
) -> SourceMap:
    """The map of a compilation: the compiler's marks (by .basm line) placed at the offsets
    the assembler gave those lines (`op_at`) and labels."""
    smap = SourceMap()
    for lineno, pos in marks_positions.items():
        offset = op_at.get(lineno)
        if offset is not None:
            smap.positions[offset] = pos
    for label, name, where in marks_functions:
        addr = labels.get(label)
        if addr is not None:
            smap.functions[addr] = Function(name, where)
    return smap


def encode(smap: SourceMap, bytecode: bytes) -> bytes:
    """The .bpos bytes of `smap`, bound to `bytecode` (docs/bytecode.md#bpos-layout)."""
    files: dict[str, int] = {}

    def file_index(name: str) -> int:
        if name not in files:
            files[name] = len(files)
        return files[name]

    positions = bytearray()
    for offset in sorted(smap.positions):
        name, line, col = smap.positions[offset]
        positions += _POS.pack(offset, file_index(name), line, col)
    functions = bytearray()
    for addr in sorted(smap.functions):
        fn = smap.functions[addr]
        name, line, col = fn.where if fn.where is not None else ("", 0, 0)
        text = (fn.name or "").encode("utf-8")
        functions += _FUNC.pack(addr, file_index(name), line, col, len(text)) + text
    out = bytearray(_HEAD.pack(MAGIC, VERSION, len(bytecode), zlib.crc32(bytecode)))
    out += _U16.pack(len(files))
    for name in files:
        raw = name.encode("utf-8", "surrogateescape")
        out += _U16.pack(len(raw)) + raw
    out += _U32.pack(len(smap.positions)) + positions
    out += _U32.pack(len(smap.functions)) + functions
    return bytes(out)


class _Reader:
    """Bounds-checked reads: every shortfall is a BuzzLoadError naming the byte."""

    def __init__(self, data: bytes, path: str) -> None:
        self.data = data
        self.pos = 0
        self.path = path

    def fail(self, what: str) -> BuzzLoadError:
        return BuzzLoadError(f"{self.path}: corrupt source map: {what} (byte {self.pos})")

    def take(self, n: int, what: str) -> bytes:
        if self.pos + n > len(self.data):
            raise self.fail(f"truncated {what}")
        chunk = self.data[self.pos : self.pos + n]
        self.pos += n
        return chunk

    def count(self, size: int, what: str) -> int:
        """A u32 record count, refused before anything is allocated if the records
        cannot fit in the bytes left."""
        (n,) = _U32.unpack(self.take(4, f"{what} count"))
        if n * size > len(self.data) - self.pos:
            raise self.fail(f"{n} {what} cannot fit in {len(self.data) - self.pos} bytes")
        return n


def decode(data: bytes, bytecode: bytes, path: str = "<bpos>") -> SourceMap:
    """The source map in .bpos bytes made for `bytecode`; BuzzLoadError if they are
    malformed or were made for other bytecode (a stale sidecar)."""
    r = _Reader(data, path)
    magic, version, size, crc = _HEAD.unpack(r.take(_HEAD.size, "header"))
    if magic != MAGIC:
        raise r.fail("not a .bpos file")
    if version != VERSION:
        raise r.fail(f"layout version {version}, this reads {VERSION}")
    if size != len(bytecode) or crc != zlib.crc32(bytecode):
        raise BuzzLoadError(f"{path}: source map made for other bytecode (stale)")
    (nfiles,) = _U16.unpack(r.take(2, "file count"))
    files: list[str] = []
    for _ in range(nfiles):
        (n,) = _U16.unpack(r.take(2, "file name length"))
        files.append(r.take(n, "file name").decode("utf-8", "replace"))

    def where(index: int, line: int, col: int) -> Position:
        if index >= len(files):
            raise r.fail(f"file index {index} out of range")
        return files[index], line, col

    smap = SourceMap()
    npos = r.count(_POS.size, "positions")
    for offset, index, line, col in _POS.iter_unpack(r.take(npos * _POS.size, "positions")):
        if offset >= len(bytecode):
            raise r.fail(f"position at offset {offset}, past the bytecode")
        smap.positions[offset] = where(index, line, col)
    nfunc = r.count(_FUNC.size, "functions")
    for _ in range(nfunc):
        addr, index, line, col, n = _FUNC.unpack(r.take(_FUNC.size, "function"))
        name = r.take(n, "function name").decode("utf-8", "replace")
        if addr >= len(bytecode):
            raise r.fail(f"function at offset {addr}, past the bytecode")
        smap.functions[addr] = Function(name or None, where(index, line, col) if line else None)
    if r.pos != len(data):
        raise r.fail(f"{len(data) - r.pos} bytes after the end")
    return smap
