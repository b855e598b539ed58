"""`fieldkit doctor`, the field preflight, with real parts: the simulated ArduPilot on a pty
(stepped in real time by a thread), a pty standing in for the XBee that answers AT command
frames as a module does, key files from `fieldkit keys init`, a config file in tmp_path.

The tests run as root here, so `os.access` grants everything: permission problems are
tested where doctor decides them, on the stat fields of a device (`device_access_problem`,
`user_may`, a made-up service user against a real pty), and the clock and disk checks are
fed the time and the free space. Nothing waits on time: the waits are doctor's own, bounded
by `--timeout`, and a test that expects silence gives `--timeout 1`.
"""

from __future__ import annotations

import dataclasses
import os
import re
import select
import shutil
import socket
import stat
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
from digi.xbee.packets.common import ATCommPacket
from pymavlink.dialects.v20 import common as mavlink2
from rigs import pty_husky, pty_vehicle
from typer.testing import CliRunner

import bvm
from fieldkit.cli import app
from fieldkit.deploy import doctor
from fieldkit.deploy.doctor import (
    CheckResult,
    Device,
    Links,
    ServiceUser,
    Settings,
    Space,
    SystemTimeTap,
    check_clock,
    check_disk,
    check_keys,
    check_serial,
    device_access_problem,
    device_problem,
    user_may,
    xbee_verdict,
)
from fieldkit.radio.xbee import AtCommand, AtResponse
from fieldkit.robot.profiles import load_profile
from fieldkit.update.release import Release
from fieldkit.update.store import VersionStore
from fieldkit.vehicle.mavlink import new_codec
from fieldkit.vehicle.pty import open_pty
from fieldkit.vehicle.sim.dji import TEST_APP_ID, TEST_APP_KEY
from fieldkit.vehicle.sim.dji_vehicle import SimM100Vehicle

runner = CliRunner()

PLAIN = "function init() {}\nfunction step() {}\n"

#: What the fake XBee answers to each AT query.
MODULE = {b"ID": b"\x7f\xff", b"SH": b"\x00\x13\xa2\x00", b"SL": b"\x40\xa1\xb2\xc3"}

#: A line of doctor's report: status, name, detail.
LINE = re.compile(r"(ok|FAIL|skip) {2,4}(\w+): (.*)")


@pytest.fixture(autouse=True)
def _no_service_user(monkeypatch: pytest.MonkeyPatch) -> None:
    """Doctor checks devices and keys for the `fieldkit` user when the machine has one: a
    machine the node was deployed on must not change what these tests see."""
    monkeypatch.setattr(doctor, "service_user", lambda: None)


def _escaped_frames(buf: bytearray) -> Iterator[bytes]:
    """The frame data of the complete API mode 2 frames at the start of `buf`, taken off it
    (in mode 2 a 0x7E only ever starts a frame)."""
    while True:
        start = buf.find(0x7E)
        if start < 0:
            buf.clear()
            return
        end = buf.find(0x7E, start + 1)
        raw = bytes(buf[start + 1 : end if end >= 0 else len(buf)])
        body = re.sub(rb"\x7d(.)", lambda m: bytes((m[1][0] ^ 0x20,)), raw, flags=re.S)
        n = int.from_bytes(body[:2], "big") if len(body) >= 2 else -1
        if n < 0 or len(body) < n + 3:
            if end < 0:
                return  # the rest has not come yet
            del buf[:end]  # a broken frame: the next one starts at `end`
            continue
        del buf[: end if end >= 0 else len(buf)]
        yield body[2 : 2 + n]


@contextmanager
def fake_xbee(ap: int = 2, answer_mode: int = 2) -> Iterator[str]:
    """A pty standing in for an XBee in API mode `ap`: a thread reads the AT command frames
    (0x08) doctor writes, in API mode 2, and answers each with an AT response (0x88)
    encoded in `answer_mode`. Yields the path the node (and doctor) opens."""
    pty = open_pty()
    stop = threading.Event()
    values = {**MODULE, b"AP": bytes((ap,))}

    def serve() -> None:
        buf = bytearray()
        while not stop.is_set():
            ready, _, _ = select.select([pty.master], [], [], 0.05)
            if not ready:
                continue
            try:
                buf += os.read(pty.master, 4096)
            except (BlockingIOError, OSError):
                continue
            for data in _escaped_frames(buf):
                if data[0] == 0x08:
                    command = data[2:4]
                    answer = AtResponse(data[1], command, 0, values.get(command, b""))
                    os.write(pty.master, answer.encode(answer_mode))

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield pty.slave_path
    finally:
        stop.set()
        thread.join()
        pty.close()


