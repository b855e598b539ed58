"""The radio delivery model of the simulator: who hears a message, and when.

Each payload a robot sends at step t reaches every other robot within `range_m` (a
broadcast medium, as the XBee and WiFi radios of the field are), except where the link
drops it, after `latency` steps plus up to `jitter` more. Drops and jitter draw from one
seeded `random.Random`, in a fixed order (senders by id, payloads in send order, receivers
by id), so a run is reproducible bit for bit from its seed.
"""

from __future__ import annotations

import heapq
import itertools
import math
import random
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

Position = tuple[float, float, float]  # metres in a local frame: x east, y north, z up


@dataclass(frozen=True)
class LinkModel:
    """The properties of every link: communication range, loss and delay."""

    range_m: float = math.inf
    drop: float = 0.0  # probability that one payload is lost on one link
    latency: int = 1  # steps from sending to the receiver's next inbox
    jitter: int = 0  # extra steps, uniform in 0..jitter

    def __post_init__(self) -> None:
        if not 0.0 <= self.drop <= 1.0:
            raise ValueError(f"drop must be a probability in [0, 1], got {self.drop}")
        if self.latency < 1:
            raise ValueError(f"latency must be at least 1 step, got {self.latency}")
        if self.jitter < 0:
            raise ValueError(f"jitter must be >= 0, got {self.jitter}")
        if not self.range_m > 0:
            raise ValueError(f"range_m must be > 0, got {self.range_m}")


def distance(a: Position, b: Position) -> float:
    """Euclidean distance between two positions."""
    return math.dist(a, b)


def bearing(origin: Position, target: Position) -> tuple[float, float]:
    """(distance in the horizontal plane, azimuth) of `target` seen from `origin`.

    Azimuth in radians from north, positive toward east, as ROSBuzz computes it (spec wire
    §6.1); the field sees altitude only through the autopilot, so elevation is left to 0.
    """
    east = target[0] - origin[0]
    north = target[1] - origin[1]
    return math.hypot(east, north), math.atan2(east, north)


class Radio:
    """Carries payloads between robots according to a `LinkModel`."""

    def __init__(self, model: LinkModel, seed: int) -> None:
        self.model = model
        self.rng = random.Random(seed)
        self._in_flight: list[tuple[int, int, int, int, bytes]] = []  # (due, seq, to, from, p)
        self._seq = itertools.count()
        self.sent = 0
        self.delivered = 0
        self.dropped = 0

    def in_range(self, a: Position, b: Position) -> bool:
        """Whether two robots at these positions can hear each other."""
        return distance(a, b) <= self.model.range_m

    def transmit(
        self,
        step: int,
        sender: int,
        payloads: Iterable[bytes],
        positions: Mapping[int, Position],
    ) -> None:
        """Send `payloads` from `sender` at `step` to everyone in range."""
        model = self.model
        rng = self.rng
        here = positions[sender]
        hearers = [
            r for r in sorted(positions) if r != sender and self.in_range(here, positions[r])
        ]
        for payload in payloads:
            self.sent += 1
            for r in hearers:
                if model.drop and rng.random() < model.drop:
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
