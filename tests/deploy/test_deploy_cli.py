"""`fieldkit deploy --root DIR`: what it installs, twice, removed again, and every error
with nothing written. Real files in a real directory; the command run as a user runs it."""

from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import bvm
from fieldkit.deploy import layout
from fieldkit.deploy.install import SAVED_SUFFIX

from .kit import HELLO, HUSKY, TASKS, deploy, dji_app_key, errors, fieldkit, listing, m100

UNIT = "etc/systemd/system/fieldkit-node.service"
CONFIG = "etc/fieldkit/fieldkit.toml"


#: The robots the idempotence and uninstall tests deploy: a Solo (its autopilot on WiFi), a
#: Husky (MCU, XBee and GPS receiver on USB) and an M100 (its app key installed 0600).
ROBOTS = ("solo", "husky", "m100")


def robot(name: str, tmp_path: Path, *more: str | Path) -> tuple[str | Path, ...]:
    """The options deploying robot `name` (an M100 with its app key file in tmp_path)."""
    if name == "m100":
        return m100(dji_app_key(tmp_path), *more)
    if name == "husky":
        return (*HUSKY, *more)
    return ("--profile", "solo", "--robot-id", "2", *more)


def unit_lines(root: Path, key: str, unit: str = UNIT) -> list[str]:
    """The values of `key=` in a rendered unit."""
    prefix = f"{key}="
    text = (root / unit).read_text()
    return [line[len(prefix) :] for line in text.splitlines() if line.startswith(prefix)]


def test_deploy_installs_the_node_under_root(tmp_path: Path) -> None:
    """The contract: exit 0, the unit and the config under DIR; ExecStart is this
    interpreter running `node --config /etc/fieldkit/fieldkit.toml`; inside the files, the
    robot's paths, never DIR."""
    root = tmp_path / "root"
    result = deploy("--profile", "solo", "--root", root, "--script", HELLO, "--robot-id", "3")
    assert result.exit_code == 0, result.output
    (exec_start,) = unit_lines(root, "ExecStart")
    argv = shlex.split(exec_start)
    assert Path(argv[0]).is_absolute() and argv[0] == sys.executable
    assert argv[1:] == ["-m", "fieldkit", "node", "--config", "/etc/fieldkit/fieldkit.toml"]
    config = tomllib.loads((root / CONFIG).read_text())
    assert config == {
        "node": {
            "profile": "solo",
            "robot_id": 3,
            "radio": "serial:///dev/xbee?baud=230400&api=2",  # the profile's [usb] radio
            "state_dir": "/var/lib/fieldkit/state",
            "script": "/var/lib/fieldkit/script/hello.bzz",
        },
        "record": {"dir": "/var/log/fieldkit", "max_mb": 2048, "keep_mb": 8192},
    }
    assert (root / CONFIG).read_text().startswith("# written by fieldkit deploy; ")
    assert (root / "var/lib/fieldkit/script/hello.bzz").read_bytes() == HELLO.read_bytes()
    for name in (
        "usr/lib/sysusers.d/fieldkit.conf",
        "usr/lib/tmpfiles.d/fieldkit.conf",
        "etc/udev/rules.d/99-fieldkit.rules",
        "etc/fieldkit/deploy-manifest.json",
    ):
        assert (root / name).is_file(), name
    for d, mode in (("var/lib/fieldkit", 0o750), ("var/log/fieldkit", 0o750)):
        assert (root / d).stat().st_mode & 0o7777 == mode
    wants = root / "etc/systemd/system/multi-user.target.wants/fieldkit-node.service"
    assert os.readlink(wants) == "/etc/systemd/system/fieldkit-node.service"
    # The solo's autopilot is on WiFi (UDP), its XBee on USB: network, and /dev/xbee only.
    assert unit_lines(root, "DeviceAllow") == ["/dev/xbee rw"]
    assert unit_lines(root, "RestrictAddressFamilies") == ["AF_UNIX AF_INET AF_INET6"]
    assert unit_lines(root, "PrivateNetwork") == []
    for path in root.rglob("*"):
        if path.is_file() and not path.is_symlink():
            assert str(root) not in path.read_text(errors="replace"), path
    written = [line for line in result.stderr.splitlines() if line.startswith("wrote ")]
    assert f"wrote {root / UNIT}" in written and f"wrote {root / CONFIG}" in written
    assert "installed under" in result.stdout and "robot 3" in result.stdout
    # The robot's devices are not here: said, not refused.
    assert "no USB device 0403:6015 is plugged in" in result.stderr
    assert "not on this staging machine" in result.stderr


