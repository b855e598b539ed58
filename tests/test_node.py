"""The field node end to end: the VM, the supervisor and a MAVLink vehicle on a real pty.

The vehicle is fieldkit's simulated ArduPilot (`SimRig`: the vehicle and pymavlink link on
the two ends of a pty, stepped in lockstep on a simulated clock), so the node's whole path
runs: telemetry in, script step, supervisor, MAVLink commands with their ACKs, out.
"""

from __future__ import annotations

import os

import pytest
from rigs import RIG_HOME, SimRig

import bvm
from fieldkit.node.autopilot_port import MavlinkAutopilot
from fieldkit.node.node import Node
from fieldkit.robot.rc import RcCommand

HOME = RIG_HOME

FLY = """
function init() { BVMSTATE = "TURNEDOFF" }
function step() {
  if (flight.rc_cmd == 22) BVMSTATE = "TAKEOFF"
  if (BVMSTATE == "TAKEOFF") {
    uav_takeoff(TARGET_ALTITUDE)
    if (pose.position.altitude > TARGET_ALTITUDE * 0.9) {
      BVMSTATE = "GO"
      goto_abs(10.0, 0.0, 0.0, 0.0)
    }
  }
  if (BVMSTATE == "GO" and BROKEN == 1) { var crash = 1 / 0 }
  log(BVMSTATE, " ", pose.position.altitude)
}
"""


def make_node(rig: SimRig, src: str, lines: list[str], **globals_: object) -> Node:
    t = rig.link.telemetry
    home = (t.lat, t.lon, 0.0)
    program = bvm.compile_source(src.replace("BROKEN == 1", f"{globals_.get('BROKEN', 0)} == 1"))
    return Node(
        rig.profile,
        program,
        3,
        MavlinkAutopilot(rig.link, home),  # type: ignore[arg-type]
        None,
        home=home,  # type: ignore[arg-type]
        commands=[RcCommand(0.5, 3, 22)],
        clock=rig.clock,
        out=lines.append,
    )


def run(rig: SimRig, node: Node, seconds: float) -> None:
    for _ in range(round(seconds * 10)):
        node.tick()
        rig.tick()


def test_the_node_flies_the_script(rig: SimRig) -> None:
    lines: list[str] = []
    node = make_node(rig, FLY, lines)
    run(rig, node, 40.0)
    v = rig.sim.vehicle
    alt = rig.profile.kinematics.takeoff_altitude_m
    assert v.z == pytest.approx(alt, abs=0.5)
    assert v.y == pytest.approx(10.0, abs=1.0)  # 10 m north of where it took off
    summary = node.summary()
    assert summary["final_state"] == "GO"
    assert summary["ticks"] == 400 and summary["errors"] == []
    assert summary["mavlink_messages"] > 100 and summary["mavlink_bad_frames"] == 0
    assert lines[0].startswith("TURNEDOFF")  # unstamped: `out` (a NodeLog) stamps it


def test_a_script_error_holds_the_vehicle_and_the_node_goes_on(rig: SimRig) -> None:
    lines: list[str] = []
    node = make_node(rig, FLY, lines, BROKEN=1)
    run(rig, node, 30.0)
    summary = node.summary()
    assert len(summary["errors"]) == 1 and "division by zero" in summary["errors"][0]  # type: ignore[index]
    assert ":12:" in summary["errors"][0]  # type: ignore[index]
    compiled = FLY.replace("BROKEN == 1", "1 == 1")  # as make_node compiles it
    col = compiled.splitlines()[11].index("/") + 1  # at the `/` itself, the stack under it
    assert summary["errors"][0].splitlines() == [  # type: ignore[index]
        f"<buzz>:12:{col}: division by zero",
        "  in step, called by the host",
    ]
    assert summary["failsafe"].startswith("script error")  # type: ignore[union-attr]
    assert rig.link.telemetry.mode == rig.profile.autopilot.loiter_mode  # solo: hold = LOITER
    assert rig.sim.vehicle.z >= 4.5  # hovering, not landed or falling
    assert summary["ticks"] == 300  # every tick ran


