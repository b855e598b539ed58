"""Many Buzz VMs in one process, stepped in lock step over a simulated radio.

    h = Harness(bvm.compile_file("gossip.bzz"), robot_ids=range(10),
                positions=line(10, spacing=10.0), link=LinkModel(range_m=15.0, drop=0.5),
                seed=1)
    h.run(100)
    h.vms[3]["value"]

Each step, every robot does what the field node does, in the same order (spec wire §10.6):
take the payloads that arrived, apply them, refresh its neighbors (the robots in range,
with distance and azimuth), run `step()`, and hand this step's messages to the radio,
within a byte budget. A robot whose script fails is stopped and its error kept; the others
go on.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping

import bvm
from bvm.errors import BuzzError
from fieldkit.sim.radio import LinkModel, Position, Radio, bearing

_log = logging.getLogger("fieldkit.sim")


def line(n: int, spacing: float) -> dict[int, Position]:
    """Robots 0..n-1 on a line along x, `spacing` metres apart."""
    return {i: (i * spacing, 0.0, 0.0) for i in range(n)}


class Harness:
    """N robots running one program over a `Radio`."""

    def __init__(
        self,
        program: bvm.Program,
        robot_ids: Iterable[int],
        *,
        positions: Mapping[int, Position] | None = None,
        link: LinkModel | None = None,
        seed: int = 0,
        budget_bytes: int | None = None,
        overhead: int = 0,
        setup: Callable[[int, bvm.VM], None] | None = None,
    ) -> None:
        """`setup(robot_id, vm)` runs before the global code (to register host functions)."""
        self.ids = sorted(set(robot_ids))
        self.positions: dict[int, Position] = dict(
            positions if positions is not None else {i: (0.0, 0.0, 0.0) for i in self.ids}
        )
        missing = [i for i in self.ids if i not in self.positions]
        if missing:
            raise ValueError(f"no position for robots {missing}")
        self.radio = Radio(link or LinkModel(), seed)
        self.budget_bytes = budget_bytes
        self.overhead = overhead
        self.step_count = 0
        self.errors: dict[int, BuzzError] = {}
        self.vms: dict[int, bvm.VM] = {}
        for rid in self.ids:
            vm = bvm.VM(robot_id=rid, rng_seed=seed * 65536 + rid)
            vm.load(program)
            if setup is not None:
                setup(rid, vm)
            self.vms[rid] = vm
            self._guard(rid, vm.execute)
            if "init" in vm.buzz_globals():
                self._guard(rid, lambda vm=vm: vm.call("init"))

    def _guard(self, rid: int, action: Callable[[], object]) -> None:
        if rid in self.errors:
            return
        try:
            action()
        except BuzzError as e:
            self.errors[rid] = e
            _log.error("robot %d stopped: %s", rid, e)

    def neighbors_of(self, rid: int) -> list[tuple[int, float, float, float]]:
        """(id, distance, azimuth, elevation) of the robots `rid` can hear now."""
        here = self.positions[rid]
        out = []
        for other in self.ids:
            if other != rid and self.radio.in_range(here, self.positions[other]):
                dist, azimuth = bearing(here, self.positions[other])
                out.append((other, dist, azimuth, 0.0))
        return out

    def step(self) -> None:
        """One step of every robot, then the radio carries what they sent."""
        t = self.step_count
        for receiver, sender, payload in self.radio.arrivals(t):
            if receiver not in self.errors:
                self.vms[receiver].receive(sender, payload)
        outgoing: dict[int, list[bytes]] = {}
        for rid in self.ids:
            vm = self.vms[rid]
            self._guard(rid, vm.process_inbox)
            vm.set_neighbors(self.neighbors_of(rid))
            self._guard(rid, lambda vm=vm: vm.call("step"))
            if rid not in self.errors:
                outgoing[rid] = vm.drain_outbox(self.budget_bytes, self.overhead)
        for rid, payloads in outgoing.items():
            self.radio.transmit(t, rid, payloads, self.positions)
        self.step_count += 1

    def run(self, steps: int) -> None:
        """Run `steps` steps."""
        for _ in range(steps):
            self.step()
