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
        text = f"{self.path}:{self.line}:{self.col}: {self.message}"
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
    """A Buzz runtime error, reported as `file:line:col: message` once located.

    `offset` is the bytecode offset the error is attributed to (the reference's
    `oldpc` rules); `location` is `(file, line, col)` from the debug info.
    """

    def __init__(self, message: str, offset: int | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.offset = offset
        self.location: tuple[str, int, int] | None = None

    def __str__(self) -> str:
        if self.location is not None:
            file, line, col = self.location
            return f"{file}:{line}:{col}: {self.message}"
        if self.offset is not None:
            return f"bytecode offset {self.offset}: {self.message}"
        return self.message


class BuzzBudgetExceeded(BuzzError):
    """A step ran past its instruction or time budget (an infinite loop cannot freeze a robot)."""
