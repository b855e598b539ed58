"""The autopilot side of the field node: a MAVLink link, and a simulated vehicle to test it.

- `link.Autopilot`: the node's link to ArduPilot/PX4 over any pymavlink URL; non-blocking,
  polled from the node's loop; commands checked against their COMMAND_ACK and retried.
- `vehicle_sim.SimVehicle`: a MAVLink vehicle that answers like ArduCopter or ArduPilot Rover,
  steppable for tests, real-time for `fieldkit vehicle-sim`.

The names below are loaded on first use: pymavlink takes half a second to import, and every
`fieldkit` command imports this package for its `vehicle-sim` subcommand.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fieldkit.autopilot.link import (
        Autopilot,
        AutopilotError,
        Command,
        CommandStatus,
        Event,
        FrameReader,
        Telemetry,
    )
    from fieldkit.autopilot.vehicle_sim import (
        PtyPair,
        SimFaults,
        SimRig,
        SimVehicle,
        VehicleSimError,
        open_pty,
    )

_WHERE = {
    "Autopilot": "link",
    "AutopilotError": "link",
    "Command": "link",
    "CommandStatus": "link",
    "Event": "link",
    "FrameReader": "link",
    "Telemetry": "link",
    "PtyPair": "vehicle_sim",
    "SimFaults": "vehicle_sim",
    "SimRig": "vehicle_sim",
    "SimVehicle": "vehicle_sim",
    "VehicleSimError": "vehicle_sim",
    "open_pty": "vehicle_sim",
}

__all__ = [
    "Autopilot",
    "AutopilotError",
    "Command",
    "CommandStatus",
    "Event",
    "FrameReader",
    "PtyPair",
    "SimFaults",
    "SimRig",
    "SimVehicle",
    "Telemetry",
    "VehicleSimError",
    "open_pty",
]


def __getattr__(name: str) -> Any:
    """Import a public name from its module on first use."""
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
