"""`fieldkit doctor`: the field preflight, one check per line, each failure with its fix.

An operator runs it on the robot before a mission, with the service's config file:

    ok    config: /etc/fieldkit/fieldkit.toml
    ok    profile: solo (uav, ardupilot autopilot), from device_profiles/solo.toml
    FAIL  serial: /dev/autopilot (the autopilot): the fieldkit user is not in group dialout ...
          fix: sudo usermod -aG dialout fieldkit, then sudo systemctl restart fieldkit-node ...
    skip  autopilot: its serial device failed the serial check
    ...

The checks run in the order of `CHECKS`; each is a small function returning a `CheckResult`.
A check that cannot run because one before it failed is a `skip` naming that check (its
`cause`); a skip with no cause (`--skip NAME`, nothing of that kind configured) is no
failure. Only `check_autopilot` and `check_radio` touch a device; the others read files and
the clock, and take what they decide on as arguments, so a test feeds them the numbers and
stat fields a robot would have (the time, free space, a device's mode, owner and group).

Doctor reads and never repairs: it opens the ports the node would open, so run it with the
node's service stopped (two readers on one serial line steal each other's bytes). The one
exception is a state directory holding versions: it is opened as the node opens it
(`VersionStore`), which may tidy what a crash left there, as the node's next start would.
"""

from __future__ import annotations

import datetime
import errno
import math
import os
import pwd
import socket
import stat
import time
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import bvm
from bvm.errors import BuzzCompileError
from fieldkit import resources
from fieldkit.deploy import layout
from fieldkit.node.config import NodeConfigError
from fieldkit.robot.link_security import NONE, SIGNED
from fieldkit.robot.profiles import Profile, ProfileError, load_profile

#: The checks, in the order they run and print.
CHECKS: tuple[str, ...] = (
    "config",
    "profile",
    "serial",
    "autopilot",
    "radio",
    "script",
    "keys",
    "clock",
    "disk",
)

#: The user the node's service runs as (`fieldkit deploy` creates it, in group dialout).
SERVICE_USER = layout.USER

#: The group that owns serial ports on Debian and Ubuntu.
SERIAL_GROUP = layout.SERIAL_GROUP

#: `fieldkit doctor`'s default config file: the one `fieldkit deploy` writes.
DEFAULT_CONFIG = Path(layout.CONFIG)

#: A system clock before this year has not been set since boot (a Pi has no RTC: 1970).
MIN_YEAR = 2025

#: Largest difference between the system time and the autopilot's GPS time that passes.
CLOCK_TOLERANCE_S = 5.0

#: Free space kept beyond a flight's recording cap (record.max_mb), for logs and the state.
DISK_MARGIN_MB = 100.0

#: Longest wait for the XBee's answers to our AT commands (a module answers in milliseconds).
RADIO_WAIT_S = 2.0

#: Longest wait, once the fix is there, for the autopilot's time (SYSTEM_TIME).
TIME_WAIT_S = 2.0

#: The AT queries sent to an XBee: API mode, network ID, the two halves of its serial number.
AT_QUERIES: tuple[bytes, ...] = (b"AP", b"ID", b"SH", b"SL")

#: How a continuation line (more detail, a fix) is indented under its check's line.
INDENT = " " * 6

Status = Literal["ok", "FAIL", "skip"]
"""A check's outcome: passed, failed, or not run."""

Role = Literal["autopilot", "radio", "gps"]
"""What a serial device is for (gps: a receiver on its own port, a Clearpath base's)."""


# ----------------------------------------------------------------------------- results


@dataclass(frozen=True)
class CheckResult:
    """One check's outcome: `detail` says what was found (or what is wrong), `fix` exactly
    what to do about a failure (one instruction a line); a skip's `cause` is the failed
    check it follows from (None: skipped on purpose, or nothing to check)."""

    name: str
    status: Status
    detail: str
    fix: str = ""
    cause: str | None = None

    @property
    def passed(self) -> bool:
        """Whether the check ran and passed."""
        return self.status == "ok"

    def lines(self) -> list[str]:
        """As printed: `ok    NAME: detail` or `FAIL  NAME: ...`, more detail and each
        `fix:` line indented below it."""
        first, *more = self.detail.splitlines() or [""]
        out = [f"{self.status:<6}{self.name}: {first}"]
        out += [f"{INDENT}{line}" for line in more]
        out += [f"{INDENT}fix: {line}" for line in self.fix.splitlines()]
        return out


def _ok(name: str, detail: str) -> CheckResult:
    return CheckResult(name, "ok", detail)


def _fail(name: str, detail: str, fix: str) -> CheckResult:
    return CheckResult(name, "FAIL", detail, fix)


def _skip(name: str, detail: str, cause: str | None = None) -> CheckResult:
    return CheckResult(name, "skip", detail, cause=cause)


def _problems(name: str, found: list[tuple[str, str]]) -> CheckResult:
    """One FAIL for several (problem, fix) pairs: every problem, then every fix."""
    fixes = list(dict.fromkeys(fix for _, fix in found))  # once each, in order
    return _fail(name, "\n".join(p for p, _ in found), "\n".join(fixes))


@dataclass(frozen=True)
class Outcome:
    """Every check's result, and what the command's last line says about them."""

    results: tuple[CheckResult, ...]

    @property
    def failed(self) -> list[CheckResult]:
        """The checks that ran and failed."""
        return [r for r in self.results if r.status == "FAIL"]

    @property
    def skipped_for_failure(self) -> list[CheckResult]:
        """The checks not run because one before them failed: not passed either."""
        return [r for r in self.results if r.status == "skip" and r.cause is not None]

    @property
    def passed(self) -> bool:
        """Whether nothing failed (skips on purpose, or with nothing to check, pass)."""
        return not self.failed and not self.skipped_for_failure


