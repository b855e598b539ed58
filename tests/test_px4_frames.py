"""PX4's worked MAVLink frames, byte for byte: each made by our encoders, each decoded back.

The frames and their meaning are those of the PX4 offboard spec (section 9.2; companion
1/195, PX4 1/1). The companion's frames come out of `Px4Core` (its heartbeat, commands and
codec), PX4's out of `SimPx4`; decoding goes through `FrameReader` and into the other side,
which must read each frame as the spec says.
"""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import all as mavlink2

from fieldkit.robot.profiles import load_profile
from fieldkit.vehicle.mavlink import FrameReader
from fieldkit.vehicle.px4 import (
    MODES,
    SETTABLE,
    Px4Core,
    custom_mode,
    mode_name,
    set_mode_params,
    split_custom_mode,
)
from fieldkit.vehicle.sim.px4 import SimPx4

HOME = (45.5049, -73.6133)

# The spec's hex, split in lines of 64 digits.
FRAMES = {
    "companion_heartbeat": "FD0900000001C300000000000000120800040373EA",
    "arm": (
        "FD2000000101C34C00000000803F000000000000000000000000000000000000000000000000900101014AFA"
    ),
    "disarm_force": (
        "FD2000000201C34C0000000000000098A5460000000000000000000000000000000000000000900101015A81"
    ),
    "set_mode_offboard": (
        "FD2000000301C34C00000000803F0000C0400000000000000000000000000000000000000000B00001015281"
    ),
    "position_target_local_ned": (
        "FD3500000401C3540000E803000000000000000000000000A0C0000000000000"
        "0000000000000000000000000000000000000000000000000000F8090101014B"
        "2B"
    ),
    "takeoff_nav": (
        "FD2000000701C34C00000000C07F0000C07F0000C07F0000C07F0000C07F0000C07F0000C07F16000101B252"
    ),
    "set_mode_auto_land": (
        "FD2000000901C34C00000000803F000080400000C04000000000000000000000000000000000B0000101A6D5"
    ),
    "px4_heartbeat_offboard_armed": "FD09000000010100000000000600020C9104037352",
    "px4_ack_arm_rejected": "FD0A00000201014D0000900101000000000001C31AE2",
    "px4_extended_sys_state_in_air": "FD020000040101F5000000029BFC",
}

# The spec's HEARTBEAT custom_mode table: name, main, sub, decimal.
CUSTOM_MODES = [
    ("MANUAL", 1, 0, 65536),
    ("ALTCTL", 2, 0, 131072),
    ("POSCTL", 3, 0, 196608),
    ("ORBIT", 3, 1, 16973824),
    ("READY", 4, 1, 17039360),
    ("TAKEOFF", 4, 2, 33816576),
    ("LOITER", 4, 3, 50593792),
    ("MISSION", 4, 4, 67371008),
    ("RTL", 4, 5, 84148224),
    ("LAND", 4, 6, 100925440),
    ("FOLLOWME", 4, 8, 134479872),
    ("PRECLAND", 4, 9, 151257088),
    ("VTOL_TAKEOFF", 4, 10, 168034304),
    ("ACRO", 5, 0, 327680),
    ("OFFBOARD", 6, 0, 393216),
    ("STABILIZED", 7, 0, 458752),
]


def frame(name: str) -> bytes:
    return bytes.fromhex(FRAMES[name])


def decode(data: bytes) -> object:
    """The one message in `data`, by our resynchronising reader (no byte left over)."""
    reader = FrameReader(mavlink2.MAVLink(None))
    msgs = reader.feed(data)
    assert len(msgs) == 1 and reader.bad_frames == 0 and reader.unknown_frames == 0
    assert bytes(msgs[0].get_msgbuf()) == data
    return msgs[0]


def connected_core(**options: object) -> Px4Core:
    """A Px4Core that has heard the spec's PX4 heartbeat (armed, OFFBOARD) and a position,
    its outbox emptied."""
    core = Px4Core(profile=load_profile("spiri"), clock=lambda: 1.0, **options)  # type: ignore[arg-type]
    assert core.receive_data(frame("px4_heartbeat_offboard_armed")) == 1
    enc = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    pos = enc.global_position_int_encode(0, 455049000, -736133000, 55000, 5000, 0, 0, 0, 0)
    assert core.receive_data(bytes(pos.pack(enc))) == 1
    core.data_to_send()
    return core


