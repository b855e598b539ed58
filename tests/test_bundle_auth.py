"""Authenticated bundles (fieldkit.robot.bundle_auth): the trailer, the replay window, the
counter that survives reboots and kill -9, and the byte budget (docs/security.md)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from rigs import kill_and_drain

from fieldkit.robot import bundle as B
from fieldkit.robot import bundle_auth as A
from fieldkit.update import packets as pk

SWARM = bytes(range(32))
KEY = A.bundle_key(SWARM)
CHILD = Path(__file__).with_name("counter_crash_child.py")
#: A child that neither ends nor dies within this is hung (a hang guard, not a timing).
HANG_S = 120

CMD = bytes.fromhex("00 03 0003 636d64 01 00000016")  # BROADCAST "cmd" = 22
JOIN = bytes.fromhex("04 0003")


def air(robot: int = 7, messages: tuple[bytes, ...] = (CMD, JOIN), number: int = 1) -> bytes:
    return B.encode_fields(robot, messages, 45.5, -73.6, 10.0, number, 123456789)


def other_key() -> A.BundleKey:
    """A key of another swarm whose key id differs from KEY's."""
    for i in range(1, 100):
        k = A.bundle_key(bytes([i]) * 32)
        if k.id != KEY.id:
            return k
    raise AssertionError("no other key id in 99 keys")


def reason(v: A.Verifier, data: bytes) -> str:
    with pytest.raises(A.AuthError) as e:
        v.verify(data)
    assert e.value.reason in A.REASONS
    return e.value.reason


def sealed_run(n: int, robot: int = 7) -> list[bytes]:
    """n sealed bundles of `robot`, counters 1..n."""
    s = A.Sealer(robot, KEY, A.MemoryCounter())
    return [s.seal(air(robot, number=i)) for i in range(1, n + 1)]


# ------------------------------------------------------------------ format


def test_round_trip_of_real_bundles() -> None:
    s = A.Sealer(7, KEY, A.MemoryCounter())
    v = A.Verifier(KEY)
    full = (b"\xaa" * (A.SEALED_MAX_BUZZ_BYTES - 2),)
    for messages in ((), (CMD, JOIN), full):
        plain = air(7, messages)
        sealed = s.seal(plain)
        assert len(sealed) == len(plain) + A.TRAILER_BYTES
        assert A.is_sealed(sealed) and not A.is_sealed(plain)
        out = v.verify(sealed)
        assert out == plain
        got = B.decode(out)
        assert (got.robot, got.messages, got.lat) == (7, messages, 45.5)
    assert v.counters == {A.ACCEPTED: 3}


def test_the_trailer_layout() -> None:
    """Word A: counter (u48 BE), key id, format; word B: HMAC-SHA256 over sender||air||A."""
    import hashlib
    import hmac

    plain = air()
    sealed = A.Sealer(7, KEY, A.MemoryCounter(0x010203040506)).seal(plain)
    a, tag = sealed[-16:-8], sealed[-8:]
    assert a == bytes.fromhex("010203040506") + bytes([KEY.id, 1])
    want = hmac.new(KEY.secret, b"\x00\x07" + plain + a, hashlib.sha256).digest()[:8]
    assert tag == want
    # As a payload64 word (what a node on the ROS topics sees) the format is the low byte.
    assert int.from_bytes(a, "big") & 0xFF == A.FORMAT
    # The bundle key is not the update frames' key: the same swarm key, another HKDF info.
    assert KEY.secret != pk.frame_key(SWARM)
    assert A.bundle_key(SWARM).id == KEY.id  # derived, not random


def test_sizes_fit_one_xbee_frame() -> None:
    """A full sealed bundle is 240 air bytes: one standard XbeeMav packet of 242 < 250 bytes,
    RF data of 243 <= 250. One byte more of content does not fit."""
    assert A.MAX_SEALED_AIR_BYTES == 240 and A.MAX_PLAIN_AIR_BYTES == 224
    assert A.SEALED_MAX_MSG_SIZE == 184 and A.SEALED_MAX_BUZZ_BYTES == 180
    assert B.drain_budget(A.MAX_PLAIN_AIR_BYTES) == A.SEALED_MAX_BUZZ_BYTES
    assert 2 + A.MAX_SEALED_AIR_BYTES < 250 and A.MAX_SEALED_RF_BYTES <= B.XBEE_MAX_RF
    s = A.Sealer(3, KEY, A.MemoryCounter())
    for content in (182, 184):  # header 4 + prefix 2 + message
        msg = b"m" * (content - B.BUNDLE_HEADER - B.MSG_OVERHEAD)
        assert B.block_size([msg]) == content
        sealed = s.seal(air(3, (msg,)))
        assert len(sealed) <= A.MAX_SEALED_AIR_BYTES
        assert len(b"S\x03\x01" + sealed) <= B.XBEE_MAX_RF
    too_big = b"m" * (185 - 6)
    with pytest.raises(ValueError, match="budget_bytes=180"):
        s.seal(air(3, (too_big,)))
    # Plain ROSBuzz bundles keep their 190 bytes: the sealed limit is only the trailer's.
    assert B.MAX_MSG_SIZE == 190 and len(air(3, (b"m" * 184,))) == B.MAX_AIR_BYTES