def test_serial_links_get_no_network_and_exactly_their_devices(tmp_path: Path) -> None:
    """The Husky: its MCU, its XBee and its GPS receiver, all serial on USB adapters:
    PrivateNetwork, AF_UNIX alone, their three devices by their udev names."""
    root = tmp_path / "root"
    result = deploy("--profile", "husky", "--root", root, "--robot-id", "1")
    assert result.exit_code == 0, result.output
    assert unit_lines(root, "DeviceAllow") == ["/dev/autopilot rw", "/dev/xbee rw", "/dev/gps rw"]
    assert unit_lines(root, "PrivateNetwork") == ["yes"]
    assert unit_lines(root, "RestrictAddressFamilies") == ["AF_UNIX"]
    assert unit_lines(root, "After") == ["dev-autopilot.device", "dev-xbee.device",
                                         "dev-gps.device"]  # fmt: skip
    config = tomllib.loads((root / CONFIG).read_text())["node"]
    assert (config["autopilot"], config["gps"]) == ("/dev/autopilot", "/dev/gps")
    rules = (root / "etc/udev/rules.d/99-fieldkit.rules").read_text().splitlines()
    assert [r for r in rules if not r.startswith("#")] == [
        'SUBSYSTEM=="tty", ATTRS{idVendor}=="067b", ATTRS{idProduct}=="2303", '
        'SYMLINK+="autopilot", GROUP="dialout", MODE="0660"',
        'SUBSYSTEM=="tty", ATTRS{idVendor}=="0403", ATTRS{idProduct}=="6015", '
        'SYMLINK+="xbee", GROUP="dialout", MODE="0660"',
        'SUBSYSTEM=="tty", ATTRS{idVendor}=="1546", ATTRS{idProduct}=="01a8", '
        'SYMLINK+="gps", GROUP="dialout", MODE="0660"',
    ]
    # Staged: the robot's GPS is not on this machine either, said like the others.
    assert (
        "gps /dev/gps (USB 1546:01a8, the husky profile's [usb] gps): no USB device "
        "1546:01a8 is plugged in (the robot's devices are not on this staging machine)"
        in result.stderr
    )
    # Without a script the node runs what its state directory holds: said so.
    assert "no --script" in result.stderr


def test_command_line_links_replace_the_profiles(tmp_path: Path) -> None:
    """--autopilot DEV and --radio URL go into the config and the device list; no udev
    rule for an adapter no longer used; a network radio opens the network."""
    root = tmp_path / "root"
    result = deploy("--profile", "husky", "--root", root, "--autopilot", "/dev/ttyS4,115200",
                    "--radio", "udp://192.168.1.255:24580?peers=8.8.4.4:1",
                    "--gps", "/dev/ttyS5")  # fmt: skip
    assert result.exit_code == 0, result.output
    config = tomllib.loads((root / CONFIG).read_text())["node"]
    assert config["autopilot"] == "/dev/ttyS4,115200"
    assert config["radio"] == "udp://192.168.1.255:24580?peers=8.8.4.4:1"
    assert unit_lines(root, "DeviceAllow") == ["/dev/ttyS4 rw", "/dev/ttyS5 rw"]
    (allow,) = unit_lines(root, "IPAddressAllow")
    assert "192.168.0.0/16" in allow.split() and "8.8.4.4" in allow.split()
    # None of the profile's USB adapters is used: no udev rule at all.
    assert not (root / "etc/udev/rules.d/99-fieldkit.rules").exists()


@pytest.mark.parametrize("name", ROBOTS)
def test_deploy_twice_changes_nothing(tmp_path: Path, name: str) -> None:
    """Same options again: not a byte, mode or modification time changes."""
    root = tmp_path / "root"
    args = robot(name, tmp_path, "--root", root, "--script", TASKS)
    assert deploy(*args).exit_code == 0
    before = listing(root)
    again = deploy(*args)
    assert again.exit_code == 0, again.output
    assert listing(root) == before
    assert "0 files written" in again.stdout and "wrote " not in again.stderr


def test_a_new_deploy_replaces_the_old_one(tmp_path: Path) -> None:
    """Another script and no includes: the old script and its includes go, the tree is the
    one a fresh deploy of the new options makes."""
    root, fresh = tmp_path / "root", tmp_path / "fresh"
    assert deploy("--profile", "solo", "--root", root, "--script", TASKS).exit_code == 0
    assert (root / "var/lib/fieldkit/script/include/states.bzz").is_file()
    result = deploy("--profile", "solo", "--root", root, "--script", HELLO)
    assert result.exit_code == 0, result.output
    assert deploy("--profile", "solo", "--root", fresh, "--script", HELLO).exit_code == 0
    assert listing(root, mtimes=False) == listing(fresh, mtimes=False)
    assert f"removed {root / 'var/lib/fieldkit/script/include'}" in result.stderr


def seed(root: Path) -> None:
    """What a robot's root has before deploy: directories and files deploy must not touch."""
    (root / "etc/systemd/system").mkdir(parents=True)
    (root / "etc/systemd/system/other.service").write_text("[Service]\nExecStart=/bin/true\n")
    (root / "etc/hostname").write_text("solo3\n")
    (root / "var/lib/other").mkdir(parents=True)


