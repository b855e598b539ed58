"""Mutations of compiled programs (.bo bytecode and .bdb debug info).

Random bytes are almost always rejected by the string-table check or die on the first
instruction. Mutating real programs keeps most of the file valid, so the VM gets far
into hostile code: corrupted jump targets, wrong opcodes, overlapping instructions,
string ids past the table, stack underflows, truncated arguments, bogus debug records.

Two families:

* byte-level: bit flips, interesting bytes, truncation, insertion, deletion, swaps,
  duplicated ranges, 4-byte interesting integers;
* instruction-level (`decode_program` walks the instruction stream): replace an opcode
  by another of the same width, retarget a jump/closure address to another instruction
  boundary, set an argument to an edge value, delete/duplicate/swap whole instructions.
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from .choosers import Chooser

NUM_OPCODES = 47
FIRST_ARG_OPCODE = 35
ADDRESS_OPS = {38, 40, 44, 45, 46}  # pushcn pushl jump jumpz jumpnz
INTERESTING_BYTES = [0x00, 0x01, 0x7F, 0x80, 0xFF, 0x05, 0x06, 0x21, 0x22, 0x2C, 0x2D, 0x2E]
INTERESTING_INTS = [
    0, 1, 2, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF, 0xFFFF, 0x10000, 0xFFFE, 100, 65, 72, 1000,
]  # fmt: skip


def code_start(bo: bytes) -> int | None:
    """Offset of the first instruction after the string table, or None if malformed."""
    if len(bo) < 2:
        return None
    count = bo[0] | (bo[1] << 8)
    pos = 2
    for _ in range(count):
        end = bo.find(b"\0", pos)
        if end < 0:
            return None
        pos = end + 1
    return pos


def decode_program(bo: bytes) -> list[tuple[int, int]]:
    """(offset, opcode) of each instruction, walking linearly from the code start."""
    start = code_start(bo)
    if start is None:
        return []
    out = []
    pc = start
    while pc < len(bo):
        op = bo[pc]
        out.append((pc, op))
        pc += 5 if FIRST_ARG_OPCODE <= op < NUM_OPCODES else 1
    return out


def _set_arg(b: bytearray, off: int, value: int) -> None:
    if off + 5 <= len(b):
        struct.pack_into("<I", b, off + 1, value & 0xFFFFFFFF)


# ---------------------------------------------------------------- byte level


def _flip(ch: Chooser, b: bytearray) -> None:
    if b:
        i = ch.integer(0, len(b) - 1)
        b[i] ^= 1 << ch.integer(0, 7)


def _interesting_byte(ch: Chooser, b: bytearray) -> None:
    if b:
        b[ch.integer(0, len(b) - 1)] = ch.choice(INTERESTING_BYTES + list(range(NUM_OPCODES)))


def _truncate(ch: Chooser, b: bytearray) -> None:
    if b:
        del b[ch.integer(0, len(b) - 1) :]


def _insert(ch: Chooser, b: bytearray) -> None:
    i = ch.integer(0, len(b))
    b[i:i] = ch.raw(ch.integer(1, 6))


def _delete(ch: Chooser, b: bytearray) -> None:
    if b:
        i = ch.integer(0, len(b) - 1)
        del b[i : i + ch.integer(1, 6)]


def _swap_bytes(ch: Chooser, b: bytearray) -> None:
    if len(b) >= 2:
        i, j = ch.integer(0, len(b) - 1), ch.integer(0, len(b) - 1)
        b[i], b[j] = b[j], b[i]


def _duplicate_range(ch: Chooser, b: bytearray) -> None:
    if b:
        i = ch.integer(0, len(b) - 1)
        n = ch.integer(1, min(32, len(b) - i))
        j = ch.integer(0, len(b))
        b[j:j] = b[i : i + n]


def _interesting_int(ch: Chooser, b: bytearray) -> None:
    if len(b) >= 4:
        i = ch.integer(0, len(b) - 4)
        struct.pack_into("<I", b, i, ch.choice(INTERESTING_INTS + [len(b), len(b) - 1]))


BYTE_MUTATIONS: list[Callable[[Chooser, bytearray], None]] = [
    _flip,
    _interesting_byte,
    _truncate,
    _insert,
    _delete,
    _swap_bytes,
    _duplicate_range,
    _interesting_int,
]

# ---------------------------------------------------------------- instruction level


def _pick(ch: Chooser, b: bytearray) -> tuple[list[tuple[int, int]], int, int] | None:
    ins = decode_program(bytes(b))
    if not ins:
        return None
    k = ch.integer(0, len(ins) - 1)
    return ins, ins[k][0], k


def _replace_opcode(ch: Chooser, b: bytearray) -> None:
    got = _pick(ch, b)
    if got is None:
        return
    _, off, _ = got
    if b[off] >= FIRST_ARG_OPCODE:
        b[off] = ch.integer(FIRST_ARG_OPCODE, NUM_OPCODES - 1)
    else:
        b[off] = ch.integer(0, FIRST_ARG_OPCODE - 1)


def _retarget(ch: Chooser, b: bytearray) -> None:
    ins = decode_program(bytes(b))
    addr = [(off, op) for off, op in ins if op in ADDRESS_OPS]
    if not addr or not ins:
        return
    off, _ = ch.choice(addr)
    target = ch.choice(ins)[0] if ch.chance(0.8) else ch.choice(INTERESTING_INTS + [len(b)])
    _set_arg(b, off, target)


def _edge_arg(ch: Chooser, b: bytearray) -> None:
    ins = [(off, op) for off, op in decode_program(bytes(b)) if op >= FIRST_ARG_OPCODE]
    if not ins:
        return
    off, op = ch.choice(ins)
    if op == 35:  # pushf: float edge values
        val = ch.choice([0x7F800000, 0xFF800000, 0x7FC00000, 0xFFC00000, 0x80000000, 1, 0])
    else:
        val = ch.choice(INTERESTING_INTS + [ch.integer(0, 80), len(b)])
    _set_arg(b, off, val)


def _delete_instruction(ch: Chooser, b: bytearray) -> None:
    got = _pick(ch, b)
    if got is None:
        return
    _, off, _ = got
    del b[off : off + (5 if b[off] >= FIRST_ARG_OPCODE else 1)]


def _duplicate_instruction(ch: Chooser, b: bytearray) -> None:
    got = _pick(ch, b)
    if got is None:
        return
    _, off, _ = got
    n = 5 if b[off] >= FIRST_ARG_OPCODE else 1
    b[off:off] = b[off : off + n]


def _swap_instructions(ch: Chooser, b: bytearray) -> None:
    got = _pick(ch, b)
    if got is None:
        return
    ins, off, k = got
    if k + 1 >= len(ins):
        return
    off2 = ins[k + 1][0]
    end = ins[k + 2][0] if k + 2 < len(ins) else len(b)
    b[off:end] = b[off2:end] + b[off:off2]


def _insert_instruction(ch: Chooser, b: bytearray) -> None:
    got = _pick(ch, b)
    if got is None:
        return
    _, off, _ = got
    op = ch.integer(0, NUM_OPCODES - 1)
    new = bytes([op])
    if op >= FIRST_ARG_OPCODE:
        new += struct.pack("<I", ch.choice(INTERESTING_INTS + [ch.integer(0, 80)]))
    b[off:off] = new


INSTRUCTION_MUTATIONS: list[Callable[[Chooser, bytearray], None]] = [
    _replace_opcode,
    _retarget,
    _edge_arg,
    _delete_instruction,
    _duplicate_instruction,
    _swap_instructions,
    _insert_instruction,
]


def mutate_bytecode(ch: Chooser, bo: bytes, *, max_mutations: int = 4) -> bytes:
    """A mutant of `bo`: 1..max_mutations byte- or instruction-level mutations."""
    b = bytearray(bo)
    for _ in range(ch.integer(1, max_mutations)):
        if ch.chance(0.6):
            ch.choice(INSTRUCTION_MUTATIONS)(ch, b)
        else:
            ch.choice(BYTE_MUTATIONS)(ch, b)
    return bytes(b)


def mutate_debug(ch: Chooser, bdb: bytes, *, max_mutations: int = 3) -> bytes:
    """A mutant of a .bdb (records: u32 offset, u64 line, u64 col, u16 len, name)."""
    b = bytearray(bdb)
    for _ in range(ch.integer(1, max_mutations)):
        r = ch.integer(0, 3)
        if r == 0 and len(b) >= 22:
            # A huge or zero name length in some record-aligned place.
            i = ch.integer(0, len(b) - 2)
            struct.pack_into("<H", b, i, ch.choice([0, 1, 0xFFFF, 0x8000]))
        elif r == 1 and len(b) >= 8:
            i = ch.integer(0, len(b) - 8)
            struct.pack_into("<Q", b, i, ch.choice([0, 2**63, 2**64 - 1, 1]))
        else:
            ch.choice(BYTE_MUTATIONS)(ch, b)
    return bytes(b)
