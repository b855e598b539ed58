"""The DJI link on real ptys: `DjiLink` (pyserial) against `SimM100Vehicle`, the node's view of
it, `open_link`, and `fieldkit vehicle-sim --profile m100` as a process.

Waits are on bytes or conditions with wall-clock deadlines (hang guards), never on time.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
from rigs import kill_and_drain
from rigs.dji import DJI_HOME, DjiPtyRig

from fieldkit.node.autopilot_port import MavlinkAutopilot
from fieldkit.robot import geo
from fieldkit.robot.profiles import load_profile
from fieldkit.robot.safety import Order
from fieldkit.vehicle.autopilot import AutopilotError
from fieldkit.vehicle.dji import messages as M
from fieldkit.vehicle.dji.core import DjiError
from fieldkit.vehicle.dji.link import DjiLink
from fieldkit.vehicle.links import open_link
from fieldkit.vehicle.pty import open_pty
from fieldkit.vehicle.sim.dji import TEST_APP_ID, TEST_APP_KEY
from fieldkit.vehicle.sim.dji_vehicle import SimM100Vehicle


def test_takeoff_goto_land_over_a_pty() -> None:
    with DjiPtyRig() as rig:
        rx: list[bytes] = []
        tx: list[bytes] = []
        rig.link.on_rx, rig.link.on_tx = rx.append, tx.append
        rig.link.wait_connected(10.0, idle=rig.tick, poll_interval=0.0)
        rig.link.wait_gps_fix(5.0, idle=rig.tick, poll_interval=0.0)
        t = rig.link.wait_position(5.0, idle=rig.tick, poll_interval=0.0)
        assert rig.link.core.connected and rig.sim.authority

        rig.link.wait_command(rig.link.takeoff(4.0), 20.0, idle=rig.tick, poll_interval=0.0)
        assert rig.run_until(lambda: abs((t.alt_rel_m or 0) - 4.0) < 0.05, 15.0)
        lat, lon = geo.offset_gps(*DJI_HOME, 12.0, 5.0)
        assert rig.link.goto(lat, lon, 6.0).ok
        assert rig.run_until(
            lambda: geo.range_bearing(*rig.sim.position[:2], lat, lon)[0] < 0.1, 30
        )
        rig.link.wait_command(rig.link.land(), 5.0, idle=rig.tick, poll_interval=0.0)
        assert rig.run_until(lambda: rig.link.core.flight_status == M.STATUS_STANDBY, 30.0)
        assert not t.armed and rig.sim.vehicle.z == 0.0

        # Every byte crossed the line, through the taps, and nothing was damaged.
        assert sum(map(len, rx)) == rig.link.core.bytes_received == rig.sim.bytes_sent
        assert sum(map(len, tx)) == rig.link.bytes_written == rig.sim.bytes_received
        assert rig.link.bad_frames == 0 and rig.sim.reader.bad_frames == 0
        assert rig.sim.movement_frames > 300 and rig.link.bytes_dropped == 0


def test_a_wrong_app_id_fails_the_start_up_naming_the_code() -> None:
    with DjiPtyRig(app_id=77, unknown_app_code=0x0006) as rig:
        with pytest.raises(DjiError) as e:
            rig.link.wait_connected(10.0, idle=rig.tick, poll_interval=0.0)
        assert str(e.value) == (
            "activation refused: 0x0006 SERVER_ACCESS_REFUSED (the server refused the app id) "
            "(app id 77)"
        )


def test_a_wrong_app_key_fails_the_start_up() -> None:
    with DjiPtyRig(app_key="a" * 64) as rig:
        with pytest.raises(DjiError, match="0xFF00 KEY_ERROR"):
            rig.link.wait_connected(10.0, idle=rig.tick, poll_interval=0.0)


def test_a_silent_line_says_what_to_check() -> None:
    with DjiPtyRig() as rig:
        rig.sim.faults.silent = True
        with pytest.raises(DjiError) as e:
            rig.link.wait_connected(2.0, idle=rig.tick, poll_interval=0.0)
        assert str(e.value).startswith("M100 not activated after 2 s on /dev/")
        assert "nothing received" in str(e.value) and "baud rate" in str(e.value)


def test_the_node_port_flies_the_m100_and_sees_the_pilot() -> None:
    """The node's VehiclePort adapter (MavlinkAutopilot, duck-typed) on the DJI link."""
    with DjiPtyRig() as rig:
        rig.link.wait_connected(10.0, idle=rig.tick, poll_interval=0.0)
        rig.link.wait_position(5.0, idle=rig.tick, poll_interval=0.0)
        port = MavlinkAutopilot(rig.link, (*DJI_HOME, 0.0))  # type: ignore[arg-type]
        frame = geo.LocalFrame(*DJI_HOME)
        port.execute(Order("takeoff", (5.0,)), frame)
        assert rig.run_until(lambda: port.telemetry().alt > 4.95, 20.0)
        tel = port.telemetry()
        assert tel.status == 2 and tel.armed and not tel.rc_override
        assert tel.battery_percent > 90 and tel.heartbeat_age_s < 0.1
        for _ in range(300):  # the supervisor's goto, re-sent every tick (every 5 steps)
            port.execute(Order("goto", (10.0, -6.0, 5.0)), frame)
            rig.run_for(0.1)
            port.poll()
        x, y, _ = frame.from_gps(*rig.sim.position[:2])
        assert (y, x) == pytest.approx((10.0, -6.0), abs=0.2)
        rig.sim.pilot_switch("A")
        rig.run_for(0.2)
        port.poll()
        assert port.telemetry().rc_override
        messages, bad = port.counters()
        assert messages > 1000 and bad == 0


