"""PX4's conversation (`Px4Core`) against the simulated PX4 (`SimPx4`), in memory and on a pty.

`MemoryRig("spiri")` passes the bytes between the two cores on a simulated clock (the
profile's flavour picks PX4's pair); `SimRig("spiri")` puts the same pair on a real pty
through the pymavlink transport. What the link writes is decoded frame by frame, with its
link-clock time, so the tests see the order and the rate of what reached PX4.
"""

from __future__ import annotations

import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import all as mavlink2
from rigs import MemoryRig, SimRig

from fieldkit.robot import geo
from fieldkit.robot.script_api import IN_AIR, ON_GROUND
from fieldkit.vehicle import CommandStatus, MavCommand, Px4Autopilot, Px4Core, SimPx4
from fieldkit.vehicle.link import Autopilot
from fieldkit.vehicle.px4 import OFFBOARD

HOME = (45.5049, -73.6133)
ROOT = Path(__file__).resolve().parents[1]
SET_MODE = mavlink2.MAV_CMD_DO_SET_MODE
ARM = mavlink2.MAV_CMD_COMPONENT_ARM_DISARM
SETPOINT = "SET_POSITION_TARGET_GLOBAL_INT"


class Wire:
    """Every message the link writes, decoded, with the rig time it left at."""

    def __init__(self, rig: MemoryRig) -> None:
        self.sent: list[tuple[float, Any]] = []
        self._decoder = mavlink2.MAVLink(None)
        original = rig.link.data_to_send

        def data_to_send() -> bytes:
            data = original()
            for msg in self._decoder.parse_buffer(data) or []:
                self.sent.append((rig.now, msg))
            return data

        rig.link.data_to_send = data_to_send  # type: ignore[method-assign]

    def of(self, kind: str, since: float = -1.0) -> list[tuple[float, Any]]:
        """(time, message) of one type, from `since` on."""
        return [(t, m) for t, m in self.sent if m.get_type() == kind and t >= since]

    def modes(self, since: float = -1.0) -> list[tuple[float, tuple[float, float]]]:
        """(time, (main, sub)) of every DO_SET_MODE sent."""
        return [
            (t, (m.param2, m.param3))
            for t, m in self.of("COMMAND_LONG", since)
            if m.command == SET_MODE
        ]


@pytest.fixture
def make_rig() -> Callable[..., MemoryRig]:
    """MemoryRigs of the Spiri at HOME."""

    def make(**options: Any) -> MemoryRig:
        return MemoryRig("spiri", home=HOME, **options)

    return make


def finish(rig: MemoryRig, cmd: MavCommand, seconds: float = 10.0) -> MavCommand:
    """Tick until `cmd` is over."""
    assert rig.run_until(lambda: cmd.done, seconds), f"{cmd} still pending"
    return cmd


def events(rig: MemoryRig) -> list[tuple[str, str]]:
    return [(e.kind, e.text) for e in rig.link.drain_events()]


def airborne(rig: MemoryRig, alt: float = 3.0) -> None:
    """Connected, taken off in OFFBOARD and hovering at `alt` metres."""
    rig.connect(10.0)
    assert finish(rig, rig.link.takeoff(alt)).ok
    t = rig.link.telemetry
    assert rig.run_until(lambda: abs((t.alt_rel_m or 0.0) - alt) < 0.05 and t.mode == OFFBOARD, 15)


def max_gap(times: list[float]) -> float:
    """The longest time between two consecutive times."""
    return max(b - a for a, b in zip(times, times[1:], strict=False))


def stall(rig: MemoryRig, seconds: float) -> None:
    """The node's loop hangs: the vehicle flies on, the link neither reads nor writes."""
    for _ in range(round(seconds / rig.dt)):
        rig.sim.step(rig.dt)
        rig.now += rig.dt


# ---------------------------------------------------------------------------- start-up


