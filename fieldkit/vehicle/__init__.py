"""The vehicle side of the field node: autopilot protocols, their transports, their simulators.

- `autopilot.AutopilotCore`: the MAVLink conversation with ArduPilot/PX4, without I/O;
  commands checked against their COMMAND_ACK and retried;
- `link.Autopilot`: that core on any pymavlink URL, non-blocking, polled from the node's loop;
  a serial device that vanishes is closed and reopened at `reopen.ReopenPolicy`'s pace;
- `mavlink`: the codec and `FrameReader`, the resynchronising MAVLink parser;
- `pty`: `open_pty` and `PtyPair`, the line between a simulated machine and its driver;
- `px4.Px4Core` / `link.Px4Autopilot`: PX4's conversation (custom modes, the OFFBOARD
  setpoint stream, its failsafes) without I/O / on a pymavlink connection;
- `sim.ardupilot.SimArduPilot` / `sim.vehicle.SimVehicle`: a vehicle that answers like
  ArduCopter or ArduPilot Rover, without I/O / on a port (real time for `fieldkit vehicle-sim`);
  `sim.px4.SimPx4` / `sim.vehicle.SimPx4Vehicle` the same for PX4; `open_sim_vehicle` picks
  one by the profile's flavour.
- `links.open_link`: the link a profile's flavour needs (`Autopilot`, `Px4Autopilot`, the
  DJI `dji.link.DjiLink`, or for a Clearpath base `clearpath.link.Husky`: its MCU's serial
  protocol and a GPS receiver);
- `dji`: the M100 backend; `sim.dji`: a simulated M100;
- `clearpath`: the Husky backend; `sim.husky`: a simulated Husky (MCU and GPS).

The names below are loaded on first use: pymavlink takes half a second to import, and a caller
that wants only a pty should not pay for it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from fieldkit.vehicle.autopilot import (
        AutopilotCore,
        AutopilotError,
        AutopilotState,
        CommandStatus,
        Event,
        MavCommand,
    )
    from fieldkit.vehicle.link import Autopilot, Px4Autopilot
    from fieldkit.vehicle.mavlink import FrameReader
    from fieldkit.vehicle.pty import PtyPair, open_pty
    from fieldkit.vehicle.px4 import Px4Core
    from fieldkit.vehicle.sim.ardupilot import SimArduPilot, SimFaults, VehicleSimError
    from fieldkit.vehicle.sim.px4 import SimPx4
    from fieldkit.vehicle.sim.vehicle import SimPx4Vehicle, SimVehicle, open_sim_vehicle

_WHERE = {
    "Autopilot": "link",
    "AutopilotCore": "autopilot",
    "AutopilotError": "autopilot",
    "MavCommand": "autopilot",
    "CommandStatus": "autopilot",
    "Event": "autopilot",
    "FrameReader": "mavlink",
    "AutopilotState": "autopilot",
    "PtyPair": "pty",
    "open_pty": "pty",
    "SimArduPilot": "sim.ardupilot",
    "SimFaults": "sim.ardupilot",
    "VehicleSimError": "sim.ardupilot",
    "SimVehicle": "sim.vehicle",
    "Px4Autopilot": "link",
    "Px4Core": "px4",
    "SimPx4": "sim.px4",
    "SimPx4Vehicle": "sim.vehicle",
    "open_sim_vehicle": "sim.vehicle",
}

__all__ = [
    "Autopilot",
    "AutopilotCore",
    "AutopilotError",
    "MavCommand",
    "CommandStatus",
    "Event",
    "FrameReader",
    "PtyPair",
    "SimArduPilot",
    "SimFaults",
    "SimVehicle",
    "AutopilotState",
    "VehicleSimError",
    "open_pty",
    "Px4Autopilot",
    "Px4Core",
    "SimPx4",
    "SimPx4Vehicle",
    "open_sim_vehicle",
]


def __getattr__(name: str) -> Any:
    """Import a public name from its module on first use."""
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value