# ----------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class Settings:
    """What the checks need of the node's options: the config file as `fieldkit node
    --config` merges it (the command line's `node_options`), paths resolved."""

    config: Path
    profile: str
    script: Path | None = None
    autopilot: str | None = None
    radio: str | None = None
    include: tuple[str, ...] = ()
    state_dir: Path | None = None
    keys: Path | None = None
    security: str | None = None
    #: Where the node's bags go (the config's record.dir, or node.record's folder).
    record_dir: Path | None = None
    record_max_mb: float = 2048.0
    #: A Clearpath base's GPS port (node.gps; None: the profile's [gps] port).
    gps: str | None = None
    #: The DJI app an M100 is activated with (the config's [dji]), as (app id, app key).
    dji_app: tuple[int, str] | None = field(default=None, repr=False)


@dataclass(frozen=True)
class ServiceUser:
    """The service's user as the system knows it: its uid and every group it is in."""

    name: str
    uid: int
    gids: frozenset[int] = field(default_factory=frozenset)


def service_user(name: str = SERVICE_USER) -> ServiceUser | None:
    """The service user, if this machine has one (None before `fieldkit deploy`)."""
    try:
        pw = pwd.getpwnam(name)
    except KeyError:
        return None
    return ServiceUser(name, pw.pw_uid, frozenset(os.getgrouplist(name, pw.pw_gid)))


def user_may(user: ServiceUser, mode: int, owner: int, group: int, want: int) -> bool:
    """Whether `user` gets the `want` bits (4 read, 2 write, 1 search) of a file with this
    mode, owner and group: the owner's bits if it owns it, else the group's if it is in the
    group, else the others' (POSIX permission bits; ACLs are not read)."""
    if user.uid == 0:
        return True
    if owner == user.uid:
        bits = mode >> 6
    elif group in user.gids:
        bits = mode >> 3
    else:
        bits = mode
    return bits & want == want


def _group_name(gid: int) -> str:
    import grp

    try:
        return grp.getgrgid(gid).gr_name
    except KeyError:
        return str(gid)


def _user_name(uid: int) -> str:
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return str(uid)


def device_access_problem(
    path: str,
    mode: int,
    owner: int,
    group: int,
    user: ServiceUser,
    *,
    group_name: Callable[[int], str] = _group_name,
    user_name: Callable[[int], str] = _user_name,
) -> tuple[str, str] | None:
    """Why the service user could not open the serial device `path` for reading and
    writing, and the fix; None if it could. The classic: a user not in the device's group
    (dialout)."""
    if user_may(user, mode, owner, group, 6):
        return None
    perms = f"mode {stat.S_IMODE(mode):04o}, owner {user_name(owner)}, group {group_name(group)}"
    restart = "then sudo systemctl restart fieldkit-node"
    if (mode >> 3) & 6 == 6 and owner != user.uid:
        name = group_name(group)
        return (
            f"the {user.name} user is not in group {name}, which owns it ({perms}): the "
            "service cannot open it",
            f"sudo usermod -aG {name} {user.name}, {restart} (or re-run `fieldkit deploy`, "
            f"which puts {user.name} in {SERIAL_GROUP}): a service user outside the port's "
            "group is the most common reason a robot's service cannot open its ports",
        )
    return (
        f"not readable and writable by the {user.name} user ({perms})",
        f"sudo chgrp {SERIAL_GROUP} {path} && sudo chmod 660 {path}, {restart}; to keep it "
        f'after a replug, a udev rule with GROUP="{SERIAL_GROUP}", MODE="0660" (`fieldkit '
        "deploy` installs one)",
    )


# ----------------------------------------------------------------------------- 1. config


def check_config(
    path: Path, load: Callable[[Path], Settings]
) -> tuple[CheckResult, Settings | None]:
    """The config file loads and merges as the node's options (`load` raises
    NodeConfigError with one line per problem)."""
    try:
        settings = load(path)
    except NodeConfigError as e:
        if not path.exists():
            fix = (
                f"write it with `fieldkit deploy --profile NAME` (it writes {DEFAULT_CONFIG}), "
                "or give --config FILE"
            )
        else:
            fix = (
                f"correct {path} where the lines above say: [node] keys are `fieldkit node`'s "
                "options with underscores (docs/cli.md#node)"
            )
        return _fail("config", "\n".join(e.problems), fix), None
    return _ok("config", str(path)), settings


# ----------------------------------------------------------------------------- 2. profile


def check_profile(settings: Settings) -> tuple[CheckResult, Profile | None]:
    """The profile the config names loads and checks out."""
    try:
        prof = load_profile(settings.profile)
    except (ProfileError, OSError) as e:
        text = str(e)
        if "unknown profile" in text or "not a profile name" in text:
            fix = (
                f"set node.profile in {settings.config} to a shipped profile's name or the "
                "path of your own .toml"
            )
        else:
            fix = (
                "correct the profile where the lines above say "
                "(docs/field-guide.md#device-profiles)"
            )
        return _fail("profile", text, fix), None
    where = f", from {prof.path}" if prof.path is not None else ""
    return _ok(
        "profile", f"{prof.name} ({prof.vehicle}, {prof.autopilot.flavour} autopilot){where}"
    ), prof


# ----------------------------------------------------------------------------- 3. serial


@dataclass(frozen=True)
class Device:
    """A serial device the node opens: what for, its path, and which setting names it."""

    role: Role
    path: str
    source: str


@dataclass(frozen=True)
class Links:
    """The node's links as the settings name them (the autopilot, the radio, a Clearpath
    base's GPS receiver): serial devices to check, network links (no device), and settings
    that do not parse (role, problem, fix)."""

    devices: tuple[Device, ...] = ()
    network: tuple[str, ...] = ()
    bad: tuple[tuple[Role, str, str], ...] = ()


def autopilot_url(settings: Settings, profile: Profile) -> tuple[str, str]:
    """The autopilot's pymavlink URL and the setting it comes from."""
    if settings.autopilot is not None:
        return settings.autopilot, "node.autopilot"
    return profile.autopilot.url, f"the {profile.name} profile's autopilot.url"


def is_device_path(url: str) -> bool:
    """Whether a pymavlink URL is a serial device (`/dev/ttyACM0`), not `udpin:`, `tcp:`..."""
    return url.startswith("/")


