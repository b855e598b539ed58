"""The XBee radio's sans-I/O core (`XBeeCore`): bytes and time in, frames and events out.

No port, no pty, no sleep: `Air` plays the XBee modules in memory. It de-frames each core's
0x10 transmit requests, answers 0x8B transmit status and hands every other core a 0x90 receive
packet built by digi-xbee (an implementation independent of ours), optionally dropping or
corrupting frames. Time is a number the test moves.
"""

from __future__ import annotations

import random
import struct
from collections.abc import Callable

import pytest
from digi.xbee.models.address import XBee16BitAddress, XBee64BitAddress
from digi.xbee.packets.common import ReceivePacket as DigiReceive
from fuzz.bundle_fuzz import EXAMPLE

from fieldkit.radio import xbee as X
from fieldkit.radio.xbee_core import ModemEvent, PacketReceived, TransmitReport, XBeeCore
from fieldkit.robot import bundle as B

SERIALS = {1: 0x0013A20040000001, 2: 0x0013A20040000002, 3: 0x0013A20040000003}
ID_MAP = {f"{s:016X}": i for i, s in SERIALS.items()}

Rule = Callable[[int, int, bytes], bool]


def bundle(robot: int, number: int, text: bytes = b"hi") -> B.Bundle:
    """A small bundle from `robot`."""
    return B.Bundle(robot, (text,), 45.0, -73.0, 5.0, number=number)


def big_payload(words: int, seed: int = 0) -> bytes:
    """An updater-like payload (word 0 = 1, as ROSBuzz's UPDATER_MESSAGE) of `words` words."""
    rng = random.Random(seed)
    return struct.pack(">Q", 1) + rng.randbytes(8 * (words - 1))


