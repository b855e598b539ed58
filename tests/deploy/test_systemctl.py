"""A live deploy's commands, against recording fakes of systemctl, systemd-sysusers,
systemd-tmpfiles and udevadm first on PATH (this machine's PID 1 need not be systemd): real
programs, run as deploy runs them, that log their arguments and what they saw."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from fieldkit.deploy import DeployError, layout
from fieldkit.deploy.deployment import deploy, uninstall
from fieldkit.deploy.install import Installer
from fieldkit.deploy.plan import Machine, Options, make_plan
from fieldkit.deploy.systemctl import Systemctl, UnitState, after_files, systemd_missing

from .kit import HELLO, SYSTEM_PYTHON

#: Each fake logs one line: its name, its arguments, and whether the config file existed
#: (sysusers must run before any file is written). `systemctl show` answers with the next
#: line of $FAKE_STATES (the last one for ever), as `systemctl show` prints properties.
FAKE = """#!/bin/sh
seen=absent
[ -e "$FAKE_ROOT/etc/fieldkit/fieldkit.toml" ] && seen=present
echo "$(basename "$0") $* [config $seen]" >> "$FAKE_LOG"
if [ "$(basename "$0")" = systemd-sysusers ]; then cat > "$FAKE_LOG.sysusers"; fi
if [ "$(basename "$0")" = systemctl ] && [ "$1" = show ]; then
  n=$(cat "$FAKE_LOG.n" 2>/dev/null || echo 1)
  line=$(sed -n "${n}p" "$FAKE_STATES")
  [ -n "$line" ] && echo $((n + 1)) > "$FAKE_LOG.n" || line=$(tail -n 1 "$FAKE_STATES")
  printf 'ActiveState=%s\\nSubState=%s\\nStatusText=%s\\n' $line
fi
exit "${FAKE_EXIT:-0}"
"""


@pytest.fixture
def fakes(tmp_path: Path) -> dict[str, str]:
    """A bin directory of fakes; the environment that puts them first on PATH."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in ("systemctl", "systemd-sysusers", "systemd-tmpfiles", "udevadm"):
        path = bin_dir / tool
        path.write_text(FAKE)
        path.chmod(path.stat().st_mode | stat.S_IXUSR)
    states = tmp_path / "states"
    states.write_text("activating start -\nactive running tick=3\n")
    return {
        **os.environ,
        "PATH": f"{bin_dir}:{os.environ['PATH']}",
        "FAKE_LOG": str(tmp_path / "log"),
        "FAKE_STATES": str(states),
        "FAKE_ROOT": str(tmp_path / "root"),
    }


def log(env: dict[str, str]) -> list[str]:
    path = Path(env["FAKE_LOG"])
    lines = path.read_text().splitlines() if path.exists() else []
    path.unlink(missing_ok=True)
    Path(env["FAKE_LOG"] + ".n").unlink(missing_ok=True)
    return lines


def systemctl(env: dict[str, str], said: list[str]) -> Systemctl:
    """The layer, with its waits made instant (the fakes answer at once)."""
    return Systemctl(said.append, env=env, sleep=lambda _: None)


def live_plan() -> Options:
    return Options("husky", script=HELLO, robot_id=1, python=SYSTEM_PYTHON)


def test_systemd_missing_says_what(tmp_path: Path, fakes: dict[str, str]) -> None:
    assert systemd_missing(tmp_path / "absent", fakes["PATH"]) == (
        f"systemd is not running on this machine ({tmp_path / 'absent'} does not exist)"
    )
    assert systemd_missing(tmp_path, fakes["PATH"]) is None
    empty = tmp_path / "empty"
    empty.mkdir()
    assert systemd_missing(tmp_path, str(empty)) == f"systemctl not found (PATH={empty})"