def node_links(settings: Settings, profile: Profile) -> Links:
    """Which serial devices the node would open, as `fieldkit node` picks its links."""
    from fieldkit.radio.xbee_serial import parse_url

    devices: list[Device] = []
    network: list[str] = []
    bad: list[tuple[Role, str, str]] = []
    url, source = autopilot_url(settings, profile)
    if is_device_path(url):
        devices.append(Device("autopilot", url, source))
    else:
        network.append(f"autopilot {url}")
    if settings.gps is not None:
        devices.append(Device("gps", settings.gps, "node.gps"))
    elif profile.gps is not None:
        devices.append(Device("gps", profile.gps.port, f"the {profile.name} profile's gps.port"))
    radio = settings.radio
    if radio is None:
        if profile.radio.kind == "xbee":
            devices.append(
                Device("radio", profile.radio.port, f"the {profile.name} profile's radio.port")
            )
        else:
            network.append(f"radio UDP port {profile.radio.udp_port}")
    elif radio == "none":
        network.append("no radio (node.radio = none)")
    elif radio.startswith("udp://"):
        network.append(f"radio {radio}")
    else:
        try:
            where = parse_url(radio)
        except ValueError as e:
            bad.append(("radio", f"node.radio: {e}", _RADIO_URL_FIX))
        else:
            if where.device is not None:
                devices.append(Device("radio", where.device, "node.radio"))
            else:
                network.append(f"radio {where.pyserial_url}")
    return Links(tuple(devices), tuple(network), tuple(bad))


_RADIO_URL_FIX = (
    'set node.radio to "serial:///dev/xbee?baud=230400&api=2" (an XBee), "udp://HOST:PORT" '
    'or "none", or remove it to use the profile\'s radio'
)


def _missing_fix(device: Device) -> str:
    what = {
        "autopilot": "the autopilot's serial or USB cable",
        "radio": "the XBee",
        "gps": "the GPS receiver",
    }[device.role]
    named = {"autopilot": "/dev/autopilot", "radio": "/dev/xbee", "gps": "/dev/gps"}[device.role]
    return (
        f"plug in {what} and find it with `ls -l /dev/serial/by-id/`; {named} is made by "
        f"the udev rule `fieldkit deploy` installs from the profile's USB ids (`udevadm "
        f"trigger` after a replug); else set {device.source} to the device"
    )


def device_problem(
    device: Device,
    user: ServiceUser | None,
    *,
    stat_fn: Callable[[str], os.stat_result] = os.stat,
    access: Callable[[str, int], bool] = os.access,
) -> tuple[str, str] | None:
    """What is wrong with one serial device (missing, not a character device, not
    permitted to this process or to the service user) and the fix; None if nothing."""
    path = device.path
    label = f"{path} ({device.role}, {device.source})"
    try:
        st = stat_fn(path)
    except FileNotFoundError:
        return f"{label}: missing", _missing_fix(device)
    except OSError as e:
        return f"{label}: {e.strerror or e}", _missing_fix(device)
    if not stat.S_ISCHR(st.st_mode):
        return (
            f"{label}: not a serial device (not a character device)",
            f"set {device.source} to the serial device (e.g. /dev/ttyUSB0)",
        )
    if not access(path, os.R_OK | os.W_OK):
        me = _user_name(os.geteuid())
        return (
            f"{label}: not readable and writable by {me}, who runs doctor "
            f"(group {_group_name(st.st_gid)}, mode {stat.S_IMODE(st.st_mode):04o})",
            f"run doctor as root or as the service user: sudo -u {SERVICE_USER} fieldkit doctor",
        )
    if user is not None:
        found = device_access_problem(path, st.st_mode, st.st_uid, st.st_gid, user)
        if found is not None:
            return f"{label}: {found[0]}", found[1]
    return None


def check_serial(
    links: Links,
    user: ServiceUser | None,
    *,
    stat_fn: Callable[[str], os.stat_result] = os.stat,
    access: Callable[[str, int], bool] = os.access,
) -> tuple[CheckResult, frozenset[Role]]:
    """Every serial device present, a character device, and open to this process and to
    the service user; also the roles whose device failed (their checks are skipped)."""
    found: list[tuple[str, str]] = [(problem, fix) for _, problem, fix in links.bad]
    bad: set[Role] = {role for role, _, _ in links.bad}
    good: list[str] = []
    for device in links.devices:
        problem = device_problem(device, user, stat_fn=stat_fn, access=access)
        if problem is None:
            good.append(f"{device.path} ({device.role})")
        else:
            found.append(problem)
            bad.add(device.role)
    if found:
        return _problems("serial", found), frozenset(bad)
    if not links.devices:
        return _skip("serial", "no serial device: " + ", ".join(links.network)), frozenset()
    who = (
        f"open to this user and to the {user.name} user"
        if user is not None
        else f"open to this user (no {SERVICE_USER} user here: run `fieldkit deploy`)"
    )
    extra = f"; not serial: {', '.join(links.network)}" if links.network else ""
    return _ok("serial", f"{', '.join(good)}: {who}{extra}"), frozenset()


# ----------------------------------------------------------------------------- 4. autopilot


class SystemTimeTap:
    """The autopilot's UNIX time, read off the link's bytes as they pass (`Autopilot.on_rx`):
    the offset of the latest SYSTEM_TIME that carried one (0 means the autopilot has no GPS
    time yet) from this machine's clock when it arrived."""

    def __init__(self, wall: Callable[[], float] = time.time) -> None:
        """Decode with a codec of our own: the link's parser stays untouched."""
        from fieldkit.vehicle.mavlink import FrameReader, new_codec

        self._wall = wall
        self._reader = FrameReader(new_codec(self, 255, 0))
        #: Autopilot time minus system time, seconds (None until a SYSTEM_TIME with a time).
        self.offset_s: float | None = None

    def write(self, buf: bytes) -> None:
        """The codec's sink: this tap never sends."""

    def feed(self, data: bytes) -> None:
        """Bytes from the autopilot."""
        for msg in self._reader.feed(data):
            if msg.get_type() == "SYSTEM_TIME" and msg.time_unix_usec > 0:
                self.offset_s = msg.time_unix_usec * 1e-6 - self._wall()


def _enum_name(enum: str, value: int | None, prefix: str) -> str:
    from pymavlink.dialects.v20 import common as mavlink2

    entry = mavlink2.enums[enum].get(value) if value is not None else None
    return entry.name.removeprefix(prefix) if entry is not None else str(value)


