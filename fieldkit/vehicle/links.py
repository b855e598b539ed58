"""The link the field node opens for its profile, whatever the autopilot family speaks.

    link = open_link(profile, url, clock=tick_clock.now)   # ArduPilot, PX4
    link = open_link(profile, url, clock=..., dji_app_id=ID, dji_app_key=KEY)   # an M100
    link = open_link(profile, url, clock=..., gps="/dev/ttyUSB1")   # a Husky and its GPS
    link.wait_heartbeat(30.0)   # start-up: heartbeat / DJI activation+authority / MCU status
    link.poll()                 # the loop

`VehicleLink` is what the node, its recorder and its safe stop use of a link: the
`VehicleCore` orders and views plus the port's poll, taps and start-up waits. The MAVLink
`fieldkit.vehicle.link.Autopilot` (ArduPilot, PX4), the DJI Onboard SDK's
`fieldkit.vehicle.dji.link.DjiLink` and the Clearpath base's `fieldkit.vehicle.clearpath.link.Husky`
(its MCU and a GPS receiver) all serve it; `open_link` picks one by the profile's
`autopilot.flavour`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, TypeVar

from fieldkit.robot.profiles import Profile
from fieldkit.vehicle.autopilot import AutopilotError, AutopilotState, CommandStatus, Event
from fieldkit.vehicle.core import VehicleCommand


class VehicleLink(Protocol):
    """A vehicle core on its port, as the node uses it (parameters positional, so that each
    backend keeps its own names and keyword extras)."""

    url: str
    on_rx: Callable[[bytes], None] | None
    on_tx: Callable[[bytes], None] | None

    @property
    def telemetry(self) -> AutopilotState:
        """The latest telemetry."""

    @property
    def pilot_override(self) -> bool:
        """Whether the pilot has the vehicle."""

    @property
    def messages(self) -> int:
        """Good frames received."""

    @property
    def bad_frames(self) -> int:
        """Frames dropped for their checksum or layout."""

    def poll(self, timeout: float = 0.0, /) -> int:
        """Read, handle, move commands on, write: the loop's one call."""

    def drain_events(self) -> list[Event]:
        """What happened since the last call."""

    def heartbeat_age(self) -> float:
        """Seconds since the vehicle was last heard."""

    def time_state(self) -> dict[str, object]:
        """The core's clock readings."""

    def set_time_state(self, state: dict[str, object], /) -> None:
        """Restore `time_state()`'s readings."""

    def arm(self) -> VehicleCommand:
        """Arm."""

    def disarm(self) -> VehicleCommand:
        """Disarm."""

    def takeoff(self, altitude_m: float, /) -> VehicleCommand:
        """Take off."""

    def goto(self, lat: float, lon: float, alt_m: float, /) -> VehicleCommand:
        """Go to a point (alt above home)."""

    def hold(self) -> VehicleCommand:
        """Stop and keep position."""

    def land(self) -> VehicleCommand:
        """Land."""

    def rtl(self) -> VehicleCommand:
        """Return home."""

    def cancel_all(self, reason: str = "cancelled", /) -> None:
        """Give up every command in progress."""

    def request_streams(self, rate_hz: float, /) -> VehicleCommand:
        """Telemetry at `rate_hz` (at least)."""

    def wait_heartbeat(self, timeout: float, /) -> AutopilotState:
        """Start-up: the vehicle is there and ready to be commanded."""

    def wait_gps_fix(self, timeout: float, /) -> AutopilotState:
        """Start-up: a GPS good enough to fly on."""

    def wait_position(self, timeout: float, /) -> AutopilotState:
        """Start-up: a position."""

    def wait_command(self, command: Any, timeout: float, /) -> Any:
        """Poll until `command` is over; AutopilotError if it failed or is still pending."""

    def close(self) -> None:
        """Close the port."""


class _Outcome(Protocol):
    """A command as `command_outcome` reads it (every backend's command is one)."""

    name: str
    error: str | None
    status: CommandStatus

    @property
    def ok(self) -> bool:
        """Whether the vehicle accepted it."""


_C = TypeVar("_C", bound=_Outcome)


def poll_until(
    poll: Callable[[float], object],
    clock: Callable[[], float],
    cond: Callable[[], bool],
    deadline: float,
    idle: Callable[[], None] | None,
    poll_interval: float,
) -> bool:
    """Poll until `cond()` holds (True) or `clock()` reaches `deadline` (False): the links'
    start-up waits. `idle` runs between polls (a test steps its simulated vehicle there)."""
    while True:
        poll(poll_interval)
        if cond():
            return True
        if clock() >= deadline:
            return False
        if idle is not None:
            idle()


def command_outcome(command: _C, finished: bool, timeout: float, error: type[Exception]) -> _C:
    """`command` once a wait for it is over (`finished`: it ended in time); `error` (the
    link's AutopilotError) if it is still pending after `timeout` seconds or failed."""
    if not finished:
        raise error(f"{command.name}: not finished after {timeout:g} s")
    if not command.ok:
        raise error(command.error or f"{command.name}: {command.status.value}")
    return command


def open_link(
    profile: Profile,
    url: str | None = None,
    *,
    clock: Callable[[], float] | None = None,
    gps: str | None = None,
    dji_app_id: int | None = None,
    dji_app_key: str | None = None,
    dji_stream_thread: bool = True,
    in_tick: Callable[[], bool] | None = None,
) -> VehicleLink:
    """The link of `profile`'s autopilot family on `url` (default: `autopilot.url`).

    Flavour "dji" needs the developer's app id and app key (the node's config); the DJI
    link streams its movement control from a thread at the profile's control rate, held
    back while `in_tick()` (the node's tick clock is frozen) so that its sends fall between
    ticks; a replay opens it with `dji_stream_thread=False` and sends them itself. A
    Clearpath base reads its GPS on `gps` (default: the profile's `[gps] port`). Raises
    AutopilotError (the DJI link's DjiError is one) when the link cannot be opened, or for a
    `gps` given to a flavour whose GPS is inside the autopilot.
    """
    flavour = profile.autopilot.flavour
    options: dict[str, Any] = {} if clock is None else {"clock": clock}  # else each link's own
    if gps is not None and flavour != "clearpath":
        raise AutopilotError(
            f"{profile.name}: --gps is for a base with a GPS of its own (flavour clearpath); "
            f"its autopilot (flavour {flavour}) has the GPS inside"
        )
    if flavour == "clearpath":
        from fieldkit.vehicle.clearpath.link import Husky

        return Husky.from_profile(profile, url, gps, **options)
    if flavour == "dji":
        from fieldkit.vehicle.dji.link import DjiLink

        if dji_app_id is None or dji_app_key is None:
            raise AutopilotError(
                f"{profile.name}: the DJI Onboard SDK needs the developer's app id and app key: "
                "give them in the node config ([dji] app_id and app_key)"
            )
        return DjiLink.from_profile(
            profile,
            url,
            app_id=dji_app_id,
            app_key=dji_app_key,
            stream_thread=dji_stream_thread,
            stream_paused=in_tick,
            **options,
        )
    from fieldkit.vehicle.link import Autopilot

    return Autopilot.from_profile(profile, url, **options)


__all__ = ["VehicleLink", "command_outcome", "open_link", "poll_until"]
