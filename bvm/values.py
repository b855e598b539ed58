"""Buzz values as plain Python objects, so translated bytecode runs at Python speed.

Buzz        Python
nil         None
integer     int, always inside int32 (wrapped after every operation)
float       float, always a binary32 value (rounded after every operation)
string      str, one character per byte (latin-1), so `len` is the byte length
table       Table, a dict subclass (insertion order, see docs/compat.md)
closure     Closure
userdata    Userdata, an opaque host object
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from typing import Any

from bvm.errors import BuzzError

INT_MIN = -0x80000000
INT_MAX = 0x7FFFFFFF

#: The longest string a script may build: a doubling loop must not exhaust a robot's memory.
MAX_STRING_BYTES = 16 * 1024 * 1024

# A C-style (double)->(float) conversion: correctly rounded, overflow -> inf, no exception.
# Translated code assigns to and reads back this one-element binary32 array inline. One
# cell serves every VM: safe because the GIL never switches threads between the store
# and the load of one statement pair (a free-threaded Python would need one per thread).
F32_CELL = memoryview(bytearray(4)).cast("f")


def f32(x: float) -> float:
    """Round a Python float to the nearest binary32 value (as C's cast does)."""
    F32_CELL[0] = x
    return F32_CELL[0]


def i32(x: int) -> int:
    """Wrap a Python int to int32, two's complement."""
    return ((x + 0x80000000) & 0xFFFFFFFF) - 0x80000000


def f2i(x: float) -> int:
    """float -> int32 as x86 truncation does: NaN, inf and out of range give INT_MIN."""
    if x != x or x >= 2147483648.0 or x <= -2147483649.0:
        return INT_MIN
    return int(x)


class Table(dict):
    """A Buzz table: keys are int, float (not NaN) or str; a nil value means absent."""

    __slots__ = ()

    def __missing__(self, key: Any) -> None:
        # `t[k]` on an absent key is nil, which lets translated code index directly.
        return None

    def __repr__(self) -> str:
        return f"Table({dict.__repr__(self)})"

    # Tables are compared by identity, as in Buzz.
    __eq__ = object.__eq__
    __ne__ = object.__ne__
    __hash__ = object.__hash__  # type: ignore[assignment]  # dict sets None; tables hash by id


class Closure:
    """A Buzz closure: bytecode (`native=False`, `ref` = address) or host (`ref` = function id).

    `actrec` is the captured activation record, a tuple whose element 0 is `self`.
    `fn(closure, *args)` runs it; it is resolved when the closure is made (and patched
    once, on the first call, to the translation for that argument count).
    """

    __slots__ = ("ref", "native", "actrec", "fn")

    def __init__(self, ref: int, native: bool, actrec: tuple, fn: Callable[..., Any]) -> None:
        self.ref = ref
        self.native = native
        self.actrec = actrec
        self.fn = fn

    def rebind(self, new_self: Any) -> Closure:
        """A copy of this closure whose `self` is `new_self` (what `tput` does in Buzz)."""
        return Closure(self.ref, self.native, (new_self,) + self.actrec[1:], self.fn)

    def __repr__(self) -> str:
        kind = "c" if self.native else "n"
        return f"[{kind}-closure @{self.ref}]"


class Userdata:
    """An opaque host object handed to Buzz code."""

    __slots__ = ("value",)

    def __init__(self, value: Any) -> None:
        self.value = value

    def __repr__(self) -> str:
        return f"[userdata @{id(self.value):#x}]"


TYPE_NAMES: dict[type, str] = {
    type(None): "nil",
    int: "integer",
    float: "float",
    str: "string",
    Table: "table",
    Closure: "closure",
    Userdata: "userdata",
}

# Numeric type codes used in the wire format and by hosts.
TYPE_CODES: dict[type, int] = {
    type(None): 0,
    int: 1,
    float: 2,
    str: 3,
    Table: 4,
    Closure: 5,
    Userdata: 6,
}


def type_name(x: Any) -> str:
    """The Buzz type name of a value: nil, integer, float, string, table, closure, userdata."""
    return TYPE_NAMES.get(x.__class__, "userdata")


def is_true(x: Any) -> bool:
    """Buzz truthiness: only nil and the integer 0 are false (0.0, "" and {} are true)."""
    return x is not None and (x.__class__ is not int or x != 0)


def format_float(x: float) -> str:
    """Format a float as C's printf("%f") does on glibc (inf, -inf, nan, -nan)."""
    if x != x:
        return "-nan" if math.copysign(1.0, x) < 0 else "nan"
    if x in (math.inf, -math.inf):
        return "inf" if x > 0 else "-inf"
    return f"{x:f}"


def format_value(x: Any) -> str:
    """Format a value as the reference `log` prints it."""
    cls = x.__class__
    if cls is str:
        return x
    if cls is int:
        return str(x)
    if cls is float:
        return format_float(x)
    if x is None:
        return "[nil]"
    if cls is Table:
        return f"[table with {len(x)} elems]"
    return repr(x)


def format_log(args: Iterable[Any]) -> str:
    """One `log(...)` line, without its newline: the values as `format_value` prints them,
    with nothing between them (the reference bzzrun's `log`, and `io.fwrite`). Every host's
    `log` prints this: `fieldkit run`, the simulator and the node (docs/compat.md#R5)."""
    return "".join([format_value(a) for a in args])


def to_buzz(x: Any) -> Any:
    """Convert a Python value to a Buzz value (used for host function results and `vm[name] = v`).

    bool -> 0/1, int -> wrapped int32, float -> binary32, bytes -> str, dict/list/tuple -> table
    (lists and tuples become tables indexed from 0), None -> nil. Buzz values pass through.
    """
    cls = x.__class__
    if cls is int:
        return x if INT_MIN <= x <= INT_MAX else i32(x)
    if cls is str or x is None or cls is Table or cls is Closure or cls is Userdata:
        return x
    if cls is float:
        return f32(x)
    if cls is bool:
        return int(x)
    if isinstance(x, (bytes, bytearray)):
        return bytes(x).decode("latin-1")
    if isinstance(x, dict):
        t = Table()
        for k, v in x.items():
            bk = to_buzz(k)
            if bk.__class__ not in (int, float, str) or bk != bk:
                raise BuzzError(
                    f"type mismatch: a {type_name(bk)} value can't be used as table key"
                )
            bv = to_buzz(v)
            if bv is not None:
                t[bk] = bv
        return t
    if isinstance(x, (list, tuple)):
        t = Table()
        for i, v in enumerate(x):
            bv = to_buzz(v)
            if bv is not None:
                t[i] = bv
        return t
    if isinstance(x, int):  # int subclasses such as IntEnum
        return i32(int(x))
    if isinstance(x, float):
        return f32(float(x))
    if isinstance(x, str):
        return str(x)
    return Userdata(x)


def copy_tree(v: Any) -> Any:
    """A deep copy of a value whose tables form a tree (decoded values do): new tables,
    the same scalars and closures."""
    if v.__class__ is not Table:
        return v
    return Table({k: copy_tree(x) if x.__class__ is Table else x for k, x in v.items()})


def to_python(x: Any, _memo: dict[int, dict] | None = None) -> Any:
    """Convert a Buzz value to plain Python: tables become dicts (recursively, keeping the
    shape of cyclic tables), userdata unwraps."""
    cls = x.__class__
    if cls is Table:
        memo = {} if _memo is None else _memo
        out = memo.get(id(x))
        if out is None:
            out = memo[id(x)] = {}
            for k, v in x.items():
                out[k] = to_python(v, memo) if v.__class__ is Table else to_python(v)
        return out
    if cls is Userdata:
        return x.value
    return x
