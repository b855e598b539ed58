"""The update agent alone (sans-I/O): spreading over many hops, the barrier, rollback.

Agents talk over a seeded, lossy line or grid here, with no runtime and no simulator; the
patch check is a stand-in (a version, the base's hash and the new bytes), so these tests are
about the protocol. The real, signed patch runs through it in tests/update/test_sim_update.py.
"""

from __future__ import annotations

import hashlib
import random
import struct

import pytest

from fieldkit.update import packets as pk
from fieldkit.update.agent import (
    AgentConfig,
    Resume,
    Rollback,
    Standby,
    Switch,
    UpdateAgent,
    newer,
)
from fieldkit.update.release import Release

V0 = Release(b"version zero bytecode")
V1 = Release(b"version one bytecode, a bit longer" * 20)  # several chunks


class StandInPatchError(ValueError):
    """A stand-in patch that does not check out."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


def stand_in_patch(base: Release, new: Release, version: int) -> bytes:
    """b"TEST" | u32 version | base sha256 | the new bytecode."""
    return b"TEST" + struct.pack("<I", version) + bytes.fromhex(base.hash) + new.bo


def stand_in_verify(data: bytes, base: Release, current: int) -> tuple[int, Release]:
    """Check a stand-in patch as the real verifier would check its fields."""
    if data[:4] != b"TEST":
        raise StandInPatchError("bad-magic")
    (version,) = struct.unpack_from("<I", data, 4)
    if version <= current:
        raise StandInPatchError("replayed")
    if data[8:40] != hashlib.sha256(base.bo).digest():
        raise StandInPatchError("wrong-base")
    return version, Release(data[40:])


class Swarm:
    """Agents on a graph, one frame each per tick, each link dropping at `loss`."""

    def __init__(
        self,
        n: int,
        links: dict[int, list[int]],
        *,
        loss: float = 0.0,
        seed: int = 0,
        config: AgentConfig | None = None,
    ) -> None:
        self.agents = {
            i: UpdateAgent(i, 0, V0, stand_in_verify, config=config, seed=seed)
            for i in range(1, n + 1)
        }
        self.links = links
        self.loss = loss
        self.rng = random.Random(seed)
        self.tick = 0
        self.actions: list[tuple[int, int, object]] = []
        self.in_air: list[tuple[int, bytes]] = []
        self.dead: set[int] = set()

    def step(self) -> None:
        """One tick: deliver last tick's frames, every agent decides and sends."""
        for sender, frame in self.in_air:
            for r in self.links[sender]:
                if r not in self.dead and self.rng.random() >= self.loss:
                    self.agents[r].receive(frame)
        self.in_air = []
        for rid, a in self.agents.items():
            if rid in self.dead:
                continue
            action = a.tick(self.tick)
            if action is not None:
                self.actions.append((self.tick, rid, action))
            frame = a.frame()
            if frame is not None:
                assert len(frame) <= a.config.budget_bytes
                self.in_air.append((rid, frame))
        self.tick += 1

    def run_until(self, done: object, limit: int) -> int:
        """Step until `done()` (a callable) holds; the tick it did."""
        for _ in range(limit):
            if done():  # type: ignore[operator]
                return self.tick
            self.step()
        raise AssertionError(f"not done after {limit} ticks: {self.versions()}")

    def versions(self) -> dict[int, int]:
        return {i: a.version for i, a in self.agents.items()}

    def live(self) -> dict[int, UpdateAgent]:
        return {i: a for i, a in self.agents.items() if i not in self.dead}


def line(n: int) -> dict[int, list[int]]:
    return {i: [j for j in (i - 1, i + 1) if 1 <= j <= n] for i in range(1, n + 1)}


def warm(swarm: Swarm, ticks: int = 300) -> None:
    """Let the barrier table fill before the update, as a swarm that has flown a while."""
    for _ in range(ticks):
        swarm.step()


def test_heartbeats_compare_across_the_wrap() -> None:
    assert newer(1, 0) and newer(0, 0xFFFF) and not newer(0xFFFF, 0) and not newer(5, 5)


