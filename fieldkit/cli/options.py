"""Option values several commands share: `--set NAME=VALUE` and `--home LAT,LON`.

A value that does not parse is a command-line error (exit 2, `error:` first), the same on
`sim run`, `sitl` and `node`.
"""

from __future__ import annotations

import math
import re

from fieldkit.cli.errors import fail, usage_error

#: A Buzz identifier: what `--set` may name.
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")

#: A script global's value as `--set` gives it.
SetValue = int | float | str


def set_value(text: str) -> SetValue:
    """VALUE of `--set NAME=VALUE`: an int if it parses as one, else a float, else a string."""
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = float(text)
    except ValueError:
        return text
    # "nan"/"inf" parse as floats, but a script never wants them: keep the text.
    return value if math.isfinite(value) else text


def parse_sets(texts: list[str] | None) -> dict[str, SetValue]:
    """`--set NAME=VALUE` options (repeatable, the last one wins) as script globals."""
    out: dict[str, SetValue] = {}
    for text in texts or []:
        name, eq, value = text.partition("=")
        name = name.strip()
        if not eq or not _NAME.match(name):
            raise usage_error(
                f"--set {text!r}: expected NAME=VALUE with NAME a Buzz identifier, e.g. SHAPE=Y"
            )
        out[name] = set_value(value)
    return out


def parse_home(text: str) -> tuple[float, float]:
    """`--home LAT,LON` in degrees: not two numbers is exit 2, not a place on Earth exit 1."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        lat, lon = float(parts[0]), float(parts[1])
    except ValueError:
        raise usage_error(
            f"--home: expected LAT,LON in degrees such as 45.5017,-73.5673, got {text!r}"
        ) from None
    if not (math.isfinite(lat) and -90.0 < lat < 90.0):
        raise fail(f"--home: latitude must be between -90 and 90, got {parts[0].strip()}")
    if not (math.isfinite(lon) and -180.0 <= lon <= 180.0):
        raise fail(f"--home: longitude must be between -180 and 180, got {parts[1].strip()}")
    return lat, lon


__all__ = ["SetValue", "parse_home", "parse_sets", "set_value"]
