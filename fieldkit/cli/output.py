"""Where the command line puts results: the output directory, the JSON writer, progress."""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import typer

from fieldkit import results
from fieldkit.cli.errors import fail


def write_json(path: Path, data: object) -> Path:
    """Write `data` as fieldkit's stable JSON (sorted keys) and say `wrote PATH` on stderr."""
    try:
        results.write_json(path, data)
    except OSError as e:
        raise fail(f"{path}: cannot write: {e.strerror or e}") from None
    wrote(path)
    return path


def wrote(path: Path) -> None:
    """Say where a result file went (stderr: stdout carries what scripts log)."""
    typer.echo(f"wrote {path}", err=True)


def out_dir(out: Path, option: str = "--out") -> Path:
    """Create the results directory `out` (and its parents), or fail with `error:`."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise fail(f"{option} {out}: cannot create: {e.strerror or e}") from None
    return out


@contextmanager
def progress_bar(label: str, total: int) -> Iterator[Callable[[int, int], None]]:
    """A context giving `advance(done, total)`; draws on stderr only when it is a terminal."""
    if not sys.stderr.isatty():
        yield lambda done, total: None
        return
    from rich.progress import Progress

    with Progress(transient=True) as progress:
        task = progress.add_task(label, total=total)

        def advance(done: int, total: int) -> None:
            progress.update(task, completed=done, total=total)

        yield advance


__all__ = ["out_dir", "progress_bar", "write_json", "wrote"]
