"""Translate Buzz bytecode functions into Python functions at load time.

A dispatch loop over opcodes runs 20-50x slower than plain Python, so each function
is turned into Python source once and compiled by CPython:

* the operand stack becomes Python locals (a symbolic stack of expressions), and the
  local symbol slots become Python locals `_l0, _l1, ...`;
* Buzz globals are the generated functions' own module globals, so a global read is
  CPython's specialized `LOAD_GLOBAL` (an absent name falls through to a builtins
  mapping that answers nil);
* control flow is recovered from the shapes the Buzz compiler emits (if, if/else,
  while, for; Buzz has no break or goto) into Python `if` and `while True`;
* types are inferred flow-sensitively (constants, int/float arithmetic, locals, and the
  argument types seen on the first call, guarded at entry), so known ints and floats run
  as bare Python operations plus the int32 wrap or the binary32 rounding; unknown
  operands take an inline int/int path and call bvm/ops.py for everything else;
* a call of the running closure (`callee is _C`, tested at run time) enters its
  unguarded body directly, and when the body provably returns ints (or floats) given
  that its own direct calls do, their results are typed so; a body that returns
  anything else hands it back by `_Deopt` to code that assumes nothing (self_call);
* loop iterations are counted for the budget by a `for` over one chunk's counts.

Anything that does not fit (hand-made or hostile bytecode, inconsistent stack depths,
an instruction certain to fail) raises `NotStructured`, and that function runs on the
reference interpreter instead, so semantics never depend on the translator's coverage.

Error locations cost nothing on the fast path: each generated line maps to a bytecode
offset, and bvm/vm.py reads the traceback when an error occurs.
"""

from __future__ import annotations

import itertools
import keyword
import math
import os
import re
import sys
import warnings
import weakref
from types import CodeType
from typing import TYPE_CHECKING, Any

from bvm import ops
from bvm.budget import CHUNK
from bvm.errors import BuzzError
from bvm.interp import MAX_LOCALS, Halt
from bvm.opcodes import Op
from bvm.program import Instruction
from bvm.values import F32_CELL, Closure, Table, f32, i32, type_name

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from bvm.vm import VM

#: Generated code object -> list mapping each generated line number to a bytecode offset.
#: Weak, so the maps go with the translations (a node that reloads scripts doesn't grow).
LINE_MAPS: weakref.WeakKeyDictionary[CodeType, list[int]] = weakref.WeakKeyDictionary()

_MAX_INSTRUCTIONS = 100_000
_MAX_NESTING = 80  # CPython's tokenizer allows 100 indentation levels
_MAX_LOOPS = 18  # and 20 statically nested loops
_MAX_PASSES = 8  # loop re-emissions while inferring types
_MAX_TAILS = 8  # self-calls per function whose continuation is emitted twice
#: Direct self-calls (see `_Codegen.self_call`) and chunked loop counters (see
#: `_Codegen.end_iteration`); tests turn them off to compare.
SELF_CALLS = True
CHUNKED_LOOPS = True
_IDENT = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")

# Static types of symbolic values. BOOL is a Python bool (a comparison result) that
# becomes the Buzz int 0/1 only where it is used as a value.
INT, FLOAT, STR, NIL, TABLE, CLOSURE, BOOL, ANY = (
    "int", "float", "str", "nil", "table", "closure", "bool", "any"
)  # fmt: skip
_KNOWN_CLASS = {int: INT, float: FLOAT, str: STR, Table: TABLE}


class NotStructured(Exception):
    """The function has a shape the translator does not handle; interpret it instead."""


def _join(a: str, b: str) -> str:
    return a if a == b else ANY


def python_name(name: str) -> str | None:
    """The Python global a Buzz global can live under, or None when it needs `_G[...]`."""
    if _IDENT.match(name) and not keyword.iskeyword(name):
        return name
    return None


# An int's known interval (lo, hi); None when it may be any int32.
Range = tuple[int, int] | None
_I32 = (-0x80000000, 0x7FFFFFFF)
_NEGATE = {"<": ">=", "<=": ">", ">": "<=", ">=": "<", "==": "!=", "!=": "=="}
_MIRROR = {"<": ">", "<=": ">=", ">": "<", ">=": "<=", "==": "==", "!=": "!="}


def _fits(lo: int, hi: int) -> Range:
    """The interval if it stays inside int32 (no wrap can happen), else None."""
    return (lo, hi) if _I32[0] <= lo and hi <= _I32[1] else None


def _interval(op: Op, a: Range, b: Range) -> Range:
    """The interval of a + b, a - b or a * b when both are known and it fits int32."""
    if a is None or b is None:
        return None
    if op is Op.ADD:
        return _fits(a[0] + b[0], a[1] + b[1])
    if op is Op.SUB:
        return _fits(a[0] - b[1], a[1] - b[0])
    products = [x * y for x in a for y in b]
    return _fits(min(products), max(products))


def _int_test_of(a: _Expr, sym: str, b: _Expr) -> tuple[int, str, int] | None:
    """(slot, operator, literal) when a comparison tests an INT local against an int literal."""
    local = re.fullmatch(r"_l(\d+)", a.code)
    if a.ty == INT and local and b.ty == INT and b.const is not None:
        return int(local.group(1)), sym, b.const
    local = re.fullmatch(r"_l(\d+)", b.code)
    if b.ty == INT and local and a.ty == INT and a.const is not None:
        return int(local.group(1)), _MIRROR[sym], a.const
    return None


def _join_range(a: Range, b: Range) -> Range:
    if a is None or b is None:
        return None
    return (min(a[0], b[0]), max(a[1], b[1]))


def _widen(old: Range, new: Range) -> Range:
    """At a loop header: a bound that moved goes to the int32 limit, so loops settle fast."""
    if old is None or new is None:
        return None
    lo = old[0] if new[0] >= old[0] else _I32[0]
    hi = old[1] if new[1] <= old[1] else _I32[1]
    return None if (lo, hi) == _I32 else (lo, hi)


def _refine(rng: Range, op: str, c: int) -> Range:
    """What `x op c` being true says about x."""
    lo, hi = rng if rng is not None else _I32
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
    return None if (lo, hi) == _I32 else (lo, hi)


class _Expr:
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
        return self.ty == NIL or self.const is not None


class _Loop:
    __slots__ = ("exit", "start", "exits")

    def __init__(self, exit_addr: int | None, start: int) -> None:
        self.exit = exit_addr
        self.start = start
        self.exits: tuple[list[str], list[Range]] | None = None  # locals at the breaks


class _SelfCall:
    """What a translation knows for calling itself directly: a call whose callee is, at run
    time, the very closure running (`callee is _C`) with arguments of the speculated types
    can enter the unguarded body `name` instead of going through the closure protocol."""

    __slots__ = ("addr", "n_actrec", "spec", "name", "ret", "sites", "returns")

    def __init__(
        self, addr: int, n_actrec: int, spec: tuple[str, ...], name: str, ret: str = ANY
    ) -> None:
        self.addr = addr
        self.n_actrec = n_actrec
        self.spec = spec  # the parameter types the body assumes
        self.name = name  # the module global holding the unguarded body
        # The type the body is assumed to return (ANY: nothing assumed). Sound by
        # induction when every return outside a deoptimized tail then has this type; the
        # others check their value and raise `_Deopt` with it, caught at the call site.
        self.ret = ret
        self.sites = 0  # self-calls emitted
        self.returns: list[str] = []  # static types of the returns outside deoptimized tails


class _Deopt(Exception):  # noqa: N818 - not an error: a control transfer to the caller
    """Raised by a body whose result is not its inferred type, to the direct self-call that
    entered it; that call site then continues on code that assumes nothing of the result
    (`args[0]`). No `__init__` of its own: raising it must not take a Python frame, which
    at the recursion limit would turn a return into a stack overflow."""


#: A line of `_Codegen.lines` only the unguarded body keeps (its `_Deopt` check).
_DEOPT_ONLY = 1


