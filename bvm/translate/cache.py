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

#: Generated code object -> list mapping each generated line number to a bytecode offset.
#: Weak, so the maps go with the translations (a node that reloads scripts doesn't grow).
LINE_MAPS: weakref.WeakKeyDictionary[CodeType, list[int]] = weakref.WeakKeyDictionary()

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

    def make_room(self) -> None:
        """Clear the cache when full, starting a new generation of names."""
        if len(self._code) >= self.max_size:
            self._code.clear()
            self.generation = next(_generations)

    def compiled(self, text: str, offsets: list[int], name: str) -> CodeType:
        """The code object of generated module source `text`, compiled once."""
        key = (text, tuple(offsets))
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
