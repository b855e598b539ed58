"""The node's start-up on its vehicle link, shared by `fieldkit node` and its replay.

    t = start_vehicle(link, profile, connect_timeout, say)

The vehicle heard (a heartbeat; an M100 activated and its control authority held; a
Clearpath MCU answering), the telemetry streams asked for, a GPS fix and a position, then
the stream requests given a moment to be answered, so that the loop begins with no command
in flight. A replay runs the very same calls on the recorded start-up bytes, handing in the
next recorded read each time a wait would wait (`idle`): the link then sends what the
recorded node sent, in the same order, and a core whose answers are matched by sequence
number (the M100's) reaches the state the recorded one had.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast

from fieldkit.robot.profiles import Profile
from fieldkit.vehicle.autopilot import AutopilotError, AutopilotState
from fieldkit.vehicle.links import VehicleLink

#: Seconds the start-up gives the stream requests to be answered before the loop begins.
STREAMS_SETTLE_S = 5.0


def start_vehicle(
    link: VehicleLink,
    profile: Profile,
    connect_timeout: float,
    say: Callable[[str], None],
    *,
    idle: Callable[[], None] | None = None,
    poll_interval: float = 0.05,
) -> AutopilotState:
    """Run the start-up; the telemetry with a position. AutopilotError (each backend's) if
    the vehicle is not heard, or gives no fix or position, within the profile's times."""
    waits = cast(Any, link)  # every backend's waits take `idle` and `poll_interval`
    say(f"autopilot: waiting up to {connect_timeout:g} s for a heartbeat on {link.url}")
    waits.wait_heartbeat(connect_timeout, idle=idle, poll_interval=poll_interval)
    streams = link.request_streams(profile.node.loop_rate_hz)
    fix_s = profile.autopilot.gps_fix_timeout_s
    say(f"autopilot: waiting up to {fix_s:g} s for a GPS fix")
    waits.wait_gps_fix(fix_s, idle=idle, poll_interval=poll_interval)
    t: AutopilotState = waits.wait_position(fix_s, idle=idle, poll_interval=poll_interval)
    # The loop begins with no command in flight: the stream requests answered (or given up
    # on), so that a recording's first tick does not depend on how far they had got.
    if not streams.done:
        try:
            waits.wait_command(streams, STREAMS_SETTLE_S, idle=idle, poll_interval=poll_interval)
        except AutopilotError as e:
            say(f"autopilot: stream rates not all confirmed ({e}); going on")
    if not streams.done:
        link.cancel_all("the loop begins")
    return t


__all__ = ["STREAMS_SETTLE_S", "start_vehicle"]