def check_vehicle(
    profile: Profile,
    url: str,
    timeout: float,
    *,
    gps: str | None = None,
    dji_app: tuple[int, str] | None = None,
) -> CheckResult:
    """The start-up of a vehicle that does not speak MAVLink (a DJI M100, a Clearpath base)
    as the node does it, through its own link: heard (DJI: activated, control granted; the
    Husky's MCU answering) within `timeout`, then a 3D GPS fix within the profile's
    gps_fix_timeout_s capped by `timeout`."""
    from fieldkit.vehicle.autopilot import AutopilotError
    from fieldkit.vehicle.links import open_link

    flavour = profile.autopilot.flavour
    app_id, app_key = dji_app if dji_app is not None else (None, None)
    fix = (
        f"check the wiring and baud of {url} ({profile.autopilot.baud} baud, flavour "
        f"{flavour})"
        + ("; for an M100, the [dji] app id and key of the config" if flavour == "dji" else "")
    )
    try:
        link = open_link(profile, url, gps=gps, dji_app_id=app_id, dji_app_key=app_key)
    except AutopilotError as e:
        return _fail("autopilot", str(e), fix)
    try:
        try:
            link.wait_heartbeat(timeout)
        except AutopilotError as e:
            return _fail("autopilot", str(e), _dji_key_fix(link, app_id) or fix)
        fix_s = min(profile.autopilot.gps_fix_timeout_s, timeout)
        try:
            t = link.wait_gps_fix(fix_s)
        except AutopilotError as e:
            return _fail(
                "autopilot",
                f"{flavour} vehicle on {url} answers, but {e}",
                _silent_gps_fix(link, profile) or _no_fix(profile),
            )
    finally:
        link.close()
    sats = "?" if t.satellites is None else str(t.satellites)
    return _ok(
        "autopilot",
        f"{flavour} vehicle on {url}: mode {t.mode}, {'armed' if t.armed else 'disarmed'}, "
        f"GPS fix type {t.gps_fix_type}, {sats} satellites",
    )


def _dji_key_fix(link: object, app_id: int | None) -> str | None:
    """The fix when an M100 refused the app key (KEY_ERROR), else None. Never the key."""
    from fieldkit.vehicle.dji.link import DjiLink

    if not (isinstance(link, DjiLink) and link.core.key_rejected):
        return None
    return (
        f"the app key of the config's [dji] is not the one DJI gave app {app_id}: copy it "
        "again from DJI's developer site into the key file (64 hex digits, mode 0600; "
        "`fieldkit deploy --dji-app-id N --dji-app-key-file FILE` installs it as "
        f"{layout.DJI_APP_KEY}), then run doctor again"
    )


def _silent_gps_fix(link: object, profile: Profile) -> str | None:
    """The fix when a Clearpath base's GPS receiver sent nothing readable, else None (a
    receiver that talks but has no fix yet needs the sky, not a cable)."""
    from fieldkit.vehicle.clearpath.link import Husky

    if not (isinstance(link, Husky) and link.gps.messages == 0):
        return None
    baud = profile.gps.baud if profile.gps is not None else "?"
    return (
        f"check the GPS receiver on {link.gps.url}: powered, plugged in, sending NMEA (or UBX) "
        f"at gps.baud = {baud}; find it with `ls -l /dev/serial/by-id/` and set node.gps (or "
        "`fieldkit deploy --gps DEV`) if it is on another port"
    )


def check_autopilot(
    profile: Profile, url: str, timeout: float, *, wall: Callable[[], float] = time.time
) -> tuple[CheckResult, float | None]:
    """A heartbeat within `timeout`, then a 3D GPS fix within the profile's
    gps_fix_timeout_s capped by `timeout`; also the autopilot's time offset, if it sent
    its time."""
    from pymavlink.dialects.v20 import common as mavlink2

    from fieldkit.vehicle.autopilot import AutopilotError
    from fieldkit.vehicle.link import Autopilot

    try:
        link = Autopilot.from_profile(profile, url)
    except AutopilotError as e:
        return _fail("autopilot", str(e), _autopilot_fix(profile, url, 0, 0)), None
    tap = SystemTimeTap(wall)
    link.on_rx = tap.feed
    try:
        try:
            link.wait_heartbeat(timeout)
        except AutopilotError as e:
            fix = _autopilot_fix(profile, url, link.bytes_received, link.bad_frames)
            return _fail("autopilot", str(e), fix), None
        link.request_streams(profile.node.loop_rate_hz)
        fix_s = min(profile.autopilot.gps_fix_timeout_s, timeout)
        try:
            link.wait_gps_fix(fix_s)
        except AutopilotError as e:
            return _fail("autopilot", f"heartbeat on {url}, but {e}", _no_fix(profile)), None
        # Asked for outright: ArduPilot streams it with EXTRA3, PX4 on request.
        ask = link.command(mavlink2.MAV_CMD_REQUEST_MESSAGE, (mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME,))
        deadline = time.monotonic() + TIME_WAIT_S
        while tap.offset_s is None and time.monotonic() < deadline:
            if ask.done and (not ask.ok or link.message_counts["SYSTEM_TIME"]):
                break  # refused, or sent without a time (no GPS time yet)
            link.poll(0.05)
        t = link.telemetry
    finally:
        link.close()
    kind = _enum_name("MAV_AUTOPILOT", t.autopilot_type, "MAV_AUTOPILOT_")
    vehicle = _enum_name("MAV_TYPE", t.mav_type, "MAV_TYPE_")
    fix_name = _enum_name("GPS_FIX_TYPE", t.gps_fix_type, "GPS_FIX_TYPE_")
    fix_name = fix_name.replace("_FIX", " fix").replace("_", " ")  # "3D fix", "RTK FIXED"
    sats = "?" if t.satellites is None else str(t.satellites)
    detail = (
        f"{kind} {vehicle} on {url}: mode {t.mode}, {'armed' if t.armed else 'disarmed'}, "
        f"GPS {fix_name} (fix type {t.gps_fix_type}), {sats} satellites"
    )
    return _ok("autopilot", detail), tap.offset_s


