"""Re-export for `fieldkit.sitl` (being rewritten elsewhere): use `fieldkit.vehicle` instead."""

from fieldkit.vehicle.pty import PtyPair, open_pty
from fieldkit.vehicle.sim.ardupilot import DEFAULT_HOME
from fieldkit.vehicle.sim.vehicle import SimVehicle

__all__ = ["DEFAULT_HOME", "PtyPair", "SimVehicle", "open_pty"]
