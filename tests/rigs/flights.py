"""A flight the vehicle backends' end-to-end tests share, and how they start fieldkit."""

from __future__ import annotations

import os
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


#: Take off on RC code 22, then 10 m north; log how far north of the climb it is, and how high
#: (metres per degree of latitude at 45.5 degrees: 111,140; Buzz's float32 latitude is good to
#: 0.4 m there). `BROKEN == 1`: fail on the way.
FLY_NORTH = """
function init() { BVMSTATE = "TURNEDOFF" }
function step() {
  if (flight.rc_cmd == 22 and BVMSTATE == "TURNEDOFF") BVMSTATE = "TAKEOFF"
  if (BVMSTATE == "TAKEOFF") {
    uav_takeoff(TARGET_ALTITUDE)
    if (pose.position.altitude > TARGET_ALTITUDE * 0.9) {
      BVMSTATE = "GO"
      LAT0 = pose.position.latitude
      goto_abs(10.0, 0.0, 0.0, 0.0)
    }
  }
  if (BVMSTATE == "GO") {
    north = (pose.position.latitude - LAT0) * 111140.0
    log("north ", north, " alt ", pose.position.altitude)
    if (BROKEN == 1 and north > 9.0) { var crash = 1 / 0 }
  }
}
"""
NORTH = re.compile(r"robot 1: north (-?[\d.]+) alt (-?[\d.]+)")


def field_env() -> dict[str, str]:
    """The environment a `python -m fieldkit` child runs in: this checkout first."""
    return dict(os.environ, PYTHONPATH=str(ROOT))