def test_open_link_picks_the_dji_link_and_wants_the_keys() -> None:
    prof = load_profile("m100")
    pty = open_pty()
    try:
        with pytest.raises(AutopilotError, match=r"app id and app key: give them in the node"):
            open_link(prof, pty.slave_path, clock=time.monotonic)
        link = open_link(
            prof,
            pty.slave_path,
            clock=time.monotonic,
            dji_app_id=TEST_APP_ID,
            dji_app_key=TEST_APP_KEY,
        )
        assert isinstance(link, DjiLink) and link.core.control_rate_hz == 50.0
        link.close()
        with pytest.raises(DjiError, match="cannot open the DJI link /nonexistent/tty"):
            open_link(
                prof,
                "/nonexistent/tty",
                clock=time.monotonic,
                dji_app_id=1,
                dji_app_key=TEST_APP_KEY,
            )
    finally:
        pty.close()


@contextmanager
def realtime_m100(**options: object) -> Iterator[tuple[SimM100Vehicle, str]]:
    """A simulated M100 on a pty stepped in real time by a thread, as vehicle-sim runs it."""
    pty = open_pty()
    sim = SimM100Vehicle(load_profile("m100"), pty.master, home=DJI_HOME, **options)  # type: ignore[arg-type]
    stop = threading.Event()
    thread = threading.Thread(target=sim.run, args=(50.0, stop), daemon=True)
    thread.start()
    try:
        yield sim, pty.slave_path
    finally:
        stop.set()
        thread.join()
        sim.close()
        pty.close()


def test_the_stream_thread_keeps_movement_control_going_between_polls() -> None:
    with realtime_m100() as (sim, path):
        link = DjiLink(
            path, app_id=TEST_APP_ID, app_key=TEST_APP_KEY, profile=load_profile("m100"),
            stream_thread=True,
        )  # fmt: skip
        try:
            link.wait_connected(10.0)
            link.wait_command(link.takeoff(2.0), 20.0)
            deadline = time.monotonic() + 20.0
            while sim.vehicle.z < 1.9 and time.monotonic() < deadline:
                link.poll(0.05)
            assert sim.vehicle.z >= 1.9
            # No poll from here on: only the thread sends; the frames keep coming.
            before = sim.movement_frames
            deadline = time.monotonic() + 10.0
            while sim.movement_frames < before + 20 and time.monotonic() < deadline:
                time.sleep(0.01)
            assert sim.movement_frames >= before + 20
        finally:
            link.close()  # gives control authority back to the RC
        assert not sim.authority and sim.device == M.DEVICE_RC


def test_vehicle_sim_runs_an_m100_for_the_profile() -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "fieldkit", "vehicle-sim", "--profile", "m100", "--port", "auto",
         "--home", "45.5,-73.6", "--rc-mode", "F"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/")
        link = DjiLink(path, app_id=TEST_APP_ID, app_key=TEST_APP_KEY, profile=load_profile("m100"))
        try:
            t = link.wait_connected(20.0)
            link.wait_position(10.0)
            assert t.lat == pytest.approx(45.5, abs=1e-6) and link.core.version is not None
        finally:
            link.close()
    finally:
        _, err = kill_and_drain(proc, 10.0)
    assert "vehicle-sim: m100 (DJI M100 flight controller, OPEN protocol; app id 1024768" in err
    assert "activated: app id 1024768" in err


@pytest.mark.parametrize(
    ("args", "text"),
    [
        (["--app-key", "12"], "error: --app-key: the DJI app key must be 64 hex digits"),
        (["--app-id", "0"], "error: --app-id must be a positive 32-bit number, got 0"),
        (["--rc-mode", "X"], "error: --rc-mode must be P, A or F, got 'X'"),
    ],
)
def test_vehicle_sim_checks_the_dji_options(args: list[str], text: str) -> None:
    from typer.testing import CliRunner

    from fieldkit.cli import app

    result = CliRunner().invoke(app, ["vehicle-sim", "--profile", "m100", *args])
    assert result.exit_code == 1 and text in result.output
    other = CliRunner().invoke(app, ["vehicle-sim", "--profile", "solo", "--app-id", "5"])
    assert other.exit_code == 1 and "--app-id and --app-key are for DJI profiles" in other.output
