"""Which link drives a profile's vehicle: `open_link` picks it by `autopilot.flavour`.

    link = open_link(profile, url, gps=gps_dev, clock=clock)   # Autopilot, Husky...
    link.wait_heartbeat(30.0); link.request_streams(10.0)...    # the node's start-up
    link.poll()                                                  # its loop

`VehicleLink` is what the node's start-up, loop, recording and safe stop use of any link: a
`fieldkit.vehicle.core.VehicleCore` on its port(s), with the bounded start-up waits.
`fieldkit.vehicle.link.Autopilot` (MAVLink: ArduPilot, PX4) and
`fieldkit.vehicle.clearpath.link.Husky` (the Clearpath MCU and a GPS) are two.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from fieldkit.robot.profiles import Profile
from fieldkit.vehicle.autopilot import AutopilotState
from fieldkit.vehicle.core import VehicleCommand


class VehicleLink(Protocol):
    """A vehicle core on its port(s), as the node drives it."""

    url: str
    telemetry: AutopilotState
    #: Taps on the (main) port's bytes, read and written: the flight recorder's.
    on_rx: Callable[[bytes], None] | None
    on_tx: Callable[[bytes], None] | None

    def poll(self, timeout: float = 0.0) -> int:
        """Read what the port(s) hold, move time-driven work on; good frames handled."""

    def close(self) -> None:
        """Close the port(s); pending commands are cancelled."""

    def drain_events(self) -> list[Any]:
        """What happened since the last call (`Event`s)."""

    def heartbeat_age(self) -> float:
        """Seconds since the vehicle was last heard."""

    def wait_heartbeat(self, timeout: float) -> AutopilotState:
        """Start-up: poll until the vehicle is heard; AutopilotError on timeout."""

    def request_streams(self, rate_hz: float) -> VehicleCommand:
        """Start-up: ask for telemetry at `rate_hz`."""

    def wait_gps_fix(self, timeout: float) -> AutopilotState:
        """Start-up: poll until a 3D fix; AutopilotError on timeout."""

    def wait_position(self, timeout: float) -> AutopilotState:
        """Start-up: poll until a position is known; AutopilotError on timeout."""

    def wait_command(self, command: Any, timeout: float) -> VehicleCommand:
        """Poll until `command` is over; AutopilotError if it failed or is still pending."""

    def cancel_all(self, reason: str = "cancelled") -> None:
        """Give up every command in progress."""

    def hold(self) -> VehicleCommand:
        """Stop and keep position."""

    def land(self) -> VehicleCommand:
        """Land (a ground robot: stop)."""

    def time_state(self) -> dict[str, object]:
        """The core's clock readings, for a replay."""


def open_link(
    profile: Profile,
    url: str | None = None,
    *,
    gps: str | None = None,
    clock: Callable[[], float] | None = None,
) -> VehicleLink:
    """The link the profile's flavour needs, opened on `url` (default: `autopilot.url`) and,
    for a Clearpath base, `gps` (default: the profile's `[gps] port`). AutopilotError (with
    the reason) if a port will not open; a `gps` for a flavour without its own GPS port too."""
    from fieldkit.vehicle.autopilot import AutopilotError

    options: dict[str, Any] = {} if clock is None else {"clock": clock}
    if profile.autopilot.flavour == "clearpath":
        from fieldkit.vehicle.clearpath.link import Husky

        return Husky.from_profile(profile, url, gps, **options)
    if gps is not None:
        raise AutopilotError(
            f"{profile.name}: --gps is for a base with a GPS of its own (flavour clearpath); "
            f"its autopilot (flavour {profile.autopilot.flavour}) has the GPS inside"
        )
    from fieldkit.vehicle.link import Autopilot

    return Autopilot.from_profile(profile, url, **options)


__all__ = ["VehicleLink", "open_link"]
