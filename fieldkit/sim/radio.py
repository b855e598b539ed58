"""The radio relay model of the simulator: who hears a packet, when, and from where.

ROSBuzz has no network simulation (docs/rosbuzz.md#no-network-simulation), so the simulator
brings its own. A packet a robot sends at tick t reaches every other robot within `range_m`
(a broadcast medium, as the field's XBee and WiFi radios are), except where its link drops
it, after `latency` ticks plus 0..`jitter` more (uniform, so packets may overtake each
other).

Losses, per directed link (sender -> receiver), are either

* constant: each packet is lost with probability `drop`, independently; or
* bursty (`GilbertElliott`): each link is a two-state Markov chain, good (G) or bad (B),
  stepped once per tick, losing a packet with probability `loss_good` or `loss_bad`
  according to its state at the tick it is sent; see `GilbertElliott.from_loss` for the
  chain of a given mean loss rate and mean burst length.

Each sender may put at most `bandwidth` bytes on the air per tick (the budget the simulator
drains its VM's outbox with; more raises ValueError), and every delivery is situated: it
carries the sender's position at send time, so the receiver computes range and bearing
from where the sender was, as ROSBuzz does from the packet's latitude and longitude.

Per tick: `set_positions(positions)`, then `broadcast(step, sender, data)` once per sender
(one opaque bundle, e.g. `fieldkit.robot.bundle.encode`), then `receptions(step)` gives each
broadcast with the robots receiving it, (sender, data, sender_position, receivers, note), or
`deliveries(step)` one (receiver, sender, data, sender_position) tuple per reception.

Speed, for thousands of robots: the hearers of every robot come from one query of a k-d
tree (scipy's cKDTree) built once per tick for the pairs within range, checked and sorted
in one numpy pass, so each sender costs about its own neighbours instead of all N; a
broadcast is queued once with its receivers, in per-tick buckets.
Reproducibility: every random draw comes from one `random.Random(seed)`, in a fixed order
(the order of the broadcast calls; within a broadcast, the loss draws of the receivers by
id, then the jitter draws of the survivors), so a run is bit for bit reproducible from its
seed provided the caller sends in a fixed order (e.g. by robot id).
"""

from __future__ import annotations

import heapq
import math
import random
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

Position = tuple[float, float, float]  # metres in a local frame: x east, y north, z up
#: One delivery: (receiver, sender, data, the sender's position when it sent).
Delivery = tuple[int, int, bytes, Position]
#: One broadcast as it arrives: (sender, data, sender's position, the receivers by id,
#: the sender's note: anything it attached to the broadcast, e.g. what it encoded).
Reception = tuple[int, bytes, Position, list[int], object]

_CANDIDATE_MARGIN = 1.0 + 1e-9


