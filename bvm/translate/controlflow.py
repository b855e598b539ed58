"""Control-flow discovery: the instructions of one function and the shapes of its loops.

Buzz has no break or goto, so the compiler emits a few fixed shapes (if, if/else, while,
for); the translator recovers them from jumps. A function that does not decode, jumps
out of range or overlaps itself is declined (`NotStructured`) and interpreted instead.
"""

from __future__ import annotations

import itertools
from typing import TYPE_CHECKING

from bvm.opcodes import Op
from bvm.program import Instruction

if TYPE_CHECKING:
    from bvm.program import Program

MAX_INSTRUCTIONS = 100_000


class NotStructured(Exception):
    """The function has a shape the translator does not handle; interpret it instead."""


def discover(program: Program, entry: int) -> list[Instruction]:
    """All instructions reachable from `entry`, in address order; NotStructured if any is bad."""
    size = len(program.bytecode)
    seen: dict[int, Instruction] = {}
    work = [entry]
    while work:
        pc = work.pop()
        if pc in seen:
            continue
        ins = program.decode(pc)
        if ins is None:
            raise NotStructured(f"undecodable instruction at {pc}")
        seen[pc] = ins
        if len(seen) > MAX_INSTRUCTIONS:
            raise NotStructured("function too large")
        op = ins.op
        if op is Op.DONE or op is Op.RET0 or op is Op.RET1:
            continue
        if op is Op.JUMP or op is Op.JUMPZ or op is Op.JUMPNZ:
            target = ins.int_arg
            if target >= size:
                raise NotStructured("jump out of range")
            work.append(target)
            if op is Op.JUMP:
                continue
        work.append(ins.next)
    instrs = sorted(seen.values(), key=lambda i: i.addr)
    for a, b in itertools.pairwise(instrs):
        if a.next > b.addr and a.op is not Op.DONE:
            raise NotStructured("overlapping instructions")
    return instrs


def loop_headers(instrs: list[Instruction]) -> set[int]:
    """The addresses backward jumps go to (loop headers); NotStructured for a conditional
    backward jump, which no compiled loop has."""
    headers = set()
    for ins in instrs:
        if ins.op in (Op.JUMP, Op.JUMPZ, Op.JUMPNZ) and ins.int_arg <= ins.addr:
            if ins.op is not Op.JUMP:
                raise NotStructured("conditional backward jump")
            headers.add(ins.int_arg)
    return headers


def loop_depth(instrs: list[Instruction]) -> int:
    """An upper bound of the loop nesting: the most backward jumps spanning one point."""
    events = []
    for ins in instrs:
        if ins.op is Op.JUMP and ins.int_arg <= ins.addr:
            events += [(ins.int_arg, 1), (ins.addr + 1, -1)]
    depth = deepest = 0
    for _, step in sorted(events):
        depth += step
        deepest = max(deepest, depth)
    return deepest


def for_shape(
    instrs: list[Instruction], index: dict[int, int], i: int, j: int, header: int
) -> tuple[int, int, int, int] | None:
    """(p, lb, le, lu) when instructions from i have the compiler's `for` shape.

    Lc: cond; jumpnz Lb; jump Le; Lu: update; jump Lc; Lb: body; jump Lu; Le:
    """
    p = i
    control = (Op.JUMP, Op.JUMPZ, Op.JUMPNZ, Op.RET0, Op.RET1, Op.DONE)
    while p < j and instrs[p].op not in control:
        p += 1
    if p + 2 >= j or instrs[p].op is not Op.JUMPNZ or instrs[p + 1].op is not Op.JUMP:
        return None
    lb = index.get(instrs[p].int_arg)
    le = index.get(instrs[p + 1].int_arg)
    lu = p + 2
    if lb is None or le is None or not (lu < lb < le <= j):
        return None
    if instrs[lb - 1].op is not Op.JUMP or instrs[lb - 1].arg != header:
        return None
    if instrs[le - 1].op is not Op.JUMP or instrs[le - 1].arg != instrs[lu].addr:
        return None
    return p, lb, le, lu
