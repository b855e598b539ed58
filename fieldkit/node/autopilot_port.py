"""The field node's view of its autopilot: a `fieldkit.vehicle.links.VehicleLink` (the MAVLink
`Autopilot`, the DJI `DjiLink`; a Clearpath base has its own `HuskyPort`) as telemetry snapshots
in, supervisor orders out."""

from __future__ import annotations

import logging
from typing import cast

from fieldkit.node.health import LinkHealth, policy_health
from fieldkit.robot import geo
from fieldkit.robot.safety import Order
from fieldkit.robot.script_api import FLIGHT_STATUSES, IN_AIR, ON_GROUND, FlightStatus
from fieldkit.robot.vehicle import Telemetry, VehiclePort
from fieldkit.vehicle.links import VehicleLink
from fieldkit.vehicle.reopen import ReopenPolicy

_log = logging.getLogger("fieldkit.node")


class MavlinkAutopilot:
    """Adapts a vehicle link (MAVLink or DJI) to the node's `AutopilotPort`."""

    def __init__(self, link: VehicleLink, home: tuple[float, float, float]) -> None:
        self.link = link
        self.home = home  # where the node's frame starts: used until the first position

    def poll(self) -> None:
        """Read the line, move pending commands on, send our heartbeat; log the link's events.

        A line error or a lost device ("link") is a warning: `autopilot: /dev/autopilot lost
        (read failed: Input/output error); reopening`; its return (`... back after 4 s`) and
        everything else the link reports is information.
        """
        self.link.poll()
        for event in self.link.drain_events():
            text = event.text
            level = logging.WARNING if event.kind == "link" else logging.INFO
            _log.log(level, "%s", text if text.startswith("autopilot") else f"autopilot: {text}")

    def telemetry(self) -> Telemetry:
        """The latest state; the last known position (or home) while none is reported."""
        t = self.link.telemetry
        lat = t.lat if t.lat is not None else self.home[0]
        lon = t.lon if t.lon is not None else self.home[1]
        alt = t.alt_rel_m if t.alt_rel_m is not None else 0.0
        status: FlightStatus
        if t.landed_state in FLIGHT_STATUSES:
            status = cast(FlightStatus, t.landed_state)  # one of the four, checked
        else:
            status = IN_AIR if t.armed and alt > 0.3 else ON_GROUND
        return Telemetry(
            lat=lat,
            lon=lon,
            alt=alt,
            yaw=t.yaw_rad or 0.0,
            voltage=t.battery_voltage_v or 0.0,
            current=t.battery_current_a or 0.0,
            battery_percent=t.battery_percent if t.battery_percent is not None else 100.0,
            armed=t.armed,
            heartbeat_age_s=self.link.heartbeat_age(),
            rc_override=self.link.pilot_override,
            status=status,
        )

    def execute(self, order: Order, frame: geo.LocalFrame) -> None:
        """Start one supervisor order on the autopilot (commands are ACK-checked there)."""
        link = self.link
        kind = order.kind
        if kind == "goto":
            north, east, alt = order.args
            lat, lon, _ = frame.to_gps(east, north, 0.0)
            link.goto(lat, lon, alt)
        elif kind == "takeoff":
            link.takeoff(order.args[0])
        elif kind in ("land", "rtl", "hold"):
            # A safety order supersedes whatever is still queued (a takeoff waiting for its
            # turn would undo it).
            link.cancel_all(f"superseded by {kind}")
            getattr(link, kind)()
        elif kind == "arm":
            link.arm()
        elif kind == "disarm":
            link.disarm()

    def link_health(self, now: float) -> LinkHealth:
        """The serial device's losses at `now` (the link's clock: the node's); a link that
        does not reopen a device (a network one) reports none."""
        link = self.link
        policy = getattr(link, "reopen", None)
        if not isinstance(policy, ReopenPolicy):
            return LinkHealth()
        return policy_health(now, int(getattr(link, "bytes_dropped", 0)), policy)

    def counters(self) -> tuple[int, int]:
        """(MAVLink messages received, bad frames)."""
        return self.link.messages, self.link.bad_frames


def vehicle_port(link: VehicleLink, home: tuple[float, float, float]) -> VehiclePort:
    """The node's `VehiclePort` over whichever link `fieldkit.vehicle.links.open_link` gave:
    a Clearpath base's own (its orders are wheel speeds), else the autopilot adapter."""
    from fieldkit.vehicle.clearpath.core import HuskyCore
    from fieldkit.vehicle.clearpath.port import HuskyPort

    if isinstance(link, HuskyCore):
        return HuskyPort(link, home)
    return MavlinkAutopilot(link, home)
