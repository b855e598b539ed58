"""Translate Buzz bytecode functions into Python functions at load time.

A dispatch loop over opcodes runs 20-50x slower than plain Python, so each function
is turned into Python source once and compiled by CPython:

* the operand stack becomes Python locals (a symbolic stack of expressions);
* local symbol slots become Python locals `l0, l1, ...`;
* control flow is recovered from the shapes the Buzz compiler emits (if, if/else,
  while, for; Buzz has no break or goto), into Python `if` and `while True`;
* int/int arithmetic, comparisons and string/int-keyed table access are inlined;
  everything else calls the one definition in bvm/ops.py.

Anything that does not fit (hand-made or hostile bytecode, inconsistent stack depths,
a call with an unexpected argument count, an instruction that is certain to fail)
raises `NotStructured`, and the caller runs that function on the reference
interpreter instead, so semantics never depend on the translator's coverage.

Error locations cost nothing on the fast path: each generated line is mapped to the
bytecode offset it came from, and bvm/vm.py reads the traceback when an error occurs.
"""

from __future__ import annotations

import itertools
import math
from typing import TYPE_CHECKING, Any

from bvm import ops
from bvm.errors import BuzzError
from bvm.interp import Halt
from bvm.opcodes import Op
from bvm.program import Instruction
from bvm.values import Closure, Table, i32, type_name

if TYPE_CHECKING:
    from collections.abc import Callable

    from bvm.vm import VM

#: Generated file name -> list mapping each generated line number to a bytecode offset.
LINE_MAPS: dict[str, list[int]] = {}

_MAX_INSTRUCTIONS = 100_000
_MAX_NESTING = 80  # CPython's tokenizer allows 100 indentation levels
_MAX_LOOPS = 18  # and 20 statically nested loops
_serial = itertools.count()


class NotStructured(Exception):
    """The function has a shape the translator does not handle; interpret it instead."""


class _Missing:
    """Default value of parameters, marking an argument the caller did not pass."""


MISSING = _Missing()


def _wrap(x: Any) -> Any:
    return i32(x) if x.__class__ is int else x


def _not_callable(c: Any) -> Any:
    raise BuzzError(f"type mismatch: expected closure, got {type_name(c)}")


def _gload(name: Any) -> Any:  # pragma: no cover - replaced per VM, see _namespace
    raise NotImplementedError


# Binary operators: (template for the int/int fast path, slow-path function name).
_ARITH = {
    Op.ADD: ("+", "_add"),
    Op.SUB: ("-", "_sub"),
    Op.MUL: ("*", "_mul"),
}
_OTHER_BINARY = {
    Op.DIV: "_div",
    Op.MOD: "_mod",
    Op.POW: "_pow",
    Op.BAND: "_band",
    Op.BOR: "_bor",
    Op.LSHIFT: "_lshift",
    Op.RSHIFT: "_rshift",
}
_COMPARE = {
    Op.EQ: ("==", "_eq", True),
    Op.NEQ: ("!=", "_neq", True),
    Op.LT: ("<", "_lt", False),
    Op.LTE: ("<=", "_lte", False),
    Op.GT: (">", "_gt", False),
    Op.GTE: (">=", "_gte", False),
}

_NOCONST = object()


class _Expr:
    """A symbolic stack entry: Python code that evaluates to the value, without side effects.

    `kind` is "val" for a Buzz value or "bool" for a Python bool (a comparison result
    that becomes the int 0/1 only where it is used as a value).
    """

    __slots__ = ("code", "kind", "const")

    def __init__(self, code: str, kind: str = "val", const: Any = _NOCONST) -> None:
        self.code = code
        self.kind = kind
        self.const = const


class _Loop:
    __slots__ = ("header", "exit", "start")

    def __init__(self, header: int, exit_addr: int | None, start: int) -> None:
        self.header = header
        self.exit = exit_addr
        self.start = start


