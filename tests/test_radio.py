"""The simulator's radio model (fieldkit.sim.radio): losses, delays, range, bandwidth, speed.

Statistical tests are seeded, and their tolerances are about five standard errors: they
pass reliably, and a model off by a few per cent fails them.
"""

from __future__ import annotations

import heapq
import itertools
import math
import random

import pytest
from harness import MessageRadio
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fieldkit.sim.radio import GilbertElliott, LinkModel, Position, RadioModel

FAST = settings(deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])


def cluster(n: int) -> dict[int, Position]:
    """Robot 0 and n others, all at one spot: every link in range."""
    return {i: (0.0, 0.0, 0.0) for i in range(n + 1)}


def loss_sequences(model: LinkModel, receivers: int, ticks: int, seed: int) -> list[list[bool]]:
    """Per receiver of robot 0's one broadcast a tick: whether each tick's packet was lost."""
    radio = RadioModel(model, seed)
    radio.set_positions(cluster(receivers))
    heard = [[True] * ticks for _ in range(receivers + 1)]
    for t in range(ticks):
        radio.broadcast(t, 0, b"x")
        for r, *_ in radio.deliveries(t + model.latency + model.jitter):
            heard[r][t] = False
    assert radio.dropped == sum(map(sum, heard[1:]))
    return heard[1:]


def bursts(lost: list[bool]) -> list[int]:
    """Lengths of the runs of consecutive losses."""
    return [len(list(g)) for k, g in itertools.groupby(lost) if k]


# ---------------------------------------------------------------- constant loss


def test_constant_drop_rate() -> None:
    seqs = loss_sequences(LinkModel(drop=0.3), receivers=100, ticks=2000, seed=1)
    n = 100 * 2000
    rate = sum(map(sum, seqs)) / n
    assert abs(rate - 0.3) < 5 * math.sqrt(0.3 * 0.7 / n)  # 0.005
    # Independent losses: bursts are geometric with mean 1 / (1 - p).
    runs = [b for s in seqs for b in bursts(s)]
    assert abs(sum(runs) / len(runs) - 1 / 0.7) < 0.03


def test_no_drop_no_draws() -> None:
    radio = RadioModel(LinkModel(), 5)
    radio.set_positions(cluster(10))
    state = radio.rng.getstate()
    radio.broadcast(0, 0, b"x")
    assert radio.rng.getstate() == state
    assert len(radio.deliveries(1)) == 10


# ---------------------------------------------------------------- Gilbert-Elliott


def test_gilbert_elliott_formulas() -> None:
    ge = GilbertElliott.from_loss(0.2, 5.0)
    assert ge.p_bg == pytest.approx(0.2)
    assert ge.p_gb == pytest.approx(0.05)  # 0.2 * 0.2 / 0.8
    assert ge.mean_loss == pytest.approx(0.2)
    assert ge.mean_burst == pytest.approx(5.0)
    elliott = GilbertElliott.from_loss(0.2, 4.0, loss_good=0.05, loss_bad=0.8)
    assert elliott.mean_loss == pytest.approx(0.2)
    assert elliott.bad_share == pytest.approx(0.15 / 0.75)
    assert GilbertElliott.from_loss(2 / 3, 2.0).p_gb == pytest.approx(1.0)  # the edge


@pytest.mark.parametrize(
    ("loss", "burst"), [(0.9, 2.0), (0.5, 0.5), (1.0, 5.0), (-0.1, 2.0), (0.1, math.nan)]
)
def test_gilbert_elliott_unreachable_parameters(loss: float, burst: float) -> None:
    with pytest.raises(ValueError):
        GilbertElliott.from_loss(loss, burst)


@pytest.mark.parametrize(("loss", "burst"), [(0.2, 5.0), (0.05, 2.0), (0.4, 10.0)])
def test_gilbert_elliott_mean_loss_and_burst(loss: float, burst: float) -> None:
    seqs = loss_sequences(LinkModel.bursty(loss, burst), receivers=50, ticks=6000, seed=2)
    rate = sum(map(sum, seqs)) / (50 * 6000)
    runs = [b for s in seqs for b in bursts(s)]
    mean_burst = sum(runs) / len(runs)
    # Correlated samples: the standard error of the rate grows with the burst length.
    ge = GilbertElliott.from_loss(loss, burst)
    fade = 1 - ge.p_gb - ge.p_bg
    se_rate = math.sqrt(loss * (1 - loss) * (1 + fade) / (1 - fade) / (50 * 6000))
    assert abs(rate - loss) < 5 * se_rate
    se_burst = math.sqrt(burst * (burst - 1) / len(runs))  # geometric runs
    assert abs(mean_burst - burst) < 5 * se_burst + 0.01
    # A constant loss of the same rate has much shorter bursts: the test tells them apart.
    assert 1 / (1 - loss) < burst - 5 * se_burst


