"""Device profiles: what a robot model can do and how to reach it, from one TOML file each.

The simulator reads a profile's kinematics and battery; the field node will read the rest
(autopilot link, radio, failsafes, geofence, robot id). Shipped profiles live in the
repository's `device_profiles/` directory, installed as package data (fieldkit/resources.py):

    load_profile("solo")                      # device_profiles/solo.toml
    load_profile("site/my_husky.toml")        # any explicit path
    list_profiles()                           # ["husky", "m100", "solo", "spiri"]

Every problem in a file is a `ProfileError` naming the file, the dotted field and what is
wrong, for example `device_profiles/solo.toml: kinematics.max_speed_mps: must be > 0, got -1`.
All problems of a file are reported at once, one per line, so a field engineer fixes them
in one pass.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Literal, TypeVar

from fieldkit import resources
from fieldkit.errors import FieldkitError

_T = TypeVar("_T")

PROFILE_DIR = resources.profile_dir()
"""Where bare profile names are looked up: the shipped profiles (`device_profiles/`)."""

VehicleKind = Literal["uav", "ground"]
"""`vehicle`: a UAV flies; a ground robot stays at z = 0."""
Flavour = Literal["ardupilot", "px4", "dji", "clearpath"]
"""`autopilot.flavour`: which autopilot family speaks on `autopilot.url`."""
FailsafeAction = Literal["hold", "land", "rtl", "stop"]
"""A `failsafe.on_*` action (see `Failsafe`)."""
RadioKind = Literal["xbee", "udp"]
"""`radio.kind`: an XBee mesh on a serial port, or UDP broadcast (WiFi)."""
IdSource = Literal["config", "hostname", "xbee"]
"""`robot_id.source`: a fixed value, the hostname's trailing digits, or the XBee serial."""

VEHICLES: tuple[str, ...] = ("uav", "ground")
"""Allowed values of `vehicle`."""
FLAVOURS: tuple[str, ...] = ("ardupilot", "px4", "dji", "clearpath")
"""Allowed values of `autopilot.flavour`."""
FAILSAFE_ACTIONS: tuple[str, ...] = ("hold", "land", "rtl", "stop")
"""Allowed failsafe actions for a UAV."""
GROUND_FAILSAFE_ACTIONS: tuple[str, ...] = ("stop", "hold")
"""Allowed failsafe actions for a ground robot (it cannot land or fly home)."""
RADIO_KINDS: tuple[str, ...] = ("xbee", "udp")
"""Allowed values of `radio.kind`."""
SECURITY_MODES: tuple[str, ...] = ("signed", "none")
"""Allowed values of `radio.security`: authenticated bundles or ROSBuzz's plain bytes."""
ID_SOURCES: tuple[str, ...] = ("config", "hostname", "xbee")
"""Allowed values of `robot_id.source`."""
GPS_PROTOCOLS: tuple[str, ...] = ("nmea", "ubx")
"""Allowed values of `gps.protocol`: NMEA 0183 sentences, or u-blox's binary UBX."""
MAX_ROBOT_ID = 255
"""Largest robot id: ROSBuzz, XbeeMav and MAVLink sysid hold 8 bits (docs/bundle.md#robot-ids)."""

# Mode names per flavour, as pymavlink's mode mappings spell them (DJI: the names our DJI
# adapter maps onto Onboard SDK control authority and flight tasks). Ground robots run an
# ArduPilot-Rover-like link, which has HOLD where a copter has LOITER and no LAND at all.
_DEFAULT_MODES: dict[tuple[str, str], tuple[str, str, str, str]] = {
    ("ardupilot", "uav"): ("GUIDED", "LOITER", "LAND", "RTL"),
    ("px4", "uav"): ("OFFBOARD", "LOITER", "LAND", "RTL"),
    ("dji", "uav"): ("SDK_CONTROL", "HOVER", "LANDING", "GO_HOME"),
    ("ardupilot", "ground"): ("GUIDED", "HOLD", "HOLD", "RTL"),
    ("px4", "ground"): ("OFFBOARD", "LOITER", "LOITER", "RTL"),
    ("dji", "ground"): ("SDK_CONTROL", "HOVER", "HOVER", "GO_HOME"),
    # The Clearpath MCU has no modes: these name what the Husky core is doing (driving to a
    # point, stopped, driving home), with ArduPilot Rover's words.
    ("clearpath", "ground"): ("GUIDED", "HOLD", "HOLD", "RTL"),
    ("clearpath", "uav"): ("GUIDED", "HOLD", "HOLD", "RTL"),
}


class ProfileError(FieldkitError, ValueError):
    """A device profile that cannot be used; the message says where and why, one line each."""

    def __init__(self, problems: list[str]) -> None:
        """Wrap one or more `file: field: problem` lines."""
        super().__init__("\n".join(problems))
        self.problems: tuple[str, ...] = tuple(problems)