def profile_with_radio_port(tmp_path: Path, port: str) -> Path:
    """The solo profile with its XBee on `port`."""
    path = load_profile("solo").path
    assert path is not None
    text = path.read_text()
    assert 'port = "/dev/ttyUSB0"' in text
    mine = tmp_path / "mine.toml"
    mine.write_text(text.replace('port = "/dev/ttyUSB0"', f'port = "{port}"'))
    return mine


def robot_keys(tmp_path: Path) -> Path:
    """A robot's key folder: operator.pub and swarm.key from `fieldkit keys init`."""
    result = runner.invoke(app, ["keys", "init", str(tmp_path / "operator")])
    assert result.exit_code == 0, result.output
    keys = tmp_path / "keys"
    keys.mkdir()
    for name in ("operator.pub", "swarm.key"):
        shutil.copy2(tmp_path / "operator" / name, keys / name)  # modes kept
    return keys


def write_config(tmp_path: Path, tables: str = "", **node: str) -> Path:
    """fieldkit.toml with these [node] values (paths relative to tmp_path), a [record], and
    `tables` (more tables, as TOML) last."""
    (tmp_path / "s.bzz").write_text(PLAIN)
    (tmp_path / "rec").mkdir(exist_ok=True)
    values = {"profile": "solo", "script": "s.bzz", "state_dir": "state", **node}
    lines = ["[node]", *(f'{k} = "{v}"' for k, v in values.items())]
    lines += ["[record]", 'dir = "rec"', "max_mb = 1", *tables.splitlines()]
    path = tmp_path / "fieldkit.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def run(config: Path, *args: str) -> tuple[int, dict[str, tuple[str, str]], str]:
    """`fieldkit doctor --config CONFIG ARGS`: its status, each check's (status, the rest of
    its lines), and stderr (where the last line goes)."""
    result = runner.invoke(app, ["doctor", "--config", str(config), *args])
    assert "Traceback" not in result.output
    if result.exit_code == 0:
        assert re.fullmatch(r"\d of 9 checks passed.*, none failed", result.stdout.splitlines()[-1])
        return 0, _checks(result.stdout), result.stderr
    return result.exit_code, _checks(result.stdout), result.stderr


def _checks(stdout: str) -> dict[str, tuple[str, str]]:
    """Each check's (status, the rest of its lines) in a report."""
    checks: dict[str, tuple[str, str]] = {}
    name = ""
    for line in stdout.splitlines():
        m = LINE.fullmatch(line)
        if m:
            name = m.group(2)
            checks[name] = (m.group(1), m.group(3))
        elif line.startswith(doctor.INDENT) and name:
            status, text = checks[name]
            checks[name] = (status, f"{text}\n{line.strip()}")
    return checks


# ------------------------------------------------------------------ the whole preflight


def test_a_ready_robot_passes_every_check(tmp_path: Path) -> None:
    keys = robot_keys(tmp_path)
    with pty_vehicle() as autopilot, fake_xbee() as xbee:
        profile = profile_with_radio_port(tmp_path, xbee)
        config = write_config(
            tmp_path, profile=str(profile), autopilot=autopilot, keys=str(keys), security="signed"
        )
        status, checks, stderr = run(config, "--timeout", "10")
    assert status == 0, (checks, stderr)
    assert list(checks) == list(doctor.CHECKS)
    assert {s for s, _ in checks.values()} == {"ok"}, checks
    assert "ARDUPILOTMEGA QUADROTOR on" in checks["autopilot"][1]
    assert "GPS 3D fix (fix type 3), 10 satellites" in checks["autopilot"][1]
    assert "no SYSTEM_TIME" in checks["clock"][1]  # the simulated ArduPilot does not send it
    assert "API mode 2 (AP=2), network ID 7FFF, serial 0013A20040A1B2C3" in checks["radio"][1]
    assert re.search(r"s\.bzz compiles: \d+ bytes of bytecode", checks["script"][1])
    assert "security signed" in checks["keys"][1]
    assert stderr == ""