def discover(vm: VM, entry: int) -> list[Instruction]:
    """All instructions reachable from `entry`, in address order; NotStructured if any is bad."""
    program = vm.program
    assert program is not None
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
        if len(seen) > _MAX_INSTRUCTIONS:
            raise NotStructured("function too large")
        op = ins.op
        if op is Op.DONE or op is Op.RET0 or op is Op.RET1:
            continue
        if op is Op.JUMP or op is Op.JUMPZ or op is Op.JUMPNZ:
            if ins.arg >= size:  # type: ignore[operator]
                raise NotStructured("jump out of range")
            work.append(ins.arg)  # type: ignore[arg-type]
            if op is Op.JUMP:
                continue
        work.append(ins.next)
    instrs = sorted(seen.values(), key=lambda i: i.addr)
    for a, b in itertools.pairwise(instrs):
        if a.next > b.addr and a.op is not Op.DONE:
            raise NotStructured("overlapping instructions")
    return instrs


def _loop_depth(instrs: list[Instruction]) -> int:
    """An upper bound of the loop nesting: the most backward jumps spanning one point."""
    events = []
    for ins in instrs:
        if ins.op is Op.JUMP and ins.arg <= ins.addr:  # type: ignore[operator]
            events += [(ins.arg, 1), (ins.addr + 1, -1)]
    depth = deepest = 0
    for _, step in sorted(events):
        depth += step
        deepest = max(deepest, depth)
    return deepest