@dataclass(frozen=True)
class Kinematics:
    """Motion limits. Ground robots have no vertical motion: the vertical fields are 0."""

    max_speed_mps: float  # horizontal
    max_accel_mps2: float  # applied to horizontal and vertical motion separately
    max_climb_mps: float
    max_descent_mps: float
    takeoff_altitude_m: float
    hover_accuracy_m: float  # how close to a target counts as "there"


@dataclass(frozen=True)
class AutopilotSettings:
    """How to reach the flight controller and which modes to select."""

    flavour: Flavour
    url: str  # pymavlink connection string: "/dev/ttyUSB0", "udpin:0.0.0.0:14550", ...
    baud: int
    guided_mode: str
    loiter_mode: str
    land_mode: str
    rtl_mode: str
    heartbeat_timeout_s: float
    gps_fix_timeout_s: float


DJI_BROADCAST_RATES: tuple[int, ...] = (1, 10, 50, 100)
"""Allowed `dji.broadcast_hz`: the rates the M100's set-broadcast-frequency command knows."""


@dataclass(frozen=True)
class DjiSettings:
    """`[dji]`: the DJI Onboard SDK link's settings that are not secret (flavour "dji").

    The app id and app key are the developer's and come from the node's config, never from
    a profile (docs/vehicles.md#dji-onboard-sdk-matrice-100).
    """

    broadcast_hz: int = 50  # telemetry items asked for at this rate (1, 10, 50 or 100)
    control_rate_hz: float = 50.0  # movement-control frames per second (DJI: 50, its maximum)
    encrypt: bool = True  # AES-256 on control, task and movement frames, with the app key


@dataclass(frozen=True)
class NodeSettings:
    """The field node's own settings."""

    loop_rate_hz: float = 10.0


@dataclass(frozen=True)
class Geofence:
    """Where the robot may go: a lat/lon polygon (empty = no polygon) and an altitude ceiling."""

    polygon: tuple[tuple[float, float], ...]
    max_altitude_m: float


@dataclass(frozen=True)
class Failsafe:
    """What the host does, without asking the script, when something goes wrong.

    Actions: "hold" brakes and keeps position; "land" lands where it is; "rtl" returns to
    launch and lands; "stop" stops the script and brakes to a standstill (a UAV in the air
    then hovers: nothing is ever disarmed in the air).
    """

    on_heartbeat_loss: FailsafeAction
    on_low_battery: FailsafeAction
    on_script_error: FailsafeAction
    low_battery_percent: float
    #: What the node orders when it is stopped (SIGTERM, `systemctl stop`): "hold" keeps a
    #: UAV where it is (a pilot or a restarted node takes over), "land" lands it; a ground
    #: robot stops ("stop", its hold mode).
    on_stop: FailsafeAction = "hold"


@dataclass(frozen=True)
class Battery:
    """Linear drain model: voltage falls from full to empty over `endurance_s` of use."""

    full_voltage: float
    empty_voltage: float
    endurance_s: float  # hover time (UAV) or drive time (ground) from a full charge
    capacity_wh: float | None = None


@dataclass(frozen=True)
class RadioSettings:
    """The inter-robot radio."""

    kind: RadioKind
    port: str  # serial device of the XBee; unused for UDP
    baud: int
    api_mode: int  # XBee API mode 1, or 2 (escaped)
    udp_port: int
    per_step_budget_bytes: int  # Buzz bytes per step, as ROSBuzz (docs/rosbuzz.md#radio-budget)
    # XBee 64-bit serial (16 upper-case hex digits) -> robot id, like XbeeMav's database.xml.
    id_map: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}), hash=False)
    # "signed" or "none"; None: signed when the robot has keys, none without.
    security: str | None = None


@dataclass(frozen=True)
class RobotId:
    """Where the robot's id comes from: a fixed value, the hostname's digits, or the XBee.

    "hostname" takes the digits at the end of the host name ("solo3" -> 3); "xbee" looks
    the radio's 64-bit serial up in `RadioSettings.id_map`, as XbeeMav does with its database.
    """

    source: IdSource
    value: int | None = None  # only with source = "config"


@dataclass(frozen=True)
class UsbIds:
    """The USB adapters of the robot's serial links, as `VENDOR:PRODUCT` (lower-case hex).

    `fieldkit deploy` turns them into udev rules that give the adapters stable names,
    /dev/autopilot, /dev/xbee and /dev/gps, whatever ttyUSB/ttyACM number the kernel hands
    out; None where the link is not a USB serial adapter (a UART, a network link) or is not
    known.
    """

    autopilot: str | None = None
    radio: str | None = None
    gps: str | None = None  # a GPS receiver on a port of its own ([gps]: a Clearpath base)


@dataclass(frozen=True)
class GpsSettings:
    """A GPS receiver on a serial port of its own (the Husky's; autopilots have theirs)."""

    port: str  # serial device, e.g. "/dev/clearpath/gps"
    baud: int
    protocol: str  # "nmea" or "ubx" (a u-blox receiver; NMEA sentences are read too)
    timeout_s: float = 2.0  # silence after which the fix counts as lost


