"""The reference interpreter: one bytecode instruction at a time, exactly as the C VM steps.

It runs what the translator (bvm/translate/) declines: the load-time prologue,
hand-made or hostile bytecode whose control flow has no structured shape, and calls
with an unexpected number of arguments. It is also the oracle the translator is fuzzed
against. It is small and slow on purpose; speed lives in the translator.

Errors are attributed to `oldpc` following the reference's rules (docs/bytecode.md#step-loop),
and to the failing instruction itself for the source map: an exception leaving a frame
records that frame's `oldpc`, instruction and entry (see `recorded_pcs`), which the
locator in bvm/vm.py reads for the error's position and call stack.
"""

from __future__ import annotations

from types import TracebackType
from typing import TYPE_CHECKING, Any

from bvm import ops
from bvm.errors import BuzzError
from bvm.opcodes import Op
from bvm.values import Closure, Table, is_true, type_name

if TYPE_CHECKING:
    from bvm.vm import VM

_BINARY = {
    Op.ADD: ops.add,
    Op.SUB: ops.sub,
    Op.MUL: ops.mul,
    Op.DIV: ops.div,
    Op.MOD: ops.mod,
    Op.POW: ops.power,
    Op.BAND: ops.band,
    Op.BOR: ops.bor,
    Op.LSHIFT: ops.lshift,
    Op.RSHIFT: ops.rshift,
}
_COMPARE = {
    Op.EQ: ops.equals,
    Op.NEQ: lambda a, b: not ops.equals(a, b),
    Op.GT: ops.greater,
    Op.GTE: ops.greater_equal,
    Op.LT: ops.less,
    Op.LTE: ops.less_equal,
}

_NOT_ENOUGH_LOCALS = (
    "wrong number of local variables: not enough local symbols in stack "
    "(maybe you called a function with an insufficient number of parameters?)"
)


_TOO_FEW_LOCALS = "wrong number of local variables: not enough local symbols in stack"


#: Local symbols one activation may hold (compiled functions use a handful).
MAX_LOCALS = 4096


#: The attribute of an exception that maps interpreted frames' traceback entries to pcs.
PCS_ATTRIBUTE = "bvm_interpreter_pcs"

#: The entry recorded for the global code (and the load-time prologue): no function.
TOPLEVEL = -1


def recorded_pcs(exc: BaseException) -> dict[TracebackType, tuple[int, int, int]]:
    """For each interpreted frame `exc` left, by the frame's traceback entry: its `oldpc`
    (the reference's error offset), the offset of the instruction it was running (the
    failing operation, or the call the error came through) and the function's entry
    address (`TOPLEVEL` for the global code)."""
    pcs: dict[TracebackType, tuple[int, int, int]] = exc.__dict__.get(PCS_ATTRIBUTE, {})
    return pcs


class Halt(Exception):
    """`done` was executed: the VM stops, in state DONE."""


def _empty() -> BuzzError:
    return BuzzError("stack error: empty stack")


