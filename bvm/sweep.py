"""What a program does with one global, read off its bytecode (behind lazy neighbour poses).

`global_use(program, name)` sweeps the code once, linearly, and answers whether the program
only ever reads members of global `name` (`name.k`, or `name.k(...)` through a method call)
and which keys: then the host may keep what scripts cannot see (stdlib/neighbors.py).

The answer holds for any bytecode, not just a compiler's:
- every global must be read by a literal name (a computed name may be `name`);
- every jump and `pushcn`/`pushl` closure must land on an instruction of the sweep, outside
  the patterns, so no other path enters them with another stack;
- a method call's `dup` copy of the table (docs/bytecode.md#calls) must stay below its
  closure, unread, until the `callc` that pops it as its ignored self slot: the sweep
  follows the stack depth, opcode by opcode, with no jump or return on the way;
- code entered anywhere else (a closure received over the radio names any offset) must be
  checked by the host with `GlobalUse.enters_cleanly` before it runs.
Programs over MAX_SWEPT_BYTES are not swept (the answer is "any use"): the sweep keeps three
small arrays per instruction, and a robot's loader must stay quick on hostile files.
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass
from typing import TYPE_CHECKING

from bvm.opcodes import ADDRESS_OPS, Op

if TYPE_CHECKING:
    from bvm.program import Program

#: Larger programs are not swept (real scripts compile to tens of kilobytes).
MAX_SWEPT_BYTES = 512 * 1024

# (popped, pushed) of the opcodes a method call's arguments may hold; calls apart.
_EFFECT: dict[int, tuple[int, int]] = {
    Op.NOP: (0, 0),
    Op.PUSHNIL: (0, 1),
    Op.DUP: (1, 2),
    Op.POP: (1, 0),
    **{op: (2, 1) for op in (Op.ADD, Op.SUB, Op.MUL, Op.DIV, Op.MOD, Op.POW, Op.LAND)},
    **{op: (2, 1) for op in (Op.LOR, Op.BAND, Op.BOR, Op.LSHIFT, Op.RSHIFT, Op.EQ, Op.NEQ)},
    **{op: (2, 1) for op in (Op.GT, Op.GTE, Op.LT, Op.LTE, Op.TGET)},
    **{op: (1, 1) for op in (Op.UNM, Op.LNOT, Op.BNOT, Op.GLOAD)},
    Op.GSTORE: (2, 0),
    Op.PUSHT: (0, 1),
    Op.TPUT: (3, 0),
    **{op: (0, 1) for op in (Op.PUSHF, Op.PUSHI, Op.PUSHS, Op.PUSHCN, Op.PUSHCC, Op.PUSHL)},
    Op.LLOAD: (0, 1),
    Op.LSTORE: (1, 0),
    Op.LREMOVE: (0, 0),
}
_CALLS = (Op.CALLC, Op.CALLS)
_ADDRESS = frozenset(int(op) for op in ADDRESS_OPS)


@dataclass(frozen=True)
class GlobalUse:
    """What the code does with one global: `keys` it reads as members, if that is all
    (None: any other use); `clean` marks the offsets where code may be entered without
    landing inside such a read."""

    keys: frozenset[str] | None
    clean: bytes = b""

    def enters_cleanly(self, addr: int) -> bool:
        """Whether code entered at `addr` keeps `keys` true (an instruction of the sweep,
        outside every member read)."""
        return 0 <= addr < len(self.clean) and self.clean[addr] == 1


_ANY_USE = GlobalUse(None)


def global_use(program: Program, name: str) -> GlobalUse:
    """Sweep `program` for its uses of global `name` (see the module docstring)."""
    bc = program.bytecode
    if len(bc) > MAX_SWEPT_BYTES:
        return _ANY_USE
    # The instructions as three arrays, not Instruction objects: a tenth of the memory.
    addrs = array("l")
    ops = bytearray()
    args = array("q")
    pc = program.code_start
    while (ins := program.decode(pc)) is not None:
        addrs.append(pc)
        ops.append(ins.op)
        args.append(ins.arg if isinstance(ins.arg, int) else 0)
        pc = ins.next if ins.op is not Op.DONE else pc + 1
    clean = bytearray(len(bc))
    for addr in addrs:
        clean[addr] = 1
    targets = {args[i] for i, op in enumerate(ops) if op in _ADDRESS}
    if any(not 0 <= t < len(bc) or not clean[t] for t in targets):
        return _ANY_USE  # a jump or closure into the middle of an instruction
    keys: set[str] = set()
    watched: list[int] = []  # stack positions of open method calls' copies of the table
    depth = 0  # the stack's depth since the outermost open call began
    n = len(ops)
    i = 0
    while i < n:
        op = ops[i]
        if op == Op.GLOAD:
            if i == 0 or ops[i - 1] != Op.PUSHS or addrs[i] in targets:
                return _ANY_USE  # a global read by a computed name
            if program.string(args[i - 1]) == name:
                found = _member_read(program, ops, args, i)
                if found is None:
                    return _ANY_USE
                key, call = found
                keys.add(key)
                last = i + (3 if call else 2)  # the tget
                for k in range(i, last + 1):
                    clean[addrs[k]] = 0
                if call:
                    if not watched:
                        depth = 1  # the table, pushed by the pushs before the gload
                    watched.append(depth - 1)
                    depth += 1  # [..., table, closure]
                i = last + 1
                continue
        if watched:
            clean[addrs[i]] = 0
            if op in _CALLS:
                count = args[i - 1] if ops[i - 1] == Op.PUSHI else -1
                if count < 0:
                    return _ANY_USE
                popped = count + 3  # the count, the arguments, the closure, the self slot
                bottom = depth - popped
                if bottom < watched[-1]:
                    return _ANY_USE  # the copy would be an argument or the closure
                if bottom == watched[-1]:
                    watched.pop()  # popped as the self slot, unread
                depth = bottom + 1
            else:
                effect = _EFFECT.get(op)
                if effect is None or depth - effect[0] <= watched[-1]:
                    return _ANY_USE  # a jump, a return, or an op that reads the copy
                depth += effect[1] - effect[0]
        i += 1
    if watched:
        return _ANY_USE  # the code ended inside a method call
    if any(not clean[t] for t in targets):
        return _ANY_USE  # a jump or closure into a member read
    return GlobalUse(frozenset(keys), bytes(clean))


def _member_read(
    program: Program, ops: bytearray, args: array[int], i: int
) -> tuple[str, bool] | None:
    """At the `gload` of index i: the key of `gload; [dup;] pushs k; tget` and whether it
    is a method call (the `dup`), or None for any other use of the loaded value."""
    call = i + 1 < len(ops) and ops[i + 1] == Op.DUP
    j = i + 1 + call
    if j + 1 >= len(ops) or ops[j] != Op.PUSHS or ops[j + 1] != Op.TGET:
        return None
    key = program.string(args[j])
    return None if key is None else (key, call)


__all__ = ["MAX_SWEPT_BYTES", "GlobalUse", "global_use"]