class _Codegen:
    """Emits the Python source of one function from its structured instruction list."""

    def __init__(
        self,
        vm: VM,
        instrs: list[Instruction],
        slot_types: list[str],
        toplevel: bool,
        selfcall: _SelfCall | None = None,
        key: str = "",
    ) -> None:
        self.vm = vm
        self.selfcall = selfcall
        # Names of bound constants are `<prefix><key>_<n>`: the same in every VM that
        # translates the same function the same way, so they can share the compiled code.
        self.key = key
        self._names = itertools.count()
        self.tail_depth = 0  # > 0 inside the copy of a tail that assumes nothing of a result
        self.instrs = instrs
        self.index = {ins.addr: i for i, ins in enumerate(instrs)}
        self.headers = set()
        for ins in instrs:
            if ins.op in (Op.JUMP, Op.JUMPZ, Op.JUMPNZ) and ins.arg <= ins.addr:  # type: ignore[operator]
                if ins.op is not Op.JUMP:
                    raise NotStructured("conditional backward jump")
                self.headers.add(ins.arg)
        self.toplevel = toplevel
        self.types = list(slot_types)  # the static type of each live local slot
        self.ranges: list[Range] = [None] * len(slot_types)  # intervals of INT locals
        self.stack: list[_Expr] = []
        self.lines: list[tuple[int, str, int, int]] = []  # indent, text, offset, flags
        self.emitted = 0
        self.max_emitted = 2000 + 40 * len(instrs)
        self.indent = 1
        self.loops = 0
        self.dead = False
        self.ntemps = 0
        self.consts: dict[str, Any] = {}
        self.counters: list[str] = []  # the loop-iteration counters of the enclosing loops
        self.used_locals: set[int] = set()
        self.global_names: set[str] = set()
        # A chunked loop is two Python blocks (`while` and `for`), and CPython allows 20
        # nested blocks: the outermost loops are chunked, as many as the deepest nest allows.
        depth = _loop_depth(instrs)
        self.chunked_depth = max(0, min(depth, _MAX_LOOPS - 1 - depth)) if CHUNKED_LOOPS else 0

    # ------------------------------------------------------------ helpers

    def emit(self, text: str, offset: int, flags: int = 0, indent: int | None = None) -> None:
        indent = self.indent if indent is None else indent
        if indent > _MAX_NESTING:
            raise NotStructured("nesting too deep")
        self.emitted += 1
        if self.emitted > self.max_emitted:
            # Loop re-emission while types settle can multiply with nesting: give up and
            # interpret rather than spend unbounded time translating.
            raise NotStructured("translation work exceeded its bound")
        self.lines.append((indent, text, offset, flags))

    def temp(self) -> str:
        self.ntemps += 1
        return f"_t{self.ntemps}"

    def push(self, code: str, ty: str = ANY, const: Any = None, rng: Range = None) -> None:
        self.stack.append(_Expr(code, ty, const, rng=rng))

    def fresh(self, prefix: str) -> str:
        """A new module-global name for a constant this translation binds."""
        return f"{prefix}{self.key}_{next(self._names)}"

    def pop(self) -> _Expr:
        if not self.stack:
            raise NotStructured("stack underflow")
        return self.stack.pop()

    def literal(self, value: Any) -> None:
        if value is None:
            self.push("None", NIL)
            return
        ty = _KNOWN_CLASS[value.__class__]
        if value.__class__ is float and (math.isinf(value) or value != value or value == 0.0):
            # inf, NaN (keeping its sign bit) and -0.0 have no exact literal: bind the object
            name = self.fresh("_k")
            self.consts[name] = value
            self.push(name, ty, value)
        else:
            # A negative literal is parenthesized: `-2.5.__class__` would negate the class.
            code = f"({value!r})" if ty in (INT, FLOAT) and value < 0 else repr(value)
            self.push(code, ty, value, (value, value) if ty == INT else None)

    @staticmethod
    def val(e: _Expr) -> str:
        """Code for the Buzz value of an entry."""
        return f"(1 if {e.code} else 0)" if e.ty == BOOL else e.code

    @staticmethod
    def vtype(e: _Expr) -> str:
        """The static Buzz type of an entry's value."""
        return INT if e.ty == BOOL else e.ty

    def truth(self, e: _Expr) -> str:
        """Code for the Buzz truthiness of an entry (only nil and int 0 are false)."""
        ty, c = e.ty, e.code
        if ty == BOOL:
            return c
        if ty == NIL:
            return "False"
        if ty == INT:
            return "True" if e.const not in (None, 0) else f"({c} != 0)"
        if ty in (FLOAT, STR, TABLE, CLOSURE):
            return "True"
        return f"({c} is not None and ({c}.__class__ is not _int or {c} != 0))"

    def falsity(self, e: _Expr) -> str:
        return f"not {self.truth(e)}"

    @staticmethod
    def int_test(*entries: _Expr) -> str:
        """Code testing that every entry of unknown type holds an int."""
        tests = [f"{e.code}.__class__ is _int" for e in entries if e.ty == ANY]
        return " and ".join(tests) or "True"

    def block(self, i: int, j: int, loop: _Loop | None, offset: int) -> None:
        """An indented region; `pass` when it emits nothing."""
        self.indent += 1
        mark = len(self.lines)
        self.region(i, j, loop)
        if len(self.lines) == mark:
            self.emit("pass", offset)
        self.indent -= 1

    def tick(self, offset: int, jumps: int = 1) -> None:
        """End of an iteration: count its backward jumps on the loop's local counter (see
        bvm/budget.py; a `for` iteration makes two, as the interpreter counts them)."""
        counter = self.counters[-1]
        self.emit(f"{counter} -= {jumps}", offset)
        self.emit(f"if not {counter}: {counter} = _tick()", offset)

    def settle(self, offset: int) -> None:
        """Charge the iterations the enclosing loops' counters have not settled yet."""
        if self.counters:
            spent = " + ".join(f"_K - {c}" for c in self.counters)
            self.emit(f"_charge({spent})", offset)

    def snapshot(self) -> tuple:
        sc = self.selfcall
        return (
            len(self.lines),
            list(self.types),
            list(self.ranges),
            self.dead,
            self.indent,
            self.loops,
            (sc.sites, len(sc.returns)) if sc is not None else None,
        )

    def restore(self, snap: tuple) -> None:
        n, types, ranges, self.dead, self.indent, self.loops, calls = snap
        del self.lines[n:]
        self.types = list(types)
        self.ranges = list(ranges)
        if calls is not None:  # what the discarded code counted is gone with it
            sc = self.selfcall
            assert sc is not None
            sc.sites = calls[0]
            del sc.returns[calls[1] :]

    # ------------------------------------------------------------ structure

    def region(self, i: int, j: int, loop: _Loop | None, *, leaves: int = 0) -> None:
        """Emit instructions [i, j); the symbolic stack is empty at the start and holds
        `leaves` entries at the end (1 for a `for` condition, 0 everywhere else)."""
        instrs = self.instrs
        while i < j:
            ins = instrs[i]
            if ins.addr in self.headers and not (loop is not None and loop.start == i):
                i = self.loop(i, j)
                continue
            op = ins.op
            if op is Op.JUMPZ or op is Op.JUMPNZ:
                i = self.branch(i, j, loop)
                continue
            if op is Op.JUMP:
                raise NotStructured("unstructured jump")
            if (op is Op.CALLC or op is Op.CALLS) and not self.dead:
                self.call(ins, (i, j, loop, leaves))
            else:
                self.simple(ins)
            i += 1
        if len(self.stack) != leaves and not self.dead:
            raise NotStructured("values left on the stack at a block boundary")

    def loop(self, i: int, j: int) -> int:
        """A loop whose header is instruction i; returns the index after it.

        The body is emitted assuming the locals' types and int ranges at entry; if they
        differ at the end of an iteration, the header's are widened (types joined, moving
        range bounds sent to the int32 limits) and the body is emitted again.
        """
        instrs = self.instrs
        header = instrs[i].addr
        if self.stack:
            raise NotStructured("stack not empty at loop entry")
        backs = [k for k in range(i, j) if instrs[k].op is Op.JUMP and instrs[k].arg == header]
        if not backs:
            raise NotStructured("loop back edge outside the region")
        self.loops += 1
        if self.loops > _MAX_LOOPS:
            raise NotStructured("loops nested too deeply")
        shape = self.for_shape(i, j, header)
        counter = f"_n{self.loops}"
        chunked = self.loops <= self.chunked_depth
        if not chunked:
            self.emit(f"{counter} = _K", header)
        self.counters.append(counter)
        snap = self.snapshot()
        for _ in range(_MAX_PASSES):
            entry = (list(self.types), list(self.ranges))
            if shape is not None:
                after, loop, end = self.for_loop(i, shape, chunked)
            else:
                k = backs[-1]
                exit_addr = instrs[k + 1].addr if k + 1 < len(instrs) else None
                loop = _Loop(exit_addr, i)
                self.open_loop(header, 1, chunked)
                self.region(i, k, loop)
                end = None if self.dead else (list(self.types), list(self.ranges))
                self.end_iteration(len(entry[0]), instrs[k].addr, 1, chunked)
                after = k + 1
            if end is not None and len(end[0]) != len(entry[0]):
                raise NotStructured("loop body changes the number of locals")
            widened = entry
            if end is not None:
                widened = (
                    [_join(a, b) for a, b in zip(entry[0], end[0], strict=True)],
                    [_widen(a, _join_range(a, b)) for a, b in zip(entry[1], end[1], strict=True)],
                )
                widened = (widened[0], self.int_ranges(widened[0], widened[1]))
            if widened == entry:
                break
            self.restore(snap)
            self.types, self.ranges = list(widened[0]), list(widened[1])
        else:
            raise NotStructured("loop types did not settle")
        self.counters.pop()
        self.emit(f"_charge(_K - {counter})", header)
        self.loops -= 1
        self.dead = False
        self.types, self.ranges = loop.exits if loop.exits is not None else entry
        return after

    @staticmethod
    def int_ranges(types: list[str], ranges: list[Range]) -> list[Range]:
        """Ranges only mean something for INT locals."""
        return [r if t == INT else None for t, r in zip(types, ranges, strict=True)]

    def for_shape(self, i: int, j: int, header: int) -> tuple[int, int, int, int] | None:
        """(p, lb, le, lu) when instructions from i have the compiler's `for` shape.

        Lc: cond; jumpnz Lb; jump Le; Lu: update; jump Lc; Lb: body; jump Lu; Le:
        """
        instrs = self.instrs
        p = i
        control = (Op.JUMP, Op.JUMPZ, Op.JUMPNZ, Op.RET0, Op.RET1, Op.DONE)
        while p < j and instrs[p].op not in control:
            p += 1
        if p + 2 >= j or instrs[p].op is not Op.JUMPNZ or instrs[p + 1].op is not Op.JUMP:
            return None
        lb = self.index.get(instrs[p].arg)  # type: ignore[arg-type]
        le = self.index.get(instrs[p + 1].arg)  # type: ignore[arg-type]
        lu = p + 2
        if lb is None or le is None or not (lu < lb < le <= j):
            return None
        if instrs[lb - 1].op is not Op.JUMP or instrs[lb - 1].arg != header:
            return None
        if instrs[le - 1].op is not Op.JUMP or instrs[le - 1].arg != instrs[lu].addr:
            return None
        return p, lb, le, lu

    def for_loop(
        self, i: int, shape: tuple[int, int, int, int], chunked: bool
    ) -> tuple[int, _Loop, Any]:
        p, lb, le, lu = shape
        instrs = self.instrs
        nslots = len(self.types)
        self.open_loop(instrs[i].addr, 2, chunked)
        loop = _Loop(instrs[le].addr, i)
        self.region(i, p, loop, leaves=1)
        cond = self.pop()
        self.note_exit(loop, cond, False)
        self.emit(f"if {self.falsity(cond)}: break", instrs[p].addr)
        self.assume(cond, True)
        body, update = _Loop(instrs[le].addr, lb), _Loop(instrs[le].addr, lu)
        self.region(lb, le - 1, body)
        self.region(lu, lb - 1, update)
        for part in (body, update):  # a break out of either also exits the loop
            if part.exits is not None:
                self.join_exit(loop, *part.exits)
        end = None if self.dead else (list(self.types), list(self.ranges))
        self.end_iteration(nslots, instrs[lb - 1].addr, 2, chunked)
        return le, loop, end

    def open_loop(self, header: int, jumps: int, chunked: bool) -> None:
        """Start a loop's code: `while True:`, and when chunked, the iteration counter as
        a `for` over the counts of one chunk (see end_iteration)."""
        self.emit("while True:", header)
        self.indent += 1
        if chunked:
            self.emit(f"for {self.counters[-1]} in _KS{jumps}:", header)
            self.indent += 1

    def end_iteration(self, nslots: int, offset: int, jumps: int, chunked: bool) -> None:
        """End a loop's code. A chunked loop counts its iterations down by `for` over a
        tuple (one C step an iteration) and settles each chunk in the `for`'s `else`:
        exactly when the counter of the unchunked form reaches 0, with the same value in
        the counter at every iteration. A loop exit (`break`) leaves the `for`, skipping
        the `else`, and then the `while`."""
        if not self.dead:
            if len(self.types) != nslots:
                raise NotStructured("loop body changes the number of locals")
            if not chunked:
                self.tick(offset, jumps)
        if chunked:
            self.indent -= 1
            self.emit("else:", offset)
            self.emit("    _tick()", offset)
            self.emit("    continue", offset)
            self.emit("break", offset)
        self.indent -= 1

    def note_exit(self, loop: _Loop, cond: _Expr | None = None, holds: bool = True) -> None:
        """Record the locals' state at a `break` taken when `cond` is `holds` (joined over
        every exit of the loop)."""
        types, ranges = list(self.types), list(self.ranges)
        if cond is not None and cond.cmp is not None:
            slot, op, c = cond.cmp
            ranges[slot] = _refine(ranges[slot], op if holds else _NEGATE[op], c)
        self.join_exit(loop, types, ranges)

    @staticmethod
    def join_exit(loop: _Loop, types: list[str], ranges: list[Range]) -> None:
        """Join one exit's locals into the loop's exit record."""
        if loop.exits is None:
            loop.exits = (types, ranges)
        elif len(loop.exits[0]) != len(types):
            raise NotStructured("loop exits with different numbers of locals")
        else:
            loop.exits = (
                [_join(a, b) for a, b in zip(loop.exits[0], types, strict=True)],
                [_join_range(a, b) for a, b in zip(loop.exits[1], ranges, strict=True)],
            )

    def assume(self, cond: _Expr, holds: bool) -> None:
        """Code that runs only when `cond` is `holds`: narrow the tested local's range."""
        if cond.cmp is not None:
            slot, op, c = cond.cmp
            if slot < len(self.ranges) and self.types[slot] == INT:
                self.ranges[slot] = _refine(self.ranges[slot], op if holds else _NEGATE[op], c)

    def branch(self, i: int, j: int, loop: _Loop | None) -> int:
        """A conditional jump at instruction i: a loop exit, an if, or an if/else."""
        instrs = self.instrs
        ins = instrs[i]
        cond = self.pop()
        if self.stack:
            raise NotStructured("stack not empty at a branch")
        # The jump is taken when the value is false (jumpz) or true (jumpnz).
        jumps_if = ins.op is Op.JUMPNZ
        taken = self.truth(cond) if jumps_if else self.falsity(cond)
        stays = self.falsity(cond) if jumps_if else self.truth(cond)
        target = ins.arg
        if loop is not None and target == loop.exit:
            self.note_exit(loop, cond, jumps_if)
            self.emit(f"if {taken}: break", ins.addr)
            self.assume(cond, not jumps_if)
            return i + 1
        m = self.index.get(target)  # type: ignore[arg-type]
        if m is None or m <= i or m > j:
            raise NotStructured("branch leaves its region")
        entry = (list(self.types), list(self.ranges))
        self.emit(f"if {stays}:", ins.addr)
        last = instrs[m - 1]
        n2 = None
        if m - 1 > i and last.op is Op.JUMP and last.arg > target:  # type: ignore[operator]
            n2 = self.index.get(last.arg)  # type: ignore[arg-type]
            if n2 is not None and n2 > j:
                n2 = None
        self.assume(cond, not jumps_if)
        self.block(i + 1, m - 1 if n2 is not None else m, loop, ins.addr)
        then_dead, then_state = self.dead, (self.types, self.ranges)
        self.dead = False
        self.types, self.ranges = list(entry[0]), list(entry[1])
        self.assume(cond, jumps_if)
        if n2 is None:
            else_dead, else_state = False, (self.types, self.ranges)
            after = m
        else:
            self.emit("else:", last.addr)
            self.block(m, n2, loop, last.addr)
            else_dead, else_state = self.dead, (self.types, self.ranges)
            after = n2
        if then_dead and else_dead:
            self.dead = True
            self.types, self.ranges = entry
        elif then_dead or else_dead:
            # Only one branch returns: the code after the if/else runs (from the other).
            self.dead = False
            state = else_state if then_dead else then_state
            self.types, self.ranges = list(state[0]), list(state[1])
        elif len(then_state[0]) != len(else_state[0]):
            raise NotStructured("branches leave different numbers of locals")
        else:
            self.dead = False
            self.types = [_join(a, b) for a, b in zip(then_state[0], else_state[0], strict=True)]
            joined = [_join_range(a, b) for a, b in zip(then_state[1], else_state[1], strict=True)]
            self.ranges = self.int_ranges(self.types, joined)
        return after

    # ------------------------------------------------------------ instructions

    def simple(self, ins: Instruction) -> None:
        """One straight-line instruction."""
        if self.dead:
            return  # unreachable code after a return inside a structured block
        op = ins.op
        at = ins.addr
        if op is Op.NOP:
            return
        if op is Op.PUSHNIL:
            self.literal(None)
        elif op is Op.PUSHI or op is Op.PUSHF:
            self.literal(ins.arg)
        elif op is Op.PUSHS:
            s = self.vm.program.string(ins.arg)  # type: ignore[union-attr, arg-type]
            if s is None:
                raise NotStructured("unknown string id")
            self.literal(s)
        elif op is Op.DUP:
            e = self.pop()
            self.stack += [e, e]
        elif op is Op.POP:
            self.pop()
        elif op in (Op.ADD, Op.SUB, Op.MUL):
            self.arith(ins)
        elif op in _HELPER_BINARY:
            self.helper_binary(ins)
        elif op in _COMPARE:
            self.compare(ins)
        elif op is Op.UNM:
            self.unary_minus(ins)
        elif op is Op.BNOT:
            a = self.pop()
            t = self.temp()
            if a.ty == INT:
                self.emit(f"{t} = ~{a.code}", at)
            else:
                self.emit(f"{t} = _bnot({self.val(a)})", at)
            self.push(t, INT)
        elif op is Op.LNOT:
            a = self.pop()
            t = self.temp()
            self.emit(f"{t} = {self.falsity(a)}", at)
            self.push(t, BOOL)
        elif op is Op.LAND or op is Op.LOR:
            b, a = self.pop(), self.pop()
            t = self.temp()
            word = "and" if op is Op.LAND else "or"
            self.emit(f"{t} = ({self.truth(a)}) {word} ({self.truth(b)})", at)
            self.push(t, BOOL)
        elif op is Op.GLOAD:
            self.gload(ins)
        elif op is Op.GSTORE:
            self.gstore(ins)
        elif op is Op.PUSHT:
            t = self.temp()
            self.emit(f"{t} = _Table()", at)
            self.push(t, TABLE)
        elif op is Op.TPUT:
            self.tput(ins)
        elif op is Op.TGET:
            self.tget(ins)
        elif op is Op.CALLC or op is Op.CALLS:
            self.call(ins, None)
        elif op is Op.PUSHCN:
            t = self.temp()
            entry = self.entry_name(ins.arg, 1)  # type: ignore[arg-type]
            self.emit(f"{t} = _Closure({ins.arg}, False, (None,), {entry}.fn)", at)
            self.push(t, CLOSURE)
        elif op is Op.PUSHCC:
            t = self.temp()
            self.emit(f"{t} = _native({ins.arg})", at)
            self.push(t, CLOSURE)
        elif op is Op.PUSHL:
            n = len(self.types)
            if n == 0:
                actrec, size = "(None,)", 1
            else:
                actrec, size = "(" + "".join(f"_l{k}, " for k in range(n)) + ")", n
                self.used_locals.update(range(n))
            t = self.temp()
            entry = self.entry_name(ins.arg, size)  # type: ignore[arg-type]
            self.emit(f"{t} = _Closure({ins.arg}, False, {actrec}, {entry}.fn)", at)
            self.push(t, CLOSURE)
        elif op is Op.LLOAD:
            k = ins.arg
            if k >= len(self.types):  # type: ignore[operator]
                raise NotStructured("reads a local that does not exist")
            self.used_locals.add(k)  # type: ignore[arg-type]
            self.push(f"_l{k}", self.types[k], rng=self.ranges[k])  # type: ignore[index]
        elif op is Op.LSTORE:
            self.lstore(ins)
        elif op is Op.LREMOVE:
            n = ins.arg
            if n + (0 if self.toplevel else 1) > len(self.types):  # type: ignore[operator]
                raise NotStructured("removes locals that do not exist")
            if n:
                del self.types[len(self.types) - n :]  # type: ignore[operator]
                del self.ranges[len(self.ranges) - n :]  # type: ignore[operator]
        elif op is Op.RET0 or op is Op.RET1:
            if self.toplevel:
                raise NotStructured("return at top level")
            e = None if op is Op.RET0 else self.pop()
            value = "None" if e is None else self.val(e)
            self.settle(at)
            sc = self.selfcall
            if sc is not None:
                ty = NIL if e is None else self.vtype(e)
                if not self.tail_depth:
                    sc.returns.append(ty)
                if sc.ret != ANY and ty != sc.ret:
                    # Not provably the assumed type: the unguarded body hands its caller
                    # anything else through `_Deopt` (the guarded entry just returns).
                    cls = _GUARD_CLASS[sc.ret]
                    check = f"if {value}.__class__ is not {cls}: " if ty == ANY else ""
                    self.emit(f"{check}raise _Deopt({value})", at, _DEOPT_ONLY)
            self.emit(f"return {value}", at)
            self.stack.clear()
            self.dead = True
        elif op is Op.DONE:
            self.emit("return None" if self.toplevel else "raise _Halt()", at)
            self.stack.clear()
            self.dead = True
        else:  # pragma: no cover - jumps are handled by region()
            raise NotStructured(f"unexpected {op.mnemonic}")

    def arith(self, ins: Instruction) -> None:
        """add, sub, mul: int32 wrap for ints, binary32 rounding for floats."""
        b, a = self.pop(), self.pop()
        a, b = self.float_literal(a, b)
        sym, slow = _ARITH[ins.op]
        t = self.temp()
        av, bv = self.val(a), self.val(b)
        ta, tb = self.vtype(a), self.vtype(b)
        at = ins.addr
        if ta == INT and tb == INT:
            rng = _interval(
                ins.op, a.rng if a.ty == INT else (0, 1), b.rng if b.ty == INT else (0, 1)
            )
            if rng is not None and self.inline_expr(f"({av} {sym} {bv})", INT, rng):
                return  # provably inside int32: cannot fail or wrap, so no statement
            self.emit(f"{t} = {av} {sym} {bv}", at)
            if rng is None:  # it may leave int32: wrap
                self.emit(self.wrap_check(t, ins.op, b), at)
            self.push(t, INT, rng=rng)
        elif ta == FLOAT and tb == FLOAT:
            self.emit(f"_F[0] = {av} {sym} {bv}", at)
            self.emit(f"{t} = _F[0]", at)
            self.push(t, FLOAT)
        elif ta in (INT, ANY) and tb in (INT, ANY) and ins.op is not Op.MUL:
            # Let Python add or subtract whatever it is given, and check the result once:
            # an int in range is the answer; anything else (a float, a concatenated string)
            # is redone by the full rule, and a TypeError means the types don't combine.
            # (Not for `*`: "ab" * 2**31 would allocate before any check.)
            self.emit(f"try: {t} = {av} {sym} {bv}", at)
            self.emit(f"except _TypeError: {t} = {slow}({av}, {bv})", at)
            self.emit(
                f"if {t}.__class__ is not _int or {t} > 1073741823 or {t} < -1073741823: "
                f"{t} = _redo({slow}, {av}, {bv}, {t})",
                at,
            )
            self.push(t, ANY)
        elif ta in (INT, ANY) and tb in (INT, ANY):
            self.emit(f"if {self.int_test(a, b)}:", at)
            self.emit(f"    {t} = {av} {sym} {bv}", at)
            self.emit(f"    {self.wrap_check(t, ins.op, b)}", at)
            self.emit(f"else: {t} = {slow}({av}, {bv})", at)
            self.push(t, ANY)
        elif {ta, tb} == {FLOAT, ANY}:
            unknown = a if ta == ANY else b
            self.emit(f"if {unknown.code}.__class__ is _float:", at)
            self.emit(f"    _F[0] = {av} {sym} {bv}", at)
            self.emit(f"    {t} = _F[0]", at)
            self.emit(f"else: {t} = {slow}({av}, {bv})", at)
            self.push(t, FLOAT)
        else:
            self.emit(f"{t} = {slow}({av}, {bv})", at)
            numeric = ta in (INT, FLOAT) and tb in (INT, FLOAT)
            self.push(t, FLOAT if numeric or FLOAT in (ta, tb) else ANY)

    def float_literal(self, a: _Expr, b: _Expr) -> tuple[_Expr, _Expr]:
        """With a float operand, an int literal is converted to binary32 now, as Buzz would."""
        if a.ty == FLOAT and b.ty == INT and b.const is not None:
            self.literal(f32(float(b.const)))
            b = self.stack.pop()
        elif b.ty == FLOAT and a.ty == INT and a.const is not None:
            self.literal(f32(float(a.const)))
            a = self.stack.pop()
        return a, b

    @staticmethod
    def wrap_check(t: str, op: Op, b: _Expr) -> str:
        """The int32 overflow test. Its bounds are +-(2**30 - 1) because CPython 3.11
        specializes comparisons only with "compact" ints (magnitude below 2**30; -2**30 is
        not one), and two plain tests beat a chained comparison; `_i32` is exact for
        everything beyond. Adding or subtracting a small literal can only leave one way."""
        small = b.ty == INT and b.const is not None and 0 <= b.const < 0x40000000
        if small and op is Op.ADD:
            return f"if {t} > 1073741823: {t} = _i32({t})"
        if small and op is Op.SUB:
            return f"if {t} < -1073741823: {t} = _i32({t})"
        return f"if {t} > 1073741823 or {t} < -1073741823: {t} = _i32({t})"

    def inline_expr(self, code: str, ty: str, rng: Range = None) -> bool:
        """Push an operation that cannot fail as an expression rather than a statement into
        a temporary (saving a store and a load); False when it is too long to repeat, as
        `dup` may copy it and every use evaluates it."""
        if len(code) > 48:
            return False
        self.push(code, ty, rng=rng)
        return True

    def helper_binary(self, ins: Instruction) -> None:
        b, a = self.pop(), self.pop()
        if ins.op is Op.DIV:
            a, b = self.float_literal(a, b)
        t = self.temp()
        ta, tb = self.vtype(a), self.vtype(b)
        av, bv = self.val(a), self.val(b)
        at = ins.addr
        op = ins.op
        positive = tb == INT and b.const is not None and b.const > 0
        if ta == INT and positive and op in (Op.MOD, Op.DIV):
            # By a positive divisor, Buzz's remainder rule is Python's %, and C's truncating
            # division is floor division of the magnitude.
            if op is Op.MOD:
                self.emit(f"{t} = {av} % {bv}", at)
            else:
                self.emit(f"{t} = {av} // {bv} if {av} >= 0 else -(-{av} // {bv})", at)
            self.push(t, INT)
            return
        if op is Op.MOD and ta in (INT, ANY) and tb in (INT, ANY):
            # The same for ints known only at run time (`COUNTER % PERIOD`, every step of
            # most scripts); anything else takes the full rule.
            test = self.int_test(a, b)
            cond = f"{bv} > 0" if test == "True" else f"{test} and {bv} > 0"
            self.emit(f"{t} = ({av} % {bv}) if {cond} else _mod({av}, {bv})", at)
            self.push(t, INT if ta == INT and tb == INT else ANY)
            return
        if ta == FLOAT and tb == FLOAT and op is Op.DIV and b.const not in (None, 0.0):
            self.emit(f"_F[0] = {av} / {bv}", at)
            self.emit(f"{t} = _F[0]", at)
            self.push(t, FLOAT)
            return
        if ta == INT and tb == INT and op in (Op.BAND, Op.BOR, Op.RSHIFT):
            expr = {Op.BAND: f"{av} & {bv}", Op.BOR: f"{av} | {bv}"}.get(op)
            self.emit(f"{t} = {expr or f'{av} >> ({bv} & 31)'}", at)
            self.push(t, INT)
            return
        self.emit(f"{t} = {_HELPER_BINARY[op]}({av}, {bv})", at)
        if op is Op.POW:
            ty = FLOAT
        elif op in (Op.BAND, Op.BOR, Op.LSHIFT, Op.RSHIFT) or (ta == INT and tb == INT):
            ty = INT
        elif ta in (INT, FLOAT) and tb in (INT, FLOAT):
            ty = FLOAT
        else:
            ty = ANY
        self.push(t, ty)

    def unary_minus(self, ins: Instruction) -> None:
        a = self.pop()
        t = self.temp()
        if a.ty == INT:
            self.emit(f"{t} = -{a.code}", ins.addr)
            self.emit(f"if {t} == 2147483648: {t} = -2147483648", ins.addr)
            self.push(t, INT)
        elif a.ty == FLOAT:
            self.emit(f"{t} = -{a.code}", ins.addr)
            self.push(t, FLOAT)
        else:
            self.emit(f"{t} = _unm({self.val(a)})", ins.addr)
            self.push(t, ANY)

    def compare(self, ins: Instruction) -> None:
        b, a = self.pop(), self.pop()
        sym, slow = _COMPARE[ins.op]
        av, bv = self.val(a), self.val(b)
        ta, tb = self.vtype(a), self.vtype(b)
        equality = ins.op in (Op.EQ, Op.NEQ)
        same = ta == tb and ta != ANY
        if same and (equality or ta in (INT, FLOAT, STR)):
            # Python's own comparison is Buzz's for these (IEEE for floats, bytes for strings).
            # It cannot fail, so it stays an expression: `if a < b:` with no temporary.
            self.stack.append(_Expr(f"({av} {sym} {bv})", BOOL, cmp=_int_test_of(a, sym, b)))
            return
        if equality and ta != ANY and tb != ANY and NIL in (ta, tb):
            self.push("False" if ins.op is Op.EQ else "True", BOOL)
            return
        if equality and NIL in (ta, tb) and ANY in (ta, tb):
            # Only nil equals nil (Buzz compares everything but numbers and strings by
            # identity): an identity test that cannot fail.
            unknown = av if ta == ANY else bv
            self.stack.append(_Expr(f"({unknown} is {'not ' * (ins.op is Op.NEQ)}None)", BOOL))
            return
        t = self.temp()
        if equality and ANY in (ta, tb):
            known = tb if ta == ANY else ta
            unknown, other = (av, bv) if ta == ANY else (bv, av)
            cls = _GUARD_CLASS.get(known, f"{other}.__class__")
            self.emit(
                f"{t} = ({av} {sym} {bv}) if {unknown}.__class__ is {cls} else {slow}({av}, {bv})",
                ins.addr,
            )
        elif ta in (INT, ANY) and tb in (INT, ANY) and not equality:
            self.emit(
                f"{t} = ({av} {sym} {bv}) if {self.int_test(a, b)} else {slow}({av}, {bv})",
                ins.addr,
            )
        else:
            self.emit(f"{t} = {slow}({av}, {bv})", ins.addr)
        self.push(t, BOOL)

    def gload(self, ins: Instruction) -> None:
        name = self.pop()
        t = self.temp()
        pyname = python_name(name.const) if name.ty == STR and name.is_literal else None
        if pyname is not None:
            self.emit(f"{t} = {pyname}", ins.addr)
            self.stack.append(_Expr(t, origin=self.vm.globals.get(pyname)))
        else:
            self.emit(f"{t} = _gload({self.val(name)})", ins.addr)
            self.push(t)

    def gstore(self, ins: Instruction) -> None:
        v, name = self.pop(), self.pop()
        pyname = python_name(name.const) if name.ty == STR and name.is_literal else None
        if pyname is not None:
            self.global_names.add(pyname)
            self.emit(f"{pyname} = {self.val(v)}", ins.addr)
        else:
            self.emit(f"_gstore({self.val(name)}, {self.val(v)})", ins.addr)

    def key_test(self, k: _Expr) -> list[str]:
        if self.vtype(k) in (INT, STR):
            return []
        c = f"({k.code})" if k.is_literal else k.code  # `-1.5.__class__` would parse wrong
        return [f"({c}.__class__ is _str or {c}.__class__ is _int)"]

    def tget(self, ins: Instruction) -> None:
        k, tab = self.pop(), self.pop()
        t = self.temp()
        kv, tc = self.val(k), self.val(tab)
        tests = ([] if tab.ty == TABLE else [f"{tc}.__class__ is _Table"]) + self.key_test(k)
        # Attributed to the previous instruction when it fails (reference oldpc rule).
        at = self.prev_addr(ins)
        if tests:
            self.emit(f"{t} = {tc}[{kv}] if {' and '.join(tests)} else _tget({tc}, {kv})", at)
        else:
            self.emit(f"{t} = {tc}[{kv}]", at)
        origin = None
        if tab.origin.__class__ is Table and k.ty in (STR, INT):
            origin = tab.origin.get(k.const)
        self.stack.append(_Expr(t, origin=origin))

    def tput(self, ins: Instruction) -> None:
        v, k, tab = self.pop(), self.pop(), self.pop()
        kv, vv, tc = self.val(k), self.val(v), self.val(tab)
        at = self.prev_addr(ins)
        vt = self.vtype(v)
        if vt in (NIL, CLOSURE):  # deletion, or a closure to re-bind: the full rule
            self.emit(f"_tput({tc}, {kv}, {vv})", at)
            return
        tests = ([] if tab.ty == TABLE else [f"{tc}.__class__ is _Table"]) + self.key_test(k)
        if vt == ANY:
            tests.append(f"{vv} is not None and {vv}.__class__ is not _Closure")
        if tests:
            self.emit(f"if {' and '.join(tests)}: {tc}[{kv}] = {vv}", at)
            self.emit(f"else: _tput({tc}, {kv}, {vv})", at)
        else:
            self.emit(f"{tc}[{kv}] = {vv}", at)

    def call(self, ins: Instruction, context: tuple[int, int, Any, int] | None) -> None:
        """A call; `context` is the (index, region end, loop, leaves) of region() around it."""
        n = self.pop()
        if n.ty != INT or n.const is None or n.const < 0:
            raise NotStructured("call with a computed argument count")
        args = [self.pop() for _ in range(n.const)][::-1]
        c = self.pop()
        self.pop()  # the self slot below the closure: its value is ignored
        t = self.temp()
        at = ins.addr
        if c.ty not in (ANY, CLOSURE):
            self.emit(f"{t} = _not_callable({self.val(c)})", at)
        elif self.is_self_call(c, args):
            self.self_call(c, args, t, at, context)
            return
        elif self.direct_native(c, args, t, at):
            # Not the native's declared type: the unguarded path calls whatever closure
            # the name holds by then, which may return anything.
            self.push(t)
            return
        else:
            for line in self.closure_call(c, args, t):
                self.emit(line, at)
        self.push(t)

    def closure_call(self, c: _Expr, args: list[_Expr], t: str) -> list[str]:
        """The lines of a call through the closure protocol, result in `t`."""
        cc = c.code
        argv = "".join(f", {self.val(a)}" for a in args)
        tup = "".join(f"{self.val(a)}, " for a in args)
        # Zero-cost try: a non-closure has no `.fn`, a wrong argument count is a
        # TypeError raised at this very call; _call_failed tells those from errors
        # raised inside the callee, which it re-raises.
        # `_fn = c.fn; _fn(...)`: CPython 3.11 specializes a slot load, not a method load.
        return [
            f"try: _fn = {cc}.fn; {t} = _fn({cc}{argv})",
            f"except (_TypeError, _AttributeError): "
            f"{t} = _call_failed(_exc_info()[1], {cc}, ({tup}))",
        ]

    def is_self_call(self, c: _Expr, args: list[_Expr]) -> bool:
        """Whether a call looks like a call of the running function (its global holds it at
        translation time) with arguments of the types the unguarded body assumes."""
        sc, o = self.selfcall, c.origin
        return (
            sc is not None
            and o.__class__ is Closure
            and not o.native
            and o.ref == sc.addr
            and len(o.actrec) == sc.n_actrec
            and len(args) == len(sc.spec)
            and all(ty == ANY or self.vtype(a) == ty for a, ty in zip(args, sc.spec, strict=True))
        )

    def self_call(
        self,
        c: _Expr,
        args: list[_Expr],
        t: str,
        at: int,
        context: tuple[int, int, Any, int] | None,
    ) -> None:
        """A call of what may be the running closure: if the callee is `_C` (identity, at
        run time), the unguarded body is called directly. Any closure running this
        translation executes this bytecode with `_C`'s captured record, and the arguments
        have the speculated types, so that is what `_C.fn` would do, one frame the same.

        When the body is assumed to return type T (`ret`), the rest of the region after
        the call is emitted twice: once where the result is T (the direct call returned),
        and once, after a `_Deopt` or a call through the closure protocol, where it may be
        anything. The second copy must end in a return (so the two never merge)."""
        sc = self.selfcall
        assert sc is not None
        sc.sites += 1
        cc = c.code
        direct = f"{t} = {sc.name}(_C{''.join(f', {self.val(a)}' for a in args)})"
        general = self.closure_call(c, args, t)
        callee = self.unload_global(c, args)
        if callee != cc:  # test the global itself; only the general call needs the temporary
            general.insert(0, f"{cc} = {callee}")
        tail = sc.ret != ANY and context is not None and not context[3]
        if tail and not self.tail_depth and sc.sites <= _MAX_TAILS:
            if self.tail_twice(callee, direct, general, t, at, context):
                return
        self.emit(f"if {callee} is _C:", at)
        if sc.ret == ANY:  # the body never raises _Deopt
            self.emit(f"    {direct}", at)
        else:
            self.emit(f"    try: {direct}", at)
            self.emit(f"    except _Deopt: {t} = _exc_info()[1].args[0]", at)
        self.emit("else:", at)
        for line in general:
            self.emit(f"    {line}", at)
        self.push(t)

    def unload_global(self, c: _Expr, args: list[_Expr]) -> str:
        """The global name a callee was just loaded from, taking back the load into its
        temporary when nothing ran since (so the global still holds that value) and
        nothing else reads it; else the callee's code."""
        if not self.lines:
            return c.code
        indent, text, _, flags = self.lines[-1]
        name = text.removeprefix(f"{c.code} = ")
        if indent != self.indent or flags or name == text or python_name(name) != name:
            return c.code
        if any(re.search(rf"\b{c.code}\b", e.code) for e in (*self.stack, *args)):
            return c.code
        self.lines.pop()
        return name

    def tail_twice(
        self,
        callee: str,
        direct: str,
        general: list[str],
        t: str,
        at: int,
        context: tuple[int, int, Any, int],
    ) -> bool:
        """Emit a direct self-call whose result has the assumed type, with the rest of the
        region copied for the other cases (see self_call); False, with nothing emitted,
        when that rest does not end in a return. The shape:

            if callee is not _C:
                <general call>; <rest, result unknown>
            try: <direct call>
            except _Deopt:
                <result from the _Deopt>; <rest, result unknown>
            <rest, result of the assumed type>
        """
        sc = self.selfcall
        assert sc is not None
        i, j, loop, _ = context
        snap = self.snapshot()
        ntemps, stack, counters = self.ntemps, list(self.stack), list(self.counters)
        exits = loop.exits if loop is not None else None
        mark = len(self.lines)
        self.indent += 1
        self.stack.append(_Expr(t))
        self.tail_depth += 1
        try:
            self.region(i + 1, j, loop)
            ends = self.dead
        except NotStructured:
            ends = False
        finally:
            self.tail_depth -= 1
        rest = self.lines[mark:]
        self.restore(snap)
        # The copies never rejoin: their temporaries' names are free again (a smaller frame).
        self.ntemps, self.stack, self.counters = ntemps, stack, counters
        if not ends:
            if loop is not None:
                loop.exits = exits  # the breaks of the abandoned copy are not emitted
            return False
        self.emit(f"if {callee} is not _C:", at)
        for line in general:
            self.emit(f"    {line}", at)
        for indent, text, offset, flags in rest:
            self.emit(text, offset, flags, indent)
        self.emit(f"try: {direct}", at)
        self.emit("except _Deopt:", at)
        self.emit(f"    {t} = _exc_info()[1].args[0]", at)
        for indent, text, offset, flags in rest:
            self.emit(text, offset, flags, indent)
        # Below: reached only when the direct call returned normally.
        self.stack.append(_Expr(t, sc.ret))
        return True

    def direct_native(self, c: _Expr, args: list[_Expr], t: str, at: int) -> bool:
        """Call a host function's implementation directly when the callee is, at run time,
        the very closure it is now (an identity guard); False when that does not apply."""
        closure = c.origin
        if closure.__class__ is not Closure or not closure.native:
            return False
        impl, arity = self.vm.native_impl(closure.ref)
        if impl is None or (arity is not None and arity != len(args)):
            return False
        guard = self.fresh("_nc")
        self.consts[guard] = closure
        call = f"_ni{closure.ref}"
        self.consts[call] = impl
        owner = "None"
        if closure.actrec[0] is not None:
            owner = self.fresh("_ns")
            self.consts[owner] = closure.actrec[0]
        argv = "".join(f", {self.val(a)}" for a in args)
        cc = c.code
        direct = f"{call}({owner}{argv})"
        fast = self.inline_native(impl, args, direct)
        if fast is not None:
            expr, tests = fast
            # Parenthesized: the template may itself be a conditional expression.
            direct = f"({expr}) if {' and '.join(tests)} else {direct}" if tests else expr
        self.emit(f"if {cc} is {guard}: {t} = {direct}", at)
        self.emit("else:", at)
        for line in self.closure_call(c, args, t):
            self.emit(f"    {line}", at)
        return True

    def inline_native(
        self, impl: Any, args: list[_Expr], call: str
    ) -> tuple[str, list[str]] | None:
        """A library native's declared inline expression (`impl.inline`) for these arguments,
        with the class tests it still needs; None when it does not apply.

        The template gets the arguments as {0}, {1}... and the real call as {call} (for the
        cases it leaves to the native). It can use the helpers of `helpers()` (`_len`...),
        never Python's builtins, and must be exactly the native's result when it applies."""
        inline = getattr(impl, "inline", None)
        if inline is None or len(inline[1]) != len(args):
            return None
        template, types = inline
        tests = []
        for a, ty in zip(args, types, strict=True):
            if self.vtype(a) == ty:
                continue
            if self.vtype(a) != ANY:
                return None  # known to be another type: the native raises its error
            tests.append(f"{a.code}.__class__ is {_GUARD_CLASS[ty]}")
        return template.format(*(self.val(a) for a in args), call=call), tests

    def lstore(self, ins: Instruction) -> None:
        k = ins.arg
        v = self.pop()
        if k > len(self.types) or k >= MAX_LOCALS:  # type: ignore[operator]
            raise NotStructured("stores past the end of the locals")
        if len(self.stack) > 64:  # compiled code stores between statements, stack near empty
            raise NotStructured("deep stack at a local store")
        if k == len(self.types):
            self.types.append(ANY)
            self.ranges.append(None)
        name = f"_l{k}"
        # Values already on the stack that read this local must keep the old value.
        for idx, e in enumerate(self.stack):
            if re.search(rf"\b{name}\b", e.code):
                t = self.temp()
                self.emit(f"{t} = {self.val(e)}", ins.addr)
                self.stack[idx] = _Expr(t, self.vtype(e), rng=e.rng)
        self.emit(f"{name} = {self.val(v)}", ins.addr)
        self.types[k] = self.vtype(v)  # type: ignore[index]
        self.ranges[k] = v.rng if v.ty == INT else None  # type: ignore[index]
        self.used_locals.add(k)  # type: ignore[arg-type]

    def prev_addr(self, ins: Instruction) -> int:
        i = self.index[ins.addr]
        return self.instrs[i - 1].addr if i > 0 else ins.addr

    def entry_name(self, addr: int, size: int) -> str:
        name = f"_e{addr}_{size}"
        self.consts[name] = self.vm.entry(addr, size)
        return name


