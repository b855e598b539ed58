"""The campaign loop, command line and report shared by the seeded fuzz harnesses (`*_fuzz.py`).

A harness makes input k of seed S from `random.Random(f"{S}:{k}")` and checks it; this module
runs inputs k = start, start+1, ... until a time or count budget is spent, counts failures
under their replay id `S:k`, and prints the report whose last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import argparse
import collections
import math
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from typing import Any, TypeVar

#: Inputs between two progress lines of a long campaign, and the least seconds between them.
PROGRESS_INPUTS = 4096
PROGRESS_SECONDS = 30.0
#: Replay ids listed in the report at the most.
LISTED_FAILURES = 50


@dataclass
class Stats:
    """What a campaign did: the counts every harness keeps (harnesses subclass it for more)."""

    inputs: int = 0
    failures: int = 0
    kinds: collections.Counter[str] = field(default_factory=collections.Counter)
    failed: list[str] = field(default_factory=list)

    def fail(
        self, replay_id: str, text: str, out: Callable[[str], None], *, shown: int | None = None
    ) -> None:
        """Count a failure of input `replay_id`; print `text` unless `shown` have been already."""
        self.failures += 1
        self.failed.append(replay_id)
        if shown is None or self.failures <= shown:
            out(text)

    def details(self) -> list[str]:
        """The report's lines between the rate and the failures: the kinds of input run."""
        return [f"kinds: {dict(sorted(self.kinds.items()))}"]

    def merge(self, other: Stats) -> None:
        """Add another slice's counts to these, field by field (a subclass's counts too):
        numbers add up, lists extend, dicts of counts add up key by key."""
        for f in fields(self):
            mine, theirs = getattr(self, f.name), getattr(other, f.name)
            if isinstance(mine, list):
                mine.extend(theirs)
            elif isinstance(mine, dict):
                for key, n in theirs.items():
                    mine[key] = mine.get(key, 0) + n
            else:
                setattr(self, f.name, mine + theirs)


S = TypeVar("S", bound=Stats)


def campaign(
    run_one: Callable[[int], None],
    stats: S,
    *,
    seconds: float | None = None,
    max_inputs: int | None = None,
    start: int = 0,
    clock_every: int = 1,
    progress: Callable[[str], None] | None = None,
) -> S:
    """Call `run_one(k)` for k = start, start+1, ... until `max_inputs` ran or `seconds` passed.

    `run_one` records its outcome in `stats`; the loop counts `stats.inputs`. The clock is read
    every `clock_every` inputs, so that a harness whose inputs take microseconds spends its time
    on them. With `progress`, a timed campaign tells how far it is now and then.
    """
    end = math.inf if seconds is None else time.monotonic() + seconds
    last = time.monotonic()
    k = start
    while max_inputs is None or stats.inputs < max_inputs:
        if stats.inputs % clock_every == 0 and time.monotonic() >= end:
            break
        run_one(k)
        stats.inputs += 1
        k += 1
        if (
            progress is not None
            and end < math.inf
            and stats.inputs % PROGRESS_INPUTS == 0
            and time.monotonic() - last > PROGRESS_SECONDS
        ):
            last = time.monotonic()
            progress(f"  ... inputs {stats.inputs}, failures {stats.failures}")
    return stats


@dataclass
class EventStats(Stats):
    """The counts of a harness whose inputs are sequences of events `(kind, data, ...)`."""

    events: int = 0


E = TypeVar("E", bound=EventStats)


def run_events(
    seed: str,
    k: int,
    stats: E,
    out: Callable[[str], None],
    build_and_check: Callable[[str, int, E], tuple[Sequence[tuple[Any, ...]], str | None]],
) -> None:
    """Make input k of `seed` and check it (`build_and_check` returns its events and the
    failure, or None), counting its events and their kinds; a harness that raises fails the
    input, with its traceback."""
    try:
        events, failure = build_and_check(seed, k, stats)
        kinds = {event[0] for event in events}
    except Exception:
        failure, kinds = "harness raised:\n" + traceback.format_exc(), {"harness"}
        events = []
    stats.events += len(events)
    for kind in kinds:
        stats.kinds[kind] += 1
    if failure is not None:
        stats.fail(f"{seed}:{k}", f"FAIL {seed}:{k}: {failure}", out, shown=20)


