"""Code generation: the Python source of one bytecode function.

The operand stack becomes Python locals (a symbolic stack of expressions) and the local
symbol slots become Python locals `_l0, _l1, ...`. Buzz globals are the generated
functions' own module globals, so a global read is CPython's specialized `LOAD_GLOBAL`.
Control flow is emitted as Python `if` and `while True` along the shapes controlflow
recovers; types and int ranges (lattice) flow through it, so known ints and floats run as
bare Python operations plus the int32 wrap or the binary32 rounding, and unknown operands
take an inline int/int path and call bvm/ops.py for everything else. Loop iterations are
counted for the budget by a `for` over one chunk's counts.

Every generated line carries the offset of the instruction it performs, which locates an
error raised there (the reference's offset differs for `tget`/`tput`: see `SHIFTED`).
"""

from __future__ import annotations

import itertools
import math
import re
from typing import TYPE_CHECKING, Any

from bvm.inline import inline_of
from bvm.interp import MAX_LOCALS
from bvm.opcodes import Op
from bvm.program import Instruction
from bvm.translate import selfcall
from bvm.translate.controlflow import NotStructured, for_shape, loop_depth, loop_headers
from bvm.translate.lattice import (
    ANY,
    BOOL,
    CLOSURE,
    FLOAT,
    GUARD_CLASS,
    INT,
    KNOWN_CLASS,
    NEGATE,
    NIL,
    STR,
    TABLE,
    Expr,
    Range,
    int_ranges,
    int_test_of,
    interval,
    join,
    join_range,
    refine,
    widen,
)
from bvm.translate.naming import python_name
from bvm.translate.selfcall import SelfCall
from bvm.values import Closure, Table, f32

if TYPE_CHECKING:
    from bvm.translate.host import TranslatorHost

MAX_NESTING = 80  # CPython's tokenizer allows 100 indentation levels
MAX_LOOPS = 18  # and 20 statically nested loops
MAX_PASSES = 8  # loop re-emissions while inferring types

#: A line's flag: the reference reports its errors at the instruction before the line's
#: own (`tget`/`tput` move `oldpc` only on success, docs/bytecode.md#step-loop).
SHIFTED = 2

#: Where a call sits: (instruction index, region end, enclosing loop, entries the region
#: leaves on the stack), so a self-call can emit the rest of its region twice.
RegionContext = tuple[int, int, "Loop | None", int]
#: Emission state: lines, local types and ranges, dead, indent, loops, self-call counts.
Snapshot = tuple[int, list[str], list[Range], bool, int, int, tuple[int, int] | None]


class Loop:
    """A loop being emitted: where its exit jumps go, and the locals at its exits."""

    __slots__ = ("exit", "start", "exits")

    def __init__(self, exit_addr: int | None, start: int) -> None:
        self.exit = exit_addr
        self.start = start
        self.exits: tuple[list[str], list[Range]] | None = None  # locals at the breaks


