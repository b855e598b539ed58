"""Whole translations shared between VMs that run the same program.

A thousand robots running one script would each generate the same Python source for the
same functions: the code cache (cache.py) spares them the compile, but generating the
source (control flow, types, code) is most of what is left, and every robot pays it on the
first call of every function. A translation depends on the bytecode and on what the
translator read of its VM: global values (and members of global tables) whose current
value guides direct host calls and self-calls, and the host functions behind them.

So the first VM translates through a `Recorder`, which notes each of those reads with
what the translator made of the answer (a `signature`), and how to find each object the
translation binds (a recipe: the path to a global, a host function's id, an entry).
Another VM of the same program reuses the translation when every read gives it the same
signature (`Shared.replay`): the same source, hence the same code object, executed in its
own namespace with its own objects bound. Any difference translates afresh. The
translations are the same either way (the test compares runs with and without sharing).
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Iterator, Mapping
from typing import Any

from bvm.inline import inline_of
from bvm.program import Program
from bvm.translate.host import FunctionEntry, TranslatorHost
from bvm.values import Closure, Table

#: A read of the VM: ("g", name) a global, ("m", path, key) a member of a table read at
#: `path`, ("n", fid) a host function, ("e", addr, n_actrec) an entry made.
Read = tuple[Any, ...]

#: How many different translations of one function (by what they read) are kept.
MAX_VARIANTS = 8


def signature(value: Any) -> Any:
    """What code generation makes of a value it read (Expr.origin): its class, and of a
    closure what a direct or self call depends on."""
    if value.__class__ is Closure:
        return ("closure", value.native, value.ref, len(value.actrec), value.actrec[0] is None)
    return value.__class__


def impl_signature(impl: Any, arity: int | None) -> Any:
    """What code generation makes of a host function: whether there is one, its arity and
    the inline expression it declares."""
    return (impl is None, arity, id(inline_of(impl)) if impl is not None else None)


class _Globals(Mapping[str, Any]):
    """The VM's globals as the recorder hands them to code generation: reads are noted."""

    def __init__(self, recorder: Recorder) -> None:
        self._recorder = recorder

    def __getitem__(self, name: str) -> Any:
        """A global's current value, noted with its path."""
        globals_ = self._recorder.vm.globals
        if name not in globals_:
            raise KeyError(name)
        return self._recorder.read(("g", name), globals_[name])

    def get(self, name: str, default: Any = None) -> Any:
        """A global's current value (`default` if unset), noted with its path."""
        return self._recorder.read(("g", name), self._recorder.vm.globals.get(name, default))

    def __iter__(self) -> Iterator[str]:
        return iter(self._recorder.vm.globals)

    def __len__(self) -> int:
        return len(self._recorder.vm.globals)


class Recorder:
    """A TranslatorHost in front of a VM that notes what the translation reads of it."""

    def __init__(self, vm: TranslatorHost) -> None:
        self.vm = vm
        self.program = vm.program
        self.globals = _Globals(self)
        self.reads: list[tuple[Read, Any]] = []
        self.paths: dict[int, Read] = {}  # id of an object read -> how it was read
        self._alive: list[Any] = []  # the objects of `paths`, so that no id is reused
        self.shareable = True

    def read(self, path: Read, value: Any) -> Any:
        """Note that `path` gave `value`."""
        self.reads.append((path, signature(value)))
        if value.__class__ is Closure or value.__class__ is Table:
            self.paths.setdefault(id(value), path)
            self._alive.append(value)
        return value

    def member(self, table: Any, key: Any) -> Any:
        """`table.get(key)` of a table read earlier, noted."""
        path = self.paths.get(id(table))
        if path is None:  # not read through us: cannot be found in another VM
            self.shareable = False
            return table.get(key)
        return self.read(("m", path, key), table.get(key))

    def native_impl(self, fid: int) -> tuple[Callable[..., Any] | None, int | None]:
        """The VM's host function `fid`, noted."""
        impl, arity = self.vm.native_impl(fid)
        self.reads.append((("n", fid), impl_signature(impl, arity)))
        return impl, arity

    def entry(self, addr: int, n_actrec: int) -> FunctionEntry:
        """The VM's entry (made if new: the replay makes it too, in the same order)."""
        self.reads.append((("e", addr, n_actrec), None))
        return self.vm.entry(addr, n_actrec)

    def namespace(self) -> dict[str, Any]:
        """The VM's namespace."""
        return self.vm.namespace()

    def path_of(self, value: Any) -> Read | None:
        """How `value` was read (None: not through this recorder)."""
        return self.paths.get(id(value))


def resolve(vm: TranslatorHost, path: Read) -> Any:
    """The value at `path` in `vm`, found the way the translator found it."""
    if path[0] == "g":
        return vm.globals.get(path[1])
    table = resolve(vm, path[1])
    return table.get(path[2]) if table.__class__ is Table else None


class Shared:
    """One translation (or its failure) with the reads it depends on."""

    __slots__ = ("reads", "result")

    def __init__(self, reads: list[tuple[Read, Any]], result: Any) -> None:
        self.reads = reads
        self.result = result

    def replay(self, vm: TranslatorHost) -> bool:
        """Whether `vm` answers every read alike (making the entries the translation made)."""
        for path, sig in self.reads:
            kind = path[0]
            if kind == "e":
                vm.entry(path[1], path[2])
            elif kind == "n":
                if impl_signature(*vm.native_impl(path[1])) != sig:
                    return False
            elif signature(resolve(vm, path)) != sig:
                return False
        return True


class SharedStore:
    """Translations by program and function, for the VMs of one code cache."""

    def __init__(self) -> None:
        self._by_program: dict[int, tuple[weakref.ref[Program], dict[Any, list[Shared]]]] = {}

    def variants(self, program: Program, key: Any) -> list[Shared]:
        """The translations kept for `key` in `program` (a list to append to)."""
        held = self._by_program.get(id(program))
        if held is None or held[0]() is not program:
            pid = id(program)

            def gone(ref: weakref.ref[Program]) -> None:
                if self._by_program.get(pid, (None,))[0] is ref:
                    del self._by_program[pid]

            held = (weakref.ref(program, gone), {})
            self._by_program[pid] = held
        return held[1].setdefault(key, [])

    def clear(self) -> None:
        """Forget every translation (the code cache was cleared)."""
        self._by_program.clear()
