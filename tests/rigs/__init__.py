"""Test rigs for the vehicle side: a simulated vehicle and the node's link, wired together.

- `SimRig`: a `SimVehicle` and an `Autopilot` on the two ends of a real pty;
- `MemoryRig`: the same pair as protocol cores (`SimArduPilot`, `AutopilotCore`) passing bytes
  in memory: no port, no kernel, no waiting;
- `HuskyMemoryRig` / `pty_husky`: the simulated Clearpath Husky (MCU and GPS) with its core in
  memory, or on two real ptys for a `Husky` link or a `fieldkit node`.

A px4 profile (the Spiri) gets PX4's pair: `SimPx4Vehicle` and `Px4Autopilot`, `SimPx4` and
`Px4Core`.

Both step the vehicle and the link in lockstep on a simulated clock, in the same order, so the
same scenario gives the same bytes through either.
"""

from __future__ import annotations

import signal
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from fieldkit.robot.profiles import Profile, load_profile
from fieldkit.vehicle.autopilot import AutopilotCore
from fieldkit.vehicle.link import Autopilot, Px4Autopilot
from fieldkit.vehicle.pty import open_pty
from fieldkit.vehicle.px4 import Px4Core
from fieldkit.vehicle.sim.ardupilot import SimArduPilot
from fieldkit.vehicle.sim.px4 import SimPx4
from fieldkit.vehicle.sim.vehicle import open_sim_vehicle

#: Where the rigs' vehicles start (the `rig` fixture's home).
RIG_HOME = (45.5049, -73.6133)


class _SteppedRig:
    """What both rigs share: a simulated clock advanced by `tick()` in steps of `dt`."""

    dt: float
    now: float

    def tick(self) -> None:
        """One step of the vehicle and the link."""
        raise NotImplementedError

    def clock(self) -> float:
        """The simulated time, seconds."""
        return self.now

    def run_for(self, seconds: float) -> None:
        """Tick for `seconds` of simulated time."""
        for _ in range(round(seconds / self.dt)):
            self.tick()

    def run_until(self, cond: Callable[[], bool], seconds: float) -> bool:
        """Tick until `cond()` holds (True) or `seconds` of simulated time pass (False)."""
        for _ in range(round(seconds / self.dt)):
            if cond():
                return True
            self.tick()
        return cond()


class SimRig(_SteppedRig):
    """A `SimVehicle` and an `Autopilot` on the two ends of a pty, stepped in lockstep.

    The link's clock is the simulated time (`now`), so its deadlines, retries and heartbeat
    ages follow the simulation. Each `tick()` steps the vehicle, waits until every byte it
    sent has reached the link, polls the link, then waits until every byte the link sent has
    reached the vehicle (which handles it at once). Waiting is on the bytes, with a wall-clock
    deadline, never on time: the exchange is deterministic and as fast as the machine allows.
    """

    def __init__(
        self,
        profile: str | Profile = "solo",
        *,
        dt: float = 0.1,
        sync_timeout_s: float = 5.0,
        link_options: dict[str, Any] | None = None,
        **sim_options: Any,
    ) -> None:
        """Open a pty, put a SimVehicle (with `sim_options`) and an Autopilot on it."""
        self.profile = load_profile(profile) if isinstance(profile, str) else profile
        self.dt = dt
        self.now = 0.0
        self.sync_timeout_s = sync_timeout_s
        self.pty = open_pty()
        try:
            self.sim = open_sim_vehicle(self.profile, self.pty.master, **sim_options)
            px4 = self.profile.autopilot.flavour == "px4"
            self.link = (Px4Autopilot if px4 else Autopilot)(
                self.pty.slave_path,
                profile=self.profile,
                clock=self.clock,
                **(link_options or {}),
            )
        except BaseException:
            self.pty.close()
            raise

    def tick(self) -> None:
        """One step of the vehicle and one poll of the link, every byte delivered both ways."""
        self.sim.step(self.dt)
        self.now += self.dt
        deadline = time.monotonic() + self.sync_timeout_s
        self.link.poll()
        while self.link.bytes_received < self.sim.bytes_sent:
            self._check(deadline, "vehicle -> link")
            self.link.poll(0.1)
        while self.sim.bytes_received < self.link.bytes_sent:
            self._check(deadline, "link -> vehicle")
            self.sim.service(0.1)

    def _check(self, deadline: float, way: str) -> None:
        if time.monotonic() > deadline:
            raise TimeoutError(
                f"{way}: bytes not delivered after {self.sync_timeout_s:g} s "
                f"(vehicle sent {self.sim.bytes_sent}, link read {self.link.bytes_received}; "
                f"link sent {self.link.bytes_sent}, vehicle read {self.sim.bytes_received})"
            )

    def connect(self, rate_hz: float = 10.0, timeout_s: float = 10.0) -> None:
        """Wait for the heartbeat and get the streams going at `rate_hz`."""
        self.link.wait_heartbeat(timeout_s, idle=self.tick, poll_interval=0.0)
        cmd = self.link.request_streams(rate_hz)
        self.link.wait_command(cmd, timeout_s, idle=self.tick, poll_interval=0.0)
        self.tick()

    def close(self) -> None:
        """Close the link, the vehicle and the pty."""
        self.link.close()
        self.sim.close()
        self.pty.close()

    def __enter__(self) -> SimRig:
        """Use as a context manager: closed on exit."""
        return self

    def __exit__(self, *exc: object) -> None:
        """Close everything."""
        self.close()