_ARITH = {Op.ADD: ("+", "_add"), Op.SUB: ("-", "_sub"), Op.MUL: ("*", "_mul")}
_HELPER_BINARY = {
    Op.DIV: "_div",
    Op.MOD: "_mod",
    Op.POW: "_pow",
    Op.BAND: "_band",
    Op.BOR: "_bor",
    Op.LSHIFT: "_lshift",
    Op.RSHIFT: "_rshift",
}
_COMPARE = {
    Op.EQ: ("==", "_eq"),
    Op.NEQ: ("!=", "_neq"),
    Op.LT: ("<", "_lt"),
    Op.LTE: ("<=", "_lte"),
    Op.GT: (">", "_gt"),
    Op.GTE: (">=", "_gte"),
}


def param_types(args: tuple) -> tuple[str, ...]:
    """The types to specialize on for these first-call arguments (ANY = no guard)."""
    return tuple(_KNOWN_CLASS.get(a.__class__, ANY) for a in args)


_GUARD_CLASS = {INT: "_int", FLOAT: "_float", STR: "_str", TABLE: "_Table"}


def translate(
    vm: VM,
    addr: int,
    n_actrec: int,
    nargs: int,
    *,
    toplevel: bool = False,
    speculate: tuple[str, ...] | None = None,
) -> Callable[..., Any]:
    """Python function for the bytecode function at `addr`, or raise NotStructured.

    For a function: called as `f(closure, *args)` with `n_actrec` captured slots and
    exactly `nargs` arguments. With `speculate`, argument k is assumed to have type
    `speculate[k]`; a call that breaks the assumption goes to the general translation.
    At top level: `f()`.
    """
    instrs = discover(vm, addr)
    if instrs[0].addr != addr:
        # Hand-made code that jumps back before its entry: regions run from the lowest
        # address, so only the interpreter can start in the middle.
        raise NotStructured("entry is not the function's lowest address")
    if toplevel:
        key = f"{addr}T"
        return _build(vm, instrs, _generate(vm, instrs, [], True, None, key), None, 0, 0, None)
    spec = speculate or (ANY,) * nargs
    # What the translation depends on besides the bytecode: names derived from it are the
    # same in every VM (see _compiled).
    key = f"{addr}_{n_actrec}_{nargs}{'S' if speculate else 'G'}{''.join(t[0] for t in spec)}"
    slot_types = [ANY] * n_actrec + list(spec)
    failure = NotStructured("no translation")
    for gen, sc in _function_bodies(vm, instrs, slot_types, n_actrec, spec, key):
        try:
            return _build(vm, instrs, gen, sc, n_actrec, nargs, speculate)
        except NotStructured as e:  # CPython refused it: try the next, simpler, candidate
            failure = e
    raise failure


