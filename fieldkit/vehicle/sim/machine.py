"""The simulated machine a profile's `autopilot.flavour` needs, on its own ptys, behind one face.

    machine = open_sim_machine(load_profile("husky"), home=(45.5017, -73.5673), hold_fix=True)
    machine.node_args()        # ["--autopilot", MCU_PTY, "--gps", GPS_PTY]: for fieldkit node
    machine.step(0.05)         # lines served, physics by 50 ms
    machine.node_heard         # the node has written to it: it is up
    machine.release_fix()      # the GPS fix held back until now
    machine.close()            # the ptys too

`fieldkit sitl` runs a team of these, one a robot, whatever each robot is: ArduPilot (the
Solo, and any MAVLink profile), PX4 (the Spiri), the DJI M100 (`SimM100`: the node is given
the test app id and key, `app`) and the Clearpath Husky (`SimHusky`: its MCU and its GPS on
two ptys, the node's `--autopilot` and `--gps`). Each is the same simulator `fieldkit
vehicle-sim` runs; this adds the ptys and the few views a host of many needs: where the
machine is, what mode it reads as, whether the node has spoken to it.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod

from fieldkit.robot.profiles import Profile
from fieldkit.vehicle.pty import PtyPair, open_pty
from fieldkit.vehicle.sim.dji import TEST_APP_ID, TEST_APP_KEY
from fieldkit.vehicle.sim.dji_vehicle import SimM100Vehicle
from fieldkit.vehicle.sim.husky_pty import SimHuskyPorts
from fieldkit.vehicle.sim.vehicle import SimVehicle, open_sim_vehicle

#: What a machine reads as when its motors or drive are off (the tracks' mode column).
DISARMED = "DISARMED"


class SimMachine(ABC):
    """One simulated machine on ptys it owns, as a host of many drives it."""

    #: The machine's kind in words (`ArduPilot`, `PX4`, `DJI M100`, `Clearpath Husky`).
    kind: str = ""

    def __init__(self, profile: Profile, ptys: list[PtyPair]) -> None:
        self.profile = profile
        self.ptys = ptys

    @property
    def autopilot_path(self) -> str:
        """The pty the node opens as its autopilot (`--autopilot`)."""
        return self.ptys[0].slave_path

    def node_args(self) -> list[str]:
        """The `fieldkit node` options that point it at this machine."""
        return ["--autopilot", self.autopilot_path]

    @property
    def app(self) -> tuple[int, str] | None:
        """The DJI app (id, key) the node must be given, for an M100; None otherwise."""
        return None

    @abstractmethod
    def step(self, dt: float) -> None:
        """Serve the lines (no waiting), advance the physics by `dt`, send what is due."""

    @property
    @abstractmethod
    def position(self) -> tuple[float, float, float]:
        """(lat, lon, metres above the ground) now."""

    @property
    @abstractmethod
    def mode(self) -> str:
        """What the machine is doing, in one word (its flight mode; DISARMED when off)."""

    @property
    @abstractmethod
    def node_heard(self) -> bool:
        """Whether the node has written anything to it yet."""

    @abstractmethod
    def release_fix(self) -> None:
        """Give the GPS its fix now (held back by `hold_fix`)."""

    @abstractmethod
    def _close_machine(self) -> None:
        """Close what the simulator opened."""

    def close(self) -> None:
        """Close the simulator, then the ptys."""
        try:
            self._close_machine()
        finally:
            for pty in self.ptys:
                pty.close()


class MavlinkMachine(SimMachine):
    """A simulated ArduPilot or PX4 (`SimVehicle`) on one pty."""

    def __init__(self, profile: Profile, sim: SimVehicle, ptys: list[PtyPair]) -> None:
        super().__init__(profile, ptys)
        self.sim = sim
        self.kind = "PX4" if profile.autopilot.flavour == "px4" else "ArduPilot"

    def step(self, dt: float) -> None:
        """Serve the line, advance the physics by `dt`."""
        self.sim.step(dt)

    @property
    def position(self) -> tuple[float, float, float]:
        """(lat, lon, height above home)."""
        return self.sim.position

    @property
    def mode(self) -> str:
        """The autopilot's flight mode (GUIDED, OFFBOARD, LAND...), DISARMED when disarmed."""
        return str(self.sim.mode) if self.sim.armed else DISARMED

    @property
    def node_heard(self) -> bool:
        """Whether the node has sent a byte."""
        return self.sim.bytes_received > 0

    def release_fix(self) -> None:
        """A 3D fix from now on."""
        self.sim.gps_fix_delay_s = 0.0

    def _close_machine(self) -> None:
        self.sim.close()


