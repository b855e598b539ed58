"""What a node hands its flight recorder, tick by tick: the path a recording takes."""

from __future__ import annotations

import os

from rigs import RIG_HOME, SimRig

import bvm
from bvm.digest import state_digest
from fieldkit.node.autopilot_port import MavlinkAutopilot
from fieldkit.node.node import Node
from fieldkit.radio.udp import UdpRadio
from fieldkit.robot.rc import RcCommand
from fieldkit.robot.runtime import TickRecord

SRC = """
function step() {
  neighbors.broadcast("hi", id)
  if (flight.rc_cmd == 22) { uav_takeoff(5.0)  log("up") }
}
"""


class Calls:
    """A recorder that keeps the calls in order."""

    def __init__(self) -> None:
        self.calls: list[tuple[object, ...]] = []

    def begin_tick(self, tick: int, clock_s: float, unix_ns: int) -> None:
        self.calls.append(("begin", tick, clock_s, unix_ns))

    def radio_in(self, sender: int, data: bytes) -> None:
        self.calls.append(("in", sender, data))

    def radio_out(self, data: bytes) -> None:
        self.calls.append(("out", data))

    def end_tick(self, record: TickRecord, digest: bytes, log: list[str]) -> None:
        self.calls.append(("end", record.tick, digest, list(log), record.order))


def test_every_tick_reaches_the_recorder_in_order_with_the_autopilots_bytes() -> None:
    port = 30000 + os.getpid() % 2000
    rig = SimRig("solo", home=RIG_HOME, gps_fix_delay_s=0.0)
    radio = UdpRadio(1, port=port, group="127.255.255.255")
    other = UdpRadio(2, port=port, group="127.255.255.255")
    rx: list[bytes] = []
    tx: list[bytes] = []
    try:
        rig.connect()
        assert rig.run_until(lambda: rig.link.telemetry.gps_fix_type >= 3, 10.0)
        rig.link.on_rx, rig.link.on_tx = rx.append, tx.append
        t = rig.link.telemetry
        home = (t.lat, t.lon, 0.0)
        rec = Calls()
        node = Node(
            rig.profile,
            bvm.compile_source(SRC, "s.bzz"),
            1,
            MavlinkAutopilot(rig.link, home),  # type: ignore[arg-type]
            radio,
            home=home,  # type: ignore[arg-type]
            commands=[RcCommand(0.2, 1, 22)],
            clock=rig.clock,
            out=lambda _l: None,
            recorder=rec,
        )
        for _ in range(10):
            other.send(b"\x00" * 7 + b"\x02" + b"\x00" * 40)  # heard as a frame from robot 2
            node.tick()
            rig.tick()
        kinds = [c[0] for c in rec.calls]
        assert kinds.count("begin") == kinds.count("end") == 10
        # Each tick: begin, what the radio handed in, what went out, end; in that order.
        first = kinds.index("end")
        assert kinds[0] == "begin" and "out" in kinds[:first]
        assert [c[1] for c in rec.calls if c[0] == "begin"] == list(range(10))
        assert any(c[0] == "in" and c[1] == 2 for c in rec.calls)
        ends = [c for c in rec.calls if c[0] == "end"]
        assert ends[-1][2] == state_digest(node.runtime.vm)
        assert any(c[3] == ["up"] for c in ends)  # the script's line, in its tick
        assert any(c[4] is not None and c[4].kind == "takeoff" for c in ends)
        assert rx and tx  # the autopilot's bytes, both ways, at the port
    finally:
        radio.close()
        other.close()
        rig.close()