def test_the_order_is_the_checklist_and_a_missing_device_says_how_to_find_it(
    tmp_path: Path,
) -> None:
    config = write_config(tmp_path, autopilot=str(tmp_path / "ttyACM9"), radio="none")
    status, checks, stderr = run(config, "--skip", "script")
    assert status == 1
    assert checks["serial"][0] == "FAIL"
    detail = checks["serial"][1]
    assert f"{tmp_path / 'ttyACM9'} (autopilot, node.autopilot): missing" in detail
    assert "fix: plug in the autopilot's serial or USB cable" in detail
    assert "ls -l /dev/serial/by-id/" in detail
    assert checks["autopilot"] == ("skip", "its serial device failed the serial check")
    assert checks["radio"][0] == "skip" and "node.radio = none" in checks["radio"][1]
    assert checks["script"] == ("skip", "--skip script")
    errors = [line for line in stderr.splitlines() if line.startswith("error: ")]
    assert errors == [f"error: 1 of 9 checks failed for {config}: serial; 1 skipped because of it"]


def test_no_heartbeat_fails_the_autopilot_within_the_timeout(tmp_path: Path) -> None:
    silent = open_pty()  # nothing behind it
    try:
        config = write_config(tmp_path, autopilot=silent.slave_path, radio="none")
        status, checks, _ = run(config, "--timeout", "1")
    finally:
        silent.close()
    assert status == 1
    state, text = checks["autopilot"]
    assert state == "FAIL" and "no heartbeat from the autopilot after 1 s" in text
    assert "(0 bytes received, 0 bad frames)" in text
    assert "fix: nothing came in on" in text and "SERIALn_PROTOCOL" in text
    assert checks["clock"][0] == "ok" and "its check did not pass" in checks["clock"][1]


def test_a_heartbeat_without_a_gps_fix_fails_the_autopilot(tmp_path: Path) -> None:
    with pty_vehicle(gps_fix_delay_s=1e6) as autopilot:
        config = write_config(tmp_path, autopilot=autopilot, radio="none")
        status, checks, _ = run(config, "--timeout", "1")
    assert status == 1
    state, text = checks["autopilot"]
    assert state == "FAIL" and "but no GPS fix after 1 s (fix type" in text, text
    assert "fix: take the robot outdoors" in text and "gps_fix_timeout_s = 120 s" in text


def test_a_silent_xbee_fails_the_radio(tmp_path: Path) -> None:
    silent = open_pty()
    try:
        config = write_config(tmp_path, radio=f"serial://{silent.slave_path}?baud=57600&api=1")
        status, checks, _ = run(config, "--timeout", "1", "--skip", "autopilot")
    finally:
        silent.close()
    assert status == 1
    state, text = checks["radio"]
    assert state == "FAIL" and "no answer from the XBee on" in text
    assert "its baud rate (BD) is 57600 as node.radio says" in text and "AP=1" in text


def test_an_xbee_in_another_api_mode_fails_the_radio(tmp_path: Path) -> None:
    with fake_xbee(ap=1, answer_mode=1) as xbee:
        config = write_config(tmp_path, radio=f"serial://{xbee}?api=2")
        status, checks, _ = run(config, "--skip", "autopilot")
    assert status == 1
    state, text = checks["radio"]
    assert state == "FAIL" and "runs API mode 1 (AP=1), node.radio says 2" in text, text
    assert "fix: set AP=2 on the module with XCTU" in text


def test_a_udp_port_in_use_fails_the_radio_naming_it(tmp_path: Path) -> None:
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.bind(("127.0.0.1", 0))
    port = holder.getsockname()[1]
    try:
        config = write_config(tmp_path, radio=f"udp://127.0.0.1:{port}")
        status, checks, _ = run(config, "--skip", "autopilot", "--skip", "serial")
    finally:
        holder.close()
    assert status == 1
    state, text = checks["radio"]
    assert state == "FAIL" and f"UDP port {port} is in use by another program" in text
    assert f"sudo ss -ulpn 'sport = :{port}'" in text
    # Free again: the same config passes.
    status, checks, _ = run(config, "--skip", "autopilot", "--skip", "serial")
    assert checks["radio"][0] == "ok" and f"UDP port {port} free" in checks["radio"][1]


def test_a_script_that_does_not_compile_fails_at_its_place(tmp_path: Path) -> None:
    config = write_config(tmp_path, radio="none")
    (tmp_path / "s.bzz").write_text("function init() {}\nfunction step() {\n  x = (1 +\n}\n")
    status, checks, _ = run(config, "--skip", "autopilot", "--skip", "serial")
    assert status == 1
    state, text = checks["script"]
    assert state == "FAIL" and re.match(rf"{re.escape(str(tmp_path))}/s\.bzz:\d+:\d+: ", text)
    assert "fix: correct the script at that place; `fieldkit compile" in text


