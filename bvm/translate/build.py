"""Build and cache: a bytecode function's translation as a callable Python function.

The candidates code generation offers (best first, see selfcall.candidates) are turned
into module source with their entry guards and prologues, compiled through the code
cache, and executed in the VM's namespace; each resulting code object's line map goes
into LINE_MAPS so errors can be located and call stacks told.
"""

from __future__ import annotations

from collections.abc import Callable
from types import CodeType
from typing import Any

from bvm.program import Instruction
from bvm.translate.cache import LINE_MAPS, NO_OP, LineMap
from bvm.translate.codegen import SHIFTED, Codegen, generate
from bvm.translate.controlflow import NotStructured, discover
from bvm.translate.host import TranslatorHost
from bvm.translate.lattice import ANY, GUARD_CLASS
from bvm.translate.options import DEFAULT_OPTIONS, TranslateOptions
from bvm.translate.selfcall import DEOPT_ONLY, SelfCall, candidates
from bvm.translate.shared import MAX_VARIANTS, Recorder, Shared, resolve


class Built:
    """A compiled translation, ready to install in any VM of its program: the code, the
    names it defines, its line map and how to find each constant it binds."""

    __slots__ = ("code", "fname", "bname", "sc_name", "line_map", "recipes", "mapped")

    def __init__(
        self,
        code: CodeType,
        fname: str,
        bname: str | None,
        sc_name: str | None,
        line_map: LineMap,
        recipes: dict[str, tuple[Any, ...] | None],
    ) -> None:
        self.code = code
        self.fname = fname
        self.bname = bname  # the unguarded body's own name, if it has one
        self.sc_name = sc_name  # the name direct self-calls call
        self.line_map = line_map
        self.recipes = recipes
        # Whether LINE_MAPS has the functions' code: every install makes functions of the
        # same code objects, which live as long as `code`, so once is enough.
        self.mapped = False

    def constants(self, vm: TranslatorHost) -> dict[str, Any]:
        """The constants this translation binds, found in `vm`."""
        out: dict[str, Any] = {}
        for name, recipe in self.recipes.items():
            assert recipe is not None  # a Built with an unknown constant is never shared
            kind = recipe[0]
            if kind == "value":
                out[name] = recipe[1]
            elif kind == "path":
                out[name] = resolve(vm, recipe[1])
            elif kind == "owner":
                out[name] = resolve(vm, recipe[1]).actrec[0]
            elif kind == "impl":
                out[name] = vm.native_impl(recipe[1])[0]
            elif kind == "entry":
                out[name] = vm.entry(recipe[1], recipe[2])
            else:  # general
                out[name] = vm.entry(recipe[1], recipe[2]).call_general
        return out

    def install(self, vm: TranslatorHost, consts: dict[str, Any]) -> Callable[..., Any]:
        """Define the translation in `vm`'s namespace with `consts`; its function."""
        namespace = vm.namespace()
        for key, value in consts.items():
            namespace.setdefault(key, value)
        local: dict[str, Any] = {}
        exec(self.code, namespace, local)
        f: Callable[..., Any] = local[self.fname]
        body = f
        if self.sc_name is not None:
            body = local[self.bname] if self.bname is not None else f
            namespace[self.sc_name] = body
        if not self.mapped:
            LINE_MAPS[f.__code__] = LINE_MAPS[body.__code__] = self.line_map
            self.mapped = True
        return f


def translate(
    vm: TranslatorHost,
    addr: int,
    n_actrec: int,
    nargs: int,
    *,
    toplevel: bool = False,
    speculate: tuple[str, ...] | None = None,
    options: TranslateOptions = DEFAULT_OPTIONS,
) -> Callable[..., Any]:
    """Python function for the bytecode function at `addr`, or raise NotStructured.

    For a function: called as `f(closure, *args)` with `n_actrec` captured slots and
    exactly `nargs` arguments. With `speculate`, argument k is assumed to have type
    `speculate[k]`; a call that breaks the assumption goes to the general translation.
    At top level: `f()`.
    """
    if vm.program is None:
        raise NotStructured("no program loaded")
    if not options.share_translations:
        return _translate(vm, addr, n_actrec, nargs, toplevel, speculate, options)[0]
    # Another VM of this program may have made this translation already (shared.py).
    cache = options.cache
    cache.make_room()
    flags = (options.self_calls, options.chunked_loops)
    key = (addr, n_actrec, nargs, toplevel, speculate, flags, cache.generation)
    variants = cache.shared.variants(vm.program, key)
    for shared in variants:
        if shared.replay(vm):
            if isinstance(shared.result, NotStructured):
                raise NotStructured(str(shared.result))
            built: Built = shared.result
            return built.install(vm, built.constants(vm))
    recorder = Recorder(vm)
    try:
        f, built = _translate(recorder, addr, n_actrec, nargs, toplevel, speculate, options)
    except NotStructured as e:
        if recorder.shareable and len(variants) < MAX_VARIANTS:
            variants.append(Shared(recorder.reads, e))
        raise
    shareable = recorder.shareable and None not in built.recipes.values()
    if shareable and len(variants) < MAX_VARIANTS and key[-1] == cache.generation:
        variants.append(Shared(recorder.reads, built))
    return f


