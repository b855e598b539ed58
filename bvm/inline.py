"""Inline expressions: what a library function declares the translator may emit in place
of a call to it.

A native declares, with `@inline(template, *types)`, a Python expression that computes
exactly its result when its arguments have the given Buzz types. Where translated code
calls that native with arguments of those types (known statically, or tested at run
time), it evaluates the expression instead of making a call. The template names the
arguments `{0}`, `{1}`, ..., the real call `{call}` (for the cases it leaves to the
native), and may use the helpers below by placeholder (`{len}(x)`), never Python's
builtins, which generated code cannot see.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

#: The Buzz types an argument of an inline expression can be required to have.
ArgType = Literal["int", "float", "str", "table"]

#: The helpers a template may use: placeholder -> (its name in generated code, the object).
HELPERS: dict[str, tuple[str, Any]] = {"len": ("_len", len), "str": ("_str", str)}

_ATTRIBUTE = "inline"
_F = TypeVar("_F", bound=Callable[..., Any])


@dataclass(frozen=True)
class InlineExpression:
    """A native's inline expression and the argument types it applies to."""

    template: str
    types: tuple[ArgType, ...]

    def expand(self, args: Sequence[str], call: str) -> str:
        """The expression for these argument expressions, `call` being the real call."""
        names = {placeholder: name for placeholder, (name, _) in HELPERS.items()}
        return self.template.format(*args, call=call, **names)


def inline(template: str, *types: ArgType) -> Callable[[_F], _F]:
    """Declare the inline expression of the decorated native (see the module docstring)."""

    def declare(impl: _F) -> _F:
        setattr(impl, _ATTRIBUTE, InlineExpression(template, types))
        return impl

    return declare


def inline_of(impl: object) -> InlineExpression | None:
    """The inline expression `impl` declares, or None."""
    found = getattr(impl, _ATTRIBUTE, None)
    return found if isinstance(found, InlineExpression) else None