def test_the_committed_version_is_what_is_checked(tmp_path: Path) -> None:
    store = VersionStore(tmp_path / "state")
    program = bvm.compile_source(PLAIN + "x = 1\n", "v.bzz")
    store.commit(0, store.put(Release.from_program(program)), reason="test")
    config = write_config(tmp_path, radio="none")
    (tmp_path / "s.bzz").write_text("not buzz (\n")  # only seeds an empty state folder
    status, checks, _ = run(config, "--skip", "autopilot", "--skip", "serial")
    assert status == 0, checks
    assert (
        f"version 0 ({Release.from_program(program).hash[:12]}…) committed in"
        in (checks["script"][1])
    )
    assert f"{len(program.bytecode)} bytes of bytecode" in checks["script"][1]


def test_a_swarm_key_readable_by_others_fails_the_keys(tmp_path: Path) -> None:
    keys = robot_keys(tmp_path)
    (keys / "swarm.key").chmod(0o644)
    config = write_config(tmp_path, radio="none", keys=str(keys))
    status, checks, _ = run(config, "--skip", "autopilot", "--skip", "serial")
    assert status == 1
    state, text = checks["keys"]
    assert state == "FAIL" and "swarm.key: is a secret key readable or writable by others" in text
    assert f"fix: chmod 600 {keys / 'swarm.key'}" in text


def test_the_operators_signing_key_on_a_robot_fails_the_keys(tmp_path: Path) -> None:
    keys = robot_keys(tmp_path)
    shutil.copy2(tmp_path / "operator" / "operator.key", keys / "operator.key")
    config = write_config(tmp_path, radio="none", keys=str(keys))
    status, checks, _ = run(config, "--skip", "autopilot", "--skip", "serial")
    assert status == 1
    state, text = checks["keys"]
    assert state == "FAIL" and "operator.key: the operator's signing key is on the robot" in text
    assert f"fix: remove it (shred -u {keys / 'operator.key'})" in text


def test_signed_security_without_keys_fails_the_keys(tmp_path: Path) -> None:
    config = write_config(tmp_path, radio="none", security="signed")
    status, checks, _ = run(config, "--skip", "autopilot", "--skip", "serial")
    assert status == 1
    state, text = checks["keys"]
    assert state == "FAIL" and "security signed (node.security)" in text
    assert 'fix: set node.keys = "/etc/fieldkit/keys"' in text


def test_a_bad_config_fails_and_skips_what_needs_it(tmp_path: Path) -> None:
    config = tmp_path / "fieldkit.toml"
    config.write_text('[node]\nprofile = "solo"\nrobot_id = "3a"\nrecod = "x"\n')
    status, checks, stderr = run(config)
    assert status == 1
    state, text = checks["config"]
    assert state == "FAIL"
    assert f'{config}: node.robot_id: must be an integer, got "3a"' in text
    assert "node.recod: unknown key (did you mean record?)" in text
    assert "fix: correct" in text
    needs_it = [name for name in doctor.CHECKS if name not in ("config", "clock")]
    for name in needs_it:
        assert checks[name] == ("skip", "the config check failed"), name
    assert checks["clock"][0] == "ok"  # needs no config: it still runs
    assert f"error: 1 of 9 checks failed for {config}: config; 7 skipped because of it" in stderr


def test_a_config_without_a_profile_is_a_config_failure(tmp_path: Path) -> None:
    config = tmp_path / "fieldkit.toml"
    config.write_text('[node]\nset = ["not an assignment"]\n')
    status, checks, stderr = run(config)
    assert status == 1
    text = checks["config"][1]
    assert "node.set: --set 'not an assignment': expected NAME=VALUE" in text
    assert "node.profile: missing" in text
    assert len([line for line in stderr.splitlines() if line.startswith("error: ")]) == 1


def test_the_command_line_follows_the_exit_code_rule(tmp_path: Path) -> None:
    result = runner.invoke(app, ["doctor", "--skip", "nose"])
    assert result.exit_code == 2 and "--skip 'nose': no such check" in result.stderr
    result = runner.invoke(app, ["doctor", "--timeout", "0"])
    assert result.exit_code == 1 and "error: --timeout must be > 0" in result.stderr
    # The default config is the one deploy writes.
    result = runner.invoke(app, ["doctor", "--skip", "autopilot", "--skip", "radio"])
    if not Path("/etc/fieldkit/fieldkit.toml").exists():
        assert result.exit_code == 1
        assert "FAIL  config: /etc/fieldkit/fieldkit.toml: cannot read" in result.stdout


# ------------------------------------------------------------------ permissions, fed data