def _build(
    vm: VM,
    instrs: list[Instruction],
    gen: _Codegen,
    sc: _SelfCall | None,
    n_actrec: int,
    nargs: int,
    speculate: tuple[str, ...] | None,
) -> Callable[..., Any]:
    """Compile a generated function (and its unguarded body, if it calls itself directly)."""
    first = addr = instrs[0].addr
    _make_room()
    # The cache's generation is in the function names: code objects compare by value, not
    # by file name, and LINE_MAPS holds each under the first equal one, whose death would
    # remove the entry; so a copy compiled after a clear must not equal one still alive.
    fname, bname = f"_f{gen.key}_{_generation}", f"_b{gen.key}_{_generation}"
    source: list[str] = []
    offsets = [first]  # line numbers start at 1; index 0 is unused

    def define(head: str, prologue: list[str], deopt: bool) -> None:
        if gen.global_names:
            prologue = [f"global {', '.join(sorted(gen.global_names))}", *prologue]
        source.append(head)
        offsets.append(first)
        for text in prologue:
            source.append("    " + text)
            offsets.append(first)
        for indent, text, offset, flags in gen.lines:
            if deopt or not flags & _DEOPT_ONLY:
                source.append("    " * indent + text)
                offsets.append(offset)
        if not gen.lines:
            source.append("    return None")
            offsets.append(first)

    twice = False
    if gen.toplevel:
        define(f"def {fname}():", [], False)
    else:
        params = "".join(f", _l{n_actrec + k}" for k in range(nargs))
        guards = [
            f"_l{n_actrec + k}.__class__ is not {_GUARD_CLASS[ty]}"
            for k, ty in enumerate(speculate or ())
            if ty in _GUARD_CLASS
        ]
        unpack = []
        if any(k < n_actrec for k in gen.used_locals):
            unpack.append(f"{', '.join(f'_l{k}' for k in range(n_actrec))}, = _C.actrec")
        prologue = list(unpack)
        if guards:
            general = f"_g{addr}_{n_actrec}_{nargs}"
            gen.consts[general] = vm.entry(addr, n_actrec).call_general
            prologue.insert(0, f"if {' or '.join(guards)}: return {general}(_C{params})")
        define(f"def {fname}(_C{params}):", prologue, False)
        # The unguarded body that direct self-calls enter: a copy, so that entering
        # through the guard costs no extra call (the same function when nothing differs).
        twice = sc is not None and (bool(guards) or sc.ret != ANY)
        if twice:
            define(f"def {bname}(_C{params}):", unpack, True)
    text = "\n".join(source) + "\n"
    code = _compiled(text, offsets, f"<buzz:{vm.program.path}@{addr}:{gen.key}")  # type: ignore[union-attr]
    namespace = vm.namespace()
    for key, value in gen.consts.items():
        namespace.setdefault(key, value)
    local: dict[str, Any] = {}
    exec(code, namespace, local)
    f = local[fname]
    LINE_MAPS[f.__code__] = offsets
    if sc is not None:
        body = local[bname] if twice else f
        LINE_MAPS[body.__code__] = offsets
        namespace[sc.name] = body
    return f