class MemoryRig(_SteppedRig):
    """A `SimArduPilot` and an `AutopilotCore` passing bytes in memory, stepped in lockstep.

    A tick does what `SimRig.tick` does, minus the pty: the vehicle takes what the link wrote
    since the last tick (a `SimVehicle` reads it at the start of its step), steps, the link
    reads everything the vehicle sent and ticks, and the vehicle handles what the link wrote.
    """

    def __init__(
        self,
        profile: str | Profile = "solo",
        *,
        dt: float = 0.1,
        link_options: dict[str, Any] | None = None,
        **sim_options: Any,
    ) -> None:
        """A SimArduPilot (with `sim_options`) and an AutopilotCore on the simulated clock."""
        self.profile = load_profile(profile) if isinstance(profile, str) else profile
        self.dt = dt
        self.now = 0.0
        px4 = self.profile.autopilot.flavour == "px4"
        self.sim: SimArduPilot = (SimPx4 if px4 else SimArduPilot)(self.profile, **sim_options)
        self.link: AutopilotCore = (Px4Core if px4 else AutopilotCore)(
            profile=self.profile, clock=self.clock, **(link_options or {})
        )

    def tick(self) -> None:
        """One step of the vehicle and one tick of the link, every byte delivered both ways."""
        self.sim.receive_data(self.link.data_to_send())
        self.sim.step(self.dt)
        self.now += self.dt
        self.link.receive_data(self.sim.data_to_send())
        self.link.tick()
        self.sim.receive_data(self.link.data_to_send())

    def poll(self) -> None:
        """What `Autopilot.poll()` does between ticks: read what the vehicle sent, tick."""
        self.link.receive_data(self.sim.data_to_send())
        self.link.tick()

    def wait(self, cond: Callable[[], bool], timeout_s: float) -> bool:
        """`Autopilot`'s blocking waits with the rig's tick as their idle step (as `SimRig`
        uses them): poll, test `cond`, tick, until `timeout_s` of simulated time pass."""
        deadline = self.now + timeout_s
        while True:
            self.poll()
            if cond():
                return True
            if self.now >= deadline:
                return False
            self.tick()

    def connect(self, rate_hz: float = 10.0, timeout_s: float = 10.0) -> None:
        """Wait for the heartbeat and get the streams going at `rate_hz`, as `SimRig` does."""
        assert self.wait(lambda: self.link.telemetry.last_heartbeat is not None, timeout_s)
        cmd = self.link.request_streams(rate_hz)
        assert self.wait(lambda: cmd.done, timeout_s) and cmd.ok, cmd
        self.tick()


@contextmanager
def pty_vehicle(
    home: tuple[float, float] = RIG_HOME, profile: str = "solo", gps_fix_delay_s: float = 0.0
) -> Iterator[str]:
    """A simulated ArduPilot on a pty, GPS fixed (after `gps_fix_delay_s` simulated
    seconds), stepped in real time by a thread (as `fieldkit vehicle-sim` runs it): yields
    the pty's path, for a `fieldkit node` to open."""
    pty = open_pty()
    sim = open_sim_vehicle(
        load_profile(profile), pty.master, home=home, gps_fix_delay_s=gps_fix_delay_s
    )
    stop = threading.Event()
    thread = threading.Thread(target=sim.run, args=(50.0, stop), daemon=True)
    thread.start()
    try:
        yield pty.slave_path
    finally:
        stop.set()
        thread.join()
        sim.close()
        pty.close()