FIELDKIT = ServiceUser("fieldkit", uid=999, gids=frozenset({999}))
DIALOUT = 20
CHAR = stat.S_IFCHR


def _names(gid: int) -> str:
    return {DIALOUT: "dialout", 5: "tty", 0: "root"}.get(gid, str(gid))


def test_a_service_user_outside_the_devices_group_is_told_to_join_it() -> None:
    found = device_access_problem(
        "/dev/autopilot", CHAR | 0o660, 0, DIALOUT, FIELDKIT, group_name=_names
    )
    assert found is not None
    problem, fix = found
    assert problem.startswith("the fieldkit user is not in group dialout, which owns it")
    assert "mode 0660" in problem
    assert fix.startswith("sudo usermod -aG dialout fieldkit, then sudo systemctl restart")
    assert "re-run `fieldkit deploy`" in fix
    joined = ServiceUser("fieldkit", 999, frozenset({999, DIALOUT}))
    assert device_access_problem("/dev/autopilot", CHAR | 0o660, 0, DIALOUT, joined) is None


def test_a_device_no_group_may_open_needs_its_mode_changed() -> None:
    found = device_access_problem("/dev/ttyUSB0", CHAR | 0o600, 0, 0, FIELDKIT, group_name=_names)
    assert found is not None
    assert "not readable and writable by the fieldkit user (mode 0600" in found[0]
    assert found[1].startswith("sudo chgrp dialout /dev/ttyUSB0 && sudo chmod 660 /dev/ttyUSB0")


def test_permission_bits_are_the_owners_then_the_groups_then_the_others() -> None:
    assert user_may(FIELDKIT, 0o600, 999, 0, 6)
    assert not user_may(FIELDKIT, 0o066, 999, 999, 6)  # the owner's bits, even if others'd do
    assert user_may(FIELDKIT, 0o060, 0, 999, 6)
    assert not user_may(FIELDKIT, 0o640, 0, 999, 6)
    assert user_may(FIELDKIT, 0o606, 0, 0, 6)
    assert user_may(ServiceUser("root", 0), 0o000, 5, 5, 6)


def test_a_real_pty_checked_for_a_service_user_outside_its_group() -> None:
    pty = open_pty()
    try:
        device = Device("radio", pty.slave_path, "node.radio")
        st = os.stat(pty.slave_path)
        outsider = ServiceUser("fieldkit", uid=4242, gids=frozenset({4242}))
        result, bad = check_serial(Links((device,)), outsider)
        assert result.status == "FAIL" and bad == {"radio"}
        assert f"{pty.slave_path} (radio, node.radio): " in result.detail
        insider = ServiceUser("fieldkit", 4242, frozenset({4242, st.st_gid}))
        if (st.st_mode >> 3) & 6 == 6:  # a group that may read and write: joining it is enough
            assert "not in group" in result.detail
            assert check_serial(Links((device,)), insider)[0].status == "ok"
    finally:
        pty.close()


def test_a_device_this_user_may_not_open_says_who_should_run_doctor() -> None:
    pty = open_pty()
    try:
        device = Device("autopilot", pty.slave_path, "node.autopilot")
        problem = device_problem(device, None, access=lambda path, mode: False)
    finally:
        pty.close()
    assert problem is not None
    assert "not readable and writable by" in problem[0]
    assert "sudo -u fieldkit fieldkit doctor" in problem[1]


def test_a_regular_file_is_no_serial_device(tmp_path: Path) -> None:
    (tmp_path / "ttyUSB0").write_text("")
    device = Device("radio", str(tmp_path / "ttyUSB0"), "the solo profile's radio.port")
    problem = device_problem(device, None)
    assert problem is not None and "not a serial device" in problem[0]


# ------------------------------------------------------------------ clock and disk, fed


def test_the_clock_of_a_pi_without_rtc_fails() -> None:
    result = check_clock(133.0, None, "")
    assert result.status == "FAIL"
    assert "the system time is 1970-01-01T00:02:13Z: never set since boot" in result.detail
    assert "timedatectl set-ntp true" in result.fix