@dataclass(frozen=True)
class DriveSettings:
    """A differential (skid-steer) base driven wheel speed by wheel speed."""

    #: Effective wheel separation B in omega = (v_R - v_L) / B. Skid steering slips, so it is
    #: wider than the geometric track (Husky: 0.5708 m; ROS 1's controller used x 1.875).
    wheel_separation_m: float = 1.0703
    #: Host-side limit of the turn rate (ROS 1's Husky controller config: 2.0 rad/s).
    max_turn_rate_rps: float = 2.0


@dataclass(frozen=True)
class Profile:
    """One robot model's complete device profile."""

    name: str
    vehicle: VehicleKind
    kinematics: Kinematics
    autopilot: AutopilotSettings
    node: NodeSettings
    geofence: Geofence
    failsafe: Failsafe
    battery: Battery
    radio: RadioSettings
    robot_id: RobotId
    description: str = ""
    path: Path | None = None  # the file it was loaded from
    usb: UsbIds = field(default_factory=UsbIds)
    dji: DjiSettings = DjiSettings()  # the [dji] table (flavour "dji" only)
    gps: GpsSettings | None = None  # a GPS on its own port ([gps]; flavour "clearpath")
    drive: DriveSettings | None = None  # a differential base ([drive]; flavour "clearpath")

    @property
    def is_ground(self) -> bool:
        """Whether this is a ground robot (no takeoff, no altitude)."""
        return self.vehicle == "ground"


# --------------------------------------------------------------------------- loading


def list_profiles(directory: Path | None = None) -> list[str]:
    """Names of the shipped profiles (or of the `*.toml` files in `directory`), sorted."""
    d = PROFILE_DIR if directory is None else directory
    return sorted(p.stem for p in d.glob("*.toml"))


