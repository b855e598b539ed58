"""The Clearpath MCU's messages: type codes, and the payloads a node and a simulated MCU use.

    set_diff_speed(0.5, 0.5, 5.0, 5.0)        # a Frame: both wheel speeds (m/s), then accels
    request(ENCODERS, 0)                      # "send the encoder data once, now"
    decode(frame)                             # Encoders(...), Ack(...), SafetyStatus(...)...
    fields(frame)                             # a JSON-able dict, names as in the spec

Real values travel as scaled integers (spec section 4): `raw = value x scale` truncated toward
zero, as the reference's C cast does (0.29 m/s x 100 is 28, not 29). The reference wraps an
out-of-range value silently; here it is clamped to the field first, so a wild speed can never
become a wild speed the other way. Speeds, accelerations, volts, amps, degrees and charge
travel x100; encoder travel and speed, and orientation, x1000.

A data payload whose length is not the one its counts imply is a `PayloadError` (the
reference raises too); the core counts it as a bad frame.
"""

from __future__ import annotations

import math
import struct
from dataclasses import asdict, dataclass
from enum import IntEnum
from typing import Any

from fieldkit.vehicle.clearpath.frame import Frame, parse_frame


class MsgType(IntEnum):
    """Message type codes (spec section 5) this package sends, answers or reads."""

    # set / command (host -> MCU)
    SET_PLATFORM_NAME = 0x0002
    SET_PLATFORM_TIME = 0x0005
    SET_SAFETY_SYSTEM = 0x0010
    SET_DIFF_SPEED = 0x0200
    SET_DIFF_CONTROL = 0x0201
    SET_DIFF_OUTPUT = 0x0202
    SET_ACKERMANN = 0x0203
    SET_VELOCITY = 0x0204
    SET_TURN = 0x0205
    SET_MAX_SPEED = 0x0210
    SET_MAX_ACCEL = 0x0211
    SET_GEAR = 0x0212
    PROCESSOR_RESET = 0x2000
    RESTORE_SETTINGS = 0x2001
    STORE_SETTINGS = 0x2002
    # requests (host -> MCU): data type - 0x4000
    REQ_ECHO = 0x4000
    REQ_PLATFORM_INFO = 0x4001
    REQ_PLATFORM_NAME = 0x4002
    REQ_FIRMWARE_INFO = 0x4003
    REQ_SYSTEM_STATUS = 0x4004
    REQ_POWER_SYSTEM = 0x4005
    REQ_SAFETY_SYSTEM = 0x4010
    REQ_DIFF_SPEED = 0x4200
    REQ_MAX_SPEED = 0x4210
    REQ_MAX_ACCEL = 0x4211
    REQ_ORIENTATION = 0x4600
    REQ_ENCODERS = 0x4800
    REQ_RAW_ENCODERS = 0x4801
    # data (MCU -> host)
    ECHO = 0x8000
    PLATFORM_INFO = 0x8001
    PLATFORM_NAME = 0x8002
    FIRMWARE_INFO = 0x8003
    SYSTEM_STATUS = 0x8004
    POWER_SYSTEM = 0x8005
    PROCESSOR_STATUS = 0x8006
    SAFETY_SYSTEM = 0x8010
    DIFF_SPEED = 0x8200
    DIFF_OUTPUT = 0x8202
    VELOCITY = 0x8204
    MAX_SPEED = 0x8210
    MAX_ACCEL = 0x8211
    ORIENTATION = 0x8600
    ROTATION_RATE = 0x8601
    ACCELERATION = 0x8602
    MAGNETOMETER = 0x8606
    ENCODERS = 0x8800
    RAW_ENCODERS = 0x8801


REQUEST_OFFSET = 0x4000
"""request type = data type - 0x4000."""
ONCE = 0
"""A request's frequency that asks for the data once, now."""
UNSUBSCRIBE = 0xFFFF
"""A request's frequency that cancels a subscription."""
PASS_CODE = 0x3A18
"""The pass code of processor reset, restore and store settings."""

