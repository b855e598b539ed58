"""The node's config file: every `fieldkit node` option from one TOML file.

A deployed robot's service runs `fieldkit node --config /etc/fieldkit/fieldkit.toml`:

    [node]                       # the options of `fieldkit node`, underscores for dashes
    profile = "solo"
    robot_id = 3
    autopilot = "/dev/autopilot"
    radio = "serial:///dev/xbee?baud=230400&api=2"
    state_dir = "/var/lib/fieldkit/state"
    keys = "/etc/fieldkit/keys"
    security = "signed"
    set = ["SHAPE=Y"]
    update_outbox = "/var/lib/fieldkit/outbox/update.patch"   # an originator's

    [record]                     # a new bag per run, under one folder with a total cap
    dir = "/var/log/fieldkit"
    max_mb = 2048                # one flight's cap (as --record-max-mb)
    keep_mb = 8192               # the folder's cap: the oldest flights go first

The command line overrides the file, option by option (`--set` name by name). Relative paths
are relative to the file's folder. Every problem of a file is reported at once, one per line,
as `FILE: node.robot_id: must be an integer, got "3a"`, like a profile's; an unknown key is
an error with the nearest known one as a hint, because a misspelt `recod` silently ignored
is a flight not recorded.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fieldkit.errors import FieldkitError


class NodeConfigError(FieldkitError, ValueError):
    """A config file that cannot be used; one `file: key: problem` line per problem."""

    def __init__(self, problems: list[str]) -> None:
        """Wrap the problems found, in file order."""
        super().__init__("\n".join(problems))
        self.problems: tuple[str, ...] = tuple(problems)


@dataclass(frozen=True)
class RecordSettings:
    """The `[record]` table: where each run's bag goes and how much disk they may take."""

    dir: Path
    max_mb: float = 2048.0
    keep_mb: float | None = None


@dataclass(frozen=True)
class NodeConfig:
    """A checked config file: `node` holds the `[node]` options given (others are absent)."""

    path: Path
    node: Mapping[str, Any] = field(default_factory=dict)
    record: RecordSettings | None = None


# ----------------------------------------------------------------------------- schema

Check = Callable[[Any], str | None]
"""A value check: None if the value is good, else what is wrong with it."""


def _string(v: Any) -> str | None:
    return None if isinstance(v, str) and v else "must be a non-empty string"


def _integer(v: Any) -> str | None:
    return None if isinstance(v, int) and not isinstance(v, bool) else "must be an integer"


def _number(v: Any) -> str | None:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return "must be a number"
    return None if math.isfinite(v) else "must be a finite number"


def _strings(v: Any) -> str | None:
    ok = isinstance(v, list) and all(isinstance(s, str) and s for s in v)
    return None if ok else 'must be a list of strings, e.g. ["a", "b"]'


def _one_of(*allowed: str) -> Check:
    def check(v: Any) -> str | None:
        return None if v in allowed else f"must be one of {', '.join(map(repr, allowed))}"

    return check


def _positive(v: Any) -> str | None:
    return _number(v) or (None if v > 0 else "must be > 0")


NODE_KEYS: dict[str, Check] = {
    "profile": _string,
    "script": _string,
    "autopilot": _string,
    "gps": _string,
    "radio": _string,
    "robot_id": _integer,
    "seconds": _positive,
    "out": _string,
    "record": _string,
    "record_max_mb": _positive,
    "include": _strings,
    "command": _strings,
    "set": _strings,
    "connect_timeout": _positive,
    "seed": _integer,
    "state_dir": _string,
    "keys": _string,
    "security": _one_of("signed", "none"),
    "update_outbox": _string,
}
"""The `[node]` keys: `fieldkit node`'s options, named with underscores, and their checks."""

PATH_KEYS = frozenset({"script", "out", "record", "state_dir", "keys", "include", "update_outbox"})
"""Keys whose values are paths: resolved against the config file's folder."""

RECORD_KEYS: dict[str, Check] = {"dir": _string, "max_mb": _positive, "keep_mb": _positive}
"""The `[record]` keys."""

TABLES = {"node": NODE_KEYS, "record": RECORD_KEYS}


def _describe(v: Any) -> str:
    """A value as the message shows it: TOML-like, short."""
    text = f'"{v}"' if isinstance(v, str) else repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


def _unknown(source: str, where: str, key: str, known: list[str]) -> str:
    near = difflib.get_close_matches(key, known, n=1)
    hint = f" (did you mean {near[0]}?)" if near else f" (known: {', '.join(sorted(known))})"
    return f"{source}: {where}{key}: unknown key{hint}"


def parse_config(data: Mapping[str, Any], *, source: str, base: Path) -> NodeConfig:
    """Check a parsed file's tables; paths resolved against `base`. NodeConfigError lists
    every problem at once."""
    problems: list[str] = []
    for table, value in data.items():
        if table not in TABLES:
            problems.append(_unknown(source, "", table, list(TABLES)))
        elif not isinstance(value, dict):
            problems.append(f"{source}: {table}: must be a table ([{table}])")
    checked: dict[str, dict[str, Any]] = {}
    for table, schema in TABLES.items():
        values = data.get(table, {})
        good: dict[str, Any] = {}
        checked[table] = good
        if not isinstance(values, dict):
            continue
        for key, v in values.items():
            check = schema.get(key)
            if check is None:
                problems.append(_unknown(source, f"{table}.", key, list(schema)))
                continue
            wrong = check(v)
            if wrong is not None:
                problems.append(f"{source}: {table}.{key}: {wrong}, got {_describe(v)}")
                continue
            if table == "node" and key in PATH_KEYS or (table, key) == ("record", "dir"):
                v = [str(base / p) for p in v] if isinstance(v, list) else str(base / v)
            elif isinstance(v, int) and check is _positive:
                v = float(v)
            good[key] = v
    node = checked["node"]
    if "record" in node and "dir" in checked["record"]:
        problems.append(
            f"{source}: node.record: give one of node.record (one bag) and record.dir "
            "(a new bag per run)"
        )
    rec = checked["record"]
    if rec and "dir" not in rec:
        problems.append(f'{source}: record.dir: missing (e.g. dir = "/var/log/fieldkit")')
    if problems:
        raise NodeConfigError(problems)
    record = None
    if rec:
        record = RecordSettings(
            dir=Path(rec["dir"]), max_mb=rec.get("max_mb", 2048.0), keep_mb=rec.get("keep_mb")
        )
    return NodeConfig(path=base, node=node, record=record)


def load_config(path: Path) -> NodeConfig:
    """Read and check a config file; NodeConfigError says what is wrong and where."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise NodeConfigError([f"{path}: cannot read: {e.strerror or e}"]) from None
    except UnicodeDecodeError as e:
        raise NodeConfigError([f"{path}: not UTF-8 text: {e.reason} at byte {e.start}"]) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise NodeConfigError([f"{path}: invalid TOML: {e}"]) from None
    config = parse_config(data, source=str(path), base=path.parent)
    return NodeConfig(path=path, node=config.node, record=config.record)


__all__ = [
    "NODE_KEYS",
    "NodeConfig",
    "NodeConfigError",
    "RecordSettings",
    "load_config",
    "parse_config",
]