#: Compiled generated code by (source, line map): robots running the same script translate
#: the same functions to the same text, and compiling is most of a translation's cost.
#: Each VM still runs the code in its own namespace (`exec` below makes its functions).
_CODE: dict[tuple[str, tuple[int, ...]], CodeType] = {}
_CODE_MAX = 20_000
_generation = 0


def _make_room() -> None:
    """Clear the cache when full, starting a new generation of names."""
    global _generation
    if len(_CODE) >= _CODE_MAX:
        _CODE.clear()
        _generation += 1


def _compiled(text: str, offsets: list[int], name: str) -> CodeType:
    """The code object of generated module source `text`, compiled once."""
    key = (text, tuple(offsets))
    code = _CODE.get(key)
    if code is not None:
        return code
    if os.environ.get("BVM_DUMP_PY"):  # a developer's window into the translator
        sys.stderr.write(f"# {name}\n{text}\n")
    try:
        with warnings.catch_warnings():
            # Hostile bytecode can index a number: a run-time error, not a compiler remark.
            warnings.simplefilter("ignore", SyntaxWarning)
            code = compile(text, f"{name}>", "exec")
    except (SyntaxError, RecursionError, MemoryError, ValueError) as e:
        raise NotStructured(f"generated code did not compile: {e}") from None
    _CODE[key] = code
    return code


