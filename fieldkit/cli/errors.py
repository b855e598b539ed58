"""The command line's one way to report an error, and its exit-code rule.

Every command exits 0 on success; 1 on a failure, after one line on stderr that begins
`error:` (for Buzz source errors `error: FILE:LINE:COL: message`, 1-based column; a hint or,
for a runtime error, the Buzz call stack may follow on the next lines); 2 when
the command line does not parse (an unknown option, a missing argument, `--seconds abc`).
Nothing a user can type ends in a Python traceback: `FieldkitGroup` turns usage errors into
the same `error:` line and unexpected exceptions into an `error:` line naming them. It also
renders every command's help as plain text (`plain_help`). Ctrl-C is a failure too:
`error: interrupted`, exit 1 (`fieldkit run` says where in the script).
"""

from __future__ import annotations

import os
import sys
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any, get_args

import typer
from typer.core import TyperArgument, TyperCommand, TyperGroup, TyperOption

from bvm.errors import BuzzAsmError, BuzzCompileError, BuzzError, BuzzLoadError

#: Exit statuses: success, a failure reported with `error:`, a command line that does not parse.
EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2

#: What typer returns when Ctrl-C interrupted a command (128 + SIGINT); reported as a failure.
EXIT_INTERRUPTED = 130

#: Set to 1 to see the traceback of an unexpected exception (for a bug report).
DEBUG_ENV = "FIELDKIT_DEBUG"


def error_text(problem: str | BaseException, path: str | Path | None = None) -> str:
    """What follows `error: `: the message, with its place (`path:line:col: ` for Buzz code).

    `path` names the file a problem is about when the exception does not carry it (a runtime
    error without debug info, a corrupt .bo, an OSError without a file name).
    """
    if isinstance(problem, str):
        return problem
    if isinstance(problem, (BuzzCompileError, BuzzAsmError)):
        return str(problem)  # they carry path:line[:col] themselves
    if isinstance(problem, BuzzError):
        located = problem.location is not None or path is None
        return str(problem) if located else f"{path}: {problem}"
    if isinstance(problem, OSError):
        where = problem.filename if problem.filename is not None else path
        reason = problem.strerror or str(problem)
        return f"{where}: {reason}" if where is not None else reason
    if isinstance(problem, BuzzLoadError) and path is not None:
        return f"{path}: {problem}"
    return str(problem)


def report(problem: str | BaseException, path: str | Path | None = None) -> None:
    """Print `error: ...` on stderr (more lines, such as a hint, may follow the first)."""
    typer.echo(f"error: {error_text(problem, path)}", err=True)


def fail(problem: str | BaseException, path: str | Path | None = None) -> typer.Exit:
    """Report `problem` and return the exit (status 1) to raise: `raise fail(e) from None`."""
    report(problem, path)
    return typer.Exit(EXIT_FAILURE)


class UsageProblem(typer.TyperException):
    """A command line that does not parse, found by a command itself (exit 2)."""

    exit_code = EXIT_USAGE


def usage_error(message: str) -> UsageProblem:
    """A value that does not parse (exit 2, `error: MESSAGE`): `raise usage_error(...)`."""
    return UsageProblem(message)


class FieldkitGroup(TyperGroup):
    """The root command group: applies the exit-code rule to whatever a command raises."""

    def main(
        self,
        args: Sequence[str] | None = None,
        prog_name: str | None = None,
        complete_var: str | None = None,
        standalone_mode: bool = True,
        windows_expand_args: bool = True,
        **extra: Any,
    ) -> Any:
        """Run the command line; exit with the status of the rule above."""
        plain_help(self)
        if not standalone_mode:  # a caller that handles exceptions itself
            return super().main(
                args, prog_name, complete_var, standalone_mode, windows_expand_args, **extra
            )
        try:
            # Non-standalone: click hands usage errors back to us instead of printing them,
            # and returns the status of a typer.Exit (None when the command returned).
            status = super().main(
                args, prog_name, complete_var, False, windows_expand_args, **extra
            )
        except typer.TyperException as e:  # typer's (vendored) click usage errors, and ours
            status = _usage_error(e)
        except typer.Abort:
            typer.echo("error: aborted", err=True)
            status = EXIT_FAILURE
        except Exception as e:  # noqa: BLE001  # the contract: never a traceback
            status = _unexpected(e)
        if status == EXIT_INTERRUPTED:  # Ctrl-C that no command reported: typer's silent 130
            typer.echo("error: interrupted", err=True)
            status = EXIT_FAILURE
        sys.exit(status if isinstance(status, int) else EXIT_OK)