def _autopilot_fix(profile: Profile, url: str, received: int, bad: int) -> str:
    if received and bad:
        return (
            f"bytes arrive but are not MAVLink: make the autopilot port's baud rate equal "
            f"the profile's autopilot.baud = {profile.autopilot.baud} (ArduPilot: SERIALn_BAUD), "
            "and its protocol MAVLink (SERIALn_PROTOCOL = 2)"
        )
    if received:
        return (
            f"MAVLink arrives on {url} but no vehicle heartbeat: check that the autopilot, not "
            "only a radio or a ground station, is at the other end, and that it is powered"
        )
    if not is_device_path(url):
        return (
            f"nothing came in on {url}: check that the autopilot (or its telemetry bridge) "
            "sends MAVLink there and that this machine is on its network"
        )
    return (
        f"nothing came in on {url}: check the autopilot is powered, the cable (TX to RX, "
        f"a common ground), and that the port speaks MAVLink (ArduPilot: SERIALn_PROTOCOL "
        f"= 2) at autopilot.baud = {profile.autopilot.baud}"
    )


def _no_fix(profile: Profile) -> str:
    return (
        "take the robot outdoors with a clear sky and wait for a 3D fix, then run doctor "
        f"again (--timeout S waits longer; the node waits up to autopilot.gps_fix_timeout_s "
        f"= {profile.autopilot.gps_fix_timeout_s:g} s at start)"
    )


# ----------------------------------------------------------------------------- 5. radio


def check_radio(settings: Settings, profile: Profile, timeout: float) -> CheckResult:
    """The node's radio answers: an XBee its AT commands, in the configured API mode; a UDP
    radio's port is free and opens."""
    from fieldkit.radio.xbee_serial import parse_url

    radio = settings.radio
    if radio == "none":
        return _skip("radio", "node.radio = none: this robot runs without a radio")
    if radio is None and profile.radio.kind == "udp":
        return check_udp(profile.radio.udp_port, None)
    if radio is not None and radio.startswith("udp://"):
        from urllib.parse import urlsplit

        try:
            udp_port = urlsplit(radio).port or profile.radio.udp_port
        except ValueError:
            return _fail("radio", f"node.radio: bad port in {radio!r}", _RADIO_URL_FIX)
        return check_udp(udp_port, radio)
    baud, api_mode = profile.radio.baud, profile.radio.api_mode
    device: str | None
    if radio is None:
        device, pyserial_url, source = profile.radio.port, None, f"the {profile.name} profile"
    else:
        try:
            where = parse_url(radio)
        except ValueError as e:
            return _fail("radio", f"node.radio: {e}", _RADIO_URL_FIX)
        device, pyserial_url, source = where.device, where.pyserial_url, "node.radio"
        baud = int(where.options.get("baud", baud))
        api_mode = int(where.options.get("api_mode", api_mode))
    name = device or pyserial_url or "?"
    try:
        line = _open_serial(device, pyserial_url, baud)
    except (OSError, ValueError) as e:
        return _fail("radio", f"{name}: cannot open: {_reason(e)}", _RADIO_URL_FIX)
    try:
        answers, received = query_xbee(line, api_mode, min(timeout, RADIO_WAIT_S))
    finally:
        line.close()
    return xbee_verdict(
        answers,
        name=name,
        source=source,
        baud=baud,
        api_mode=api_mode,
        received=received,
        waited=min(timeout, RADIO_WAIT_S),
    )


def _open_serial(device: str | None, pyserial_url: str | None, baud: int) -> Any:
    import serial

    # A read returns what came within 0.1 s: the wait loop needs no select (loop:// has no fd).
    if device is not None:
        return serial.Serial(device, baud, timeout=0.1, write_timeout=1.0)
    return serial.serial_for_url(pyserial_url, baud, timeout=0.1, write_timeout=1.0)


def _reason(e: BaseException) -> str:
    cause = e.__cause__ or e.__context__
    if isinstance(cause, OSError) and cause.strerror:
        return cause.strerror
    if isinstance(e, OSError) and e.strerror:
        return e.strerror
    return str(e)


def query_xbee(port: Any, api_mode: int, timeout: float) -> tuple[dict[bytes, Any], int]:
    """Send the `AT_QUERIES` as local AT command frames on an open pyserial port; the
    answers that came back within `timeout` (by command) and the bytes read."""
    from fieldkit.radio.xbee import AtCommand, AtResponse, FrameReader

    frames = b"".join(AtCommand(i + 1, cmd).encode(api_mode) for i, cmd in enumerate(AT_QUERIES))
    port.write(frames)
    port.flush()
    reader = FrameReader(api_mode)
    answers: dict[bytes, AtResponse] = {}
    received = 0
    deadline = time.monotonic() + timeout
    while len(answers) < len(AT_QUERIES) and time.monotonic() < deadline:
        data = port.read(max(1, port.in_waiting))
        received += len(data)
        for frame in reader.feed(data):
            if (
                isinstance(frame, AtResponse)
                and 1 <= frame.frame_id <= len(AT_QUERIES)
                and frame.command == AT_QUERIES[frame.frame_id - 1]
            ):
                answers[frame.command] = frame
        ap = answers.get(b"AP")
        if ap is not None and ap.status == 0 and ap.data and ap.data[-1] != api_mode:
            break  # another API mode: the other answers may never parse
    return dict(answers), received


