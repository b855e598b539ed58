"""The rendered files, read by the real systemd tools: `systemd-analyze verify` accepts the
units, `systemd-analyze security --offline=true` rates the node's exposure at 2.0 or less,
`systemd-sysusers` and `systemd-tmpfiles` make the user and the directories from our files
in a scratch root, and `systemd-escape` names device units as we do."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path, PurePosixPath
from typing import Any

import pytest

from fieldkit.deploy import DeployError, layout
from fieldkit.deploy.install import File
from fieldkit.deploy.plan import Machine, Options, Plan, make_plan
from fieldkit.deploy.units import device_unit, exec_line, render, sysusers, tmpfiles

from .kit import HELLO, SYSTEM_PYTHON, TASKS, dji_app_key

ANALYZE = shutil.which("systemd-analyze")
needs_analyze = pytest.mark.skipif(
    ANALYZE is None, reason="systemd-analyze is not installed (Debian: apt-get install systemd)"
)

#: The goal of issue 17: the node's unit no more exposed than this.
EXPOSURE_GOAL = 2.0


def plan(profile: str = "solo", python: str = sys.executable, **options: Any) -> Plan:
    """The plan of a staged deploy (this machine stands in for the robot)."""
    return make_plan(Options(profile=profile, python=python, **options), Machine(staging=True))


def text_of(p: Plan, target: PurePosixPath) -> str:
    (entry,) = [e for e in p.entries if e.path == target]
    assert isinstance(entry, File)
    return entry.data.decode()


def write_unit(tmp_path: Path, p: Plan, name: str = layout.NODE_UNIT) -> Path:
    """The plan's unit as a file `systemd-analyze` can read."""
    path = tmp_path / name
    path.write_text(text_of(p, layout.UNIT_DIR / name))
    return path


def verify(unit: Path) -> None:
    """`systemd-analyze verify`: no error and no warning (an unknown key is only a warning)."""
    assert ANALYZE is not None
    done = subprocess.run([ANALYZE, "verify", "--man=no", str(unit)], capture_output=True,
                          text=True, check=False)  # fmt: skip
    assert done.returncode == 0 and done.stderr == "" and done.stdout == "", done.stderr


def exposure(unit: Path) -> float:
    """The overall exposure `systemd-analyze security --offline=true` gives the unit."""
    assert ANALYZE is not None
    done = subprocess.run([ANALYZE, "security", "--offline=true", "--no-pager", str(unit)],
                          capture_output=True, text=True, check=False)  # fmt: skip
    m = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", done.stdout)
    assert m is not None, done.stdout + done.stderr
    return float(m.group(1))


CASES: dict[str, dict[str, Any]] = {
    # the solo: autopilot over WiFi (UDP), XBee on USB
    "udp": dict(profile="solo", script=HELLO),
    # the husky: MCU, XBee and GPS receiver, all serial on USB adapters
    "serial": dict(profile="husky", robot_id=1),
    # the m100: the flight controller on a UART, a USB XBee, the app key file (DJI_KEY)
    "dji": dict(profile="m100", robot_id=1, dji_app_id=1024768),
    # the spiri: a UART and a USB XBee
    "uart": dict(profile="spiri", robot_id=1),
    # no device at all: a network autopilot, no radio
    "no-devices": dict(profile="solo", radio="none"),
}


def case_plan(case: str, tmp_path: Path, python: str = sys.executable) -> Plan:
    """The plan of case `case` (an M100's with an app key file in tmp_path)."""
    options = dict(CASES[case])
    if "dji_app_id" in options:
        options["dji_app_key_file"] = dji_app_key(tmp_path)
    return plan(python=python, **options)


@needs_analyze
@pytest.mark.parametrize("case", list(CASES))
def test_the_node_unit_verifies(tmp_path: Path, case: str) -> None:
    verify(write_unit(tmp_path, case_plan(case, tmp_path)))


@needs_analyze
def test_the_update_unit_verifies(tmp_path: Path, keys: Path) -> None:
    p = plan(script=TASKS, originator=True, operator_keys=keys)
    unit = write_unit(tmp_path, p, layout.UPDATE_UNIT)
    verify(unit)
    assert exposure(unit) <= 1.0


@needs_analyze
@pytest.mark.parametrize(
    ("case", "python", "highest"),
    [
        ("serial", SYSTEM_PYTHON, 0.6),
        ("uart", SYSTEM_PYTHON, 0.6),
        ("dji", SYSTEM_PYTHON, 0.6),
        ("udp", SYSTEM_PYTHON, 1.4),
        ("no-devices", SYSTEM_PYTHON, 1.2),
        # fieldkit under /home or /root: ProtectHome=read-only costs 0.1
        ("serial", "/root/venv/bin/python", 0.7),
        ("udp", "/root/venv/bin/python", 1.5),
    ],
)
def test_the_node_units_exposure_meets_the_goal(
    tmp_path: Path, case: str, python: str, highest: float, capsys: pytest.CaptureFixture[str]
) -> None:
    """At most 2.0 (the issue's goal) in every case, and no worse than measured when the
    hardening was written: a line that goes missing shows up here."""
    p = case_plan(case, tmp_path, python)
    figure = exposure(write_unit(tmp_path, p))
    with capsys.disabled():
        print(f"\nexposure of fieldkit-node.service, {case}, {python}: {figure}")
    assert figure <= EXPOSURE_GOAL
    assert figure <= highest