# ---------------------------------------------------------------------------- the checksum


@pytest.mark.parametrize(("data", "crc"), [(b"123456789", 0x6F91), (b"", 0xFFFF), (b"A", 0x5C0A)])
def test_the_x25_vectors(data: bytes, crc: int) -> None:
    assert mavlink2.x25crc(data).crc == crc


# ---------------------------------------------------------------------------- modes


@pytest.mark.parametrize(("name", "main", "sub", "value"), CUSTOM_MODES)
def test_custom_mode_integers(name: str, main: int, sub: int, value: int) -> None:
    assert custom_mode(main, sub) == value
    assert split_custom_mode(value) == (main, sub)
    assert mode_name(value) == name and MODES[name] == (main, sub)
    assert value.to_bytes(4, "little") == bytes((0, 0, main, sub))


def test_mode_names_of_the_unknown_and_what_do_set_mode_selects() -> None:
    assert mode_name(custom_mode(4, 7)) == "PX4(4.7)"  # the retired RTGS
    assert mode_name(custom_mode(9, 0)) == "PX4(9.0)"
    assert mode_name(custom_mode(6, 3)) == "OFFBOARD"  # no sub modes outside AUTO/POSCTL
    assert set_mode_params("OFFBOARD") == (1.0, 6.0, 0.0)
    assert set_mode_params("LAND") == (1.0, 4.0, 6.0)
    assert set_mode_params("RTL") == (1.0, 4.0, 5.0)
    assert set_mode_params("LOITER") == (1.0, 4.0, 3.0)
    assert set_mode_params("READY") is None and "READY" not in SETTABLE
    assert set_mode_params("GUIDED") is None


# ---------------------------------------------------------------------------- companion side


def test_companion_heartbeat() -> None:
    core = Px4Core(clock=lambda: 0.0)
    core.tick()  # the first tick sends our heartbeat
    out = core.data_to_send()
    assert out == frame("companion_heartbeat")
    hb = decode(out)
    assert (hb.type, hb.autopilot, hb.base_mode, hb.custom_mode, hb.system_status) == (  # type: ignore[attr-defined]
        18, 8, 0, 0, 4)  # fmt: skip


def test_the_spec_heartbeat_tells_the_core_offboard_and_armed() -> None:
    core = connected_core()
    t = core.telemetry
    assert (core.target_system, core.target_component) == (1, 1)
    assert t.mode == "OFFBOARD" and t.custom_mode == 393216 and t.armed
    assert t.autopilot_type == 12 and t.mav_type == 2 and t.system_status == 4


def test_arm() -> None:
    core = connected_core()
    core._mav.seq = 1
    cmd = core.arm()
    out = core.data_to_send()
    assert out == frame("arm")
    m = decode(out)
    assert (m.command, m.param1, m.param2, m.confirmation) == (400, 1.0, 0.0, 0)  # type: ignore[attr-defined]
    assert (m.target_system, m.target_component) == (1, 1)  # type: ignore[attr-defined]
    assert not cmd.done


def test_forced_disarm() -> None:
    core = connected_core()
    core._mav.seq = 2
    core.disarm(force=True)
    out = core.data_to_send()
    assert out == frame("disarm_force")
    assert decode(out).param2 == 21196.0  # type: ignore[attr-defined]


def test_set_mode_offboard_once_the_stream_runs() -> None:
    core = connected_core(offboard_warmup_s=0.0)
    assert core.goto(*HOME, 5.0).ok  # the stream: OFFBOARD's condition
    assert decode(core.data_to_send()).get_type() == "SET_POSITION_TARGET_GLOBAL_INT"  # type: ignore[attr-defined]
    core._mav.seq = 3
    core.set_mode("OFFBOARD")
    out = core.data_to_send()
    assert out == frame("set_mode_offboard")
    m = decode(out)
    assert (m.command, m.param1, m.param2, m.param3) == (176, 1.0, 6.0, 0.0)  # type: ignore[attr-defined]


