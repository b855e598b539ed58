"""The DJI Onboard SDK core (`DjiCore`) against the simulated M100 flight controller, no pty.

`DjiMemoryRig` passes the bytes between `SimM100` and `DjiCore` in memory on a simulated
50 Hz clock: the protocol is tested here, the serial transport in tests/test_dji_link.py.
"""

from __future__ import annotations

import math

import pytest
from rigs.dji import DJI_HOME, DjiMemoryRig

from fieldkit.robot import geo
from fieldkit.vehicle.autopilot import CommandStatus
from fieldkit.vehicle.dji import messages as M
from fieldkit.vehicle.dji.core import DjiCommand, DjiCore, DjiError
from fieldkit.vehicle.sim.dji import TEST_APP_ID, TEST_APP_KEY

POSITION_MODE = 11  # control mode of flag 0x91: POS/POS/ANG (spec §8.2)


def texts(rig: DjiMemoryRig) -> list[tuple[str, str]]:
    """The core's events so far, as (kind, text)."""
    return [(e.kind, e.text) for e in rig.core.drain_events()]


def finish(rig: DjiMemoryRig, cmd: DjiCommand, seconds: float = 20.0) -> DjiCommand:
    """Tick until `cmd` is over."""
    assert rig.run_until(lambda: cmd.done, seconds), f"{cmd} still pending"
    return cmd


def airborne(rig: DjiMemoryRig, alt: float = 5.0) -> None:
    """Connected and hovering at `alt` metres."""
    rig.connect()
    assert finish(rig, rig.core.takeoff(alt)).ok
    assert rig.run_until(lambda: abs(rig.sim.vehicle.z - alt) < 0.05, 20.0)


# ---------------------------------------------------------------------------- connection


def test_activation_sets_the_broadcast_and_decodes_it() -> None:
    rig = DjiMemoryRig()
    assert rig.run_until(lambda: rig.core.activated, 5.0)
    core, sim = rig.core, rig.sim
    assert sim.activated and core.version is not None
    assert core.version.firmware_text == "3.1.10.0"
    # The rates asked for: 50 Hz for what the core reads, the time stamp 1 Hz, the rest off.
    assert sim.broadcast_rates == (1, 50, 0, 50, 0, 50, 0, 50, 0, 50, 50, 50)
    rig.run_for(1.0)
    t = core.telemetry
    assert (t.lat, t.lon) == pytest.approx(DJI_HOME, abs=1e-7)
    assert t.alt_rel_m == 0.0 and t.alt_msl_m == 50.0 and t.gps_fix_type == 3
    assert t.battery_percent == 100.0 and t.landed_state == 1 and not t.armed
    assert t.yaw_rad == pytest.approx(sim_yaw(rig), abs=1e-6)
    assert t.rc_channels[4] == 1900  # the mode switch in F reads as 1900 us
    assert core.heartbeat_age() < 0.1 and core.messages > 40 and core.bad_frames == 0
    assert ("activation", "flight controller: M100 firmware 3.1.10.0, serial 0SIM000100") in (
        texts(rig)
    )
    assert not core.authority and not core.pilot_override and t.mode == "RC_F"


def sim_yaw(rig: DjiMemoryRig) -> float:
    """The simulated aircraft's heading as the broadcast carries it (0 north, to the east)."""
    return math.remainder(math.pi / 2 - rig.sim.vehicle.yaw, 2 * math.pi)


def test_an_unknown_app_id_is_retried_then_refused_naming_the_code() -> None:
    rig = DjiMemoryRig(app_id=4242)
    takeoff = rig.core.takeoff(5.0)  # waits for the activation, then fails with it
    assert rig.run_until(lambda: rig.core.activation_error is not None, 10.0)
    error = rig.core.activation_error
    assert error is not None and error.startswith("activation refused: 0x0003 NEW_DEVICE")
    assert "(app id 4242)" in error
    # "New device" is worth retrying (users report two attempts): three in all.
    assert rig.sim.refusals[M.CMD_ACTIVATE] == 3
    assert takeoff.status is CommandStatus.FAILED
    assert takeoff.error == f"takeoff 5: not sent, not activated: {error}"
    assert ("activation", error) in texts(rig)
    # Final: nothing more is tried, later orders fail at once.
    rig.run_for(3.0)
    assert rig.sim.refusals[M.CMD_ACTIVATE] == 3
    assert rig.core.land().status is CommandStatus.FAILED