def test_the_sealer_refuses_what_is_not_its_bundle() -> None:
    s = A.Sealer(7, KEY, A.MemoryCounter())
    with pytest.raises(ValueError, match="robot 8"):
        s.seal(air(8))
    with pytest.raises(ValueError, match="not a bundle"):
        s.seal(pk.encode(pk.Frame(7, ())))
    with pytest.raises(ValueError, match="header says"):
        s.seal(air() + bytes(8))
    assert s.last == 0  # no counter spent on a refusal


# ------------------------------------------------------------------ rejections


def test_every_rejection_reason() -> None:
    v = A.Verifier(KEY)
    good = sealed_run(3)
    assert reason(v, air()) == A.MISSING_TRAILER
    assert reason(v, b"") == A.BAD_FORMAT
    assert reason(v, bytes(range(64))) == A.BAD_FORMAT  # word 0's type is 0x0607, not 2
    assert reason(v, good[0][:-8]) == A.BAD_FORMAT  # half a trailer
    assert reason(v, good[0] + bytes(8)) == A.BAD_FORMAT
    assert reason(v, good[0] + bytes(1000)) == A.BAD_FORMAT
    fmt2 = bytearray(good[0])
    fmt2[-9] = 2  # a future trailer format
    assert reason(v, bytes(fmt2)) == A.BAD_FORMAT
    foreign = A.Sealer(7, other_key(), A.MemoryCounter()).seal(air())
    assert reason(v, foreign) == A.UNKNOWN_KEY
    for i in (0, 20, 44, len(good[0]) - 16, len(good[0]) - 1):  # body, sender, counter, tag
        bent = bytearray(good[0])
        bent[i] ^= 0x01
        assert reason(v, bytes(bent)) == A.BAD_TAG, i
    rewound = bytearray(good[2])
    rewound[-11] ^= 0x03  # counter 3 -> 0: the tag no longer matches
    assert reason(v, bytes(rewound)) == A.BAD_TAG
    assert v.verify(good[1]) == air(number=2)
    assert reason(v, good[1]) == A.REPLAYED
    run = sealed_run(70)
    assert v.verify(run[69])  # counter 70
    assert reason(v, run[4]) == A.TOO_OLD  # counter 5: 65 below
    assert v.verify(run[5])  # counter 6: 64 below, the window's last
    assert reason(v, run[5]) == A.REPLAYED
    assert reason(v, good[0]) == A.TOO_OLD
    assert v.counters[A.ACCEPTED] == 3
    counts = {r: v.counters[r] for r in A.REASONS}
    assert counts == {
        A.MISSING_TRAILER: 1, A.BAD_FORMAT: 6, A.UNKNOWN_KEY: 1, A.BAD_TAG: 6,
        A.REPLAYED: 2, A.TOO_OLD: 2,
    }  # fmt: skip


def test_rejections_name_the_sender_and_never_raise_anything_else() -> None:
    v = A.Verifier(KEY)
    with pytest.raises(A.AuthError) as e:
        v.verify(air(robot=42))
    assert e.value.sender == 42 and "robot 42" in str(e.value) and "missing-trailer" in str(e.value)
    for junk in (None, "text", 7, [1, 2]):
        assert reason(v, junk) == A.BAD_FORMAT  # type: ignore[arg-type]
    assert v.verify(memoryview(sealed_run(1)[0])) == air()


def test_reordering_within_the_window_is_accepted_once() -> None:
    """Mesh relays deliver late: any order within 64 below the highest passes, once each."""
    run = sealed_run(80)
    v = A.Verifier(KEY)
    assert v.verify(run[79]) == air(number=80)
    for i in range(78, 14, -1):  # counters 79 down to 16: 1..64 below 80
        assert v.verify(run[i]) == air(number=i + 1)
    assert reason(v, run[14]) == A.TOO_OLD  # counter 15
    for i in range(15, 80):
        assert reason(v, run[i]) == A.REPLAYED
    # Bundles skipped within the window are still accepted when they come.
    v2 = A.Verifier(KEY)
    for i in (9, 2, 30, 11, 3):
        v2.verify(run[i])
    assert [reason(v2, run[i]) for i in (9, 2, 30, 11, 3)] == [A.REPLAYED] * 5
    assert v2.verify(run[10]) and v2.verify(run[0])


