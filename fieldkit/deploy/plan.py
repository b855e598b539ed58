"""One deployment, planned: every file, directory and symlink to install, from the options,
with every check that can fail made first, so that an error leaves nothing written.

`make_plan` raises a `FieldkitError` (a profile, key or deploy error) or a bvm compile or
load error for what cannot be deployed; what can be deployed but deserves a word (a device
that is not on this staging machine) is a warning in `Plan.warnings`.
"""

from __future__ import annotations

import grp
import os
import re
import socket
import stat
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import fieldkit
from fieldkit.deploy import DeployError, layout
from fieldkit.deploy.config_file import NodeConfig, node_config
from fieldkit.deploy.install import Dir, Entry, File, Symlink
from fieldkit.deploy.links import (
    Link,
    UsbRule,
    autopilot_link,
    gps_link,
    ip_allow_list,
    named_hosts,
    radio_link,
)
from fieldkit.deploy.script import ScriptInstall, prepare
from fieldkit.deploy.units import (
    NodeService,
    UpdateService,
    node_unit,
    sysusers,
    tmpfiles,
    udev_rules,
    update_unit,
)
from fieldkit.robot.profiles import MAX_ROBOT_ID, Profile, load_profile
from fieldkit.update.keys import (
    OPERATOR_KEY,
    OPERATOR_PUB,
    SWARM_KEY,
    load_robot_keys,
    load_signing_key,
)

#: Where the sysfs lists USB devices (their idVendor and idProduct files).
USB_DEVICES = Path("/sys/bus/usb/devices")

#: Directories a unit with PrivateTmp= cannot see into: no interpreter may live there.
_PRIVATE_TMP = (PurePosixPath("/tmp"), PurePosixPath("/var/tmp"))
#: Directories ProtectHome=yes hides: an interpreter there needs ProtectHome=read-only.
_HOMES = (PurePosixPath("/home"), PurePosixPath("/root"), PurePosixPath("/run/user"))


@dataclass(frozen=True)
class Options:
    """What `fieldkit deploy` was asked for."""

    profile: str
    script: Path | None = None
    robot_id: int | None = None
    autopilot: str | None = None
    radio: str | None = None
    gps: str | None = None  # a Clearpath base's GPS receiver
    keys: Path | None = None
    dji_app_id: int | None = None  # an M100's app (flavour dji): its id...
    dji_app_key_file: Path | None = None  # ...and the file holding its key
    originator: bool = False
    operator_keys: Path | None = None
    python: str = field(default_factory=lambda: sys.executable)


@dataclass
class Plan:
    """Everything one deployment installs, and what it says about it."""

    profile: Profile
    robot_id: str  # for messages: "robot 3", or where the id will come from
    entries: list[Entry]
    units: list[str]  # the units to enable and start
    udev: bool  # udev rules installed: reload and trigger udev
    node: NodeService
    script: ScriptInstall | None
    warnings: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Machine:
    """What the plan looks up on this machine (replaceable in tests)."""

    staging: bool  # --root: the robot's devices and host name are not here
    exists: Callable[[str], bool] = os.path.exists
    usb_devices: Path = USB_DEVICES
    hostname: Callable[[], str] = socket.gethostname