def test_an_update_spreads_down_a_twelve_hop_line_at_half_loss_and_everyone_switches() -> None:
    n = 13
    swarm = Swarm(n, line(n), loss=0.5, seed=3)
    warm(swarm)
    assert swarm.agents[1].inject(stand_in_patch(V0, V1, 1))
    swarm.run_until(lambda: all(a.version == 1 for a in swarm.agents.values()), 6000)
    # Everyone stood by, then switched: none caught up without the barrier's say, none rolled back.
    kinds = [type(a) for _, _, a in swarm.actions]
    assert kinds.count(Standby) == n and kinds.count(Switch) == n
    assert Rollback not in kinds and Resume not in kinds
    assert all(a.release == V1 for a in swarm.agents.values())
    # Robots many hops away got it from their neighbours, not from robot 1.
    assert swarm.agents[n].counters["patches_verified"] == 1


def test_the_switch_waits_for_the_last_robot_of_the_line() -> None:
    n = 8
    swarm = Swarm(n, line(n), seed=1)
    warm(swarm)
    swarm.agents[1].inject(stand_in_patch(V0, V1, 1))
    swarm.run_until(lambda: all(a.version == 1 for a in swarm.agents.values()), 3000)
    first_switch = min(t for t, _, a in swarm.actions if isinstance(a, Switch))
    last_standby = max(t for t, _, a in swarm.actions if isinstance(a, Standby))
    assert first_switch > last_standby  # a barrier: nobody switched before all were ready


def test_a_script_error_in_grace_rolls_the_whole_swarm_back_to_the_previous_version() -> None:
    n = 6
    swarm = Swarm(n, line(n), loss=0.2, seed=2)
    warm(swarm)
    swarm.agents[1].inject(stand_in_patch(V0, V1, 1))
    swarm.run_until(lambda: all(a.version == 1 for a in swarm.agents.values()), 3000)
    swarm.agents[4].script_failed("s.bzz:3:5: unknown function 'foo'")
    swarm.run_until(lambda: all(a.version == 0 for a in swarm.agents.values()), 3000)
    for a in swarm.agents.values():
        assert a.release == V0
        assert "script error" in a.bad[1] or "rolled back" in a.bad[1]
    # A replay of the rolled-back patch is refused everywhere, and nobody pulls it again.
    swarm.agents[2].inject(stand_in_patch(V0, V1, 1))
    for _ in range(200):
        swarm.step()
    assert all(a.version == 0 for a in swarm.agents.values())


def test_a_barrier_that_never_passes_times_out_and_nobody_switches() -> None:
    n = 4
    config = AgentConfig(barrier_timeout_ticks=200, live_ticks=600)
    swarm = Swarm(n, line(n), seed=4, config=config)
    warm(swarm)
    # Robot 4 is alive but will never get the patch: its link to 3 drops everything from 3.
    swarm.links[3] = [2]
    swarm.agents[1].inject(stand_in_patch(V0, V1, 1))
    heard = [swarm.agents[i] for i in (1, 2, 3)]  # robot 4 hears nobody: it never knows
    swarm.run_until(lambda: all(1 in a.bad for a in heard), 3000)
    assert all(a.version == 0 for a in swarm.agents.values())
    assert not any(isinstance(a, Switch) for _, _, a in swarm.actions)
    # Whichever timed out first says why; the others may only have heard that it did.
    assert any("barrier timeout" in a.bad[1] for a in heard)


def test_a_robot_that_dies_mid_update_does_not_block_the_rest() -> None:
    n = 5
    config = AgentConfig(live_ticks=300, barrier_timeout_ticks=1200)
    swarm = Swarm(n, line(n) | {5: [4], 4: [3, 5]}, seed=5, config=config)
    warm(swarm)
    swarm.dead.add(5)  # gone before the update: its heartbeat stops
    swarm.agents[1].inject(stand_in_patch(V0, V1, 1))
    swarm.run_until(lambda: all(a.version == 1 for a in swarm.live().values()), 3000)