@pytest.mark.parametrize("name", ROBOTS)
def test_uninstall_leaves_the_tree_as_it_was(tmp_path: Path, name: str) -> None:
    """deploy, then --uninstall: the tree as before, but for the state and recordings
    directories (and the parents made for them); --purge removes those too: byte for byte
    the tree before deploy, modification times of files included."""
    root = tmp_path / "root"
    seed(root)
    before = listing(root)
    args = robot(name, tmp_path, "--root", root, "--script", TASKS)
    assert deploy(*args).exit_code == 0
    result = deploy("--root", root, "--uninstall")
    assert result.exit_code == 0, result.output
    kept = {"var/lib/fieldkit": ("dir", "0750"), "var/log": ("dir", "0755"),
            "var/log/fieldkit": ("dir", "0750")}  # fmt: skip
    assert listing(root) == {**before, **kept}
    assert f"kept {root / 'var/lib/fieldkit'}" in result.stderr
    assert "uninstalled from" in result.stdout

    assert deploy(*robot(name, tmp_path, "--root", root, "--script", HELLO)).exit_code == 0
    purged = deploy("--root", root, "--uninstall", "--purge")
    assert purged.exit_code == 0, purged.output
    assert listing(root) == {**before, "var/log": ("dir", "0755")}  # made by the first deploy
    root2 = tmp_path / "root2"
    seed(root2)
    before2 = listing(root2)
    assert deploy(*robot(name, tmp_path, "--root", root2, "--script", HELLO)).exit_code == 0
    assert deploy("--root", root2, "--uninstall", "--purge").exit_code == 0
    assert listing(root2) == before2


def test_purge_removes_state_and_recordings(tmp_path: Path) -> None:
    """What the node made in its state and log directories stays until --purge."""
    root = tmp_path / "root"
    assert deploy("--profile", "solo", "--root", root, "--script", HELLO).exit_code == 0
    (root / "var/lib/fieldkit/state").mkdir()
    (root / "var/lib/fieldkit/state/committed").write_text("0\n")
    (root / "var/log/fieldkit/flight-1").mkdir()
    assert deploy("--root", root, "--uninstall").exit_code == 0
    assert (root / "var/lib/fieldkit/state/committed").is_file()
    assert (root / "var/log/fieldkit/flight-1").is_dir()
    assert not (root / "var/lib/fieldkit/script").exists()  # deploy's own files go
    assert deploy("--root", root, "--uninstall", "--purge").exit_code == 0
    assert not (root / "var/lib/fieldkit").exists() and not (root / "var/log/fieldkit").exists()
    nothing = deploy("--root", root, "--uninstall")
    assert nothing.exit_code == 0 and "nothing to uninstall" in nothing.stdout


def test_a_file_the_user_changed_is_kept_and_said(tmp_path: Path) -> None:
    """--uninstall keeps a file changed since deploy; deploy replaces it, keeping a copy."""
    root = tmp_path / "root"
    args = ("--profile", "solo", "--root", root, "--script", HELLO)
    assert deploy(*args).exit_code == 0
    config = root / CONFIG
    config.write_text(config.read_text() + "# mine\n")
    again = deploy(*args)
    assert again.exit_code == 0, again.output
    saved = config.with_name(config.name + SAVED_SUFFIX)
    assert saved.read_text().endswith("# mine\n") and not config.read_text().endswith("# mine\n")
    assert f"the changed version saved as {saved}" in again.stderr
    config.write_text("# mine alone\n")
    result = deploy("--root", root, "--uninstall")
    assert result.exit_code == 0, result.output
    assert config.read_text() == "# mine alone\n"
    assert f"warning: kept {config}: changed since fieldkit deploy installed it" in result.stderr
    assert (root / "etc/fieldkit").is_dir()  # it holds the user's files: kept, and said
    assert not (root / UNIT).exists()


def test_dry_run_prints_everything_and_changes_nothing(tmp_path: Path) -> None:
    """Every file with its mode and text, every directory and symlink; the tree (even a
    DIR that does not exist) unchanged. Without --root it shows the commands too."""
    root = tmp_path / "root"
    result = deploy("--profile", "husky", "--root", root, "--script", TASKS, "--dry-run")
    assert result.exit_code == 0, result.output
    assert not root.exists()
    out = result.stdout
    assert f"file {root / UNIT} (mode 0644, new)" in out
    assert f"dir  {root / 'etc/fieldkit/keys'} (mode 0700, owner fieldkit, new)" in out
    assert "    | ExecStart=" in out and "    | DeviceAllow=/dev/xbee rw" in out
    assert f"file {root / 'var/lib/fieldkit/script/include/states.bzz'} (mode 0644, new)" in out
    assert "(no commands: --root stages the files only)" in out
    assert deploy("--profile", "husky", "--root", root, "--script", HELLO).exit_code == 0
    before = listing(root)
    again = deploy("--profile", "husky", "--root", root, "--robot-id", "4", "--dry-run")
    assert again.exit_code == 0 and listing(root) == before
    assert f"file {root / CONFIG} (mode 0644, changed)" in again.stdout
    assert f"file {root / UNIT} (mode 0644, unchanged)" in again.stdout
    # No root needed to look (the robot's devices must be there, as for a deploy: this
    # machine has none, so the links are the Solo's network autopilot and no radio).
    live = deploy("--profile", "solo", "--robot-id", "1", "--radio", "none", "--dry-run")
    assert live.exit_code == 0, live.output
    for command in (
        "run: systemd-sysusers --replace=/usr/lib/sysusers.d/fieldkit.conf -",
        "run: systemd-tmpfiles --create /usr/lib/tmpfiles.d/fieldkit.conf",
        "run: systemctl daemon-reload",
        "run: systemctl enable --now fieldkit-node.service",
        "run: systemctl show -p ActiveState,SubState,StatusText fieldkit-node.service",
    ):
        assert command in live.stdout, command
    uninstall = deploy("--root", root, "--uninstall", "--dry-run")
    assert uninstall.exit_code == 0 and listing(root) == before
    assert f"remove {root / UNIT}" in uninstall.stdout