# Acknowledgement result bits (section 6.3).
ACK_BAD_CHECKSUM = 0x0001
ACK_BAD_TYPE = 0x0002
ACK_BAD_FORMAT = 0x0004
ACK_RANGE = 0x0008
ACK_NO_BANDWIDTH = 0x0010
ACK_OVER_FREQ = 0x0020
ACK_OVER_SUBSCRIBE = 0x0040
ACK_BITS: dict[int, str] = {
    ACK_BAD_CHECKSUM: "bad checksum",
    ACK_BAD_TYPE: "unsupported message type",
    ACK_BAD_FORMAT: "bad message format",
    ACK_RANGE: "value out of range",
    ACK_NO_BANDWIDTH: "not enough bandwidth",
    ACK_OVER_FREQ: "subscription frequency too high",
    ACK_OVER_SUBSCRIBE: "too many subscriptions",
}
"""Acknowledgement result bits and what they mean."""

# Safety system flags (section 6.5), as HuskyStatus names them.
SAFETY_TIMEOUT = 0x0001
SAFETY_LOCKOUT = 0x0002
SAFETY_ESTOP = 0x0008
SAFETY_ROS_PAUSE = 0x0010
SAFETY_NO_BATTERY = 0x0020
SAFETY_CURRENT_LIMIT = 0x0040
SAFETY_FLAGS: dict[int, str] = {
    SAFETY_TIMEOUT: "timeout",
    SAFETY_LOCKOUT: "lockout",
    SAFETY_ESTOP: "e_stop",
    SAFETY_ROS_PAUSE: "ros_pause",
    SAFETY_NO_BATTERY: "no_battery",
    SAFETY_CURRENT_LIMIT: "current_limit",
}
"""Safety flags and their HuskyStatus names."""
NO_MOTION = (
    SAFETY_TIMEOUT
    | SAFETY_LOCKOUT
    | SAFETY_ESTOP
    | SAFETY_ROS_PAUSE
    | SAFETY_NO_BATTERY
    | SAFETY_CURRENT_LIMIT
)
"""Flags under which the base will not move whatever it is told (spec section 8)."""


class PayloadError(ValueError):
    """A payload whose length or layout does not fit its message type."""


def name_of(type_: int) -> str:
    """A type code's name, e.g. "SET_DIFF_SPEED"; "0x1234" for codes we do not know."""
    try:
        return MsgType(type_).name
    except ValueError:
        return f"0x{type_:04X}"


def flag_names(flags: int, names: dict[int, str]) -> list[str]:
    """The names of the bits set in `flags` (unknown bits as "bit N")."""
    out = [name for bit, name in names.items() if flags & bit]
    known = 0
    for bit in names:
        known |= bit
    rest = flags & ~known
    out += [f"bit {i}" for i in range(16) if rest >> i & 1]
    return out


# ------------------------------------------------------------------ scaled numbers


def raw(value: float, scale: float, size: int = 2) -> int:
    """`value x scale` truncated toward zero and clamped to a signed field of `size` bytes."""
    top = (1 << (8 * size - 1)) - 1
    x = value * scale
    if math.isnan(x):
        return 0
    if x >= top:
        return top
    if x <= -top - 1:
        return -top - 1
    return math.trunc(x)


def _s16s(values: tuple[float, ...], scale: float) -> bytes:
    return struct.pack(f"<{len(values)}h", *(raw(v, scale) for v in values))


# ------------------------------------------------------------------ host -> MCU


def set_diff_speed(left: float, right: float, left_accel: float, right_accel: float) -> Frame:
    """Set differential wheel speeds (m/s) with their accelerations (m/s²): the drive order."""
    return Frame(MsgType.SET_DIFF_SPEED, _s16s((left, right, left_accel, right_accel), 100))


def set_max_speed(forward: float, reverse: float) -> Frame:
    """The MCU's own speed limit (m/s) forward and in reverse."""
    return Frame(MsgType.SET_MAX_SPEED, _s16s((forward, reverse), 100))


def set_max_accel(forward: float, reverse: float) -> Frame:
    """The MCU's own acceleration limit (m/s²) forward and in reverse."""
    return Frame(MsgType.SET_MAX_ACCEL, _s16s((forward, reverse), 100))


def request(data_type: int, frequency: int = ONCE) -> Frame:
    """Ask for data type `data_type` (or give its request code): once (0), at that many Hz, or
    stop a subscription (0xFFFF)."""
    code = data_type - REQUEST_OFFSET if data_type >= 0x8000 else data_type
    return Frame(code, struct.pack("<H", frequency & 0xFFFF))


# ------------------------------------------------------------------ decoded payloads