def make_plan(options: Options, machine: Machine) -> Plan:
    """Check everything and plan the files; raises on anything that cannot be deployed."""
    warnings: list[str] = []
    profile = load_profile(options.profile)
    shipped = _is_shipped_name(options.profile)
    profile_ref = options.profile if shipped else str(_installed_profile(profile))
    rid = _robot_id(profile, options.robot_id, machine, warnings)
    autopilot, more = autopilot_link(profile, options.autopilot)
    warnings += more
    radio, more = radio_link(profile, options.radio)
    warnings += more
    gps, more = gps_link(profile, options.gps)
    warnings += more
    links = (autopilot, radio) if gps is None else (autopilot, radio, gps)
    rules = [link.usb for link in links if link.usb is not None]
    _check_rules(profile, rules)
    for link in links:
        _check_device(link, machine, warnings)
    dji_key = _dji_app(profile, options)
    protect_home = _check_interpreter(options.python, machine, warnings)
    script = prepare(options.script) if options.script is not None else None
    operator_keys = (
        _operator_keys(options.operator_keys) if options.operator_keys is not None else []
    )
    if options.originator:
        if script is None or not script.is_source:
            raise DeployError(
                "--originator watches the script for changes: give --script with a .bzz"
            )
        if options.operator_keys is None:
            raise DeployError(
                "--originator signs patches with the operator's key: give --operator-keys DIR "
                "(the directory `fieldkit keys init` made)"
            )
    elif options.operator_keys is not None:
        raise DeployError(
            "--operator-keys is for --originator only: a robot never holds the operator's "
            "signing key otherwise"
        )
    keys = _robot_keys(options.keys, warnings) if options.keys is not None else []
    if options.originator:
        keys = _originator_keys(keys, operator_keys, options)

    network = autopilot.network or radio.network
    devices = tuple(dict.fromkeys(link.device for link in links if link.device))
    ip_allow = ip_allow_list(links) if network else None
    if network and ip_allow is None:
        warnings.append(
            f"{', '.join(named_hosts(links))}: a host name, not an address: the service's "
            "IP address filter (IPAddressAllow=) is left off"
        )
    node = NodeService(
        profile=profile.name,
        python=options.python,
        gps_fix_timeout_s=profile.autopilot.gps_fix_timeout_s,
        devices=devices,
        network=network,
        ip_allow=ip_allow,
        protect_home=protect_home,
    )
    config = NodeConfig(
        profile=profile_ref,
        robot_id=options.robot_id,
        autopilot=autopilot.config,
        radio=radio.config,
        gps=gps.config if gps is not None else None,
        script=str(script.target) if script is not None else None,
        keys=bool(keys),
        include=script is not None and script.has_includes,
        originator=options.originator,
        dji_app_id=options.dji_app_id if dji_key is not None else None,
    )

    def text(path: PurePosixPath, content: str, mode: int = 0o644) -> File:
        """A text file of the install."""
        return File(path, content.encode(), mode)

    unit = layout.UNIT_DIR / layout.NODE_UNIT
    entries: list[Entry] = [
        Dir(layout.ETC_DIR, 0o755),
        File(layout.LOCK, b"", 0o600),
        text(layout.CONFIG, node_config(config)),
        Dir(layout.KEYS_DIR, 0o700, layout.USER),
        *[_key_file(layout.KEYS_DIR / name, data) for name, data in keys],
        text(unit, node_unit(node)),
        Symlink(layout.WANTS_DIR / layout.NODE_UNIT, str(unit)),
        text(layout.SYSUSERS, sysusers()),
        text(layout.TMPFILES, tmpfiles(options.originator, dji_key is not None)),
        Dir(layout.STATE_DIR, 0o750, layout.USER),
        Dir(layout.LOG_DIR, 0o750, layout.USER),
    ]
    if dji_key is not None:
        entries.append(dji_key)
    if not shipped:
        assert profile.path is not None  # loaded from a file
        entries += [
            Dir(layout.PROFILES_DIR, 0o755),
            File(_installed_profile(profile), profile.path.read_bytes(), 0o644),
        ]
    if rules:
        entries.append(text(layout.UDEV_RULES, udev_rules(profile.name, rules)))
    if script is not None:
        entries.append(Dir(layout.SCRIPT_DIR, 0o755))
        for target in sorted({p.parent for p in script.files} - {layout.SCRIPT_DIR}):
            for d in reversed([target, *target.parents]):
                if d.is_relative_to(layout.SCRIPT_DIR) and d != layout.SCRIPT_DIR:
                    entries.append(Dir(d, 0o755))
        entries += [File(p, data, 0o644) for p, data in sorted(script.files.items())]
    units = [layout.NODE_UNIT]
    if options.originator:
        assert script is not None
        update = UpdateService(
            profile=profile_ref,
            python=options.python,
            script=str(script.target),
            include=str(layout.INCLUDE_DIR) if script.has_includes else None,
            protect_home=protect_home,
        )
        update_path = layout.UNIT_DIR / layout.UPDATE_UNIT
        entries += [
            Dir(layout.OPERATOR_KEYS_DIR, 0o700, layout.USER),
            *[_key_file(layout.OPERATOR_KEYS_DIR / name, data) for name, data in operator_keys],
            text(update_path, update_unit(update)),
            Symlink(layout.WANTS_DIR / layout.UPDATE_UNIT, str(update_path)),
        ]
        units.append(layout.UPDATE_UNIT)
    if script is None:
        warnings.append(
            f"no --script: the node runs the version committed in {layout.NODE_STATE_DIR}, "
            "and does not start until there is one"
        )
    return Plan(
        profile=profile,
        robot_id=rid,
        entries=_unique(entries),
        units=units,
        udev=bool(rules),
        node=node,
        script=script,
        warnings=warnings,
    )