def xbee_verdict(
    answers: dict[bytes, Any],
    *,
    name: str,
    source: str,
    baud: int,
    api_mode: int,
    received: int,
    waited: float,
) -> CheckResult:
    """What the XBee's answers say: silent, in another API mode, or answering."""
    if not answers:
        return _fail(
            "radio",
            f"no answer from the XBee on {name} to AT commands in {waited:g} s "
            f"({received} bytes received)",
            f"check the module is powered and on this port, its baud rate (BD) is {baud} as "
            f"{source} says, and it runs API mode {api_mode} (AP={api_mode}; in transparent "
            "mode, AP=0, it answers no frame): set them with XCTU "
            "(docs/field-guide.md#xbee-radio-settings)",
        )
    ap = answers.get(b"AP")
    if ap is not None and ap.status == 0 and ap.data and ap.data[-1] != api_mode:
        return _fail(
            "radio",
            f"the XBee on {name} runs API mode {ap.data[-1]} (AP={ap.data[-1]}), "
            f"{source} says {api_mode}",
            f"set AP={api_mode} on the module with XCTU, or make {source}'s API mode "
            f"{ap.data[-1]} (radio.api_mode, or ?api= in node.radio): every robot the same",
        )

    def value(cmd: bytes) -> str:
        r = answers.get(cmd)
        return "?" if r is None or r.status != 0 else r.data.hex().upper()

    serial = "?" if "?" in (value(b"SH"), value(b"SL")) else value(b"SH") + value(b"SL")
    mode = "?" if ap is None or not ap.data else str(ap.data[-1])
    return _ok(
        "radio",
        f"XBee on {name} answers: API mode {mode} (AP={mode}), network ID {value(b'ID')}, "
        f"serial {serial}",
    )


def check_udp(port: int, url: str | None) -> CheckResult:
    """A UDP radio: its port is free (bound without sharing, so that another program's
    socket on it shows), then the radio opens as the node opens it."""
    from fieldkit.radio import UdpRadio, open_radio

    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.bind(("", port))
    except OSError as e:
        if e.errno == errno.EADDRINUSE:
            return _fail(
                "radio",
                f"UDP port {port} is in use by another program",
                f"find it with `sudo ss -ulpn 'sport = :{port}'`; stop it (a node running as "
                "a service: sudo systemctl stop fieldkit-node), or give the radio another "
                'port (the profile\'s radio.udp_port, or node.radio = "udp://0.0.0.0:PORT")',
            )
        return _fail("radio", f"UDP port {port}: {e.strerror or e}", _RADIO_URL_FIX)
    finally:
        probe.close()
    try:
        radio = open_radio(url, 0) if url is not None else UdpRadio(0, port=port, group="0.0.0.0")
    except (OSError, ValueError) as e:
        return _fail("radio", f"{url or f'UDP port {port}'}: {_reason(e)}", _RADIO_URL_FIX)
    try:
        to = ", ".join(f"{h}:{p}" for h, p in getattr(radio, "destinations", []))
    finally:
        radio.close()
    return _ok("radio", f"UDP port {port} free; the radio opens (sends to {to})")


# ----------------------------------------------------------------------------- 6. script


def check_script(settings: Settings) -> CheckResult:
    """The script the node would run compiles: the state directory's committed version,
    else the config's script (which seeds an empty state directory)."""
    from fieldkit.update.store import StoreError, VersionStore

    state = settings.state_dir
    holds = state is not None and any(
        (state / name).exists() for name in ("committed.json", "history.jsonl")
    )
    if state is not None and holds:
        try:
            store = VersionStore(state)
            version = store.committed()
            if version is not None:
                path = store.path(version.hash)
                program = store.get(version.hash).program(str(path))
                return _ok(
                    "script",
                    f"version {version.version} ({version.hash[:12]}…) committed in {state}: "
                    f"{len(program.bytecode)} bytes of bytecode",
                )
        except (StoreError, bvm.BuzzLoadError) as e:
            return _fail(
                "script",
                str(e),
                f"move {state} aside and let node.script seed a fresh one (the node makes "
                "it version 0), or re-run `fieldkit deploy --script FILE`",
            )
    if settings.script is None:
        where = f"{state} holds no committed version and " if state is not None else ""
        return _fail(
            "script",
            f"{where}the config names no script",
            f'set node.script = "/path/to/behaviour.bzz" in {settings.config} (or run '
            "`fieldkit deploy --script FILE`)",
        )
    path = resources.find_script(settings.script)
    check = f"`fieldkit compile {path}` checks it, `fieldkit sim run {path}` runs it"
    try:
        if path.suffix == ".bo":
            program = bvm.Program.load(path)
        else:
            program = bvm.compile_file(path, include_dirs=list(settings.include))
    except BuzzCompileError as e:
        return _fail("script", str(e), f"correct the script at that place; {check}")
    except bvm.BuzzLoadError as e:
        return _fail("script", f"{path}: {e}", f"compile it again from its .bzz; {check}")
    except OSError as e:
        return _fail(
            "script",
            f"{path}: cannot read: {e.strerror or e}",
            f"correct node.script in {settings.config}",
        )
    seeds = f"; it seeds the state folder {state} as version 0" if state is not None else ""
    return _ok("script", f"{path} compiles: {len(program.bytecode)} bytes of bytecode{seeds}")


# ----------------------------------------------------------------------------- 7. keys


