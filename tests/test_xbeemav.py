"""XbeeMav packets and fragmentation (docs/bundle.md#xbeemav), and XBeeRadio over real ptys.

The protocol across several robots (lost fragments, corruption, strangers) is tested without
a port in tests/test_xbee_core.py; the pty tests here check the serial transport.

The radio tests run each XBeeRadio on the slave side of a pseudo-terminal; `Mesh` plays the
XBee modules on the master sides: it de-frames each radio's 0x10 transmit requests, answers
0x8B transmit status, and hands every other radio a 0x90 receive packet built by digi-xbee
(an implementation independent of ours), optionally dropping or corrupting frames. The
radios share a fake clock that moves only when the wire is quiet, so protocol timers
(pacing, the 500 ms ack wait, the 30 s timeout) are deterministic and no test sleeps.
"""

from __future__ import annotations

import logging
import os
import random
import re
import select
import struct
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from digi.xbee.models.address import XBee16BitAddress, XBee64BitAddress
from digi.xbee.packets.common import ReceivePacket as DigiReceive
from fuzz.bundle_fuzz import EXAMPLE
from hypothesis import given, settings
from hypothesis import strategies as st

from fieldkit.node.health import radio_health
from fieldkit.radio import RadioLink, XBeeRadio, from_profile, open_radio
from fieldkit.radio import xbee as X
from fieldkit.radio import xbeemav as M
from fieldkit.robot import bundle as B
from fieldkit.robot.profiles import RadioSettings

SERIALS = {1: 0x0013A20040000001, 2: 0x0013A20040000002, 3: 0x0013A20040000003}
ID_MAP = {f"{s:016X}": i for i, s in SERIALS.items()}


class FakeClock:
    """A clock tests move by hand."""

    def __init__(self, now: float = 100.0) -> None:
        self.now = now

    def __call__(self) -> float:
        """The current fake time."""
        return self.now


def bundle(robot: int, number: int, text: bytes = b"hi") -> B.Bundle:
    """A small bundle from `robot`."""
    return B.Bundle(robot, (text,), 45.0, -73.0, 5.0, number=number)


def big_payload(words: int, seed: int = 0) -> bytes:
    """An updater-like payload (word 0 = 1, as ROSBuzz's UPDATER_MESSAGE) of `words` words."""
    rng = random.Random(seed)
    return struct.pack(">Q", 1) + rng.randbytes(8 * (words - 1))


# ---------------------------------------------------------------- packets


def test_standard_packet_is_the_bundle_rf_data() -> None:
    """A bundle travels as 'S' + sysid + msgid + words: bundle.to_rf_data (docs/bundle.md)."""
    engine = M.XbeeMav(7, clock=FakeClock())
    engine.submit(B.encode(EXAMPLE), M.msgid_of(B.encode(EXAMPLE)) or 0)
    assert engine.pump() == [B.to_rf_data(EXAMPLE)]
    assert engine.stats["standard_out"] == 1


def test_msgid_comes_from_the_message_number() -> None:
    """ROSBuzz sets msgid = message_number's low 8 bits; updater messages have none."""
    assert M.msgid_of(B.encode(bundle(3, 0x1234))) == 0x34
    assert M.msgid_of(big_payload(40)) is None
    assert M.msgid_of(bytes(7)) is None


def test_fragment_layout() -> None:
    """75 words: S = 602 bytes -> fragments of 250, 250, 102 at offsets 0, 250, 500, then a
    ping carrying the count: 'F' id addr index offset(BE) chunk / 'P' id addr count."""
    payload = big_payload(75)
    engine = M.XbeeMav(5, clock=FakeClock(), interframe_s=0)
    engine.submit(payload, 0x42)
    out = engine.pump()
    packet = bytes((5, 0x42)) + payload
    assert out == [
        b"F\x42\x05\x00\x00\x00" + packet[:250],
        b"F\x42\x05\x01\x00\xfa" + packet[250:500],
        b"F\x42\x05\x02\x01\xf4" + packet[500:],
        b"P\x42\x05\x03",
    ]
    assert max(len(rf) for rf in out) == M.MAX_RF_DATA