def test_the_clock_is_compared_with_the_autopilots_gps_time() -> None:
    now = 1_780_000_000.0  # 2026
    ok = check_clock(now, 0.4, "")
    assert ok.status == "ok" and "+0.4 s from the autopilot's GPS time" in ok.detail
    late = check_clock(now, 30.0, "")
    assert late.status == "FAIL" and "is 30.0 s behind the autopilot's GPS time" in late.detail
    assert "sudo date -u -s '2026-05-28 20:27:10' (the autopilot's GPS time now)" in late.fix
    ahead = check_clock(now, -7.5, "")
    assert ahead.status == "FAIL" and "7.5 s ahead of the autopilot's" in ahead.detail
    # A Pi booted in 1970 with a GPS fix: the fix line gives the time to set.
    booted = check_clock(200.0, now - 200.0, "")
    assert booted.status == "FAIL" and "'2026-05-28 20:26:40'" in booted.fix
    alone = check_clock(now, None, "not compared: the autopilot sent no SYSTEM_TIME")
    assert alone.status == "ok"
    assert alone.detail == "2026-05-28T20:26:40Z; not compared: the autopilot sent no SYSTEM_TIME"


def test_the_autopilots_time_is_read_off_the_bytes() -> None:
    class Sink:
        def __init__(self) -> None:
            self.data = b""

        def write(self, buf: bytes) -> None:
            self.data += buf

    sink = Sink()
    mav = new_codec(sink, 1, 1)
    mav.system_time_send(0, 1000)  # no GPS time yet: no offset
    tap = SystemTimeTap(wall=lambda: 1_780_000_000.0)
    tap.feed(sink.data)
    assert tap.offset_s is None
    sink.data = b""
    mav.system_time_send(1_780_000_002_500_000, 2000)
    mav.heartbeat_send(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0)
    for i in range(0, len(sink.data), 7):  # any split of the stream
        tap.feed(sink.data[i : i + 7])
    assert tap.offset_s == pytest.approx(2.5)


def _settings(tmp_path: Path, **changes: Any) -> Settings:
    """A robot's settings under tmp_path, its record folder made."""
    (tmp_path / "rec").mkdir(exist_ok=True)
    base = Settings(
        config=tmp_path / "fieldkit.toml",
        profile="solo",
        state_dir=tmp_path / "state",
        record_dir=tmp_path / "rec",
        record_max_mb=500.0,
    )
    return dataclasses.replace(base, **changes)


def test_the_disk_needs_a_flights_cap_and_a_margin(tmp_path: Path) -> None:
    mb = 2**20
    settings = _settings(tmp_path)
    short = check_disk(settings, None, space=lambda p: Space(1, 550 * mb))
    assert short.status == "FAIL"
    assert "550 MB free, 600 MB needed (record.max_mb = 500 + 100 MB)" in short.detail
    assert "lower record.max_mb" in short.fix
    room = check_disk(settings, None, space=lambda p: Space(1, 601 * mb))
    assert room.status == "ok" and "601 MB free, 600 MB needed" in room.detail
    # On two filesystems, the state needs only the margin.
    apart = check_disk(
        settings, None, space=lambda p: Space(2 if p.name == "state" else 1, 550 * mb)
    )
    assert apart.status == "FAIL" and "record folder" in apart.detail
    assert "state folder" not in apart.detail.split("\n")[0].split(":")[0]


def test_doctor_reports_a_missing_record_folder_and_leaves_it_missing(tmp_path: Path) -> None:
    config = write_config(tmp_path, radio="none")
    (tmp_path / "rec").rmdir()
    status, checks, _ = run(config, "--skip", "autopilot", "--skip", "serial")
    assert status == 1
    assert checks["disk"][0] == "FAIL"
    assert f"record folder {tmp_path / 'rec'}: missing" in checks["disk"][1]
    assert not (tmp_path / "rec").exists()  # the node makes it; doctor only looks
    assert not (tmp_path / "state").exists()


def test_the_record_folder_must_exist_and_be_the_services(tmp_path: Path) -> None:
    settings = _settings(tmp_path, record_dir=tmp_path / "gone")
    result = check_disk(settings, None, space=lambda p: Space(1, 10**12))
    assert (
        result.status == "FAIL" and f"record folder {tmp_path / 'gone'}: missing" in result.detail
    )
    root_owned = check_disk(_settings(tmp_path), FIELDKIT, space=lambda p: Space(1, 10**12))
    assert root_owned.status == "FAIL"
    assert (
        f"record folder {tmp_path / 'rec'}: not writable by the fieldkit user" in root_owned.detail
    )
    assert f"sudo chown fieldkit: {tmp_path / 'rec'} (" in root_owned.fix