def load_profile(name_or_path: str | Path) -> Profile:
    """Load and validate a profile: a bare name like "solo" or a path to a TOML file."""
    path = _resolve(name_or_path)
    shown = _display(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise ProfileError([f"{shown}: cannot read: {e.strerror or e}"]) from e
    except UnicodeDecodeError as e:
        raise ProfileError([f"{shown}: not UTF-8 text: {e.reason} at byte {e.start}"]) from e
    except tomllib.TOMLDecodeError as e:
        # tomllib's message already carries "(at line L, column C)".
        raise ProfileError([f"{shown}: invalid TOML: {e}"]) from e
    return parse_profile(data, source=shown, path=path)


def _resolve(name_or_path: str | Path) -> Path:
    """The file a profile argument designates."""
    if isinstance(name_or_path, Path):
        return name_or_path
    s = name_or_path
    looks_like_path = s.endswith(".toml") or "/" in s or "\\" in s
    if looks_like_path:
        return Path(s)
    if not s or not all(c.isalnum() or c in "_-" for c in s):
        raise ProfileError([f"{s!r}: not a profile name or a .toml path"])
    path = PROFILE_DIR / f"{s}.toml"
    if not path.is_file():
        known = ", ".join(list_profiles()) or "none"
        raise ProfileError([f"{s}: unknown profile (known: {known}); or give a .toml path"])
    return path


def _display(path: Path) -> str:
    """How a file is named in messages: shipped profiles relative to the repository."""
    try:
        return str(path.resolve().relative_to(PROFILE_DIR.parent))
    except ValueError:
        return str(path)


# --------------------------------------------------------------------------- validation

_MISSING: Any = object()


class _Checker:
    """Collects `source: field: problem` lines while reading one profile."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.problems: list[str] = []

    def fail(self, where: str, problem: str) -> None:
        """Record one problem."""
        self.problems.append(f"{self.source}: {where}: {problem}")

    def table(
        self, data: Mapping[str, Any], key: str, allowed: tuple[str, ...], required: bool
    ) -> dict[str, Any] | None:
        """The sub-table `key`, checked for unknown fields; None when absent or not a table."""
        if key not in data:
            if required:
                self.fail(key, "missing required table")
                return None
            return {}
        t = data[key]
        if not isinstance(t, dict):
            self.fail(key, f"must be a table, got {_describe(t)}")
            return None
        self.unknown(t, allowed, prefix=f"{key}.")
        return t

    def unknown(self, t: Mapping[str, Any], allowed: tuple[str, ...], prefix: str = "") -> None:
        """Report every key of `t` that is not in `allowed`."""
        for k in t:
            if k not in allowed:
                self.fail(f"{prefix}{k}", "unknown field")

    def get(
        self,
        t: Mapping[str, Any] | None,
        where: str,
        kind: Callable[[_Checker, str, Any], Any],
        default: Any = _MISSING,
    ) -> Any:
        """Field `where` (dotted) of table `t`, converted by `kind`; None if it is unusable."""
        if t is None:
            return None
        key = where.rsplit(".", 1)[-1]
        if key not in t:
            if default is _MISSING:
                self.fail(where, "missing required field")
                return None
            return default
        return kind(self, where, t[key])


def _describe(v: Any) -> str:
    """A value's TOML type and value, for messages."""
    names = {bool: "boolean", int: "integer", float: "float", str: "string"}
    name = names.get(type(v))
    if name is not None:
        return f"{name} {str(v).lower() if isinstance(v, bool) else repr(v)}"
    if isinstance(v, list):
        return "an array"
    if isinstance(v, dict):
        return "a table"
    return type(v).__name__  # dates and times


def _float(c: _Checker, where: str, v: Any) -> float | None:
    """A finite number; TOML integers are accepted where a float is expected."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        c.fail(where, f"must be a number, got {_describe(v)}")
        return None
    f = float(v)
    if not math.isfinite(f):
        c.fail(where, f"must be finite, got {v}")
        return None
    return f


def _int(c: _Checker, where: str, v: Any) -> int | None:
    """An integer (a float such as 10.0 is refused: counts and ports are whole numbers)."""
    if isinstance(v, bool) or not isinstance(v, int):
        c.fail(where, f"must be an integer, got {_describe(v)}")
        return None
    return v


def _str(c: _Checker, where: str, v: Any) -> str | None:
    """A string."""
    if not isinstance(v, str):
        c.fail(where, f"must be a string, got {_describe(v)}")
        return None
    return v


def _nonempty(c: _Checker, where: str, v: Any) -> str | None:
    """A string with something in it."""
    s = _str(c, where, v)
    if s is not None and not s.strip():
        c.fail(where, "must not be empty")
        return None
    return s


def _choice(options: tuple[str, ...]) -> Callable[[_Checker, str, Any], str | None]:
    """A string among `options`."""

    def check(c: _Checker, where: str, v: Any) -> str | None:
        s = _str(c, where, v)
        if s is not None and s not in options:
            listed = ", ".join(f'"{o}"' for o in options)
            c.fail(where, f"must be one of {listed}, got {s!r}")
            return None
        return s

    return check


def _num(
    g: float | None = None, ge: float | None = None, lt: float | None = None
) -> Callable[[_Checker, str, Any], float | None]:
    """A finite number with bounds: > g, >= ge, < lt."""

    def check(c: _Checker, where: str, v: Any) -> float | None:
        f = _float(c, where, v)
        if f is None:
            return None
        if g is not None and not f > g:
            c.fail(where, f"must be > {_fmt(g)}, got {_fmt(v)}")
            return None
        if ge is not None and not f >= ge:
            c.fail(where, f"must be >= {_fmt(ge)}, got {_fmt(v)}")
            return None
        if lt is not None and not f < lt:
            c.fail(where, f"must be < {_fmt(lt)}, got {_fmt(v)}")
            return None
        return f

    return check


def _whole(lo: int, hi: int) -> Callable[[_Checker, str, Any], int | None]:
    """An integer in [lo, hi]."""

    def check(c: _Checker, where: str, v: Any) -> int | None:
        i = _int(c, where, v)
        if i is not None and not lo <= i <= hi:
            c.fail(where, f"must be in {lo}..{hi}, got {i}")
            return None
        return i

    return check


def _fmt(v: float | int) -> str:
    """A number as a user wrote it: 5 rather than 5.0."""
    if isinstance(v, float) and v.is_integer():
        return str(int(v))
    return str(v)


_TOP = (
    "name",
    "vehicle",
    "description",
    "kinematics",
    "autopilot",
    "node",
    "geofence",
    "failsafe",
    "battery",
    "radio",
    "robot_id",
    "usb",
    "dji",
    "gps",
    "drive",
)
_KINEMATICS = (
    "max_speed_mps",
    "max_accel_mps2",
    "max_climb_mps",
    "max_descent_mps",
    "takeoff_altitude_m",
    "hover_accuracy_m",
)
_AUTOPILOT = (
    "flavour",
    "url",
    "baud",
    "guided_mode",
    "loiter_mode",
    "land_mode",
    "rtl_mode",
    "heartbeat_timeout_s",
    "gps_fix_timeout_s",
)
_MODES = ("guided_mode", "loiter_mode", "land_mode", "rtl_mode")
_NODE = ("loop_rate_hz",)
_GEOFENCE = ("polygon", "max_altitude_m")
_FAILSAFE = (
    "on_heartbeat_loss",
    "on_low_battery",
    "on_script_error",
    "low_battery_percent",
    "on_stop",
)
STOP_ACTIONS: tuple[str, ...] = ("hold", "land")
"""Allowed `failsafe.on_stop` for a UAV (a ground robot: "stop" or "hold")."""
_BATTERY = ("full_voltage", "empty_voltage", "endurance_s", "capacity_wh")
_RADIO = (
    "kind",
    "port",
    "baud",
    "api_mode",
    "udp_port",
    "per_step_budget_bytes",
    "id_map",
    "security",
)
_ROBOT_ID = ("source", "value")
_USB = ("autopilot", "radio", "gps")
_DJI = ("broadcast_hz", "control_rate_hz", "encrypt")
_GPS = ("port", "baud", "protocol", "timeout_s")
_DRIVE = ("wheel_separation_m", "max_turn_rate_rps")

_POSITIVE = _num(g=0.0)
_PORT = _whole(1, 65535)


def parse_profile(data: Mapping[str, Any], source: str, path: Path | None = None) -> Profile:
    """Validate an already-parsed TOML document; `source` names it in error messages."""
    c = _Checker(source)
    c.unknown(data, _TOP)
    name = c.get(data, "name", _nonempty)
    vehicle = c.get(data, "vehicle", _choice(VEHICLES))
    description = c.get(data, "description", _str, "")
    ground = vehicle == "ground"

    kinematics = _kinematics(c, c.table(data, "kinematics", _KINEMATICS, True), vehicle)
    autopilot = _autopilot(c, c.table(data, "autopilot", _AUTOPILOT, True), vehicle)
    t = c.table(data, "node", _NODE, False)
    node = NodeSettings(c.get(t, "node.loop_rate_hz", _POSITIVE, 10.0)) if t is not None else None
    geofence = _geofence(c, c.table(data, "geofence", _GEOFENCE, not ground), vehicle, kinematics)
    failsafe = _failsafe(c, c.table(data, "failsafe", _FAILSAFE, False), vehicle)
    battery = _battery(c, c.table(data, "battery", _BATTERY, True))
    radio = _radio(c, c.table(data, "radio", _RADIO, True))
    robot_id = _robot_id(c, c.table(data, "robot_id", _ROBOT_ID, False), radio)
    usb = _usb(c, c.table(data, "usb", _USB, False))
    dji = _dji(c, c.table(data, "dji", _DJI, False), autopilot)
    clearpath = autopilot is not None and autopilot.flavour == "clearpath"
    gps = _gps(c, c.table(data, "gps", _GPS, False), "gps" in data, clearpath)
    if usb is not None and usb.gps is not None and "gps" not in data:
        c.fail("usb.gps", "names a GPS receiver's adapter, and the profile has no [gps] table")
    drive = _drive(c, c.table(data, "drive", _DRIVE, False), "drive" in data, clearpath)

    if c.problems:
        raise ProfileError(c.problems)
    return Profile(
        name=name,
        vehicle=vehicle,
        kinematics=_checked(kinematics),
        autopilot=_checked(autopilot),
        node=_checked(node),
        geofence=_checked(geofence),
        failsafe=_checked(failsafe),
        battery=_checked(battery),
        radio=_checked(radio),
        robot_id=_checked(robot_id),
        description=description,
        path=path,
        usb=_checked(usb),
        dji=_checked(dji),
        gps=gps,
        drive=drive,
    )


def _checked(section: _T | None) -> _T:
    """A section that passed its checks: None only ever comes with a problem recorded, so
    after `c.problems` was found empty this cannot fail."""
    if section is None:
        raise ProfileError(["internal: a section is missing but no problem was recorded"])
    return section


def _kinematics(c: _Checker, t: dict[str, Any] | None, vehicle: str | None) -> Kinematics | None:
    """[kinematics]: every value positive, except the vertical ones of a ground robot (0)."""
    if t is None:
        return None
    speed = c.get(t, "kinematics.max_speed_mps", _POSITIVE)
    accel = c.get(t, "kinematics.max_accel_mps2", _POSITIVE)
    accuracy = c.get(t, "kinematics.hover_accuracy_m", _POSITIVE)
    vertical = ("max_climb_mps", "max_descent_mps", "takeoff_altitude_m")
    values: dict[str, float | None] = {}
    for key in vertical:
        where = f"kinematics.{key}"
        if vehicle == "ground":
            # A copied UAV profile would otherwise carry a takeoff height into a Husky.
            v = c.get(t, where, _float, 0.0)
            if v is not None and v != 0.0:
                c.fail(where, f"ground robots do not fly; use 0 or leave it out, got {_fmt(v)}")
                v = None
            values[key] = v
        else:
            values[key] = c.get(t, where, _POSITIVE)
    climb, descent, takeoff = (values[key] for key in vertical)
    if (
        speed is None
        or accel is None
        or accuracy is None
        or climb is None
        or descent is None
        or takeoff is None
    ):
        return None
    return Kinematics(
        max_speed_mps=speed,
        max_accel_mps2=accel,
        max_climb_mps=climb,
        max_descent_mps=descent,
        takeoff_altitude_m=takeoff,
        hover_accuracy_m=accuracy,
    )


def _autopilot(
    c: _Checker, t: dict[str, Any] | None, vehicle: str | None
) -> AutopilotSettings | None:
    """[autopilot]: flavour and link are required; mode names default per flavour."""
    if t is None:
        return None
    flavour = c.get(t, "autopilot.flavour", _choice(FLAVOURS))
    url = c.get(t, "autopilot.url", _nonempty)
    baud = c.get(t, "autopilot.baud", _whole(1, 10_000_000), 57600)
    defaults = _DEFAULT_MODES.get((flavour, vehicle or "uav"), (None,) * 4)
    modes = [
        c.get(t, f"autopilot.{key}", _nonempty, d) for key, d in zip(_MODES, defaults, strict=True)
    ]
    heartbeat = c.get(t, "autopilot.heartbeat_timeout_s", _POSITIVE, 3.0)
    gps_fix = c.get(t, "autopilot.gps_fix_timeout_s", _POSITIVE, 120.0)
    guided, loiter, land, rtl = modes
    if (
        flavour is None
        or url is None
        or baud is None
        or heartbeat is None
        or gps_fix is None
        or guided is None
        or loiter is None
        or land is None
        or rtl is None
    ):
        return None
    return AutopilotSettings(flavour, url, baud, guided, loiter, land, rtl, heartbeat, gps_fix)


def _geofence(
    c: _Checker, t: dict[str, Any] | None, vehicle: str | None, kin: Kinematics | None
) -> Geofence | None:
    """[geofence]: a polygon of >= 3 [lat, lon] corners (or none) and the altitude ceiling."""
    if t is None:
        return None
    polygon = _polygon(c, t.get("polygon", []))
    if vehicle == "ground":
        ceiling = c.get(t, "geofence.max_altitude_m", _float, 0.0)
        if ceiling is not None and ceiling != 0.0:
            c.fail(
                "geofence.max_altitude_m",
                f"ground robots do not fly; use 0 or leave it out, got {_fmt(ceiling)}",
            )
            ceiling = None
    else:
        # Required for UAVs: a ceiling is a safety limit, better stated than defaulted.
        ceiling = c.get(t, "geofence.max_altitude_m", _POSITIVE)
        if ceiling is not None and kin is not None and ceiling < kin.takeoff_altitude_m:
            c.fail(
                "geofence.max_altitude_m",
                f"must be >= kinematics.takeoff_altitude_m ({_fmt(kin.takeoff_altitude_m)}), "
                f"got {_fmt(ceiling)}",
            )
            ceiling = None
    if polygon is None or ceiling is None:
        return None
    return Geofence(polygon, ceiling)


def _polygon(c: _Checker, v: Any) -> tuple[tuple[float, float], ...] | None:
    """A list of [lat, lon] pairs: empty, or at least 3 corners enclosing some area."""
    where = "geofence.polygon"
    if not isinstance(v, list):
        c.fail(where, f"must be an array of [lat, lon] pairs, got {_describe(v)}")
        return None
    corners: list[tuple[float, float]] = []
    ok = True
    for i, pair in enumerate(v):
        at = f"{where}[{i}]"
        if not isinstance(pair, list) or len(pair) != 2:
            c.fail(at, f"must be a [lat, lon] pair, got {_describe(pair)}")
            ok = False
            continue
        lat = _float(c, f"{at}[0]", pair[0])
        lon = _float(c, f"{at}[1]", pair[1])
        if lat is not None and not -90.0 <= lat <= 90.0:
            c.fail(f"{at}[0]", f"latitude must be in -90..90, got {_fmt(lat)}")
            lat = None
        if lon is not None and not -180.0 <= lon <= 180.0:
            c.fail(f"{at}[1]", f"longitude must be in -180..180, got {_fmt(lon)}")
            lon = None
        if lat is None or lon is None:
            ok = False
            continue
        corners.append((lat, lon))
    if not ok:
        return None
    if 0 < len(corners) < 3:
        c.fail(where, f"needs at least 3 corners (or none), got {len(corners)}")
        return None
    if corners:
        # Shoelace in degrees: only its sign-free size matters, to catch collinear corners.
        twice_area = sum(
            a[1] * b[0] - b[1] * a[0]
            for a, b in zip(corners, corners[1:] + corners[:1], strict=True)
        )
        if abs(twice_area) < 1e-14:
            c.fail(where, "corners enclose no area")
            return None
    return tuple(corners)


def _failsafe(c: _Checker, t: dict[str, Any] | None, vehicle: str | None) -> Failsafe | None:
    """[failsafe]: one action per trigger; ground robots can only stop or hold."""
    if t is None:
        return None
    ground = vehicle == "ground"
    defaults = {
        "on_heartbeat_loss": "stop" if ground else "land",
        "on_low_battery": "stop" if ground else "rtl",
        "on_script_error": "stop" if ground else "hold",
    }
    actions: dict[str, FailsafeAction | None] = {}
    for key, default in defaults.items():
        where = f"failsafe.{key}"
        a = c.get(t, where, _choice(FAILSAFE_ACTIONS), default)
        if ground and a is not None and a not in GROUND_FAILSAFE_ACTIONS:
            c.fail(where, f'ground robots cannot "{a}"; use "stop" or "hold"')
            a = None
        actions[key] = a
    low = c.get(t, "failsafe.low_battery_percent", _num(g=0.0, lt=100.0), 20.0)
    allowed = GROUND_FAILSAFE_ACTIONS if ground else STOP_ACTIONS
    on_stop = c.get(t, "failsafe.on_stop", _choice(allowed), "stop" if ground else "hold")
    heartbeat = actions["on_heartbeat_loss"]
    battery = actions["on_low_battery"]
    script = actions["on_script_error"]
    if low is None or heartbeat is None or battery is None or script is None or on_stop is None:
        return None
    return Failsafe(heartbeat, battery, script, low_battery_percent=low, on_stop=on_stop)


def _battery(c: _Checker, t: dict[str, Any] | None) -> Battery | None:
    """[battery]: the linear drain model (full > empty > 0, endurance > 0)."""
    if t is None:
        return None
    full = c.get(t, "battery.full_voltage", _POSITIVE)
    empty = c.get(t, "battery.empty_voltage", _POSITIVE)
    endurance = c.get(t, "battery.endurance_s", _POSITIVE)
    capacity = c.get(t, "battery.capacity_wh", _POSITIVE, None)
    if full is not None and empty is not None and not full > empty:
        c.fail(
            "battery.empty_voltage",
            f"must be < battery.full_voltage ({_fmt(full)}), got {_fmt(empty)}",
        )
        return None
    if None in (full, empty, endurance) or (capacity is None and "capacity_wh" in t):
        return None
    return Battery(full, empty, endurance, capacity)


def _radio(c: _Checker, t: dict[str, Any] | None) -> RadioSettings | None:
    """[radio]: an XBee needs its serial port; id_map maps XBee serials to robot ids."""
    if t is None:
        return None
    kind = c.get(t, "radio.kind", _choice(RADIO_KINDS))
    port = c.get(t, "radio.port", _str, "")
    if kind == "xbee" and port is not None and not port.strip():
        c.fail("radio.port", 'required when kind is "xbee" (the XBee serial device)')
        port = None
    # 230400 is what the XBees are configured for in the field (docs/rosbuzz.md#radio-budget).
    baud = c.get(t, "radio.baud", _whole(1, 10_000_000), 230400)
    api_mode = c.get(t, "radio.api_mode", _whole(1, 2), 2)
    udp_port = c.get(t, "radio.udp_port", _PORT, 24580)
    budget = c.get(t, "radio.per_step_budget_bytes", _whole(1, 1 << 20), 190)
    id_map = _id_map(c, t.get("id_map", {}))
    security = c.get(t, "radio.security", _choice(SECURITY_MODES), None)
    if (
        kind is None
        or port is None
        or baud is None
        or api_mode is None
        or udp_port is None
        or budget is None
        or id_map is None
    ):
        return None
    return RadioSettings(kind, port, baud, api_mode, udp_port, budget, id_map, security)


def _id_map(c: _Checker, v: Any) -> Mapping[str, int] | None:
    """radio.id_map: 16-hex-digit XBee serials -> distinct robot ids."""
    where = "radio.id_map"
    if not isinstance(v, dict):
        c.fail(where, f"must be a table of serial = id, got {_describe(v)}")
        return None
    out: dict[str, int] = {}
    owner: dict[int, str] = {}
    ok = True
    for serial, rid in v.items():
        at = f"{where}.{serial}"
        if len(serial) != 16 or not all(ch in "0123456789abcdefABCDEF" for ch in serial):
            c.fail(at, "must be an XBee 64-bit serial (16 hex digits)")
            ok = False
            continue
        i = _whole(0, MAX_ROBOT_ID)(c, at, rid)
        if i is None:
            ok = False
            continue
        key = serial.upper()
        if key in out:
            c.fail(at, "serial listed twice")
            ok = False
            continue
        if i in owner:
            c.fail(at, f"robot id {i} is already given to {owner[i]}")
            ok = False
            continue
        out[key] = i
        owner[i] = key
    return MappingProxyType(out) if ok else None


def _bool(c: _Checker, where: str, v: Any) -> bool | None:
    """A boolean."""
    if not isinstance(v, bool):
        c.fail(where, f"must be true or false, got {_describe(v)}")
        return None
    return v


def _dji(
    c: _Checker, t: dict[str, Any] | None, autopilot: AutopilotSettings | None
) -> DjiSettings | None:
    """[dji]: the Onboard SDK link's rates and encryption; only for flavour "dji"."""
    if t is None:
        return None
    if t and autopilot is not None and autopilot.flavour != "dji":
        c.fail("dji", f'only for autopilot.flavour = "dji", not {autopilot.flavour!r}')
        return None
    d = DjiSettings()
    rate = c.get(t, "dji.broadcast_hz", _int, d.broadcast_hz)
    if rate is not None and rate not in DJI_BROADCAST_RATES:
        listed = ", ".join(str(r) for r in DJI_BROADCAST_RATES)
        c.fail("dji.broadcast_hz", f"must be one of {listed} (the M100's rates), got {rate}")
        rate = None
    control = c.get(t, "dji.control_rate_hz", _num(g=0.0), d.control_rate_hz)
    if control is not None and control > 50.0:
        c.fail(
            "dji.control_rate_hz", f"must be <= 50 (the most the M100 reads), got {_fmt(control)}"
        )
        control = None
    encrypt = c.get(t, "dji.encrypt", _bool, d.encrypt)
    if rate is None or control is None or encrypt is None:
        return None
    return DjiSettings(rate, control, encrypt)


def _robot_id(c: _Checker, t: dict[str, Any] | None, radio: RadioSettings | None) -> RobotId | None:
    """[robot_id]: "config" needs a value; "xbee" needs an XBee radio with an id_map."""
    if t is None:
        return None
    source = c.get(t, "robot_id.source", _choice(ID_SOURCES), "hostname")
    if source == "config":
        value = c.get(t, "robot_id.value", _whole(0, MAX_ROBOT_ID))
        if value is None:
            return None
    else:
        value = None
        if "value" in t and source is not None:
            c.fail("robot_id.value", f'only used with source = "config", not {source!r}')
    if source == "xbee" and radio is not None:
        if radio.kind != "xbee":
            c.fail("robot_id.source", f'"xbee" needs radio.kind = "xbee", not {radio.kind!r}')
        elif not radio.id_map:
            c.fail("robot_id.source", '"xbee" needs radio.id_map to list the XBee serials')
    if source is None:
        return None
    return RobotId(source, value)


_USB_ID = re.compile(r"[0-9a-fA-F]{4}:[0-9a-fA-F]{4}")
_ABSENT: Any = object()  # an optional field left out (None means "recorded a problem")


def _usb_id(c: _Checker, where: str, v: Any) -> str | None:
    """`VENDOR:PRODUCT`, four hex digits each as `lsusb` prints them; kept lower-case."""
    s = _str(c, where, v)
    if s is not None and not _USB_ID.fullmatch(s):
        c.fail(
            where,
            "must be VENDOR:PRODUCT, four hex digits each as lsusb prints them "
            f'(e.g. "0403:6015"), got {s!r}',
        )
        return None
    return None if s is None else s.lower()


def _usb(c: _Checker, t: dict[str, Any] | None) -> UsbIds | None:
    """[usb]: optional USB ids of the serial adapters: the autopilot's, the radio's, and a
    GPS receiver's of its own."""
    if t is None:
        return None
    autopilot = c.get(t, "usb.autopilot", _usb_id, _ABSENT)
    radio = c.get(t, "usb.radio", _usb_id, _ABSENT)
    gps = c.get(t, "usb.gps", _usb_id, _ABSENT)
    if autopilot is None or radio is None or gps is None:  # a problem was recorded
        return None
    return UsbIds(
        autopilot=None if autopilot is _ABSENT else autopilot,
        radio=None if radio is _ABSENT else radio,
        gps=None if gps is _ABSENT else gps,
    )


def _gps(c: _Checker, t: dict[str, Any] | None, given: bool, clearpath: bool) -> GpsSettings | None:
    """[gps]: the receiver's port; required by a Clearpath base (its MCU has no GPS)."""
    if t is None:
        return None  # not a table: already said
    if not given:
        if clearpath:
            c.fail(
                "gps",
                'missing required table with autopilot.flavour = "clearpath" (the GPS '
                'receiver: port = "/dev/ttyUSB1", baud, protocol = "nmea")',
            )
        return None
    port = c.get(t, "gps.port", _nonempty)
    # 19200: what Clearpath's own bringup sets its NMEA receivers to (HUSKY_NAVSAT_BAUD).
    baud = c.get(t, "gps.baud", _whole(1, 10_000_000), 19200)
    protocol = c.get(t, "gps.protocol", _choice(GPS_PROTOCOLS), "nmea")
    timeout = c.get(t, "gps.timeout_s", _POSITIVE, 2.0)
    if port is None or baud is None or protocol is None or timeout is None:
        return None
    return GpsSettings(port, baud, protocol, timeout)


def _drive(
    c: _Checker, t: dict[str, Any] | None, given: bool, clearpath: bool
) -> DriveSettings | None:
    """[drive]: the differential base's geometry and turn limit (defaults: the Husky's)."""
    if t is None:
        return None  # not a table: already said
    if not given:
        return DriveSettings() if clearpath else None
    separation = c.get(t, "drive.wheel_separation_m", _POSITIVE, DriveSettings.wheel_separation_m)
    turn = c.get(t, "drive.max_turn_rate_rps", _POSITIVE, DriveSettings.max_turn_rate_rps)
    if separation is None or turn is None:
        return None
    return DriveSettings(separation, turn)
