"""What every vehicle protocol core offers: the one interface of fieldkit's backends.

A core is a sans-I/O state machine for one autopilot family, fed bytes and time:

    core.receive_data(bytes_from_the_vehicle)     # parse, update telemetry, match ACKs
    core.tick()                                   # retries, timeouts, periodic sends
    port.write(core.data_to_send())               # what it wants on the wire
    core.telemetry                                # the latest AutopilotState
    for event in core.drain_events(): log(event.text)
    cmd = core.takeoff(5.0)                       # returns at once; cmd.done / cmd.ok later

`fieldkit.vehicle.autopilot.AutopilotCore` (MAVLink: ArduPilot, PX4) is one; the DJI Onboard
SDK and Clearpath MCU cores are others. The transport around a core (a serial port, a pty, a
pymavlink connection) is thin and shared; the node, SITL and replay talk to this interface
only. Telemetry is an `AutopilotState` and events are `Event`s whatever the protocol, so the
supervisor and the recording see every robot the same way.
"""

from __future__ import annotations

from typing import Protocol

from fieldkit.vehicle.autopilot import AutopilotState, Event


class VehicleCommand(Protocol):
    """One order in progress: returned at once by a core, moved on by its `tick()`."""

    name: str
    error: str | None

    @property
    def done(self) -> bool:
        """Whether it is over, whatever the outcome."""

    @property
    def ok(self) -> bool:
        """Whether the vehicle accepted (acknowledged) it."""


class VehicleCore(Protocol):
    """A protocol core: bytes and time in, telemetry, events and bytes out; no I/O."""

    url: str
    telemetry: AutopilotState

    def receive_data(self, data: bytes) -> int:
        """Bytes read from the vehicle's port: the number of good frames handled."""

    def data_to_send(self) -> bytes:
        """Bytes to write to the vehicle's port now (taken: a second call gives new ones)."""

    def tick(self) -> None:
        """Move time-driven work on: retries, timeouts, keep-alives, setpoint streams."""

    def drain_events(self) -> list[Event]:
        """What happened since the last call, for the node's log."""

    def heartbeat_age(self) -> float:
        """Seconds since the vehicle was last heard (inf before the first time)."""

    @property
    def heartbeat_lost(self) -> bool:
        """Whether the vehicle has been silent longer than the profile allows."""

    @property
    def pilot_override(self) -> bool:
        """Whether the pilot has taken control (an RC switch, DJI's mode switch)."""

    @property
    def messages(self) -> int:
        """Good frames received."""

    @property
    def bad_frames(self) -> int:
        """Frames dropped for their checksum or layout."""

    def arm(self) -> VehicleCommand:
        """Arm the motors (a ground robot: enable its drive)."""

    def disarm(self) -> VehicleCommand:
        """Disarm (refused in the air by the vehicle, as it should be)."""

    def takeoff(self, altitude_m: float) -> VehicleCommand:
        """Take off to `altitude_m` above home (a ground robot: done at once)."""

    def goto(self, lat: float, lon: float, alt_m: float) -> VehicleCommand:
        """Go to a position (alt above home); a setpoint, superseded by the next one."""

    def hold(self) -> VehicleCommand:
        """Stop and keep position (a ground robot: stop the wheels now)."""

    def land(self) -> VehicleCommand:
        """Land where it is (a ground robot: stop)."""

    def rtl(self) -> VehicleCommand:
        """Return home (and land, for a UAV)."""

    def cancel_all(self, reason: str = "cancelled") -> None:
        """Give up every command in progress."""

    def time_state(self) -> dict[str, object]:
        """The core's clock readings (last heard, last sent...), for a replay to restore."""

    def set_time_state(self, state: dict[str, object]) -> None:
        """Restore `time_state()`'s readings."""


__all__ = ["VehicleCommand", "VehicleCore"]
