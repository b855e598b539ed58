"""Argument types the benches share: a bad value is argparse's usage error (exit 2), not a
traceback from deep inside a run."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def sizes(text: str) -> list[int]:
    """A comma-separated list of robot counts, each at least 1: sorted, without repeats."""
    try:
        counts = sorted({int(s) for s in text.split(",")})
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"a comma-separated list of robot counts, got {text!r}"
        ) from None
    if counts[0] < 1:
        raise argparse.ArgumentTypeError(f"robot counts must be at least 1, got {counts[0]}")
    return counts


def at_least(low: int) -> Callable[[str], int]:
    """An integer of at least `low`."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"an integer, got {text!r}") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be at least {low}, got {value}")
        return value

    return parse


def _number(text: str, what: str) -> float:
    """`text` as a float, or argparse's error naming `what` was expected."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what}, got {text!r}") from None


def seconds(text: str) -> float:
    """A finite, positive number of (simulated) seconds."""
    value = _number(text, "a number of seconds")
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive number of seconds, got {text}")
    return value


def probability(text: str) -> float:
    """A drop rate in [0, 1]."""
    value = _number(text, "a probability")
    if not 0.0 <= value <= 1.0:  # NaN fails both
        raise argparse.ArgumentTypeError(f"must be in [0, 1], got {text}")
    return value