def _generate(
    vm: VM,
    instrs: list[Instruction],
    slot_types: list[str],
    toplevel: bool,
    selfcall: _SelfCall | None,
    key: str,
) -> _Codegen:
    gen = _Codegen(vm, instrs, slot_types, toplevel, selfcall, key)
    gen.region(0, len(instrs), None)
    return gen


def _function_bodies(
    vm: VM,
    instrs: list[Instruction],
    slot_types: list[str],
    n_actrec: int,
    spec: tuple,
    key: str,
) -> Iterator[tuple[_Codegen, _SelfCall | None]]:
    """A function's candidate codes, best first; each with its self-call record (None when
    it makes no direct self-calls). The last makes none, as before they existed.

    The direct self-calls' result type is inferred optimistically: assume the body
    returns T (the one type its returns have, apart from unknown ones), translate again,
    and keep that when every return outside the deoptimized tails then has type T."""
    if SELF_CALLS:
        addr = instrs[0].addr
        sc = _SelfCall(addr, n_actrec, spec, f"_s{key}")
        try:
            gen = _generate(vm, instrs, slot_types, False, sc, key)
        except NotStructured:
            gen = None
        if gen is not None and not sc.sites:
            yield gen, None  # the code without self-calls: there is no simpler one
            return
        if gen is not None:
            known = {ty for ty in sc.returns if ty != ANY}
            if gen.dead and len(known) == 1 and known <= {INT, FLOAT}:
                typed = _SelfCall(addr, n_actrec, spec, sc.name, known.pop())
                try:
                    gen2 = _generate(vm, instrs, slot_types, False, typed, key)
                except NotStructured:
                    gen2 = None
                # Sound either way (a return not of the type raises _Deopt; falling off
                # the end would not, hence `dead`); worth it when the direct calls do
                # return the type.
                if gen2 is not None and gen2.dead and all(t == typed.ret for t in typed.returns):
                    yield gen2, typed
            yield gen, sc
    yield _generate(vm, instrs, slot_types, False, None, key), None