def test_gilbert_elliott_skipped_ticks_use_the_n_step_law() -> None:
    """Sending every 3rd tick: P(lost | previous lost) = pi + (1 - pi) fade^3."""
    ge = GilbertElliott.from_loss(0.2, 5.0)
    radio = RadioModel(LinkModel(bursts=ge), 4)
    radio.set_positions(cluster(50))
    lost = [[] for _ in range(51)]
    for t in range(0, 3 * 4000, 3):
        radio.broadcast(t, 0, b"x")
        got = {r for r, *_ in radio.deliveries(t + 1)}
        for r in range(1, 51):
            lost[r].append(r not in got)
    pairs = [(a, b) for s in lost[1:] for a, b in itertools.pairwise(s)]
    after_loss = [b for a, b in pairs if a]
    p = sum(after_loss) / len(after_loss)
    want = 0.2 + 0.8 * (1 - ge.p_gb - ge.p_bg) ** 3  # 0.55
    assert abs(p - want) < 5 * math.sqrt(want * (1 - want) / len(after_loss))
    assert abs(p - (1 - ge.p_bg)) > 0.1  # not the one-step law


def test_packets_in_one_tick_share_the_link_state() -> None:
    """A bad link loses every packet of the tick (loss_bad = 1), a good one none."""
    radio = MessageRadio(LinkModel.bursty(0.5, 3.0), 9)
    radio.transmit(0, 0, [b"a", b"b", b"c"], cluster(200))
    got: dict[int, int] = {}
    for r, _, _ in radio.arrivals(1):
        got[r] = got.get(r, 0) + 1
    assert set(got.values()) == {3}
    assert 60 < len(got) < 140


def test_bursts_and_drop_are_exclusive() -> None:
    with pytest.raises(ValueError):
        LinkModel(drop=0.1, bursts=GilbertElliott(0.1, 0.5))
    with pytest.raises(ValueError):
        GilbertElliott(0.1, 0.0)


# ---------------------------------------------------------------- range, delay, position


def test_range_is_respected_including_the_boundary() -> None:
    radio = RadioModel(LinkModel(range_m=10.0), 0)
    radio.set_positions({i: (float(i * 5), 0.0, 0.0) for i in range(6)})  # 0, 5, ... 25 m
    radio.broadcast(0, 2, b"x")  # at 10 m: hears 0 (10 m), 1, 3, 4 (10 m)
    assert sorted(r for r, *_ in radio.deliveries(1)) == [0, 1, 3, 4]
    assert radio.neighbors(0) == [1, 2]
    assert radio.hearers((2.5, 9.0, 0.0)) == [0, 1]


def test_range_is_three_dimensional() -> None:
    radio = RadioModel(LinkModel(range_m=10.0), 0)
    radio.set_positions({0: (0.0, 0.0, 0.0), 1: (0.0, 0.0, 10.5), 2: (6.0, 0.0, 8.0)})
    assert radio.neighbors(0) == [2]


def test_hearers_on_the_range_circle_agree_with_the_exact_test() -> None:
    """Robots at the range, in every direction: the whole-tick hearers (numpy) decide each
    as the exact per-point test (math.dist) does, to the last bit."""
    rng = random.Random(3)
    r = 37.3
    points = {0: (0.0, 0.0, 0.0)}
    for i in range(1, 2001):
        a = rng.uniform(0.0, 2.0 * math.pi)
        points[i] = (r * math.cos(a), r * math.sin(a), rng.choice((0.0, 1e-7, -1e-7)))
    radio = RadioModel(LinkModel(range_m=r), 0)
    radio.set_positions(points)
    exact = [i for i in range(1, 2001) if math.dist(points[0], points[i]) <= r]
    assert 0 < len(exact) < 2000  # both sides of the boundary occur
    assert radio.neighbors(0) == exact == radio.hearers(points[0], 0)
    for i in (1, 500, 2000):
        assert radio.neighbors(i) == radio.hearers(points[i], i)


