"""The Husky as a robot's host sees it: a `fieldkit.robot.vehicle.VehiclePort` over `Husky`.

What `fieldkit.node.autopilot_port.MavlinkAutopilot` is for a MAVLink autopilot: each tick the
node polls it, reads a `Telemetry` snapshot and hands it the supervisor's order.
"""

from __future__ import annotations

import logging

from fieldkit.node.health import LinkHealth, policy_health
from fieldkit.robot import geo
from fieldkit.robot.safety import Order
from fieldkit.robot.script_api import ON_GROUND
from fieldkit.robot.vehicle import Telemetry
from fieldkit.vehicle.clearpath.core import HuskyCore
from fieldkit.vehicle.reopen import ReopenPolicy

_log = logging.getLogger("fieldkit.node")


class HuskyPort:
    """Adapts a Husky link (or its core, polled by the caller) to the node's `VehiclePort`."""

    def __init__(self, link: HuskyCore, home: tuple[float, float, float]) -> None:
        """`home`: the node frame's origin, the position reported until the GPS gives one."""
        self.link = link
        self.home = home

    def poll(self) -> None:
        """Read both ports, run the control cycle, log what happened: a line error or a lost
        device ("link") as a warning (`husky: MCU port /dev/husky lost (...); reopening...`),
        the rest (its return included) as information."""
        poll = getattr(self.link, "poll", None)
        if poll is not None:
            poll()
        else:
            self.link.tick()
        for event in self.link.drain_events():
            text = event.text
            level = logging.WARNING if event.kind == "link" else logging.INFO
            _log.log(level, "%s", text if text.startswith(("husky", "gps")) else f"husky: {text}")

    def telemetry(self) -> Telemetry:
        """The latest state; the last known position (or home) while none is known."""
        t = self.link.telemetry
        return Telemetry(
            lat=t.lat if t.lat is not None else self.home[0],
            lon=t.lon if t.lon is not None else self.home[1],
            alt=0.0,
            yaw=t.yaw_rad or 0.0,
            voltage=t.battery_voltage_v or 0.0,
            current=t.battery_current_a or 0.0,
            battery_percent=t.battery_percent if t.battery_percent is not None else 100.0,
            armed=t.armed,
            heartbeat_age_s=self.link.heartbeat_age(),
            rc_override=self.link.pilot_override,
            status=ON_GROUND,
        )

    def execute(self, order: Order, frame: geo.LocalFrame) -> None:
        """Start one supervisor order: a goto is the controller's new target; a stop (hold,
        land) writes zero speeds at once; takeoff is nothing for a ground robot."""
        link = self.link
        kind = order.kind
        if kind == "goto":
            north, east, _ = order.args
            lat, lon, _ = frame.to_gps(east, north, 0.0)
            link.goto(lat, lon, 0.0)
        elif kind == "takeoff":
            link.takeoff(order.args[0])
        elif kind in ("land", "rtl", "hold"):
            link.cancel_all(f"superseded by {kind}")
            getattr(link, kind)()
        elif kind == "arm":
            link.arm()
        elif kind == "disarm":
            link.disarm()

    def link_health(self, now: float) -> LinkHealth:
        """The devices' losses at `now`: the MCU's and the GPS's ports count as the
        autopilot's (down while either is, their outages added up); a core polled by the
        caller, without ports, reports none."""
        policies = [
            p
            for p in (getattr(self.link, "reopen", None), getattr(self.link, "gps_reopen", None))
            if isinstance(p, ReopenPolicy)
        ]
        if not policies:
            return LinkHealth()
        return policy_health(now, int(getattr(self.link, "bytes_dropped", 0)), *policies)

    def counters(self) -> tuple[int, int]:
        """(good MCU frames and GPS sentences, bad ones)."""
        return self.link.messages, self.link.bad_frames


__all__ = ["HuskyPort"]