def test_keys_install_the_robots_two_files_only(tmp_path: Path, keys: Path) -> None:
    """--keys DIR: operator.pub and swarm.key, 0600 in a 0700 directory; never the
    signing key; the node runs signed."""
    root = tmp_path / "root"
    result = deploy("--profile", "solo", "--root", root, "--script", HELLO, "--keys", keys)
    assert result.exit_code == 0, result.output
    installed = root / "etc/fieldkit/keys"
    assert sorted(p.name for p in installed.iterdir()) == ["operator.pub", "swarm.key"]
    assert installed.stat().st_mode & 0o777 == 0o700
    for p in installed.iterdir():
        assert p.stat().st_mode & 0o777 == 0o600
        assert p.read_bytes() == (keys / p.name).read_bytes()
    assert "operator.key left out" in result.stderr
    config = tomllib.loads((root / CONFIG).read_text())["node"]
    assert (config["keys"], config["security"]) == ("/etc/fieldkit/keys", "signed")
    assert not list(root.rglob("operator.key"))


def test_an_m100_gets_its_app_key_for_the_service_alone(tmp_path: Path) -> None:
    """--dji-app-id --dji-app-key-file: the key installed 0600 for the fieldkit user (also at
    every boot, through tmpfiles.d), named by the config's [dji]; the node's own loader
    reads it back; the key's digits nowhere but in that file (the manifest has its hash);
    --uninstall removes it."""
    import hashlib
    import json

    from fieldkit.node.config import load_config
    from fieldkit.vehicle.sim.dji import TEST_APP_ID, TEST_APP_KEY

    root = tmp_path / "root"
    key = dji_app_key(tmp_path, "  " + TEST_APP_KEY.upper() + "  ")  # as pasted: case, blanks
    result = deploy(*m100(key, "--root", root, "--script", HELLO))
    assert result.exit_code == 0, result.output
    config = tomllib.loads((root / CONFIG).read_text())
    assert config["dji"] == {"app_id": TEST_APP_ID, "app_key_file": "/etc/fieldkit/dji-app-key"}
    assert "autopilot" not in config["node"] and "gps" not in config["node"]
    installed = root / "etc/fieldkit/dji-app-key"
    assert installed.read_text() == TEST_APP_KEY.upper() + "\n"
    assert installed.stat().st_mode & 0o777 == 0o600
    tmpfiles = (root / "usr/lib/tmpfiles.d/fieldkit.conf").read_text().splitlines()
    assert "z /etc/fieldkit/dji-app-key 0600 fieldkit fieldkit -" in tmpfiles
    # The node reads it as deployed (the config's path is the robot's: read it from here).
    here = tmp_path / "fieldkit.toml"
    here.write_text((root / CONFIG).read_text().replace("/etc/fieldkit/", f"{root}/etc/fieldkit/"))
    loaded = load_config(here)
    assert loaded.dji is not None
    assert (loaded.dji.app_id, loaded.dji.app_key.lower()) == (TEST_APP_ID, TEST_APP_KEY)
    manifest = json.loads((root / "etc/fieldkit/deploy-manifest.json").read_text())
    digest = hashlib.sha256(installed.read_bytes()).hexdigest()
    assert manifest["files"]["/etc/fieldkit/dji-app-key"] == {"mode": "0600", "sha256": [digest]}
    secret = TEST_APP_KEY.lower()
    for path in root.rglob("*"):
        if path.is_file() and path != installed:
            assert secret not in path.read_text(errors="replace").lower(), path
    assert secret not in result.output.lower()
    # The dry run says the file is there and what it holds, never the digits.
    dry = deploy(*m100(key, "--root", root, "--script", HELLO, "--dry-run"))
    assert dry.exit_code == 0, dry.output
    assert f"file {installed} (mode 0600, owner fieldkit, unchanged)" in dry.stdout
    assert "    <secret: 64 hex digits>" in dry.stdout
    assert secret not in dry.output.lower()
    removed = deploy("--root", root, "--uninstall")
    assert removed.exit_code == 0, removed.output
    assert f"removed {installed}" in removed.stderr and not installed.exists()


