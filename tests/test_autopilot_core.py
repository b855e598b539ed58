"""The autopilot protocol core (`AutopilotCore`) against the simulated ArduPilot's core, no pty.

`MemoryRig` passes the bytes between `SimArduPilot` and `AutopilotCore` in memory, stepping
both in lockstep on a simulated clock, in the order `SimRig` does over a pty: the same
scenario gives the same bytes either way (checked below), so the protocol is tested here and
the pty transport in tests/test_autopilot.py.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from pymavlink.dialects.v20 import all as mavlink2
from rigs import MemoryRig, SimRig

from fieldkit.robot import geo
from fieldkit.robot.profiles import load_profile
from fieldkit.vehicle import AutopilotCore, CommandStatus, MavCommand, SimArduPilot

HOME = (45.5049, -73.6133)


@pytest.fixture
def make_rig() -> Iterator[Callable[..., MemoryRig]]:
    """MemoryRigs at HOME."""

    def make(profile: str = "solo", **options: Any) -> MemoryRig:
        return MemoryRig(profile, home=HOME, **options)

    yield make


def kinds(rig: MemoryRig) -> list[tuple[str, str]]:
    """The link's events so far, as (kind, text)."""
    return [(e.kind, e.text) for e in rig.link.drain_events()]


def finish(rig: MemoryRig, cmd: MavCommand, seconds: float = 10.0) -> MavCommand:
    """Tick until `cmd` is over."""
    assert rig.run_until(lambda: cmd.done, seconds), f"{cmd} still pending"
    return cmd


def airborne(rig: MemoryRig, alt: float = 5.0) -> None:
    """Connected, GUIDED, armed and hovering at `alt` metres."""
    rig.connect(10.0)
    assert finish(rig, rig.link.takeoff(alt)).ok
    accuracy = rig.profile.kinematics.hover_accuracy_m
    assert rig.run_until(lambda: abs((rig.link.telemetry.alt_rel_m or 0.0) - alt) < accuracy, 20)


# ---------------------------------------------------------------------------- commands


