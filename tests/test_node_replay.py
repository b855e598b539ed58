"""Real telemetry through the field node: a recorded ArduCopter flight fed through a pty.

The script's `pose`, `battery` and `flight` globals must say what the log says at each
point, and the log's corrupt frames must cost nothing but the bad-frame counter.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import all as mavlink2

import bvm
from bvm.values import f32
from fieldkit.node.autopilot_port import MavlinkAutopilot
from fieldkit.node.node import Node
from fieldkit.robot.profiles import load_profile
from fieldkit.vehicle.link import Autopilot
from fieldkit.vehicle.pty import open_pty

TLOGS = Path(__file__).resolve().parent / "data" / "tlogs"  # with their licences
FLIGHT = TLOGS / "quad-flight-arducopter.tlog"

WATCH = """
function step() {
  seen = {.lat = pose.position.latitude, .lon = pose.position.longitude,
          .alt = pose.position.altitude, .v = battery.voltage, .cap = battery.capacity,
          .status = flight.status}
}
"""


def frames_of(path: Path) -> list[bytes]:
    """The raw MAVLink frames of a tlog (each record: 8-byte timestamp, then one frame)."""
    data = path.read_bytes()
    out, i = [], 0
    while i + 10 < len(data):
        j = i + 8
        n = data[j + 1] + (8 if data[j] == 0xFE else 12 + (13 if data[j + 2] & 1 else 0))
        out.append(data[j : j + n])
        i = j + n
    return out


class Expected:
    """What the log says so far, as pymavlink parses it frame by frame."""

    def __init__(self) -> None:
        self.parser = mavlink2.MAVLink(None)
        self.parser.robust_parsing = True
        self.pos = self.volts = self.percent = None
        self.armed = False
        self.bad = 0

    def feed(self, frame: bytes) -> None:
        for m in self.parser.parse_buffer(frame) or []:
            kind = m.get_type()
            if kind == "BAD_DATA":
                self.bad += 1
            elif m.get_srcSystem() != 1:
                continue
            elif kind == "GLOBAL_POSITION_INT" and (m.lat or m.lon):
                self.pos = (m.lat * 1e-7, m.lon * 1e-7, m.relative_alt * 1e-3)
            elif kind == "SYS_STATUS":
                self.volts = m.voltage_battery * 1e-3
                self.percent = m.battery_remaining
            elif kind == "HEARTBEAT" and m.get_srcComponent() == 1:
                self.armed = bool(m.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)


def test_a_real_flight_shows_in_the_script_globals() -> None:
    frames = frames_of(FLIGHT)[30_000:46_000]  # arming, flying, landing; 240 bad frames
    pty = open_pty()
    now = [0.0]
    link = Autopilot(pty.slave_path, clock=lambda: now[0], heartbeat_interval_s=None)
    expected = Expected()
    checked = 0
    statuses: set[int] = set()
    try:
        node = Node(
            load_profile("solo"),
            bvm.compile_source(WATCH, "watch.bzz"),
            1,
            MavlinkAutopilot(link, (-35.36, 149.16, 0.0)),
            None,
            home=(-35.36, 149.16, 0.0),
            clock=lambda: now[0],
            out=lambda _text: None,
        )
        fed = 0
        for k, frame in enumerate(frames):
            os.write(pty.master, frame)
            fed += len(frame)
            expected.feed(frame)
            if k % 400 != 399:
                continue
            while link.bytes_received < fed:  # the line holds no more than a few KiB
                link.poll(0.5)
            now[0] += 0.1  # the log's own pace is far slower: this is faster than real time
            node.tick()
            if expected.pos is None or expected.volts is None:
                continue
            seen = node.runtime.vm["seen"]
            lat, lon, alt = expected.pos
            assert (seen["lat"], seen["lon"]) == (f32(lat), f32(lon))
            assert seen["alt"] == pytest.approx(alt, abs=1e-3)
            assert seen["v"] == f32(expected.volts)
            assert seen["cap"] == expected.percent
            assert seen["status"] == (2 if expected.armed and alt > 0.3 else 1)
            checked += 1
            statuses.add(seen["status"])
    finally:
        link.close()
        pty.close()
    assert checked >= 30 and statuses == {1, 2}  # on the ground and in the air
    assert expected.bad > 200
    assert link.bad_frames >= expected.bad  # the corrupt frames: a counter, nothing else
    summary = node.summary()
    assert summary["errors"] == [] and summary["mavlink_bad_frames"] == link.bad_frames
