"""Coordinate maths between GPS (WGS84 degrees) and local metric frames; pure functions.

Two frames appear in fieldkit, always named explicitly:

- **NED offsets** `(north_m, east_m)`: what ROSBuzz computes for neighbours and goals
  (docs/rosbuzz.md#neighbor-table, docs/wire-format.md#neighbor-feed). Flat earth on a sphere of
  radius `EARTH_RADIUS_M`:
  north = rad(lat − lat0)·R, east = rad(lon − lon0)·R·cos(rad(lat)). Note that the cosine
  is taken at the *target* latitude, not the origin's: we keep that so that our neighbour
  ranges match a ROSBuzz robot's on the same radio, and `offset_gps` inverts it exactly.
- **Local ENU** `(x, y, z)`: x east, y north, z up, metres from a `LocalFrame` origin, the
  frame of the simulator and of the autopilots' local position.

Azimuths are radians from north, positive toward east (atan2(east, north)), as the Buzz
`neighbors` structure expects.

Two deliberate differences from ROSBuzz, both invisible away from the antimeridian and the
poles: a longitude difference is taken the short way round (ROSBuzz would put a robot 1 m
across the antimeridian 40 000 km away), and results are kept in double precision (ROSBuzz
stores them into C floats; Buzz rounds them to binary32 anyway when they enter the VM).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

EARTH_RADIUS_M = 6371000.0
"""Sphere radius used by ROSBuzz for every GPS <-> metres conversion."""

DEFAULT_HOME = (45.5017, -73.5673)
"""Where simulated robots start when no `--home LAT,LON` is given (Montreal, WGS84 degrees):
the simulator's origin, the vehicle simulator's and SITL's home alike."""

# The same factor as ROSBuzz's DEG2RAD macro, so that results agree to the last bit.
_DEG2RAD = math.pi / 180.0


def _lon_delta(lon0: float, lon: float) -> float:
    """lon − lon0 in degrees, the short way round; exact when |lon − lon0| <= 180."""
    d = lon - lon0
    # Only adjust when needed: a blanket modulo would perturb the low bits of every result.
    if d > 180.0:
        d -= 360.0
    elif d < -180.0:
        d += 360.0
    return d


def _wrap_lon(lon: float) -> float:
    """Longitude brought back into [-180, 180]."""
    if lon > 180.0:
        return lon - 360.0
    if lon < -180.0:
        return lon + 360.0
    return lon


def ned_offset(lat0: float, lon0: float, lat: float, lon: float) -> tuple[float, float]:
    """(north_m, east_m) of GPS point (lat, lon) seen from (lat0, lon0), as ROSBuzz computes it."""
    north = (lat - lat0) * _DEG2RAD * EARTH_RADIUS_M
    east = _lon_delta(lon0, lon) * _DEG2RAD * EARTH_RADIUS_M * math.cos(lat * _DEG2RAD)
    return north, east


def range_bearing(lat0: float, lon0: float, lat: float, lon: float) -> tuple[float, float]:
    """(distance_m, azimuth_rad) of (lat, lon) from (lat0, lon0); 0 = north, +pi/2 = east."""
    north, east = ned_offset(lat0, lon0, lat, lon)
    return math.hypot(north, east), math.atan2(east, north)


def offset_gps(lat0: float, lon0: float, north_m: float, east_m: float) -> tuple[float, float]:
    """GPS point (lat, lon) at `north_m`, `east_m` from (lat0, lon0): the inverse of `ned_offset`.

    Raises ValueError when the offset leaves the valid latitudes or lands on a pole (where
    east offsets have no meaning).
    """
    lat = lat0 + north_m / EARTH_RADIUS_M / _DEG2RAD
    if not -90.0 <= lat <= 90.0:
        raise ValueError(f"offset of {north_m} m north from latitude {lat0} leaves the globe")
    # ned_offset scales east by cos(target latitude); the target latitude is already known
    # here from the north offset alone, so this division undoes it exactly.
    cos_lat = math.cos(lat * _DEG2RAD)
    if cos_lat < 1e-12:
        raise ValueError(f"latitude {lat} is a pole: an east offset is undefined there")
    lon = _wrap_lon(lon0 + east_m / (EARTH_RADIUS_M * cos_lat) / _DEG2RAD)
    return lat, lon


@dataclass(frozen=True)
class LocalFrame:
    """A local ENU frame (x east, y north, z up, metres) anchored at a GPS origin."""

    lat: float
    lon: float
    alt: float = 0.0

    def __post_init__(self) -> None:
        """Reject origins that cannot anchor a frame."""
        if not (math.isfinite(self.lat) and math.isfinite(self.lon) and math.isfinite(self.alt)):
            raise ValueError(f"frame origin must be finite, got {self.lat}, {self.lon}, {self.alt}")
        if not -90.0 < self.lat < 90.0:
            raise ValueError(f"frame origin latitude must be in (-90, 90), got {self.lat}")
        if not -180.0 <= self.lon <= 180.0:
            raise ValueError(f"frame origin longitude must be in [-180, 180], got {self.lon}")

    def to_gps(self, x: float, y: float, z: float = 0.0) -> tuple[float, float, float]:
        """(lat, lon, alt) of the local point (x east, y north, z up)."""
        lat, lon = offset_gps(self.lat, self.lon, y, x)
        return lat, lon, self.alt + z

    def from_gps(
        self, lat: float, lon: float, alt: float | None = None
    ) -> tuple[float, float, float]:
        """Local (x east, y north, z up) of a GPS point; no altitude means z = 0."""
        north, east = ned_offset(self.lat, self.lon, lat, lon)
        return east, north, 0.0 if alt is None else alt - self.alt
