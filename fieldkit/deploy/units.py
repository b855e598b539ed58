"""The files systemd reads, rendered from the templates in `fieldkit.systemd` (the
repository's `systemd/` folder): the node's unit, the update monitor's unit, sysusers.d,
tmpfiles.d and the udev rules.

A template holds `@NAME@` placeholders. Each must be given a value and each value must be
used (a template and this module that drift apart fail loudly); a placeholder alone on its
line whose value is empty takes its line with it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import PurePosixPath

from fieldkit import resources
from fieldkit.deploy import DeployError, layout
from fieldkit.deploy.links import UsbRule

_PLACEHOLDER = re.compile(r"@([A-Z_]+)@")

#: `fieldkit node --connect-timeout` by default: the wait for the autopilot's heartbeat.
NODE_CONNECT_TIMEOUT_S = 30.0
#: Start-up beyond the two waits: imports, the script's compile and global code, READY.
START_MARGIN_S = 30.0


def render(template: str, values: Mapping[str, str]) -> str:
    """The text of `template` (a file of `fieldkit.systemd`) with its placeholders filled."""
    text = (resources.systemd_dir() / template).read_text(encoding="utf-8")
    wanted = set(_PLACEHOLDER.findall(text))
    if wanted != set(values):
        raise DeployError(
            f"{template}: placeholders {sorted(wanted)} but values for {sorted(values)}"
        )
    lines = []
    for line in text.splitlines():
        alone = _PLACEHOLDER.fullmatch(line.strip())
        if alone is not None and not values[alone.group(1)]:
            continue
        lines.append(_PLACEHOLDER.sub(lambda m: values[m.group(1)], line))
    return "\n".join(lines) + "\n"


def exec_quote(arg: str) -> str:
    """One argument of an `Exec*=` line, as systemd reads it back: specifiers (`%`) and
    variables (`$`) escaped, quoted if it holds spaces, quotes or backslashes."""
    escaped = arg.replace("%", "%%").replace("$", "$$")
    if escaped and not re.search(r"[\s\"'\\;]", escaped):
        return escaped
    inner = escaped.replace("\\", "\\\\").replace('"', '\\"')
    return f'"{inner}"'


def _text(value: str) -> str:
    """A value in free text such as Description=, where `%` starts a specifier."""
    return value.replace("%", "%%")


def exec_line(argv: Sequence[str]) -> str:
    """An `Exec*=` command line: the absolute program, then its arguments."""
    if not argv or not PurePosixPath(argv[0]).is_absolute():
        raise DeployError(f"the service's program must be an absolute path, got {argv[:1]}")
    return " ".join(exec_quote(a) for a in argv)


def device_unit(path: str) -> str:
    """The systemd device unit of a device path (`/dev/ttyUSB0` -> `dev-ttyUSB0.device`),
    escaped as `systemd-escape --path --suffix=device` does."""
    parts = [p for p in path.split("/") if p]
    escaped = []
    for part in parts:
        out = []
        for i, ch in enumerate(part):
            if ch.isascii() and (ch.isalnum() or ch in ":_" or (ch == "." and i > 0)):
                out.append(ch)
            else:
                out.extend(f"\\x{b:02x}" for b in ch.encode())
        escaped.append("".join(out))
    return "-".join(escaped) + ".device"


@dataclass(frozen=True)
class NodeService:
    """What the node's unit depends on: the interpreter, the waits, devices and network."""

    profile: str
    python: str  # the absolute interpreter that ran deploy
    gps_fix_timeout_s: float
    devices: tuple[str, ...]  # serial devices it may open, read-write
    network: bool  # an autopilot or radio over IP
    ip_allow: tuple[str, ...] | None  # IPAddressAllow= (None: no IP filter)
    protect_home: str = "yes"  # "read-only" when the interpreter lives under /home

    @property
    def argv(self) -> list[str]:
        """The node's command line."""
        return [self.python, "-m", "fieldkit", "node", "--config", str(layout.CONFIG)]

    @property
    def timeout_start_s(self) -> int:
        """TimeoutStartSec=: the heartbeat wait, the GPS fix wait and a margin."""
        return math.ceil(NODE_CONNECT_TIMEOUT_S + self.gps_fix_timeout_s + START_MARGIN_S)


