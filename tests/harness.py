"""A test rig: many bare Buzz VMs in one process, stepped in lock step over a radio model.

    h = Harness(bvm.compile_file("gossip.bzz"), robot_ids=range(10),
                positions=line(10, spacing=10.0), link=LinkModel(range_m=15.0, drop=0.5),
                seed=1)
    h.run(100)
    h.vms[3]["value"]

Unlike the simulator (whose robots are `fieldkit.robot.RobotRuntime`s, with script API,
supervisor and vehicles), this steps bare VMs and sends each Buzz message as its own packet:
what the swarm primitives' tests need (gossip, stigmergy, barriers) without a robot around
them. Each step: take the payloads that arrived, apply them, refresh the neighbours (the
robots in range now, through the robots' one geometry, `fieldkit.robot.neighbors`), run
`step()`, and hand this step's messages to the radio within a byte budget. A robot whose
script fails is stopped and its error kept; the others go on.
"""

from __future__ import annotations

import heapq
import itertools
import logging
from collections.abc import Callable, Iterable, Mapping

import bvm
from bvm.errors import BuzzError
from fieldkit.robot import neighbors as nb
from fieldkit.sim.radio import LinkModel, Position, RadioModel

_log = logging.getLogger("fieldkit.sim")


def line(n: int, spacing: float) -> dict[int, Position]:
    """Robots 0..n-1 on a line along x, `spacing` metres apart."""
    return {i: (i * spacing, 0.0, 0.0) for i in range(n)}


class MessageRadio(RadioModel):
    """The radio model carrying single Buzz messages instead of bundles: per payload and
    receiver, the loss draw then the jitter draw, in send order (seeded runs replay)."""

    def __init__(self, model: LinkModel, seed: int) -> None:
        super().__init__(model, seed)
        self._in_flight: list[tuple[int, int, int, int, bytes]] = []  # (due, seq, to, from, p)
        self._seq = itertools.count()
        self._grid_source: tuple[int, int] | None = None  # (id(positions), step)

    def _lost(self, step: int, sender: int, receiver: int) -> bool:
        """Whether one packet from `sender` to `receiver` sent at `step` is lost (draws)."""
        model = self.model
        if model.bursts is None:
            return bool(model.drop) and self.rng.random() < model.drop
        return not self._survivors(step, sender, (receiver,))

    def transmit(
        self,
        step: int,
        sender: int,
        payloads: Iterable[bytes],
        positions: Mapping[int, Position],
    ) -> None:
        """Send `payloads` from `sender` at `step` to everyone in range.

        `positions` must not change within a step: its positions are set on the first call
        of the step and reused by the other senders.
        """
        payloads = list(payloads)
        self._account(step, sender, sum(map(len, payloads)))
        if self._grid_source != (id(positions), step):
            self.set_positions(positions)
            self._grid_source = (id(positions), step)
        model = self.model
        rng = self.rng
        hearers = self.hearers(positions[sender], sender)
        for payload in payloads:
            self.sent += 1
            for r in hearers:
                if self._lost(step, sender, r):
                    self.dropped += 1
                    continue
                due = step + model.latency + (rng.randint(0, model.jitter) if model.jitter else 0)
                heapq.heappush(self._in_flight, (due, next(self._seq), r, sender, payload))

    def arrivals(self, step: int) -> list[tuple[int, int, bytes]]:
        """Pop every (receiver, sender, payload) due at or before `step`, in send order."""
        out = []
        flight = self._in_flight
        while flight and flight[0][0] <= step:
            _, _, r, s, payload = heapq.heappop(flight)
            out.append((r, s, payload))
        self.delivered += len(out)
        return out

    @property
    def in_flight(self) -> int:
        """Deliveries queued and not yet due (bundles and single messages)."""
        return super().in_flight + len(self._in_flight)


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
        self.radio = MessageRadio(link or LinkModel(), seed)
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

    def neighbors_of(self, rid: int) -> nb.Columns:
        """(ids, distances, azimuths) of the robots `rid` can hear now."""
        here = self.positions[rid]
        heard: nb.HeardTable = {
            other: (self.positions[other][0], self.positions[other][1], 0)
            for other in self.ids
            if other != rid and self.radio.in_range(here, self.positions[other])
        }
        return nb.columns([heard], [(here[0], here[1])], 0, 0)[0]

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
            vm.set_neighbor_columns(*self.neighbors_of(rid))
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


class QuietHarness(Harness):
    """The harness without neighbour tables, for scripts that read none (a barrier): a
    large grid's would cost O(N^2) a step. The radio still decides who hears whom."""

    EMPTY: nb.Columns = nb.columns([{}], [(0.0, 0.0)], 0, 0)[0]

    def neighbors_of(self, rid: int) -> nb.Columns:
        """No neighbours."""
        return self.EMPTY