def test_keys_the_service_user_cannot_read_fail(tmp_path: Path) -> None:
    keys = robot_keys(tmp_path)
    keys.chmod(0o700)  # root's
    settings = _settings(tmp_path, keys=keys)
    result = check_keys(settings, load_profile("solo"), FIELDKIT)
    assert result.status == "FAIL"
    assert f"{keys / 'swarm.key'}: not readable by the fieldkit user" in result.detail
    assert f"sudo chown fieldkit: {keys / 'swarm.key'}" in result.fix
    assert f"{keys}: the fieldkit user may not enter it" in result.detail
    assert check_keys(settings, load_profile("solo"), None).status == "ok"


def test_a_result_prints_its_fix_under_it() -> None:
    result = CheckResult("serial", "FAIL", "one\ntwo", "do this\nthen that")
    assert result.lines() == [
        "FAIL  serial: one",
        "      two",
        "      fix: do this",
        "      fix: then that",
    ]
    assert CheckResult("clock", "ok", "fine").lines() == ["ok    clock: fine"]


def test_an_xbee_that_answers_part_says_what_it_knows() -> None:
    answers = {b"AP": AtResponse(1, b"AP", 0, b"\x02"), b"ID": AtResponse(2, b"ID", 2, b"")}
    result = xbee_verdict(
        answers, name="/dev/xbee", source="the solo profile", baud=230400, api_mode=2,
        received=20, waited=2.0,
    )  # fmt: skip
    assert result.status == "ok"
    assert result.detail == ("XBee on /dev/xbee answers: API mode 2 (AP=2), network ID ?, serial ?")


@pytest.mark.parametrize("api_mode", [1, 2])
@pytest.mark.parametrize("command", doctor.AT_QUERIES)
def test_the_at_command_frame_is_digis(api_mode: int, command: bytes) -> None:
    frame = AtCommand(0x11, command).encode(api_mode)  # frame id 0x11: escaped in mode 2
    digi = ATCommPacket(0x11, command.decode()).output(escaped=api_mode == 2)
    assert frame == digi
    # By hand: length 4, type 08, frame id 01, "AP", checksum FF - (08 + 01 + 41 + 50) = 65.
    assert AtCommand(1, b"AP").encode(1) == bytes.fromhex("7e 00 04 08 01 41 50 65")


# ------------------------------------------------------------------ the Husky and the M100


@contextmanager
def pty_m100() -> Iterator[str]:
    """A simulated M100 flight controller on a pty (the test app id and key), stepped in
    real time by a thread as `fieldkit vehicle-sim --profile m100` runs it: yields the
    path the node (and doctor) opens."""
    pty = open_pty()
    fc = SimM100Vehicle(load_profile("m100"), pty.master, home=(45.5049, -73.6133))
    stop = threading.Event()
    thread = threading.Thread(target=fc.run, args=(50.0, stop), daemon=True)
    thread.start()
    try:
        yield pty.slave_path
    finally:
        stop.set()
        thread.join()
        fc.close()
        pty.close()


def dji_table(tmp_path: Path, key: str = TEST_APP_KEY) -> str:
    """The config's [dji] table, its key in a 0600 file as `fieldkit deploy` installs it."""
    path = tmp_path / "dji-app-key"
    path.write_text(key + "\n")
    path.chmod(0o600)
    return f'[dji]\napp_id = {TEST_APP_ID}\napp_key_file = "{path}"'


def test_a_ready_husky_passes_every_check(tmp_path: Path) -> None:
    """The simulated Husky (its MCU and its GPS receiver on two ptys) and an XBee: the serial
    check covers the three devices, the autopilot check goes through the Husky's own link."""
    keys = robot_keys(tmp_path)
    with pty_husky() as (mcu, gps, _), fake_xbee() as xbee:
        config = write_config(tmp_path, profile="husky", autopilot=mcu, gps=gps,
                              radio=f"serial://{xbee}?baud=230400&api=2", keys=str(keys),
                              security="signed")  # fmt: skip
        status, checks, stderr = run(config, "--timeout", "10")
    assert status == 0, (checks, stderr)
    assert {s for s, _ in checks.values()} == {"ok"}, checks
    serial = checks["serial"][1]
    assert f"{mcu} (autopilot), {gps} (gps), {xbee} (radio): open to this user" in serial
    assert "clearpath vehicle on" in checks["autopilot"][1]
    assert "GPS fix type 3, 10 satellites" in checks["autopilot"][1]