@dataclass(frozen=True, slots=True)
class Ack:
    """The MCU's answer to a command or request: its type echoed, 0 = accepted."""

    type: int
    result: int

    @property
    def ok(self) -> bool:
        """Whether the command was accepted."""
        return self.result == 0

    def reason(self) -> str:
        """The refusal in words, e.g. "value out of range"."""
        return ", ".join(flag_names(self.result, ACK_BITS)) or "accepted"


@dataclass(frozen=True, slots=True)
class Encoders:
    """Cumulative travel (m) and speed (m/s) of each encoder: index 0 left, 1 right."""

    travel: tuple[float, ...]
    speed: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class DiffSpeeds:
    """Wheel speeds (m/s) and accelerations (m/s²), as set or as measured."""

    left: float
    right: float
    left_accel: float
    right_accel: float


@dataclass(frozen=True, slots=True)
class SystemStatus:
    """Uptime, and the voltages (battery, left driver, right driver), currents and
    temperatures the MCU measures."""

    uptime_ms: int
    voltages: tuple[float, ...]
    currents: tuple[float, ...]
    temperatures: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class PowerSystem:
    """Per battery: charge (0..1), capacity (Wh) and description byte."""

    charges: tuple[float, ...]
    capacities: tuple[int, ...]
    descriptions: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class SafetyStatus:
    """The safety flags (SAFETY_*)."""

    flags: int

    @property
    def names(self) -> list[str]:
        """The flags set, by their HuskyStatus names."""
        return flag_names(self.flags, SAFETY_FLAGS)


@dataclass(frozen=True, slots=True)
class PlatformInfo:
    """Model string, revision and serial number."""

    model: str
    revision: int
    serial: int


@dataclass(frozen=True, slots=True)
class FirmwareInfo:
    """Firmware and protocol versions, and the build's write time (packed bits)."""

    firmware: tuple[int, int]
    protocol: tuple[int, int]
    write_time: int


@dataclass(frozen=True, slots=True)
class Triple:
    """Three values: roll, pitch, yaw (rad) for orientation; x, y, z for the others."""

    a: float
    b: float
    c: float


@dataclass(frozen=True, slots=True)
class Limits:
    """Forward and reverse limits (max speed m/s, max accel m/s²)."""

    forward: float
    reverse: float


@dataclass(frozen=True, slots=True)
class Request:
    """A request as the MCU sees it: which data, how often (0 once, 0xFFFF stop)."""

    data_type: int
    frequency: int


Decoded = (
    Ack
    | Encoders
    | DiffSpeeds
    | SystemStatus
    | PowerSystem
    | SafetyStatus
    | PlatformInfo
    | FirmwareInfo
    | Triple
    | Limits
    | Request
)


def _need(payload: bytes, n: int, what: str) -> None:
    if len(payload) != n:
        raise PayloadError(f"{what}: {len(payload)} payload bytes, its layout needs {n}")


def _counted(payload: bytes, at: int, width: int, what: str) -> int:
    """The count byte at `at`, checked against what is left (width bytes per entry)."""
    if at >= len(payload):
        raise PayloadError(f"{what}: payload ends before its count byte")
    n = payload[at]
    if len(payload) < at + 1 + width * n:
        raise PayloadError(f"{what}: count {n} needs {width * n} bytes after it")
    return n


def _encoders(p: bytes) -> Encoders:
    n = _counted(p, 0, 6, "encoders")
    _need(p, 1 + 6 * n, "encoders")
    travel = struct.unpack_from(f"<{n}i", p, 1)
    speed = struct.unpack_from(f"<{n}h", p, 1 + 4 * n)
    return Encoders(tuple(t / 1000 for t in travel), tuple(s / 1000 for s in speed))


def _system_status(p: bytes) -> SystemStatus:
    if len(p) < 5:
        raise PayloadError(f"system status: {len(p)} payload bytes, at least 7 needed")
    uptime = struct.unpack_from("<I", p)[0]
    at = 4
    groups: list[tuple[float, ...]] = []
    for what in ("voltages", "currents", "temperatures"):
        n = _counted(p, at, 2, f"system status {what}")
        groups.append(tuple(v / 100 for v in struct.unpack_from(f"<{n}h", p, at + 1)))
        at += 1 + 2 * n
    if at != len(p):
        raise PayloadError(f"system status: {len(p) - at} bytes past its temperatures")
    return SystemStatus(uptime, *groups)