def kill_and_drain(proc: subprocess.Popen[str], timeout: float) -> tuple[str, str]:
    """SIGKILL `proc` and return the rest of its stdout and stderr. Not `communicate()`:
    with both streams piped it reads the file descriptors directly, and loses what an
    earlier `proc.stdout.readline()` had already pulled into the stream's buffer (lines the
    child printed just before it died)."""
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=timeout)  # dead: both pipes now end
    assert proc.stdout is not None and proc.stderr is not None
    return proc.stdout.read(), proc.stderr.read()


class HuskyMemoryRig(_SteppedRig):
    """A `SimHusky` and a `HuskyCore` passing bytes in memory, stepped in lockstep: each
    `tick()` (0.1 s) runs the simulated machine in `substeps` steps, handing the core what
    its MCU and its GPS sent after each, then ticks the core (its control cycle)."""

    def __init__(
        self,
        profile: str | Profile = "husky",
        *,
        dt: float = 0.1,
        substeps: int = 5,
        core_options: dict[str, Any] | None = None,
        **sim_options: Any,
    ) -> None:
        """A SimHusky (with `sim_options`) and a HuskyCore on the simulated clock."""
        from fieldkit.vehicle.clearpath.core import HuskyCore
        from fieldkit.vehicle.sim.husky import SimHusky

        self.profile = load_profile(profile) if isinstance(profile, str) else profile
        self.dt = dt
        self.substeps = substeps
        self.now = 0.0
        self.sim = SimHusky(self.profile, **sim_options)
        self.core = HuskyCore(profile=self.profile, clock=self.clock, **(core_options or {}))
        self.mcu_wire: list[bytes] = []  # every byte string the core wrote, in order

    def deliver(self) -> None:
        """What the core wrote reaches the MCU (a stop order's frame, at once)."""
        data = self.core.data_to_send()
        if data:
            self.mcu_wire.append(data)
            self.sim.mcu.receive_data(data)

    def tick(self) -> None:
        """One 0.1 s step of the machine and one tick of the core, bytes delivered both ways."""
        h = self.dt / self.substeps
        for _ in range(self.substeps):
            self.deliver()
            self.sim.step(h)
            self.now += h
            self.core.receive_data(self.sim.mcu.data_to_send())
            self.core.receive_gps(self.sim.gps.data_to_send())
        self.core.tick()
        self.deliver()

    def connect(self, timeout_s: float = 5.0) -> None:
        """Start-up as the node does it: the MCU heard, its platform asked, a GPS fix, armed."""
        assert self.run_until(lambda: self.core.telemetry.last_heartbeat is not None, timeout_s)
        streams = self.core.request_streams(10.0)
        assert self.run_until(lambda: streams.done, timeout_s) and streams.ok, streams
        assert self.run_until(lambda: self.core.gps.has_fix, timeout_s)
        arm = self.core.arm()
        assert self.run_until(lambda: arm.done, timeout_s) and arm.ok, arm


@contextmanager
def pty_husky(
    home: tuple[float, float] = RIG_HOME, profile: str = "husky", **options: Any
) -> Iterator[tuple[str, str, Any]]:
    """A simulated Husky on two ptys, stepped in real time by a thread (as `fieldkit
    vehicle-sim` runs it): yields the MCU's pty path, the GPS's, and the simulator."""
    from fieldkit.vehicle.sim.husky_pty import SimHuskyPorts

    mcu, gps = open_pty(), open_pty()
    sim = SimHuskyPorts(load_profile(profile), mcu.master, gps.master, home=home, **options)
    stop = threading.Event()
    thread = threading.Thread(target=sim.run, args=(50.0, stop), daemon=True)
    thread.start()
    try:
        yield mcu.slave_path, gps.slave_path, sim
    finally:
        stop.set()
        thread.join()
        sim.close()
        mcu.close()
        gps.close()