def _unique(entries: list[Entry]) -> list[Entry]:
    """Each path once (a directory named twice, as the parent of two includes)."""
    seen: dict[PurePosixPath, Entry] = {}
    for e in entries:
        seen.setdefault(e.path, e)
    return list(seen.values())


def _is_shipped_name(profile: str) -> bool:
    """A shipped profile's name (`solo`), not a file's path."""
    return not (profile.endswith(".toml") or "/" in profile or "\\" in profile)


def _installed_profile(profile: Profile) -> PurePosixPath:
    """Where a profile given as a file is installed on the robot."""
    assert profile.path is not None
    return layout.PROFILES_DIR / profile.path.name


def _robot_id(profile: Profile, given: int | None, machine: Machine, warnings: list[str]) -> str:
    """The robot id (`robot 3`), or where the node will take it from; an id the node would
    refuse (or a host name without one, on the robot itself) is an error now."""
    if given is not None:
        if not 0 <= given <= MAX_ROBOT_ID:
            raise DeployError(f"--robot-id must be 0..{MAX_ROBOT_ID}, got {given}")
        return f"robot {given}"
    source = profile.robot_id
    if source.source == "config" and source.value is not None:
        return f"robot {source.value}"
    if source.source == "hostname":
        host = machine.hostname()
        m = re.search(r"(\d+)$", host)
        if m is not None and int(m.group(1)) <= MAX_ROBOT_ID and not machine.staging:
            return f"robot {int(m.group(1))}, from the host name"
        problem = (
            f"the {profile.name} profile takes the robot id from the host name "
            f'(robot_id.source = "hostname"), and {host!r} ends in no id'
        )
        if not machine.staging:
            raise DeployError(f"{problem}\nhint: give --robot-id N, or rename the host (solo3)")
        return "robot id from the robot's host name"
    return f"robot id from the robot's {source.source}"


def _check_rules(profile: Profile, rules: list[UsbRule]) -> None:
    """Two adapters with one USB id: a udev rule matching on the id cannot tell them apart
    (both would get both names), so the node might open its GPS as its MCU."""
    seen: dict[tuple[str, str], str] = {}
    for rule in rules:
        other = seen.setdefault((rule.vendor, rule.product), rule.name)
        if other != rule.name:
            raise DeployError(
                f"the {profile.name} profile's [usb] gives {other} and {rule.name} one USB id, "
                f"{rule.vendor}:{rule.product}: a udev rule cannot tell the two adapters apart"
                f"\nhint: give one of them by its device (--{_option(other)} or "
                f"--{_option(rule.name)} /dev/serial/by-id/...), or drop its id from [usb]"
            )


def _option(rule_name: str) -> str:
    """The option that gives a link's device: the XBee's rule is the radio's."""
    return "radio" if rule_name == "xbee" else rule_name