def test_a_silent_gps_fails_the_autopilot_naming_the_receiver(tmp_path: Path) -> None:
    with pty_husky() as (mcu, gps, sim):
        sim.faults.gps_silent = True
        config = write_config(tmp_path, profile="husky", autopilot=mcu, gps=gps, radio="none")
        status, checks, stderr = run(config, "--timeout", "1")
    assert status == 1
    assert checks["serial"][0] == "ok"
    state, text = checks["autopilot"]
    assert state == "FAIL", checks
    assert "clearpath vehicle on" in text and "answers, but no GPS fix after 1 s" in text
    assert f"nothing readable from {gps} (0 bytes" in text
    assert f"fix: check the GPS receiver on {gps}: powered, plugged in" in text
    assert "gps.baud = 19200" in text and "fieldkit deploy --gps DEV" in text
    assert "outdoors" not in text  # a cable, not the sky
    assert errors_of(stderr) == [f"error: 1 of 9 checks failed for {config}: autopilot"]


def test_a_missing_gps_device_fails_the_serial_check(tmp_path: Path) -> None:
    """The GPS is a serial device like the others: missing, it fails the serial check, and
    the Husky's link (which opens both) is not tried."""
    with pty_husky() as (mcu, _, _):
        config = write_config(tmp_path, profile="husky", autopilot=mcu, radio="none",
                              gps=str(tmp_path / "ttyGPS"))  # fmt: skip
        status, checks, _ = run(config, "--timeout", "1")
    assert status == 1
    state, text = checks["serial"]
    assert state == "FAIL"
    assert f"{tmp_path / 'ttyGPS'} (gps, node.gps): missing" in text
    assert "fix: plug in the GPS receiver" in text and "/dev/gps is made by the udev rule" in text
    assert checks["autopilot"] == ("skip", "its GPS receiver's device failed the serial check")


def test_the_profiles_gps_port_is_checked_when_the_config_names_none(tmp_path: Path) -> None:
    config = write_config(tmp_path, profile="husky", autopilot="/dev/null", radio="none")
    status, checks, _ = run(config, "--timeout", "1")
    assert status == 1
    text = checks["serial"][1]
    assert "/dev/ttyUSB1 (gps, the husky profile's gps.port): missing" in text


def test_a_ready_m100_passes_every_check(tmp_path: Path) -> None:
    """The simulated M100 (vehicle-sim's) accepts the test app: activated, control granted,
    a GPS fix; the key is in no line of the report."""
    keys = robot_keys(tmp_path)
    with pty_m100() as fc, fake_xbee() as xbee:
        config = write_config(tmp_path, dji_table(tmp_path), profile="m100", autopilot=fc,
                              radio=f"serial://{xbee}?baud=230400&api=2", keys=str(keys),
                              security="signed")  # fmt: skip
        status, checks, stderr = run(config, "--timeout", "10")
    assert status == 0, (checks, stderr)
    assert {s for s, _ in checks.values()} == {"ok"}, checks
    assert f"dji vehicle on {fc}: mode" in checks["autopilot"][1]
    assert "GPS fix type 3" in checks["autopilot"][1]
    assert f"{fc} (autopilot)" in checks["serial"][1]
    assert not [t for _, t in checks.values() if TEST_APP_KEY[:16] in t.lower()]
    assert TEST_APP_KEY[:16] not in stderr.lower()


def test_a_wrong_dji_app_key_fails_clearly(tmp_path: Path) -> None:
    """A key the M100 was not activated with: its KEY_ERROR, and the fix names the key
    file and deploy's options; neither key appears anywhere."""
    wrong = "f" * 64
    with pty_m100() as fc:
        config = write_config(tmp_path, dji_table(tmp_path, wrong), profile="m100",
                              autopilot=fc, radio="none")  # fmt: skip
        result = runner.invoke(app, ["doctor", "--config", str(config), "--timeout", "5"])
    assert result.exit_code == 1, result.output
    checks = _checks(result.stdout)
    state, text = checks["autopilot"]
    assert state == "FAIL", checks
    assert "control authority refused: 0xFF00 KEY_ERROR" in text
    assert (
        f"fix: the app key of the config's [dji] is not the one DJI gave app {TEST_APP_ID}" in text
    )
    assert "--dji-app-key-file FILE" in text
    for key in (wrong, TEST_APP_KEY):
        assert key not in result.output and key[:16] not in result.output


def test_an_m100_config_without_its_app_fails_the_autopilot(tmp_path: Path) -> None:
    config = write_config(tmp_path, profile="m100", autopilot="/dev/null", radio="none")
    status, checks, _ = run(config, "--timeout", "1")
    assert status == 1
    state, text = checks["autopilot"]
    assert state == "FAIL" and "needs the developer's app id and app key" in text, text


def errors_of(stderr: str) -> list[str]:
    """The `error:` lines."""
    return [line for line in stderr.splitlines() if line.startswith("error: ")]
