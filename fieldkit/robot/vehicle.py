"""The vehicle as a robot's host sees it: a telemetry snapshot in, one order out.

Every vehicle backend (the ArduPilot MAVLink link today) serves a `VehiclePort`: the field
node polls it, reads its `Telemetry` each tick, and hands it the supervisor's `Order`.
`sensors_from` turns a snapshot into the runtime's `Sensors`, the only place that does.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from fieldkit.robot import geo
from fieldkit.robot.safety import Order
from fieldkit.robot.script_api import ON_GROUND, FlightStatus, Sensors


@dataclass(frozen=True, slots=True)
class Telemetry:
    """The vehicle's state at one tick, as its backend reports it."""

    lat: float
    lon: float
    alt: float  # relative to home, metres
    yaw: float
    voltage: float
    current: float
    battery_percent: float
    armed: bool
    heartbeat_age_s: float
    rc_override: bool
    status: FlightStatus = ON_GROUND


class VehiclePort(Protocol):
    """What a robot's host needs of its vehicle backend."""

    def poll(self) -> None:
        """Read what arrived, progress pending commands, send the periodic heartbeat."""

    def telemetry(self) -> Telemetry:
        """The latest telemetry snapshot."""

    def execute(self, order: Order, frame: geo.LocalFrame) -> None:
        """Start carrying out one order of the supervisor."""

    def counters(self) -> tuple[int, int]:
        """(messages received, bad frames)."""


def sensors_from(t: Telemetry, frame: geo.LocalFrame) -> Sensors:
    """The runtime's `Sensors` for a telemetry snapshot, positions in `frame`."""
    east, north, _ = frame.from_gps(t.lat, t.lon, t.alt)
    return Sensors(
        lat=t.lat,
        lon=t.lon,
        alt=t.alt,
        north=north,
        east=east,
        yaw=t.yaw,
        voltage=t.voltage,
        current=t.current,
        battery_percent=t.battery_percent,
        status=t.status,
        armed=t.armed,
        heartbeat_age_s=t.heartbeat_age_s,
        rc_override=t.rc_override,
    )


__all__ = ["Telemetry", "VehiclePort", "sensors_from"]