def interpret(
    vm: VM, pc: int, lsyms: list[Any] | None, *, toplevel: bool = False, stop_at_nop: bool = False
) -> Any:
    """Run one frame from `pc` until it returns (or, at top level, until `done`).

    `lsyms` is the frame's local symbols (element 0 is `self`); the top level has its own
    list so that a `var` inside a top-level block works (the reference crashes there).
    With `stop_at_nop`, run the load-time prologue: stop after the first `nop` and return
    the pc that follows it.
    """
    program = vm.program
    if program is None:
        raise BuzzError("no code loaded")
    size = len(program.bytecode)
    decode = program.decode
    charge = vm.budget.charge  # one loop iteration per backward jump (bvm/budget.py)
    stack: list[Any] = []
    push = stack.append
    pop = stack.pop
    if lsyms is None:
        lsyms = []
    oldpc = pc
    entry = TOPLEVEL if toplevel else pc
    ins = None  # the instruction running, for the error locator (None: pc does not decode)
    try:
        while True:
            ins = decode(pc)
            if ins is None:
                oldpc = pc
                if pc < 0 or pc >= size or program.bytecode[pc] < len(Op):
                    raise BuzzError("pc out of range")
                raise BuzzError("unknown instruction")
            op = ins.op
            # Most instructions move oldpc before acting; pop/tput/tget only after success,
            # so their errors are reported at the previous instruction (reference rule).
            if op is not Op.POP and op is not Op.TPUT and op is not Op.TGET:
                oldpc = pc
            pc = ins.next
            if op is Op.NOP:
                if stop_at_nop:
                    return pc
            elif op is Op.DONE:
                if toplevel:
                    return None
                raise Halt()
            elif op is Op.PUSHNIL:
                push(None)
            elif op is Op.DUP:
                if not stack:
                    raise _empty()
                push(stack[-1])
            elif op is Op.POP:
                if not stack:
                    raise _empty()
                pop()
                oldpc = ins.addr
            elif op is Op.RET0 or op is Op.RET1:
                if toplevel:
                    raise BuzzError("return outside a function")
                if op is Op.RET0:
                    return None
                if not stack:
                    raise _empty()
                return stack[-1]
            elif op in _BINARY:
                if len(stack) < 2:
                    raise _empty()
                b = pop()
                stack[-1] = _BINARY[op](stack[-1], b)
            elif op in _COMPARE:
                if len(stack) < 2:
                    raise _empty()
                b = pop()
                stack[-1] = 1 if _COMPARE[op](stack[-1], b) else 0
            elif op is Op.UNM or op is Op.BNOT or op is Op.LNOT:
                if not stack:
                    raise _empty()
                a = stack[-1]
                if op is Op.UNM:
                    stack[-1] = ops.unm(a)
                elif op is Op.BNOT:
                    stack[-1] = ops.bnot(a)
                else:
                    stack[-1] = 0 if is_true(a) else 1
            elif op is Op.LAND or op is Op.LOR:
                if len(stack) < 2:
                    raise _empty()
                b = pop()
                a = stack[-1]
                if op is Op.LAND:
                    stack[-1] = 1 if is_true(a) and is_true(b) else 0
                else:
                    stack[-1] = 1 if is_true(a) or is_true(b) else 0
            elif op is Op.GLOAD:
                if not stack:
                    raise _empty()
                stack[-1] = vm.gload(stack[-1])
            elif op is Op.GSTORE:
                if len(stack) < 2:
                    raise _empty()
                value = pop()
                vm.gstore(pop(), value)
            elif op is Op.PUSHT:
                push(Table())
            elif op is Op.TPUT:
                if len(stack) < 3:
                    raise _empty()
                v = pop()
                k = pop()
                t = pop()
                ops.tput(t, k, v)
                oldpc = ins.addr
            elif op is Op.TGET:
                if len(stack) < 2:
                    raise _empty()
                k = pop()
                stack[-1] = ops.tget(stack[-1], k)
                oldpc = ins.addr
            elif op is Op.CALLC or op is Op.CALLS:
                if not stack:
                    raise _empty()
                n = pop()
                if n.__class__ is not int:
                    raise BuzzError(f"type mismatch: expected integer, got {type_name(n)}")
                if n < 0 or len(stack) < n + 2:
                    raise BuzzError(f"stack error: stack idx {n + 1} out of bounds")
                c = stack[-n - 1]
                if c.__class__ is not Closure:
                    raise BuzzError(f"type mismatch: expected closure, got {type_name(c)}")
                args = stack[len(stack) - n :] if n else []
                del stack[len(stack) - n - 2 :]  # the arguments, the closure and its self slot
                push(vm.invoke(c, tuple(args)))
            elif op is Op.PUSHF or op is Op.PUSHI:
                push(ins.arg)
            elif op is Op.PUSHS:
                s = program.string(ins.arg)  # type: ignore[arg-type]  # only pushf's is a float
                if s is None:
                    raise BuzzError(f"unknown string id: id read = {ins.arg & 0xFFFF}")  # type: ignore[operator]  # only pushf's is a float
                push(s)
            elif op is Op.PUSHCN:
                push(vm.make_closure(ins.arg, (None,)))  # type: ignore[arg-type]  # only pushf's is a float
            elif op is Op.PUSHCC:
                push(vm.native_closure(ins.arg))  # type: ignore[arg-type]  # only pushf's is a float
            elif op is Op.PUSHL:
                # A lambda captures the creator's locals by value; at top level, just a nil self.
                actrec = tuple(lsyms) if lsyms else (None,)
                push(vm.make_closure(ins.arg, actrec))  # type: ignore[arg-type]  # only pushf's is a float
            elif op is Op.LLOAD:
                i: int = ins.arg  # type: ignore[assignment]  # only pushf's is a float
                if i >= len(lsyms):
                    raise BuzzError(_NOT_ENOUGH_LOCALS)
                push(lsyms[i])
            elif op is Op.LSTORE:
                if not stack:
                    raise _empty()
                i = ins.arg  # type: ignore[assignment]  # only pushf's is a float
                v = pop()
                if i < len(lsyms):
                    lsyms[i] = v
                elif i >= MAX_LOCALS:  # hand-made bytecode: don't let one frame eat memory
                    raise BuzzError(
                        "wrong number of local variables: "
                        f"slot {i} is past the limit of {MAX_LOCALS}"
                    )
                else:
                    # Storing past the end grows the record; the gap is nil.
                    lsyms.extend([None] * (i - len(lsyms)))
                    lsyms.append(v)
            elif op is Op.LREMOVE:
                count: int = ins.arg  # type: ignore[assignment]  # only pushf's is a float
                # A function's record also holds `self`; the top level's holds only block locals.
                if count + (0 if toplevel else 1) > len(lsyms):
                    raise BuzzError(_TOO_FEW_LOCALS)
                if count:
                    del lsyms[len(lsyms) - count :]
            elif op is Op.JUMP:
                pc = _target(ins.arg, size)  # type: ignore[arg-type]  # only pushf's is a float
                if pc <= ins.addr:
                    charge(1)
            elif op is Op.JUMPZ or op is Op.JUMPNZ:
                if not stack:
                    raise _empty()
                x = pop()
                if is_true(x) == (op is Op.JUMPNZ):
                    pc = _target(ins.arg, size)  # type: ignore[arg-type]  # only pushf's is a float
                    if pc <= ins.addr:
                        charge(1)
            else:  # pragma: no cover - every opcode is handled above
                raise BuzzError("unknown instruction")

    except BaseException as e:
        # The error locator (bvm/vm.py) attributes an error to the innermost Buzz frame,
        # for an interpreted one the `oldpc` it had: recorded on the exception, keyed by
        # this frame's traceback entry, only when one leaves (no cost on the way). Inline,
        # not a call: at the recursion limit a call would raise anew.
        e.__dict__.setdefault(PCS_ATTRIBUTE, {})[e.__traceback__] = (
            oldpc,
            oldpc if ins is None else ins.addr,
            entry,
        )
        raise


def _target(addr: int, size: int) -> int:
    if addr >= size:
        raise BuzzError("pc out of range")
    return addr
