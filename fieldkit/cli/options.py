"""Options several commands share: `--command`, `--set NAME=VALUE`, `--home LAT,LON` and
`--update T:NEW.bzz[:ROBOT]`.

Each is declared once (`CommandOption`, `SetOption`, `HomeOption`) and parsed once. A value
that does not parse is a command-line error (exit 2, `error:` first), the same on `sim run`,
`sitl`, `node` and `vehicle-sim`.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from fieldkit.cli.errors import fail, usage_error
from fieldkit.robot.geo import DEFAULT_HOME

if TYPE_CHECKING:
    from fieldkit.robot.rc import RcCommand
    from fieldkit.update.keys import RobotKeys

#: `--command T:ROBOT:CODE[:P...]` (repeatable).
CommandOption = Annotated[
    list[str] | None,
    typer.Option(
        "--command",
        metavar="T:ROBOT:CODE[:P...]",
        help="Hand robot ROBOT a remote-control code at second T (repeatable): 22 takeoff, "
        "21 land, 20 home, 900 task allocation (P: the root robot's id, optional), 901 "
        "coverage, 16 waypoint (P: ID:LAT:LON:ALT).",
    ),
]

#: `--set NAME=VALUE` (repeatable).
SetOption = Annotated[
    list[str] | None,
    typer.Option(
        "--set",
        metavar="NAME=VALUE",
        help="Set script global NAME before init() (repeatable; VALUE an int, else a float, "
        "else a string), e.g. --set SHAPE=Y.",
    ),
]

#: `--home LAT,LON`.
HomeOption = Annotated[
    str | None,
    typer.Option(
        "--home",
        metavar="LAT,LON",
        help="Where the robots start, in degrees "
        f"(default {DEFAULT_HOME[0]},{DEFAULT_HOME[1]}, Montreal).",
        show_default=False,
    ),
]

#: `--update T:NEW.bzz[:ROBOT]` (repeatable).
UpdateOption = Annotated[
    list[str] | None,
    typer.Option(
        "--update",
        metavar="T:NEW.bzz[:ROBOT]",
        help="At second T, hand robot ROBOT (default 1) a signed over-the-air update to "
        "NEW.bzz, compiled and tested first; it spreads over the radio (repeatable).",
    ),
]


#: `--security signed|none`.
SecurityOption = Annotated[
    str | None,
    typer.Option(
        "--security",
        metavar="signed|none",
        help="signed: every radio bundle carries a tag under the swarm key and a counter "
        "(needs --keys); none: ROSBuzz's plain bytes, with a warning. Default: the "
        "profile's [radio] security, else signed with --keys and none without.",
        show_default=False,
    ),
]

#: `--keys DIR` where it serves the radio (and updates): the robot's keys.
KeysOption = Annotated[
    Path | None,
    typer.Option(
        "--keys",
        metavar="DIR",
        help="The robot's keys (from `fieldkit keys init`: operator.pub, swarm.key): bundles "
        "are signed with them, updates and operator commands checked.",
    ),
]

#: Printed when a run's radio is not authenticated.
INSECURE = (
    "warning: security none: radio bundles are not authenticated: anyone in radio range "
    "can inject, replay or forge them (give --keys DIR to sign; docs/security.md)"
)


def security_mode(given: str | None, has_keys: bool, profile_setting: str | None = None) -> str:
    """The radio's security mode: `--security`, else the profile's, else signed with keys
    and none without; signed without keys is exit 1 (`warn_if_insecure` says none)."""
    from fieldkit.robot.link_security import MODES, NONE, SIGNED

    if given is not None and given not in MODES:
        raise usage_error(f"--security must be signed or none, got {given!r}")
    mode = given or profile_setting or (SIGNED if has_keys else NONE)
    if mode == SIGNED and not has_keys:
        source = "--security signed" if given else 'the profile\'s [radio] security = "signed"'
        raise fail(
            f"{source} authenticates bundles with the swarm key: give --keys DIR "
            f"(made by `fieldkit keys init DIR`), or --security none"
        )
    return mode


def warn_if_insecure(mode: str) -> None:
    """Say on stderr that a run's radio is not authenticated (once its command line and
    configuration have checked out, so that an `error:` comes first)."""
    if mode == "none":
        typer.echo(INSECURE, err=True)


def load_keys(directory: Path) -> RobotKeys:
    """The robot's keys (`--keys`): the operator's public key and the swarm key, or exit 1
    saying which file is wrong and how to mend it (missing, another kind, readable by others)."""
    from fieldkit.errors import FieldkitError
    from fieldkit.update.keys import load_robot_keys

    try:
        return load_robot_keys(directory)
    except FieldkitError as e:  # KeyFileError: names the file, the problem, a hint
        raise fail(e) from None


@dataclass(frozen=True)
class UpdateAt:
    """One `--update`: when, which script, at which robot."""

    t: float
    script: Path
    robot: int


def parse_updates(texts: list[str] | None) -> list[UpdateAt]:
    """`--update T:NEW.bzz[:ROBOT]` options (a form that does not parse: exit 2)."""
    out = []
    for text in texts or []:
        t_text, sep, rest = text.partition(":")
        script, robot_text = rest, "1"
        head, colon, tail = rest.rpartition(":")
        if colon and tail.strip().isdigit():
            script, robot_text = head, tail
        try:
            if not sep or not script:
                raise ValueError
            t = float(t_text)
            robot = int(robot_text)
        except ValueError:
            raise usage_error(
                f"--update {text!r}: expected T:NEW.bzz[:ROBOT], e.g. 20:buzz_scripts/v2.bzz:3"
            ) from None
        if not math.isfinite(t) or t < 0:
            raise usage_error(f"--update {text!r}: T must be a time >= 0 in seconds")
        out.append(UpdateAt(t, Path(script), robot))
    return out


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


def parse_commands(texts: list[str] | None) -> list[RcCommand]:
    """`--command` options as remote-control commands (a form that does not parse: exit 2)."""
    from fieldkit.errors import ConfigError
    from fieldkit.robot.rc import RcCommand

    try:
        return [RcCommand.parse(text) for text in texts or []]
    except ConfigError as e:
        raise usage_error(str(e)) from None


def parse_home(text: str | None) -> tuple[float, float]:
    """`--home LAT,LON` in degrees (None: the default home): not two numbers is exit 2, not a
    place on Earth exit 1."""
    if text is None:
        return DEFAULT_HOME
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


__all__ = [
    "CommandOption",
    "HomeOption",
    "INSECURE",
    "KeysOption",
    "load_keys",
    "SecurityOption",
    "security_mode",
    "warn_if_insecure",
    "SetOption",
    "SetValue",
    "UpdateAt",
    "UpdateOption",
    "parse_commands",
    "parse_home",
    "parse_sets",
    "parse_updates",
    "set_value",
]