def test_receptions_group_each_broadcast_with_its_receivers() -> None:
    """receptions() and deliveries() are the same events, with the same random draws."""
    model = LinkModel(latency=1, jitter=2, drop=0.3)
    grouped, flat = RadioModel(model, 5), RadioModel(model, 5)
    got_grouped, got_flat = [], []
    for t in range(20):
        for radio in (grouped, flat):
            radio.set_positions(cluster(8))
            for sender in range(9):
                radio.broadcast(t, sender, bytes([t, sender]), note=(t, sender))
        for sender, data, where, receivers, note in grouped.receptions(t):
            assert receivers == sorted(receivers) and sender not in receivers
            assert note == tuple(data)  # what the sender attached, with its broadcast
            got_grouped += [(r, sender, data, where) for r in receivers]
        got_flat += flat.deliveries(t)
    assert got_grouped == got_flat and len(got_flat) > 500
    assert grouped.delivered == flat.delivered == len(got_flat)
    assert grouped.in_flight == flat.in_flight > 0


def test_latency_and_jitter() -> None:
    radio = RadioModel(LinkModel(latency=3, jitter=2), 6)
    radio.set_positions(cluster(20))
    delays = []
    for t in range(50):
        radio.broadcast(t, 0, t.to_bytes(2, "big"))
        for _, _, data, _ in radio.deliveries(t):
            delays.append(t - int.from_bytes(data, "big"))
    assert set(delays) == {3, 4, 5}  # never early, never late, every delay happens
    assert len(delays) + radio.in_flight == 50 * 20
    counts = [delays.count(d) for d in (3, 4, 5)]
    assert max(counts) - min(counts) < 0.15 * len(delays)  # uniform


def test_every_packet_arrives_once() -> None:
    radio = RadioModel(LinkModel(latency=2, jitter=4), 8)
    radio.set_positions(cluster(5))
    for t in range(30):
        radio.broadcast(t, 0, bytes([t]))
    got = radio.deliveries(10**6)
    assert sorted((r, d) for r, _, d, _ in got) == sorted(
        (r, bytes([t])) for t in range(30) for r in range(1, 6)
    )
    assert radio.delivered == 150 and radio.in_flight == 0 and radio.deliveries(10**6) == []


def test_each_delivery_carries_the_position_at_send_time() -> None:
    radio = RadioModel(LinkModel(range_m=50.0, latency=2), 0)
    radio.set_positions({1: (0.0, 0.0, 0.0), 2: (30.0, 40.0, 0.0)})
    radio.broadcast(0, 2, b"hello")
    radio.set_positions({1: (0.0, 0.0, 0.0), 2: (-3.0, 4.0, 0.0)})  # it moved since
    assert radio.deliveries(1) == []
    [(receiver, sender, data, where)] = radio.deliveries(2)
    assert (receiver, sender, data, where) == (1, 2, b"hello", (30.0, 40.0, 0.0))


def test_broadcast_needs_positions() -> None:
    with pytest.raises(RuntimeError):
        RadioModel(LinkModel(), 0).broadcast(0, 1, b"x", (0.0, 0.0, 0.0))


def test_non_finite_positions_are_refused() -> None:
    with pytest.raises(ValueError):
        RadioModel(LinkModel(range_m=5.0), 0).set_positions({1: (math.nan, 0.0, 0.0)})


# ---------------------------------------------------------------- bandwidth and counters


def test_bandwidth_is_respected() -> None:
    radio = RadioModel(LinkModel(bandwidth=100), 0)
    positions = cluster(3)
    radio.set_positions(positions)
    radio.broadcast(0, 0, bytes(60))
    assert radio.room(0, 0) == 40
    with pytest.raises(ValueError, match="bandwidth"):
        radio.broadcast(0, 0, bytes(41))
    assert radio.sent == 1 and radio.bytes_sent == {0: 60}  # the refused packet left no trace
    radio.broadcast(0, 0, bytes(40))
    radio.broadcast(0, 1, bytes(100))  # another robot has its own budget
    assert radio.room(1, 0) == 100  # a new step, a new budget
    radio.broadcast(1, 0, bytes(100))
    messages = MessageRadio(LinkModel(bandwidth=100), 0)
    messages.transmit(1, 0, [bytes(100)], positions)
    with pytest.raises(ValueError):
        messages.transmit(1, 0, [b"x"], positions)
    with pytest.raises(ValueError):
        LinkModel(bandwidth=0)
    assert RadioModel(LinkModel(), 0).room(0, 0) is None


def test_byte_counters_and_histogram() -> None:
    radio = RadioModel(LinkModel(), 0)
    radio.set_positions(cluster(2))
    for t in range(3):
        radio.broadcast(t, 0, bytes(48))
        radio.broadcast(t, 1, bytes(232 if t else 48))
    assert radio.step_bytes() == {0: 48, 1: 232}
    assert radio.bytes_sent == {0: 144, 1: 512}
    assert radio.air_histogram() == {48: 4, 232: 2}


# ---------------------------------------------------------------- reproducibility