def test_the_dry_run_never_shows_a_private_key(tmp_path: Path, keys: Path) -> None:
    """--keys and --operator-keys: swarm.key and operator.key are said, never shown."""
    root = tmp_path / "root"
    result = deploy("--profile", "solo", "--root", root, "--script", TASKS, "--keys", keys,
                    "--originator", "--operator-keys", keys, "--dry-run")  # fmt: skip
    assert result.exit_code == 0, result.output
    for name in ("swarm.key", "operator.key"):
        body = (keys / name).read_text().strip().splitlines()
        assert all(line not in result.stdout for line in body if len(line) > 8), name
    assert result.stdout.count("    <secret: a private key>") == 3  # swarm.key twice
    assert "-----BEGIN PUBLIC KEY-----" in result.stdout  # operator.pub is no secret


def test_a_gps_given_by_its_device(tmp_path: Path) -> None:
    """--gps DEV: that device in the config and the unit, and no udev rule for the
    receiver's USB id (the two others keep theirs)."""
    root = tmp_path / "root"
    result = deploy(*HUSKY, "--root", root, "--gps", "/dev/ttyUSB2")
    assert result.exit_code == 0, result.output
    assert tomllib.loads((root / CONFIG).read_text())["node"]["gps"] == "/dev/ttyUSB2"
    assert unit_lines(root, "DeviceAllow") == ["/dev/autopilot rw", "/dev/xbee rw",
                                               "/dev/ttyUSB2 rw"]  # fmt: skip
    rules = (root / "etc/udev/rules.d/99-fieldkit.rules").read_text()
    assert 'SYMLINK+="gps"' not in rules and 'SYMLINK+="xbee"' in rules
    assert "gps --gps /dev/ttyUSB2: no such device (the robot's devices" in result.stderr


def test_two_adapters_with_one_usb_id_are_refused(tmp_path: Path) -> None:
    """A udev rule matches on the USB id: two adapters sharing one cannot be told apart."""
    from fieldkit.robot.profiles import load_profile

    shipped = load_profile("husky").path
    assert shipped is not None
    mine = tmp_path / "mine.toml"
    mine.write_text(shipped.read_text().replace('gps = "1546:01a8"', 'gps = "067b:2303"'))
    root = tmp_path / "root"
    result = deploy("--profile", mine, "--root", root, "--robot-id", "1")
    assert result.exit_code == 1, result.output
    (line,) = errors(result.stderr)
    assert line == (
        "error: the husky profile's [usb] gives autopilot and gps one USB id, 067b:2303: a "
        "udev rule cannot tell the two adapters apart"
    )
    assert "hint: give one of them by its device (--autopilot or --gps" in result.stderr
    assert not root.exists()
    # By its device, the GPS needs no rule: no clash.
    ok = deploy("--profile", mine, "--root", root, "--robot-id", "1", "--gps", "/dev/ttyS2")
    assert ok.exit_code == 0, ok.output


def test_the_originator_gets_the_update_monitor(tmp_path: Path, keys: Path) -> None:
    """--originator --operator-keys: the update unit (watching the installed script, writing
    into the outbox) and the signing key beside the two others, the fieldkit user's alone."""
    root = tmp_path / "root"
    result = deploy("--profile", "solo", "--root", root, "--script", TASKS, "--originator",
                    "--operator-keys", keys)  # fmt: skip
    assert result.exit_code == 0, result.output
    unit = "etc/systemd/system/fieldkit-update.service"
    (exec_start,) = unit_lines(root, "ExecStart", unit)
    argv = shlex.split(exec_start)
    assert argv[0] == sys.executable
    assert argv[1:] == ["-m", "fieldkit", "update", "/var/lib/fieldkit/script/task_allocation.bzz",
                        "--watch", "--keys", "/etc/fieldkit/operator-keys", "--base",
                        "/var/lib/fieldkit/outbox/update.bo", "--patch-out",
                        "/var/lib/fieldkit/outbox/update.patch", "--profile", "solo", "-I",
                        "/var/lib/fieldkit/script/include"]  # fmt: skip
    assert unit_lines(root, "PrivateNetwork", unit) == ["yes"]
    assert unit_lines(root, "PrivateDevices", unit) == ["yes"]
    operator = root / "etc/fieldkit/operator-keys"
    assert sorted(p.name for p in operator.iterdir()) == ["operator.key", "operator.pub",
                                                          "swarm.key"]  # fmt: skip
    assert all(p.stat().st_mode & 0o777 == 0o600 for p in operator.iterdir())
    assert "fieldkit-update.service" in result.stdout
    tmpfiles = (root / "usr/lib/tmpfiles.d/fieldkit.conf").read_text()
    assert "Z /etc/fieldkit/operator-keys ~0700 fieldkit fieldkit -" in tmpfiles
    # The node originates what the monitor writes: the outbox in its config, and the keys
    # that verify the patches (taken from --operator-keys: no --keys was given).
    from fieldkit.node.config import load_config

    config = load_config(root / CONFIG)
    assert config.node["update_outbox"] == "/var/lib/fieldkit/outbox/update.patch"
    assert (config.node["keys"], config.node["security"]) == ("/etc/fieldkit/keys", "signed")
    robot_keys = root / "etc/fieldkit/keys"
    assert sorted(p.name for p in robot_keys.iterdir()) == ["operator.pub", "swarm.key"]
    assert all((robot_keys / n).read_bytes() == (keys / n).read_bytes() for n in
               ("operator.pub", "swarm.key"))  # fmt: skip
    # The node's unit may read it: the outbox is inside its StateDirectory= (writable, so
    # readable, under ProtectSystem=strict), hidden by no path rule, and both units run as
    # one user (the outbox is 0700).
    node_unit = "etc/systemd/system/fieldkit-node.service"
    assert unit_lines(root, "ProtectSystem", node_unit) == ["strict"]
    assert unit_lines(root, "StateDirectory", node_unit) == ["fieldkit"]
    assert unit_lines(root, "StateDirectory", unit) == ["fieldkit/outbox"]
    for rule in ("InaccessiblePaths", "ReadOnlyPaths", "TemporaryFileSystem", "PrivateUsers"):
        assert unit_lines(root, rule, node_unit) == []
    assert unit_lines(root, "User", node_unit) == unit_lines(root, "User", unit) == ["fieldkit"]