def test_position_target_local_ned_and_the_simulated_px4_takes_it() -> None:
    core = connected_core()
    core._mav.seq = 4
    core._mav.set_position_target_local_ned_send(
        1000, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, 0x09F8, 0.0, 0.0, -5.0, *([0.0] * 6), 0.0, 0.0
    )
    out = core.data_to_send()
    assert out == frame("position_target_local_ned")
    m = decode(out)
    assert (m.time_boot_ms, m.coordinate_frame, m.type_mask, m.z) == (1000, 1, 2552, -5.0)  # type: ignore[attr-defined]
    sim = SimPx4(load_profile("spiri"), home=HOME)
    sim.step(0.1)  # the GPS fix: a local position
    assert sim.receive_data(out) == 1
    assert sim.setpoints == 1 and sim.setpoints_dropped == 0
    assert sim.offboard_target == (0.0, 0.0, 5.0, math.pi / 2)  # 5 m up, facing north


def test_takeoff_nav_all_nan() -> None:
    core = connected_core()
    core._mav.seq = 7
    core.command(mavlink2.MAV_CMD_NAV_TAKEOFF, [math.nan] * 7)
    out = core.data_to_send()
    assert out == frame("takeoff_nav")
    m = decode(out)
    assert m.command == 22 and all(math.isnan(getattr(m, f"param{i}")) for i in range(1, 8))  # type: ignore[attr-defined]


def test_set_mode_auto_land() -> None:
    core = connected_core()
    core._mav.seq = 9
    cmd = core.land()
    assert cmd.name == "land (LAND)"
    out = core.data_to_send()
    assert out == frame("set_mode_auto_land")
    m = decode(out)
    assert (m.command, m.param1, m.param2, m.param3) == (176, 1.0, 4.0, 6.0)  # type: ignore[attr-defined]


# ---------------------------------------------------------------------------- PX4's side


def px4_sim() -> SimPx4:
    sim = SimPx4(load_profile("spiri"), home=HOME)
    sim._mav.seq = 0
    return sim


def test_px4_heartbeat_offboard_armed() -> None:
    sim = px4_sim()
    sim.mode = "OFFBOARD"
    sim.vehicle.armed = True
    sim._send_heartbeat()
    out = sim.data_to_send()
    assert out == frame("px4_heartbeat_offboard_armed")
    hb = decode(out)
    assert (hb.autopilot, hb.base_mode, hb.custom_mode) == (12, 0x91, 393216)  # type: ignore[attr-defined]


def test_px4_heartbeat_disarmed_in_hold() -> None:
    sim = px4_sim()
    sim.mode = "LOITER"
    sim._send_heartbeat()
    hb = decode(sim.data_to_send())
    assert (hb.base_mode, hb.custom_mode, hb.system_status) == (0x1D, 50593792, 3)  # type: ignore[attr-defined]


def test_px4_refuses_to_arm_without_a_fix() -> None:
    """A real refusal by the simulated PX4 (no GPS fix yet), from a companion 1/195: the
    spec's ACK, after the STATUSTEXT that says why."""
    sim = SimPx4(load_profile("spiri"), home=HOME, gps_fix_delay_s=100.0)
    enc = mavlink2.MAVLink(None, srcSystem=1, srcComponent=195)
    arm = enc.command_long_encode(1, 1, 400, 0, 1.0, 0, 0, 0, 0, 0, 0)
    sim._mav.seq = 1
    assert sim.receive_data(bytes(arm.pack(enc))) == 1
    out = sim.data_to_send()
    reader = FrameReader(mavlink2.MAVLink(None))
    text, ack = reader.feed(out)
    assert text.get_type() == "STATUSTEXT" and text.text == "Arming denied: GPS fix too low"
    assert bytes(ack.get_msgbuf()) == frame("px4_ack_arm_rejected")
    assert (ack.command, ack.result, ack.target_system, ack.target_component) == (400, 1, 1, 195)


def test_px4_extended_sys_state_in_air() -> None:
    sim = px4_sim()
    sim.vehicle.start_flying(5.0)
    sim._mav.seq = 4
    sim._send_extended_sys_state()
    out = sim.data_to_send()
    assert out == frame("px4_extended_sys_state_in_air")
    m = decode(out)
    assert (m.vtol_state, m.landed_state) == (0, 2)  # type: ignore[attr-defined]
