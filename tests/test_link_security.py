"""A robot's security mode: what it seals, what it lets through, what it reports."""

from __future__ import annotations

from pathlib import Path

import pytest

import bvm
from fieldkit.robot import bundle as B
from fieldkit.robot import bundle_auth as A
from fieldkit.robot import geo
from fieldkit.robot.link_security import NONE, OWN_ECHO, SEALED, SIGNED, LinkSecurity
from fieldkit.robot.profiles import load_profile
from fieldkit.robot.runtime import RobotRuntime
from fieldkit.robot.script_api import Sensors

KEY = A.bundle_key(b"k" * 32)
OTHER = A.bundle_key(b"o" * 32)


def signed(rid: int, key: A.BundleKey = KEY, lines: list[str] | None = None) -> LinkSecurity:
    report = None if lines is None else lines.append
    return LinkSecurity.signed_with(rid, key, A.MemoryCounter(), report=report)


def air(rid: int, messages: tuple[bytes, ...] = (b"hello",)) -> bytes:
    return B.encode_fields(rid, messages, 45.5, -73.5, 10.0, 1)


def test_a_sealed_bundle_opens_once_at_a_robot_of_the_same_swarm() -> None:
    a, b = signed(1), signed(2)
    sent = a.seal(air(1))
    assert len(sent) == len(air(1)) + A.TRAILER_BYTES and a.last_counter == 1
    assert b.open(sent) == air(1)
    assert b.open(sent) is None  # again: a replay
    assert b.counters[A.ACCEPTED] == 1 and b.rejected() == {A.REPLAYED: 1}


def test_forged_plain_and_foreign_bundles_are_dropped_and_mixed_settings_reported() -> None:
    lines: list[str] = []
    b = signed(2, lines=lines)
    forged = bytearray(signed(1).seal(air(1)))
    forged[20] ^= 1
    assert b.open(bytes(forged)) is None
    assert b.open(air(3)) is None  # a plain bundle: robot 3 runs none, or is ROSBuzz
    assert b.open(air(3)) is None
    assert b.open(signed(4, OTHER).seal(air(4))) is None  # another swarm key
    assert b.rejected() == {A.BAD_TAG: 1, A.MISSING_TRAILER: 2, A.UNKNOWN_KEY: 1}
    assert sorted(b.mixed) == [3, 4]
    assert len(lines) == 2  # once per robot, however often it is heard
    assert "robot 3 sends plain bundles" in lines[0] and "robot 4 seals" in lines[1]


def test_a_plain_robot_drops_sealed_bundles_and_says_a_neighbour_is_signed() -> None:
    lines: list[str] = []
    plain = LinkSecurity(2, NONE, report=lines.append)
    assert plain.open(air(1)) == air(1)
    assert plain.open(signed(1).seal(air(1))) is None
    assert plain.counters[SEALED] == 1 and list(plain.mixed) == [1]
    assert "robot 1 sends sealed bundles" in lines[0]
    assert plain.seal(air(2)) == air(2) and plain.max_content == B.MAX_MSG_SIZE


def test_own_bundles_heard_back_never_reach_the_verifier() -> None:
    a = signed(1)
    sent = a.seal(air(1))
    assert a.open(sent) is None and a.rejected() == {OWN_ECHO: 1}
    assert a.counters[A.ACCEPTED] == 0


def test_signed_needs_a_sealer_and_a_known_mode() -> None:
    with pytest.raises(ValueError, match="sealer"):
        LinkSecurity(1, SIGNED)
    with pytest.raises(ValueError, match="mode"):
        LinkSecurity(1, "open")  # type: ignore[arg-type]


BIG = """
function step() {
  neighbors.broadcast("a", "xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx")
  neighbors.broadcast("b", "yyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyyy")
  neighbors.broadcast("c", "zzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzzz")
}
"""


def sensors() -> Sensors:
    return Sensors(lat=45.5, lon=-73.5, alt=0.0, north=0.0, east=0.0)


def runtime(rid: int, security: LinkSecurity | None) -> RobotRuntime:
    profile = load_profile("solo")
    rt = RobotRuntime(rid, profile, geo.LocalFrame(45.5, -73.5, 0.0), security=security)
    assert rt.start(bvm.compile_source(BIG, "big.bzz"), sensors())
    return rt


def test_a_signed_robot_fills_bundles_to_the_sealed_budget_within_one_xbee_frame() -> None:
    plain, sealed = runtime(1, None), runtime(1, signed(1))
    assert plain.budget == B.MAX_BUZZ_BYTES and sealed.budget == A.SEALED_MAX_BUZZ_BYTES
    sizes = []
    for _ in range(20):
        out = sealed.tick(sensors())
        assert A.is_sealed(out.bundle) and len(out.bundle) <= A.MAX_SEALED_AIR_BYTES
        assert B.block_size(out.messages) <= A.SEALED_MAX_MSG_SIZE
        sizes.append(len(out.bundle))
        assert len(plain.tick(sensors()).bundle) <= B.MAX_AIR_BYTES
    assert max(sizes) >= 200  # two of the three broadcasts a tick: the budget is used


def test_the_runtime_decodes_nothing_its_security_drops() -> None:
    sender, receiver = runtime(1, signed(1)), runtime(2, signed(2))
    out = sender.tick(sensors())
    receiver.receive_bundle(out.bundle)
    assert receiver.counters["bundles_heard"] == 1 and 1 in receiver.heard
    forged = bytearray(out.bundle)
    forged[60] ^= 4  # a message byte, under the old tag
    before = receiver.vm.counters["decode_errors"]
    receiver.receive_bundle(bytes(forged))
    receiver.receive_bundle(out.bundle)  # replayed
    assert receiver.counters["bundles_heard"] == 1
    assert receiver.counters["bundle_errors"] == 0  # dropped before the decoder
    assert receiver.vm.counters["decode_errors"] == before
    assert receiver.security is not None
    assert receiver.security.rejected() == {A.BAD_TAG: 1, A.REPLAYED: 1}


def test_a_robot_that_cannot_keep_its_counter_falls_silent_and_says_so(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir()
    store = A.CounterStore(state / "bundle.counter")
    state.rmdir()
    state.write_text("x")  # the state directory gone: no counter can be reserved
    sec = LinkSecurity.signed_with(1, KEY, store)
    rt = runtime(1, sec)
    out = rt.tick(sensors())
    assert out.bundle == b"" and rt.counters["unsent_bundles"] == 1
    assert rt.ticks == 1  # the tick went on: the vehicle still gets its orders


def test_clock_jumps_change_nothing(monkeypatch: pytest.MonkeyPatch) -> None:
    """GPS time arriving late, an RTC back at 1970, a bogus week ahead: no check reads a clock,
    so nothing locks out and nothing old gets in."""
    import time

    a, b = signed(1), signed(2)
    sent = [a.seal(air(1)) for _ in range(5)]
    assert all(b.open(x) is not None for x in sent)
    for now in (0.0, 1e10, 86400.0 * 365 * 30, 5.0):  # 1970, far ahead, today, back again
        monkeypatch.setattr(time, "time", lambda now=now: now)
        monkeypatch.setattr(time, "time_ns", lambda now=now: int(now * 1e9))
        monkeypatch.setattr(time, "monotonic", lambda now=now: now)
        fresh = a.seal(air(1))
        assert b.open(fresh) is not None  # never locked out
        assert all(b.open(old) is None for old in sent)  # nothing already heard gets in
        sent.append(fresh)
    assert b.rejected() == {A.REPLAYED: sum(range(5, 9))}