def test_a_refused_app_id_is_final_at_once() -> None:
    rig = DjiMemoryRig(app_id=4242, unknown_app_code=0x0006)
    assert rig.run_until(lambda: rig.core.activation_error is not None, 5.0)
    assert "0x0006 SERVER_ACCESS_REFUSED" in (rig.core.activation_error or "")
    assert rig.sim.refusals[M.CMD_ACTIVATE] == 1


def test_a_wrong_app_key_is_caught_by_the_first_encrypted_command() -> None:
    rig = DjiMemoryRig(app_key="f" * 64)
    assert rig.run_until(lambda: rig.core.activated, 5.0)  # the id is right: activated
    cmd = finish(rig, rig.core.obtain_control())
    assert cmd.error == (
        "obtain control failed: control authority refused: 0xFF00 KEY_ERROR (the encryption "
        "key is wrong: check the app key)"
    )
    assert rig.core.key_rejected and not rig.core.authority
    assert rig.sim.key_errors == 1 and not rig.sim.authority
    assert any(k == "activation" and "not this app id's" in t for k, t in texts(rig))


def test_without_encryption_frames_go_in_clear() -> None:
    rig = DjiMemoryRig(core_options={"encrypt": False})
    rig.connect()
    assert rig.sim.reader.undecryptable == 0 and rig.sim.authority


def test_a_bad_app_key_or_rate_is_refused_before_anything_is_sent() -> None:
    with pytest.raises(DjiError, match="64 hex digits"):
        DjiCore(app_id=1, app_key="abc")
    with pytest.raises(DjiError, match="one of 1, 10, 50, 100 Hz"):
        DjiCore(app_id=1, app_key=TEST_APP_KEY, broadcast_hz=20)
    with pytest.raises(DjiError, match=r"\(0, 50\] Hz"):
        DjiCore(app_id=1, app_key=TEST_APP_KEY, control_rate_hz=100.0)


def test_a_silent_flight_controller_is_reported_once_and_retried() -> None:
    rig = DjiMemoryRig()
    rig.sim.faults.silent = True
    rig.run_for(5.0)
    events = texts(rig)
    assert (
        events.count(
            (
                "activation",
                "connect failed: get version: no answer after 3 tries; trying again every 1 s",
            )
        )
        == 1
    )
    # 3 tries a second, the same frame each time: run once, then answered from the cache.
    assert rig.sim.received[M.CMD_GET_VERSION] >= 4 and rig.sim.duplicates >= 8
    assert rig.core.heartbeat_lost
    rig.sim.faults.silent = False
    assert rig.run_until(lambda: rig.core.activated, 3.0)


def test_heartbeat_loss_and_return_are_events() -> None:
    rig = DjiMemoryRig()
    rig.connect()
    texts(rig)
    rig.sim.faults.silent = True
    rig.run_for(4.0)
    assert any(t.startswith("flight controller silent: no frame for 3.") for _, t in texts(rig))
    rig.sim.faults.silent = False
    rig.run_for(0.5)
    assert ("heartbeat", "flight controller heard again") in texts(rig)


# ---------------------------------------------------------------------------- authority


def test_authority_refused_with_the_switch_out_of_f() -> None:
    rig = DjiMemoryRig(rc_mode="P")
    assert rig.run_until(lambda: rig.core.activated, 5.0)
    rig.run_for(0.2)
    core = rig.core
    assert core.pilot_override and core.telemetry.rc_override and core.telemetry.mode == "RC_P"
    refused = core.takeoff(5.0)
    assert refused.error == "takeoff 5 refused: the pilot has control (RC mode switch in P, not F)"
    cmd = finish(rig, core.obtain_control())  # asked anyway: the FC says why not
    assert cmd.error == (
        "obtain control failed: control authority refused: 0x0000 RC_MODE_NOT_F "
        "(put the RC mode switch in F)"
    )
    assert cmd.code == M.CONTROL_SWITCH_NOT_F and not rig.sim.authority


def test_obtain_in_progress_is_sent_again_as_a_new_command() -> None:
    rig = DjiMemoryRig(obtain_in_progress_first=True)
    rig.connect()
    assert rig.sim.received[M.CMD_CONTROL] == 2 and rig.sim.duplicates == 0
    assert ("authority", "control authority obtained") in texts(rig)