def test_arm_refused_before_the_gps_fix_then_accepted(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig(gps_fix_delay_s=5.0)
    rig.connect(10.0)
    refused = finish(rig, rig.link.arm())
    assert refused.status is CommandStatus.FAILED
    assert refused.error == (
        "arm failed: MAV_CMD_COMPONENT_ARM_DISARM refused: MAV_RESULT_FAILED (PreArm: Need 3D Fix)"
    )
    assert refused.attempts == 1  # a refusal is final: no retry
    assert ("command", refused.error) in kinds(rig)
    assert rig.wait(lambda: rig.link.telemetry.gps_fix_type >= 3, 10.0)
    accepted = finish(rig, rig.link.arm())
    assert accepted.ok and accepted.result_name == "MAV_RESULT_ACCEPTED"
    assert rig.run_until(lambda: rig.link.telemetry.armed, 1.5)
    assert ("armed", "armed") in kinds(rig)


def test_set_mode_by_name(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    rig.connect(10.0)
    cmd = finish(rig, rig.link.set_mode("GUIDED"))
    assert cmd.ok
    assert rig.sim.mode == "GUIDED" and rig.sim.custom_mode == 4
    assert rig.run_until(lambda: rig.link.telemetry.mode == "GUIDED", 1.5)
    assert rig.link.telemetry.custom_mode == 4 and not rig.link.pilot_override
    # A name the vehicle type does not have is refused at once, nothing sent.
    sent = rig.link.bytes_sent
    unknown = rig.link.set_mode("WARP")
    assert unknown.status is CommandStatus.FAILED and unknown.done
    assert "unknown mode 'WARP' (known: ACRO, ALT_HOLD, AUTO," in (unknown.error or "")
    assert rig.link.bytes_sent == sent


def test_mode_refused_without_position(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig(gps_fix_delay_s=100.0)
    rig.connect(10.0)
    cmd = finish(rig, rig.link.set_mode("GUIDED"))
    assert cmd.error == (
        "set_mode GUIDED failed: mode GUIDED refused: MAV_RESULT_FAILED "
        "(Mode change to GUIDED failed: requires position)"
    )
    assert rig.sim.mode == "STABILIZE"


def test_takeoff_reaches_the_altitude(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    rig.connect(10.0)
    cmd = rig.link.takeoff(5.0)
    assert cmd.name == "takeoff 5" and cmd.status is CommandStatus.ACTIVE  # sent at once
    finish(rig, cmd)
    assert cmd.ok
    # GUIDED, arm, NAV_TAKEOFF: one each, in that order, each acknowledged.
    sim = rig.sim
    assert [sim.commands[c] for c in (176, 400, 22)] == [1, 1, 1]
    accuracy = rig.profile.kinematics.hover_accuracy_m
    t = rig.link.telemetry
    assert rig.run_until(lambda: t.landed_state == 2 and abs((t.alt_rel_m or 0) - 5.0) < 0.05, 10)
    assert t.armed and t.mode == "GUIDED"
    assert geo.range_bearing(t.lat, t.lon, *HOME)[0] < accuracy  # type: ignore[arg-type]
    assert rig.now < 5.0  # 5 m at 2.5 m/s climb: about 3 s


def test_goto_converges_on_an_absolute_target(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    airborne(rig)
    lat, lon = geo.offset_gps(*HOME, 40.0, -30.0)
    cmd = rig.link.goto(lat, lon, 8.0)
    assert cmd.ok and cmd.done  # setpoints have no ACK: done once sent
    assert rig.link.last_target == (lat, lon, 8.0)
    accuracy = rig.profile.kinematics.hover_accuracy_m
    t = rig.link.telemetry

    def there() -> bool:
        return (
            geo.range_bearing(t.lat, t.lon, lat, lon)[0] < accuracy  # type: ignore[arg-type]
            and abs((t.alt_rel_m or 0.0) - 8.0) < accuracy
        )

    assert rig.run_until(there, 30.0)
    rig.run_for(3.0)
    assert there() and (t.ground_speed_mps or 0.0) < 0.05  # it stays: an absolute target
    assert rig.sim.guided_target == pytest.approx((lat, lon, 8.0), abs=1e-7)


def test_land_disarms_on_touchdown(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    airborne(rig)
    cmd = finish(rig, rig.link.land())
    assert cmd.ok and cmd.name == "land (LAND)"
    t = rig.link.telemetry
    assert rig.run_until(lambda: not t.armed, 20.0)
    assert t.mode == "LAND" and abs(t.alt_rel_m or 0.0) < 0.01
    rig.run_for(1.0)
    assert t.landed_state == 1


def test_rtl_climbs_returns_and_lands_at_home(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    airborne(rig)
    lat, lon = geo.offset_gps(*HOME, -60.0, 25.0)
    rig.link.goto(lat, lon, 6.0)
    t = rig.link.telemetry
    assert rig.run_until(lambda: geo.range_bearing(t.lat, t.lon, lat, lon)[0] < 1.0, 40)  # type: ignore[arg-type]
    assert finish(rig, rig.link.rtl()).ok
    highest = 0.0

    def landed() -> bool:
        nonlocal highest
        highest = max(highest, t.alt_rel_m or 0.0)
        return not t.armed

    assert rig.run_until(landed, 90.0)
    assert t.mode == "RTL"
    assert highest == pytest.approx(rig.sim.rtl_alt_m, abs=0.05)  # climbed before returning
    accuracy = rig.profile.kinematics.hover_accuracy_m
    assert geo.range_bearing(t.lat, t.lon, *HOME)[0] < accuracy  # type: ignore[arg-type]


def test_ground_robot_never_flies(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig("husky")
    rig.connect(10.0)
    assert rig.link.telemetry.mav_type == mavlink2.MAV_TYPE_GROUND_ROVER
    refused = rig.link.takeoff(5.0)
    assert refused.status is CommandStatus.FAILED
    assert refused.error == "takeoff 5 refused: husky is a ground robot: it does not fly"
    # The vehicle refuses too when asked directly: Rover does not know NAV_TAKEOFF.
    direct = finish(rig, rig.link.command(mavlink2.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, 0, 0, 0, 5)))
    assert direct.result_name == "MAV_RESULT_UNSUPPORTED"
    assert direct.error == (
        "MAV_CMD_NAV_TAKEOFF failed: MAV_CMD_NAV_TAKEOFF refused: MAV_RESULT_UNSUPPORTED"
    )
    assert finish(rig, rig.link.set_mode("GUIDED")).ok and rig.sim.custom_mode == 15
    assert finish(rig, rig.link.arm()).ok
    lat, lon = geo.offset_gps(*HOME, 12.0, 5.0)
    rig.link.goto(lat, lon, 30.0)  # the altitude means nothing to a ground robot
    t = rig.link.telemetry
    highest = 0.0

    def there() -> bool:
        nonlocal highest
        highest = max(highest, abs(t.alt_rel_m or 0.0), rig.sim.vehicle.z)
        return geo.range_bearing(t.lat, t.lon, lat, lon)[0] < 0.5  # type: ignore[arg-type]

    assert rig.run_until(there, 30.0)
    assert highest == 0.0 and rig.sim.guided_target is not None
    assert rig.sim.guided_target[2] == 0.0
    land = finish(rig, rig.link.land())
    assert land.ok and land.name == "land (HOLD)" and rig.sim.mode == "HOLD"


def test_a_lost_ack_is_retried(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    rig.connect(10.0)
    rig.sim.faults.drop_acks = 1
    cmd = finish(rig, rig.link.arm())
    assert cmd.ok and cmd.attempts == 2
    assert rig.sim.commands[mavlink2.MAV_CMD_COMPONENT_ARM_DISARM] == 2
    assert rig.sim.acks_dropped == 1
    assert 1.0 <= cmd.finished - cmd.created <= 1.3  # type: ignore[operator]


def test_no_ack_at_all_is_reported_and_the_queue_moves_on(
    make_rig: Callable[..., MemoryRig],
) -> None:
    rig = make_rig()
    rig.connect(10.0)
    rig.sim.faults.drop_acks = 3  # every attempt of the first command
    done: list[MavCommand] = []
    mode = rig.link.set_mode("GUIDED", on_done=done.append)
    arm = rig.link.arm(on_done=done.append)
    assert rig.link.pending == (mode, arm) and arm.status is CommandStatus.QUEUED
    finish(rig, arm)
    assert done == [mode, arm]
    assert mode.error == "set_mode GUIDED failed: mode GUIDED: no COMMAND_ACK after 3 tries"
    assert rig.sim.commands[mavlink2.MAV_CMD_DO_SET_MODE] == 3
    assert rig.sim.mode == "GUIDED"  # it acted: only the answers were lost
    assert arm.ok and arm.attempts == 1
    assert rig.link.pending == ()


def test_a_refused_command_is_reported(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    airborne(rig)
    seen: list[MavCommand] = []
    cmd = finish(rig, rig.link.disarm(on_done=seen.append))
    assert seen == [cmd] and cmd.status is CommandStatus.FAILED
    assert cmd.error == "disarm failed: MAV_CMD_COMPONENT_ARM_DISARM refused: MAV_RESULT_FAILED"
    assert [e.command for e in rig.link.drain_events() if e.command is not None][-1] is cmd
    assert rig.sim.armed
    forced = finish(rig, rig.link.disarm(force=True))
    assert forced.ok and not rig.sim.armed and rig.sim.vehicle.z == 0.0


def test_safety_commands_jump_the_queue(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    airborne(rig)
    streams = rig.link.request_streams(5.0)  # nine steps
    arm = rig.link.arm()
    land = rig.link.land()
    assert rig.link.pending == (streams, land, arm)
    finish(rig, arm)
    assert land.finished is not None and arm.finished is not None
    assert land.finished < arm.finished
    rig.link.cancel_all("test over")


def test_commands_wait_for_a_heartbeat_then_give_up(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig(link_options={"queue_timeout_s": 2.0})
    rig.sim.faults.silent = True
    cmd = rig.link.arm()
    assert cmd.status is CommandStatus.QUEUED
    assert rig.link.goto(*HOME, 5.0).error == (
        "goto 45.5049000,-73.6133000,5 refused: no heartbeat from the autopilot yet"
    )
    finish(rig, cmd, 3.0)
    assert cmd.error == "arm: not sent, no heartbeat from the autopilot after 2 s"
    assert rig.sim.commands.total() == 0


# ---------------------------------------------------------------------------- robustness


def test_garbage_and_corrupt_frames_cost_only_a_counter(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig(seed=7)
    rig.connect(10.0)
    faults = rig.sim.faults
    faults.garbage_every, faults.garbage_len, faults.corrupt_every = 3, 24, 11
    rig.run_for(3.0)
    takeoff = finish(rig, rig.link.takeoff(5.0))
    rig.run_for(5.0)
    faults.garbage_every = faults.corrupt_every = 0
    rig.run_for(3.0)  # enough clean bytes to flush any half-believed frame
    sim, link = rig.sim, rig.link
    assert sim.garbage_bytes > 1000 and sim.corrupted_frames > 20
    # Every frame that left intact arrived, whatever noise surrounded it.
    assert link.messages == sim.frames_sent - sim.corrupted_frames
    assert link.bad_frames >= sim.corrupted_frames
    assert link.link_errors == 0
    assert takeoff.ok  # a corrupted ACK is retried like a lost one
    t = link.telemetry
    lat, lon, alt = sim.position
    assert (t.lat, t.lon) == pytest.approx((lat, lon), abs=2e-7) and t.alt_rel_m == pytest.approx(
        alt, abs=0.01
    )


def test_hostile_values_are_not_telemetry(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    rig.connect(10.0)
    rig.run_for(1.0)
    t = rig.link.telemetry
    before = (t.lat, t.lon, t.yaw_rad, t.battery_percent)
    enc = mavlink2.MAVLink(rig.sim, srcSystem=1, srcComponent=1)  # frames from "the vehicle"
    enc.global_position_int_send(0, 2**31 - 1, 5, 0, 0, 0, 0, 0, 0)  # latitude 214 degrees
    enc.attitude_send(0, 0.0, 0.0, math.nan, 0.0, 0.0, 0.0)
    enc.sys_status_send(0, 0, 0, 0, 12000, -1, 127, 0, 0, 0, 0, 0, 0)
    enc.rc_channels_send(0, 255, *([1500] * 18), 255)
    rig.poll()
    assert rig.link.link_errors == 0
    assert (t.lat, t.lon, t.yaw_rad) == (before[0], before[1], None)
    assert t.battery_percent is None and t.battery_voltage_v == 12.0
    assert len(t.rc_channels) == 18


def test_heartbeat_loss_is_detected(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    rig.connect(5.0)
    rig.run_for(2.0)
    kinds(rig)
    rig.sim.faults.heartbeats = False
    positions = rig.link.message_counts["GLOBAL_POSITION_INT"]
    assert rig.run_until(lambda: rig.link.heartbeat_lost, 5.0)
    assert 3.0 < rig.link.heartbeat_age() <= 3.2  # the profile's 3 s, plus up to a tick
    assert rig.link.message_counts["GLOBAL_POSITION_INT"] >= positions + 10  # the rest flows
    assert [k for k in kinds(rig) if k[0] == "heartbeat"] == [
        ("heartbeat", "autopilot heartbeat lost: none for 3.1 s")
    ]
    rig.sim.faults.heartbeats = True
    assert rig.run_until(lambda: not rig.link.heartbeat_lost, 1.5)
    assert ("heartbeat", "autopilot heartbeat back") in kinds(rig)


def test_pilot_override_by_the_mode_switch(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    airborne(rig)
    kinds(rig)
    assert not rig.link.pilot_override
    assert rig.sim.pilot_switch("LOITER")
    t = rig.link.telemetry
    assert rig.run_until(lambda: t.rc_override, 0.5)  # RC_CHANNELS at 10 Hz
    assert t.rc_channels[4] == 1900 and len(t.rc_channels) == 16 and rig.link.pilot_override
    assert rig.run_until(lambda: t.mode == "LOITER", 1.5)  # the heartbeat, at 1 Hz
    assert rig.link.mode_override
    events = [text for kind, text in kinds(rig) if kind == "override"]
    assert sorted(events) == [
        "RC channel 5 at 1900 us: the pilot has control",
        "mode changed to LOITER without the node (it asked for GUIDED): pilot or autopilot "
        "failsafe",
    ]
    # The pilot hands back: switch low, and the node asks for GUIDED again.
    rig.sim.pilot_release()
    assert finish(rig, rig.link.set_mode("GUIDED")).ok
    assert rig.run_until(lambda: not rig.link.pilot_override and t.mode == "GUIDED", 1.5)


def test_low_battery_is_reported(make_rig: Callable[..., MemoryRig]) -> None:
    rig = make_rig()
    rig.connect(10.0)
    rig.sim.set_battery(15.0)
    t = rig.link.telemetry
    assert rig.run_until(lambda: t.battery_percent == 15.0, 0.5)
    battery = rig.profile.battery
    expected = battery.empty_voltage + (battery.full_voltage - battery.empty_voltage) * 0.15
    assert t.battery_voltage_v == pytest.approx(expected, abs=0.001)
    assert t.battery_current_a == pytest.approx(0.3)  # disarmed: the electronics only


# ---------------------------------------------------------------------------- the cores alone


def _record(rig: MemoryRig | SimRig) -> dict[str, bytearray]:
    """Every byte the vehicle and the link put on the line from now on."""
    rec = {"sim": bytearray(), "link": bytearray()}
    if isinstance(rig, MemoryRig):
        sim_out, link_out = rig.sim.data_to_send, rig.link.data_to_send

        def sim_data() -> bytes:
            data = sim_out()
            rec["sim"] += data
            return data

        def link_data() -> bytes:
            data = link_out()
            rec["link"] += data
            return data

        rig.sim.data_to_send = sim_data  # type: ignore[method-assign]
        rig.link.data_to_send = link_data  # type: ignore[method-assign]
    else:
        port_write = rig.sim.port.write

        def to_link(data: bytes) -> int:
            rec["sim"] += data
            return port_write(data)

        def to_sim(data: bytes) -> None:
            rec["link"] += data

        rig.sim.port.write = to_link  # type: ignore[method-assign]
        rig.link.on_tx = to_sim  # every byte the link wrote to the port
    return rec


def _flight(rig: MemoryRig | SimRig) -> list[tuple[str, str]]:
    """Connect, take off through line noise, lose an ACK, fly, RTL; the link's events."""
    rig.connect(10.0)
    takeoff = rig.link.takeoff(5.0)
    assert rig.run_until(lambda: takeoff.done, 20.0)
    rig.sim.faults.garbage_every, rig.sim.faults.corrupt_every = 7, 11
    rig.sim.faults.drop_acks = 1
    loiter = rig.link.set_mode("LOITER")
    assert rig.run_until(lambda: loiter.done, 10.0)
    rig.link.set_mode("GUIDED")
    rig.run_for(2.0)
    rig.link.goto(*geo.offset_gps(*HOME, 20.0, 10.0), 8.0)
    rig.run_for(8.0)
    rig.link.rtl()
    rig.run_for(10.0)
    return [(e.kind, e.text) for e in rig.link.drain_events() if e.kind != "link"]


@pytest.mark.parametrize("profile", ["solo", "husky", "spiri"])
def test_memory_rig_and_pty_rig_put_the_same_bytes_on_the_line(profile: str) -> None:
    """The cores without a port and the transports on a pty exchange the same bytes both
    ways, frame for frame, and the link sees the same flight."""
    memory = MemoryRig(profile, home=HOME, gps_fix_delay_s=1.0, seed=3)
    on_pty = SimRig(profile, home=HOME, gps_fix_delay_s=1.0, seed=3)
    try:
        recs = [_record(memory), _record(on_pty)]
        events = [_flight(memory), _flight(on_pty)]
        assert recs[0]["sim"] == recs[1]["sim"] and len(recs[0]["sim"]) > 50_000
        assert recs[0]["link"] == recs[1]["link"]
        assert events[0] == events[1]
        assert memory.link.telemetry == on_pty.link.telemetry
        assert memory.sim.position == on_pty.sim.position
    finally:
        on_pty.close()


def test_the_link_core_takes_any_split_of_the_stream() -> None:
    """The vehicle's bytes fed at once or a few at a time: the same telemetry and counts."""
    rig = MemoryRig(home=HOME)
    rig.connect(10.0)
    rig.run_for(1.0)
    stream = b""
    for _ in range(20):
        rig.sim.step(0.1)
        stream += rig.sim.data_to_send()
    whole, pieces = AutopilotCore(clock=rig.clock), AutopilotCore(clock=rig.clock)
    assert whole.receive_data(stream) > 100
    for i in range(0, len(stream), 7):
        pieces.receive_data(stream[i : i + 7])
    assert whole.telemetry == pieces.telemetry and whole.message_counts == pieces.message_counts
    assert whole.telemetry.lat == pytest.approx(HOME[0], abs=1e-6)


def test_a_command_leaves_through_data_to_send_and_the_ack_completes_it() -> None:
    """No port: arm() is queued until a heartbeat is heard, then sent as a COMMAND_LONG;
    the vehicle core's COMMAND_ACK, fed back, completes it."""
    now = [0.0]
    link = AutopilotCore(clock=lambda: now[0], heartbeat_interval_s=None)
    sim = SimArduPilot(load_profile("solo"), home=HOME)
    cmd = link.arm()
    assert cmd.status is CommandStatus.QUEUED and link.data_to_send() == b""
    sim.step(0.1)
    link.receive_data(sim.data_to_send())  # the heartbeat
    assert link.data_to_send() == b""  # sent when time moves on, as poll() does after reading
    link.tick()
    out = link.data_to_send()
    decoder = mavlink2.MAVLink(None)
    sent = decoder.parse_buffer(out)
    assert [m.get_type() for m in sent] == ["COMMAND_LONG"]
    assert sent[0].command == mavlink2.MAV_CMD_COMPONENT_ARM_DISARM and sent[0].param1 == 1
    assert sim.receive_data(out) == 1
    link.receive_data(sim.data_to_send())
    assert cmd.ok and sim.armed


def test_the_vehicle_core_is_deterministic() -> None:
    """Same inputs, same bytes: two vehicle cores fed the same commands agree byte for byte."""
    outs = []
    for _ in range(2):
        sim = SimArduPilot(load_profile("solo"), home=HOME, default_rate_hz=10.0, seed=5)
        sim.faults.garbage_every = 5
        enc = mavlink2.MAVLink(None, srcSystem=255, srcComponent=191)
        out = b""
        for k in range(50):
            if k == 10:  # arm
                arm = enc.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
                sim.receive_data(arm.pack(enc))
            sim.step(0.1)
            out += sim.data_to_send()
        outs.append(out)
    assert outs[0] == outs[1] and len(outs[0]) > 10_000
