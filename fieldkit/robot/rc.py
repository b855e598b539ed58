"""Remote-control commands: the codes an operator hands a robot (ROSBuzz's `flight.rc_cmd`).

One `RcCommand` is one code for one robot at a time after start: 22 take off, 21 land,
20 go home, 900 task allocation, 901 coverage, 16 a waypoint (its four parameters: waypoint
id, latitude, longitude, altitude). The simulator, the field node and SITL all take them in
the same `T:ROBOT:CODE[:P1:P2...]` text (the node, a robot of its own, `T:CODE[:P...]`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from fieldkit.errors import ConfigError

#: The waypoint code: it carries (waypoint id, lat, lon, alt).
RC_WAYPOINT: Final = 16

#: The script's `rc_goto` table: (waypoint id, lat, lon, alt).
RcGoto = tuple[int, float, float, float]


@dataclass(frozen=True)
class RcCommand:
    """A remote-control code handed to one robot at a time after start (seconds)."""

    t: float
    robot: int
    code: int
    params: tuple[float, ...] = ()  # code 16: (waypoint id, lat, lon, alt)

    @classmethod
    def parse(cls, text: str, robot: int | None = None) -> RcCommand:
        """Parse `T:ROBOT:CODE[:P...]`, or `T:CODE[:P...]` for the given `robot`."""
        form = (
            "T:CODE[:PARAMS...], e.g. 5:22"
            if robot is not None
            else ("T:ROBOT:CODE[:PARAMS...], e.g. 5:1:22 (robot 1 takes off at 5 s)")
        )
        parts = text.split(":")
        head = 2 if robot is not None else 3
        try:
            if len(parts) < head:
                raise ValueError
            t = float(parts[0])
            rid = robot if robot is not None else int(parts[1])
            code = int(parts[head - 1])
            params = tuple(float(p) for p in parts[head:])
        except ValueError:
            raise ConfigError(f"--command {text!r}: expected {form}") from None
        if t < 0 or not math.isfinite(t):
            raise ConfigError(f"--command {text!r}: time must be >= 0 seconds")
        if code == RC_WAYPOINT and len(params) != 4:
            raise ConfigError(f"--command {text!r}: code 16 needs 4 params ID:LAT:LON:ALT")
        return cls(t, rid, code, params)

    def text(self, with_robot: bool = True) -> str:
        """The command as `parse` reads it back (SITL hands it to a node this way)."""
        head = f"{self.t!r}:{self.robot}:{self.code}" if with_robot else f"{self.t!r}:{self.code}"
        return ":".join([head, *(repr(p) for p in self.params)])

    @property
    def goto(self) -> RcGoto | None:
        """The waypoint (id, lat, lon, alt) of a code-16 command, else None."""
        if self.code != RC_WAYPOINT or len(self.params) != 4:
            return None
        wid, lat, lon, alt = self.params
        return int(wid), lat, lon, alt


__all__ = ["RC_WAYPOINT", "RcCommand", "RcGoto"]