def test_a_lost_ack_is_retransmitted_and_not_run_twice() -> None:
    rig = DjiMemoryRig()
    assert rig.run_until(lambda: rig.core.activated, 5.0)
    rig.sim.faults.drop_acks = 1
    sent = rig.core.frames_sent
    cmd = finish(rig, rig.core.obtain_control())
    assert cmd.ok and cmd.attempts == 2
    assert rig.core.frames_sent - sent == 2
    assert rig.sim.received[M.CMD_CONTROL] == 1 and rig.sim.duplicates == 1


def test_the_pilot_takes_control_back_and_the_node_never_fights_it() -> None:
    rig = DjiMemoryRig()
    airborne(rig)
    core, sim = rig.core, rig.sim
    lat, lon = geo.offset_gps(*DJI_HOME, 40.0, 0.0)
    assert core.goto(lat, lon, 5.0).ok
    rig.run_for(2.0)
    texts(rig)
    pending = core.arm()  # queued behind nothing: in flight when the pilot flips
    sim.pilot_switch("P")
    rig.run_for(0.1)
    assert core.pilot_override and not core.authority and core.setpoint is None
    assert core.telemetry.rc_override and core.telemetry.mode == "RC_P"
    assert pending.done and not pending.ok
    events = texts(rig)
    assert ("override", "RC mode switch F -> P: the pilot has the M100") in events
    assert any(t.startswith("control authority taken back (") for _, t in events)
    # Nothing more goes out to fly it: no movement, no obtain, orders refused.
    moved, asked = sim.movement_frames, sim.received[M.CMD_CONTROL]
    for order in (core.goto(lat, lon, 5.0), core.hold(), core.land(), core.rtl()):
        assert order.status is CommandStatus.FAILED and "the pilot has control" in (
            order.error or ""
        )
    rig.run_for(3.0)
    assert sim.movement_frames == moved and sim.received[M.CMD_CONTROL] == asked
    v = sim.vehicle
    assert v.settled and v.y < 38.0  # it stopped where the pilot took it
    # The switch back in F hands the robot back: the next order asks for authority again.
    sim.pilot_switch("F")
    rig.run_for(0.1)
    assert not core.pilot_override
    assert finish(rig, core.goto(lat, lon, 5.0)).ok
    assert rig.run_until(lambda: geo.range_bearing(*sim.position[:2], lat, lon)[0] < 0.5, 30)
    assert core.authority and sim.received[M.CMD_CONTROL] == asked + 1


def test_the_app_taking_control_is_an_override_until_an_explicit_obtain() -> None:
    rig = DjiMemoryRig()
    airborne(rig)
    rig.sim.app_takes_control()
    rig.run_for(0.2)
    core = rig.core
    assert core.pilot_override and not core.authority
    assert core.hold().status is CommandStatus.FAILED
    assert "control authority taken back" in " ".join(t for _, t in texts(rig))


# ---------------------------------------------------------------------------- flight


def test_takeoff_goto_land() -> None:
    rig = DjiMemoryRig()
    rig.connect()
    core, sim = rig.core, rig.sim
    takeoff = core.takeoff(5.0)
    finish(rig, takeoff)
    assert takeoff.ok and sim.received[M.CMD_TASK] == 1
    t = core.telemetry
    assert t.armed and t.landed_state == 2 and core.flight_status == M.STATUS_IN_AIR
    assert t.home == pytest.approx((*DJI_HOME, 50.0), abs=1e-3)
    # DJI's take-off stops near 1.2 m; the core climbs on to 5 m by movement control.
    assert rig.run_until(lambda: abs((t.alt_rel_m or 0) - 5.0) < 0.05, 10.0)
    assert sim.control_mode == POSITION_MODE and t.mode == "SDK_CONTROL"

    lat, lon = geo.offset_gps(*DJI_HOME, 30.0, -20.0)
    goto = core.goto(lat, lon, 8.0)
    assert goto.ok  # a setpoint: done at once with authority
    frames, start = sim.movement_frames, rig.now
    rig.run_for(2.0)
    # 50 Hz on the simulated clock, every one applied by the flight controller.
    assert sim.movement_frames - frames == pytest.approx(100, abs=2)

    def there() -> bool:
        dist = geo.range_bearing(t.lat, t.lon, lat, lon)[0]  # type: ignore[arg-type]
        return dist < 0.05 and (t.ground_speed_mps or 0.0) < 0.05

    assert rig.run_until(there, 40.0)
    assert abs((t.alt_rel_m or 0) - 8.0) < 0.05 and rig.now - start > 5.0

    land = finish(rig, core.land())
    assert land.ok and core.setpoint is None
    seen: list[int] = []
    rig.run_until(
        lambda: seen.append(core.flight_status or 0) or core.flight_status == M.STATUS_STANDBY,
        30.0,
    )
    statuses = [s for i, s in enumerate(seen) if i == 0 or seen[i - 1] != s]
    assert statuses == [M.STATUS_LANDING, M.STATUS_LANDED, M.STATUS_STANDBY]
    assert not t.armed and t.landed_state == 1 and abs(t.alt_rel_m or 0) < 0.01
    assert geo.range_bearing(t.lat, t.lon, lat, lon)[0] < 0.5  # landed where it was
    assert sim.movement_ignored <= 2  # only frames already on the line when it landed