def discover(vm: VM, entry: int) -> list[Instruction]:
    """All instructions reachable from `entry`, in address order; NotStructured if any is bad."""
    program = vm.program
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
            target = ins.arg
            if target >= size:  # type: ignore[operator]
                raise NotStructured("jump out of range")
            work.append(target)  # type: ignore[arg-type]
            if op is Op.JUMP:
                continue
        work.append(ins.next)
    instrs = sorted(seen.values(), key=lambda i: i.addr)
    for a, b in itertools.pairwise(instrs):
        if a.next > b.addr and a.op is not Op.DONE:
            raise NotStructured("overlapping instructions")
    return instrs


class _Codegen:
    """Emits the Python source of one function from its structured instruction list."""

    def __init__(self, vm: VM, instrs: list[Instruction], nslots: int, toplevel: bool) -> None:
        self.vm = vm
        self.instrs = instrs
        self.index = {ins.addr: i for i, ins in enumerate(instrs)}
        self.headers = {
            ins.arg
            for ins in instrs
            if ins.op is Op.JUMP and ins.arg <= ins.addr  # type: ignore[operator]
        }
        for ins in instrs:
            if ins.op in (Op.JUMPZ, Op.JUMPNZ) and ins.arg <= ins.addr:  # type: ignore[operator]
                raise NotStructured("conditional backward jump")
        self.toplevel = toplevel
        self.nslots = nslots
        self.stack: list[_Expr] = []
        self.lines: list[tuple[int, str, int]] = []
        self.indent = 1
        self.loops = 0
        self.dead = False
        self.ntemps = 0
        self.consts: dict[str, Any] = {}
        self.used_locals: set[int] = set()

    # ------------------------------------------------------------ helpers

    def emit(self, text: str, offset: int) -> None:
        if self.indent > _MAX_NESTING:
            raise NotStructured("nesting too deep")
        self.lines.append((self.indent, text, offset))

    def temp(self) -> str:
        self.ntemps += 1
        return f"t{self.ntemps}"

    def pop(self) -> _Expr:
        if not self.stack:
            raise NotStructured("stack underflow")
        return self.stack.pop()

    def const(self, value: Any) -> _Expr:
        if value is None:
            return _Expr("None", const=None)
        if value.__class__ is float and (math.isinf(value) or value != value or value == 0.0):
            # inf, NaN (keeping its sign bit) and -0.0 have no exact literal: bind the object
            name = f"_k{len(self.consts)}"
            self.consts[name] = value
            return _Expr(name, const=value)
        return _Expr(repr(value), const=value)

    @staticmethod
    def val(e: _Expr) -> str:
        """Code for the Buzz value of an entry."""
        return f"(1 if {e.code} else 0)" if e.kind == "bool" else e.code

    @staticmethod
    def truth(e: _Expr) -> str:
        """Code for the Buzz truthiness of an entry (only nil and int 0 are false)."""
        if e.kind == "bool":
            return e.code
        if e.const is not _NOCONST:
            c = e.const
            return "True" if (c is not None and (c.__class__ is not int or c != 0)) else "False"
        c = e.code
        return f"({c} is not None and ({c}.__class__ is not int or {c} != 0))"

    def falsity(self, e: _Expr) -> str:
        return f"not {self.truth(e)}"

    def int_checks(self, *entries: _Expr) -> str:
        """Code testing that every non-constant entry holds an int (bools become 0/1)."""
        checks = [
            f"{e.code}.__class__ is int"
            for e in entries
            if e.kind != "bool" and e.const.__class__ is not int
        ]
        if any(e.const.__class__ not in (int, type(_NOCONST)) for e in entries):
            return "False"  # a float, string or nil literal never takes the int path
        return " and ".join(checks) or "True"

    def block(self, i: int, j: int, loop: _Loop | None, offset: int) -> None:
        """An indented region; `pass` when it emits nothing."""
        self.indent += 1
        mark = len(self.lines)
        self.region(i, j, loop)
        if len(self.lines) == mark:
            self.emit("pass", offset)
        self.indent -= 1

    def tick(self, offset: int) -> None:
        self.emit("_B[0] -= 1", offset)
        self.emit("if _B[0] <= 0: _tick()", offset)

    # ------------------------------------------------------------ structure

    def region(self, i: int, j: int, loop: _Loop | None) -> None:
        """Emit instructions [i, j); the symbolic stack is empty at both ends."""
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
            self.simple(ins)
            i += 1
        if self.stack and not self.dead:
            raise NotStructured("values left on the stack at a block boundary")

    def loop(self, i: int, j: int) -> int:
        """A loop whose header is instruction i; returns the index after it."""
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
        slots = self.nslots
        after = self.for_loop(i, j, header)
        if after is None:
            k = backs[-1]
            exit_addr = instrs[k + 1].addr if k + 1 < len(instrs) else None
            self.emit("while True:", header)
            self.indent += 1
            self.region(i, k, _Loop(header, exit_addr, i))
            self.end_iteration(slots, instrs[k].addr)
            after = k + 1
        self.loops -= 1
        self.dead = False
        return after

    def for_loop(self, i: int, j: int, header: int) -> int | None:
        """The `for` shape: Lc: cond; jumpnz Lb; jump Le; Lu: update; jump Lc; Lb: body; jump Lu."""
        instrs = self.instrs
        p = i
        while p < j and instrs[p].op not in (
            Op.JUMP,
            Op.JUMPZ,
            Op.JUMPNZ,
            Op.RET0,
            Op.RET1,
            Op.DONE,
        ):
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
        if instrs[lu].addr not in self.headers:
            return None
        slots = self.nslots
        self.emit("while True:", header)
        self.indent += 1
        loop = _Loop(header, instrs[le].addr, i)
        self.region(i, p, loop)
        cond = self.pop()
        self.emit(f"if {self.falsity(cond)}: break", instrs[p].addr)
        self.region(lb, le - 1, _Loop(instrs[lu].addr, instrs[le].addr, lb))
        self.region(lu, lb - 1, _Loop(instrs[lu].addr, instrs[le].addr, lu))
        self.end_iteration(slots, instrs[lb - 1].addr)
        return le

    def end_iteration(self, slots: int, offset: int) -> None:
        if not self.dead:
            if self.nslots != slots:
                raise NotStructured("loop body changes the number of locals")
            self.tick(offset)
        self.indent -= 1
        self.nslots = slots

    def branch(self, i: int, j: int, loop: _Loop | None) -> int:
        """A conditional jump at instruction i: a loop exit, an if, or an if/else."""
        instrs = self.instrs
        ins = instrs[i]
        cond = self.pop()
        if self.stack:
            raise NotStructured("stack not empty at a branch")
        # The jump is taken when the value is false (jumpz) or true (jumpnz).
        taken = self.falsity(cond) if ins.op is Op.JUMPZ else self.truth(cond)
        stays = self.truth(cond) if ins.op is Op.JUMPZ else self.falsity(cond)
        target = ins.arg
        if loop is not None and target == loop.exit:
            self.emit(f"if {taken}: break", ins.addr)
            return i + 1
        m = self.index.get(target)  # type: ignore[arg-type]
        if m is None or m <= i or m > j:
            raise NotStructured("branch leaves its region")
        slots = self.nslots
        self.emit(f"if {stays}:", ins.addr)
        last = instrs[m - 1]
        n2 = None
        if m - 1 > i and last.op is Op.JUMP and last.arg > target:  # type: ignore[operator]
            n2 = self.index.get(last.arg)  # type: ignore[arg-type]
            if n2 is None or n2 > j:
                n2 = None
        then_end = m - 1 if n2 is not None else m
        self.block(i + 1, then_end, loop, ins.addr)
        then_dead, then_slots = self.dead, self.nslots
        self.dead = False
        self.nslots = slots
        if n2 is None:
            if not then_dead and then_slots != slots:
                raise NotStructured("if body changes the number of locals")
            return m
        self.emit("else:", last.addr)
        self.block(m, n2, loop, last.addr)
        else_dead, else_slots = self.dead, self.nslots
        if then_dead and else_dead:
            self.dead = True
        elif then_dead:
            self.nslots = else_slots
        elif else_dead:
            self.nslots = then_slots
        elif then_slots != else_slots:
            raise NotStructured("branches leave different numbers of locals")
        else:
            self.nslots = then_slots
        return n2

    # ------------------------------------------------------------ instructions

    def simple(self, ins: Instruction) -> None:
        """One straight-line instruction."""
        op = ins.op
        at = ins.addr
        push = self.stack.append
        if self.dead:
            # Unreachable code after a return inside a structured block: nothing to emit.
            return
        if op is Op.NOP:
            return
        if op is Op.PUSHNIL:
            push(self.const(None))
        elif op is Op.PUSHI or op is Op.PUSHF:
            push(self.const(ins.arg))
        elif op is Op.PUSHS:
            s = self.vm.program.string(ins.arg)  # type: ignore[arg-type]
            if s is None:
                raise NotStructured("unknown string id")
            push(_Expr(repr(s), const=s))
        elif op is Op.DUP:
            e = self.pop()
            push(e)
            push(e)
        elif op is Op.POP:
            self.pop()
        elif op in _ARITH:
            self.arith(ins)
        elif op in _OTHER_BINARY:
            b, a = self.pop(), self.pop()
            t = self.temp()
            self.emit(f"{t} = {_OTHER_BINARY[op]}({self.val(a)}, {self.val(b)})", at)
            push(_Expr(t))
        elif op in _COMPARE:
            self.compare(ins)
        elif op is Op.UNM or op is Op.BNOT:
            a = self.pop()
            t = self.temp()
            fn = "_unm" if op is Op.UNM else "_bnot"
            self.emit(f"{t} = {fn}({self.val(a)})", at)
            push(_Expr(t))
        elif op is Op.LNOT:
            a = self.pop()
            t = self.temp()
            self.emit(f"{t} = {self.falsity(a)}", at)
            push(_Expr(t, "bool"))
        elif op is Op.LAND or op is Op.LOR:
            b, a = self.pop(), self.pop()
            t = self.temp()
            word = "and" if op is Op.LAND else "or"
            self.emit(f"{t} = ({self.truth(a)}) {word} ({self.truth(b)})", at)
            push(_Expr(t, "bool"))
        elif op is Op.GLOAD:
            name = self.pop()
            t = self.temp()
            if name.const.__class__ is str:
                self.emit(f"{t} = _G[{name.code}]", at)
            else:
                self.emit(f"{t} = _gload({self.val(name)})", at)
            push(_Expr(t))
        elif op is Op.GSTORE:
            v, name = self.pop(), self.pop()
            if name.const.__class__ is str:
                self.emit(f"_G[{name.code}] = {self.val(v)}", at)
            else:
                self.emit(f"_gstore({self.val(name)}, {self.val(v)})", at)
        elif op is Op.PUSHT:
            t = self.temp()
            self.emit(f"{t} = _Table()", at)
            push(_Expr(t))
        elif op is Op.TPUT:
            self.tput(ins)
        elif op is Op.TGET:
            self.tget(ins)
        elif op is Op.CALLC or op is Op.CALLS:
            self.call(ins)
        elif op is Op.PUSHCN:
            t = self.temp()
            entry = self.entry_name(ins.arg, 1)  # type: ignore[arg-type]
            self.emit(f"{t} = _Closure({ins.arg}, False, (None,), {entry}.fn)", at)
            push(_Expr(t))
        elif op is Op.PUSHCC:
            t = self.temp()
            self.emit(f"{t} = _native({ins.arg})", at)
            push(_Expr(t))
        elif op is Op.PUSHL:
            n = self.nslots
            if n == 0:
                actrec, size = "(None,)", 1
            else:
                actrec, size = "(" + "".join(f"l{k}, " for k in range(n)) + ")", n
                self.used_locals.update(range(n))
            t = self.temp()
            entry = self.entry_name(ins.arg, size)  # type: ignore[arg-type]
            self.emit(f"{t} = _Closure({ins.arg}, False, {actrec}, {entry}.fn)", at)
            push(_Expr(t))
        elif op is Op.LLOAD:
            k = ins.arg
            if k >= self.nslots:  # type: ignore[operator]
                raise NotStructured("reads a local that does not exist")
            self.used_locals.add(k)  # type: ignore[arg-type]
            push(_Expr(f"l{k}"))
        elif op is Op.LSTORE:
            self.lstore(ins)
        elif op is Op.LREMOVE:
            n = ins.arg
            if n + (0 if self.toplevel else 1) > self.nslots:  # type: ignore[operator]
                raise NotStructured("removes locals that do not exist")
            self.nslots -= n  # type: ignore[operator]
        elif op is Op.RET0 or op is Op.RET1:
            if self.toplevel:
                raise NotStructured("return at top level")
            value = "None" if op is Op.RET0 else self.val(self.pop())
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
        b, a = self.pop(), self.pop()
        sym, slow = _ARITH[ins.op]
        t = self.temp()
        av, bv = self.val(a), self.val(b)
        fast = self.int_checks(a, b)
        at = ins.addr
        self.emit(f"{t} = {av} {sym} {bv} if {fast} else {slow}({av}, {bv})", at)
        self.emit(f"if not -2147483648 <= {t} <= 2147483647: {t} = _wrap({t})", at)
        self.stack.append(_Expr(t))

    def compare(self, ins: Instruction) -> None:
        b, a = self.pop(), self.pop()
        sym, slow, any_same_class = _COMPARE[ins.op]
        t = self.temp()
        av, bv = self.val(a), self.val(b)
        if any_same_class:
            # ==/!= are right for any two values of one class (identity for tables etc.).
            fast = f"{av}.__class__ is {bv}.__class__"
        else:
            fast = self.int_checks(a, b)
        self.emit(f"{t} = ({av} {sym} {bv}) if {fast} else {slow}({av}, {bv})", ins.addr)
        self.stack.append(_Expr(t, "bool"))

    def tget(self, ins: Instruction) -> None:
        k, tab = self.pop(), self.pop()
        t = self.temp()
        kv = self.val(k)
        tc = self.val(tab)
        if k.const.__class__ in (str, int):
            fast = f"{tc}.__class__ is _Table"
        else:
            fast = f"{tc}.__class__ is _Table and ({kv}.__class__ is str or {kv}.__class__ is int)"
        # Attributed to the previous instruction when it fails (reference oldpc rule).
        at = self.prev_addr(ins)
        self.emit(f"{t} = {tc}[{kv}] if {fast} else _tget({tc}, {kv})", at)
        self.stack.append(_Expr(t))

    def tput(self, ins: Instruction) -> None:
        v, k, tab = self.pop(), self.pop(), self.pop()
        kv, vv, tc = self.val(k), self.val(v), self.val(tab)
        checks = [f"{tc}.__class__ is _Table"]
        if k.const.__class__ not in (str, int):
            checks.append(f"({kv}.__class__ is str or {kv}.__class__ is int)")
        if v.kind != "bool" and v.const is _NOCONST:
            checks.append(f"{vv} is not None and {vv}.__class__ is not _Closure")
        elif v.const is None:
            checks = ["False"]
        at = self.prev_addr(ins)
        self.emit(f"if {' and '.join(checks)}: {tc}[{kv}] = {vv}", at)
        self.emit(f"else: _tput({tc}, {kv}, {vv})", at)

    def call(self, ins: Instruction) -> None:
        n = self.pop()
        if n.const.__class__ is not int or n.const < 0:
            raise NotStructured("call with a computed argument count")
        args = [self.pop() for _ in range(n.const)][::-1]
        c = self.pop()
        self.pop()  # the self slot below the closure: its value is ignored
        t = self.temp()
        argv = "".join(f", {self.val(a)}" for a in args)
        if c.const is not _NOCONST or c.kind == "bool":
            self.emit(f"{t} = _not_callable({self.val(c)})", ins.addr)
        else:
            cc = c.code
            self.emit(
                f"{t} = {cc}.fn({cc}{argv}) if {cc}.__class__ is _Closure else _not_callable({cc})",
                ins.addr,
            )
        self.stack.append(_Expr(t))

    def lstore(self, ins: Instruction) -> None:
        k = ins.arg
        v = self.pop()
        if k > self.nslots:  # type: ignore[operator]
            raise NotStructured("stores past the end of the locals")
        if k == self.nslots:
            self.nslots += 1
        name = f"l{k}"
        # Values already on the stack that read this local must keep the old value.
        for idx, e in enumerate(self.stack):
            if name in e.code:
                t = self.temp()
                self.emit(f"{t} = {self.val(e)}", ins.addr)
                self.stack[idx] = _Expr(t)
        self.emit(f"{name} = {self.val(v)}", ins.addr)
        self.used_locals.add(k)  # type: ignore[arg-type]

    def prev_addr(self, ins: Instruction) -> int:
        i = self.index[ins.addr]
        return self.instrs[i - 1].addr if i > 0 else ins.addr

    def entry_name(self, addr: int, size: int) -> str:
        name = f"_e{addr}_{size}"
        self.consts[name] = self.vm.entry(addr, size)
        return name


