"""A loaded Buzz program: the .bo bytecode, its string table, its .bdb debug info and,
when the compiler made one, its source map (the .bpos sidecar, bvm/srcmap.py).

Bytecode arrives over the air, so everything here is bounds-checked and capped: a
truncated, corrupted or hostile file gives a `BuzzLoadError`, never an exception of
another kind and never unbounded memory.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass, field
from pathlib import Path

from bvm import srcmap as _srcmap
from bvm.errors import BuzzLoadError
from bvm.opcodes import FIRST_ARG_OPCODE, NUM_OPCODES, Op
from bvm.srcmap import Position, SourceMap
from bvm.sweep import GlobalUse, global_use

_log = logging.getLogger("bvm")

#: Largest .bo or .bdb accepted (a real script is a few KiB).
MAX_FILE_BYTES = 16 * 1024 * 1024

# Names the reference registers after the bytecode strings, in order
# (docs/stdlib.md#registration-order). A `pushs` with an id past the bytecode's own strings
# resolves into this list, as it does there.
BUILTIN_STRINGS: tuple[str, ...] = (
    tuple(
        "get filter kin nonkin foreach map reduce count broadcast listen ignore neighbors id "
        "type int float clone size isnil isint isfloat isstring istable isclosure isuserdata "
        "stigmergy create swarm union intersection difference math abs floor ceil round log "
        "log2 log10 exp sqrt sin cos tan asin acos atan min max pi rng setseed uniform "
        "gaussian exponential fopen fclose fsize fforeach fwrite io errno error_message".split()
    )
    + ("No error",)
    + tuple("length sub concat tostring toint tofloat string".split())
)

_PUSHF = struct.Struct("<f")
_ARG = struct.Struct("<I")


@dataclass(frozen=True)
class Instruction:
    """One decoded instruction: opcode, argument (None when it takes none) and the next pc."""

    addr: int
    op: Op
    arg: int | float | None
    next: int

    @property
    def int_arg(self) -> int:
        """The argument of an instruction that takes an int (every one but `pushf`)."""
        arg = self.arg
        if not isinstance(arg, int):
            raise TypeError(f"{self.op.mnemonic} at {self.addr} has no int argument")
        return arg


@dataclass
class Program:
    """Compiled Buzz bytecode (`.bytecode`, the .bo bytes) with its debug info (`.debug`)
    and, when compiled from source here, its source map (`.srcmap`)."""

    bytecode: bytes
    debug: bytes = b""
    path: str = "<buzz>"
    srcmap: SourceMap | None = None
    strings: list[str] = field(init=False)
    code_start: int = field(init=False)
    locations: dict[int, tuple[str, int, int]] = field(init=False)
    _ids: list[str] = field(init=False, repr=False)
    _names: dict[int, str] | None = field(default=None, init=False, repr=False)
    _plan: tuple[tuple[tuple[str, int], ...], int] | bool | None = field(
        default=None, init=False, repr=False, compare=False
    )
    _global_uses: dict[str, GlobalUse] = field(
        default_factory=dict, init=False, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        if len(self.bytecode) > MAX_FILE_BYTES or len(self.debug) > MAX_FILE_BYTES:
            raise BuzzLoadError(f"{self.path}: file larger than {MAX_FILE_BYTES} bytes")
        self.strings, self.code_start = _parse_strings(self.bytecode, self.path)
        own = set(self.strings)
        # Ids past the program's own strings name the library's, as the reference numbers them.
        self._ids = self.strings + [s for s in BUILTIN_STRINGS if s not in own]
        self.locations = _parse_debug(self.debug, self.path)

    @classmethod
    def load(cls, bo_path: str | Path) -> Program:
        """Load a .bo file and, when present, the .bdb and .bpos beside it.

        A .bpos that cannot be read, is malformed, or was made for other bytecode is
        ignored with a warning on the `bvm` logger: errors then point where the
        reference's would (from the .bdb)."""
        bo_path = Path(bo_path)
        try:
            bytecode = _read_capped(bo_path)
            bdb_path = bo_path.with_suffix(".bdb")
            debug = _read_capped(bdb_path) if bdb_path.exists() else b""
        except OSError as e:
            raise BuzzLoadError(f"{bo_path}: cannot read: {e.strerror or e}") from None
        program = cls(bytecode, debug, str(bo_path))
        bpos_path = bo_path.with_suffix(".bpos")
        try:
            if bpos_path.exists():
                data = _read_capped(bpos_path)
                program.srcmap = _srcmap.decode(data, bytecode, str(bpos_path))
        except OSError as e:
            _log.warning("%s: source map ignored: cannot read: %s", bpos_path, e.strerror or e)
        except BuzzLoadError as e:
            _log.warning("source map ignored, errors located from the .bdb: %s", e)
        return program

    def position(self, op_offset: int | None, offset: int | None) -> Position | None:
        """Where to report an error: the source map's position of the failing instruction
        (`op_offset`), else the .bdb entry of the reference's error offset (`offset`)."""
        if op_offset is not None and self.srcmap is not None:
            found = self.srcmap.position(op_offset)
            if found is not None:
                return found
        return self.locations.get(offset) if offset is not None else None

    def function_name(self, addr: int) -> str:
        """How a call stack names the function at `addr`: its name, `<lambda at
        FILE:LINE:COL>` for an anonymous one, else the name the load-time prologue gives
        it, else `<function at offset N>`."""
        fn = self.srcmap.functions.get(addr) if self.srcmap is not None else None
        if fn is not None:
            if fn.name:
                return fn.name
            if fn.where is not None:
                file, line, col = fn.where
                return f"<lambda at {file}:{line}:{col}>"
        name = self._prologue_names().get(addr)
        return name if name is not None else f"<function at offset {addr}>"

    def registrations(self) -> tuple[tuple[tuple[str, int], ...], int] | None:
        """The prologue as data, when it is the compiler's: `pushs name; pushcn addr;
        gstore` triples and a `nop`. The (name, address) pairs in order and the pc after
        the `nop`; None for any other prologue (the interpreter runs it)."""
        plan = self._plan
        if plan is None:
            triples, pc = self._prologue()
            end = self.decode(pc)
            plan = False
            if end is not None and end.op is Op.NOP and all(n is not None for n, _ in triples):
                plan = (tuple(triples), end.next)  # type: ignore[arg-type]  # names checked
            self._plan = plan
        return plan if isinstance(plan, tuple) else None

    def _prologue_names(self) -> dict[int, str]:
        """Named functions by address, from the prologue's `pushs name; pushcn addr;
        gstore` triples (in every .bo, with or without debug files)."""
        names = self._names
        if names is None:
            names = {}
            for name, addr in self._prologue()[0]:
                if name is not None:
                    names.setdefault(addr, name)
            self._names = names
        return names

    def _prologue(self) -> tuple[list[tuple[str | None, int]], int]:
        """The leading `pushs name; pushcn addr; gstore` triples as (name, address), a
        name None when its string id names none, and the pc where they end."""
        triples: list[tuple[str | None, int]] = []
        pc = self.code_start
        while True:
            a = self.decode(pc)
            b = self.decode(a.next) if a is not None else None
            c = self.decode(b.next) if b is not None else None
            if a is None or b is None or c is None:
                break
            if a.op is not Op.PUSHS or b.op is not Op.PUSHCN or c.op is not Op.GSTORE:
                break
            triples.append((self.string(a.int_arg), b.int_arg))
            pc = c.next
        return triples, pc

    def member_reads(self, name: str) -> frozenset[str] | None:
        """The keys the code reads from global `name` as `name.k` or `name.k(...)`, if
        that is all it does with it; None if the value may go anywhere else (bvm/sweep.py)."""
        return self.global_use(name).keys

    def global_use(self, name: str) -> GlobalUse:
        """What the code does with global `name` (bvm/sweep.py), swept once."""
        found = self._global_uses.get(name)
        if found is None:
            found = self._global_uses[name] = global_use(self, name)
        return found

    def string(self, sid: int) -> str | None:
        """The string a `pushs` id names, or None when no string has that id."""
        sid &= 0xFFFF
        return self._ids[sid] if sid < len(self._ids) else None

    def location(self, offset: int) -> tuple[str, int, int] | None:
        """(file, line, col) of the instruction at `offset`, from the .bdb."""
        return self.locations.get(offset)

    def decode(self, pc: int) -> Instruction | None:
        """Decode the instruction at `pc` with the VM's range rules, or None if it can't run.

        As in the reference, an instruction must be followed by at least one more byte
        (its pc increment must stay inside the file), except `done`, `ret0` and `ret1`.
        """
        bc = self.bytecode
        size = len(bc)
        if pc < self.code_start or pc >= size:
            return None
        code = bc[pc]
        if code >= NUM_OPCODES:
            return None
        op = Op(code)
        if op is Op.DONE:
            return Instruction(pc, op, None, pc)
        if code < FIRST_ARG_OPCODE:
            # ret0/ret1 jump back to the caller without moving pc past themselves.
            if pc + 1 >= size and op is not Op.RET0 and op is not Op.RET1:
                return None
            return Instruction(pc, op, None, pc + 1)
        if pc + 5 >= size:
            return None
        if op is Op.PUSHF:
            arg: int | float = _PUSHF.unpack_from(bc, pc + 1)[0]
        else:
            word: int = _ARG.unpack_from(bc, pc + 1)[0]
            if op is Op.PUSHI:
                word = word - 0x100000000 if word & 0x80000000 else word
            arg = word
        return Instruction(pc, op, arg, pc + 5)