def _power(p: bytes) -> PowerSystem:
    n = _counted(p, 0, 5, "power system")
    _need(p, 1 + 5 * n, "power system")
    charges = struct.unpack_from(f"<{n}h", p, 1)
    caps = struct.unpack_from(f"<{n}h", p, 1 + 2 * n)
    desc = tuple(p[1 + 4 * n : 1 + 5 * n])
    return PowerSystem(tuple(c / 100 for c in charges), tuple(caps), desc)


def _platform_info(p: bytes) -> PlatformInfo:
    n = _counted(p, 0, 1, "platform info")
    _need(p, n + 6, "platform info")
    model = p[1 : 1 + n].decode("ascii", "replace")
    revision, serial = struct.unpack_from("<BI", p, 1 + n)
    return PlatformInfo(model, revision, serial)


def _firmware(p: bytes) -> FirmwareInfo:
    _need(p, 8, "firmware info")
    a, b, c, d, t = struct.unpack("<BBBBI", p)
    return FirmwareInfo((a, b), (c, d), t)


def _s16_values(p: bytes, n: int, scale: float, what: str) -> tuple[float, ...]:
    _need(p, 2 * n, what)
    return tuple(v / scale for v in struct.unpack(f"<{n}h", p))


def decode_data(type_: int, payload: bytes) -> Decoded | None:
    """A data message's payload (type >= 0x8000), decoded; None for kinds we do not read.
    PayloadError for a payload that does not fit its type."""
    p = bytes(payload)
    if type_ == MsgType.ENCODERS:
        return _encoders(p)
    if type_ == MsgType.DIFF_SPEED:
        return DiffSpeeds(*_s16_values(p, 4, 100, "differential speeds"))
    if type_ == MsgType.SYSTEM_STATUS:
        return _system_status(p)
    if type_ == MsgType.POWER_SYSTEM:
        return _power(p)
    if type_ == MsgType.SAFETY_SYSTEM:
        _need(p, 2, "safety system")
        return SafetyStatus(struct.unpack("<H", p)[0])
    if type_ == MsgType.PLATFORM_INFO:
        return _platform_info(p)
    if type_ == MsgType.FIRMWARE_INFO:
        return _firmware(p)
    if type_ in (MsgType.ORIENTATION, MsgType.ROTATION_RATE, MsgType.ACCELERATION):
        return Triple(*_s16_values(p, 3, 1000, name_of(type_).lower()))
    if type_ == MsgType.MAGNETOMETER:
        return Triple(*_s16_values(p, 3, 1000, "magnetometer"))
    if type_ in (MsgType.MAX_SPEED, MsgType.MAX_ACCEL):
        return Limits(*_s16_values(p, 2, 100, name_of(type_).lower()))
    return None


def decode(frame: Frame) -> Decoded | None:
    """A frame from the MCU decoded: data (type >= 0x8000) or an acknowledgement (type
    below, 2-byte result); None for data kinds we do not read. PayloadError if malformed."""
    if frame.is_data:
        return decode_data(frame.type, frame.payload)
    _need(frame.payload, 2, f"acknowledgement of {name_of(frame.type)}")
    return Ack(frame.type, struct.unpack("<H", frame.payload)[0])


def decode_command(frame: Frame) -> Decoded | None:
    """A frame from the host decoded (what the MCU reads): a request, or a command's values;
    None for commands we do not model. PayloadError if malformed."""
    t, p = frame.type, frame.payload
    if REQUEST_OFFSET <= t < 0x8000:
        _need(p, 2, f"request {name_of(t)}")
        return Request(t + REQUEST_OFFSET, struct.unpack("<H", p)[0])
    if t == MsgType.SET_DIFF_SPEED:
        return DiffSpeeds(*_s16_values(p, 4, 100, "set differential speed"))
    if t in (MsgType.SET_MAX_SPEED, MsgType.SET_MAX_ACCEL):
        return Limits(*_s16_values(p, 2, 100, name_of(t).lower()))
    if t == MsgType.SET_SAFETY_SYSTEM:
        _need(p, 2, "set safety system")
        return SafetyStatus(struct.unpack("<H", p)[0])
    return None


