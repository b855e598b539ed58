"""The Buzz bytecode instruction set (47 opcodes, Buzz: src/buzz/buzzvm.h)."""

from __future__ import annotations

from enum import IntEnum


class Op(IntEnum):
    """One Buzz opcode; the value is the byte stored in the .bo file."""

    NOP = 0
    DONE = 1
    PUSHNIL = 2
    DUP = 3
    POP = 4
    RET0 = 5
    RET1 = 6
    ADD = 7
    SUB = 8
    MUL = 9
    DIV = 10
    MOD = 11
    POW = 12
    UNM = 13
    LAND = 14
    LOR = 15
    LNOT = 16
    BAND = 17
    BOR = 18
    BNOT = 19
    LSHIFT = 20
    RSHIFT = 21
    EQ = 22
    NEQ = 23
    GT = 24
    GTE = 25
    LT = 26
    LTE = 27
    GLOAD = 28
    GSTORE = 29
    PUSHT = 30
    TPUT = 31
    TGET = 32
    CALLC = 33
    CALLS = 34
    PUSHF = 35
    PUSHI = 36
    PUSHS = 37
    PUSHCN = 38
    PUSHCC = 39
    PUSHL = 40
    LLOAD = 41
    LSTORE = 42
    LREMOVE = 43
    JUMP = 44
    JUMPZ = 45
    JUMPNZ = 46

    @property
    def mnemonic(self) -> str:
        """The lower-case name used in .basm text (`pushi`, `jumpz`, ...)."""
        return self.name.lower()

    @property
    def has_arg(self) -> bool:
        """True when the opcode is followed by a 4-byte little-endian argument."""
        return self >= FIRST_ARG_OPCODE


# Every opcode from pushf on carries a 4-byte argument; the VM tests `op >= 35`.
FIRST_ARG_OPCODE: int = 35

#: Opcodes followed by a 4-byte argument.
ARG_OPS: frozenset[Op] = frozenset(op for op in Op if op >= FIRST_ARG_OPCODE)

#: Opcodes whose argument is a bytecode address (a label in .basm).
ADDRESS_OPS: frozenset[Op] = frozenset({Op.PUSHCN, Op.PUSHL, Op.JUMP, Op.JUMPZ, Op.JUMPNZ})

#: Opcodes whose argument must be written as a label in .basm (bzzasm never parses a number).
LABEL_ONLY_OPS: frozenset[Op] = frozenset({Op.JUMP, Op.JUMPZ, Op.JUMPNZ})

#: Mnemonic -> opcode, e.g. `NAME_TO_OP["pushi"] is Op.PUSHI`.
NAME_TO_OP: dict[str, Op] = {op.mnemonic: op for op in Op}

#: Opcode byte -> mnemonic.
OP_TO_NAME: dict[int, str] = {int(op): op.mnemonic for op in Op}

NUM_OPCODES: int = len(Op)


def has_arg(opcode: int) -> bool:
    """True when the raw opcode byte takes a 4-byte argument (like the VM: `opcode >= 35`)."""
    return opcode >= FIRST_ARG_OPCODE
