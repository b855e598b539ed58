"""Self-call speculation: a call of the running closure enters its unguarded body directly.

A recursive Buzz function calls itself through a global (`fib(n - 1)`). When, at run
time, that global holds the very closure running (`callee is _C`) and the arguments have
the types the translation speculated on, the call can skip the closure protocol and the
entry guard. When the body provably returns ints (or floats) given that its own direct
calls do, their results are typed so; a body that returns anything else hands it back
by `Deopt` to a copy of the call site's continuation that assumes nothing.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING

from bvm.translate.controlflow import NotStructured
from bvm.translate.lattice import ANY, FLOAT, GUARD_CLASS, INT, Expr
from bvm.translate.naming import python_name
from bvm.values import Closure

if TYPE_CHECKING:
    from bvm.translate.codegen import Codegen, RegionContext

#: Self-calls per function whose continuation is emitted twice.
MAX_TAILS = 8
#: A line of `Codegen.lines` only the unguarded body keeps (its `Deopt` check).
DEOPT_ONLY = 1


class SelfCall:
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
        # others check their value and raise `Deopt` with it, caught at the call site.
        self.ret = ret
        self.sites = 0  # self-calls emitted
        self.returns: list[str] = []  # static types of the returns outside deoptimized tails


class Deopt(Exception):  # noqa: N818 - not an error: a control transfer to the caller
    """Raised by a body whose result is not its inferred type, to the direct self-call that
    entered it; that call site then continues on code that assumes nothing of the result
    (`args[0]`). No `__init__` of its own: raising it must not take a Python frame, which
    at the recursion limit would turn a return into a stack overflow."""


def candidates(
    generate: Callable[[SelfCall | None], Codegen],
    addr: int,
    n_actrec: int,
    spec: tuple[str, ...],
    key: str,
    enabled: bool,
) -> Iterator[tuple[Codegen, SelfCall | None]]:
    """A function's candidate codes, best first; each with its self-call record (None when
    it makes no direct self-calls). The last makes none, as before they existed.

    `generate(selfcall)` emits the function with that self-call record. The direct
    self-calls' result type is inferred optimistically: assume the body returns T (the
    one type its returns have, apart from unknown ones), translate again, and keep that
    when every return outside the deoptimized tails then has type T."""
    if enabled:
        sc = SelfCall(addr, n_actrec, spec, f"_s{key}")
        gen: Codegen | None
        try:
            gen = generate(sc)
        except NotStructured:
            gen = None
        if gen is not None and not sc.sites:
            yield gen, None  # the code without self-calls: there is no simpler one
            return
        if gen is not None:
            known = {ty for ty in sc.returns if ty != ANY}
            if gen.dead and len(known) == 1 and known <= {INT, FLOAT}:
                typed = SelfCall(addr, n_actrec, spec, sc.name, known.pop())
                gen2: Codegen | None
                try:
                    gen2 = generate(typed)
                except NotStructured:
                    gen2 = None
                # Sound either way (a return not of the type raises Deopt; falling off
                # the end would not, hence `dead`); worth it when the direct calls do
                # return the type.
                if gen2 is not None and gen2.dead and all(t == typed.ret for t in typed.returns):
                    yield gen2, typed
            yield gen, sc
    yield generate(None), None


def is_self_call(gen: Codegen, c: Expr, args: list[Expr]) -> bool:
    """Whether a call looks like a call of the running function (its global holds it at
    translation time) with arguments of the types the unguarded body assumes."""
    sc, o = gen.selfcall, c.origin
    return (
        sc is not None
        and o.__class__ is Closure
        and not o.native
        and o.ref == sc.addr
        and len(o.actrec) == sc.n_actrec
        and len(args) == len(sc.spec)
        and all(ty == ANY or gen.vtype(a) == ty for a, ty in zip(args, sc.spec, strict=True))
    )


def emit_return_check(gen: Codegen, ty: str, value: str, at: int) -> None:
    """At a return of type `ty`: record it, and when it is not provably the assumed type,
    make the unguarded body hand it to its caller through `Deopt` (the guarded entry just
    returns)."""
    sc = gen.selfcall
    if sc is None:
        return
    if not gen.tail_depth:
        sc.returns.append(ty)
    if sc.ret != ANY and ty != sc.ret:
        cls = GUARD_CLASS[sc.ret]
        check = f"if {value}.__class__ is not {cls}: " if ty == ANY else ""
        gen.emit(f"{check}raise _Deopt({value})", at, DEOPT_ONLY)


def self_call(
    gen: Codegen,
    c: Expr,
    args: list[Expr],
    t: str,
    at: int,
    context: RegionContext | None,
) -> None:
    """A call of what may be the running closure: if the callee is `_C` (identity, at
    run time), the unguarded body is called directly. Any closure running this
    translation executes this bytecode with `_C`'s captured record, and the arguments
    have the speculated types, so that is what `_C.fn` would do, one frame the same.

    When the body is assumed to return type T (`ret`), the rest of the region after
    the call is emitted twice: once where the result is T (the direct call returned),
    and once, after a `Deopt` or a call through the closure protocol, where it may be
    anything. The second copy must end in a return (so the two never merge)."""
    sc = gen.selfcall
    assert sc is not None
    sc.sites += 1
    cc = c.code
    direct = f"{t} = {sc.name}(_C{''.join(f', {gen.val(a)}' for a in args)})"
    general = gen.closure_call(c, args, t)
    callee = unload_global(gen, c, args)
    if callee != cc:  # test the global itself; only the general call needs the temporary
        general.insert(0, f"{cc} = {callee}")
    if (
        context is not None
        and sc.ret != ANY
        and not context[3]
        and not gen.tail_depth
        and sc.sites <= MAX_TAILS
        and tail_twice(gen, callee, direct, general, t, at, context)
    ):
        return
    gen.emit(f"if {callee} is _C:", at)
    if sc.ret == ANY:  # the body never raises Deopt
        gen.emit(f"    {direct}", at)
    else:
        gen.emit(f"    try: {direct}", at)
        gen.emit(f"    except _Deopt: {t} = _exc_info()[1].args[0]", at)
    gen.emit("else:", at)
    for line in general:
        gen.emit(f"    {line}", at)
    gen.push(t)


def unload_global(gen: Codegen, c: Expr, args: list[Expr]) -> str:
    """The global name a callee was just loaded from, taking back the load into its
    temporary when nothing ran since (so the global still holds that value) and
    nothing else reads it; else the callee's code."""
    if not gen.lines:
        return c.code
    indent, text, _, flags = gen.lines[-1]
    name = text.removeprefix(f"{c.code} = ")
    if indent != gen.indent or flags or name == text or python_name(name) != name:
        return c.code
    if any(re.search(rf"\b{c.code}\b", e.code) for e in (*gen.stack, *args)):
        return c.code
    gen.lines.pop()
    return name