class Codegen:
    """Emits the Python source of one function from its structured instruction list."""

    def __init__(
        self,
        vm: TranslatorHost,
        instrs: list[Instruction],
        slot_types: list[str],
        toplevel: bool,
        selfcall: SelfCall | None = None,
        key: str = "",
        chunked_loops: bool = True,
    ) -> None:
        if vm.program is None:
            raise NotStructured("no program loaded")
        self.vm = vm
        self.program = vm.program
        self.selfcall = selfcall
        # Names of bound constants are `<prefix><key>_<n>`: the same in every VM that
        # translates the same function the same way, so they can share the compiled code.
        self.key = key
        self._names = itertools.count()
        self.tail_depth = 0  # > 0 inside the copy of a tail that assumes nothing of a result
        self.instrs = instrs
        self.index = {ins.addr: i for i, ins in enumerate(instrs)}
        self.headers = loop_headers(instrs)
        self.toplevel = toplevel
        self.types = list(slot_types)  # the static type of each live local slot
        self.ranges: list[Range] = [None] * len(slot_types)  # intervals of INT locals
        self.stack: list[Expr] = []
        self.lines: list[tuple[int, str, int, int]] = []  # indent, text, offset, flags
        self.emitted = 0
        self.max_emitted = 2000 + 40 * len(instrs)
        self.indent = 1
        self.loops = 0
        self.dead = False
        self.ntemps = 0
        self.consts: dict[str, Any] = {}
        # How to find each constant in another VM of the same program (shared.py); None
        # when one cannot be found there (the translation is then not shared).
        self.recipes: dict[str, tuple[Any, ...] | None] = {}
        self.counters: list[str] = []  # the loop-iteration counters of the enclosing loops
        self.used_locals: set[int] = set()
        self.global_names: set[str] = set()
        # A chunked loop is two Python blocks (`while` and `for`), and CPython allows 20
        # nested blocks: the outermost loops are chunked, as many as the deepest nest allows.
        depth = loop_depth(instrs)
        self.chunked_depth = max(0, min(depth, MAX_LOOPS - 1 - depth)) if chunked_loops else 0

    # ------------------------------------------------------------ helpers

    def emit(self, text: str, offset: int, flags: int = 0, indent: int | None = None) -> None:
        """Append one line of generated code, attributed to bytecode `offset`."""
        indent = self.indent if indent is None else indent
        if indent > MAX_NESTING:
            raise NotStructured("nesting too deep")
        self.emitted += 1
        if self.emitted > self.max_emitted:
            # Loop re-emission while types settle can multiply with nesting: give up and
            # interpret rather than spend unbounded time translating.
            raise NotStructured("translation work exceeded its bound")
        self.lines.append((indent, text, offset, flags))

    def temp(self) -> str:
        """A new temporary's name."""
        self.ntemps += 1
        return f"_t{self.ntemps}"

    def push(self, code: str, ty: str = ANY, const: Any = None, rng: Range = None) -> None:
        """Push a symbolic entry."""
        self.stack.append(Expr(code, ty, const, rng=rng))

    def fresh(self, prefix: str) -> str:
        """A new module-global name for a constant this translation binds."""
        return f"{prefix}{self.key}_{next(self._names)}"

    def bind(self, name: str, value: Any, recipe: tuple[Any, ...] | None) -> None:
        """Bind constant `name` to `value`, found in another VM by `recipe`."""
        self.consts[name] = value
        self.recipes[name] = recipe

    def path_of(self, value: Any) -> tuple[Any, ...] | None:
        """How the host read `value` (a recording host only, see shared.py)."""
        return self.vm.path_of(value)

    def pop(self) -> Expr:
        """Pop a symbolic entry; NotStructured on underflow (hand-made bytecode)."""
        if not self.stack:
            raise NotStructured("stack underflow")
        return self.stack.pop()

    def literal(self, value: Any) -> None:
        """Push a constant."""
        if value is None:
            self.push("None", NIL)
            return
        ty = KNOWN_CLASS[value.__class__]
        if value.__class__ is float and (math.isinf(value) or value != value or value == 0.0):
            # inf, NaN (keeping its sign bit) and -0.0 have no exact literal: bind the object
            name = self.fresh("_k")
            self.bind(name, value, ("value", value))
            self.push(name, ty, value)
        else:
            # A negative literal is parenthesized: `-2.5.__class__` would negate the class.
            code = f"({value!r})" if ty in (INT, FLOAT) and value < 0 else repr(value)
            self.push(code, ty, value, (value, value) if ty == INT else None)

    @staticmethod
    def val(e: Expr) -> str:
        """Code for the Buzz value of an entry."""
        return f"(1 if {e.code} else 0)" if e.ty == BOOL else e.code

    @staticmethod
    def vtype(e: Expr) -> str:
        """The static Buzz type of an entry's value."""
        return INT if e.ty == BOOL else e.ty

    def truth(self, e: Expr) -> str:
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

    def falsity(self, e: Expr) -> str:
        """Code for the Buzz falsity of an entry."""
        return f"not {self.truth(e)}"

    @staticmethod
    def int_test(*entries: Expr) -> str:
        """Code testing that every entry of unknown type holds an int."""
        tests = [f"{e.code}.__class__ is _int" for e in entries if e.ty == ANY]
        return " and ".join(tests) or "True"

    def block(self, i: int, j: int, loop: Loop | None, offset: int) -> None:
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

    def snapshot(self) -> Snapshot:
        """The emission state, to go back to when a trial emission is discarded."""
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

    def restore(self, snap: Snapshot) -> None:
        """Discard what was emitted since `snap` was taken."""
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

    def region(self, i: int, j: int, loop: Loop | None, *, leaves: int = 0) -> None:
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
        if self.loops > MAX_LOOPS:
            raise NotStructured("loops nested too deeply")
        shape = for_shape(instrs, self.index, i, j, header)
        counter = f"_n{self.loops}"
        chunked = self.loops <= self.chunked_depth
        if not chunked:
            self.emit(f"{counter} = _K", header)
        self.counters.append(counter)
        snap = self.snapshot()
        for _ in range(MAX_PASSES):
            entry = (list(self.types), list(self.ranges))
            if shape is not None:
                after, loop, end = self.for_loop(i, shape, chunked)
            else:
                k = backs[-1]
                exit_addr = instrs[k + 1].addr if k + 1 < len(instrs) else None
                loop = Loop(exit_addr, i)
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
                    [join(a, b) for a, b in zip(entry[0], end[0], strict=True)],
                    [widen(a, join_range(a, b)) for a, b in zip(entry[1], end[1], strict=True)],
                )
                widened = (widened[0], int_ranges(widened[0], widened[1]))
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

    def for_loop(
        self, i: int, shape: tuple[int, int, int, int], chunked: bool
    ) -> tuple[int, Loop, tuple[list[str], list[Range]] | None]:
        """A `for` loop of that shape: (the index after it, its exit record, the locals
        at the end of an iteration, None when it cannot end)."""
        p, lb, le, lu = shape
        instrs = self.instrs
        nslots = len(self.types)
        self.open_loop(instrs[i].addr, 2, chunked)
        loop = Loop(instrs[le].addr, i)
        self.region(i, p, loop, leaves=1)
        cond = self.pop()
        self.note_exit(loop, cond, False)
        self.emit(f"if {self.falsity(cond)}: break", instrs[p].addr)
        self.assume(cond, True)
        body, update = Loop(instrs[le].addr, lb), Loop(instrs[le].addr, lu)
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

    def note_exit(self, loop: Loop, cond: Expr | None = None, holds: bool = True) -> None:
        """Record the locals' state at a `break` taken when `cond` is `holds` (joined over
        every exit of the loop)."""
        types, ranges = list(self.types), list(self.ranges)
        if cond is not None and cond.cmp is not None:
            slot, op, c = cond.cmp
            ranges[slot] = refine(ranges[slot], op if holds else NEGATE[op], c)
        self.join_exit(loop, types, ranges)

    @staticmethod
    def join_exit(loop: Loop, types: list[str], ranges: list[Range]) -> None:
        """Join one exit's locals into the loop's exit record."""
        if loop.exits is None:
            loop.exits = (types, ranges)
        elif len(loop.exits[0]) != len(types):
            raise NotStructured("loop exits with different numbers of locals")
        else:
            loop.exits = (
                [join(a, b) for a, b in zip(loop.exits[0], types, strict=True)],
                [join_range(a, b) for a, b in zip(loop.exits[1], ranges, strict=True)],
            )

    def assume(self, cond: Expr, holds: bool) -> None:
        """Code that runs only when `cond` is `holds`: narrow the tested local's range."""
        if cond.cmp is not None:
            slot, op, c = cond.cmp
            if slot < len(self.ranges) and self.types[slot] == INT:
                self.ranges[slot] = refine(self.ranges[slot], op if holds else NEGATE[op], c)

    def branch(self, i: int, j: int, loop: Loop | None) -> int:
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
        target = ins.int_arg
        if loop is not None and target == loop.exit:
            self.note_exit(loop, cond, jumps_if)
            self.emit(f"if {taken}: break", ins.addr)
            self.assume(cond, not jumps_if)
            return i + 1
        m = self.index.get(target)
        if m is None or m <= i or m > j:
            raise NotStructured("branch leaves its region")
        entry = (list(self.types), list(self.ranges))
        self.emit(f"if {stays}:", ins.addr)
        last = instrs[m - 1]
        n2 = None
        if m - 1 > i and last.op is Op.JUMP and last.int_arg > target:
            n2 = self.index.get(last.int_arg)
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
            self.types = [join(a, b) for a, b in zip(then_state[0], else_state[0], strict=True)]
            joined = [join_range(a, b) for a, b in zip(then_state[1], else_state[1], strict=True)]
            self.ranges = int_ranges(self.types, joined)
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
            s = self.program.string(ins.int_arg)
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
            entry = self.entry_name(ins.int_arg, 1)
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
            entry = self.entry_name(ins.int_arg, size)
            self.emit(f"{t} = _Closure({ins.arg}, False, {actrec}, {entry}.fn)", at)
            self.push(t, CLOSURE)
        elif op is Op.LLOAD:
            k = ins.int_arg
            if k >= len(self.types):
                raise NotStructured("reads a local that does not exist")
            self.used_locals.add(k)
            self.push(f"_l{k}", self.types[k], rng=self.ranges[k])
        elif op is Op.LSTORE:
            self.lstore(ins)
        elif op is Op.LREMOVE:
            n = ins.int_arg
            if n + (0 if self.toplevel else 1) > len(self.types):
                raise NotStructured("removes locals that do not exist")
            if n:
                del self.types[len(self.types) - n :]
                del self.ranges[len(self.ranges) - n :]
        elif op is Op.RET0 or op is Op.RET1:
            if self.toplevel:
                raise NotStructured("return at top level")
            ret = None if op is Op.RET0 else self.pop()
            value = "None" if ret is None else self.val(ret)
            self.settle(at)
            selfcall.emit_return_check(self, NIL if ret is None else self.vtype(ret), value, at)
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
            rng = interval(
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
            redo = (
                f"{t}.__class__ is not _int or {t} > 1073741823 or {t} < -1073741823: "
                f"{t} = _redo({slow}, {av}, {bv}, {t})"
            )
            if ta == ANY and tb == ANY:
                # Two floats (vector maths on table fields): the full rule written out.
                self.emit(
                    f"if {t}.__class__ is _float and {av}.__class__ is _float and "
                    f"{bv}.__class__ is _float: {_round_both(t, av, sym, bv)}",
                    at,
                )
                self.emit(f"elif {redo}", at)
            else:
                self.emit(f"if {redo}", at)
            self.push(t, ANY)
        elif ta in (INT, ANY) and tb in (INT, ANY):
            self.emit(f"if {self.int_test(a, b)}:", at)
            self.emit(f"    {t} = {av} {sym} {bv}", at)
            self.emit(f"    {self.wrap_check(t, ins.op, b)}", at)
            if ta == ANY and tb == ANY:
                # Two floats (vector maths on table fields): the full rule written out.
                self.emit(f"elif {av}.__class__ is _float and {bv}.__class__ is _float:", at)
                self.emit(f"    {_round_both(t, av, sym, bv)}", at)
            self.emit(f"else: {t} = {slow}({av}, {bv})", at)
            self.push(t, ANY)
        elif {ta, tb} == {FLOAT, ANY}:
            # The unknown float is rounded first, as the rule does: a host may have stored
            # a double that is not binary32 (the known one is binary32 already).
            unknown = av if ta == ANY else bv
            expr = f"{t} {sym} {bv}" if ta == ANY else f"{av} {sym} {t}"
            self.emit(f"if {unknown}.__class__ is _float:", at)
            self.emit(f"    _F[0] = {unknown}; {t} = _F[0]; _F[0] = {expr}; {t} = _F[0]", at)
            self.emit(f"else: {t} = {slow}({av}, {bv})", at)
            self.push(t, FLOAT)
        else:
            self.emit(f"{t} = {slow}({av}, {bv})", at)
            numeric = ta in (INT, FLOAT) and tb in (INT, FLOAT)
            self.push(t, FLOAT if numeric or FLOAT in (ta, tb) else ANY)

    def float_literal(self, a: Expr, b: Expr) -> tuple[Expr, Expr]:
        """With a float operand, an int literal is converted to binary32 now, as Buzz would."""
        if a.ty == FLOAT and b.ty == INT and b.const is not None:
            self.literal(f32(float(b.const)))
            b = self.stack.pop()
        elif b.ty == FLOAT and a.ty == INT and a.const is not None:
            self.literal(f32(float(a.const)))
            a = self.stack.pop()
        return a, b

    @staticmethod
    def wrap_check(t: str, op: Op, b: Expr) -> str:
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
        """div, mod, pow and the bitwise operators: inline where the types allow."""
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
                self.emit(f"{t} = {_INT_INLINE[op].format(a=av, b=bv)}", at)
            self.push(t, INT)
            return
        if op is Op.MOD and ta in (INT, ANY) and tb in (INT, ANY):
            # The same for ints known only at run time (`COUNTER % PERIOD`, every step of
            # most scripts); anything else takes the full rule.
            # (A divisor beyond int32, which only a host could store, takes the rule,
            # which wraps.)
            test = self.int_test(a, b)
            cond = f"0 < {bv} < 2147483648"
            cond = cond if test == "True" else f"{test} and {cond}"
            self.emit(f"{t} = ({av} % {bv}) if {cond} else _mod({av}, {bv})", at)
            self.push(t, INT if ta == INT and tb == INT else ANY)
            return
        if op in _INT_INLINE and ta in (INT, ANY) and tb in (INT, ANY) and ANY in (ta, tb):
            # Ints known only at run time (fields of received messages, `flags | bit`):
            # Python's operator where it is Buzz's rule, the full rule for anything else.
            test = self.int_test(a, b)
            cond = test
            if op is Op.DIV:
                # A dividend beyond int32 (only a host could store one) takes the rule,
                # which wraps the quotient.
                cond = f"{test} and {bv} > 0 and -2147483649 < {av} < 2147483648"
            fast = _INT_INLINE[op].format(a=av, b=bv)
            self.emit(f"{t} = {fast} if {cond} else {_HELPER_BINARY[op]}({av}, {bv})", at)
            self.push(t, ANY if op is Op.DIV else INT)
            return
        if ta == FLOAT and tb == FLOAT and op is Op.DIV and b.const not in (None, 0.0):
            self.emit(f"_F[0] = {av} / {bv}", at)
            self.emit(f"{t} = _F[0]", at)
            self.push(t, FLOAT)
            return
        if ta == INT and tb == INT and op in (Op.BAND, Op.BOR, Op.RSHIFT):
            self.emit(f"{t} = {_INT_INLINE[op].format(a=av, b=bv)}", at)
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
        """Negation: int32 wrap for ints, plain for floats, the full rule otherwise."""
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
        """A comparison: a plain Python expression where it cannot fail."""
        b, a = self.pop(), self.pop()
        sym, slow = _COMPARE[ins.op]
        av, bv = self.val(a), self.val(b)
        ta, tb = self.vtype(a), self.vtype(b)
        equality = ins.op in (Op.EQ, Op.NEQ)
        same = ta == tb and ta != ANY
        if same and (equality or ta in (INT, FLOAT, STR)):
            # Python's own comparison is Buzz's for these (IEEE for floats, bytes for strings).
            # It cannot fail, so it stays an expression: `if a < b:` with no temporary.
            self.stack.append(Expr(f"({av} {sym} {bv})", BOOL, cmp=int_test_of(a, sym, b)))
            return
        if equality and ta != ANY and tb != ANY and NIL in (ta, tb):
            self.push("False" if ins.op is Op.EQ else "True", BOOL)
            return
        if equality and NIL in (ta, tb) and ANY in (ta, tb):
            # Only nil equals nil (Buzz compares everything but numbers and strings by
            # identity): an identity test that cannot fail.
            unknown = av if ta == ANY else bv
            self.stack.append(Expr(f"({unknown} is {'not ' * (ins.op is Op.NEQ)}None)", BOOL))
            return
        t = self.temp()
        if equality and ANY in (ta, tb):
            known = tb if ta == ANY else ta
            unknown, other = (av, bv) if ta == ANY else (bv, av)
            cls = GUARD_CLASS.get(known, f"{other}.__class__")
            self.emit(
                f"{t} = ({av} {sym} {bv}) if {unknown}.__class__ is {cls} else {slow}({av}, {bv})",
                ins.addr,
            )
        elif ta in (INT, ANY) and tb in (INT, ANY) and not equality:
            test = self.int_test(a, b)
            if ta == ANY and tb == ANY:
                # Two floats order as Python orders them (IEEE, NaN unordered), as the full
                # rule does without converting either.
                test = f"{test} or ({av}.__class__ is _float and {bv}.__class__ is _float)"
            elif _exact_in_binary32(a) or _exact_in_binary32(b):
                # A float against an int literal that binary32 holds exactly (`x < 0`): the
                # rule converts the int first, which changes nothing, so Python's mixed
                # comparison is the rule's.
                unknown = av if ta == ANY else bv
                test = f"{test} or {unknown}.__class__ is _float"
            self.emit(f"{t} = ({av} {sym} {bv}) if {test} else {slow}({av}, {bv})", ins.addr)
        elif not equality and {ta, tb} == {FLOAT, ANY}:
            # `turn < 0.0`: a float against a float is Python's comparison (as above).
            unknown = av if ta == ANY else bv
            self.emit(
                f"{t} = ({av} {sym} {bv}) if {unknown}.__class__ is _float else {slow}({av}, {bv})",
                ins.addr,
            )
        else:
            self.emit(f"{t} = {slow}({av}, {bv})", ins.addr)
        self.push(t, BOOL)

    def gload(self, ins: Instruction) -> None:
        """A global read: the Python global itself when the name is a literal identifier."""
        name = self.pop()
        t = self.temp()
        pyname = python_name(name.const) if name.ty == STR and name.is_literal else None
        if pyname is not None:
            self.emit(f"{t} = {pyname}", ins.addr)
            self.stack.append(Expr(t, origin=self.vm.globals.get(pyname)))
        else:
            self.emit(f"{t} = _gload({self.val(name)})", ins.addr)
            self.push(t)

    def gstore(self, ins: Instruction) -> None:
        """A global write, like gload."""
        v, name = self.pop(), self.pop()
        pyname = python_name(name.const) if name.ty == STR and name.is_literal else None
        if pyname is not None:
            self.global_names.add(pyname)
            self.emit(f"{pyname} = {self.val(v)}", ins.addr)
        else:
            self.emit(f"_gstore({self.val(name)}, {self.val(v)})", ins.addr)

    def key_test(self, k: Expr) -> list[str]:
        """The class tests a table key still needs (none when known int or string)."""
        if self.vtype(k) in (INT, STR):
            return []
        c = f"({k.code})" if k.is_literal else k.code  # `-1.5.__class__` would parse wrong
        return [f"({c}.__class__ is _str or {c}.__class__ is _int)"]

    def tget(self, ins: Instruction) -> None:
        """A table read, inline when the operands are known or tested to be a table and key."""
        k, tab = self.pop(), self.pop()
        t = self.temp()
        kv, tc = self.val(k), self.val(tab)
        tests = ([] if tab.ty == TABLE else [f"{tc}.__class__ is _Table"]) + self.key_test(k)
        # The reference attributes a failure to the previous instruction (SHIFTED).
        at = ins.addr
        if tests:
            self.emit(
                f"{t} = {tc}[{kv}] if {' and '.join(tests)} else _tget({tc}, {kv})", at, SHIFTED
            )
        else:
            self.emit(f"{t} = {tc}[{kv}]", at, SHIFTED)
        origin = None
        if tab.origin.__class__ is Table and k.ty in (STR, INT):
            origin = self.vm.member(tab.origin, k.const)
        self.stack.append(Expr(t, origin=origin))

    def tput(self, ins: Instruction) -> None:
        """A table write, inline for plain values; deletions and closures take the full rule."""
        v, k, tab = self.pop(), self.pop(), self.pop()
        kv, vv, tc = self.val(k), self.val(v), self.val(tab)
        at = ins.addr  # the reference's offset is the previous instruction's (SHIFTED)
        vt = self.vtype(v)
        if vt in (NIL, CLOSURE):  # deletion, or a closure to re-bind: the full rule
            self.emit(f"_tput({tc}, {kv}, {vv})", at, SHIFTED)
            return
        tests = ([] if tab.ty == TABLE else [f"{tc}.__class__ is _Table"]) + self.key_test(k)
        if vt == ANY:
            tests.append(f"{vv} is not None and {vv}.__class__ is not _Closure")
        if tests:
            self.emit(f"if {' and '.join(tests)}: {tc}[{kv}] = {vv}", at, SHIFTED)
            self.emit(f"else: _tput({tc}, {kv}, {vv})", at, SHIFTED)
        else:
            self.emit(f"{tc}[{kv}] = {vv}", at, SHIFTED)

    def call(self, ins: Instruction, context: RegionContext | None) -> None:
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
        elif selfcall.is_self_call(self, c, args):
            selfcall.self_call(self, c, args, t, at, context)
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

    def closure_call(self, c: Expr, args: list[Expr], t: str) -> list[str]:
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

    def direct_native(self, c: Expr, args: list[Expr], t: str, at: int) -> bool:
        """Call a host function's implementation directly when the callee is, at run time,
        the very closure it is now (an identity guard); False when that does not apply."""
        closure = c.origin
        if closure.__class__ is not Closure or not closure.native:
            return False
        impl, arity = self.vm.native_impl(closure.ref)
        if impl is None or (arity is not None and arity != len(args)):
            return False
        guard = self.fresh("_nc")
        path = self.path_of(closure)
        self.bind(guard, closure, None if path is None else ("path", path))
        call = f"_ni{closure.ref}"
        self.bind(call, impl, ("impl", closure.ref))
        owner = "None"
        if closure.actrec[0] is not None:
            owner = self.fresh("_ns")
            self.bind(owner, closure.actrec[0], None if path is None else ("owner", path))
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
        self, impl: object, args: list[Expr], call: str
    ) -> tuple[str, list[str]] | None:
        """A library native's declared inline expression (see bvm/inline.py) for these
        arguments, with the class tests it still needs; None when it does not apply."""
        inline = inline_of(impl)
        if inline is None or len(inline.types) != len(args):
            return None
        tests = []
        for a, ty in zip(args, inline.types, strict=True):
            if self.vtype(a) == ty:
                continue
            if self.vtype(a) != ANY:
                return None  # known to be another type: the native raises its error
            tests.append(f"{a.code}.__class__ is {GUARD_CLASS[ty]}")
        return inline.expand([self.val(a) for a in args], call), tests

    def lstore(self, ins: Instruction) -> None:
        """A local store, keeping stacked reads of the old value."""
        k = ins.int_arg
        v = self.pop()
        if k > len(self.types) or k >= MAX_LOCALS:
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
                self.stack[idx] = Expr(t, self.vtype(e), rng=e.rng)
        self.emit(f"{name} = {self.val(v)}", ins.addr)
        self.types[k] = self.vtype(v)
        self.ranges[k] = v.rng if v.ty == INT else None
        self.used_locals.add(k)

    def prev_addr(self, addr: int) -> int:
        """The address of the instruction before the one at `addr` (where the reference
        reports tget/tput errors)."""
        i = self.index[addr]
        return self.instrs[i - 1].addr if i > 0 else addr

    def entry_name(self, addr: int, size: int) -> str:
        """Bind the entry of the function at `addr` for `size` captured slots."""
        name = f"_e{addr}_{size}"
        self.bind(name, self.vm.entry(addr, size), ("entry", addr, size))
        return name