def node_unit(spec: NodeService) -> str:
    """fieldkit-node.service."""
    dependencies = []
    for device in spec.devices:
        # Started at boot once udev has the device, not before; a device missing for good
        # still lets the node start and say so (Wants=, not Requires= or BindsTo=, which
        # would also stop the node when a radio drops out mid-flight).
        unit = device_unit(device)
        dependencies += [f"Wants={unit}", f"After={unit}"]
    if spec.network:
        dependencies += ["Wants=network-online.target", "After=network-online.target"]
    if spec.devices:
        devices = ["DevicePolicy=closed"] + [f"DeviceAllow={d} rw" for d in spec.devices]
    else:
        devices = ["PrivateDevices=yes", "DevicePolicy=closed"]
    if spec.network:
        network = ["RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6"]
        if spec.ip_allow is not None:
            network += ["IPAddressDeny=any", f"IPAddressAllow={' '.join(spec.ip_allow)}"]
    else:
        network = ["PrivateNetwork=yes", "RestrictAddressFamilies=AF_UNIX", "IPAddressDeny=any"]
    return render(
        layout.NODE_UNIT,
        {
            "PROFILE": _text(spec.profile),
            "UNIT_DEPENDENCIES": "\n".join(dependencies),
            "EXEC_START": exec_line(spec.argv),
            "TIMEOUT_START_S": str(spec.timeout_start_s),
            "PROTECT_HOME": f"ProtectHome={spec.protect_home}",
            "DEVICES": "\n".join(devices),
            "NETWORK": "\n".join(network),
        },
    )


@dataclass(frozen=True)
class UpdateService:
    """What the update monitor's unit runs: the script it watches, with the node's includes."""

    profile: str  # the trial's profile (a name, or the installed profile's path)
    python: str
    script: str  # the installed .bzz
    include: str | None  # the -I directory, when the script has includes
    protect_home: str = "yes"

    @property
    def argv(self) -> list[str]:
        """The monitor's command line: a patch on every save."""
        argv = [self.python, "-m", "fieldkit", "update", self.script, "--watch"]
        argv += ["--keys", str(layout.OPERATOR_KEYS_DIR)]
        argv += ["--base", str(layout.OUTBOX_RELEASE), "--patch-out", str(layout.OUTBOX_PATCH)]
        argv += ["--profile", self.profile]
        return argv + (["-I", self.include] if self.include else [])

    @property
    def compile_argv(self) -> list[str]:
        """How the first base is made: the script compiled as the node compiles it."""
        argv = [self.python, "-m", "fieldkit", "compile", self.script]
        argv += ["-I", self.include] if self.include else []
        return argv + ["-o", str(layout.OUTBOX_RELEASE)]


def update_unit(spec: UpdateService) -> str:
    """fieldkit-update.service."""
    return render(
        layout.UPDATE_UNIT,
        {
            "PROFILE": _text(spec.profile),
            "SCRIPT": _text(spec.script),
            "EXEC_START": exec_line(spec.argv),
            "COMPILE_BASE": " ".join(exec_quote(a) for a in spec.compile_argv),
            "PROTECT_HOME": f"ProtectHome={spec.protect_home}",
        },
    )


def sysusers() -> str:
    """sysusers.d/fieldkit.conf: the fieldkit user, in dialout."""
    return render("fieldkit.sysusers", {})


def tmpfiles(originator: bool, dji_app_key: bool = False) -> str:
    """tmpfiles.d/fieldkit.conf: fieldkit's directories; key directories the user's alone
    (`Z ... ~0700`: 0700 for the directory, 0600 for the key files, owned by fieldkit, at
    every boot, so a staged image's keys need no chown); with `dji_app_key`, an M100's app
    key file the same (`z`: the file alone, if it is there)."""
    lines = ["# The robot's keys (operator.pub, swarm.key): the fieldkit user's alone."]
    dirs = [layout.KEYS_DIR]
    if originator:
        dirs.append(layout.OPERATOR_KEYS_DIR)
    for d in dirs:
        lines += [f"d {d} 0700 {layout.USER} {layout.USER} -"]
        lines += [f"Z {d} ~0700 {layout.USER} {layout.USER} -"]
    if dji_app_key:
        lines += ["# The M100's DJI app key: read by the node alone."]
        lines += [f"z {layout.DJI_APP_KEY} 0600 {layout.USER} {layout.USER} -"]
    return render("fieldkit.tmpfiles", {"KEY_DIRS": "\n".join(lines)})


def udev_rules(profile: str, rules: Sequence[UsbRule]) -> str:
    """rules.d/99-fieldkit.rules: one line per USB adapter with an id in the profile."""
    lines = [
        f'SUBSYSTEM=="tty", ATTRS{{idVendor}}=="{r.vendor}", ATTRS{{idProduct}}=="{r.product}", '
        f'SYMLINK+="{r.name}", GROUP="{layout.SERIAL_GROUP}", MODE="0660"'
        for r in rules
    ]
    return render(layout.UDEV_RULES.name, {"PROFILE": profile, "RULES": "\n".join(lines)})


__all__ = [
    "NODE_CONNECT_TIMEOUT_S",
    "NodeService",
    "UpdateService",
    "device_unit",
    "exec_line",
    "exec_quote",
    "node_unit",
    "render",
    "sysusers",
    "tmpfiles",
    "udev_rules",
]