def make_run(
    check: Callable[[str, int, S, Callable[[str], None]], None],
    new_stats: Callable[[], S],
    *,
    clock_every: int = 1,
    progress: bool = False,
) -> Callable[..., S]:
    """A harness's `run(seed, *, seconds, max_inputs, start, out)`: `check(seed, k, stats, out)`
    for each input k of a campaign (see `campaign` for `clock_every` and `progress`)."""

    def run(
        seed: str,
        *,
        seconds: float | None = None,
        max_inputs: int | None = None,
        start: int = 0,
        out: Callable[[str], None] = print,
    ) -> S:
        """Check inputs start, start+1, ... of `seed` until the time or the count runs out."""
        stats = new_stats()
        return campaign(
            lambda k: check(seed, k, stats, out),
            stats,
            seconds=seconds,
            max_inputs=max_inputs,
            start=start,
            clock_every=clock_every,
            progress=out if progress else None,
        )

    return run


def parse_args(
    argv: list[str] | None,
    doc: str | None,
    *,
    slices: bool = True,
    replay_help: str = "SEED:K -- run one input verbosely",
) -> argparse.Namespace:
    """The harness options: --seconds, --seed, --replay, and with `slices` --max-inputs, --start."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--seed", default="0")
    if slices:
        ap.add_argument("--max-inputs", type=int, help="stop after this many inputs")
        ap.add_argument("--start", type=int, default=0, help="first input index")
    ap.add_argument("--replay", help=replay_help)
    return ap.parse_args(argv)


def summary(stats: Stats, *, list_failed: bool = True) -> int:
    """Print the failed replay ids and the last line; the exit status (1 if anything failed)."""
    if list_failed and stats.failed:
        print("failed:", " ".join(stats.failed[:LISTED_FAILURES]))
    print(f"inputs: {stats.inputs}, failures: {stats.failures}")
    return 1 if stats.failures else 0


def main(
    argv: list[str] | None,
    doc: str | None,
    run: Callable[..., Stats],
    replay: Callable[[str], int],
) -> int:
    """A harness's command line: replay one input, or run a campaign and print its report."""
    args = parse_args(argv, doc)
    if args.replay:
        return replay(args.replay)
    t0 = time.monotonic()
    stats = run(args.seed, seconds=args.seconds, max_inputs=args.max_inputs, start=args.start)
    spent = time.monotonic() - t0
    print(f"seed {args.seed}, {spent:.0f} s, {stats.inputs / max(spent, 1e-9):.0f} inputs/s")
    for line in stats.details():
        print(line)
    return summary(stats)


def counted_main(
    argv: list[str] | None,
    doc: str | None,
    run: Callable[..., Any],
    replay: Callable[[str], int],
    new_stats: Callable[[], Any],
    *,
    slice_inputs: int,
) -> int:
    """A harness's command line for million-input runs: `--count N` runs exactly N inputs
    with no time limit, `--seconds S` (60 without `--count`) bounds the time. The campaign
    runs in slices of `slice_inputs`, each followed by a progress line with the rate; the
    stats of the slices add up through their `merge`."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--count", "--max-inputs", dest="count", type=int, help="inputs to run")
    ap.add_argument("--seconds", type=float, help="time budget (default 60 without --count)")
    ap.add_argument("--seed", default="0")
    ap.add_argument("--start", type=int, default=0, help="first input index")
    ap.add_argument("--replay", help="SEED:K -- run one input verbosely")
    args = ap.parse_args(argv)
    if args.replay:
        return replay(args.replay)
    seconds = args.seconds if args.seconds is not None or args.count else 60.0
    t0 = time.monotonic()
    end = None if seconds is None else t0 + seconds
    total = new_stats()
    k = args.start
    while args.count is None or total.inputs < args.count:
        left = None if end is None else end - time.monotonic()
        if left is not None and left <= 0:
            break
        n = slice_inputs if args.count is None else min(slice_inputs, args.count - total.inputs)
        part = run(args.seed, seconds=left, max_inputs=n, start=k)
        total.merge(part)
        k += part.inputs
        spent = time.monotonic() - t0
        print(
            f"  ... inputs {total.inputs}, failures {total.failures}, "
            f"{total.inputs / max(spent, 1e-9):.0f} inputs/s",
            flush=True,
        )
    spent = time.monotonic() - t0
    print(f"seed {args.seed}, {spent:.0f} s, {total.inputs / max(spent, 1e-9):.0f} inputs/s")
    for line in total.details():
        print(line)
    return summary(total)
