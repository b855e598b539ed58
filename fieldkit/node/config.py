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

    [dji]                        # an M100 (flavour dji): the developer's app, never logged
    app_id = 1012345
    app_key_file = "/etc/fieldkit/dji-app-key"   # 64 hex digits; or app_key = "..."

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
class DjiApp:
    """The `[dji]` table: the developer's app id and app key the M100 is activated with."""

    app_id: int
    app_key: str = field(repr=False)  # a secret: never in a repr, a log or an error


@dataclass(frozen=True)
class NodeConfig:
    """A checked config file: `node` holds the `[node]` options given (others are absent)."""

    path: Path
    node: Mapping[str, Any] = field(default_factory=dict)
    record: RecordSettings | None = None
    dji: DjiApp | None = None


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


def _app_id(v: Any) -> str | None:
    return _integer(v) or (None if 0 < v <= 0xFFFFFFFF else "must be 1..4294967295")


def _app_key(v: Any) -> str | None:
    from fieldkit.vehicle.dji.crypto import AppKeyError, parse_app_key

    if not isinstance(v, str):
        return "must be a string of 64 hex digits"
    try:
        parse_app_key(v)
    except AppKeyError as e:
        return str(e)
    return None


DJI_KEYS: dict[str, Check] = {"app_id": _app_id, "app_key": _app_key, "app_key_file": _string}
"""The `[dji]` keys: the app key itself, or a file that holds it (kept 0600)."""

SECRET_KEYS = frozenset({("dji", "app_key")})
"""Values an error message must never repeat."""

TABLES = {"node": NODE_KEYS, "record": RECORD_KEYS, "dji": DJI_KEYS}


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
                got = "" if (table, key) in SECRET_KEYS else f", got {_describe(v)}"
                problems.append(f"{source}: {table}.{key}: {wrong}{got}")
                continue
            if (
                table == "node"
                and key in PATH_KEYS
                or (table, key) in (("record", "dir"), ("dji", "app_key_file"))
            ):
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
    dji = _dji_app(source, checked["dji"], problems)
    if problems:
        raise NodeConfigError(problems)
    record = None
    if rec:
        record = RecordSettings(
            dir=Path(rec["dir"]), max_mb=rec.get("max_mb", 2048.0), keep_mb=rec.get("keep_mb")
        )
    return NodeConfig(path=base, node=node, record=record, dji=dji)


def _dji_app(source: str, t: dict[str, Any], problems: list[str]) -> DjiApp | None:
    """The `[dji]` table's app, its key read from `app_key_file` if given there."""
    if not t:
        return None
    if "app_id" not in t:
        problems.append(f"{source}: dji.app_id: missing (the app id from DJI's developer site)")
    if ("app_key" in t) == ("app_key_file" in t):
        problems.append(f"{source}: dji: give one of app_key and app_key_file")
        return None
    key = t.get("app_key")
    if "app_key_file" in t:
        where = Path(t["app_key_file"])
        try:
            mode = where.stat().st_mode
            key = where.read_text(encoding="ascii").strip()
        except (OSError, UnicodeDecodeError) as e:
            reason = e.strerror if isinstance(e, OSError) and e.strerror else "not hex text"
            problems.append(f"{source}: dji.app_key_file: {where}: {reason}")
            return None
        if mode & 0o077:
            problems.append(
                f"{source}: dji.app_key_file: {where} is readable by others "
                f"(mode {mode & 0o777:o}): chmod 600 {where}"
            )
        wrong = _app_key(key)
        if wrong is not None:
            problems.append(f"{source}: dji.app_key_file: {where}: {wrong}")
            return None
    if "app_id" not in t or key is None:
        return None
    return DjiApp(app_id=t["app_id"], app_key=key)


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
    return NodeConfig(path=path, node=config.node, record=config.record, dji=config.dji)


__all__ = [
    "DJI_KEYS",
    "DjiApp",
    "NODE_KEYS",
    "NodeConfig",
    "NodeConfigError",
    "RecordSettings",
    "load_config",
    "parse_config",
]