def test_senders_have_windows_of_their_own() -> None:
    v = A.Verifier(KEY)
    a, b = sealed_run(5, robot=1), sealed_run(5, robot=2)
    for x, y in zip(a, b, strict=True):
        v.verify(x)
        v.verify(y)
    assert v.floors() == {1: 5, 2: 5}


def test_eviction_reopens_nothing() -> None:
    """Past max_senders the least recently heard sender's window goes, but its highest
    counter stays as its floor: its old bundles stay refused, its new ones pass."""
    v = A.Verifier(KEY, max_senders=2)
    r1, r2, r3 = (sealed_run(70, robot=r) for r in (1, 2, 3))
    v.verify(r1[9])  # robot 1, counter 10
    v.verify(r1[5])  # counter 6, reordered
    v.verify(r2[0])
    v.verify(r3[0])  # robot 1 evicted
    assert v.tracked() == 2
    assert reason(v, r1[9]) == A.REPLAYED
    assert reason(v, r1[5]) == A.REPLAYED
    assert reason(v, r1[7]) == A.REPLAYED  # unseen, but at or under the floor: refused
    assert v.verify(r1[10]) and v.verify(r1[69])
    assert reason(v, r1[10]) == A.REPLAYED
    assert v.floors() == {1: 70, 2: 1, 3: 1}


# ------------------------------------------------------------------ domains


def test_update_frames_and_rosbuzz_ota_are_not_sealed_bundles() -> None:
    v = A.Verifier(KEY)
    frame = pk.encode(pk.Frame(7, (pk.Verdict(3, pk.Reason.OPERATOR),)))
    sealed_frame = pk.seal(frame, pk.frame_key(SWARM))
    ota = (1).to_bytes(8, "big") + bytes(8 * 32)  # ROSBuzz's word 0 == 1
    for data in (frame, sealed_frame, ota, ota[:64]):
        assert not A.is_sealed(data)
        assert reason(v, data) == A.BAD_FORMAT
    # The other way round: a sealed bundle is not an update frame, under either key.
    sealed = sealed_run(1)[0]
    with pytest.raises(pk.FrameError):
        pk.unseal(sealed, pk.frame_key(SWARM))
    # And a fieldkit robot running `none` drops it: the strict decoder sees two extra words.
    with pytest.raises(B.BundleError):
        B.decode(sealed)
    assert v.counters == {A.BAD_FORMAT: 4}


# ------------------------------------------------------------------ counters on disk


def test_counter_store_reserves_blocks(tmp_path: Path) -> None:
    path = tmp_path / "bundle.counter"
    store = A.CounterStore(path, block=10)
    got = [store.next() for _ in range(25)]
    assert got == list(range(1, 26))
    assert store.writes == 3  # 1..10, 11..20, 21..30: one write per block, not per bundle
    assert path.read_text() == "fieldkit-bundle-counter-v1 31\n"
    again = A.CounterStore(path, block=10)
    assert again.next() == 31  # the rest of the block is skipped, never reused
    assert not list(tmp_path.glob(".*.tmp"))


def test_a_sender_reboot_never_reuses_a_counter_and_is_not_locked_out(tmp_path: Path) -> None:
    path = tmp_path / "bundle.counter"
    v = A.Verifier(KEY)
    seen: list[int] = []
    for boot in range(4):
        sealer = A.Sealer(7, KEY, A.CounterStore(path, block=7))
        for i in range(3 + boot * 5):
            v.verify(sealer.seal(air(number=i)))  # every bundle after a reboot passes
            seen.append(sealer.last)
    assert seen == sorted(set(seen)) and len(seen) == 4 * 3 + 5 * 6
    assert v.counters == {A.ACCEPTED: len(seen)}


def test_a_damaged_counter_file_is_an_error_not_a_restart(tmp_path: Path) -> None:
    path = tmp_path / "bundle.counter"
    for text in ("", "fieldkit-bundle-counter-v1 \n", "fieldkit-bundle-counter-v1 0\n", "12\n"):
        path.write_text(text)
        with pytest.raises(A.CounterError, match="not a bundle counter file") as e:
            A.CounterStore(path)
        assert str(path) in str(e.value) and "hint:" in str(e.value)
    path.write_text(f"fieldkit-bundle-counter-v1 {A.MAX_COUNTER + 1}\n")
    with pytest.raises(A.CounterError, match="exhausted"):
        A.CounterStore(path).next()


