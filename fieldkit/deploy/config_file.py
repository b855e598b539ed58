"""/etc/fieldkit/fieldkit.toml: the one file the service reads (`fieldkit node --config`).

A `[node]` table of `fieldkit node`'s options (underscores for dashes), a `[record]` table
for the recording and, for an M100, a `[dji]` table naming its app (the key in a file of
its own, never in this one, which anyone may read). Written by a small TOML writer:
strings, integers, floats, booleans and lists of strings are all a config needs, and
writing them is a few lines (Python reads TOML, `tomllib`, but does not write it). Each
value may carry a comment, so the file says where its values came from.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from fieldkit.deploy import layout

TomlValue = str | int | float | bool | list[str]
"""What the writer writes."""

HEADER = (
    "# written by fieldkit deploy; `fieldkit node --config` reads it; the command line overrides it"
)

#: `[record] max_mb`: the node's cap on one recording (`--record-max-mb`'s default).
RECORD_MAX_MB = 2048
#: `[record] keep_mb`: what /var/log/fieldkit may hold in recordings altogether.
RECORD_KEEP_MB = 8192


def toml_string(text: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters escaped."""
    out = []
    for ch in text:
        if ch == '"':
            out.append('\\"')
        elif ch == "\\":
            out.append("\\\\")
        elif ch in "\b\t\n\f\r":
            out.append({"\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}[ch])
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def toml_value(value: TomlValue) -> str:
    """One value as TOML writes it (a float always with its point: 2.0, not 2)."""
    if isinstance(value, bool):  # before int: a bool is an int
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"not a finite number: {value}")
        text = repr(value)
        return text if any(c in text for c in ".eE") else f"{text}.0"
    if isinstance(value, str):
        return toml_string(value)
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return "[" + ", ".join(toml_string(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} {value!r} as a config value")


@dataclass(frozen=True)
class Key:
    """One `key = value  # comment` line."""

    name: str
    value: TomlValue
    comment: str = ""


def render_toml(header: str, tables: Sequence[tuple[str, Sequence[Key]]]) -> str:
    """A TOML document: a comment header, then each table with its keys."""
    lines = [header]
    for name, keys in tables:
        lines.append(f"[{name}]")
        for key in keys:
            if any(ord(c) < 0x20 and c != "\t" or ord(c) == 0x7F for c in key.comment):
                raise ValueError(f"{key.name}: a comment holds a control character")
            line = f"{key.name} = {toml_value(key.value)}"
            lines.append(f"{line}  # {key.comment}" if key.comment else line)
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class NodeConfig:
    """What deploy knows of the node: every field None is left to the profile or the node."""

    profile: str  # a shipped profile's name, or the installed profile's path
    robot_id: int | None = None
    autopilot: str | None = None
    radio: str | None = None
    script: str | None = None  # the installed script (seeds an empty state directory)
    keys: bool = False  # the robot's keys are installed: signed bundles
    include: bool = False  # the script has includes
    originator: bool = False  # the update monitor writes patches into the outbox
    gps: str | None = None  # a Clearpath base's GPS receiver
    dji_app_id: int | None = None  # an M100's app: its key is installed as layout.DJI_APP_KEY


def node_config(config: NodeConfig) -> str:
    """The text of fieldkit.toml."""
    node = [Key("profile", config.profile)]
    if config.robot_id is not None:
        node.append(Key("robot_id", config.robot_id))
    if config.autopilot is not None:
        node.append(Key("autopilot", config.autopilot))
    if config.radio is not None:
        node.append(Key("radio", config.radio))
    if config.gps is not None:
        node.append(Key("gps", config.gps))
    node.append(Key("state_dir", str(layout.NODE_STATE_DIR), "script versions, counters"))
    if config.script is not None:
        node.append(Key("script", config.script, "seeds an empty state_dir (version 0)"))
    if config.keys:
        node.append(Key("keys", str(layout.KEYS_DIR)))
        node.append(Key("security", "signed"))
    if config.include:
        node.append(Key("include", [str(layout.INCLUDE_DIR)]))
    if config.originator:
        node.append(Key("update_outbox", str(layout.OUTBOX_PATCH), "fieldkit-update's patches"))
    record = [
        Key("dir", str(layout.LOG_DIR)),
        Key("max_mb", RECORD_MAX_MB, "one recording's cap"),
        Key("keep_mb", RECORD_KEEP_MB, "all recordings together"),
    ]
    tables: list[tuple[str, Sequence[Key]]] = [("node", node), ("record", record)]
    if config.dji_app_id is not None:
        dji = [
            Key("app_id", config.dji_app_id),
            Key("app_key_file", str(layout.DJI_APP_KEY), "64 hex digits, 0600, fieldkit's"),
        ]
        tables.append(("dji", dji))
    return render_toml(HEADER, tables)


__all__ = [
    "HEADER",
    "Key",
    "NodeConfig",
    "RECORD_KEEP_MB",
    "RECORD_MAX_MB",
    "TomlValue",
    "node_config",
    "render_toml",
    "toml_string",
    "toml_value",
]