def test_the_link_reads_px4s_offboard_parameters(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    rig.sim.params["COM_OF_LOSS_T"] = 0.8
    rig.sim.params["COM_OBL_RC_ACT"] = 4
    rig.connect(10.0)
    link = rig.link
    assert isinstance(link, Px4Core) and isinstance(rig.sim, SimPx4)
    assert link.params == {
        "COM_OF_LOSS_T": pytest.approx(0.8),
        "COM_OBL_RC_ACT": 4.0,  # an INT32, sent bytewise in the float
        "COM_DISARM_PRFLT": 10.0,
        "MIS_TAKEOFF_ALT": 2.5,
        "COM_RC_IN_MODE": 0.0,
    }
    assert link.offboard_loss_s == pytest.approx(0.8)
    t = link.telemetry
    assert t.mode == "POSCTL" and t.autopilot_type == mavlink2.MAV_AUTOPILOT_PX4
    assert rig.sim.received["REQUEST_DATA_STREAM"] == 0  # PX4 has none: intervals only
    assert rig.sim.gcs_heartbeats >= 1  # the companion's, from 1/195


# ---------------------------------------------------------------------------- arming


def test_arming_refused_by_the_preflight_checks_says_why(
    make_rig: Callable[..., MemoryRig],
) -> None:
    rig = make_rig(gps_fix_delay_s=5.0)
    rig.connect(10.0)
    refused = finish(rig, rig.link.arm())
    assert refused.status is CommandStatus.FAILED and refused.attempts == 1  # final: no retry
    assert refused.error == (
        "arm failed: MAV_CMD_COMPONENT_ARM_DISARM refused: MAV_RESULT_TEMPORARILY_REJECTED "
        "(Arming denied: GPS fix too low)"
    )
    assert ("statustext", "Arming denied: GPS fix too low") in events(rig)
    assert rig.wait(lambda: rig.link.telemetry.gps_fix_type >= 3, 10.0)
    assert finish(rig, rig.link.arm()).ok
    assert rig.run_until(lambda: rig.link.telemetry.armed, 1.5)


def test_takeoff_refused_before_a_fix_stops_its_stream(make_rig: Callable[..., MemoryRig]) -> None:
    """Without a fix PX4 refuses OFFBOARD; the takeoff fails with that, and the stream it
    started stops (nothing is flying it)."""
    rig = make_rig(gps_fix_delay_s=100.0)
    rig.connect(10.0)
    # The simulator reports zeros before a fix, which the link does not take as a position.
    assert rig.link.takeoff(3.0).error == (
        "takeoff 3 refused: position unknown (no GLOBAL_POSITION_INT yet)"
    )
    rig.sim.gps_fix_delay_s = 0.0
    assert rig.wait(lambda: rig.link.telemetry.lat is not None, 5.0)
    rig.sim.gps_fix_delay_s = 1e9  # the fix is lost again
    cmd = finish(rig, rig.link.takeoff(3.0))
    assert cmd.error == (
        "takeoff 3 failed: mode OFFBOARD refused: MAV_RESULT_TEMPORARILY_REJECTED"
    )  # DO_SET_MODE reasons go to component 190 only, as PX4 does
    assert not rig.link.streaming and not rig.sim.armed


def test_disarm_in_the_air_is_refused_and_a_forced_one_kills(
    make_rig: Callable[..., MemoryRig],
) -> None:
    rig = make_rig()
    airborne(rig)
    cmd = finish(rig, rig.link.disarm())
    assert cmd.error == (
        "disarm failed: MAV_CMD_COMPONENT_ARM_DISARM refused: MAV_RESULT_TEMPORARILY_REJECTED "
        "(Disarming denied: not landed)"
    )
    assert rig.sim.armed
    assert finish(rig, rig.link.disarm(force=True)).ok
    assert not rig.sim.armed and rig.sim.vehicle.z == 0.0


# ---------------------------------------------------------------------------- OFFBOARD


def test_takeoff_streams_before_the_switch_then_arms_and_climbs(
    make_rig: Callable[..., MemoryRig],
) -> None:
    rig = make_rig()
    rig.connect(10.0)
    wire = Wire(rig)
    start = rig.now
    cmd = rig.link.takeoff(3.0)
    assert cmd.name == "takeoff 3" and cmd.status is CommandStatus.ACTIVE
    finish(rig, cmd)
    assert cmd.ok
    setpoints = wire.of(SETPOINT)
    first = setpoints[0][0]
    [(switch, params)] = wire.modes()
    assert params == (6.0, 0.0)  # OFFBOARD
    # The stream ran the warm-up (1.2 s) before the switch, with no gap PX4 would see.
    assert switch - first >= rig.link.offboard_warmup_s - 1e-9
    before = [t for t, _ in setpoints if t <= switch]
    assert len(before) >= 12 and max_gap(before) <= 0.1 + 1e-9
    arms = [t for t, m in wire.of("COMMAND_LONG") if m.command == ARM]
    assert len(arms) == 1 and arms[0] > switch  # armed in OFFBOARD, after its ACK
    # What PX4 got: AMSL (frame 5) position-only setpoints, here and 3 m above home.
    sp = setpoints[-1][1]
    assert sp.coordinate_frame == mavlink2.MAV_FRAME_GLOBAL_INT and sp.type_mask == 0x0DF8
    assert sp.alt == pytest.approx(rig.sim.frame.alt + 3.0)
    assert (sp.lat_int, sp.lon_int) == (round(HOME[0] * 1e7), round(HOME[1] * 1e7))
    t = rig.link.telemetry
    seen: set[int] = set()

    def climbed() -> bool:
        seen.add(t.landed_state or 0)
        return abs((t.alt_rel_m or 0.0) - 3.0) < 0.05

    assert rig.run_until(climbed, 10.0)
    assert t.armed and t.mode == OFFBOARD and rig.sim.mode == OFFBOARD
    assert seen <= {ON_GROUND, IN_AIR}  # OFFBOARD only ever shows these two
    assert rig.now - start < 8.0
    assert rig.sim.setpoints_dropped == 0


def test_px4_refuses_offboard_without_a_stream(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    rig.connect(10.0)
    sent = rig.link.bytes_sent
    cmd = rig.link.set_mode(OFFBOARD)
    assert cmd.error == (
        "set_mode OFFBOARD refused: PX4 refuses OFFBOARD without a setpoint stream: "
        "goto() or takeoff() first"
    )
    assert rig.link.bytes_sent == sent  # nothing sent
    # Asked directly (a planner, component 190, gets the reason), PX4 refuses too.
    gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    ask = gcs.command_long_encode(1, 1, SET_MODE, 0, 1, 6, 0, 0, 0, 0, 0)
    rig.sim.receive_data(bytes(ask.pack(gcs)))
    reply = mavlink2.MAVLink(None).parse_buffer(rig.sim.data_to_send()) or []
    assert [m.get_type() for m in reply] == ["STATUSTEXT", "COMMAND_ACK"]
    assert reply[0].text == "Mode change to OFFBOARD denied: no offboard signal"
    assert (reply[1].result, reply[1].target_component) == (1, 190)
    assert rig.sim.mode == "POSCTL"


def test_a_setpoint_stream_too_young_or_broken_is_not_enough() -> None:
    """The simulated PX4's own rule: a signal present for `offboard_warmup_s`, no gap
    longer than COM_OF_LOSS_T."""
    sim = SimPx4(MemoryRig("spiri").profile, home=HOME)
    enc = mavlink2.MAVLink(None, srcSystem=1, srcComponent=195)
    sp = enc.set_position_target_local_ned_encode(0, 1, 1, 1, 0x09F8, 0, 0, -3, *[0.0] * 8)
    sim.step(0.1)
    for _ in range(5):
        sim.receive_data(bytes(sp.pack(enc)))
        sim.step(0.1)
    assert not sim.offboard_signal  # 0.5 s of stream
    for _ in range(6):
        sim.receive_data(bytes(sp.pack(enc)))
        sim.step(0.1)
    assert sim.offboard_signal
    for _ in range(11):
        sim.step(0.1)
    assert not sim.offboard_signal  # stopped for more than 1 s
    sim.receive_data(bytes(sp.pack(enc)))
    assert not sim.offboard_signal  # back, but young again


def test_the_stream_runs_by_the_link_clock_without_any_goto(
    make_rig: Callable[..., MemoryRig],
) -> None:
    """No order for 5 s: the setpoint still reaches PX4 at every tick (10 Hz here, 20 Hz
    when ticked at 20 Hz), and OFFBOARD holds."""
    for dt, per_second in ((0.1, 10), (0.05, 20)):
        rig = make_rig(dt=dt)
        airborne(rig)
        wire = Wire(rig)
        before = rig.sim.setpoints
        since = rig.now
        rig.run_for(5.0)
        times = [t for t, _ in wire.of(SETPOINT, since)]
        assert rig.sim.setpoints - before == len(times)
        assert len(times) == pytest.approx(5 * per_second, abs=1)
        assert max_gap(times) <= dt + 1e-9
        assert rig.sim.mode == OFFBOARD and rig.sim.failsafe is None


def test_goto_moves_the_streamed_setpoint(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    airborne(rig)
    events(rig)
    lat, lon = geo.offset_gps(*HOME, 12.0, -8.0)
    cmd = rig.link.goto(lat, lon, 5.0, yaw_deg=90.0)
    assert cmd.ok and cmd.done and rig.link.setpoint == (lat, lon, 5.0, 90.0)
    assert events(rig) == []  # a setpoint is not an event
    t = rig.link.telemetry
    accuracy = rig.profile.kinematics.hover_accuracy_m

    def there() -> bool:
        return (
            geo.range_bearing(t.lat, t.lon, lat, lon)[0] < 0.1  # type: ignore[arg-type]
            and abs((t.alt_rel_m or 0.0) - 5.0) < 0.05
        )

    assert rig.run_until(there, 20.0)  # streamed, never sent again by the node
    rig.run_for(2.0)
    assert there() and (t.ground_speed_mps or 0.0) < 0.05 < accuracy
    assert t.heading_deg == pytest.approx(90.0, abs=0.01)  # east, as asked


def test_hold_stops_the_stream_after_its_ack_and_a_goto_takes_it_back(
    make_rig: Callable[..., MemoryRig],
) -> None:
    rig = make_rig()
    airborne(rig)
    wire = Wire(rig)
    hold = rig.link.hold()
    assert hold.name == "hold (LOITER)" and rig.link.streaming  # until PX4 has answered
    finish(rig, hold)
    assert hold.ok and not rig.link.streaming and rig.sim.mode == "LOITER"
    acked = rig.now
    rig.run_for(2.0)
    assert wire.of(SETPOINT, acked + rig.dt) == []
    assert rig.sim.failsafe is None and rig.sim.mode == "LOITER"  # our own exit: no failsafe
    assert not rig.link.pilot_override
    # The node's own hold: a goto goes back to OFFBOARD, after the stream's warm-up.
    since = rig.now
    lat, lon = geo.offset_gps(*HOME, 6.0, 0.0)
    for _ in range(40):
        rig.link.goto(lat, lon, 3.0)
        rig.tick()
    [(switch, params)] = wire.modes(since)
    assert params == (6.0, 0.0) and switch - since >= rig.link.offboard_warmup_s - 1e-9
    assert rig.sim.mode == OFFBOARD
    t = rig.link.telemetry
    assert rig.run_until(lambda: geo.range_bearing(t.lat, t.lon, lat, lon)[0] < 0.1, 15)  # type: ignore[arg-type]


def test_land_is_px4s_auto_land_and_it_disarms_after_touchdown(
    make_rig: Callable[..., MemoryRig],
) -> None:
    rig = make_rig()
    airborne(rig)
    wire = Wire(rig)
    cmd = finish(rig, rig.link.land())
    assert cmd.ok and cmd.name == "land (LAND)" and wire.modes()[0][1] == (4.0, 6.0)
    t = rig.link.telemetry
    assert rig.run_until(lambda: rig.sim.vehicle.status == ON_GROUND, 10.0)
    touchdown = rig.now
    assert rig.sim.armed  # PX4 waits COM_DISARM_LAND
    assert rig.run_until(lambda: not t.armed, 5.0)
    assert 2.0 <= rig.now - touchdown <= 3.2  # 2 s, plus up to the next 1 Hz heartbeat
    assert t.mode == "LAND" and abs(t.alt_rel_m or 0.0) < 0.01 and not rig.link.pilot_override
    assert t.landed_state == ON_GROUND


def test_rtl_is_px4s_return(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    airborne(rig)
    lat, lon = geo.offset_gps(*HOME, -20.0, 15.0)
    rig.link.goto(lat, lon, 4.0)
    t = rig.link.telemetry
    assert rig.run_until(lambda: geo.range_bearing(t.lat, t.lon, lat, lon)[0] < 0.5, 30)  # type: ignore[arg-type]
    assert finish(rig, rig.link.rtl()).ok
    assert rig.run_until(lambda: not t.armed, 60.0)
    assert t.mode == "RTL" and geo.range_bearing(t.lat, t.lon, *HOME)[0] < 0.5  # type: ignore[arg-type]


# ---------------------------------------------------------------------------- leaving OFFBOARD


@pytest.mark.parametrize(
    ("action", "rc", "mode", "said"),
    [
        (0, True, "POSCTL", "COM_OBL_RC_ACT 0: Position mode"),
        (4, True, "LAND", "COM_OBL_RC_ACT 4: Land"),
        (5, True, "LOITER", "COM_OBL_RC_ACT 5: Hold"),
        (0, False, "RTL", "COM_OBL_RC_ACT 0: Position mode"),  # no RC: NAV_RCL_ACT's Return
    ],
)
def test_offboard_loss_is_reported_and_never_fought(
    make_rig: Callable[..., MemoryRig], action: int, rc: bool, mode: str, said: str
) -> None:
    rig = make_rig()
    rig.sim.params["COM_OBL_RC_ACT"] = action
    rig.sim.rc_present = rc
    airborne(rig)
    events(rig)
    modes_sent = rig.sim.commands[SET_MODE]
    stall(rig, 1.5)  # the node hangs past COM_OF_LOSS_T
    assert rig.sim.mode == mode and rig.sim.failsafe == "offboard signal lost"
    lat, lon = geo.offset_gps(*HOME, 30.0, 0.0)
    refused = []
    for _ in range(30):  # the node wakes up and goes on giving orders
        refused.append(rig.link.goto(lat, lon, 3.0))
        rig.tick()
    link, t = rig.link, rig.link.telemetry
    assert isinstance(link, Px4Core)
    assert t.mode == mode and link.pilot_override and not link.streaming
    text = next(text for kind, text in events(rig) if kind == "override")
    assert text.startswith(
        f"PX4 left OFFBOARD for {mode} without the node: offboard signal lost: no setpoint for "
    )
    assert f"> COM_OF_LOSS_T 1 s, {said}" in text
    assert f'PX4 says "Failsafe: no offboard signal, {mode}"' in text
    assert text.endswith("the node will not switch back (the pilot has it, or a new "
                         "takeoff/set_mode OFFBOARD)")  # fmt: skip
    # Never fought: no OFFBOARD switch, the gotos refused without an event each.
    assert rig.sim.commands[SET_MODE] == modes_sent and rig.sim.mode == mode
    after = [c for c in refused if not c.ok]
    assert len(after) >= 20 and all("PX4 left OFFBOARD" in (c.error or "") for c in after)
    assert [k for k, _ in events(rig) if k == "command"] == []
    setpoints = rig.sim.setpoints
    rig.run_for(2.0)
    assert rig.sim.setpoints == setpoints  # the stream has stopped


def test_the_pilots_switch_out_of_offboard_is_the_pilots(
    make_rig: Callable[..., MemoryRig],
) -> None:
    rig = make_rig()
    airborne(rig)
    events(rig)
    assert rig.sim.pilot_switch("POSCTL")
    t = rig.link.telemetry
    assert rig.run_until(lambda: t.mode == "POSCTL", 1.5)
    texts = [text for kind, text in events(rig) if kind == "override"]
    assert "RC channel 5 at 1900 us: the pilot has control" in texts
    [left] = [x for x in texts if x.startswith("PX4 left OFFBOARD")]
    assert "the pilot's switch (RC channel 5 at 1900 us)" in left
    assert "offboard signal lost" not in left  # the stream was fine
    rig.run_for(3.0)
    assert rig.sim.mode == "POSCTL" and rig.sim.failsafe is None  # no loss failsafe either
    # The node asks again, on purpose: OFFBOARD is its again.
    rig.sim.pilot_release()
    here = (t.lat, t.lon)
    cmd = rig.link.takeoff(3.0)
    assert cmd.error == "takeoff 3 refused: already in the air"
    rig.link.offboard_lost = None  # what a deliberate re-engage does (as takeoff/set_mode)
    rig.link.goto(*here, 3.0)  # type: ignore[arg-type]
    assert finish(rig, rig.link.set_mode(OFFBOARD)).ok
    assert rig.run_until(lambda: t.mode == OFFBOARD and not rig.link.pilot_override, 2.0)


def test_a_switch_on_its_way_is_given_up_when_the_pilot_takes_over(
    make_rig: Callable[..., MemoryRig],
) -> None:
    """Found by the fuzzer: a retry of an OFFBOARD switch sent before the pilot's switch
    would take the vehicle back from the pilot. It is given up instead."""
    rig = make_rig()
    airborne(rig)
    rig.sim.faults.drop_acks = 3  # our switch arrives, its answers do not
    cmd = rig.link.set_mode(OFFBOARD)
    rig.tick()
    assert cmd.status is CommandStatus.ACTIVE and rig.sim.commands[SET_MODE] == 2
    assert rig.sim.pilot_switch("POSCTL")
    finish(rig, cmd, 5.0)
    assert cmd.status is CommandStatus.CANCELLED
    assert cmd.error == "set_mode OFFBOARD: PX4 left OFFBOARD for POSCTL: not switching back"
    rig.run_for(3.0)
    assert rig.sim.commands[SET_MODE] == 2 and rig.sim.mode == "POSCTL"  # no retry


def test_a_lost_ack_of_the_switch_is_retried(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    rig.connect(10.0)
    rig.sim.faults.drop_acks = 1
    cmd = finish(rig, rig.link.takeoff(3.0))
    assert cmd.ok and rig.sim.commands[SET_MODE] == 2 and rig.sim.acks_dropped == 1


def test_a_wrong_target_gets_failed() -> None:
    """PX4 answers a command for another system or component FAILED."""
    rig = MemoryRig("spiri", home=HOME)
    rig.connect(10.0)
    enc = mavlink2.MAVLink(None, srcSystem=1, srcComponent=195)
    for target in ((1, 2), (2, 1)):
        ask = enc.command_long_encode(*target, ARM, 0, 1, 0, 0, 0, 0, 0, 0)
        rig.sim.receive_data(bytes(ask.pack(enc)))
        [ack] = mavlink2.MAVLink(None).parse_buffer(rig.sim.data_to_send()) or []
        assert (ack.command, ack.result) == (ARM, mavlink2.MAV_RESULT_FAILED)
    assert not rig.sim.armed


def test_time_state_keeps_the_stream_clock(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    airborne(rig)
    state = rig.link.time_state()
    assert state["last_setpoint"] == pytest.approx(rig.now) and state["stream_since"] is not None
    other = Px4Core(clock=rig.clock)
    other.set_time_state(state)
    assert other.time_state()["last_setpoint"] == state["last_setpoint"]


def test_an_ardupilot_link_on_px4_says_which_flavour(make_rig: Callable[..., MemoryRig]) -> None:
    from fieldkit.vehicle.autopilot import AutopilotCore

    rig = make_rig()
    rig.link = AutopilotCore(clock=rig.clock)
    assert rig.wait(lambda: rig.link.telemetry.last_heartbeat is not None, 3.0)
    assert rig.link.set_mode("LOITER").error == (
        "set_mode LOITER refused: the autopilot is PX4 (HEARTBEAT autopilot 12) but this link "
        'speaks ArduPilot: set autopilot.flavour = "px4" in the profile'
    )


# ---------------------------------------------------------------------------- the real line


def test_a_flight_over_a_real_pty_with_the_pymavlink_transport() -> None:
    with SimRig("spiri", home=HOME) as rig:
        assert isinstance(rig.link, Px4Autopilot)
        rig.connect(10.0)
        cmd = rig.link.takeoff(3.0)
        assert rig.run_until(lambda: cmd.done, 10.0) and cmd.ok
        lat, lon = geo.offset_gps(*HOME, 8.0, 4.0)
        rig.link.goto(lat, lon, 4.0)
        t = rig.link.telemetry
        assert rig.run_until(lambda: geo.range_bearing(t.lat, t.lon, lat, lon)[0] < 0.1, 20)  # type: ignore[arg-type]
        assert abs((t.alt_rel_m or 0.0) - 4.0) < 0.05 and t.mode == OFFBOARD
        land = rig.link.land()
        assert rig.run_until(lambda: not t.armed, 20.0) and land.ok
        assert rig.link.bad_frames == 0 and rig.sim.setpoints_dropped == 0


def test_from_profile_picks_the_px4_link() -> None:
    from fieldkit.robot.profiles import load_profile

    assert not hasattr(Autopilot, "setpoint")
    with SimRig("spiri", home=HOME) as rig:
        link = Autopilot.from_profile(load_profile("spiri"), rig.pty.slave_path)
        try:
            assert type(link) is Px4Autopilot and link.source_component == 195
        finally:
            link.close()
        solo = Autopilot.from_profile(load_profile("solo"), rig.pty.slave_path)
        try:
            assert type(solo) is Autopilot
        finally:
            solo.close()


def test_mypy_sees_px4core_as_a_vehicle_core(tmp_path: Path) -> None:
    """The vehicle interface, checked the way it is declared: by the type checker."""
    probe = tmp_path / "probe.py"
    probe.write_text(
        "from fieldkit.vehicle.core import VehicleCore\n"
        "from fieldkit.vehicle.link import Px4Autopilot\n"
        "from fieldkit.vehicle.px4 import Px4Core\n"
        "core: VehicleCore = Px4Core()\n"
        "def on_a_port(link: Px4Autopilot) -> VehicleCore:\n"
        "    return link\n"
        "bad: VehicleCore = 1\n"
    )
    done = subprocess.run(
        [ROOT / ".venv/bin/python", "-m", "mypy", "--follow-imports=silent",
         "--cache-dir", ROOT / ".mypy_cache", str(probe)],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    lines = [line for line in done.stdout.splitlines() if "probe.py" in line]
    # The control line fails, as it must; the two that matter pass.
    assert len(lines) == 1 and "probe.py:7: error" in lines[0], done.stdout
    assert done.returncode == 1
