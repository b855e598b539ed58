"""The ground station on a radio: a real one (`run_on_radio`), a simulated swarm's
(`SimGround`, a peer of `fieldkit.sim.simulator.Simulation`), and the UDP gateway that puts a
simulated radio on the machine's loopback so that `fieldkit cmd` and `fieldkit update` reach
a simulated swarm as they reach a real one.
"""

from __future__ import annotations

import math
import random
import socket
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from fieldkit.ground.core import GroundStation
from fieldkit.radio.udp import LOOPBACK_BROADCAST, pack_datagram, unpack_datagram

if TYPE_CHECKING:
    from fieldkit.radio.base import RadioLink
    from fieldkit.sim.simulator import Simulation

Position = tuple[float, float, float]


def run_on_radio(
    station: GroundStation,
    radio: RadioLink,
    *,
    until: Callable[[], bool],
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    rate_hz: float = 10.0,
) -> None:
    """Drive `station` on `radio` at `rate_hz` until `until()`: what the radio heard in,
    the station's frames out. Hostile input never raises (the core counts it)."""
    start = clock()
    k = 0
    while not until():
        now = clock()  # the station's time is the clock's: a second run goes on from it
        for sender, data in radio.poll():
            station.hear(data, now, sender)
        for frame in station.tick(now):
            radio.send(frame)
        k += 1
        delay = start + k / rate_hz - clock()
        if delay > 0:
            sleep(delay)


class UdpGateway:
    """A simulated radio's window onto UDP: what a station at the gateway's place hears goes
    out as datagrams (`fieldkit.radio.udp` format, the sender's robot id), and datagrams
    from other radios on the port are sent into the simulation from that place."""

    def __init__(self, port: int = 0, group: str = LOOPBACK_BROADCAST) -> None:
        """`port` 0 takes a free one (see `url`)."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if hasattr(socket, "SO_REUSEPORT"):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            sock.bind((group, port))
            sock.setblocking(False)
        except OSError:
            sock.close()
            raise
        self.sock = sock
        self.group = group
        self.port = sock.getsockname()[1]
        self.tag = random.SystemRandom().getrandbits(32)
        self.counters: dict[str, int] = {"out": 0, "in": 0, "bad": 0}

    @property
    def url(self) -> str:
        """The radio URL other programs give (`--radio`)."""
        return f"udp://{self.group}:{self.port}"

    def send(self, sender: int, data: bytes) -> None:
        """A frame robot `sender` put on the simulated air, out to UDP."""
        try:
            self.sock.sendto(pack_datagram(sender, self.tag, data), (self.group, self.port))
            self.counters["out"] += 1
        except OSError:
            self.counters["bad"] += 1

    def poll(self) -> list[bytes]:
        """Frames other radios sent on the port since the last poll (our own echo dropped)."""
        out = []
        for _ in range(1024):
            try:
                datagram = self.sock.recv(65536)
            except BlockingIOError:
                break
            except OSError:
                self.counters["bad"] += 1
                continue
            got = unpack_datagram(datagram)
            if got is None:
                self.counters["bad"] += 1
                continue
            _robot, tag, data = got
            if tag == self.tag:
                continue
            self.counters["in"] += 1
            out.append(data)
        return out

    def close(self) -> None:
        """Close the socket."""
        self.sock.close()


class SimGround:
    """A ground station (and optionally a UDP gateway) at one place in a simulated swarm,
    with the swarm's radio range: it hears the robots in range, and the robots in range
    hear it. A `Simulation` peer (`Simulation.peers`)."""

    def __init__(
        self,
        sim: Simulation,
        station: GroundStation,
        position: Position,
        *,
        gateway: UdpGateway | None = None,
        range_m: float | None = None,
    ) -> None:
        self.sim = sim
        self.station = station
        self.position = position
        self.gateway = gateway
        self.range_m = sim.radio.model.range_m if range_m is None else range_m
        self._out: list[bytes] = []

    def _in_range(self, where: Position) -> bool:
        return math.dist(where, self.position) <= self.range_m

    def overhear(self, t: int, sender: int, data: bytes, where: Position) -> None:
        """A frame robot `sender` sent from `where` at tick `t`."""
        if not data or not self._in_range(where):
            return
        self.station.hear(data, t * 0.1, sender)
        if self.gateway is not None:
            self.gateway.send(sender, data)

    def transmissions(self, t: int) -> list[tuple[bytes, list[int]]]:
        """The frames sent at tick `t` (the station's, and the gateway's), each with the
        robots in range."""
        frames = self.station.tick(t * 0.1)
        if self.gateway is not None:
            frames += self.gateway.poll()
        if not frames:
            return []
        hearers = [rid for rid, r in self.sim.robots.items() if self._in_range(r.vehicle.position)]
        return [(f, hearers) for f in frames]


__all__ = ["SimGround", "UdpGateway", "run_on_radio"]