def child(path: Path, count: int, block: int, crash_at: int = 0) -> subprocess.Popen[str]:
    env = os.environ | {"COUNTER_CRASH_AT": str(crash_at)}
    return subprocess.Popen(
        [sys.executable, str(CHILD), str(path), str(count), str(block)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )


def sent(out: str) -> list[int]:
    return [int(line.split()[1]) for line in out.splitlines() if line.startswith("sent ")]


def test_killed_at_every_step_of_a_reservation_no_counter_is_reused(tmp_path: Path) -> None:
    """The child SIGKILLs itself at each fsync and rename of its reservations in turn, all
    on one counter file: across every crash and restart, no counter is sent twice and each
    run starts above everything sent before."""
    dry = child(tmp_path / "dry", 10, 4)
    out, err = dry.communicate(timeout=HANG_S)
    assert dry.returncode == 0, err
    ops = int(out.splitlines()[-2].removeprefix("ops "))
    assert ops == 9  # 3 reservations (1..4, 5..8, 9..12) x (fsync, rename, fsync dir)
    path = tmp_path / "bundle.counter"
    everything: list[int] = []
    for k in range(1, ops + 1):
        proc = child(path, 10, 4, crash_at=k)
        out, err = proc.communicate(timeout=HANG_S)
        assert proc.returncode == -signal.SIGKILL, (k, err)
        assert "Traceback" not in err
        now = sent(out)
        assert all(c > max(everything, default=0) for c in now), (k, now, everything)
        everything += now
        assert path.exists() or not everything  # only the first rename can be missing
    assert everything == sorted(set(everything)) and len(everything) >= 30
    assert A.CounterStore(path).next() > everything[-1]


def test_killed_from_outside_mid_run_no_counter_is_reused(tmp_path: Path) -> None:
    """The parent kills the child after N lines, wherever the scheduler has it then."""
    path = tmp_path / "bundle.counter"
    everything: list[int] = []
    for n in (1, 3, 4, 5, 9, 2):
        proc = child(path, 10_000, 4)
        assert proc.stdout is not None
        lines = [proc.stdout.readline() for _ in range(n)]
        rest, _ = kill_and_drain(proc, HANG_S)
        now = sent("".join(lines) + rest)
        assert now and all(c > max(everything, default=0) for c in now)
        everything += now
    assert everything == sorted(set(everything))


# ------------------------------------------------------------------ receiver reboot


def test_floors_survive_a_receiver_reboot(tmp_path: Path) -> None:
    path = tmp_path / "bundle.floors"
    run = sealed_run(40, robot=4)
    store = A.FloorStore(path, KEY, every=10)
    v = A.Verifier(KEY, floors=store.load())
    writes = []
    for b in run[:25]:
        v.verify(b)
        writes.append(store.save_if_due(v.floors()))
    assert writes.count(True) == 2 and writes.index(True) == 9  # at counters 10 and 20
    # Reboot: counters up to the saved 20 are refused; 21..25, sent since the last save,
    # are the residual window (docs/security.md#receiver-reboot); fresh ones pass.
    store2 = A.FloorStore(path, KEY, every=10)
    v2 = A.Verifier(KEY, floors=store2.load())
    assert store2.load() == {4: 20}
    assert reason(v2, run[19]) == A.REPLAYED and reason(v2, run[0]) == A.REPLAYED
    assert v2.verify(run[30]) and v2.verify(run[22])  # 23: unseen since the reboot
    assert reason(v2, run[22]) == A.REPLAYED
    assert reason(v2, run[15]) == A.REPLAYED  # under the floor, within the window
    # After a re-key the old floors do not apply (a captured robot may have pushed them up).
    new = A.FloorStore(path, other_key())
    assert new.load() == {} and new.other_key


def test_a_damaged_floor_file_is_an_error(tmp_path: Path) -> None:
    path = tmp_path / "bundle.floors"
    head = f"fieldkit-bundle-floors-v1 {KEY.fingerprint}\n"
    for text in ("", head + "7\n", "x\n", head + "1 2", "fieldkit-bundle-floors-v1\n1 2\n"):
        path.write_text(text)
        with pytest.raises(A.CounterError, match="not a bundle floor file"):
            A.FloorStore(path, KEY).load()
    path.write_text(head + "3 99\n")
    assert A.FloorStore(path, KEY).load() == {3: 99}
