"""The M100's OPEN protocol commands: ids, return codes, and the layout of each value.

Everything here is bytes and numbers, no state: what the host core and the simulated flight
controller both need to agree on. Facts (and which of them are unverified): the spec's §6-§9,
summarised in docs/vehicles.md.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass

# ----------------------------------------------------------------------------- commands

CMD_GET_VERSION = (0x00, 0x00)
"""Get the protocol/drone version (session 2..31, no activation needed)."""
CMD_ACTIVATE = (0x00, 0x01)
"""Activation with the app id (always unencrypted)."""
CMD_SET_BROADCAST = (0x00, 0x10)
"""Set the broadcast frequency of each item (always unencrypted)."""
CMD_CONTROL = (0x01, 0x00)
"""Obtain (1) / release (0) control authority."""
CMD_TASK = (0x01, 0x01)
"""Go home / take off / land, the M100's 2-byte form."""
CMD_TASK_QUERY = (0x01, 0x02)
"""Query a task's result (documented, unused by DJI's libraries)."""
CMD_MOVEMENT = (0x01, 0x03)
"""Movement control: flag byte and four floats, session 0, no ACK."""
CMD_ARM = (0x01, 0x05)
"""Arm (1) / disarm (0) the motors, M100 form."""
PUSH_BROADCAST = (0x02, 0x00)
"""FC -> host: broadcast flight data."""
PUSH_LOST_CONTROL = (0x02, 0x01)
"""FC -> host: control authority taken away (value 0x04)."""
PUSH_FROM_MOBILE = (0x02, 0x02)
"""FC -> host: transparent data from the mobile app."""

LOST_CONTROL_VALUE = 0x04
"""The one byte of the lost-control push."""

ENCRYPTABLE_SETS = frozenset({0x01, 0x05})
"""Command sets that follow the encryption switch (control, tasks, movement, arm, virtual
RC); version, activation and broadcast frequency (set 0x00) always go in clear."""

# ----------------------------------------------------------------------------- return codes

SUCCESS = 0x0000
"""Return code: success (its meaning depends on the command)."""
KEY_ERROR = 0xFF00
"""Return code: the encryption key is wrong."""
NO_AUTHORIZATION = 0xFF01
"""Return code: not activated."""
NO_RIGHTS = 0xFF02
"""Return code: API level insufficient."""

COMMON_CODES: Mapping[int, str] = {
    KEY_ERROR: "KEY_ERROR (the encryption key is wrong: check the app key)",
    NO_AUTHORIZATION: "NO_AUTHORIZATION (the flight controller is not activated)",
    NO_RIGHTS: "NO_RIGHTS (API level insufficient)",
}
ACTIVATION_CODES: Mapping[int, str] = {
    0x0000: "SUCCESS",
    0x0001: "PARAMETER_ERROR (check the request layout)",
    0x0002: "ENCODE_ERROR (encrypted package not recognised)",
    0x0003: "NEW_DEVICE (a new device or app id needs one online activation: connect DJI GO "
    "to the RC with Internet and retry; or the app id/key belong to another account)",
    0x0004: "DJIGO_APP_NOT_CONNECTED (the DJI GO app is not responding)",
    0x0005: "NETWORK_ERROR (the DJI GO app has no Internet)",
    0x0006: "SERVER_ACCESS_REFUSED (the server refused the app id)",
    0x0007: "ACCESS_LEVEL_ERROR (API access level insufficient)",
    0x0008: "OSDK_VERSION_ERROR (app_ver does not match the firmware)",
}
ACTIVATION_RETRY = frozenset({0x0003, 0x0004, 0x0005})
"""Activation codes worth retrying (DJI GO online activation in progress)."""
ACTIVATION_VERSION_MISMATCH = 0x0008
"""Activation code: the firmware word sent was not the FC's; query the version again."""

CONTROL_SWITCH_NOT_F = 0x0000
"""Control authority: the RC mode switch is not in F."""
CONTROL_RELEASED = 0x0001
"""Control authority: released."""
CONTROL_OBTAINED = 0x0002
"""Control authority: obtained."""
CONTROL_OBTAINING = 0x0003
"""Control authority: obtain in progress, send the request again."""
CONTROL_RELEASING = 0x0004
"""Control authority: release in progress, send the request again."""
CONTROL_IOC = 0x00C9
"""Control authority: IOC mode is on, cannot obtain."""
CONTROL_CODES: Mapping[int, str] = {
    CONTROL_SWITCH_NOT_F: "RC_MODE_NOT_F (put the RC mode switch in F)",
    CONTROL_RELEASED: "RELEASE_SUCCESS",
    CONTROL_OBTAINED: "OBTAIN_SUCCESS",
    CONTROL_OBTAINING: "OBTAIN_RUNNING",
    CONTROL_RELEASING: "RELEASE_RUNNING",
    CONTROL_IOC: "IOC_OPEN (turn IOC off in the DJI GO app)",
}