def test_hold_streams_zero_velocity_and_stops_the_aircraft() -> None:
    rig = DjiMemoryRig()
    airborne(rig)
    lat, lon = geo.offset_gps(*DJI_HOME, 0.0, 60.0)
    rig.core.goto(lat, lon, 5.0)
    rig.run_for(4.0)
    v = rig.sim.vehicle
    assert math.hypot(v.vx, v.vy) > 3.0
    hold = rig.core.hold()
    assert hold.ok and rig.core.telemetry.mode == "HOVER"
    assert rig.run_until(lambda: v.settled, 5.0)
    assert rig.sim.control_mode == 4  # VEL/VEL/RATE: flag 0x49
    x = v.x
    rig.run_for(2.0)
    assert v.x == x and 10.0 < x < 55.0


def test_go_home_flies_back_and_lands() -> None:
    rig = DjiMemoryRig()
    airborne(rig)
    lat, lon = geo.offset_gps(*DJI_HOME, -25.0, 10.0)
    rig.core.goto(lat, lon, 6.0)
    assert rig.run_until(lambda: geo.range_bearing(*rig.sim.position[:2], lat, lon)[0] < 0.3, 30)
    rtl = finish(rig, rig.core.rtl())
    assert rtl.ok and rig.core.telemetry.mode == "GO_HOME"
    assert rig.run_until(lambda: rig.core.flight_status == M.STATUS_STANDBY, 60.0)
    t = rig.core.telemetry
    assert geo.range_bearing(t.lat, t.lon, *DJI_HOME)[0] < 0.5  # type: ignore[arg-type]


def test_a_landing_supersedes_a_takeoff_still_watching_the_status() -> None:
    rig = DjiMemoryRig()
    rig.connect()
    takeoff = rig.core.takeoff(5.0)
    assert rig.run_until(lambda: rig.core.flight_status == M.STATUS_IN_AIR, 5.0)
    land = rig.core.land()
    assert takeoff.status is CommandStatus.CANCELLED and "superseded by land" in (
        takeoff.error or ""
    )
    assert finish(rig, land).ok


def test_the_tasks_refusals_name_the_code() -> None:
    rig = DjiMemoryRig()
    rig.connect()
    land = finish(rig, rig.core.land())
    assert land.error == "land failed: landing refused: 0x0001 EXECUTION_FAILED"
    assert finish(rig, rig.core.arm()).ok and rig.core.telemetry.armed
    # Auto take-off only with the motors stopped (spec §7.5).
    takeoff = finish(rig, rig.core.takeoff(5.0))
    assert takeoff.error == "takeoff 5 failed: take-off refused: 0x0001 EXECUTION_FAILED"
    assert finish(rig, rig.core.disarm()).ok and not rig.core.telemetry.armed
    assert finish(rig, rig.core.takeoff(5.0)).ok
    disarm = finish(rig, rig.core.disarm())
    assert disarm.error == (
        "disarm failed: disarm refused: 0x0003 AIRCRAFT_IN_AIR_ERROR (not in the air)"
    )


def test_orders_checked_before_they_go() -> None:
    rig = DjiMemoryRig()
    rig.connect()
    core = rig.core
    sent = core.frames_sent
    for cmd in (core.takeoff(-1.0), core.goto(math.nan, 0.0, 5.0), core.goto(91.0, 0.0, 5.0)):
        assert cmd.status is CommandStatus.FAILED and "refused" in (cmd.error or "")
    assert core.frames_sent == sent