def _dji_app(profile: Profile, options: Options) -> File | None:
    """An M100's app key file, checked and ready to install 0600 for the fieldkit user;
    None for other flavours. Its bytes are never put in a message."""
    values = {"--dji-app-id": options.dji_app_id, "--dji-app-key-file": options.dji_app_key_file}
    given = [name for name, value in values.items() if value is not None]
    flavour = profile.autopilot.flavour
    if flavour != "dji":
        if given:
            said = " and ".join(f"{name} {values[name]}" for name in given)
            raise DeployError(
                f"{said}: for a DJI M100 (flavour dji); the {profile.name} profile's autopilot "
                f"is {flavour}\nhint: leave {' and '.join(given)} out"
            )
        return None
    missing = [n for n in ("--dji-app-id", "--dji-app-key-file") if n not in given]
    if missing:
        raise DeployError(
            f"the {profile.name} profile's autopilot is a DJI flight controller (flavour dji), "
            f"activated with the developer's app: give {' and '.join(missing)}\nhint: "
            "--dji-app-id N --dji-app-key-file FILE, the app's id and key (64 hex digits, in "
            "a file of mode 0600) from DJI's developer site"
        )
    assert options.dji_app_id is not None and options.dji_app_key_file is not None
    app_id, where = options.dji_app_id, options.dji_app_key_file
    if not 0 < app_id <= 0xFFFFFFFF:
        raise DeployError(f"--dji-app-id must be 1..4294967295, got {app_id}")
    return File(layout.DJI_APP_KEY, _read_app_key(where), 0o600, layout.USER, DJI_KEY_SHOWN)


#: How --dry-run shows the DJI app key file: what it holds, never its digits.
DJI_KEY_SHOWN = "64 hex digits"


def _read_app_key(where: Path) -> bytes:
    """The app key in `where` as the node reads it (64 hex digits, blanks around ignored),
    to install; DeployError naming the file (never its contents) if it is not one, or if
    others may read it."""
    from fieldkit.vehicle.dji.crypto import AppKeyError, parse_app_key

    try:
        st = where.stat()
        raw = where.read_bytes()
    except OSError as e:
        raise DeployError(f"--dji-app-key-file {where}: cannot read: {e.strerror or e}") from None
    if not stat.S_ISREG(st.st_mode):
        raise DeployError(f"--dji-app-key-file {where}: not a regular file")
    try:
        key = raw.decode("ascii").strip()
        parse_app_key(key)
    except (UnicodeDecodeError, AppKeyError) as e:
        # AppKeyError says how long or which character, never the key.
        reason = "not ASCII text" if isinstance(e, UnicodeDecodeError) else str(e)
        raise DeployError(
            f"--dji-app-key-file {where}: {reason}\nhint: the file holds the app key alone, "
            "as DJI's developer site shows it"
        ) from None
    if st.st_mode & 0o077:
        raise DeployError(
            f"--dji-app-key-file {where}: readable by others (mode "
            f"{stat.S_IMODE(st.st_mode):04o}): the app key is a secret\nhint: chmod 600 {where}"
        )
    return (key + "\n").encode("ascii")


def _check_device(link: Link, machine: Machine, warnings: list[str]) -> None:
    """A serial device the node will open must be there (USB adapters: plugged in); on a
    staging machine (--root) its absence is only a warning."""
    if link.device is None:
        return
    if link.usb is not None:
        usb = f"{link.usb.vendor}:{link.usb.product}"
        if usb_present(link.usb.vendor, link.usb.product, machine.usb_devices):
            return
        problem = f"{link.what} {link.described}: no USB device {usb} is plugged in"
        hint = "plug the adapter in, check its id with `lsusb`, or give the device"
    else:
        if machine.exists(link.device):
            _check_group(link, warnings)
            return
        problem = f"{link.what} {link.described}: no such device"
        hint = f"plug it in or wire it, or give --{link.what} with the device it is on"
    if machine.staging:
        warnings.append(f"{problem} (the robot's devices are not on this staging machine)")
        return
    raise DeployError(f"{problem}\nhint: {hint}")


def _check_group(link: Link, warnings: list[str]) -> None:
    """The service reaches serial ports through the dialout group: say if this one is not
    the group's (the commonest reason a service cannot open its port)."""
    assert link.device is not None
    try:
        st = os.stat(link.device)
        dialout = grp.getgrnam(layout.SERIAL_GROUP).gr_gid
    except (OSError, KeyError):
        return
    if st.st_gid == dialout and st.st_mode & 0o060 == 0o060:
        return
    if st.st_mode & 0o006 == 0o006:
        return
    try:
        group = grp.getgrgid(st.st_gid).gr_name
    except KeyError:
        group = str(st.st_gid)
    warnings.append(
        f"{link.what} {link.device}: group {group}, mode {stat.S_IMODE(st.st_mode):04o}: the "
        f"service opens it as a member of {layout.SERIAL_GROUP}, which cannot; give the "
        'device to dialout with a udev rule (GROUP="dialout", MODE="0660"), or the profile '
        "its USB id ([usb])"
    )