def _translate(
    vm: TranslatorHost,
    addr: int,
    n_actrec: int,
    nargs: int,
    toplevel: bool,
    speculate: tuple[str, ...] | None,
    options: TranslateOptions,
) -> tuple[Callable[..., Any], Built]:
    """translate(), from scratch."""
    assert vm.program is not None
    instrs = discover(vm.program, addr)
    if instrs[0].addr != addr:
        # Hand-made code that jumps back before its entry: regions run from the lowest
        # address, so only the interpreter can start in the middle.
        raise NotStructured("entry is not the function's lowest address")
    chunked = options.chunked_loops
    if toplevel:
        key = f"{addr}T"
        gen = generate(vm, instrs, [], True, None, key, chunked)
        return _build(vm, instrs, gen, None, 0, 0, None, options)
    spec = speculate or (ANY,) * nargs
    # What the translation depends on besides the bytecode: names derived from it are the
    # same in every VM (see CodeCache).
    key = f"{addr}_{n_actrec}_{nargs}{'S' if speculate else 'G'}{''.join(t[0] for t in spec)}"
    slot_types = [ANY] * n_actrec + list(spec)

    def emit(sc: SelfCall | None) -> Codegen:
        return generate(vm, instrs, slot_types, False, sc, key, chunked)

    failure = NotStructured("no translation")
    for gen, sc in candidates(emit, addr, n_actrec, spec, key, options.self_calls):
        try:
            return _build(vm, instrs, gen, sc, n_actrec, nargs, speculate, options)
        except NotStructured as e:  # CPython refused it: try the next, simpler, candidate
            failure = e
    raise failure


def _build(
    vm: TranslatorHost,
    instrs: list[Instruction],
    gen: Codegen,
    sc: SelfCall | None,
    n_actrec: int,
    nargs: int,
    speculate: tuple[str, ...] | None,
    options: TranslateOptions,
) -> tuple[Callable[..., Any], Built]:
    """Compile a generated function (and its unguarded body, if it calls itself directly)."""
    first = addr = instrs[0].addr
    cache = options.cache
    cache.make_room()
    fname, bname = f"_f{gen.key}_{cache.generation}", f"_b{gen.key}_{cache.generation}"
    source: list[str] = []
    # Per generated line (numbers start at 1; index 0 is unused): the reference's error
    # offset, and the instruction the line performs (NO_OP for the entry's own lines).
    offsets = [first]
    ops = [NO_OP]

    def define(head: str, prologue: list[str], deopt: bool) -> None:
        if gen.global_names:
            prologue = [f"global {', '.join(sorted(gen.global_names))}", *prologue]
        source.append(head)
        offsets.append(first)
        ops.append(NO_OP)
        for text in prologue:
            source.append("    " + text)
            offsets.append(first)
            ops.append(NO_OP)
        for indent, text, offset, flags in gen.lines:
            if deopt or not flags & DEOPT_ONLY:
                source.append("    " * indent + text)
                offsets.append(gen.prev_addr(offset) if flags & SHIFTED else offset)
                ops.append(offset)
        if not gen.lines:
            source.append("    return None")
            offsets.append(first)
            ops.append(first)

    twice = False
    if gen.toplevel:
        define(f"def {fname}():", [], False)
    else:
        params = "".join(f", _l{n_actrec + k}" for k in range(nargs))
        guards = [
            f"_l{n_actrec + k}.__class__ is not {GUARD_CLASS[ty]}"
            for k, ty in enumerate(speculate or ())
            if ty in GUARD_CLASS
        ]
        unpack = []
        if any(k < n_actrec for k in gen.used_locals):
            unpack.append(f"{', '.join(f'_l{k}' for k in range(n_actrec))}, = _C.actrec")
        prologue = list(unpack)
        if guards:
            general = f"_g{addr}_{n_actrec}_{nargs}"
            gen.bind(general, vm.entry(addr, n_actrec).call_general, ("general", addr, n_actrec))
            prologue.insert(0, f"if {' or '.join(guards)}: return {general}(_C{params})")
        define(f"def {fname}(_C{params}):", prologue, False)
        # The unguarded body that direct self-calls enter: a copy, so that entering
        # through the guard costs no extra call (the same function when nothing differs).
        twice = sc is not None and (bool(guards) or sc.ret != ANY)
        if twice:
            define(f"def {bname}(_C{params}):", unpack, True)
    text = "\n".join(source) + "\n"
    code = cache.compiled(text, (*offsets, *ops), f"<buzz:{gen.program.path}@{addr}:{gen.key}")
    built = Built(
        code,
        fname,
        bname if twice else None,
        None if sc is None else sc.name,
        LineMap(first, gen.toplevel, offsets, ops),
        gen.recipes,
    )
    return built.install(vm, gen.consts), built