def _redo(rule: Callable[[Any, Any], Any], a: Any, b: Any, result: Any) -> Any:
    """Python's `a + b` (or `-`) was not a small int: wrap an int, else apply the full rule."""
    if result.__class__ is int:
        return i32(result)
    if a.__class__ is float and b.__class__ is float:
        # Two binary32 values: their binary64 sum or difference rounded once to binary32
        # is the correctly rounded binary32 result (53 >= 2 * 24 + 2 bits), which the full
        # rule computes more slowly. NaNs and unrounded host floats take the full rule.
        cell = F32_CELL
        cell[0] = a
        if cell[0] == a:
            cell[0] = b
            if cell[0] == b:
                cell[0] = result
                return cell[0]
    return rule(a, b)


def _not_callable(c: Any) -> Any:
    raise BuzzError(f"type mismatch: expected closure, got {type_name(c)}")


def helpers() -> dict[str, Any]:
    """Names every generated function uses, independent of the VM (all start with `_`)."""
    return {
        "_int": int,
        "_float": float,
        "_len": len,
        "_str": str,
        "_TypeError": TypeError,
        "_AttributeError": AttributeError,
        "_Table": Table,
        "_Closure": Closure,
        "_Halt": Halt,
        # The counts of one chunk of a loop's iterations, 1 or 2 per iteration.
        "_KS1": tuple(range(CHUNK, 0, -1)),
        "_KS2": tuple(range(CHUNK, 0, -2)),
        "_Deopt": _Deopt,
        # The exception being handled, read in an `except` clause: an `as` name would be
        # one more local in every generated frame.
        "_exc_info": sys.exc_info,
        "_F": F32_CELL,
        "_i32": i32,
        "_redo": _redo,
        "_not_callable": _not_callable,
        "_add": ops.add,
        "_sub": ops.sub,
        "_mul": ops.mul,
        "_div": ops.div,
        "_mod": ops.mod,
        "_pow": ops.power,
        "_band": ops.band,
        "_bor": ops.bor,
        "_lshift": ops.lshift,
        "_rshift": ops.rshift,
        "_unm": ops.unm,
        "_bnot": ops.bnot,
        "_eq": ops.equals,
        "_neq": ops.not_equals,
        "_lt": ops.less,
        "_lte": ops.less_equal,
        "_gt": ops.greater,
        "_gte": ops.greater_equal,
        "_tget": ops.tget,
        "_tput": ops.tput,
    }