def test_no_devices_means_private_devices(tmp_path: Path) -> None:
    unit = text_of(plan(**CASES["no-devices"]), layout.UNIT_DIR / layout.NODE_UNIT)
    lines = unit.splitlines()
    assert "PrivateDevices=yes" in lines and not [x for x in lines if x.startswith("DeviceAllow=")]


def test_the_start_timeout_covers_the_waits() -> None:
    """Heartbeat wait (30 s) + the profile's GPS fix timeout (120 s) + a 30 s margin."""
    p = plan(**CASES["serial"])
    assert p.node.timeout_start_s == 180
    assert "TimeoutStartSec=180" in text_of(p, layout.UNIT_DIR / layout.NODE_UNIT).splitlines()


def test_a_host_name_leaves_the_ip_filter_off() -> None:
    """A peer named by a host name has no address yet: no IP filter, and a warning."""
    p = plan(profile="solo", radio="udp://mesh.local:24580")
    unit = text_of(p, layout.UNIT_DIR / layout.NODE_UNIT)
    assert not [x for x in unit.splitlines() if x.startswith(("IPAddressDeny=", "IPAddressAllow="))]
    assert any("mesh.local: a host name" in w for w in p.warnings), p.warnings


def scratch_root(tmp_path: Path) -> Path:
    """A root with this machine's user database (Debian's: dialout exists)."""
    root = tmp_path / "scratch"
    (root / "etc").mkdir(parents=True)
    for name in ("passwd", "group"):
        shutil.copy(f"/etc/{name}", root / "etc" / name)
    return root


def ids(root: Path, database: str, name: str) -> list[str]:
    """The entry `name` of root's etc/passwd or etc/group, split."""
    for line in (root / "etc" / database).read_text().splitlines():
        if line.split(":")[0] == name:
            return line.split(":")
    raise AssertionError(f"no {name} in {database}")