TASK_GO_HOME = 1
"""Task code: return home and land."""
TASK_TAKEOFF = 4
"""Task code: auto take-off (to about 1.2 m, then hover)."""
TASK_LAND = 6
"""Task code: auto landing."""
TASK_NAMES: Mapping[int, str] = {
    TASK_GO_HOME: "go home",
    TASK_TAKEOFF: "take-off",
    TASK_LAND: "landing",
}
TASK_FAILED = 0x0001
"""Task ACK (M100): execution failed."""
TASK_STARTED = 0x0002
"""Task ACK (M100): started executing: success."""
TASK_CODES: Mapping[int, str] = {
    TASK_FAILED: "EXECUTION_FAILED",
    TASK_STARTED: "STARTED",
}

ARM_SUCCESS = 0x0000
"""Arm/disarm ACK: done."""
ARM_NEED_CONTROL = 0x0001
"""Arm/disarm ACK: obtain control first."""
ARM_ALREADY = 0x0002
"""Arm/disarm ACK: already armed / disarmed."""
ARM_IN_AIR = 0x0003
"""Arm/disarm ACK: not possible in the air."""
ARM_CODES: Mapping[int, str] = {
    ARM_SUCCESS: "SUCCESS",
    ARM_NEED_CONTROL: "NEED_CONTROL_AUTHORITY (obtain control first)",
    ARM_ALREADY: "ALREADY_DONE (already armed or disarmed)",
    ARM_IN_AIR: "AIRCRAFT_IN_AIR_ERROR (not in the air)",
}
BROADCAST_CODES: Mapping[int, str] = {0x0000: "SUCCESS", 0x0001: "PARAMETER_ERROR"}


def code_text(code: int, table: Mapping[int, str]) -> str:
    """A return code as the field reads it: "0x0003 NEW_DEVICE (...)"."""
    name = table.get(code) or COMMON_CODES.get(code) or "unknown code"
    return f"0x{code:04X} {name}"


def return_code(value: bytes) -> int | None:
    """The 2-byte little-endian return code that starts an ACK value (None if shorter)."""
    if len(value) < 2:
        return None
    return value[0] | value[1] << 8


# ----------------------------------------------------------------------------- version

M100_FIRMWARE = 0x03010A00
"""The M100 FC firmware 3.1.10.0 word, sent back in activation."""
M100_VERSION_CRC = 0xA6453AAC
"""The "version CRC" every published M100 3.1 log shows."""
M100_VERSION_NAME = "SDK-v1.0 BETA M100-03.01.01.00"
"""The version name an M100 3.1 FC reports (its third number ten times too small)."""


@dataclass(frozen=True)
class VersionInfo:
    """What the get-version ACK says."""

    code: int  # 0x0000 activated, 0xFF01 not activated
    crc: int | None
    serial: str
    name: str
    hardware: str  # "M100"
    firmware: tuple[int, int, int, int]  # normalised: (3, 1, 10, 0)

    @property
    def firmware_word(self) -> int:
        """The firmware as the u32 activation wants: a<<24 | b<<16 | c<<8 | d."""
        a, b, c, d = self.firmware
        return (a & 0xFF) << 24 | (b & 0xFF) << 16 | (c & 0xFF) << 8 | (d & 0xFF)

    @property
    def firmware_text(self) -> str:
        """E.g. "3.1.10.0"."""
        return ".".join(str(n) for n in self.firmware)


def version_ack_value(
    code: int,
    serial: str = "0SIM000100",
    name: str = M100_VERSION_NAME,
    crc: int = M100_VERSION_CRC,
) -> bytes:
    """The get-version ACK value of an M100 FW 3.1: code, CRC, NUL-ended serial, 32-byte name."""
    return (
        struct.pack("<HI", code, crc)
        + serial.encode("ascii")
        + b"\x00"
        + name.encode("ascii")[:32].ljust(32, b"\x00")
    )