def _read_capped(path: Path) -> bytes:
    with path.open("rb") as f:
        data = f.read(MAX_FILE_BYTES + 1)
    if len(data) > MAX_FILE_BYTES:
        raise BuzzLoadError(f"{path}: file larger than {MAX_FILE_BYTES} bytes")
    return data


def _parse_strings(bc: bytes, path: str) -> tuple[list[str], int]:
    """The string table at the head of a .bo: u16 count, then NUL-terminated strings."""
    if len(bc) < 2:
        raise BuzzLoadError(f"{path}: truncated bytecode: no string count ({len(bc)} bytes)")
    count = bc[0] | (bc[1] << 8)
    pos = 2
    strings: list[str] = []
    seen: set[str] = set()
    for i in range(count):
        end = bc.find(b"\0", pos)
        if end < 0:
            raise BuzzLoadError(
                f"{path}: truncated bytecode: string {i} of {count} has no terminating NUL "
                f"(offset {pos})"
            )
        s = bc[pos:end].decode("latin-1")
        # A repeated string reuses its first id, shifting later ids (as the reference does).
        if s not in seen:
            seen.add(s)
            strings.append(s)
        pos = end + 1
    if pos >= len(bc):
        raise BuzzLoadError(f"{path}: truncated bytecode: no code after the string table")
    return strings, pos


_DBG_HEAD = struct.Struct("<IQQH")


def _parse_debug(bdb: bytes, path: str) -> dict[int, tuple[str, int, int]]:
    """The .bdb records: u32 offset, u64 line, u64 col, u16 name length, name."""
    out: dict[int, tuple[str, int, int]] = {}
    pos = 0
    n = len(bdb)
    while pos < n:
        if pos + _DBG_HEAD.size > n:
            raise BuzzLoadError(f"{path}: truncated debug info: partial record at byte {pos}")
        offset, line, col, namelen = _DBG_HEAD.unpack_from(bdb, pos)
        pos += _DBG_HEAD.size
        if pos + namelen > n:
            raise BuzzLoadError(f"{path}: truncated debug info: file name past the end at {pos}")
        name = bdb[pos : pos + namelen].decode("utf-8", "replace")
        pos += namelen
        out[offset] = (name, line, col)
    return out
