"""fieldkit.robot.geo: known values, ROSBuzz's formula, round trips, bearings in every quadrant."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from fieldkit.robot.geo import (
    EARTH_RADIUS_M,
    LocalFrame,
    ned_offset,
    offset_gps,
    range_bearing,
)

# A field near Montréal, where ROSBuzz was flown.
LAT0, LON0 = 45.5088, -73.5530

lats = st.floats(min_value=-80.0, max_value=80.0)
lons = st.floats(min_value=-180.0, max_value=180.0)
offsets = st.floats(min_value=-20_000.0, max_value=20_000.0)


def test_radius() -> None:
    assert EARTH_RADIUS_M == 6371000.0


def test_one_hundred_thousandth_of_a_degree_of_latitude() -> None:
    north, east = ned_offset(LAT0, LON0, LAT0 + 1e-5, LON0)
    assert north == pytest.approx(1.11195, abs=1e-5)
    assert east == 0.0


def test_east_uses_the_cosine_of_the_target_latitude() -> None:
    # At the equator 1e-5 deg of longitude is 1.11195 m; seen from the equator, a target
    # at 60 deg north counts it at cos(60 deg) = 0.5 of that (ROSBuzz's gps_convert_ned).
    _, east = ned_offset(0.0, 0.0, 0.0, 1e-5)
    assert east == pytest.approx(1.11195, abs=1e-5)
    _, east = ned_offset(0.0, 0.0, 60.0, 1e-5)
    assert east == pytest.approx(1.11195 * 0.5, abs=1e-5)
    # ... and not the origin's: swapping the roles changes the answer.
    _, east_back = ned_offset(60.0, 1e-5, 0.0, 0.0)
    assert east_back == pytest.approx(-1.11195, abs=1e-5)


def test_matches_the_rosbuzz_expression_bit_for_bit() -> None:
    lat, lon = LAT0 + 3.1e-4, LON0 - 2.7e-4
    deg2rad = math.pi / 180.0
    north = (lat - LAT0) * deg2rad * 6371000.0
    east = (lon - LON0) * deg2rad * 6371000.0 * math.cos(lat * deg2rad)
    assert ned_offset(LAT0, LON0, lat, lon) == (north, east)


def test_known_distance() -> None:
    # 100 m north and 100 m east: 141.42 m at 45 deg.
    lat, lon = offset_gps(LAT0, LON0, 100.0, 100.0)
    dist, az = range_bearing(LAT0, LON0, lat, lon)
    assert dist == pytest.approx(100.0 * math.sqrt(2.0), abs=1e-9)
    assert az == pytest.approx(math.pi / 4, abs=1e-12)


@pytest.mark.parametrize(
    ("north", "east", "azimuth"),
    [
        (10.0, 0.0, 0.0),
        (10.0, 10.0, math.pi / 4),  # NE
        (0.0, 10.0, math.pi / 2),
        (-10.0, 10.0, 3 * math.pi / 4),  # SE
        (-10.0, 0.0, math.pi),
        (-10.0, -10.0, -3 * math.pi / 4),  # SW
        (0.0, -10.0, -math.pi / 2),
        (10.0, -10.0, -math.pi / 4),  # NW
    ],
)
def test_bearings_in_all_quadrants(north: float, east: float, azimuth: float) -> None:
    lat, lon = offset_gps(LAT0, LON0, north, east)
    dist, az = range_bearing(LAT0, LON0, lat, lon)
    assert dist == pytest.approx(math.hypot(north, east), abs=1e-9)
    assert az == pytest.approx(azimuth, abs=1e-9)


def test_same_point() -> None:
    assert range_bearing(LAT0, LON0, LAT0, LON0) == (0.0, 0.0)


def test_across_the_antimeridian_is_short() -> None:
    north, east = ned_offset(0.0, 179.99999, 0.0, -179.99999)
    assert north == 0.0
    assert east == pytest.approx(2 * 1.11195, abs=1e-4)
    lat, lon = offset_gps(0.0, 179.99999, 0.0, 2.0)
    assert -180.0 <= lon < -179.99
    assert ned_offset(0.0, 179.99999, lat, lon)[1] == pytest.approx(2.0, abs=1e-6)


def test_offset_off_the_globe_is_refused() -> None:
    with pytest.raises(ValueError, match="leaves the globe"):
        offset_gps(89.9, 0.0, 100_000.0, 0.0)


@given(lats, lons, offsets, offsets)
def test_offset_gps_inverts_ned_offset(lat0: float, lon0: float, n: float, e: float) -> None:
    lat, lon = offset_gps(lat0, lon0, n, e)
    assert -180.0 <= lon <= 180.0
    north, east = ned_offset(lat0, lon0, lat, lon)
    assert north == pytest.approx(n, abs=1e-6)
    assert east == pytest.approx(e, abs=1e-6)


@given(lats, lons, offsets, offsets)
def test_range_bearing_agrees_with_the_offset(lat0: float, lon0: float, n: float, e: float) -> None:
    lat, lon = offset_gps(lat0, lon0, n, e)
    dist, az = range_bearing(lat0, lon0, lat, lon)
    assert dist == pytest.approx(math.hypot(n, e), abs=1e-6)
    # Compare directions through the unit vector: angles wrap at +-pi.
    if dist > 1e-3:
        assert math.cos(az) == pytest.approx(n / dist, abs=1e-6)
        assert math.sin(az) == pytest.approx(e / dist, abs=1e-6)


@given(lats, lons, st.floats(-500.0, 500.0), offsets, offsets, st.floats(-200.0, 200.0))
def test_local_frame_round_trip(
    lat0: float, lon0: float, alt0: float, x: float, y: float, z: float
) -> None:
    frame = LocalFrame(lat0, lon0, alt0)
    lat, lon, alt = frame.to_gps(x, y, z)
    bx, by, bz = frame.from_gps(lat, lon, alt)
    assert bx == pytest.approx(x, abs=1e-6)
    assert by == pytest.approx(y, abs=1e-6)
    assert bz == pytest.approx(z, abs=1e-6)


def test_local_frame_axes() -> None:
    frame = LocalFrame(LAT0, LON0, 30.0)
    lat, lon, alt = frame.to_gps(0.0, 10.0, 2.0)  # 10 m north, 2 m up
    assert lat > LAT0 and lon == LON0 and alt == 32.0
    lat, lon, alt = frame.to_gps(10.0, 0.0)  # 10 m east
    assert lat == LAT0 and lon > LON0 and alt == 30.0
    # Consistent with ned_offset: x is east, y is north.
    assert frame.from_gps(*ned_inverse(frame, 3.0, 4.0)) == pytest.approx((4.0, 3.0, 0.0))
    assert frame.from_gps(LAT0, LON0) == (0.0, 0.0, 0.0)


def ned_inverse(frame: LocalFrame, north: float, east: float) -> tuple[float, float]:
    """The GPS point `north`, `east` metres from the frame origin."""
    return offset_gps(frame.lat, frame.lon, north, east)


@pytest.mark.parametrize(
    ("lat", "lon", "alt"),
    [(90.0, 0.0, 0.0), (0.0, 181.0, 0.0), (math.nan, 0.0, 0.0), (0.0, 0.0, math.inf)],
)
def test_local_frame_rejects_bad_origins(lat: float, lon: float, alt: float) -> None:
    with pytest.raises(ValueError):
        LocalFrame(lat, lon, alt)
