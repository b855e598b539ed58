"""The names generated code uses at run time, the same in every VM (all start with `_`)."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

from bvm import ops
from bvm.budget import CHUNK
from bvm.errors import BuzzError
from bvm.inline import HELPERS as INLINE_HELPERS
from bvm.interp import Halt
from bvm.translate.selfcall import Deopt
from bvm.values import F32_CELL, Closure, Table, i32, type_name


def redo(rule: Callable[[Any, Any], Any], a: Any, b: Any, result: Any) -> Any:
    """Python's `a + b` (or `-`, or `*` of two floats) was not a small int: wrap an int,
    else apply the full rule."""
    if result.__class__ is int:
        return i32(result)
    if a.__class__ is float and b.__class__ is float:
        # Two binary32 values: their binary64 sum, difference or product rounded once to
        # binary32 is the correctly rounded binary32 result (53 >= 2 * 24 + 2 bits), which
        # the full rule computes more slowly. NaNs and unrounded host floats take the full
        # rule.
        cell = F32_CELL
        cell[0] = a
        if cell[0] == a:
            cell[0] = b
            if cell[0] == b:
                cell[0] = result
                return cell[0]
    return rule(a, b)


def not_callable(c: Any) -> Any:
    """A call of a value known not to be a closure."""
    raise BuzzError(f"type mismatch: expected closure, got {type_name(c)}")


#: The counts of one chunk of a loop's iterations, 1 or 2 per iteration: made once for
#: every VM (1,500 ints, a fifth of a translated robot's memory when each VM made its own).
_CHUNK_COUNTS = (tuple(range(CHUNK, 0, -1)), tuple(range(CHUNK, 0, -2)))


def helpers() -> dict[str, Any]:
    """Names every generated function uses, independent of the VM (all start with `_`)."""
    inline = dict(INLINE_HELPERS.values())
    return {
        "_int": int,
        "_float": float,
        "_len": inline["_len"],
        "_str": inline["_str"],
        "_TypeError": TypeError,
        "_AttributeError": AttributeError,
        "_Table": Table,
        "_Closure": Closure,
        "_Halt": Halt,
        "_KS1": _CHUNK_COUNTS[0],
        "_KS2": _CHUNK_COUNTS[1],
        "_Deopt": Deopt,
        # The exception being handled, read in an `except` clause: an `as` name would be
        # one more local in every generated frame.
        "_exc_info": sys.exc_info,
        "_F": F32_CELL,
        "_i32": i32,
        "_redo": redo,
        "_not_callable": not_callable,
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