def tail_twice(
    gen: Codegen,
    callee: str,
    direct: str,
    general: list[str],
    t: str,
    at: int,
    context: RegionContext,
) -> bool:
    """Emit a direct self-call whose result has the assumed type, with the rest of the
    region copied for the other cases (see self_call); False, with nothing emitted,
    when that rest does not end in a return. The shape:

        if callee is not _C:
            <general call>; <rest, result unknown>
        try: <direct call>
        except _Deopt:
            <result from the Deopt>; <rest, result unknown>
        <rest, result of the assumed type>
    """
    sc = gen.selfcall
    assert sc is not None
    i, j, loop, _ = context
    snap = gen.snapshot()
    ntemps, stack, counters = gen.ntemps, list(gen.stack), list(gen.counters)
    exits = loop.exits if loop is not None else None
    mark = len(gen.lines)
    gen.indent += 1
    gen.stack.append(Expr(t))
    gen.tail_depth += 1
    try:
        gen.region(i + 1, j, loop)
        ends = gen.dead
    except NotStructured:
        ends = False
    finally:
        gen.tail_depth -= 1
    rest = gen.lines[mark:]
    gen.restore(snap)
    # The copies never rejoin: their temporaries' names are free again (a smaller frame).
    gen.ntemps, gen.stack, gen.counters = ntemps, stack, counters
    if not ends:
        if loop is not None:
            loop.exits = exits  # the breaks of the abandoned copy are not emitted
        return False
    gen.emit(f"if {callee} is not _C:", at)
    for line in general:
        gen.emit(f"    {line}", at)
    for indent, text, offset, flags in rest:
        gen.emit(text, offset, flags, indent)
    gen.emit(f"try: {direct}", at)
    gen.emit("except _Deopt:", at)
    gen.emit(f"    {t} = _exc_info()[1].args[0]", at)
    for indent, text, offset, flags in rest:
        gen.emit(text, offset, flags, indent)
    # Below: reached only when the direct call returned normally.
    gen.stack.append(Expr(t, sc.ret))
    return True