def scenario(seed: int, model: LinkModel) -> tuple[list[object], int, int, int]:
    """Everything observable of a seeded 40-robot, 30-tick run."""
    rng = random.Random(99)
    radio = RadioModel(model, seed)
    log: list[object] = []
    for t in range(30):
        radio.set_positions({i: (rng.uniform(0, 60), rng.uniform(0, 60), 0.0) for i in range(40)})
        for i in range(40):
            radio.broadcast(t, i, bytes([i, t]))
        log.append(radio.deliveries(t))
    return log, radio.sent, radio.dropped, radio.delivered


@pytest.mark.parametrize(
    "model",
    [
        LinkModel(range_m=20.0, drop=0.3, latency=2, jitter=3),
        LinkModel.bursty(0.25, 4.0, range_m=20.0, jitter=1),
    ],
)
def test_reproducible_bit_for_bit(model: LinkModel) -> None:
    a = scenario(7, model)
    assert a == scenario(7, model)
    assert a != scenario(8, model)
    assert a[2] > 0


class LegacyRadio:
    """The per-message radio as it was before the grid (its draws must not change)."""

    def __init__(self, model: LinkModel, seed: int) -> None:
        self.model = model
        self.rng = random.Random(seed)
        self.flight: list[tuple[int, int, int, int, bytes]] = []
        self.seq = itertools.count()

    def transmit(self, step: int, sender: int, payloads: list[bytes], positions: dict) -> None:
        model, rng, here = self.model, self.rng, positions[sender]
        hearers = [
            r
            for r in sorted(positions)
            if r != sender and math.dist(here, positions[r]) <= model.range_m
        ]
        for payload in payloads:
            for r in hearers:
                if model.drop and rng.random() < model.drop:
                    continue
                due = step + model.latency + (rng.randint(0, model.jitter) if model.jitter else 0)
                heapq.heappush(self.flight, (due, next(self.seq), r, sender, payload))

    def arrivals(self, step: int) -> list[tuple[int, int, bytes]]:
        out = []
        while self.flight and self.flight[0][0] <= step:
            _, _, r, s, p = heapq.heappop(self.flight)
            out.append((r, s, p))
        return out


@pytest.mark.parametrize(
    "model",
    [LinkModel(range_m=15.0, drop=0.5), LinkModel(range_m=25.0, drop=0.3, jitter=2), LinkModel()],
)
def test_transmit_draws_as_before(model: LinkModel) -> None:
    """The harness's interface keeps its exact random draws: old seeded runs replay."""
    rng = random.Random(1)
    new, old = MessageRadio(model, 3), LegacyRadio(model, 3)
    positions = {i: (rng.uniform(0, 80), rng.uniform(0, 80), 0.0) for i in range(30)}
    for t in range(20):
        for i in sorted(positions):
            payloads = [bytes([i, t, k]) for k in range(rng.randrange(3))]
            new.transmit(t, i, payloads, positions)
            old.transmit(t, i, payloads, positions)
        assert new.arrivals(t) == old.arrivals(t)
        positions = {i: (x + rng.uniform(-3, 3), y, z) for i, (x, y, z) in positions.items()}


# ---------------------------------------------------------------- the grid


coordinate = st.one_of(
    st.floats(-200, 200, allow_nan=False),
    st.integers(-20, 20).map(lambda k: k * 10.0),  # on cell edges, at exact range multiples
)


@FAST
@given(
    st.lists(st.tuples(coordinate, coordinate, st.sampled_from([0.0, 5.0])), max_size=60),
    st.sampled_from([10.0, 0.5, 37.3, 1e-3, 1000.0, math.inf]),
)
def test_hearers_match_brute_force(points: list[Position], range_m: float) -> None:
    radio = RadioModel(LinkModel(range_m=range_m), 0)
    positions = dict(enumerate(points))
    radio.set_positions(positions)
    for i, here in positions.items():
        brute = [j for j in sorted(positions) if j != i and radio.in_range(here, positions[j])]
        assert radio.neighbors(i) == brute


def test_hearers_are_far_from_quadratic() -> None:
    """2,000 robots, ~10 neighbours each: distance checks stay a small multiple of N."""
    rng = random.Random(4)
    n, r = 2000, 50.0
    side = r * math.sqrt(math.pi * n / 10)
    radio = RadioModel(LinkModel(range_m=r), 0)
    radio.set_positions({i: (rng.uniform(0, side), rng.uniform(0, side), 0.0) for i in range(n)})
    heard = sum(len(radio.neighbors(i)) for i in range(n))
    assert 8 * n < heard < 12 * n
    # The k-d tree's candidates are the neighbours themselves (about 10 each), against
    # n - 1 = 1999 for brute force.
    assert radio.distance_checks < 12 * n