def test_an_originators_keys_must_be_one_swarms(tmp_path: Path, keys: Path) -> None:
    """--keys beside --operator-keys must hold the same two public files: the node would
    refuse every patch its monitor signs otherwise."""
    from fieldkit.update.keys import init_keys

    other = tmp_path / "other"
    init_keys(other)
    root = tmp_path / "root"
    result = deploy("--profile", "solo", "--root", root, "--script", TASKS, "--originator",
                    "--operator-keys", keys, "--keys", other)  # fmt: skip
    assert result.exit_code == 1, result.output
    assert "hold different operator.pub or swarm.key" in result.stderr
    assert not root.exists() or not any(root.rglob("*.toml"))


@pytest.mark.parametrize(
    ("args", "text"),
    [
        (["--originator", "--script", "{hello}"], "--operator-keys DIR"),
        (["--operator-keys", "{keys}", "--script", "{hello}"], "for --originator only"),
        (["--originator", "--operator-keys", "{keys}"], "give --script with a .bzz"),
    ],
)
def test_the_originator_needs_its_script_and_its_keys(
    tmp_path: Path, keys: Path, args: list[str], text: str
) -> None:
    root = tmp_path / "root"
    filled = [a.format(hello=HELLO, keys=keys) for a in args]
    result = deploy("--profile", "solo", "--root", root, *filled)
    assert result.exit_code == 1, result.output
    (line,) = errors(result.stderr)
    assert text in line
    assert not root.exists()