def usb_present(vendor: str, product: str, devices: Path = USB_DEVICES) -> bool:
    """Whether a USB device with this id is plugged in (from the sysfs)."""
    try:
        entries = list(devices.iterdir())
    except OSError:
        return False
    for entry in entries:
        try:
            v = (entry / "idVendor").read_text().strip().lower()
            p = (entry / "idProduct").read_text().strip().lower()
        except OSError:
            continue
        if (v, p) == (vendor, product):
            return True
    return False


def _check_interpreter(python: str, machine: Machine, warnings: list[str]) -> str:
    """The interpreter the unit runs, and fieldkit's own files, must be visible to the
    service; the ProtectHome= value that allows it."""
    if not PurePosixPath(python).is_absolute():
        raise DeployError(f"the interpreter {python!r} is not an absolute path")
    places = [PurePosixPath(python), PurePosixPath(os.path.realpath(python))]
    places.append(PurePosixPath(os.path.realpath(Path(fieldkit.__file__).parent)))
    for place in places:
        if any(place.is_relative_to(t) for t in _PRIVATE_TMP):
            problem = (
                f"fieldkit is installed under {place}, which the service cannot see "
                "(PrivateTmp=yes gives it a /tmp of its own)"
            )
            if not machine.staging:
                raise DeployError(f"{problem}\nhint: install fieldkit in a venv under /opt")
            warnings.append(problem)
            break
    for place in places:
        if any(place.is_relative_to(h) for h in _HOMES):
            warnings.append(
                f"fieldkit is installed under {place}: the service gets ProtectHome=read-only "
                "rather than yes (a venv under /opt keeps home directories hidden from it)"
            )
            return "read-only"
    return "yes"


def _robot_keys(directory: Path, warnings: list[str]) -> list[tuple[str, bytes]]:
    """operator.pub and swarm.key from `directory`, checked as the node loads them; never
    operator.key."""
    load_robot_keys(directory)  # KeyFileError names the file and the fix
    if (directory / OPERATOR_KEY).exists():
        warnings.append(
            f"{directory / OPERATOR_KEY} left out: a robot never holds the operator's signing "
            "key (--originator --operator-keys installs it on the one that signs)"
        )
    return [(name, _read_key(directory / name)) for name in (OPERATOR_PUB, SWARM_KEY)]


def _operator_keys(directory: Path) -> list[tuple[str, bytes]]:
    """operator.key, operator.pub and swarm.key, checked as `fieldkit update` loads them."""
    load_signing_key(directory)
    load_robot_keys(directory)
    return [(name, _read_key(directory / name)) for name in (OPERATOR_KEY, OPERATOR_PUB, SWARM_KEY)]


def _originator_keys(
    keys: list[tuple[str, bytes]], operator_keys: list[tuple[str, bytes]], options: Options
) -> list[tuple[str, bytes]]:
    """The node's keys on an originator: it verifies the patches its monitor signs, so it
    needs them even without --keys (then taken from --operator-keys, the signing key left
    out); --keys of another swarm or operator would refuse every one of them."""
    public = [(name, data) for name, data in operator_keys if name != OPERATOR_KEY]
    if not keys:
        return public
    if dict(keys) != dict(public):
        raise DeployError(
            f"--keys {options.keys} and --operator-keys {options.operator_keys} hold different "
            f"{OPERATOR_PUB} or {SWARM_KEY}: the node would refuse every patch its update "
            "monitor signs\nhint: give the keys of one swarm, or leave --keys out (the "
            "originator then takes them from --operator-keys)"
        )
    return keys


def _key_file(target: PurePosixPath, data: bytes) -> File:
    """A key file, 0600 for the fieldkit user; a private one (the swarm key, the operator's
    signing key) never shown by --dry-run."""
    secret = None if target.name == OPERATOR_PUB else "a private key"
    return File(target, data, 0o600, layout.USER, secret)


def _read_key(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as e:
        raise DeployError(f"{path}: cannot read: {e.strerror or e}") from None


__all__ = ["Machine", "Options", "Plan", "USB_DEVICES", "make_plan", "usb_present"]