def plain_help(command: TyperCommand | TyperGroup) -> None:
    """Render the help of `command` and of every command under it as plain text.

    Rich markup mode reads help text as markup: `T:ROBOT:CODE` became `T🤖CODE` (`:robot:`
    is an emoji code), `[...]` would vanish as a style tag, and flags got a `<bool>` beside
    them. Help written for a terminal must print as written, so every command and group of
    the tree gets markup mode None, whichever Typer app registered it. Typer's plain mode
    still names a repeatable parameter's type as a Python annotation (`<list[Path]>`): such
    parameters show their element's type instead.
    """
    command.rich_markup_mode = None
    for param in command.params:
        annotation = getattr(param, "type_descriptor", None)
        elements = get_args(getattr(annotation, "annotation", None))
        if not elements:
            continue
        label = f"<{_type_label(elements[0])}>"
        if isinstance(param, TyperOption) and param.multiple and param.metavar is None:
            param.metavar = label
        elif isinstance(param, TyperArgument) and not isinstance(param, _ListArgument):
            param.__class__ = _ListArgument  # same layout: only its type label differs
    if isinstance(command, TyperGroup):
        for sub in command.commands.values():
            if isinstance(sub, (TyperCommand, TyperGroup)):
                plain_help(sub)


def _type_label(annotation: object) -> str:
    """How help names a value of this type: `path`, `int`, `str`..."""
    if isinstance(annotation, type):
        return "path" if issubclass(annotation, Path) else annotation.__name__
    return "value"


class _ListArgument(TyperArgument):
    """An argument taking several values: help names its element type, not `list[...]`."""

    def display_type(self, ctx: Any) -> str:
        """`<str>` for a `list[str]` argument."""
        elements = get_args(self.type_descriptor.annotation)
        return f"<{_type_label(elements[0] if elements else None)}>"


def _usage_error(e: typer.TyperException) -> int:
    """Print the usage line (when known), then the problem as an `error:` line; its status."""
    ctx = getattr(e, "ctx", None)  # set on usage errors found while parsing
    if type(e).__name__ == "NoArgsIsHelpError":  # `fieldkit sim` alone: the help is the answer
        typer.echo(e.format_message(), err=True)
        return e.exit_code
    if ctx is not None:
        typer.echo(ctx.get_usage(), err=True)
        typer.echo(f"Try '{ctx.command_path} --help' for help.", err=True)
    typer.echo(f"error: {e.format_message()}", err=True)
    return e.exit_code


def _unexpected(e: Exception) -> int:
    """An exception no command handled: one `error:` line, the traceback only on request."""
    if os.environ.get(DEBUG_ENV) == "1":
        traceback.print_exc()
    if isinstance(e, (OSError, BuzzError, BuzzLoadError, BuzzCompileError, BuzzAsmError)):
        report(e)
    else:
        report(
            f"unexpected {type(e).__name__}: {e} (a bug in fieldkit: please report it; "
            f"{DEBUG_ENV}=1 shows the traceback)"
        )
    return EXIT_FAILURE


__all__ = [
    "DEBUG_ENV",
    "EXIT_FAILURE",
    "EXIT_INTERRUPTED",
    "EXIT_OK",
    "EXIT_USAGE",
    "FieldkitGroup",
    "UsageProblem",
    "error_text",
    "fail",
    "plain_help",
    "report",
    "usage_error",
]