def test_a_robot_back_from_a_reboot_catches_up_by_the_same_pull() -> None:
    n = 4
    swarm = Swarm(n, line(n), seed=6)
    warm(swarm)
    swarm.agents[1].inject(stand_in_patch(V0, V1, 1))
    swarm.run_until(lambda: all(a.version == 1 for a in swarm.agents.values()), 3000)
    # Robot 4 reboots on the version it had committed before the update.
    swarm.agents[4] = UpdateAgent(4, 0, V0, stand_in_verify, seed=0)
    swarm.run_until(lambda: swarm.agents[4].version == 1, 3000)
    assert any(
        isinstance(a, Switch) and "catching up" in a.reason for _, r, a in swarm.actions if r == 4
    )


def test_update_traffic_stays_within_its_budget_and_bad_frames_cost_a_counter() -> None:
    a = UpdateAgent(1, 0, V0, stand_in_verify)
    a.receive(b"\x00" * 7)
    a.receive(b"junk" * 4)
    assert a.counters["bad_frames"] == 2
    a.inject(stand_in_patch(V0, V1, 1))
    for t in range(100):
        a.tick(t)
        frame = a.frame()
        if frame is not None:
            assert len(frame) <= a.config.budget_bytes


@pytest.mark.parametrize(
    ("patch", "reason"),
    [
        (stand_in_patch(V1, V1, 1), "wrong-base"),
        (stand_in_patch(V0, V1, 0), "replayed"),
        (b"NOPE" + bytes(60), "bad-magic"),
    ],
)
def test_a_refused_patch_is_counted_and_the_robot_keeps_its_version(
    patch: bytes, reason: str
) -> None:
    a = UpdateAgent(1, 0, V0, stand_in_verify)
    assert not a.inject(patch)
    assert a.counters[f"refused_{reason}"] == 1
    assert a.version == 0 and a.release == V0 and a.staged is None


def test_offers_that_no_script_could_need_are_never_pulled() -> None:
    a = UpdateAgent(1, 0, V0, stand_in_verify)
    base = hashlib.sha256(V0.bo).digest()[:8]
    huge = pk.Frame(2, (pk.Offer(b"d" * 8, 1, 10**9, base),))
    ahead = pk.Frame(2, (pk.Offer(b"e" * 8, 5000, 1000, base),))
    for f in (huge, ahead):
        a.receive(pk.encode(f))
    assert not a.transfers
    assert a.counters["refused_too_large"] == 1


def test_frames_sealed_with_another_swarm_key_are_refused_and_change_nothing() -> None:
    key, other = pk.frame_key(b"k" * 32), pk.frame_key(b"x" * 32)
    robot = UpdateAgent(1, 1, V1, stand_in_verify, previous=[(0, V0)], frame_key=key)
    # An outsider in range forges a verdict against the running version, and an offer.
    forged = pk.encode(pk.Frame(9, (pk.Verdict(1, pk.Reason.OPERATOR),)))
    robot.receive(forged)  # no tag at all
    robot.receive(pk.seal(forged, other))  # a tag, under another key
    assert robot.counters["bad_frames"] == 2 and not robot.bad
    assert robot.tick(0) is None and robot.version == 1
    # The same verdict sealed with the swarm's key is obeyed: the swarm rolls back.
    robot.receive(pk.seal(forged, key))
    assert isinstance(robot.tick(1), Rollback) and robot.version == 0


def test_a_sealed_swarm_spreads_an_update_and_sends_only_sealed_frames() -> None:
    key = pk.frame_key(b"s" * 32)
    swarm = Swarm(4, line(4), seed=8)
    for a in swarm.agents.values():
        a.frame_key = key
    warm(swarm, 100)
    swarm.agents[1].inject(stand_in_patch(V0, V1, 1))
    swarm.run_until(lambda: all(a.version == 1 for a in swarm.agents.values()), 3000)
    assert all(a.counters["bad_frames"] == 0 for a in swarm.agents.values())
    for a in swarm.agents.values():
        f = a.frame()
        if f is not None:
            pk.decode(pk.unseal(f, key))


def test_verdicts_for_versions_that_could_never_be_accepted_are_not_kept() -> None:
    robot = UpdateAgent(1, 5, V0, stand_in_verify)
    frame = pk.Frame(2, tuple(pk.Verdict(v, pk.Reason.OPERATOR) for v in (10_000, 20_000, 7)))
    robot.receive(pk.encode(frame))
    assert list(robot.bad) == [7]  # 7 may yet come; the others are past the fast-forward bound