class Air:
    """XBee modules in memory: each core's frames reach every other core, as on a mesh."""

    def __init__(self, api_mode: int = 1) -> None:
        self.api_mode = api_mode
        self.now = 100.0
        self.cores: dict[int, XBeeCore] = {}
        self.serials: dict[int, int] = {}
        self.readers: dict[int, X.FrameReader] = {}
        self.raw: dict[int, bytearray] = {}  # every byte each core wrote
        self.sent: dict[int, list[bytes]] = {}  # the RF data of each core's transmit requests
        self.got: dict[int, list[tuple[int, bytes]]] = {}
        self.events: dict[int, list[object]] = {}
        self.drop: Rule = lambda src, dst, rf: False
        self.corrupt: Rule = lambda src, dst, rf: False

    def add(self, robot: int, serial64: int | None = None, **options: object) -> XBeeCore:
        """A core for `robot` on a module with `serial64` (the robot's own serial by default)."""
        core = XBeeCore(
            robot,
            api_mode=self.api_mode,
            id_map=ID_MAP,
            now=self.now,
            **options,  # type: ignore[arg-type]
        )
        self.cores[robot] = core
        self.serials[robot] = SERIALS.get(robot, 0x0013A200DEAD0000 + robot)
        if serial64 is not None:
            self.serials[robot] = serial64
        self.readers[robot] = X.FrameReader(self.api_mode)
        self.raw[robot] = bytearray()
        self.sent[robot] = []
        self.got[robot] = []
        self.events[robot] = []
        return core

    def step(self, dt: float = 0.05) -> None:
        """Every core writes what is due; every frame is relayed; time moves by `dt`."""
        inbox: dict[int, bytearray] = {r: bytearray() for r in self.cores}
        for src, core in self.cores.items():
            data = b"".join(core.frames_to_send(self.now))
            self.raw[src] += data
            for frame in self.readers[src].feed(data):
                assert isinstance(frame, X.TransmitRequest), frame
                assert frame.dest64 == X.BROADCAST64
                self.sent[src].append(frame.rf_data)
                if frame.frame_id:
                    inbox[src] += X.TransmitStatus(frame.frame_id).encode(self.api_mode)
                for dst in self.cores:
                    if dst == src or self.drop(src, dst, frame.rf_data):
                        continue
                    rx = DigiReceive(
                        XBee64BitAddress.from_hex_string(f"{self.serials[src]:016X}"),
                        XBee16BitAddress.from_hex_string("FFFE"),
                        2,
                        rf_data=bytearray(frame.rf_data),
                    ).output(escaped=self.api_mode == 2)
                    if self.corrupt(src, dst, frame.rf_data):
                        rx = bytearray(rx)
                        rx[len(rx) // 2] ^= 0x40
                    inbox[dst] += rx
        self.now += dt
        for robot, core in self.cores.items():
            for event in core.receive_data(bytes(inbox[robot]), self.now):
                self.events[robot].append(event)
                if isinstance(event, PacketReceived):
                    self.got[robot].append((event.sender, event.data))

    def run(self, until: Callable[[], bool], limit_s: float = 30.0) -> None:
        """Step until `until()`, at most `limit_s` of simulated time."""
        end = self.now + limit_s
        while not until():
            assert self.now < end, {r: dict(c.stats) for r, c in self.cores.items()}
            self.step()


@pytest.mark.parametrize("api_mode", [1, 2])
def test_two_cores_exchange_bundles(api_mode: int) -> None:
    """Bundles both ways; the bytes are XbeeMav's frames; the status frames come as events."""
    air = Air(api_mode)
    c1, c2 = air.add(1), air.add(2)
    b1, b2 = bundle(1, 10), bundle(2, 20, b"there")
    c1.submit(B.encode(b1))
    c2.submit(B.encode(b2))
    air.run(lambda: bool(air.got[1] and air.got[2]))
    assert air.got[2] == [(1, B.encode(b1))] and air.got[1] == [(2, B.encode(b2))]
    assert bytes(air.raw[1]) == X.transmit_request(B.to_rf_data(b1), api_mode=api_mode)
    assert TransmitReport(1, 0) in air.events[1] and not TransmitReport(1, 0).failed
    assert c1.stats["tx_status"] == 1 and c1.stats["frames_in"] == 2
    assert c1.stats["bad_frames"] == 0


def test_core_writes_the_spec_frame() -> None:
    """Robot 7 sending the example bundle writes XbeeMav's API frame byte for byte."""
    core = XBeeCore(7, now=0.0)
    core.submit(B.encode(EXAMPLE))
    raw = b"".join(core.frames_to_send(0.0))
    assert raw[:17] == bytes.fromhex("7e 00 51 10 01 00 00 00 00 00 00 ff ff ff ff 00 00")
    assert raw == X.transmit_request(B.to_rf_data(EXAMPLE))


def test_status_frames_become_events() -> None:
    """A failed transmit status and a modem status are reported and counted; other frame
    types are counted and ignored."""
    core = XBeeCore(1)
    line = (
        X.TransmitStatus(1, delivery_status=0x21).encode(1)
        + X.ModemStatus(0).encode(1)
        + X.AtResponse(1, b"SH", 0, b"\x00\x13\xa2\x00").encode(1)
    )
    events = core.receive_data(line, 1.0)
    assert events == [TransmitReport(1, 0x21), ModemEvent(0)]
    assert isinstance(events[0], TransmitReport) and events[0].failed
    assert (core.stats["tx_failed"], core.stats["modem_status"]) == (1, 1)
    assert core.stats["ignored_frames"] == 1 and core.stats["bytes_in"] == len(line)


def test_any_split_of_the_line_gives_the_same_packets() -> None:
    """Bytes fed one at a time give what the whole stream gives."""
    rx = [X.receive_packet(SERIALS[2], B.to_rf_data(bundle(2, n))) for n in range(3)]
    whole = XBeeCore(1, id_map=ID_MAP)
    expected = whole.receive_data(b"".join(rx), 0.0)
    assert [e for e in expected if isinstance(e, PacketReceived)] == [
        PacketReceived(2, B.encode(bundle(2, n))) for n in range(3)
    ]
    piecewise = XBeeCore(1, id_map=ID_MAP)
    got = [e for byte in b"".join(rx) for e in piecewise.receive_data(bytes((byte,)), 0.0)]
    assert got == expected


def test_a_truncated_frame_is_flushed_after_the_line_goes_quiet() -> None:
    """Half a frame, then silence: once `idle_flush_s` has passed it is dropped as truncated
    and a frame after it is read at once."""
    core = XBeeCore(1, id_map=ID_MAP, idle_flush_s=0.1)
    good = X.receive_packet(SERIALS[2], B.to_rf_data(bundle(2, 1)))
    assert core.receive_data(good[:10], 0.0) == []
    assert core.receive_data(b"", 0.05) == [] and core.reader.pending == 10
    assert core.receive_data(b"", 0.2) == [] and core.stats["truncated"] == 1
    assert core.receive_data(good, 0.3) == [PacketReceived(2, B.encode(bundle(2, 1)))]


def test_reset_forgets_a_partial_frame() -> None:
    """After a reopen the rest of a partial frame never comes: `reset` drops it uncounted."""
    core = XBeeCore(1, id_map=ID_MAP)
    core.receive_data(X.receive_packet(SERIALS[2], b"S\x02\x00" + bytes(8))[:7], 0.0)
    core.reset()
    assert core.reader.pending == 0 and core.stats["truncated"] == 0


def test_pacing_follows_the_fed_time() -> None:
    """The engine's clock is the time the core was fed: 4 bundles leave 2 (the burst), then
    one per 100 ms of fed time, whatever the wall clock does."""
    core = XBeeCore(1, now=0.0)
    for n in range(4):
        core.submit(B.encode(bundle(1, n)))
    assert len(core.frames_to_send(0.0)) == 2
    assert core.frames_to_send(0.05) == []
    assert len(core.frames_to_send(0.1)) == 1
    assert len(core.frames_to_send(0.2)) == 1


@pytest.mark.parametrize("api_mode", [1, 2])
def test_large_payload_with_a_lost_fragment(api_mode: int) -> None:
    """A 600-byte payload goes as 3 fragments; the air loses fragment 1 on its way to robot
    2; robot 2's ack asks for it, robot 1 resends it, robot 2 delivers the payload once."""
    air = Air(api_mode)
    c1, c2 = air.add(1), air.add(2)
    c2.submit(B.encode(bundle(2, 1)))  # robot 1 hears robot 2: a node whose ack it awaits
    air.run(lambda: bool(air.got[1]))
    lost: list[bytes] = []

    def drop(src: int, dst: int, rf: bytes) -> bool:
        if rf[:1] == b"F" and rf[3] == 1 and not lost:
            lost.append(rf)
            return True
        return False

    air.drop = drop
    payload = big_payload(75)
    c1.submit(payload)
    air.run(lambda: bool(air.got[2]) and not c1.engine.transferring)
    assert air.got[2] == [(1, payload)]
    sent = [rf for rf in air.sent[1] if rf[:1] == b"F"]
    assert [rf[3] for rf in sent] == [0, 1, 2, 1]
    assert lost == [sent[1]] and sent[3] == sent[1]
    assert c1.stats["resent_fragments"] == 1 and c1.stats["transfers_done"] == 1
    assert [rf for rf in air.sent[2] if rf[:1] == b"A"] == [b"A\x01\x02\x01", b"A\x01\x02"]


def test_three_cores_corruption_and_bundles_during_a_transfer() -> None:
    """API mode 2, three robots: a corrupted frame to robot 3 is counted and lost; a large
    payload reaches both others while bundles keep flowing."""
    air = Air(2)
    cores = [air.add(r) for r in (1, 2, 3)]
    c1, c2, c3 = cores
    hit: list[bytes] = []

    def corrupt(src: int, dst: int, rf: bytes) -> bool:
        if dst == 3 and rf[:1] == b"S" and not hit:
            hit.append(rf)
            return True
        return False

    air.corrupt = corrupt
    for c in cores:
        c.submit(B.encode(bundle(c.robot_id, 1)))
    air.run(lambda: len(air.got[1]) == 2 and len(air.got[2]) == 2 and bool(air.got[3]))
    assert len(air.got[3]) == 1  # the corrupted one is gone
    assert c3.stats["bad_checksum"] + c3.stats["bad_escape"] + c3.stats["truncated"] >= 1
    payload = big_payload(200, seed=3)
    c1.submit(payload)
    for n in range(2, 6):
        c2.submit(B.encode(bundle(2, n)))
    air.run(
        lambda: (
            (1, payload) in air.got[2] and (1, payload) in air.got[3] and not c1.engine.transferring
        )
    )
    assert air.got[2].count((1, payload)) == 1 and air.got[3].count((1, payload)) == 1
    assert [d for s, d in air.got[1] if s == 2] == [B.encode(bundle(2, n)) for n in range(1, 6)]
    assert c1.stats["transfers_done"] == 1


def test_unknown_serials_are_dropped_or_named_by_sysid() -> None:
    """Robot 9's serial is in no table: the "drop" core counts and drops its frames, the
    "sysid" core takes the id from the packet."""
    air = Air(1)
    c1 = air.add(1)
    c2 = air.add(2, unknown="sysid")
    c9 = air.add(9)
    c9.submit(B.encode(bundle(9, 4)))
    air.run(lambda: bool(air.got[2]) and c1.stats["unknown_senders"] > 0)
    assert air.got[2] == [(9, B.encode(bundle(9, 4)))]
    assert air.got[1] == [] and c1.stats["dropped_unknown"] == 1
    assert c2.stats["unknown_senders"] == 1


@pytest.mark.parametrize(
    "kwargs", [{"api_mode": 3}, {"unknown": "guess"}, {"id_map": {"nothex": 1}}]
)
def test_bad_settings_raise(kwargs: dict[str, object]) -> None:
    """API mode, unknown-sender policy and id table are checked up front."""
    with pytest.raises(ValueError):
        XBeeCore(1, **kwargs)  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        XBeeCore(256)