def check_keys(
    settings: Settings, profile: Profile | None, user: ServiceUser | None
) -> CheckResult:
    """The robot's keys: loadable (operator.pub, a private swarm.key), readable by the
    service user, never the operator's signing key; and keys wherever security needs them."""
    from fieldkit.update.keys import OPERATOR_KEY, KeyFileError, KeyPaths, load_robot_keys

    profile_mode = profile.radio.security if profile is not None else None
    mode = settings.security or profile_mode or (SIGNED if settings.keys else NONE)
    if settings.security is not None:
        said = "node.security"
    elif profile_mode is not None and profile is not None:
        said = f"the {profile.name} profile's radio.security"
    else:
        said = "the default with keys"
    found: list[tuple[str, str]] = []
    if mode == SIGNED and settings.keys is None:
        found.append(
            (
                f"security signed ({said}) authenticates bundles with the swarm key, and the "
                "config names no keys",
                f'set node.keys = "/etc/fieldkit/keys" (operator.pub and swarm.key; `fieldkit '
                f'deploy --keys DIR` installs them), or node.security = "{NONE}"',
            )
        )
    if mode == SIGNED and settings.state_dir is None:
        found.append(
            (
                "security signed keeps the robot's bundle counter in node.state_dir, and the "
                "config names none",
                'set node.state_dir = "/var/lib/fieldkit/state" (the robot\'s own, kept across '
                "reboots)",
            )
        )
    if settings.keys is None:
        if found:
            return _problems("keys", found)
        return _skip(
            "keys", "node.keys not set: radio bundles are not authenticated (security none)"
        )
    paths = KeyPaths(settings.keys)
    signing = paths.operator_key
    if signing.exists() or signing.is_symlink():
        found.append(
            (
                f"{signing}: the operator's signing key is on the robot: whoever takes the robot "
                "can sign updates and commands for the whole swarm",
                f"remove it (shred -u {signing}) and keep {OPERATOR_KEY} on the operator's "
                "machine only: a robot needs operator.pub and swarm.key",
            )
        )
    try:
        load_robot_keys(settings.keys)
    except KeyFileError as e:
        found.append((f"{e.file}: {e.problem}", e.hint))
    if user is not None:
        try:
            st = paths.directory.stat()
        except OSError:
            pass  # load_robot_keys said so
        else:
            if not user_may(user, st.st_mode, st.st_uid, st.st_gid, 1):
                found.append(
                    (
                        f"{paths.directory}: the {user.name} user may not enter it (owner "
                        f"{_user_name(st.st_uid)}, mode {stat.S_IMODE(st.st_mode):04o})",
                        f"sudo chown {user.name}: {paths.directory} && sudo chmod 700 "
                        f"{paths.directory}",
                    )
                )
        for path in paths.robot_files:
            try:
                st = path.stat()
            except OSError:
                continue  # load_robot_keys said so
            if not user_may(user, st.st_mode, st.st_uid, st.st_gid, 4):
                found.append(
                    (
                        f"{path}: not readable by the {user.name} user (owner "
                        f"{_user_name(st.st_uid)}, mode {stat.S_IMODE(st.st_mode):04o}): the "
                        "service cannot load it",
                        f"sudo chown {user.name}: {path} (or re-run `fieldkit deploy --keys DIR`)",
                    )
                )
    if found:
        return _problems("keys", found)
    return _ok(
        "keys",
        f"{settings.keys}: operator.pub and swarm.key load, swarm.key private, no "
        f"{OPERATOR_KEY}; security {mode}",
    )


# ----------------------------------------------------------------------------- 8. clock


def check_clock(now: float, autopilot_offset_s: float | None, autopilot: str) -> CheckResult:
    """The system time is set (a year >= MIN_YEAR), and within CLOCK_TOLERANCE_S of the
    autopilot's GPS time when it sent one. `autopilot` says what the autopilot gave, for
    the line when there is no offset."""
    stamp = datetime.datetime.fromtimestamp(now, datetime.UTC)
    shown = stamp.strftime("%Y-%m-%dT%H:%M:%SZ")
    known = autopilot_offset_s is not None and math.isfinite(autopilot_offset_s)
    if known:
        assert autopilot_offset_s is not None
        gps = datetime.datetime.fromtimestamp(now + autopilot_offset_s, datetime.UTC)
        setting = f"sudo date -u -s '{gps:%Y-%m-%d %H:%M:%S}' (the autopilot's GPS time now)"
    else:
        setting = "sudo date -u -s 'YYYY-MM-DD HH:MM:SS' from a good watch"
    fix = (
        f"set the time before the flight: with a network, sudo timedatectl set-ntp true; "
        f"without, {setting}; for good, an RTC, or chrony with the GPS as its source"
    )
    if stamp.year < MIN_YEAR:
        return _fail(
            "clock",
            f"the system time is {shown}: never set since boot (no RTC, no network time); "
            "bags, logs and update counters would carry it",
            fix,
        )
    if autopilot_offset_s is None:
        return _ok("clock", f"{shown}; {autopilot}")
    if not (known and abs(autopilot_offset_s) <= CLOCK_TOLERANCE_S):
        way = "behind" if autopilot_offset_s > 0 else "ahead of"
        return _fail(
            "clock",
            f"the system time {shown} is {abs(autopilot_offset_s):.1f} s {way} the "
            f"autopilot's GPS time (at most {CLOCK_TOLERANCE_S:g} s passes)",
            fix,
        )
    return _ok("clock", f"{shown}, {autopilot_offset_s:+.1f} s from the autopilot's GPS time")


# ----------------------------------------------------------------------------- 9. disk


@dataclass(frozen=True)
class Space:
    """A filesystem's free space, and which filesystem (st_dev): two folders on one share it."""

    device: int
    free_bytes: int


def disk_space(path: Path) -> Space:
    """The free space (for an unprivileged user) where `path` is or would be created."""
    here = path
    while not here.exists() and here != here.parent:
        here = here.parent
    st = os.statvfs(here)
    return Space(os.stat(here).st_dev, st.f_bavail * st.f_frsize)


def check_disk(
    settings: Settings,
    user: ServiceUser | None,
    *,
    space: Callable[[Path], Space] = disk_space,
    stat_fn: Callable[[Path], os.stat_result] = lambda p: p.stat(),
    access: Callable[[Path, int], bool] = os.access,
) -> CheckResult:
    """Room for a flight's recording (record.max_mb + DISK_MARGIN_MB) and the state, on
    each filesystem; the record and state folders writable by the service."""
    mb = float(2**20)
    folders: list[tuple[str, Path, float]] = []
    if settings.state_dir is not None:
        folders.append(("state", settings.state_dir, 0.0))
    if settings.record_dir is not None:
        folders.append(("record", settings.record_dir, settings.record_max_mb))
    if not folders:
        return _skip("disk", "no node.state_dir and no recording: nothing kept on disk")
    found: list[tuple[str, str]] = []
    needs: dict[int, tuple[Space, float, list[str]]] = {}
    for label, path, need_mb in folders:
        try:
            free = space(path)
        except OSError as e:
            found.append(
                (f"{path}: {e.strerror or e}", f"create {path} (or re-run `fieldkit deploy`)")
            )
            continue
        known, total, names = needs.get(free.device, (free, DISK_MARGIN_MB, []))
        needs[free.device] = (known, total + need_mb, [*names, f"{label} folder {path}"])
        found += _folder_problems(label, path, user, stat_fn, access)
    shown: list[str] = []
    for free, need_mb, names in needs.values():
        free_mb = free.free_bytes / mb
        if free_mb < need_mb:
            found.append(
                (
                    f"{' and '.join(names)}: {free_mb:.0f} MB free, {need_mb:.0f} MB needed "
                    f"(record.max_mb = {settings.record_max_mb:g} + {DISK_MARGIN_MB:g} MB)",
                    "free space there (old flights: fieldkit keeps record.keep_mb of them), or "
                    f"lower record.max_mb in {settings.config}",
                )
            )
        shown.append(f"{' and '.join(names)}: {free_mb:.0f} MB free, {need_mb:.0f} MB needed")
    if found:
        return _problems("disk", found)
    return _ok("disk", "; ".join(shown))