def parse_version_ack(value: bytes) -> VersionInfo:
    """Read a get-version ACK value as DJI's host does (spec §7.1); ValueError if it cannot.

    After the return code, the bytes up to the first NUL are "CRC and serial" (the first 4
    the CRC, on this firmware); the name follows. The hardware name runs from after the
    name's second space to its '-', then four dotted numbers; an M100 reports its third
    number ten times too small.
    """
    code = return_code(value)
    if code is None:
        raise ValueError("version ACK shorter than its return code")
    rest = value[2:]
    nul = rest.find(b"\x00")
    if nul < 0:
        raise ValueError("version ACK without the NUL that ends the serial number")
    head, tail = rest[:nul], rest[nul + 1 :]
    crc = int.from_bytes(head[:4], "little") if len(head) >= 4 else None
    serial = head[4:].decode("ascii", "replace")
    name = tail[:32].split(b"\x00", 1)[0].decode("ascii", "replace")
    words = name.split(" ", 2)
    if len(words) < 3:
        raise ValueError(f"version name {name!r} is not 'SDK-vX BETA HW-aa.bb.cc.dd'")
    hardware, sep, numbers = words[2].partition("-")
    parts = numbers.split(".")
    if not sep or len(parts) != 4 or not all(p.isdigit() for p in parts):
        raise ValueError(f"version name {name!r} has no HW-aa.bb.cc.dd firmware")
    a, b, c, d = (int(p) for p in parts)
    if hardware.startswith("M100"):
        c *= 10  # "03.01.01.00" is firmware 3.1.10.0
    return VersionInfo(code, crc, serial, name, hardware, (a, b, c, d))


# ----------------------------------------------------------------------------- activation

API_LEVEL = 2
"""The access level DJI's 3.x libraries ask for (flight control)."""
BUNDLE_ID = b"0" * 32
"""The bundle id DJI's 3.x libraries send (its content is apparently not checked)."""
ACTIVATION_LEN = 44
"""Bytes of the activation value."""


def activation_value(
    app_id: int, app_ver: int = M100_FIRMWARE, api_level: int = API_LEVEL
) -> bytes:
    """The activation request: app id, API level, firmware word, bundle id."""
    return struct.pack("<III", app_id & 0xFFFFFFFF, api_level, app_ver) + BUNDLE_ID


def parse_activation(value: bytes) -> tuple[int, int, int]:
    """(app id, API level, firmware word) of an activation request; ValueError if malformed."""
    if len(value) != ACTIVATION_LEN:
        raise ValueError(f"activation value of {len(value)} bytes, not {ACTIVATION_LEN}")
    app_id, level, ver = struct.unpack_from("<III", value)
    return app_id, level, ver


# ----------------------------------------------------------------------------- broadcast

ITEMS = (
    "timestamp",
    "quaternion",
    "acceleration",
    "velocity",
    "angular_rate",
    "position",
    "magnetometer",
    "rc",
    "gimbal",
    "flight_status",
    "battery",
    "control",
)
"""The M100's broadcast items, in flag-bit order (bit 0 first)."""
_ITEM_FORMATS = (
    struct.Struct("<IIB"),  # time (1/400 s ticks), nanoseconds, sync flag
    struct.Struct("<ffff"),  # q0 (w), q1, q2, q3
    struct.Struct("<fff"),
    struct.Struct("<fffB"),  # x north, y east, z (up: see VELOCITY_Z_UP), status
    struct.Struct("<fff"),
    struct.Struct("<ddffB"),  # lat, lon (radians), altitude, height, GPS health
    struct.Struct("<hhh"),
    struct.Struct("<hhhhhh"),  # roll, pitch, yaw, throttle, mode, gear
    struct.Struct("<fffB"),
    struct.Struct("<B"),
    struct.Struct("<B"),
    struct.Struct("<BB"),  # current control mode, device bits
)
ITEM_SIZES = tuple(s.size for s in _ITEM_FORMATS)
"""Bytes of each item (122 with all twelve)."""
VELOCITY_Z_UP = True
"""The broadcast vertical velocity is taken as up-positive, like the control inputs. DJI
documents the sign for control only (spec §15.5): one constant, so a check on hardware
changes one line, and host and simulator agree."""

