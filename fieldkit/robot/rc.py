"""Remote-control commands: the codes an operator hands a robot (ROSBuzz's `flight.rc_cmd`).

One `RcCommand` is one code for one robot at a time after start: 22 take off, 21 land,
20 go home, 900 task allocation, 901 coverage, 16 a waypoint (its four parameters: waypoint
id, latitude, longitude, altitude). Any other code may carry params too; a script sees the
first as `flight.rc_param` (for 900, the robot to root the shape at). The simulator, the
field node and SITL all take them in the one `T:ROBOT:CODE[:P1:P2...]` text, so `5:1:22`
means the same everywhere (a node takes only the commands for its own robot id). The
node's old two-field `T:CODE` is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from bvm.values import f32
from fieldkit.errors import ConfigError

#: The waypoint code: it carries (waypoint id, lat, lon, alt).
RC_WAYPOINT: Final = 16

#: How `--command` is written, for help texts and error messages.
COMMAND_FORM: Final = "T:ROBOT:CODE[:P...], e.g. 5:1:22 (robot 1 takes off at 5 s)"

#: The script's `rc_goto` table: (waypoint id, lat, lon, alt).
RcGoto = tuple[int, float, float, float]


#: Task allocation: its one optional param is the robot to root the shape at.
RC_TASK_ALLOCATE: Final = 900

#: The largest magnitude a param keeps as a script's binary32 float.
F32_MAX: Final = 3.4028234663852886e38


def param_problem(code: int, params: tuple[float, ...]) -> str | None:
    """What is wrong with `params` for `code` (None: nothing): every param must stay a
    finite number as a script's float, and 900's root must be a robot id."""
    if not all(math.isfinite(p) and abs(p) <= F32_MAX for p in params):
        return "every param must be a finite number within a float's range (3.4e38)"
    if code == RC_TASK_ALLOCATE and params:
        root = params[0]
        if not (root.is_integer() and 0 <= root <= 0xFFFF):
            return f"900's param is the root robot's id (0..65535), got {root:g}"
    return None


@dataclass(frozen=True)
class RcCommand:
    """A remote-control code handed to one robot at a time after start (seconds)."""

    t: float
    robot: int
    code: int
    params: tuple[float, ...] = ()  # code 16: (waypoint id, lat, lon, alt); 900: (root id,)

    @classmethod
    def parse(cls, text: str) -> RcCommand:
        """Parse `T:ROBOT:CODE[:P...]` (ConfigError, naming the form, if it does not parse)."""
        parts = text.split(":")
        try:
            if len(parts) < 3:
                raise ValueError
            t = float(parts[0])
            robot = int(parts[1])
            code = int(parts[2])
            params = tuple(float(p) for p in parts[3:])
        except ValueError:
            # The node took `T:CODE` until issue 13: say so to whoever still types it.
            gone = "; the two-field T:CODE form is gone" if len(parts) == 2 else ""
            raise ConfigError(f"--command {text!r}: expected {COMMAND_FORM}{gone}") from None
        if t < 0 or not math.isfinite(t):
            raise ConfigError(f"--command {text!r}: time must be >= 0 seconds")
        problem = param_problem(code, params)
        if problem is not None:
            raise ConfigError(f"--command {text!r}: {problem}")
        if code == RC_WAYPOINT and len(params) != 4:
            raise ConfigError(f"--command {text!r}: code 16 needs 4 params ID:LAT:LON:ALT")
        return cls(t, robot, code, params)

    def text(self) -> str:
        """The command as `parse` reads it back (SITL hands it to a node this way)."""
        return ":".join([f"{self.t!r}:{self.robot}:{self.code}", *(repr(p) for p in self.params)])

    @property
    def param(self) -> int | float | None:
        """The first param of a code other than 16, as the script's `flight.rc_param` gets
        it: an integer if it is one (task allocation's 900 takes a root id), else a binary32
        float; None without params."""
        if self.code == RC_WAYPOINT or not self.params:
            return None
        p = self.params[0]
        if p.is_integer() and abs(p) < 2**31:
            return int(p)
        return f32(p)

    @property
    def goto(self) -> RcGoto | None:
        """The waypoint (id, lat, lon, alt) of a code-16 command, else None."""
        if self.code != RC_WAYPOINT or len(self.params) != 4:
            return None
        wid, lat, lon, alt = self.params
        return int(wid), lat, lon, alt


__all__ = [
    "COMMAND_FORM",
    "F32_MAX",
    "RC_TASK_ALLOCATE",
    "RC_WAYPOINT",
    "RcCommand",
    "RcGoto",
    "param_problem",
]
