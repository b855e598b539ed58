"""Every error bvm raises, under one root: `BvmError`.

    BvmError
    ├── BuzzCompileError     malformed Buzz source
    ├── BuzzAsmError         malformed Buzz assembly
    ├── BuzzLoadError        a .bo or .bdb that cannot be loaded
    ├── BuzzError            a Buzz run-time error, located in the source
    │   └── BuzzBudgetExceeded   a step ran past its loop or time budget
    ├── wire.DecodeError     bytes that are not a Buzz message (also a ValueError)
    └── wire.EncodeError     a value or message the wire cannot carry (also a ValueError)

A host that runs scripts from elsewhere catches `BvmError` for "the script or its data
is bad" and lets anything else (a bug, or a host misusing the API) through. Exceptions
that transfer control rather than report an error (the interpreter's `Halt`, the
translator's `NotStructured`) are not part of it; they never reach a host.
"""

from __future__ import annotations

from dataclasses import dataclass


class BvmError(Exception):
    """The root of every error bvm raises."""


class BuzzCompileError(BvmError):
    """Malformed source: carries the place, the problem and an optional hint (Rust style)."""

    def __init__(
        self, path: str, line: int, col: int, message: str, hint: str | None = None
    ) -> None:
        super().__init__(message)
        self.path = path
        self.line = line
        self.col = col
        self.message = message
        self.hint = hint

    def __str__(self) -> str:
        # Line 0: about the file as a whole (it cannot be read), not a place in it.
        where = f"{self.path}:{self.line}:{self.col}" if self.line > 0 else self.path
        text = f"{where}: {self.message}"
        if self.hint:
            text += f"\n  hint: {self.hint}"
        return text


class BuzzAsmError(BvmError):
    """Malformed Buzz assembly (.basm) text."""

    def __init__(self, path: str, line: int, message: str) -> None:
        super().__init__(message)
        self.path = path
        self.line = line
        self.message = message

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.message}"


class BuzzLoadError(BvmError):
    """A .bo or .bdb that cannot be loaded: truncated, corrupted or hostile."""


class BuzzError(BvmError):
    """A Buzz runtime error, reported as `file:line:col: message` once located, followed
    by the Buzz call stack when it happened inside functions:

        robot.bzz:3:13: division by zero
          in ratio, called at robot.bzz:7:10
          in step, called by the host

    `offset` is the bytecode offset the reference attributes the error to (its `oldpc`
    rules), `op_offset` the failing instruction's own; `location` is `(file, line, col)`
    of the failing operation (from the source map, else the reference's from the .bdb).
    `stack` lists the functions it happened in, innermost first.
    """

    def __init__(self, message: str, offset: int | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.offset = offset
        self.op_offset: int | None = None
        self.location: tuple[str, int, int] | None = None
        self.stack: list[StackEntry] = []

    @property
    def headline(self) -> str:
        """The first line: `file:line:col: message` (or the offset, or just the message)."""
        if self.location is not None:
            file, line, col = self.location
            return f"{file}:{line}:{col}: {self.message}"
        if self.offset is not None:
            return f"bytecode offset {self.offset}: {self.message}"
        return self.message

    def __str__(self) -> str:
        return "\n".join([self.headline, *stack_lines(self.stack)])


@dataclass(frozen=True)
class StackEntry:
    """One Buzz function an error happened in, and where it was called from: `called_at`
    is `file:line:col` (or `bytecode offset N`), None when the host called it."""

    function: str
    called_at: str | None

    def __str__(self) -> str:
        if self.called_at is None:
            return f"  in {self.function}, called by the host"
        return f"  in {self.function}, called at {self.called_at}"


#: The most call-stack lines an error shows: the innermost and outermost halves.
MAX_STACK_LINES = 20


def stack_lines(stack: list[StackEntry]) -> list[str]:
    """The call stack as text lines, innermost first: repeats (recursion) folded into one
    line, and a very deep stack cut in the middle."""
    lines: list[str] = []
    k = 0
    while k < len(stack):
        n = 1
        while k + n < len(stack) and stack[k + n] == stack[k]:
            n += 1
        lines.append(str(stack[k]))
        if n > 1:
            lines.append(f"  ... the same call {n - 1} more times")
        k += n
    if len(lines) > MAX_STACK_LINES:
        half = MAX_STACK_LINES // 2
        hidden = len(lines) - 2 * half
        lines = [*lines[:half], f"  ... {hidden} more lines", *lines[-half:]]
    return lines


class BuzzBudgetExceeded(BuzzError):
    """A step ran past its instruction or time budget (an infinite loop cannot freeze a robot)."""