def test_an_include_outside_the_scripts_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An include found through BUZZ_INCLUDE_PATH by its bare name installs into
    script/include/, an include directory of the node; one found by a path that means
    nothing from there is refused, with nothing written."""
    lib = tmp_path / "lib"
    (lib / "sub").mkdir(parents=True)
    (lib / "util.bzz").write_text("function helper() { return 1 }\n")
    (lib / "sub" / "deep.bzz").write_text("function deep() { return 2 }\n")
    here = tmp_path / "src"
    here.mkdir()
    script = here / "main.bzz"
    script.write_text('include "util.bzz"\nfunction init() { helper() }\nfunction step() {}\n')
    monkeypatch.setenv("BUZZ_INCLUDE_PATH", str(lib))
    root = tmp_path / "root"
    result = deploy("--profile", "solo", "--root", root, "--script", script)
    assert result.exit_code == 0, result.output
    assert (root / "var/lib/fieldkit/script/include/util.bzz").is_file()
    config = tomllib.loads((root / CONFIG).read_text())["node"]
    assert config["include"] == ["/var/lib/fieldkit/script/include"]
    # The node compiles its installed copy, with that include directory, to the same program.
    installed = root / "var/lib/fieldkit/script/main.bzz"
    monkeypatch.delenv("BUZZ_INCLUDE_PATH")
    again = bvm.compile_file(installed, [str(root / "var/lib/fieldkit/script/include")])
    assert again.bytecode == bvm.compile_file(script, [str(lib)]).bytecode
    monkeypatch.setenv("BUZZ_INCLUDE_PATH", str(lib))
    script.write_text('include "sub/deep.bzz"\nfunction init() { deep() }\nfunction step() {}\n')
    other = tmp_path / "other"
    refused = deploy("--profile", "solo", "--root", other, "--script", script)
    assert refused.exit_code == 1, refused.output
    assert "its installed copy" in errors(refused.stderr)[0]
    assert not other.exists()


def test_a_bytecode_script_installs_with_its_sidecars(tmp_path: Path) -> None:
    bo = tmp_path / "hello.bo"
    program = bvm.compile_file(HELLO)
    assert fieldkit("compile", HELLO, "-o", bo).wait(timeout=60) == 0
    root = tmp_path / "root"
    result = deploy("--profile", "solo", "--root", root, "--script", bo)
    assert result.exit_code == 0, result.output
    installed = root / "var/lib/fieldkit/script"
    assert sorted(p.name for p in installed.iterdir()) == ["hello.bdb", "hello.bo", "hello.bpos"]
    assert (installed / "hello.bo").read_bytes() == program.bytecode
    config = tomllib.loads((root / CONFIG).read_text())["node"]
    assert config["script"] == "/var/lib/fieldkit/script/hello.bo"


def test_a_profile_file_is_installed_with_the_config(tmp_path: Path) -> None:
    """--profile site/mine.toml: the service cannot read the operator's file: it gets a copy
    in /etc/fieldkit/profiles/, which the config names."""
    from fieldkit.robot.profiles import load_profile

    mine = tmp_path / "mine.toml"
    shipped = load_profile("spiri").path
    assert shipped is not None
    mine.write_text(shipped.read_text().replace('name = "spiri"', 'name = "mine"'))
    root = tmp_path / "root"
    result = deploy("--profile", mine, "--root", root, "--robot-id", "1")
    assert result.exit_code == 0, result.output
    assert (root / "etc/fieldkit/profiles/mine.toml").read_bytes() == mine.read_bytes()
    config = tomllib.loads((root / CONFIG).read_text())["node"]
    assert config["profile"] == "/etc/fieldkit/profiles/mine.toml"


# ------------------------------------------------------------------------ errors


BROKEN = "function init() {}\nfunction step() {\n  x = (1 +\n}\n"


@pytest.mark.parametrize(
    ("args", "text"),
    [
        (["--profile", "nope"], "nope: unknown profile (known: husky, m100, solo, spiri)"),
        (["--profile", "solo", "--script", "{bad}"], "bad.bzz:4:1: "),
        (["--profile", "solo", "--script", "{d}/nope.bzz"], "nope.bzz"),
        (["--profile", "solo", "--robot-id", "300"], "--robot-id must be 0..255, got 300"),
        (["--profile", "solo", "--autopilot", "COM3"], "neither a serial device"),
        (["--profile", "solo", "--radio", "xbee"], "not a radio URL"),
        (["--profile", "solo", "--keys", "{d}"], "operator.pub: missing"),
        (["--profile", "solo", "--script", "{d}/x.txt"], "a script is a .bzz"),
        (["--profile", "solo", "--gps", "/dev/ttyUSB1"], "solo profile's GPS is inside its"),
        (["--profile", "husky", "--gps", "gps.local:2947"], "not a serial device path"),
        (["--profile", "m100"], "give --dji-app-id and --dji-app-key-file"),
        (["--profile", "m100", "--dji-app-id", "7"], "(flavour dji), activated with the "
         "developer's app: give --dji-app-key-file"),  # fmt: skip
        (["--profile", "m100", "--dji-app-key-file", "{d}/good.key"], "give --dji-app-id"),
        (["--profile", "solo", "--dji-app-id", "7", "--dji-app-key-file", "{d}/good.key"],
         "--dji-app-id 7 and --dji-app-key-file {d}/good.key: for a DJI M100 (flavour dji); "
         "the solo profile's autopilot is ardupilot"),
        (["--profile", "m100", "--dji-app-id", "0", "--dji-app-key-file", "{d}/good.key"],
         "--dji-app-id must be 1..4294967295, got 0"),
        (["--profile", "m100", "--dji-app-id", "7", "--dji-app-key-file", "{d}/short.key"],
         "short.key: the DJI app key must be 64 hex digits"),
        (["--profile", "m100", "--dji-app-id", "7", "--dji-app-key-file", "{d}/zzz.key"],
         "zzz.key: the DJI app key must be hex digits only; character 1 is not one"),
        (["--profile", "m100", "--dji-app-id", "7", "--dji-app-key-file", "{d}/open.key"],
         "open.key: readable by others (mode 0644): the app key is a secret"),
        (["--profile", "m100", "--dji-app-id", "7", "--dji-app-key-file", "{d}/none.key"],
         "none.key: cannot read: No such file or directory"),
    ],
)  # fmt: skip
def test_every_error_writes_nothing(tmp_path: Path, args: list[str], text: str) -> None:
    """Exit 1, one `error:` line saying what and where, and DIR as it was; a DJI app key
    in no message, whatever is wrong."""
    from fieldkit.vehicle.sim.dji import TEST_APP_KEY

    bad = tmp_path / "bad.bzz"
    bad.write_text(BROKEN)
    (tmp_path / "x.txt").write_text("x")
    for name, key, mode in (("good", TEST_APP_KEY, 0o600), ("open", TEST_APP_KEY, 0o644),
                            ("short", TEST_APP_KEY[:63], 0o600),
                            ("zzz", "z" + TEST_APP_KEY[1:], 0o600)):  # fmt: skip
        dji_app_key(tmp_path, key, mode).rename(tmp_path / f"{name}.key")
    root = tmp_path / "root"
    seed(root)
    before = listing(root)
    filled = [a.format(bad=bad, d=tmp_path) for a in args]
    result = deploy(*filled, "--root", root)
    assert result.exit_code == 1, result.output
    lines = errors(result.stderr)
    assert len(lines) == 1 and text.format(d=tmp_path) in lines[0], result.stderr
    assert "Traceback" not in result.output
    assert TEST_APP_KEY[1:40] not in result.output
    assert listing(root) == before


def test_a_file_deploy_did_not_install_is_never_overwritten(tmp_path: Path) -> None:
    root = tmp_path / "root"
    (root / "etc/fieldkit").mkdir(parents=True)
    (root / CONFIG).write_text("# the operator's own\n")
    before = listing(root)
    result = deploy("--profile", "solo", "--root", root)
    assert result.exit_code == 1, result.output
    (line,) = errors(result.stderr)
    assert (
        line == f"error: {root / CONFIG}: exists, and fieldkit deploy did not install it "
        "(it never overwrites such a file)"
    )
    assert listing(root) == before


def test_a_command_line_that_does_not_parse(tmp_path: Path) -> None:
    cases = [
        (["--root", str(tmp_path)], "Missing option '--profile'"),
        (["--profile", "solo", "--purge"], "--purge goes with --uninstall"),
    ]
    for args, text in cases:
        result = deploy(*args)
        assert result.exit_code == 2, result.output
        assert text in errors(result.stderr)[0]


def _as_a_user() -> tuple[str, ...]:
    """How to run a real process that is not root: as it is, or (as root) in a user
    namespace of its own, where it is uid 65534 and may still read this checkout."""
    if os.geteuid() != 0:
        return ()
    unshare = shutil.which("unshare")
    if unshare is None:
        pytest.skip("running as root, and there is no `unshare` to make a non-root process")
    probe = subprocess.run([unshare, "--user", "true"], capture_output=True, check=False)
    if probe.returncode != 0:
        pytest.skip("running as root, and `unshare --user` cannot make a non-root process here")
    return (unshare, "--user")


def test_without_root_it_needs_root(tmp_path: Path) -> None:
    proc = fieldkit("deploy", "--profile", "solo", prefix=_as_a_user())
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 1, err
    (line,) = errors(err)
    assert line.startswith("error: deploy installs a system service: run as root, or stage with "
                           "--root DIR")  # fmt: skip


@pytest.mark.skipif(os.geteuid() != 0, reason="the root check comes first for a non-root user")
def test_without_systemd_it_says_so(tmp_path: Path) -> None:
    if Path("/run/systemd/system").is_dir():
        pytest.skip("systemd runs here (PID 1): deploy without --root would really install")
    result = deploy("--profile", "solo")
    assert result.exit_code == 1, result.output
    (line,) = errors(result.stderr)
    assert "systemd is not running on this machine (/run/systemd/system does not exist)" in line
    assert not Path("/etc/fieldkit/deploy-manifest.json").exists()


def test_layout_paths_are_the_robots(tmp_path: Path) -> None:
    """`under` puts a robot path inside a staging root, never outside it."""
    assert layout.under(tmp_path, layout.CONFIG) == tmp_path / "etc/fieldkit/fieldkit.toml"


def test_what_a_new_deploy_will_not_do_is_said(tmp_path: Path, keys: Path) -> None:
    """Keys not given again are removed (said: the node then runs unsigned); a new script
    does not replace the version a node has committed (said, with the ways to do it)."""
    root = tmp_path / "root"
    assert (
        deploy("--profile", "solo", "--root", root, "--script", HELLO, "--keys", keys).exit_code
        == 0
    )
    (root / "var/lib/fieldkit/state").mkdir()
    (root / "var/lib/fieldkit/state/committed").write_text("0\n")
    other = tmp_path / "other.bzz"
    other.write_text("function init() {}\nfunction step() {}\n")
    result = deploy("--profile", "solo", "--root", root, "--script", other)
    assert result.exit_code == 0, result.output
    removing = "warning: removing /etc/fieldkit/keys/operator.pub, /etc/fieldkit/keys/swarm.key, "
    assert removing + "installed by the last deploy: give --keys DIR again" in result.stderr
    assert not (root / "etc/fieldkit/keys/swarm.key").exists()
    assert "it keeps running its committed one" in result.stderr


def test_a_bytecode_file_that_does_not_load(tmp_path: Path) -> None:
    bad = tmp_path / "bad.bo"
    bad.write_bytes(b"\x00\x01garbage")
    root = tmp_path / "root"
    result = deploy("--profile", "solo", "--root", root, "--script", bad)
    assert result.exit_code == 1, result.output
    (line,) = errors(result.stderr)
    assert line.startswith(f"error: {bad}: "), line
    assert not root.exists()
