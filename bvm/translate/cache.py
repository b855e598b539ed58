"""The compiled-code cache and the line maps that locate errors in generated code.

Robots running the same script translate the same functions to the same text, and
compiling is most of a translation's cost: a cache maps each generated text (with its
line map) to one code object, which every VM then runs in its own namespace.
"""

from __future__ import annotations

import itertools
import os
import sys
import warnings
import weakref
from types import CodeType

from bvm.translate.controlflow import NotStructured
from bvm.translate.shared import SharedStore

#: A line map's instruction for the lines a generated function runs before its body (its
#: `def`, entry guard and prologue): no instruction of its own.
NO_OP = -1


class LineMap:
    """Where the lines of one generated function are in the bytecode: for each line number,
    the reference's error offset (`offsets`) and the instruction the line performs (`ops`,
    NO_OP before the body); `addr` is the function's entry, `toplevel` set for the
    global code."""

    __slots__ = ("addr", "toplevel", "offsets", "ops")

    def __init__(self, addr: int, toplevel: bool, offsets: list[int], ops: list[int]) -> None:
        self.addr = addr
        self.toplevel = toplevel
        self.offsets = offsets
        self.ops = ops


#: Generated code object -> its LineMap (errors are located by the traceback's line numbers).
#: Weak, so the maps go with the translations (a node that reloads scripts doesn't grow).
LINE_MAPS: weakref.WeakKeyDictionary[CodeType, LineMap] = weakref.WeakKeyDictionary()

# Generations are numbered across every cache, so that no two caches (nor one cache
# before and after a clear) name two functions alike; see CodeCache.generation.
_generations = itertools.count()


class CodeCache:
    """Compiled generated code by (source, line map), cleared when it holds `max_size`."""

    def __init__(self, max_size: int = 20_000) -> None:
        self.max_size = max_size
        self._code: dict[tuple[str, tuple[int, ...]], CodeType] = {}
        # Part of every generated function's name. Code objects compare by value, not by
        # file name, and LINE_MAPS holds each under the first equal one, whose death would
        # remove the entry; so a copy compiled after a clear (or by another cache) must
        # not equal one still alive.
        self.generation = next(_generations)
        #: Whole translations, shared by the VMs of one program (shared.py).
        self.shared = SharedStore()

    def make_room(self) -> None:
        """Clear the cache when full, starting a new generation of names."""
        if len(self._code) >= self.max_size:
            self._code.clear()
            self.shared.clear()
            self.generation = next(_generations)

    def compiled(self, text: str, offsets: tuple[int, ...], name: str) -> CodeType:
        """The code object of generated module source `text` (whose line map is `offsets`),
        compiled once."""
        key = (text, offsets)
        code = self._code.get(key)
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
        self._code[key] = code
        return code


#: The cache VMs share unless their options name another.
SHARED_CACHE = CodeCache()
