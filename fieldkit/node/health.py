"""Device loss as the node reports it: its autopilot's and its radio's outages.

A serial device that vanishes (a loose USB cable) is closed and reopened by its transport
(fieldkit/vehicle/reopen.py's policy for every vehicle link: MAVLink's, the M100's, the
Husky's two ports, which count as its autopilot's; the XBee radio's own reopening). The
node reads how that went for `systemctl status` and summary.json: whether each device is
down now and for how long, how many times it was lost, how long it was down in all, and
what was dropped meanwhile (the autopilot's bytes, the radio's frames). A UDP radio or a
network autopilot never goes down this way: they report no outage.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from fieldkit.vehicle.reopen import ReopenPolicy


@dataclass(frozen=True)
class LinkHealth:
    """One device's losses: down now (for how long), outages, seconds down, what was dropped."""

    #: Seconds it has been down, None while it is up.
    down_for_s: float | None = None
    #: Times it was lost, the current outage included.
    outages: int = 0
    #: Seconds down in all, the current outage included.
    down_s: float = 0.0
    #: What was dropped while it was down: bytes (autopilot) or frames (radio).
    dropped: int = 0

    def status(self, name: str) -> str | None:
        """A STATUS= part (`autopilot link down 3.2 s`, `radio link lost 2 times, 5.1 s in
        all`), None for a device never lost."""
        if self.down_for_s is not None:
            return f"{name} link down {self.down_for_s:.1f} s"
        if self.outages:
            times = "once" if self.outages == 1 else f"{self.outages} times"
            return f"{name} link lost {times}, {self.down_s:.1f} s in all"
        return None


@runtime_checkable
class ReportsLinkHealth(Protocol):
    """A vehicle port that can say how its device has fared (`MavlinkAutopilot`)."""

    def link_health(self, now: float) -> LinkHealth:
        """Its device's losses at `now` (the node's clock)."""


def policy_health(now: float, dropped: int, *policies: ReopenPolicy) -> LinkHealth:
    """The losses of the devices behind `policies` at `now`, as one: down while any is (for
    the longest current outage), their outages and seconds down added up."""
    current = [p.down_for(now) for p in policies if p.down]
    return LinkHealth(
        down_for_s=max(current) if current else None,
        outages=sum(p.outages for p in policies),
        down_s=sum(p.down_s for p in policies) + sum(current),
        dropped=dropped,
    )


def radio_health(radio: object) -> LinkHealth:
    """A radio's device losses: the XBee's (reopened serial port), none for others."""
    from fieldkit.radio.xbee_serial import XBeeRadio

    if not isinstance(radio, XBeeRadio):
        return LinkHealth()
    now = radio.clock()
    current = radio.down_for(now) if radio.down else None
    return LinkHealth(
        down_for_s=current,
        outages=radio.outages,
        down_s=radio.down_s + (current or 0.0),
        dropped=radio.stats.get("frames_dropped_down", 0),
    )


__all__ = ["LinkHealth", "ReportsLinkHealth", "policy_health", "radio_health"]