def test_a_live_deploy_runs_its_commands_in_order(tmp_path: Path, fakes: dict[str, str]) -> None:
    """The user before any file (its sysusers.d text on stdin), then the files given to it,
    tmpfiles, udev, systemd's reload, the node enabled and started, its status line until
    READY. Again unchanged: no restart; changed: the running node restarted first."""
    root = tmp_path / "root"
    root.mkdir()
    usb = tmp_path / "usb"
    for n, (vendor, product) in enumerate((("067b", "2303"), ("0403", "6015"), ("1546", "01a8"))):
        (usb / f"1-{n}").mkdir(parents=True)
        (usb / f"1-{n}" / "idVendor").write_text(vendor)
        (usb / f"1-{n}" / "idProduct").write_text(product)
    machine = Machine(staging=False, usb_devices=usb)
    me = (os.getuid(), os.getgid())
    owners: list[str] = []

    def owner(user: str) -> tuple[int, int]:
        owners.append(user)
        return me

    installer = Installer(root, owners=owner, warn=lambda _: None)
    said: list[str] = []
    plan = make_plan(live_plan(), machine)
    changes = deploy(plan, installer, systemctl(fakes, said))
    assert changes.written and set(owners) == {"fieldkit"}
    assert log(fakes) == [
        "systemd-sysusers --replace=/usr/lib/sysusers.d/fieldkit.conf - [config absent]",
        "systemd-tmpfiles --create /usr/lib/tmpfiles.d/fieldkit.conf [config present]",
        "udevadm control --reload [config present]",
        "udevadm trigger --action=add --subsystem-match=tty [config present]",
        "udevadm settle --timeout=30 [config present]",
        "systemctl daemon-reload [config present]",
        "systemctl try-restart fieldkit-node.service [config present]",
        "systemctl enable --now fieldkit-node.service [config present]",
        "systemctl show -p ActiveState,SubState,StatusText fieldkit-node.service [config present]",
        "systemctl show -p ActiveState,SubState,StatusText fieldkit-node.service [config present]",
    ]
    assert Path(fakes["FAKE_LOG"] + ".sysusers").read_text().startswith("# sysusers.d: ")
    assert said[-2:] == [
        "fieldkit-node.service: activating (start): -",
        "fieldkit-node.service: active (running): tick=3",
    ]
    assert "run: systemctl enable --now fieldkit-node.service" in said

    deploy(plan, installer, systemctl(fakes, said))
    assert not [line for line in log(fakes) if "try-restart" in line]
    changed = make_plan(Options("husky", script=HELLO, robot_id=2, python=SYSTEM_PYTHON), machine)
    deploy(changed, installer, systemctl(fakes, said))
    assert "systemctl try-restart fieldkit-node.service [config present]" in log(fakes)

    removed = uninstall(installer, systemctl(fakes, said), purge=False)
    assert removed is not None
    assert removed.left == [root / "var/lib/fieldkit", root / "var/log/fieldkit"]
    assert log(fakes) == [
        "systemctl disable --now fieldkit-node.service [config present]",
        "systemctl daemon-reload [config absent]",
        "udevadm control --reload [config absent]",
    ]
    assert not (root / "etc/systemd/system/fieldkit-node.service").exists()


def test_a_node_that_fails_to_start_is_an_error(tmp_path: Path, fakes: dict[str, str]) -> None:
    """A node that fails (or fails and is being restarted) stops the deploy with its state
    and where to look; a command that fails, with its stderr."""
    Path(fakes["FAKE_STATES"]).write_text(
        "activating start -\nactivating auto-restart radio_/dev/xbee:_No_such_file\n"
    )
    said: list[str] = []
    with pytest.raises(DeployError) as e:
        systemctl(fakes, said).wait_ready(layout.NODE_UNIT)
    assert str(e.value).startswith(
        "fieldkit-node.service did not start: activating (auto-restart): "
        "radio_/dev/xbee:_No_such_file"
    )
    assert "journalctl -u fieldkit-node.service" in str(e.value)
    with pytest.raises(DeployError, match=r"`systemctl daemon-reload` failed \(exit 3\)"):
        systemctl({**fakes, "FAKE_EXIT": "3"}, said).run(["systemctl", "daemon-reload"])


def test_the_wait_is_bounded(fakes: dict[str, str]) -> None:
    """A node still waiting for its GPS fix when the bound passes: an error saying so."""
    Path(fakes["FAKE_STATES"]).write_text("activating start waiting_for_GPS_fix\n")
    now = [0.0]

    def sleep(seconds: float) -> None:
        now[0] += seconds

    layer = Systemctl(lambda _: None, env=fakes, sleep=sleep, clock=lambda: now[0])
    with pytest.raises(DeployError, match="not ready after 5 s: activating"):
        layer.wait_ready(layout.NODE_UNIT, timeout_s=5)


def test_commands_after_the_files() -> None:
    """No udev commands without rules; no restart when nothing changed."""
    commands = after_files(["fieldkit-node.service"], udev=False, changed=False)
    assert [c[0] for c in commands] == ["systemd-tmpfiles", "systemctl", "systemctl"]
    assert commands[-1] == ["systemctl", "enable", "--now", "fieldkit-node.service"]
    assert UnitState("failed", "failed", "").failed and UnitState("active", "running", "").ready
