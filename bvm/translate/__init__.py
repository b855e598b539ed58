"""Translate Buzz bytecode functions into Python functions at load time.

A dispatch loop over opcodes runs 20-50x slower than plain Python, so each function is
turned into Python source once and compiled by CPython. Anything that does not fit
(hand-made or hostile bytecode, inconsistent stack depths, an instruction certain to
fail) raises `NotStructured`, and that function runs on the reference interpreter
instead, so semantics never depend on the translator's coverage.

Error locations cost nothing on the fast path: each generated line maps to a bytecode
offset (`LINE_MAPS`), and bvm/vm.py reads the traceback when an error occurs.

The modules, one job each:

* `controlflow` -- the instructions of a function and the shapes of its loops;
* `lattice`     -- static types and int intervals (range analysis) of symbolic values;
* `codegen`     -- the Python source of a function, along those shapes and facts;
* `selfcall`    -- direct self-calls and their speculated result type;
* `build`       -- the entry point: candidates compiled into callable functions;
* `cache`       -- compiled code shared between VMs, and the line maps;
* `runtime`     -- the helpers generated code calls;
* `options`     -- what a VM asks of the translator (`TranslateOptions`);
* `host`        -- what the translator needs of a VM (`TranslatorHost`).
"""

from __future__ import annotations

from bvm.translate.build import translate
from bvm.translate.cache import LINE_MAPS, NO_OP, CodeCache, LineMap
from bvm.translate.controlflow import NotStructured, discover
from bvm.translate.host import TranslatorHost
from bvm.translate.lattice import ANY, param_types
from bvm.translate.naming import python_name
from bvm.translate.options import DEFAULT_OPTIONS, TranslateOptions
from bvm.translate.runtime import helpers

__all__ = [
    "ANY",
    "DEFAULT_OPTIONS",
    "LINE_MAPS",
    "NO_OP",
    "LineMap",
    "CodeCache",
    "NotStructured",
    "TranslateOptions",
    "TranslatorHost",
    "discover",
    "helpers",
    "param_types",
    "python_name",
    "translate",
]