RATE_CODES: Mapping[int, int] = {0: 0, 1: 1, 10: 2, 50: 3, 100: 4}
"""Broadcast frequency in Hz -> the code set-broadcast-frequency sends."""
RATE_KEEP = 5
"""Frequency code: keep the current rate."""
CODE_RATES: Mapping[int, float] = {0: 0.0, 1: 1.0, 2: 10.0, 3: 50.0, 4: 100.0}
"""Frequency code -> Hz (5, keep, has no rate of its own)."""
FREQUENCY_SLOTS = 16
"""Set-broadcast-frequency sends 16 codes; the M100 uses the first 12."""

RC_P = -8000
"""RC mode channel: P."""
RC_A = 0
"""RC mode channel: A."""
RC_F = 8000
"""RC mode channel: F, the position the SDK needs for control authority."""
RC_MODES: Mapping[int, str] = {RC_P: "P", RC_A: "A", RC_F: "F"}
"""RC mode channel value -> switch position."""

DEVICE_RC = 0
"""Control info device: the remote controller."""
DEVICE_APP = 1
"""Control info device: the mobile app."""
DEVICE_ONBOARD = 2
"""Control info device: the onboard computer (this host)."""
DEVICE_MASK = 0x07
"""Control info device bits 0..2."""
DEVICE_SDK_OPEN = 0x08
"""Control info bit 3: onboard SDK control requested/open."""

STATUS_STANDBY = 1
"""M100 flight status: on the ground."""
STATUS_TAKING_OFF = 2
"""M100 flight status: taking off."""
STATUS_IN_AIR = 3
"""M100 flight status: in the air."""
STATUS_LANDING = 4
"""M100 flight status: landing."""
STATUS_LANDED = 5
"""M100 flight status: touched down (standby about 2 s later)."""
STATUS_NAMES: Mapping[int, str] = {
    STATUS_STANDBY: "standby",
    STATUS_TAKING_OFF: "taking off",
    STATUS_IN_AIR: "in the air",
    STATUS_LANDING: "landing",
    STATUS_LANDED: "landed",
}


@dataclass
class Broadcast:
    """One broadcast push: the items it carries (None: not in this frame)."""

    timestamp: tuple[int, int, int] | None = None
    quaternion: tuple[float, float, float, float] | None = None
    acceleration: tuple[float, float, float] | None = None
    velocity: tuple[float, float, float, int] | None = None
    angular_rate: tuple[float, float, float] | None = None
    position: tuple[float, float, float, float, int] | None = None
    magnetometer: tuple[int, int, int] | None = None
    rc: tuple[int, int, int, int, int, int] | None = None
    gimbal: tuple[float, float, float, int] | None = None
    flight_status: tuple[int] | None = None
    battery: tuple[int] | None = None
    control: tuple[int, int] | None = None

    @property
    def flag(self) -> int:
        """The u16 flag: one bit per item present."""
        return sum(1 << i for i, name in enumerate(ITEMS) if getattr(self, name) is not None)

    def encode(self) -> bytes:
        """The push's value: the flag, then each item present, packed in bit order."""
        out = [self.flag.to_bytes(2, "little")]
        for name, fmt in zip(ITEMS, _ITEM_FORMATS, strict=True):
            item = getattr(self, name)
            if item is not None:
                out.append(fmt.pack(*item))
        return b"".join(out)


def parse_broadcast(value: bytes) -> Broadcast:
    """The items of a broadcast push value (after SET and ID); ValueError if it is short.

    Bits 12..15 are reserved on the M100: items behind them are not read.
    """
    if len(value) < 2:
        raise ValueError("broadcast shorter than its flag")
    flag = value[0] | value[1] << 8
    b = Broadcast()
    at = 2
    for i, (name, fmt) in enumerate(zip(ITEMS, _ITEM_FORMATS, strict=True)):
        if not flag >> i & 1:
            continue
        if at + fmt.size > len(value):
            raise ValueError(
                f"broadcast flag 0x{flag:04x} wants item {name} at byte {at}, "
                f"but the value has {len(value)} bytes"
            )
        setattr(b, name, fmt.unpack_from(value, at))
        at += fmt.size
    return b


def frequency_value(codes: list[int]) -> bytes:
    """The set-broadcast-frequency value: 16 codes, unused slots 0."""
    if len(codes) > FREQUENCY_SLOTS:
        raise ValueError(f"at most {FREQUENCY_SLOTS} frequency codes, got {len(codes)}")
    return bytes(codes) + bytes(FREQUENCY_SLOTS - len(codes))