def test_garbage_on_the_autopilot_line_costs_only_a_counter(rig: SimRig) -> None:
    lines: list[str] = []
    node = make_node(rig, FLY, lines)
    for k in range(300):
        node.tick()
        rig.tick()
        if k % 20 == 5:
            noise = b"\xfe\x09garbage\xfd\x00\x00" + bytes(range(40))
            os.write(rig.pty.master, noise)
            rig.sim.bytes_sent += len(noise)  # the rig waits for every byte on the line
    assert node.summary()["mavlink_bad_frames"] > 0
    assert node.summary()["final_state"] == "GO"


def test_heartbeat_loss_lands_once_the_link_is_back(rig: SimRig) -> None:
    # solo: on_heartbeat_loss = "land". The vehicle keeps flying its last target while
    # silent (its own failsafes are its business); when the link returns, the node lands it.
    lines: list[str] = []
    node = make_node(rig, FLY, lines)
    run(rig, node, 20.0)
    assert node.runtime.state == "GO"
    rig.sim.faults.heartbeats = False
    run(rig, node, 5.0)
    assert node.runtime.supervisor.failsafe == "autopilot heartbeat lost"
    rig.sim.faults.heartbeats = True
    run(rig, node, 20.0)
    assert rig.sim.vehicle.z == pytest.approx(0.0, abs=0.1)  # landed
    assert node.summary()["errors"] == []


def test_the_pilot_override_always_wins(rig: SimRig) -> None:
    lines: list[str] = []
    node = make_node(rig, FLY, lines)
    run(rig, node, 15.0)
    assert rig.sim.pilot_switch("LOITER")  # the backup pilot flips the mode switch
    before = (rig.sim.vehicle.x, rig.sim.vehicle.y)
    run(rig, node, 10.0)
    assert rig.link.telemetry.mode == "LOITER"  # the node did not take it back
    after = (rig.sim.vehicle.x, rig.sim.vehicle.y)
    assert after == pytest.approx(before, abs=0.5)


def test_two_nodes_hear_each_other_over_the_udp_radio() -> None:
    from fieldkit.radio.udp import UdpRadio

    src = """
    function step() {
      neighbors.broadcast("hi", id)
      seen = neighbors.count()
    }
    neighbors.listen("hi", function(topic, value, sender) { heard = value })
    """
    rigs = [SimRig("solo", home=HOME, gps_fix_delay_s=0.0) for _ in range(2)]
    radios = []
    try:
        nodes = []
        port = 24000 + os.getpid() % 2000
        for rid, r in zip((1, 2), rigs, strict=True):
            r.connect()
            assert r.run_until(lambda r=r: r.link.telemetry.gps_fix_type >= 3, 10.0)
            t = r.link.telemetry
            home = (t.lat, t.lon, 0.0)
            radio = UdpRadio(rid, port=port, group="127.255.255.255")
            radios.append(radio)
            nodes.append(
                Node(
                    r.profile,
                    bvm.compile_source(src, "hi.bzz"),
                    rid,
                    MavlinkAutopilot(r.link, home),  # type: ignore[arg-type]
                    radio,
                    home=home,  # type: ignore[arg-type]
                    clock=r.clock,
                    out=lambda _t: None,
                )
            )
        for _ in range(40):
            for node, r in zip(nodes, rigs, strict=True):
                node.tick()
                r.tick()
        for node, other in zip(nodes, (2, 1), strict=True):
            assert node.runtime.vm["heard"] == other and node.runtime.vm["seen"] == 1
            s = node.summary()
            assert s["radio_frames_in"] > 20 and s["radio_frames_out"] == 40
    finally:
        for radio in radios:
            radio.close()
        for r in rigs:
            r.close()
