"""Abstract values of the translator: static types, int intervals, and the symbolic
stack entry that carries them.

Types are flow-sensitive facts about a value at one point of a function (a local, a
stack entry); an INT may also carry the interval it is known to lie in, which lets code
generation drop the int32 wrap check of an operation that provably cannot overflow.
"""

from __future__ import annotations

import re
from typing import Any

from bvm.opcodes import Op
from bvm.values import Table

# Static types of symbolic values. BOOL is a Python bool (a comparison result) that
# becomes the Buzz int 0/1 only where it is used as a value.
INT, FLOAT, STR, NIL, TABLE, CLOSURE, BOOL, ANY = (
    "int", "float", "str", "nil", "table", "closure", "bool", "any"
)  # fmt: skip
#: The static type of a Python value's class, for the classes that have one.
KNOWN_CLASS: dict[type, str] = {int: INT, float: FLOAT, str: STR, Table: TABLE}
#: The helper name generated code tests a value's class against, per type that has one.
GUARD_CLASS = {INT: "_int", FLOAT: "_float", STR: "_str", TABLE: "_Table"}

#: An int's known interval (lo, hi); None when it may be any int32.
Range = tuple[int, int] | None
I32 = (-0x80000000, 0x7FFFFFFF)
#: The comparison that holds when one does not, and the one with operands swapped.
NEGATE = {"<": ">=", "<=": ">", ">": "<=", ">=": "<", "==": "!=", "!=": "=="}
MIRROR = {"<": ">", "<=": ">=", ">": "<", ">=": "<=", "==": "==", "!=": "!="}


def join(a: str, b: str) -> str:
    """The type of a value that is of type a on one path and b on another."""
    return a if a == b else ANY


def param_types(args: tuple[Any, ...]) -> tuple[str, ...]:
    """The types to specialize on for these first-call arguments (ANY = no guard)."""
    return tuple(KNOWN_CLASS.get(a.__class__, ANY) for a in args)


def fits(lo: int, hi: int) -> Range:
    """The interval if it stays inside int32 (no wrap can happen), else None."""
    return (lo, hi) if I32[0] <= lo and hi <= I32[1] else None


def interval(op: Op, a: Range, b: Range) -> Range:
    """The interval of a + b, a - b or a * b when both are known and it fits int32."""
    if a is None or b is None:
        return None
    if op is Op.ADD:
        return fits(a[0] + b[0], a[1] + b[1])
    if op is Op.SUB:
        return fits(a[0] - b[1], a[1] - b[0])
    products = [x * y for x in a for y in b]
    return fits(min(products), max(products))


def join_range(a: Range, b: Range) -> Range:
    """The interval of a value in a on one path and in b on another."""
    if a is None or b is None:
        return None
    return (min(a[0], b[0]), max(a[1], b[1]))


def widen(old: Range, new: Range) -> Range:
    """At a loop header: a bound that moved goes to the int32 limit, so loops settle fast."""
    if old is None or new is None:
        return None
    lo = old[0] if new[0] >= old[0] else I32[0]
    hi = old[1] if new[1] <= old[1] else I32[1]
    return None if (lo, hi) == I32 else (lo, hi)


def refine(rng: Range, op: str, c: int) -> Range:
    """What `x op c` being true says about x."""
    lo, hi = rng if rng is not None else I32
    if op == "<":
        hi = min(hi, c - 1)
    elif op == "<=":
        hi = min(hi, c)
    elif op == ">":
        lo = max(lo, c + 1)
    elif op == ">=":
        lo = max(lo, c)
    elif op == "==":
        lo, hi = max(lo, c), min(hi, c)
    if lo > hi:  # the branch cannot run: any fact is sound, keep the old one
        return rng
    return None if (lo, hi) == I32 else (lo, hi)


def int_ranges(types: list[str], ranges: list[Range]) -> list[Range]:
    """Ranges only mean something for INT locals."""
    return [r if t == INT else None for t, r in zip(types, ranges, strict=True)]


class Expr:
    """A symbolic stack entry: side-effect-free Python code, its static type and constant."""

    __slots__ = ("code", "ty", "const", "origin", "rng", "cmp")

    def __init__(
        self,
        code: str,
        ty: str = ANY,
        const: Any = None,
        origin: Any = None,
        rng: Range = None,
        cmp: tuple[int, str, int] | None = None,
    ) -> None:
        self.code = code
        self.ty = ty
        self.const = const  # the value of a literal; None when not a literal (or nil)
        self.rng = rng  # for an INT: the interval it is known to lie in (None: any int32)
        self.cmp = cmp  # for a BOOL: (local slot, operator, int literal) it tests
        # What a loaded value currently is at translation time (a global, or a member of
        # a global table): lets a call to a host function skip the closure protocol.
        self.origin = origin

    @property
    def is_literal(self) -> bool:
        """Whether the entry is a literal (nil included)."""
        return self.ty == NIL or self.const is not None


def int_test_of(a: Expr, sym: str, b: Expr) -> tuple[int, str, int] | None:
    """(slot, operator, literal) when a comparison tests an INT local against an int literal."""
    local = re.fullmatch(r"_l(\d+)", a.code)
    if a.ty == INT and local and b.ty == INT and b.const is not None:
        return int(local.group(1)), sym, b.const
    local = re.fullmatch(r"_l(\d+)", b.code)
    if b.ty == INT and local and a.ty == INT and a.const is not None:
        return int(local.group(1)), MIRROR[sym], a.const
    return None
