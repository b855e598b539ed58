"""A swarm with its ground station, in real time: `fieldkit sim run --ground`, `fieldkit sitl
--ground`.

The simulation steps at 10 Hz of wall time (a tick every 0.1 s; a swarm too big to keep up
runs as fast as it can, and the page's clock says how far behind), a `SimGround` beside
robot 1 hears and commands the robots in range, a `UdpGateway` puts that place on the
machine's loopback (`fieldkit cmd`, `fieldkit update --radio`), and the page is served on
localhost while it runs. `fieldkit sitl --ground` makes the same station, page and gateway
(`make_station`, `serve`) and stands them beside robot 1 on its radio relay
(`fieldkit.sitl`), where real node processes hear and answer them.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fieldkit.ground.core import GroundStation
from fieldkit.ground.station import SimGround, UdpGateway
from fieldkit.ground.web import GroundServer
from fieldkit.robot.operator_command import SIGNER_SEQ_FILE, CommandSigner
from fieldkit.sim.simulator import TICK_S, Simulation

#: Where the ground station stands: this many metres west of robot 1's start.
BESIDE_M = 2.0


@dataclass
class LiveGround:
    """The ground station, its page and its gateway, beside a simulation (`peer`, for `sim
    run`) or a SITL swarm (which places it on its own radio)."""

    station: GroundStation
    server: GroundServer
    gateway: UdpGateway
    peer: SimGround | None = None

    def banner(self, keys: Path | None) -> list[str]:
        """The lines that tell the operator where the page and the gateway are."""
        url = self.gateway.url
        return [
            f"ground: page at {self.server.url}",
            f"ground: radio gateway {url} (fieldkit cmd takeoff --radio {url} --keys {keys})",
        ]

    def close(self) -> None:
        """Stop the page and close the gateway."""
        self.server.stop()
        self.gateway.close()


def make_station(
    keys: Path | None,
    *,
    swarm_key: bytes | None,
    operator_pub: Any,
    origin: tuple[float, float],
    profiles: Mapping[int, str] | None = None,
    default_profile: str | None = None,
    geofence: Sequence[tuple[float, float]] = (),
    shape: str | None = None,
    root_id: int = 1,
    margin: float = 20.0,
) -> GroundStation:
    """A ground station signing with `keys`/operator.key (None, or no such file: it only
    watches), checking the swarm's traffic with `swarm_key` (None: a plain swarm)."""
    from fieldkit.update.keys import load_signing_key

    signer = None
    if keys is not None and (keys / "operator.key").exists():
        signer = CommandSigner(load_signing_key(keys), keys / SIGNER_SEQ_FILE)
    return GroundStation(
        swarm_key=swarm_key,
        signer=signer,
        operator_pub=operator_pub,
        origin=origin,
        profiles=profiles,
        default_profile=default_profile,
        geofence=geofence,
        shape=shape,
        root_id=root_id,
        margin=margin,
    )


def serve(station: GroundStation, *, http_port: int = 8080, gateway_port: int = 0) -> LiveGround:
    """`station`'s page on 127.0.0.1:`http_port` (0: any free port), not started yet, and a
    UDP gateway on `gateway_port` (0: any free one); OSError if a port is taken."""
    gateway = UdpGateway(gateway_port)
    try:
        server = GroundServer(station, port=http_port)
    except OSError:
        gateway.close()
        raise
    return LiveGround(station, server, gateway)


def attach(
    sim: Simulation,
    keys: Path | None,
    *,
    http_port: int = 8080,
    gateway_port: int = 0,
    shape: str | None = None,
    root_id: int = 1,
    margin: float = 20.0,
) -> LiveGround:
    """A ground station beside robot 1 of `sim`, signing with `keys`/operator.key (None:
    watch only), its page on 127.0.0.1:`http_port` (0: any free port) and a UDP gateway
    (OSError if a port is taken)."""
    cfg = sim.config
    station = make_station(
        keys,
        swarm_key=cfg.swarm_key if cfg.security == "signed" else None,
        operator_pub=cfg.operator_pub,
        origin=(sim.frame.lat, sim.frame.lon),
        default_profile=sim.profile.name,
        geofence=sim.profile.geofence.polygon,
        shape=shape,
        root_id=root_id,
        margin=margin,
    )
    live = serve(station, http_port=http_port, gateway_port=gateway_port)
    first = sim.robots[min(sim.robots)].vehicle
    live.peer = SimGround(sim, station, (first.x - BESIDE_M, first.y, 0.0), gateway=live.gateway)
    sim.peers.append(live.peer)
    live.server.start()
    return live


def run_live(
    sim: Simulation,
    seconds: float | None,
    *,
    stop: threading.Event,
    after_step: Callable[[], None] | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> None:
    """Step `sim` at real time until `seconds` of it have run (None: until `stop` is set)."""
    total = None if seconds is None else round(seconds / TICK_S)
    start = clock()
    while not stop.is_set() and (total is None or sim.tick < total):
        sim.step()
        if after_step is not None:
            after_step()
        delay = start + sim.tick * TICK_S - clock()
        if delay > 0:
            stop.wait(delay)


__all__ = ["BESIDE_M", "LiveGround", "attach", "make_station", "run_live", "serve"]