@dataclass(frozen=True)
class GilbertElliott:
    """A bursty loss process per directed link: a good/bad Markov chain stepped once per tick.

    Per tick, a good link turns bad with probability `p_gb` and a bad one turns good with
    `p_bg`; a packet sent in a tick is lost with `loss_good` or `loss_bad` by the link's
    state then. A new link (or one unused for a while) starts from the stationary
    distribution: P(bad) = p_gb / (p_gb + p_bg).
    """

    p_gb: float
    p_bg: float
    loss_good: float = 0.0
    loss_bad: float = 1.0

    def __post_init__(self) -> None:
        for name in ("p_gb", "p_bg", "loss_good", "loss_bad"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be a probability in [0, 1], got {value}")
        if self.p_bg == 0.0:
            raise ValueError("p_bg must be > 0: a bad state that never ends is a dead link")

    @classmethod
    def from_loss(
        cls,
        mean_loss: float,
        mean_burst: float,
        *,
        loss_good: float = 0.0,
        loss_bad: float = 1.0,
    ) -> GilbertElliott:
        """The chain with this mean loss rate and mean burst length (in ticks).

        With the defaults (the Gilbert model: the good state loses nothing, the bad state
        everything) a burst is a run of consecutive losses and a bad sojourn at once, so

            p_bg = 1 / mean_burst                       (bad sojourns are geometric)
            pi_B = mean_loss                            (stationary share of bad ticks)
            p_gb = p_bg * pi_B / (1 - pi_B)             (balance: pi_G p_gb = pi_B p_bg)

        which needs mean_burst >= 1 and p_gb <= 1, i.e. mean_loss <= mean_burst /
        (mean_burst + 1) (bursts need good ticks between them). With other state losses,
        mean_burst is the mean bad sojourn and pi_B = (mean_loss - loss_good) /
        (loss_bad - loss_good).
        """
        if not mean_burst >= 1.0:
            raise ValueError(f"mean_burst must be >= 1 tick, got {mean_burst}")
        if not loss_good <= mean_loss < loss_bad:
            raise ValueError(
                f"mean_loss must be in [loss_good, loss_bad) = [{loss_good}, {loss_bad}),"
                f" got {mean_loss}"
            )
        pi_bad = (mean_loss - loss_good) / (loss_bad - loss_good)
        p_bg = 1.0 / mean_burst
        p_gb = p_bg * pi_bad / (1.0 - pi_bad)
        if p_gb > 1.0:
            raise ValueError(
                f"mean loss {mean_loss} is unreachable with bursts of {mean_burst} ticks"
                f" (at most {mean_burst / (mean_burst + 1):.4f})"
            )
        return cls(p_gb, p_bg, loss_good, loss_bad)

    @property
    def bad_share(self) -> float:
        """The stationary probability of the bad state."""
        return self.p_gb / (self.p_gb + self.p_bg)

    @property
    def mean_loss(self) -> float:
        """The long-run share of packets lost."""
        pi_bad = self.bad_share
        return pi_bad * self.loss_bad + (1.0 - pi_bad) * self.loss_good

    @property
    def mean_burst(self) -> float:
        """The mean bad sojourn in ticks (= the mean loss burst for the Gilbert defaults)."""
        return 1.0 / self.p_bg


@dataclass(frozen=True)
class LinkModel:
    """The properties of every link: range, loss, delay, and each sender's bandwidth."""

    range_m: float = math.inf
    drop: float = 0.0  # probability that one payload is lost on one link (constant loss)
    latency: int = 1  # steps from sending to the receiver's next inbox
    jitter: int = 0  # extra steps, uniform in 0..jitter
    bursts: GilbertElliott | None = None  # bursty loss instead of `drop`
    bandwidth: int | None = None  # bytes a robot may put on the air per step; None: no limit

    def __post_init__(self) -> None:
        if not 0.0 <= self.drop <= 1.0:
            raise ValueError(f"drop must be a probability in [0, 1], got {self.drop}")
        if self.latency < 1:
            raise ValueError(f"latency must be at least 1 step, got {self.latency}")
        if self.jitter < 0:
            raise ValueError(f"jitter must be >= 0, got {self.jitter}")
        if not self.range_m > 0:
            raise ValueError(f"range_m must be > 0, got {self.range_m}")
        if self.bursts is not None and self.drop:
            raise ValueError("give either a constant drop or Gilbert-Elliott bursts, not both")
        if self.bandwidth is not None and self.bandwidth < 1:
            raise ValueError(f"bandwidth must be >= 1 byte per step, got {self.bandwidth}")

    @classmethod
    def bursty(
        cls,
        mean_loss: float,
        mean_burst: float,
        *,
        range_m: float = math.inf,
        latency: int = 1,
        jitter: int = 0,
        bandwidth: int | None = None,
    ) -> LinkModel:
        """A model with Gilbert-Elliott losses of this mean rate and mean burst length (ticks)."""
        bursts = GilbertElliott.from_loss(mean_loss, mean_burst)
        return cls(
            range_m=range_m, latency=latency, jitter=jitter, bursts=bursts, bandwidth=bandwidth
        )


def distance(a: Position, b: Position) -> float:
    """Euclidean distance between two positions."""
    return math.dist(a, b)


class RadioModel:
    """Carries packets between robots according to a `LinkModel`, reproducibly from `seed`."""

    def __init__(self, model: LinkModel, seed: int) -> None:
        self.model = model
        self.rng = random.Random(seed)
        self.sent = 0  # packets sent (a payload or a broadcast counts once, not per hearer)
        self.delivered = 0  # receptions handed out by receptions() and deliveries()
        self.dropped = 0  # receptions lost on their link
        self.distance_checks = 0  # distances computed to find hearers (the tree's candidates)
        self.bytes_sent: dict[int, int] = {}  # robot -> bytes put on the air, all steps
        self._positions: dict[int, Position] = {}
        self._everyone: list[tuple[int, Position]] = []  # (id, position) by id
        self._points = np.empty((0, 3))  # the positions of _everyone, in order
        self._tree: cKDTree | None = None
        self._heard_by: dict[int, list[int]] | None = None  # robot -> its hearers, by id
        self._buckets: dict[int, list[Reception]] = {}  # due step -> receptions, in send order
        self._due: list[int] = []  # heap of the keys of _buckets
        self._links: dict[int, dict[int, int]] = {}  # sender -> receiver -> 2 * tick + bad
        self._bytes_step: int | None = None
        self._step_bytes: dict[int, int] = {}  # robot -> bytes in step _bytes_step
        self._histogram: Counter[int] = Counter()  # bytes per step -> (robot, step) count

    # ------------------------------------------------------------------ geometry

    def in_range(self, a: Position, b: Position) -> bool:
        """Whether two robots at these positions can hear each other."""
        return distance(a, b) <= self.model.range_m

    def set_positions(self, positions: Mapping[int, Position]) -> None:
        """Where every robot is this tick (call once per tick, before the broadcasts)."""
        everyone = sorted(positions.items())
        points = np.array([p for _, p in everyone], dtype=np.float64).reshape(-1, 3)
        if not np.isfinite(points).all():
            rid, p = everyone[int(np.flatnonzero(~np.isfinite(points).all(axis=1))[0])]
            raise ValueError(f"robot {rid} has a non-finite position {p}")
        self._positions = dict(positions)
        self._everyone = everyone
        self._points = points
        self._tree = None  # built on the first question of the tick
        self._heard_by = None

    def _candidates(self) -> cKDTree | None:
        """The k-d tree of this tick's positions (None when the range is unbounded)."""
        if self._tree is None and self._everyone and math.isfinite(self.model.range_m):
            self._tree = cKDTree(self._points)
        return self._tree

    def _within(self, position: Position, exclude: int | None, near: Sequence[int]) -> list[int]:
        """The robots of `near` (indices into the id-sorted list, ascending) within range of
        `position`, by id; the exact test decides, the tree only narrows the candidates."""
        self.distance_checks += len(near)
        r = self.model.range_m
        dist = math.dist
        return [
            rid
            for rid, p in map(self._everyone.__getitem__, near)
            if rid != exclude and dist(position, p) <= r
        ]

    def hearers(self, position: Position, exclude: int | None = None) -> list[int]:
        """The robots (by id, ascending) within range of `position` at the last set_positions."""
        tree = self._candidates()
        if tree is None:
            return self._within(position, exclude, range(len(self._everyone)))
        # A hair wider than the range, so float rounding in the tree's squared distances
        # cannot lose a robot that the exact test keeps.
        near = tree.query_ball_point(position, self.model.range_m * _CANDIDATE_MARGIN)
        near.sort()
        return self._within(position, exclude, near)

    def _hearers_of(self, robot: int) -> list[int]:
        """hearers(position of `robot`, robot), from the whole tick's lists (do not modify)."""
        if self._heard_by is None:
            if self._candidates() is None:
                return self.hearers(self._positions[robot], robot)
            self._heard_by = self._all_hearers()
        return self._heard_by[robot]

    def _all_hearers(self) -> dict[int, list[int]]:
        """Every robot's hearers this tick, by id, in one numpy pass over the tree's pairs."""
        tree = self._tree
        assert tree is not None
        r = self.model.range_m
        pairs = tree.query_pairs(r * _CANDIDATE_MARGIN, output_type="ndarray")
        self.distance_checks += 2 * len(pairs)
        first, second = pairs[:, 0], pairs[:, 1]
        d = tree.data[first] - tree.data[second]
        dist = np.sqrt(np.einsum("ij,ij->i", d, d))
        keep = dist <= r
        # The exact test is math.dist's (as `hearers`): numpy's distance may differ from it
        # in the last bits, so it decides the few pairs that close to the range.
        everyone = self._everyone
        for k in np.flatnonzero(np.abs(dist - r) <= 1e-9 * r).tolist():
            i, j = pairs[k].tolist()
            keep[k] = math.dist(everyone[i][1], everyone[j][1]) <= r
        first, second = first[keep], second[keep]
        # Each kept pair hears both ways; sorted by (listener, speaker) index, which is id
        # order since `_everyone` is sorted by id.
        listener = np.concatenate((first, second))
        speaker = np.concatenate((second, first))
        order = np.lexsort((speaker, listener))
        ids = np.fromiter((rid for rid, _ in everyone), dtype=np.int64, count=len(everyone))
        heard = ids[speaker[order]].tolist()
        ends = np.cumsum(np.bincount(listener, minlength=len(everyone))).tolist()
        out = {}
        start = 0
        for (rid, _), end in zip(everyone, ends, strict=True):
            out[rid] = heard[start:end]
            start = end
        return out

    def neighbors(self, robot: int) -> list[int]:
        """The robots `robot` can hear at its position of the last set_positions, by id."""
        return list(self._hearers_of(robot))

    # ------------------------------------------------------------------ losses

    def _survivors(self, step: int, sender: int, hearers: Sequence[int]) -> list[int]:
        """The hearers whose link keeps a packet sent at `step`; draws in hearer order."""
        model = self.model
        rnd = self.rng.random
        ge = model.bursts
        if ge is None:
            drop = model.drop
            return [r for r in hearers if not rnd() < drop] if drop else list(hearers)
        links = self._links.get(sender)
        if links is None:
            links = self._links[sender] = {}
        p_gb = ge.p_gb
        stay_bad = 1.0 - ge.p_bg
        pi_bad = ge.bad_share
        fade = 1.0 - ge.p_gb - ge.p_bg
        loss_good = ge.loss_good
        loss_bad = ge.loss_bad
        tick = 2 * step
        kept = []
        for r in hearers:
            # The link's state now, from its state when it last carried a packet.
            state = links.get(r)
            if state is None:
                p_bad = pi_bad  # a new link starts from the stationary law
            else:
                bad = state & 1
                n = step - (state >> 1)
                if n == 1:
                    p_bad = stay_bad if bad else p_gb
                elif n <= 0:
                    p_bad = bad  # another packet in the same tick: same state
                else:
                    # n steps at once: the distance to the stationary law shrinks by `fade`
                    # per step.
                    p_bad = pi_bad + (bad - pi_bad) * fade**n
            bad = 1 if p_bad >= 1.0 else 0 if p_bad <= 0.0 else int(rnd() < p_bad)
            links[r] = tick + bad
            loss = loss_bad if bad else loss_good
            if loss >= 1.0 or (loss > 0.0 and rnd() < loss):
                continue
            kept.append(r)
        return kept

    # ------------------------------------------------------------------ bytes

    def _account(self, step: int, sender: int, nbytes: int) -> None:
        """Count `nbytes` on the air for `sender` at `step`; ValueError over the bandwidth."""
        if step != self._bytes_step:
            self._fold()
            self._bytes_step = step
        used = self._step_bytes.get(sender, 0) + nbytes
        limit = self.model.bandwidth
        if limit is not None and used > limit:
            raise ValueError(
                f"robot {sender} would put {used} bytes on the air in step {step},"
                f" over its bandwidth of {limit}"
            )
        self._step_bytes[sender] = used
        self.bytes_sent[sender] = self.bytes_sent.get(sender, 0) + nbytes

    def _fold(self) -> None:
        self._histogram.update(self._step_bytes.values())
        self._step_bytes = {}

    def room(self, step: int, sender: int) -> int | None:
        """Bytes `sender` may still send in `step` (None: no bandwidth limit)."""
        limit = self.model.bandwidth
        if limit is None:
            return None
        return limit - (self._step_bytes.get(sender, 0) if step == self._bytes_step else 0)

    def step_bytes(self) -> dict[int, int]:
        """Bytes each robot put on the air in the latest step anyone sent in."""
        return dict(self._step_bytes)

    def air_histogram(self) -> dict[int, int]:
        """{bytes sent in one step: number of (robot, step) pairs}, over robots that sent."""
        out = self._histogram.copy()
        out.update(self._step_bytes.values())
        return dict(sorted(out.items()))

    # ------------------------------------------------------------------ one bundle a tick

    def broadcast(
        self,
        step: int,
        sender: int,
        data: bytes,
        position: Position | None = None,
        note: object = None,
    ) -> None:
        """Put `data` on the air from `sender` at `step`, heard from `position`.

        The hearers are the robots of the last set_positions within range of `position`
        (default: the sender's position there); every delivery carries it, and each
        reception the `note` (not on the air: e.g. the decoded form of `data`, so that
        receivers need not parse it). Raises ValueError beyond the sender's bandwidth
        (nothing sent), RuntimeError before any set_positions.
        """
        if not self._everyone:
            # Without positions nobody would hear anything: a silent trap, so refuse.
            raise RuntimeError("call set_positions() before broadcast()")
        if position is None:
            position = self._positions[sender]  # KeyError before anything is counted
            hearers = self._hearers_of(sender)
        else:
            hearers = self.hearers(position, sender)
        self._account(step, sender, len(data))
        self.sent += 1
        model = self.model
        kept = (
            self._survivors(step, sender, hearers)
            if model.drop or model.bursts is not None
            else hearers
        )
        self.dropped += len(hearers) - len(kept)
        due = step + model.latency
        if not model.jitter:
            if kept:
                self._bucket(due).append((sender, data, position, kept, note))
            return
        rnd = self.rng.random
        span = model.jitter + 1
        slots: list[list[int]] = [[] for _ in range(span)]
        for r in kept:
            slots[int(rnd() * span)].append(r)
        for k, receivers in enumerate(slots):
            if receivers:
                self._bucket(due + k).append((sender, data, position, receivers, note))

    def _bucket(self, due: int) -> list[Reception]:
        bucket = self._buckets.get(due)
        if bucket is None:
            bucket = self._buckets[due] = []
            heapq.heappush(self._due, due)
        return bucket

    def receptions(self, step: int) -> list[Reception]:
        """Pop every broadcast due by `step` with the robots receiving it then, in send order:
        (sender, data, sender_position, receivers by id, note). Do not modify the lists."""
        due = self._due
        if not due or due[0] > step:
            return []
        out: list[Reception] = []
        buckets = self._buckets
        while due and due[0] <= step:
            out += buckets.pop(heapq.heappop(due))
        self.delivered += sum(len(e[3]) for e in out)
        return out

    def deliveries(self, step: int) -> list[Delivery]:
        """Pop every (receiver, sender, data, sender_position) due by `step`, in send order."""
        return [(r, s, d, p) for s, d, p, receivers, _ in self.receptions(step) for r in receivers]

    @property
    def in_flight(self) -> int:
        """Deliveries queued and not yet due."""
        return sum(len(e[3]) for bucket in self._buckets.values() for e in bucket)