def translate(
    vm: VM, addr: int, n_actrec: int, nargs: int, *, toplevel: bool = False
) -> Callable[..., Any]:
    """Python function for the bytecode function at `addr`, or raise NotStructured.

    For a function: called as `f(closure, *args)` with `n_actrec` captured slots and
    `nargs` arguments (another count is passed on to the VM). At top level: `f()`.
    """
    instrs = discover(vm, addr)
    nslots = 0 if toplevel else n_actrec + nargs
    gen = _Codegen(vm, instrs, nslots, toplevel)
    gen.region(0, len(instrs), None)
    first = instrs[0].addr
    name = f"<buzz:{vm.program.path}@{addr}#{next(_serial)}>"
    if toplevel:
        head = ["def _f():"]
        prologue: list[str] = []
    else:
        params = [f"l{n_actrec + k}" for k in range(nargs)]
        sig = "".join(f", {p}=_M" for p in params)
        head = [f"def _f(C{sig}, *X):"]
        last = params[-1] if params else None
        guard = f"X or {last} is _M" if last else "X"
        arglist = "(" + "".join(f"{p}, " for p in params) + ") + X"
        prologue = [f"if {guard}: return _other{addr}_{n_actrec}(C, {arglist})"]
        captured = sorted(k for k in gen.used_locals if k < n_actrec)
        if captured:
            names = ", ".join(f"l{k}" for k in range(n_actrec))
            prologue.append(f"{names}, = C.actrec")
        prologue += ["_B[0] -= 1", "if _B[0] <= 0: _tick()"]
    source = list(head)
    offsets = [first, first]  # line numbers start at 1; index 0 is unused
    for text in prologue:
        source.append("    " + text)
        offsets.append(first)
    for indent, text, offset in gen.lines:
        source.append("    " * indent + text)
        offsets.append(offset)
    if not gen.lines:
        source.append("    return None")
        offsets.append(first)
    namespace = vm.namespace()
    namespace.update(gen.consts)
    if not toplevel:
        namespace[f"_other{addr}_{n_actrec}"] = vm.entry(addr, n_actrec).other
    try:
        code = compile("\n".join(source) + "\n", name, "exec")
    except (SyntaxError, RecursionError, MemoryError, ValueError) as e:
        raise NotStructured(f"generated code did not compile: {e}") from None
    exec(code, namespace)
    LINE_MAPS[name] = offsets
    return namespace["_f"]


def base_namespace() -> dict[str, Any]:
    """Names every generated function can use, independent of the VM."""
    return {
        "_M": MISSING,
        "_Table": Table,
        "_Closure": Closure,
        "_Halt": Halt,
        "_wrap": _wrap,
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
        "_neq": lambda a, b: not ops.equals(a, b),
        "_lt": ops.less,
        "_lte": ops.less_equal,
        "_gt": ops.greater,
        "_gte": ops.greater_equal,
        "_tget": ops.tget,
        "_tput": ops.tput,
    }
