"""Where the command line puts results: the output directory, the JSON writer, progress."""

from __future__ import annotations

import sys
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
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


#: Off a terminal, a progress line at every this share of the work...
PROGRESS_STEP = 0.1
#: ...and at least this often, in seconds, while the work goes on (a log shows it is alive).
PROGRESS_EVERY_S = 60.0


@contextmanager
def progress_bar(label: str, total: int) -> Iterator[Callable[[int, int], None]]:
    """A context giving `advance(done, total)`: a bar on stderr when it is a terminal, else a
    plain `LABEL: 40% (40/100)` line on stderr at the start, every 10% of the work and
    every minute."""
    if not sys.stderr.isatty():
        # The 0% line: the work has begun (a log shows what it is and how long it is).
        typer.echo(f"{label}: 0% (0/{total})", err=True)
        yield _progress_lines(label)
        return
    from rich.progress import Progress

    with Progress(transient=True) as progress:
        task = progress.add_task(label, total=total)

        def advance(done: int, total: int) -> None:
            progress.update(task, completed=done, total=total)

        yield advance


def _progress_lines(label: str) -> Callable[[int, int], None]:
    """`advance(done, total)` that prints a line when the work crosses a 10% step, or when
    the last line is a minute old (a log, a CI job: no bar, but a sign of life)."""
    last_step = 0
    last_time = time.monotonic()

    def advance(done: int, total: int) -> None:
        nonlocal last_step, last_time
        if total <= 0:
            return
        step = min(int(done / total / PROGRESS_STEP + 1e-9), round(1 / PROGRESS_STEP))
        now = time.monotonic()
        if step > last_step or now - last_time >= PROGRESS_EVERY_S:
            last_step, last_time = max(step, last_step), now
            typer.echo(f"{label}: {100 * done // total}% ({done}/{total})", err=True)

    return advance


def count_states(states: Iterable[str | None]) -> str:
    """Final states counted, most common first: `DEPLOY 990, IDLE 10` (`none`: no state)."""
    counts = Counter("none" if s is None else s for s in states)
    return ", ".join(
        f"{name} {n}" for name, n in sorted(counts.items(), key=lambda x: (-x[1], x[0]))
    )


__all__ = ["count_states", "out_dir", "progress_bar", "write_json", "wrote"]