def test_a_noisy_line_only_costs_counters() -> None:
    rig = DjiMemoryRig(seed=3)
    rig.sim.faults.garbage_every = 3
    rig.sim.faults.corrupt_every = 7
    airborne(rig, 4.0)
    lat, lon = geo.offset_gps(*DJI_HOME, 15.0, 15.0)
    rig.core.goto(lat, lon, 4.0)
    assert rig.run_until(lambda: geo.range_bearing(*rig.sim.position[:2], lat, lon)[0] < 0.3, 30)
    r = rig.core.reader
    assert r.crc_errors > 50 and r.garbage_bytes > 1000 and rig.core.bad_frames > 100
    assert rig.core.link_errors == 0


def test_time_state_round_trips() -> None:
    rig = DjiMemoryRig()
    rig.connect()
    state = rig.core.time_state()
    other = DjiCore(app_id=TEST_APP_ID, app_key=TEST_APP_KEY, clock=rig.clock)
    other.set_time_state(state)
    assert other.time_state()["last_heartbeat"] == state["last_heartbeat"]


def test_the_profile_dji_table() -> None:
    from fieldkit.robot.profiles import ProfileError, load_profile, parse_profile

    m100 = load_profile("m100")
    assert (m100.dji.broadcast_hz, m100.dji.control_rate_hz, m100.dji.encrypt) == (50, 50.0, True)
    import tomllib

    from fieldkit.resources import profile_dir

    data = tomllib.loads((profile_dir() / "m100.toml").read_text())
    data["dji"] = {"broadcast_hz": 20, "control_rate_hz": 80, "encrypt": "yes", "app_key": "x"}
    with pytest.raises(ProfileError) as e:
        parse_profile(data, "m.toml")
    assert e.value.problems == (
        "m.toml: dji.app_key: unknown field",
        "m.toml: dji.broadcast_hz: must be one of 1, 10, 50, 100 (the M100's rates), got 20",
        "m.toml: dji.control_rate_hz: must be <= 50 (the most the M100 reads), got 80",
        "m.toml: dji.encrypt: must be true or false, got string 'yes'",
    )
    solo = tomllib.loads((profile_dir() / "solo.toml").read_text())
    solo["dji"] = {"encrypt": False}
    with pytest.raises(ProfileError, match='dji: only for autopilot.flavour = "dji"'):
        parse_profile(solo, "s.toml")
    core = DjiCore(app_id=1, app_key=TEST_APP_KEY, profile=m100, broadcast_hz=10, encrypt=False)
    assert core.broadcast_hz == 10 and not core.encrypt


def test_a_restarted_flight_controller_is_activated_again() -> None:
    rig = DjiMemoryRig()
    rig.connect()
    # The FC restarts on the ground: it forgets the activation and the host's control.
    rig.sim.activated = rig.sim.authority = False
    rig.sim.device = M.DEVICE_RC
    arm = finish(rig, rig.core.arm())
    assert "0xFF01 NO_AUTHORIZATION" in (arm.error or "")
    assert rig.run_until(lambda: rig.sim.activated, 3.0)
    assert ("activation", "the flight controller says it is not activated (restarted?): "
            "activating again") in texts(rig)  # fmt: skip
    assert finish(rig, rig.core.arm()).ok and rig.sim.authority


def test_after_a_silence_the_connection_is_checked_again() -> None:
    rig = DjiMemoryRig()
    rig.connect()
    versions = rig.sim.received[M.CMD_GET_VERSION]
    rig.sim.faults.silent = True
    rig.run_for(4.0)
    rig.sim.faults.silent = False
    rig.run_for(1.0)
    assert rig.sim.received[M.CMD_GET_VERSION] == versions + 1 and rig.core.activated


def test_a_flight_controller_back_from_a_restart_is_not_a_pilot_override() -> None:
    rig = DjiMemoryRig()
    rig.connect()
    rig.sim.faults.silent = True
    rig.run_for(4.0)
    rig.sim.activated = rig.sim.authority = False  # it restarted meanwhile
    rig.sim.device = M.DEVICE_RC
    rig.sim.faults.silent = False
    assert rig.run_until(lambda: rig.sim.activated, 3.0)
    assert not rig.core.pilot_override and not rig.core.authority
    assert finish(rig, rig.core.arm()).ok and rig.sim.authority