_ARITH = {Op.ADD: ("+", "_add"), Op.SUB: ("-", "_sub"), Op.MUL: ("*", "_mul")}


def _round_both(t: str, a: str, sym: str, b: str) -> str:
    """Statements (one line) setting `t` to ops' rule for two Python floats, f32(f32(a) sym
    f32(b)), through the same binary32 cell: the same bits, NaNs and infinities included,
    without a call (coverage's geometry does this thousands of times a robot)."""
    return f"_F[0] = {a}; {t} = _F[0]; _F[0] = {b}; _F[0] = {t} {sym} _F[0]; {t} = _F[0]"


#: Python's expression for two int32 values where it is Buzz's rule (division only by a
#: positive divisor: C truncation is then floor division of the magnitude).
_INT_INLINE = {
    Op.DIV: "(({a} // {b}) if {a} >= 0 else -(-{a} // {b}))",
    Op.BAND: "({a} & {b})",
    Op.BOR: "({a} | {b})",
    Op.RSHIFT: "({a} >> ({b} & 31))",
    Op.LSHIFT: "_i32({a} << ({b} & 31))",
}
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


def generate(
    vm: TranslatorHost,
    instrs: list[Instruction],
    slot_types: list[str],
    toplevel: bool,
    selfcall: SelfCall | None,
    key: str,
    chunked_loops: bool,
) -> Codegen:
    """The code of one function (or of the global code, `toplevel`)."""
    gen = Codegen(vm, instrs, slot_types, toplevel, selfcall, key, chunked_loops)
    gen.region(0, len(instrs), None)
    return gen


def _exact_in_binary32(e: Expr) -> bool:
    """Whether `e` is an int literal that converts to binary32 exactly (|n| <= 2**24)."""
    return e.ty == INT and e.const is not None and -(2**24) <= e.const <= 2**24