@pytest.mark.skipif(shutil.which("systemd-sysusers") is None, reason="no systemd-sysusers")
@pytest.mark.skipif(shutil.which("systemd-tmpfiles") is None, reason="no systemd-tmpfiles")
def test_sysusers_and_tmpfiles_make_the_user_and_its_directories(tmp_path: Path) -> None:
    """Our sysusers.d makes the fieldkit user (home /var/lib/fieldkit, no shell) in dialout;
    our tmpfiles.d then makes its directories and gives it the keys, 0600 whatever they were."""
    root = scratch_root(tmp_path)
    (root / "usr/lib/sysusers.d").mkdir(parents=True)
    (root / "usr/lib/sysusers.d/fieldkit.conf").write_text(sysusers())
    done = subprocess.run(["systemd-sysusers", f"--root={root}"], capture_output=True, text=True,
                          check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr
    user = ids(root, "passwd", "fieldkit")
    assert user[4:] == ["fieldkit swarm node", "/var/lib/fieldkit", "/usr/sbin/nologin"]
    assert "fieldkit" in ids(root, "group", "dialout")[3].split(",")
    uid, gid = int(user[2]), int(user[3])

    (root / "usr/lib/tmpfiles.d").mkdir(parents=True)
    (root / "usr/lib/tmpfiles.d/fieldkit.conf").write_text(tmpfiles(True, dji_app_key=True))
    keys = root / "etc/fieldkit/keys"
    keys.mkdir(parents=True)
    (keys / "swarm.key").write_text("x")
    (keys / "swarm.key").chmod(0o644)  # as a careless copy left it
    (root / "etc/fieldkit/dji-app-key").write_text("x")
    (root / "etc/fieldkit/dji-app-key").chmod(0o644)
    done = subprocess.run(["systemd-tmpfiles", f"--root={root}", "--create"],
                          capture_output=True, text=True, check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr
    for path, mode in (
        ("var/lib/fieldkit", 0o750),
        ("var/log/fieldkit", 0o750),
        ("etc/fieldkit/keys", 0o700),
        ("etc/fieldkit/keys/swarm.key", 0o600),
        ("etc/fieldkit/operator-keys", 0o700),
        ("etc/fieldkit/dji-app-key", 0o600),
    ):
        st = (root / path).stat()
        assert (st.st_mode & 0o7777, st.st_uid, st.st_gid) == (mode, uid, gid), path
    st = (root / "etc/fieldkit").stat()
    assert (st.st_mode & 0o7777, st.st_uid) == (0o755, 0)


@pytest.mark.skipif(shutil.which("systemd-escape") is None, reason="no systemd-escape")
@pytest.mark.parametrize(
    "path",
    ["/dev/ttyUSB0", "/dev/xbee", "/dev/serial/by-id/usb-FTDI_FT231X-if00-port0",
     "/dev/my dev.x", "/dev/tty.é"],
)  # fmt: skip
def test_device_units_are_named_as_systemd_names_them(path: str) -> None:
    done = subprocess.run(["systemd-escape", "--path", "--suffix=device", path],
                          capture_output=True, text=True, check=True)  # fmt: skip
    assert device_unit(path) == done.stdout.strip()


@needs_analyze
def test_an_interpreter_path_with_spaces_and_specifiers(tmp_path: Path) -> None:
    """A venv in `/opt/my venv%1`: quoted and escaped, systemd reads it back as that path."""
    odd = tmp_path / "my venv%1"
    odd.mkdir()
    python = odd / "python"
    python.symlink_to(sys.executable)
    line = exec_line([str(python), "-m", "fieldkit"])
    assert line == f'"{odd}/python" -m fieldkit'.replace("%", "%%")
    unit = tmp_path / "odd.service"
    unit.write_text(f"[Service]\nExecStart={line}\n")
    verify(unit)
    with pytest.raises(DeployError, match="absolute"):
        exec_line(["python", "-m", "fieldkit"])


def test_templates_and_values_must_match(tmp_path: Path) -> None:
    """A placeholder without a value, or a value without a placeholder, is an error."""
    with pytest.raises(DeployError, match="placeholders"):
        render(layout.NODE_UNIT, {"PROFILE": "solo"})


def test_the_interpreter_must_be_visible_to_the_service() -> None:
    """An interpreter under /tmp (PrivateTmp hides it) stops a live deploy; one under a
    home directory gets ProtectHome=read-only, said."""
    live = Machine(staging=False, hostname=lambda: "solo3", exists=lambda _: True)
    with pytest.raises(DeployError, match="PrivateTmp"):
        make_plan(Options("solo", radio="none", python="/tmp/venv/bin/python"), live)
    p = make_plan(Options("solo", radio="none", python="/home/pi/venv/bin/python"), live)
    assert "ProtectHome=read-only" in text_of(p, layout.UNIT_DIR / layout.NODE_UNIT)
    assert any("ProtectHome=read-only rather than yes" in w for w in p.warnings)
    assert p.robot_id == "robot 3, from the host name"


def test_a_live_deploy_needs_the_devices_plugged_in(tmp_path: Path) -> None:
    """On the robot (no --root), a missing serial device, or a USB adapter the sysfs does
    not list, stops the deploy; a sysfs that lists it lets it through."""
    sysfs = tmp_path / "usb"
    live = Machine(staging=False, hostname=lambda: "husky2", exists=lambda _: False,
                   usb_devices=sysfs)  # fmt: skip
    with pytest.raises(DeployError, match="no such device") as e:
        make_plan(Options("spiri", radio="none", python=SYSTEM_PYTHON), live)
    assert "/dev/ttyTHS2" in str(e.value)
    with pytest.raises(DeployError, match="no USB device 067b:2303 is plugged in"):
        make_plan(Options("husky", python=SYSTEM_PYTHON), live)
    for n, usb in enumerate(("067b:2303", "0403:6015")):
        device = sysfs / f"1-{n}"
        device.mkdir(parents=True)
        vendor, product = usb.split(":")
        (device / "idVendor").write_text(vendor.upper() + "\n")
        (device / "idProduct").write_text(product + "\n")
    # The Husky's GPS receiver is a device like the others: missing, it stops the deploy.
    with pytest.raises(
        DeployError,
        match=r"gps /dev/gps \(USB 1546:01a8, the husky profile's "
        r"\[usb\] gps\): no USB device 1546:01a8 is plugged in",
    ) as e:
        make_plan(Options("husky", python=SYSTEM_PYTHON), live)
    assert "hint: plug the adapter in" in str(e.value)
    (sysfs / "1-2").mkdir()
    (sysfs / "1-2" / "idVendor").write_text("1546\n")
    (sysfs / "1-2" / "idProduct").write_text("01a8\n")
    p = make_plan(Options("husky", python=SYSTEM_PYTHON), live)
    assert p.node.devices == ("/dev/autopilot", "/dev/xbee", "/dev/gps")
    # Given by its device instead: that device must be there.
    with pytest.raises(DeployError, match=r"gps --gps /dev/ttyUSB7: no such device") as e:
        make_plan(Options("husky", gps="/dev/ttyUSB7", python=SYSTEM_PYTHON), live)
    assert "give --gps with the device it is on" in str(e.value)
    with pytest.raises(DeployError, match="ends in no id"):
        make_plan(Options("husky", python=SYSTEM_PYTHON),
                  Machine(staging=False, hostname=lambda: "robot", usb_devices=sysfs))  # fmt: skip


def test_the_process_environment_is_left_as_it_was(tmp_path: Path) -> None:
    """Checking a script's installed copy compiles it elsewhere: the working directory and
    BUZZ_INCLUDE_PATH come back as they were."""
    cwd = os.getcwd()
    os.environ["BUZZ_INCLUDE_PATH"] = str(tmp_path)
    try:
        plan(script=TASKS)
        assert os.getcwd() == cwd and os.environ["BUZZ_INCLUDE_PATH"] == str(tmp_path)
    finally:
        del os.environ["BUZZ_INCLUDE_PATH"]