def _folder_problems(
    label: str,
    path: Path,
    user: ServiceUser | None,
    stat_fn: Callable[[Path], os.stat_result],
    access: Callable[[Path, int], bool],
) -> list[tuple[str, str]]:
    """A folder the node writes in: the record folder must exist; the state folder, or
    the nearest folder above it that exists (the node creates it), writable."""
    target = path
    if label == "state":
        while not target.exists() and target != target.parent:
            target = target.parent
    elif not path.is_dir():
        return [
            (
                f"record folder {path}: missing",
                f"sudo install -d -o {SERVICE_USER} -g {SERVICE_USER} {path} (`fieldkit deploy` "
                "makes it)",
            )
        ]
    owner = user.name if user is not None else SERVICE_USER
    fix = f"sudo chown {owner}: {target} (`fieldkit deploy` makes it the service's)"
    if not access(target, os.W_OK | os.X_OK):
        return [(f"{label} folder {target}: not writable by this user", fix)]
    if user is not None:
        st = stat_fn(target)
        if not user_may(user, st.st_mode, st.st_uid, st.st_gid, 3):
            return [(f"{label} folder {target}: not writable by the {user.name} user", fix)]
    return []


# ----------------------------------------------------------------------------- all of them


def run_checks(
    config: Path,
    load: Callable[[Path], Settings],
    *,
    timeout: float = 10.0,
    skip: Collection[str] = (),
    now: Callable[[], float] = time.time,
    find_user: Callable[[], ServiceUser | None] | None = None,
) -> Iterator[CheckResult]:
    """Run every check in order, yielding each result as it is known (the autopilot's
    takes up to 2 x `timeout`). `load` reads the config into `Settings`; `skip` names
    checks not to run; `now` is the system clock the clock check reads; `find_user` finds
    the service user (default: `service_user`, looked up when called)."""
    done: dict[str, CheckResult] = {}

    def blocked(name: str, needs: tuple[str, ...]) -> CheckResult | None:
        if name in skip:
            return _skip(name, f"--skip {name}")
        for dep in needs:
            r = done[dep]
            if r.status == "FAIL":
                return _skip(name, f"the {dep} check failed", cause=dep)
            if r.status == "skip" and r.cause is not None:
                return _skip(name, f"the {r.cause} check failed", cause=r.cause)
            if r.status == "skip":
                return _skip(name, f"needs the {dep} check, which was skipped")
        return None

    def emit(result: CheckResult) -> CheckResult:
        done[result.name] = result
        return result

    user = (find_user or service_user)()
    settings: Settings | None = None
    profile: Profile | None = None
    bad_roles: frozenset[Role] = frozenset()
    offset: float | None = None
    autopilot_said = "not compared with the autopilot's time: its check did not run"

    r = blocked("config", ())
    if r is None:
        r, settings = check_config(config, load)
    yield emit(r)

    r = blocked("profile", ("config",))
    if r is None:
        assert settings is not None
        r, profile = check_profile(settings)
    yield emit(r)

    r = blocked("serial", ("profile",))
    if r is None:
        assert settings is not None and profile is not None
        r, bad_roles = check_serial(node_links(settings, profile), user)
    yield emit(r)

    r = blocked("autopilot", ("profile",))
    if r is None and "autopilot" in bad_roles:
        r = _skip("autopilot", "its serial device failed the serial check", cause="serial")
    if r is None and "gps" in bad_roles:  # a Clearpath base's link opens both
        r = _skip("autopilot", "its GPS receiver's device failed the serial check", cause="serial")
    if r is None:
        assert settings is not None and profile is not None
        url, _ = autopilot_url(settings, profile)
        if profile.autopilot.flavour in ("dji", "clearpath"):  # no MAVLink, no SYSTEM_TIME
            r, offset = (
                check_vehicle(profile, url, timeout, gps=settings.gps, dji_app=settings.dji_app),
                None,
            )
        else:
            r, offset = check_autopilot(profile, url, timeout, wall=now)
        autopilot_said = (
            "not compared: the autopilot sent no SYSTEM_TIME with a GPS time"
            if r.passed
            else "not compared with the autopilot's time: its check did not pass"
        )
    yield emit(r)

    r = blocked("radio", ("profile",))
    if r is None and "radio" in bad_roles:
        r = _skip("radio", "its serial device failed the serial check", cause="serial")
    if r is None:
        assert settings is not None and profile is not None
        r = check_radio(settings, profile, timeout)
    yield emit(r)

    r = blocked("script", ("config",))
    if r is None:
        assert settings is not None
        r = check_script(settings)
    yield emit(r)

    r = blocked("keys", ("config",))
    if r is None:
        assert settings is not None
        r = check_keys(settings, profile, user)
    yield emit(r)

    r = blocked("clock", ())
    yield emit(r if r is not None else check_clock(now(), offset, autopilot_said))

    r = blocked("disk", ("config",))
    if r is None:
        assert settings is not None
        r = check_disk(settings, user)
    yield emit(r)


__all__ = [
    "CHECKS",
    "CheckResult",
    "DEFAULT_CONFIG",
    "Device",
    "Links",
    "Outcome",
    "ServiceUser",
    "Settings",
    "Space",
    "SystemTimeTap",
    "check_autopilot",
    "check_clock",
    "check_config",
    "check_disk",
    "check_keys",
    "check_profile",
    "check_radio",
    "check_script",
    "check_serial",
    "check_udp",
    "device_access_problem",
    "device_problem",
    "disk_space",
    "node_links",
    "query_xbee",
    "run_checks",
    "service_user",
    "user_may",
    "xbee_verdict",
]