# ------------------------------------------------------------------ MCU -> host (the sim's)


def ack(type_: int, result: int = 0, timestamp: int = 0) -> Frame:
    """The MCU's acknowledgement of a command or request of type `type_`."""
    return Frame(type_, struct.pack("<H", result), 0, timestamp)


def encoders(travel: tuple[float, ...], speed: tuple[float, ...], timestamp: int = 0) -> Frame:
    """Encoder data: travel (m, cumulative) and speed (m/s) per encoder."""
    n = len(travel)
    body = bytes((n,)) + struct.pack(
        f"<{n}i{n}h", *(raw(t, 1000, 4) for t in travel), *(raw(s, 1000) for s in speed)
    )
    return Frame(MsgType.ENCODERS, body, 0, timestamp)


def diff_speeds(speeds: DiffSpeeds, timestamp: int = 0) -> Frame:
    """Measured wheel speeds and accelerations."""
    values = (speeds.left, speeds.right, speeds.left_accel, speeds.right_accel)
    return Frame(MsgType.DIFF_SPEED, _s16s(values, 100), 0, timestamp)


def system_status(s: SystemStatus, timestamp: int = 0) -> Frame:
    """Uptime, voltages, currents, temperatures."""
    body = struct.pack("<I", s.uptime_ms & 0xFFFFFFFF)
    for group in (s.voltages, s.currents, s.temperatures):
        body += bytes((len(group),)) + _s16s(group, 100)
    return Frame(MsgType.SYSTEM_STATUS, body, 0, timestamp)


def power_system(p: PowerSystem, timestamp: int = 0) -> Frame:
    """Charge (0..1), capacity (Wh) and description of each battery."""
    n = len(p.charges)
    body = bytes((n,)) + _s16s(p.charges, 100)
    body += struct.pack(f"<{n}h", *p.capacities) + bytes(p.descriptions)
    return Frame(MsgType.POWER_SYSTEM, body, 0, timestamp)


def safety_status(flags: int, timestamp: int = 0) -> Frame:
    """The safety flags."""
    return Frame(MsgType.SAFETY_SYSTEM, struct.pack("<H", flags), 0, timestamp)


def platform_info(info: PlatformInfo, timestamp: int = 0) -> Frame:
    """Model, revision, serial."""
    model = info.model.encode("ascii", "replace")[:200]
    body = bytes((len(model),)) + model + struct.pack("<BI", info.revision, info.serial)
    return Frame(MsgType.PLATFORM_INFO, body, 0, timestamp)


def triple(type_: int, values: Triple, timestamp: int = 0) -> Frame:
    """Orientation (rad) and the other three-value IMU messages, x1000."""
    return Frame(type_, _s16s((values.a, values.b, values.c), 1000), 0, timestamp)


# ------------------------------------------------------------------ inspection


def fields(frame: Frame, *, from_host: bool | None = None) -> dict[str, Any]:
    """A frame as a JSON-able dict: `type`, `name`, `flags`, `timestamp`, `version` and
    `payload` decoded (its hex too). `from_host` says which way it went; by default types
    below 0x8000 read as host frames except 2-byte ones in the command range (acks)."""
    out: dict[str, Any] = {
        "type": f"0x{frame.type:04X}",
        "name": name_of(frame.type),
        "flags": frame.flags,
        "timestamp": frame.timestamp,
        "version": frame.version,
        "payload_hex": frame.payload.hex(),
    }
    host = from_host
    if host is None:
        host = not frame.is_data and (frame.type >= REQUEST_OFFSET or len(frame.payload) != 2)
    try:
        value = decode_command(frame) if host else decode(frame)
    except PayloadError as e:
        out["payload"] = None
        out["error"] = str(e)
        return out
    payload: Any = None
    if value is not None:
        payload = asdict(value)
        if isinstance(value, SafetyStatus):
            payload["names"] = value.names
        elif isinstance(value, Ack):
            payload["accepted"] = value.ok
            payload["reason"] = value.reason()
        elif isinstance(value, Request):
            payload["data_name"] = name_of(value.data_type)
    out["payload"] = payload
    return out


def describe_frame(data: bytes) -> dict[str, Any]:
    """`fieldkit frames decode clearpath`: `fields` of exactly one frame; FrameError (from
    `parse_frame`) naming the first bad byte."""
    return fields(parse_frame(data))