@pytest.mark.parametrize(
    ("words", "kind", "frames"),
    [(1, "S", 1), (30, "S", 1), (31, "F", 1), (32, "F", 2), (M.MAX_DATA // 8, "F", 255)],
)
def test_size_paths(words: int, kind: str, frames: int) -> None:
    """S < 250 is standard; S = 250 (31 words, which XbeeMav drops) is one fragment; the
    largest payload takes 255 fragments, the most a u8 count announces."""
    engine = M.XbeeMav(1, clock=FakeClock(), interframe_s=0)
    engine.submit(bytes(8 * words), 9)
    out = engine.pump()
    assert out[0][:1] == kind.encode()
    if kind == "S":
        assert out == [b"S\x01\x09" + bytes(8 * words)] and len(out[0]) <= 250
    else:
        assert len(out) == frames + 1 and out[-1] == bytes((ord("P"), 9, 1, frames))


@pytest.mark.parametrize("size", [0, 7, 12, M.MAX_DATA + 8])
def test_submit_refuses_what_cannot_go(size: int) -> None:
    """Empty, partial words, too large: ValueError."""
    with pytest.raises(ValueError):
        M.XbeeMav(1).submit(bytes(size), 0)


def transfer(
    sender: M.XbeeMav,
    receiver: M.XbeeMav,
    clock: FakeClock,
    lose: Callable[[bytes], bool] = lambda rf: False,
    order: Callable[[list[bytes]], list[bytes]] = lambda rfs: rfs,
    rounds: int = 10,
) -> list[bytes]:
    """Run sender -> receiver (acks back) until the sender is idle; the payloads delivered."""
    delivered = []
    for _ in range(rounds):
        rfs = order(sender.pump())
        for rf in rfs:
            if not lose(rf):
                got = receiver.receive(sender.address, rf)
                if got is not None:
                    delivered.append(got)
        for ack in receiver.pump():
            sender.receive(receiver.address, ack)
        clock.now += sender.round_wait_s
        if not sender.transferring and not sender.queued:
            break
    return delivered


def pair(**options: object) -> tuple[M.XbeeMav, M.XbeeMav, FakeClock]:
    """Sender 1 and receiver 2 that know each other, unpaced."""
    clock = FakeClock()
    a = M.XbeeMav(1, clock=clock, interframe_s=0, **options)  # type: ignore[arg-type]
    b = M.XbeeMav(2, clock=clock, interframe_s=0, **options)  # type: ignore[arg-type]
    a.receive(2, B.to_rf_data(bundle(2, 1)))  # heard: 2 is a node whose ack counts
    return a, b, clock


@given(
    st.integers(31, M.MAX_DATA // 8),
    st.randoms(use_true_random=False),
)
@settings(max_examples=60, deadline=None)
def test_fragmented_round_trip_any_order(words: int, rng: random.Random) -> None:
    """Any size up to the maximum, fragments shuffled and duplicated: delivered once, intact,
    acked complete in one round."""
    a, b, clock = pair()
    payload = big_payload(words, rng.randrange(1000))
    a.submit(payload, 77)

    def shuffle(rfs: list[bytes]) -> list[bytes]:
        frags = [rf for rf in rfs if rf[:1] == b"F"]
        rest = [rf for rf in rfs if rf[:1] != b"F"]
        mixed = frags + rng.sample(frags, rng.randrange(len(frags) + 1))
        rng.shuffle(mixed)
        return mixed + rest

    assert transfer(a, b, clock, order=shuffle) == [payload]
    assert a.stats["transfers_done"] == 1 and a.stats["resent_fragments"] == 0
    assert b.partials == 0 and b.partial_bytes == 0


def test_lost_fragment_is_reported_and_resent() -> None:
    """The ack names the missing index; the sender resends only it and pings again."""
    a, b, clock = pair()
    payload = big_payload(100)
    a.submit(payload, 5)
    lost = []

    def lose(rf: bytes) -> bool:
        if rf[:1] == b"F" and rf[3] == 2 and not lost:
            lost.append(rf)
            return True
        return False

    acks: list[bytes] = []
    original = b.pump

    def recording_pump() -> list[bytes]:
        out = original()
        acks.extend(out)
        return out

    b.pump = recording_pump  # type: ignore[method-assign]
    assert transfer(a, b, clock, lose=lose) == [payload]
    assert acks[0] == b"A\x05\x02\x02"  # packet 5, from robot 2, missing fragment 2
    assert acks[-1] == b"A\x05\x02"  # complete
    assert a.stats["resent_fragments"] == 1 and a.stats["transfers_done"] == 1
    assert a.stats["pings_out"] == 2


def test_ping_with_nothing_received_asks_for_everything() -> None:
    """XbeeMav stays silent; we list every index, so the sender resends the packet."""
    _, b, _ = pair()
    assert b.receive(1, b"P\x09\x01\x04") is None
    assert b.pump() == [b"A\x09\x02\x00\x01\x02\x03"]


def test_late_fragments_are_not_delivered_twice() -> None:
    """After delivery, retransmitted fragments (for another node) are ignored and their ping
    is acked complete again; a new packet reusing the id is delivered."""
    a, b, clock = pair()
    payload = big_payload(40)
    a.submit(payload, 9)
    rfs = a.pump()
    delivered = [d for rf in rfs if (d := b.receive(1, rf)) is not None]
    assert delivered == [payload]
    b.pump()
    for rf in rfs:  # the whole packet again, as a resend for a third robot would look
        assert b.receive(1, rf) is None
    assert b.stats["late_fragments"] == len(rfs) - 1
    assert b.pump() == [b"A\x09\x02"] and b.stats["reacks"] == 1
    other = big_payload(40, seed=1)
    c = M.XbeeMav(1, clock=clock, interframe_s=0)
    c.submit(other, 9)
    assert [d for rf in c.pump() if (d := b.receive(1, rf)) is not None] == [other]


def test_inconsistent_offsets_are_not_assembled() -> None:
    """Fragments whose offsets do not tile the packet: dropped, counted, all re-requested."""
    _, b, _ = pair()
    b.receive(1, b"F\x01\x01\x00\x00\x00" + bytes(250))
    b.receive(1, b"F\x01\x01\x01\x00\xf0" + bytes(10))  # should be at 250
    assert b.receive(1, b"P\x01\x01\x02") is None
    assert b.stats["bad_packets"] == 1
    assert b.pump() == [b"A\x01\x02\x00\x01"]


def test_standard_packets_of_partial_words_are_dropped() -> None:
    """'S' with no words or a partial word: counted, not delivered."""
    _, b, _ = pair()
    for rf in (b"S\x01\x02", b"S\x01\x02" + bytes(12), b"S\x01"):
        assert b.receive(1, rf) is None
    assert b.stats["bad_packets"] == 3


def test_transfer_with_no_known_node_is_one_round() -> None:
    """Nobody heard: fragments and one ping, then done (XbeeMav would ping for 30 s)."""
    clock = FakeClock()
    a = M.XbeeMav(1, clock=clock, interframe_s=0)
    a.submit(big_payload(40), 1)  # 322 bytes: 2 fragments
    assert [rf[:1] for rf in a.pump()] == [b"F", b"F", b"P"]
    clock.now += 0.5
    assert a.pump() == [] and not a.transferring
    assert a.stats["transfers_unacked"] == 1


def test_transfer_times_out_after_30_s() -> None:
    """A known node that never acks: pings every round until the 30 s deadline."""
    a, _, clock = pair()
    a.submit(big_payload(40), 1)
    pings = sum(rf[:1] == b"P" for rf in a.pump())
    assert a.transferring
    while a.transferring:
        pings += sum(rf[:1] == b"P" for rf in a.pump())
        clock.now += 0.25
        assert clock.now < 200
    assert a.stats["transfers_timeout"] == 1
    assert 50 <= pings <= 61  # one per 500 ms wait


def test_nodes_are_forgotten_after_their_ttl() -> None:
    """A robot not heard for node_ttl_s no longer holds transfers up."""
    a, _, clock = pair(node_ttl_s=10.0)
    assert a.known_nodes() == {2}
    clock.now += 11
    assert a.known_nodes() == set()


def test_pacing_is_a_token_bucket() -> None:
    """`burst` frames at once, then one per interframe_s; the standard queue keeps the newest."""
    clock = FakeClock()
    a = M.XbeeMav(1, clock=clock, interframe_s=0.1, burst=2, max_standard_queue=3)
    for n in range(5):
        a.submit(bytes(8), n)
    assert a.stats["dropped_standard"] == 2
    assert [rf[2] for rf in a.pump()] == [2, 3]
    clock.now += 0.05
    assert a.pump() == []
    clock.now += 0.05
    assert [rf[2] for rf in a.pump()] == [4]
    clock.now += 1.0
    assert a.pump() == []


def test_standard_packets_and_a_transfer_alternate() -> None:
    """While a large packet goes out, bundles keep flowing: one each, by turns."""
    a, _, clock = pair()
    a.interframe_s = a.base_interframe_s = 0.1
    a.submit(big_payload(100), 1)
    for n in range(3):
        a.submit(bytes(8), n)
    kinds = []
    for _ in range(8):
        kinds += [rf[:1] for rf in a.pump()]
        clock.now += 0.1
    assert b"".join(kinds) == b"SFSFSFFP"


def test_acks_go_first() -> None:
    """An ack jumps the queue: a sender waits on it."""
    clock = FakeClock()
    b = M.XbeeMav(2, clock=clock, interframe_s=0.1, burst=1)
    b.submit(bytes(8), 1)
    b.submit(bytes(8), 2)
    b.receive(1, b"P\x07\x01\x01")
    assert b.pump() == [b"A\x07\x02\x00"]


def test_interframe_adapts_like_xbeemav() -> None:
    """-5 ms after a one-round transfer, +5 ms after one that needed resends."""
    a, b, clock = pair()
    a.interframe_s = a.base_interframe_s = 0.1
    a.submit(big_payload(40), 1)
    transfer(a, b, clock, rounds=20)
    assert a.stats["transfers_done"] == 1
    assert a.interframe_s == pytest.approx(0.095)
    a.submit(big_payload(40), 2)
    dropped: list[bytes] = []

    def lose_first_fragment(rf: bytes) -> bool:
        if rf[:1] == b"F" and not dropped:
            dropped.append(rf)
            return True
        return False

    transfer(a, b, clock, lose=lose_first_fragment, rounds=40)
    assert a.stats["transfers_done"] == 2
    assert a.interframe_s == pytest.approx(0.1)


def test_reassembly_memory_is_bounded() -> None:
    """Partial packets: per-sender and total caps evict the least recently active; the rest
    expire 30 s after their first fragment."""
    clock = FakeClock()
    b = M.XbeeMav(
        0, clock=clock, max_partials_per_sender=2, max_partials=8, max_partial_bytes=M.MAX_PACKET
    )
    chunk = bytes(250)
    for sender in range(1, 40):
        for pid in range(5):
            for index in range(20):
                off = (index * 250).to_bytes(2, "big")
                b.receive(sender, b"F" + bytes((pid, sender, index)) + off + chunk)
            assert b.partial_bytes <= M.MAX_PACKET
            assert b.partials <= 8
    assert b.stats["partials_evicted"] > 100
    clock.now += 31
    b.pump()
    assert b.partials == 0 and b.partial_bytes == 0
    assert b.stats["partials_expired"] > 0


@given(st.lists(st.tuples(st.integers(0, 255), st.binary(max_size=300)), max_size=40))
@settings(max_examples=300, deadline=None)
def test_receive_never_raises(events: list[tuple[int, bytes]]) -> None:
    """Arbitrary RF data from arbitrary senders only moves counters."""
    b = M.XbeeMav(0, clock=FakeClock())
    for sender, rf in events:
        data = b.receive(sender, rf)
        assert data is None or (data and len(data) % 8 == 0)
    for rf in b.pump():
        assert 0 < len(rf) <= M.MAX_RF_DATA


def test_sender_byte() -> None:
    """The id a packet names itself: 'S' sysid, F/P/A address."""
    assert M.sender_byte(b"S\x07\x01") == 7
    assert M.sender_byte(b"F\x01\x08\x00") == 8
    assert M.sender_byte(b"Q\x01\x08") is None
    assert M.sender_byte(b"A\x01") is None


# ---------------------------------------------------------------- the mesh of fake modules


class Module:
    """One simulated XBee module: the master side of a pty whose slave a radio opens."""

    def __init__(self, serial64: int, api_mode: int) -> None:
        self.serial64 = serial64
        self.api_mode = api_mode
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        os.set_blocking(self.master, False)
        self.reader = X.FrameReader(api_mode)
        self.raw = bytearray()  # every byte the radio wrote
        self.sent: list[bytes] = []  # the RF data of every transmit request
        self.out = bytearray()  # bytes for the radio not yet written
        self.written = 0  # bytes written to the radio
        self.radio: XBeeRadio | None = None
        self._in0 = self._out0 = 0  # the radio's byte counters when this module got it

    def serve(self, radio: XBeeRadio) -> None:
        """Be `radio`'s module from now on (it counted bytes with another module before)."""
        self.radio = radio
        self._in0, self._out0 = radio.stats["bytes_in"], radio.stats["bytes_out"]

    def in_flight(self) -> bool:
        """Whether bytes are on their way between this module and its radio."""
        if self.radio is None:
            return False
        stats = self.radio.stats
        return (
            bool(self.out)
            or self.written != stats["bytes_in"] - self._in0
            or len(self.raw) != stats["bytes_out"] - self._out0
        )

    def close(self) -> None:
        """Close both ends."""
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


class Mesh:
    """Fake XBee modules that relay every transmit request to every other module."""

    def __init__(self, api_mode: int = 1) -> None:
        self.api_mode = api_mode
        self.modules: list[Module] = []
        self.drop: Callable[[Module, Module, bytes], bool] = lambda src, dst, rf: False
        self.corrupt: Callable[[Module, Module, bytes], bool] = lambda src, dst, rf: False

    def add(self, serial64: int) -> Module:
        """A new module on the mesh."""
        module = Module(serial64, self.api_mode)
        self.modules.append(module)
        return module

    def pump(self) -> bool:
        """Move what the radios wrote; whether anything moved."""
        moved = False
        for m in self.modules:
            try:
                data = os.read(m.master, 65536)
            except (BlockingIOError, OSError):
                data = b""
            if not data:
                continue
            moved = True
            m.raw += data
            for frame in m.reader.feed(data):
                assert isinstance(frame, X.TransmitRequest), frame
                assert frame.dest64 == X.BROADCAST64
                m.sent.append(frame.rf_data)
                if frame.frame_id:
                    m.out += X.TransmitStatus(frame.frame_id).encode(self.api_mode)
                for other in self.modules:
                    if other is m or self.drop(m, other, frame.rf_data):
                        continue
                    rx = DigiReceive(
                        XBee64BitAddress.from_hex_string(f"{m.serial64:016X}"),
                        XBee16BitAddress.from_hex_string("FFFE"),
                        2,
                        rf_data=bytearray(frame.rf_data),
                    ).output(escaped=self.api_mode == 2)
                    if self.corrupt(m, other, frame.rf_data):
                        rx = bytearray(rx)
                        rx[len(rx) // 2] ^= 0x40
                    other.out += rx
        for m in self.modules:
            if m.out:
                try:
                    n = os.write(m.master, m.out)
                except BlockingIOError:
                    continue
                del m.out[:n]
                m.written += n
                moved = True
        return moved

    def close(self) -> None:
        """Close every pty."""
        for m in self.modules:
            m.close()


@pytest.fixture
def mesh() -> Iterator[Callable[[int], Mesh]]:
    """Make a mesh in API mode 1 or 2; closed after the test."""
    made: list[Mesh] = []

    def make(api_mode: int = 1) -> Mesh:
        made.append(Mesh(api_mode))
        return made[-1]

    yield make
    for m in made:
        m.close()


def run(
    mesh: Mesh,
    radios: list[XBeeRadio],
    clock: FakeClock,
    until: Callable[[dict[int, list[tuple[int, bytes]]]], bool],
    got: dict[int, list[tuple[int, bytes]]] | None = None,
    *,
    step: float = 0.05,
    limit_s: float = 30.0,
) -> dict[int, list[tuple[int, bytes]]]:
    """Relay and poll until `until(received)`.

    The fake clock moves only when the wire is quiet: every byte written has been read on
    the other side (counted at both ends, no timing guess) and the last relay moved nothing.
    """
    got = {r.robot_id: [] for r in radios} if got is None else got
    fds = [m.master for m in mesh.modules] + [fd for r in radios if (fd := r.fileno()) is not None]
    deadline = time.monotonic() + limit_s
    while not until(got):
        assert time.monotonic() < deadline, {r.robot_id: dict(r.stats) for r in radios}
        moved = mesh.pump()
        for r in radios:
            got[r.robot_id] += r.poll()
        if any(m.in_flight() for m in mesh.modules):
            select.select(fds, [], [], 0.05)  # wait for the kernel to pass the bytes on
        elif not moved:
            clock.now += step
    return got


def radios_on(mesh: Mesh, ids: list[int], clock: FakeClock, **options: object) -> list[XBeeRadio]:
    """One XBeeRadio per id, each on its own module with that id's serial."""
    out = []
    for rid in ids:
        module = mesh.add(SERIALS.get(rid, 0x0013A200DEAD0000 + rid))
        module.radio = XBeeRadio(
            module.path,
            rid,
            api_mode=mesh.api_mode,
            id_map=ID_MAP,
            clock=clock,
            **options,  # type: ignore[arg-type]
        )
        out.append(module.radio)
    return out


@pytest.mark.parametrize("api_mode", [1, 2])
def test_two_radios_exchange_bundles(mesh: Callable[[int], Mesh], api_mode: int) -> None:
    """Bundles both ways over real ptys; the bytes on the wire are XbeeMav's frames."""
    net = mesh(api_mode)
    clock = FakeClock()
    r1, r2 = radios_on(net, [1, 2], clock)
    b1, b2 = bundle(1, 10), bundle(2, 20, b"there")
    r1.send(B.encode(b1))
    r2.send(B.encode(b2))
    got = run(net, [r1, r2], clock, lambda g: bool(g[1] and g[2]))
    assert got[2] == [(1, B.encode(b1))] and got[1] == [(2, B.encode(b2))]
    assert B.decode(got[2][0][1]) == b1
    assert bytes(net.modules[0].raw) == X.transmit_request(B.to_rf_data(b1), api_mode=api_mode)
    run(net, [r1, r2], clock, lambda g: r1.stats["tx_status"] == 1)
    assert r1.stats["frames_out"] == 1 and r1.stats["frames_in"] == 2
    assert r1.stats["bad_frames"] == 0
    for r in (r1, r2):
        r.close()


def test_radio_writes_the_spec_frame(mesh: Callable[[int], Mesh]) -> None:
    """Robot 7 sending the worked example's bundle writes its API frame exactly (docs/bundle.md)."""
    net = mesh(1)
    clock = FakeClock()
    (r7,) = radios_on(net, [7], clock)
    r7.send(B.encode(EXAMPLE))
    run(net, [r7], clock, lambda g: len(net.modules[0].raw) >= 4 + 0x51)
    raw = bytes(net.modules[0].raw)
    assert raw[:17] == bytes.fromhex("7e 00 51 10 01 00 00 00 00 00 00 ff ff ff ff 00 00")
    assert raw == X.transmit_request(B.to_rf_data(EXAMPLE))
    r7.close()


def test_io_errors_are_counted_not_raised(mesh: Callable[[int], Mesh]) -> None:
    """The module vanishes (pty master closed): poll and send keep going, counting."""
    net = mesh(1)
    clock = FakeClock()
    (r1,) = radios_on(net, [1], clock)
    os.close(net.modules[0].master)
    deadline = time.monotonic() + 10
    while not r1.stats["io_errors"]:
        assert time.monotonic() < deadline, dict(r1.stats)
        assert r1.poll() == []
        r1.send(B.encode(bundle(1, 1)))
        clock.now += 0.5
    r1.close()


def test_a_module_unplugged_and_back_is_reopened_through_its_symlink(
    mesh: Callable[[int], Mesh], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """/dev/xbee (a symlink) loses its module mid-run and gets it back as another tty: the
    radio never raises, drops and counts what it would send meanwhile, tries the path once
    a second, logs the loss and the return once each, and then talks again."""
    caplog.set_level(logging.INFO, logger="fieldkit.radio")
    net = mesh(1)
    clock = FakeClock()
    path = str(tmp_path / "xbee")
    (r1,) = radios_on(net, [1], clock)
    old = net.add(SERIALS[2])
    os.symlink(old.path, path)
    r2 = XBeeRadio(path, 2, api_mode=1, id_map=ID_MAP, clock=clock)
    old.radio = r2
    try:
        r2.send(B.encode(bundle(2, 1)))
        got = run(net, [r1, r2], clock, lambda g: bool(g[1]))
        assert got[1] == [(2, B.encode(bundle(2, 1)))]

        # The cable goes: the module's pty closes, the node file with it.
        stale = os.open(old.path, os.O_RDWR | os.O_NOCTTY)  # the old tty stays taken
        net.modules.remove(old)
        old.close()
        os.unlink(path)
        for k in range(50):  # five seconds, a bundle a tick
            assert r2.poll() == []
            r2.send(B.encode(bundle(2, 10 + k)))
            clock.now += 0.1
        assert r2.down and r2.fileno() is None
        assert r2.stats["frames_dropped_down"] >= 45  # paced out of the queue, then dropped
        assert r2.stats["reopen_failures"] == 4  # once a second, not once a poll
        # What the node's STATUS= and summary.json say of it (fieldkit/node/health.py).
        lost_at = clock.now - r2.down_for()
        health = radio_health(r2)
        assert health.down_for_s == pytest.approx(clock.now - lost_at) and health.outages == 1
        assert health.down_s == health.down_for_s
        assert health.dropped == r2.stats["frames_dropped_down"]
        assert health.status("radio") == f"radio link down {health.down_for_s:.1f} s"
        lines = [(r.levelname, r.getMessage()) for r in caplog.records]
        assert len(lines) == 1 and lines[0][0] == "WARNING"
        assert re.fullmatch(rf"radio: {re.escape(path)} lost \(read failed: .+\); reopening",
                            lines[0][1])  # fmt: skip

        # Back, as another tty behind the same symlink.
        new = net.add(SERIALS[2])
        os.close(stale)
        assert new.path != old.path
        os.symlink(new.path, path + ".new")
        os.replace(path + ".new", path)
        for _ in range(20):
            if not r2.down:
                break
            r2.poll()
            clock.now += 0.1
        assert not r2.down and r2.stats["reopens"] == 1
        back = radio_health(r2)
        assert back.down_for_s is None and back.outages == 1 and r2.down_for() == 0.0
        assert back.down_s == pytest.approx(clock.now - 0.1 - lost_at)  # reopened a poll ago
        assert back.status("radio") == f"radio link lost once, {back.down_s:.1f} s in all"
        new.serve(r2)
        assert len(caplog.records) == 2
        assert re.fullmatch(rf"radio: {re.escape(path)} back after [\d.]+ s \(\d+ frames dropped "
                            r"meanwhile\)", caplog.records[1].getMessage())  # fmt: skip
        r1.send(B.encode(bundle(1, 2)))
        r2.send(B.encode(bundle(2, 99)))
        got = run(net, [r1, r2], clock, lambda g: bool(g[1] and g[2]))
        assert got[2] == [(1, B.encode(bundle(1, 2)))]
        # What was sent during the outage is gone, none of it late; the new bundle goes.
        assert got[1] == [(2, B.encode(bundle(2, 99)))]
        assert r2.stats["frames_dropped_down"] == 50
        assert r2.stats["bad_frames"] == 0
    finally:
        r1.close()
        r2.close()


# ---------------------------------------------------------------- URLs and profiles


def test_from_url_forms(mesh: Callable[[int], Mesh]) -> None:
    """serial:// with baud and api, a plain path, pyserial's loop://; bad URLs raise."""
    net = mesh(1)
    m = net.add(SERIALS[1])
    r = XBeeRadio.from_url(f"serial://{m.path}?baud=57600&api=2&unknown=sysid", 1)
    assert (r.api_mode, r.unknown, r._baud) == (2, "sysid", 57600)
    r.close()
    r = XBeeRadio.from_url(m.path, 1)
    assert (r.api_mode, r.unknown, r._baud) == (1, "drop", 230400)
    r.close()
    r = open_radio("loop://?api=2", 4)
    assert isinstance(r, XBeeRadio) and isinstance(r, RadioLink)
    r.send(B.encode(bundle(4, 1)))
    assert r.poll() == []  # loop:// echoes our own 0x10 frame: ignored
    assert r.stats["ignored_frames"] == 1 and r.stats["frames_in"] == 1
    r.close()
    for bad in ("serial://", f"serial://{m.path}?parity=N", f"serial://{m.path}?api=x"):
        with pytest.raises(ValueError):
            XBeeRadio.from_url(bad, 1)
    with pytest.raises(ValueError):
        XBeeRadio.from_url(m.path, 1, api_mode=3)
    with pytest.raises(ValueError):
        XBeeRadio.from_url(m.path, 256)


def test_from_profile(mesh: Callable[[int], Mesh]) -> None:
    """A profile's [radio]: port, baud, API mode, id_map; an empty id_map means sysid."""
    m = mesh(1).add(SERIALS[1])
    radio = RadioSettings("xbee", m.path, 230400, 2, 24580, 190, ID_MAP)
    r = from_profile(radio, 1)
    assert isinstance(r, XBeeRadio)
    assert (r.api_mode, r.unknown, r.ids.lookup(SERIALS[2])) == (2, "drop", 2)
    r.close()
    r = from_profile(RadioSettings("xbee", m.path, 230400, 1, 24580, 190), 1)
    assert isinstance(r, XBeeRadio) and r.unknown == "sysid"
    r.close()