def quaternion_yaw(q0: float, q1: float, q2: float, q3: float) -> float:
    """Yaw (radians, 0 north, positive toward east) of the ground(NED)-to-body quaternion."""
    return math.atan2(2.0 * (q0 * q3 + q1 * q2), 1.0 - 2.0 * (q2 * q2 + q3 * q3))


def yaw_quaternion(yaw: float) -> tuple[float, float, float, float]:
    """The level attitude with `yaw` (radians from north, toward east) as a quaternion."""
    return (math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0))


# ----------------------------------------------------------------------------- movement

HORI_ANGLE = 0x00
"""Flag bits 7..6: roll/pitch angles (degrees)."""
HORI_VEL = 0x40
"""Flag bits 7..6: horizontal velocity (m/s)."""
HORI_POS = 0x80
"""Flag bits 7..6: horizontal position offset from where it is (m)."""
VERT_VEL = 0x00
"""Flag bits 5..4: vertical velocity (m/s, up positive)."""
VERT_POS = 0x10
"""Flag bits 5..4: height (m)."""
VERT_THRUST = 0x20
"""Flag bits 5..4: thrust (%)."""
YAW_ANGLE = 0x00
"""Flag bit 3: yaw angle (degrees, north 0, east +90)."""
YAW_RATE = 0x08
"""Flag bit 3: yaw rate (degrees/s)."""
FRAME_GROUND = 0x00
"""Flag bits 2..1: ground frame (x north, y east)."""
FRAME_BODY = 0x02
"""Flag bits 2..1: body frame (x forward, y right)."""
STABLE = 0x01
"""Flag bit 0: stable mode (hold position when the horizontal input is zero)."""

FLAG_POSITION = HORI_POS | VERT_POS | YAW_ANGLE | FRAME_GROUND | STABLE
"""0x91: position offset, height, yaw angle, ground frame, stable (DJI's positionAndYawCtrl)."""
FLAG_HOVER = HORI_VEL | VERT_VEL | YAW_RATE | FRAME_GROUND | STABLE
"""0x49: zero velocities and yaw rate in stable mode: brake and hold where it is."""
MOVEMENT_LEN = 17
"""Bytes of a movement-control value."""

_MOVEMENT = struct.Struct("<Bffff")


@dataclass(frozen=True)
class Movement:
    """A movement-control setpoint: the flag byte and x, y, z, yaw in its units."""

    flag: int
    x: float
    y: float
    z: float
    yaw: float

    def encode(self) -> bytes:
        """The 17-byte value."""
        return _MOVEMENT.pack(self.flag, self.x, self.y, self.z, self.yaw)

    @property
    def horizontal(self) -> int:
        """Flag bits 7..6 as 0 angle, 1 velocity, 2 position, 3 rate."""
        return self.flag >> 6 & 3

    @property
    def vertical(self) -> int:
        """Flag bits 5..4 as 0 velocity, 1 position, 2 thrust."""
        return self.flag >> 4 & 3

    @property
    def yaw_rate(self) -> bool:
        """Whether yaw is a rate (else an angle)."""
        return bool(self.flag & YAW_RATE)

    @property
    def body(self) -> bool:
        """Whether x, y are in the body frame (else ground: north, east)."""
        return bool(self.flag & FRAME_BODY)

    @property
    def control_mode(self) -> int:
        """The broadcast's control-mode number for this flag: 1 + 6V + 2H + Y (spec §8.2)."""
        return 1 + 6 * self.vertical + 2 * self.horizontal + (1 if self.yaw_rate else 0)


def parse_movement(value: bytes) -> Movement:
    """A movement-control value; ValueError unless it is 17 bytes."""
    if len(value) != MOVEMENT_LEN:
        raise ValueError(f"movement control value of {len(value)} bytes, not {MOVEMENT_LEN}")
    return Movement(*_MOVEMENT.unpack(value))


#: Expected CMD VAL lengths of the host's commands, for a receiver's checks.
VALUE_LENGTHS: Mapping[tuple[int, int], int] = {
    CMD_GET_VERSION: 1,
    CMD_ACTIVATE: ACTIVATION_LEN,
    CMD_SET_BROADCAST: FREQUENCY_SLOTS,
    CMD_CONTROL: 1,
    CMD_TASK: 2,
    CMD_TASK_QUERY: 1,
    CMD_MOVEMENT: MOVEMENT_LEN,
    CMD_ARM: 1,
}