class DjiMachine(SimMachine):
    """A simulated M100 flight controller (`SimM100Vehicle`) on one pty, activated by the
    test app."""

    kind = "DJI M100"

    def __init__(self, profile: Profile, sim: SimM100Vehicle, ptys: list[PtyPair]) -> None:
        super().__init__(profile, ptys)
        self.sim = sim

    @property
    def app(self) -> tuple[int, str] | None:
        """The test app id and key the simulated M100 accepts."""
        return TEST_APP_ID, TEST_APP_KEY

    def step(self, dt: float) -> None:
        """Serve the line, advance the physics by `dt`."""
        self.sim.step(dt)

    @property
    def position(self) -> tuple[float, float, float]:
        """(lat, lon, height above the take-off point)."""
        return self.sim.position

    @property
    def mode(self) -> str:
        """The task running (TAKEOFF, LANDING, GO_HOME), else SDK_CONTROL while the host has
        control, else the RC's mode (RC_F...); DISARMED with the motors stopped."""
        s = self.sim
        if not s.vehicle.armed:
            return DISARMED
        if s.task is not None:
            return s.task.upper()
        return "SDK_CONTROL" if s.authority else f"RC_{s.rc_switch}"

    @property
    def node_heard(self) -> bool:
        """Whether the node has sent a byte."""
        return self.sim.bytes_received > 0

    def release_fix(self) -> None:
        """GPS health good from now on."""
        self.sim.gps_fix_delay_s = 0.0

    def _close_machine(self) -> None:
        self.sim.close()


class HuskyMachine(SimMachine):
    """A simulated Husky (`SimHuskyPorts`): its MCU on one pty, its GPS on another."""

    kind = "Clearpath Husky"

    def __init__(self, profile: Profile, sim: SimHuskyPorts, ptys: list[PtyPair]) -> None:
        super().__init__(profile, ptys)
        self.sim = sim

    @property
    def gps_path(self) -> str:
        """The pty the node reads its GPS on (`--gps`)."""
        return self.ptys[1].slave_path

    def node_args(self) -> list[str]:
        """`--autopilot MCU --gps GPS`."""
        return [*super().node_args(), "--gps", self.gps_path]

    def step(self, dt: float) -> None:
        """Serve both lines, advance the physics by `dt`."""
        self.sim.step(dt)

    @property
    def position(self) -> tuple[float, float, float]:
        """(lat, lon, 0): a ground robot."""
        lat, lon = self.sim.position
        return lat, lon, 0.0

    @property
    def mode(self) -> str:
        """ESTOP, DRIVING or STOPPED (a base has no flight mode)."""
        if self.sim.faults.estop:
            return "ESTOP"
        return "DRIVING" if self.sim.drive.moving else "STOPPED"

    @property
    def node_heard(self) -> bool:
        """Whether the node has written to the MCU."""
        return self.sim.mcu.bytes_received > 0

    def release_fix(self) -> None:
        """A fix from now on."""
        self.sim.gps_fix_delay_s = 0.0

    def _close_machine(self) -> None:
        self.sim.close()


def open_sim_machine(
    profile: Profile,
    *,
    home: tuple[float, float],
    seed: int = 0,
    hold_fix: bool = False,
) -> SimMachine:
    """The simulated machine `profile`'s flavour needs, at `home`, on new ptys.

    `hold_fix` keeps the GPS without a fix until `release_fix()` (a swarm whose nodes take
    different times to start gets its fixes at once). Raises OSError without ptys, and the
    simulator's error for a profile it cannot simulate.
    """
    delay = math.inf if hold_fix else 0.0
    flavour = profile.autopilot.flavour
    ptys = [open_pty()]
    try:
        if flavour == "clearpath":
            ptys.append(open_pty())
            gps_baud = profile.gps.baud if profile.gps is not None else 19200
            husky = SimHuskyPorts(
                profile, ptys[0].master, ptys[1].master, baud=profile.autopilot.baud,
                gps_baud=gps_baud, home=home, gps_fix_delay_s=delay, seed=seed,
            )  # fmt: skip
            return HuskyMachine(profile, husky, ptys)
        if flavour == "dji":
            m100 = SimM100Vehicle(
                profile, ptys[0].master, home=home, gps_fix_delay_s=delay, seed=seed
            )
            return DjiMachine(profile, m100, ptys)
        vehicle = open_sim_vehicle(
            profile, ptys[0].master, home=home, seed=seed, gps_fix_delay_s=delay
        )
        return MavlinkMachine(profile, vehicle, ptys)
    except BaseException:
        for pty in ptys:
            pty.close()
        raise


__all__ = [
    "DISARMED",
    "DjiMachine",
    "HuskyMachine",
    "MavlinkMachine",
    "SimMachine",
    "open_sim_machine",
]
