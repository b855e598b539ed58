"""Rigs for the DJI M100 backend: the simulated flight controller and the host, in lockstep.

- `DjiMemoryRig`: `SimM100` and `DjiCore` passing bytes in memory;
- `DjiPtyRig`: `SimM100Vehicle` and `DjiLink` on the two ends of a real pty.

Both step on a simulated clock (50 Hz by default: DJI's movement-control rate), in the same
order as the MAVLink rigs (`rigs.MemoryRig`, `rigs.SimRig`), so a scenario runs the same way
through either; the pty rig waits on bytes with a wall-clock deadline, never on time.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from fieldkit.robot.profiles import Profile, load_profile
from fieldkit.vehicle.dji.core import DjiCore
from fieldkit.vehicle.dji.link import DjiLink
from fieldkit.vehicle.pty import open_pty
from fieldkit.vehicle.sim.dji import TEST_APP_ID, TEST_APP_KEY, SimM100
from fieldkit.vehicle.sim.dji_vehicle import SimM100Vehicle

#: Where the DJI rigs' aircraft start.
DJI_HOME = (45.5049, -73.6133)


class _Stepped:
    dt: float
    now: float

    def tick(self) -> None:
        """One step of the flight controller and the host."""
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


class DjiMemoryRig(_Stepped):
    """A `SimM100` and a `DjiCore` passing bytes in memory, stepped in lockstep."""

    def __init__(
        self,
        profile: str | Profile = "m100",
        *,
        dt: float = 0.02,
        app_id: int = TEST_APP_ID,
        app_key: str = TEST_APP_KEY,
        core_options: dict[str, Any] | None = None,
        **sim_options: Any,
    ) -> None:
        """A SimM100 (with `sim_options`, home DJI_HOME) and a DjiCore with `app_id`/`app_key`."""
        self.profile = load_profile(profile) if isinstance(profile, str) else profile
        self.dt = dt
        self.now = 0.0
        sim_options.setdefault("home", DJI_HOME)
        self.sim = SimM100(self.profile, **sim_options)
        self.core = DjiCore(
            app_id=app_id,
            app_key=app_key,
            profile=self.profile,
            clock=self.clock,
            **(core_options or {}),
        )

    def tick(self) -> None:
        """The FC takes what the host wrote, steps; the host reads, ticks; the FC reads."""
        self.sim.receive_data(self.core.data_to_send())
        self.sim.step(self.dt)
        self.now += self.dt
        self.core.receive_data(self.sim.data_to_send())
        self.core.tick()
        self.sim.receive_data(self.core.data_to_send())

    def connect(self, timeout_s: float = 10.0) -> None:
        """Activated and holding control authority."""
        assert self.run_until(lambda: self.core.activated, timeout_s), self.core.activation_error
        cmd = self.core.obtain_control()
        assert self.run_until(lambda: cmd.done, timeout_s) and cmd.ok, cmd


class DjiPtyRig(_Stepped):
    """A `SimM100Vehicle` and a `DjiLink` on the two ends of a pty, stepped in lockstep."""

    def __init__(
        self,
        profile: str | Profile = "m100",
        *,
        dt: float = 0.02,
        sync_timeout_s: float = 5.0,
        app_id: int = TEST_APP_ID,
        app_key: str = TEST_APP_KEY,
        link_options: dict[str, Any] | None = None,
        **sim_options: Any,
    ) -> None:
        """Open a pty, put the simulated FC and the host's link on it."""
        self.profile = load_profile(profile) if isinstance(profile, str) else profile
        self.dt = dt
        self.now = 0.0
        self.sync_timeout_s = sync_timeout_s
        sim_options.setdefault("home", DJI_HOME)
        self.pty = open_pty()
        try:
            self.sim = SimM100Vehicle(self.profile, self.pty.master, **sim_options)
            options: dict[str, Any] = {"release_on_close": False, **(link_options or {})}
            self.link = DjiLink(
                self.pty.slave_path,
                app_id=app_id,
                app_key=app_key,
                profile=self.profile,
                clock=self.clock,
                **options,
            )
        except BaseException:
            self.pty.close()
            raise

    def tick(self) -> None:
        """One step of the FC and one poll of the link, every byte delivered both ways."""
        self.sim.step(self.dt)
        self.now += self.dt
        deadline = time.monotonic() + self.sync_timeout_s
        self.link.poll()
        while self.link.core.bytes_received < self.sim.bytes_sent:
            self._check(deadline, "FC -> host")
            self.link.poll(0.1)
        while self.sim.bytes_received < self.link.bytes_written:
            self._check(deadline, "host -> FC")
            self.sim.service(0.1)

    def _check(self, deadline: float, way: str) -> None:
        if time.monotonic() > deadline:
            raise TimeoutError(
                f"{way}: bytes not delivered after {self.sync_timeout_s:g} s (FC sent "
                f"{self.sim.bytes_sent}, host read {self.link.core.bytes_received}; host wrote "
                f"{self.link.bytes_written}, FC read {self.sim.bytes_received})"
            )

    def close(self) -> None:
        """Close the link, the FC's line and the pty."""
        self.link.close()
        self.sim.close()
        self.pty.close()

    def __enter__(self) -> DjiPtyRig:
        """Use as a context manager: closed on exit."""
        return self

    def __exit__(self, *exc: object) -> None:
        """Close everything."""
        self.close()
