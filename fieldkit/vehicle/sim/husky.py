"""A simulated Clearpath Husky without I/O: the MCU's serial protocol and a GPS receiver.

    sim = SimHusky(load_profile("husky"), home=(45.5017, -73.5673))
    sim.mcu.receive_data(bytes_from_the_node)    # set speed, requests, limits...
    sim.step(0.02)                               # physics, watchdog, GPS when due
    write_mcu(sim.mcu.data_to_send())            # acknowledgements, data, subscriptions
    write_gps(sim.gps.data_to_send())            # GGA + RMC sentences (or UBX NAV-PVT)

No Husky is at hand, so this stands in for one, built from the protocol facts of the spec
(/shared/spec/clearpath-husky.md); `fieldkit.vehicle.sim.husky_pty.SimHuskyPorts` puts it on
two ptys for `fieldkit vehicle-sim --profile husky`. The MCU:

- acknowledges every frame whose FLAGS ask for it, with the frame's own type and a result:
  0, or BAD_FORMAT (payload does not fit), BAD_TYPE (a kind it does not do), RANGE (a negative
  limit), OVER_FREQ (a subscription above `max_subscription_hz`);
- set differential speed (0x0200): the wheels ramp to the speeds at the given accelerations,
  within the max speed and max acceleration set by 0x0210 / 0x0211 (defaults: the profile's
  speed, 5 m/s² as husky_base sends);
- requests: frequency 0 answers the data once, 1..max subscribes, 0xFFFF unsubscribes;
  encoders, differential speeds, system status, power, safety, platform info, firmware info,
  max speed and max accel; orientation only with `imu=True`;
- the command watchdog: no speed command for `watchdog_s` (0.5 s: an assumption, the real
  timeout is not documented) and the wheels brake to a stop and safety flag 0x0001 (timeout)
  is set, until the next speed command;
- e-stop (`faults.estop`): safety flag 0x0008, the wheels brake and ignore commands.

The GPS emits `talker`GGA and RMC (NMEA, through pynmea2) or NAV-PVT (UBX, through pyubx2) at
`gps_rate_hz`, with no fix until `gps_fix_delay_s`; `faults.gps_fix = False` drops the fix
(GGA quality 0, RMC V), `faults.gps_silent` stops it, `gps_garbage(n)` puts n noise bytes on
the line. Positions come from the shared differential-drive model
(`fieldkit.vehicle.diffdrive.DiffDrive`) in a `geo.LocalFrame` at `home`; the battery drains
with the profile's linear model. Deterministic: the same inputs and steps give the same bytes.
"""

from __future__ import annotations

import datetime
import logging
import math
import random
import struct
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypedDict

import pyubx2

from fieldkit.errors import FieldkitError
from fieldkit.robot.geo import DEFAULT_HOME, LocalFrame
from fieldkit.robot.profiles import DriveSettings, Profile
from fieldkit.vehicle.clearpath import messages as M
from fieldkit.vehicle.clearpath.frame import NO_ACK, Frame, FrameReader
from fieldkit.vehicle.clearpath.gps import KNOT_MPS, nmea_lat, nmea_lon, sentence
from fieldkit.vehicle.diffdrive import DiffDrive

_log = logging.getLogger("fieldkit.vehicle_sim")

#: When the simulated GPS's clock starts (its UTC time is this plus the simulated time).
GPS_EPOCH = datetime.datetime(2026, 1, 1, tzinfo=datetime.UTC)
#: The MCU's default acceleration limit: what husky_base sends (spec section 9).
DEFAULT_MAX_ACCEL = 5.0
#: Platform info the simulated MCU gives (the real model string is not known: illustrative).
PLATFORM = M.PlatformInfo("A200", 1, 1234)
#: Ground speed above which the course over ground is given.
_COURSE_MPS = 0.05


class HuskySimError(FieldkitError):
    """The simulated Husky cannot start (a bad home, a port it cannot open)."""


@dataclass
class HuskyFaults:
    """What goes wrong, switched on and off by tests at any step."""

    mcu_silent: bool = False  # the MCU sends nothing (dead, unplugged, wrong baud)
    estop: bool = False  # the emergency stop is pressed
    mcu_garbage_every: int = 0  # after every Nth MCU frame, `garbage_len` noise bytes
    garbage_len: int = 8
    mcu_corrupt_every: int = 0  # every Nth MCU frame leaves with a broken CRC
    drop_acks: int = 0  # the next N acknowledgements are lost (the command still acts)
    gps_fix: bool = True  # False: the receiver has no fix (it still talks)
    gps_silent: bool = False  # the receiver sends nothing


class HuskyOptions(TypedDict, total=False):
    """`SimHusky`'s keyword options, as a transport passes them on unchanged."""

    home: tuple[float, float]
    home_alt_m: float
    yaw_deg: float
    gps_rate_hz: float
    gps_fix_delay_s: float
    gps_protocol: str
    talker: str
    watchdog_s: float
    imu: bool
    max_subscription_hz: int
    seed: int


class _Line:
    """One serial line of the simulated machine: what it has to send, and counters."""

    def __init__(self) -> None:
        self.outbox: list[bytes] = []
        self.bytes_sent = 0
        self.bytes_received = 0
        self.bytes_dropped = 0
        #: Where bytes go at once (a port's write, returning what it took); None: the outbox.
        self.sink: Callable[[bytes], int] | None = None

    def data_to_send(self) -> bytes:
        """The bytes sent since the last call."""
        out = b"".join(self.outbox)
        self.outbox.clear()
        return out

    def transmit(self, data: bytes) -> None:
        """Onto the line: the sink (a full line drops bytes, as a UART), else the outbox."""
        if self.sink is None:
            self.outbox.append(data)
            self.bytes_sent += len(data)
            return
        sent = self.sink(data)
        self.bytes_sent += sent
        self.bytes_dropped += len(data) - sent


class SimMcu(_Line):
    """The Husky's MCU side: frames from the node in, acknowledgements and data out."""

    def __init__(self, sim: SimHusky) -> None:
        super().__init__()
        self.sim = sim
        self.reader = FrameReader()
        self.received: Counter[str] = Counter()  # host frames by type name
        self.frames_sent = 0
        self.acks_sent = 0
        self.acks_dropped = 0

    def receive_data(self, data: bytes) -> int:
        """Handle bytes from the node (any split); frames handled."""
        self.bytes_received += len(data)
        frames = self.reader.feed(data)
        for frame in frames:
            self.sim._on_frame(frame)
        return len(frames)

    def send(self, frame: Frame) -> None:
        """One frame out, faults applied."""
        f = self.sim.faults
        if f.mcu_silent:
            return
        wire = bytearray(frame.encode())
        self.frames_sent += 1
        n = self.frames_sent
        if f.mcu_corrupt_every and n % f.mcu_corrupt_every == 0:
            wire[-1] ^= 0x5A
        if f.mcu_garbage_every and n % f.mcu_garbage_every == 0:
            wire += self.sim._rng.randbytes(f.garbage_len)
        self.transmit(bytes(wire))


class SimGps(_Line):
    """The GPS receiver's side: sentences (or UBX frames) out; what it is sent is ignored."""

    def receive_data(self, data: bytes) -> int:
        """Configuration sent to the receiver: counted, not acted on."""
        self.bytes_received += len(data)
        return 0


class SimHusky:
    """One simulated Husky: its MCU (`mcu`) and its GPS receiver (`gps`), one physics."""

    def __init__(
        self,
        profile: Profile,
        *,
        home: tuple[float, float] = DEFAULT_HOME,
        home_alt_m: float = 50.0,
        yaw_deg: float = 0.0,
        gps_rate_hz: float = 5.0,
        gps_fix_delay_s: float = 0.0,
        gps_protocol: str | None = None,
        talker: str = "GP",
        watchdog_s: float = 0.5,
        imu: bool = False,
        max_subscription_hz: int = 50,
        seed: int = 0,
    ) -> None:
        """A Husky standing at `home` facing `yaw_deg` (from north, clockwise), wheels still.

        `gps_protocol` ("nmea" or "ubx") defaults to the profile's `[gps] protocol`.
        """
        try:
            self.frame = LocalFrame(float(home[0]), float(home[1]), float(home_alt_m))
        except (ValueError, TypeError, IndexError) as e:
            raise HuskySimError(f"bad home {home!r}: {e}") from e
        if not gps_rate_hz > 0:
            raise HuskySimError(f"GPS rate must be > 0 Hz, got {gps_rate_hz}")
        self.profile = profile
        drive = profile.drive or DriveSettings()
        self.drive = DiffDrive(
            wheel_separation_m=drive.wheel_separation_m,
            max_speed_mps=profile.kinematics.max_speed_mps,
            yaw=math.radians(90.0 - yaw_deg),
        )
        self.max_speed = (profile.kinematics.max_speed_mps, profile.kinematics.max_speed_mps)
        self.max_accel = (DEFAULT_MAX_ACCEL, DEFAULT_MAX_ACCEL)
        self.gps_rate_hz = gps_rate_hz
        self.gps_fix_delay_s = gps_fix_delay_s
        proto = gps_protocol or (profile.gps.protocol if profile.gps is not None else "nmea")
        if proto not in ("nmea", "ubx"):
            raise HuskySimError(f"GPS protocol must be nmea or ubx, got {proto!r}")
        self.gps_protocol = proto
        self.talker = talker
        self.watchdog_s = watchdog_s
        self.imu = imu
        self.max_subscription_hz = max_subscription_hz
        self.faults = HuskyFaults()
        self.time = 0.0
        self.battery_percent = 100.0
        self.mcu = SimMcu(self)
        self.gps = SimGps()
        self.speed_commands = 0
        self.last_speed_command: float | None = None
        self.watchdog_trips = 0
        self.timed_out = False  # the watchdog has stopped the wheels
        self._rng = random.Random(seed)
        self._subs: dict[int, tuple[float, float]] = {}  # data type -> (period, next due)
        self._next_gps = 0.0
        b = profile.battery
        self._drain = 100.0 / b.endurance_s

    # ------------------------------------------------------------------ views

    @property
    def position(self) -> tuple[float, float]:
        """(lat, lon) of the base now."""
        lat, lon, _ = self.frame.to_gps(self.drive.x, self.drive.y)
        return lat, lon

    @property
    def heading_deg(self) -> float:
        """Where the base faces: degrees from north, clockwise."""
        return (90.0 - math.degrees(self.drive.yaw)) % 360.0

    @property
    def gps_has_fix(self) -> bool:
        """Whether the receiver reports a fix now."""
        return self.faults.gps_fix and self.time >= self.gps_fix_delay_s

    @property
    def safety_flags(self) -> int:
        """The safety system's flags now."""
        flags = 0
        if self.timed_out:
            flags |= M.SAFETY_TIMEOUT
        if self.faults.estop:
            flags |= M.SAFETY_ESTOP
        return flags

    @property
    def voltage(self) -> float:
        """Battery voltage from the profile's linear model."""
        b = self.profile.battery
        return b.empty_voltage + (b.full_voltage - b.empty_voltage) * self.battery_percent * 0.01

    def gps_garbage(self, n: int) -> None:
        """Put `n` random bytes on the GPS line now."""
        if not self.faults.gps_silent:
            self.gps.transmit(self._rng.randbytes(n))

    def set_battery(self, percent: float) -> None:
        """Jump the battery to `percent`."""
        self.battery_percent = min(100.0, max(0.0, percent))

    # ------------------------------------------------------------------ time

    def step(self, dt: float) -> None:
        """Advance by `dt`: the watchdog, the wheels, the battery, subscriptions, the GPS."""
        self.time += dt
        d = self.drive
        if self.faults.estop:
            d.stop(self.max_accel[0])
        elif not self.timed_out and (
            self.last_speed_command is None or self.time - self.last_speed_command > self.watchdog_s
        ):
            if self.last_speed_command is not None or d.moving:
                self.timed_out = True
                self.watchdog_trips += 1
                self._note(f"command timeout: no speed command for {self.watchdog_s:g} s, stopping")
            d.stop(self.max_accel[0])
        was_moving = d.moving
        d.step(dt)
        if was_moving:
            self.battery_percent = max(0.0, self.battery_percent - self._drain * dt)
        else:
            self.battery_percent = max(0.0, self.battery_percent - self._drain * 0.2 * dt)
        t = self.time + 1e-9
        for kind, (period, due) in list(self._subs.items()):
            if t >= due:
                nxt = due + period
                if nxt <= self.time:
                    nxt = self.time + period
                self._subs[kind] = (period, nxt)
                self._send_data(kind)
        if t >= self._next_gps:
            self._next_gps += 1.0 / self.gps_rate_hz
            if self._next_gps <= self.time:
                self._next_gps = self.time + 1.0 / self.gps_rate_hz
            self._emit_gps()

    def _note(self, text: str) -> None:
        _log.info("t=%.1f %s: %s", self.time, self.profile.name, text)

    # ------------------------------------------------------------------ the MCU

    def _ms(self) -> int:
        return int(self.time * 1000.0) & 0xFFFFFFFF

    def _ack(self, frame: Frame, result: int) -> None:
        if frame.flags & NO_ACK:
            return
        if self.faults.drop_acks > 0:
            self.faults.drop_acks -= 1
            self.mcu.acks_dropped += 1
            return
        self.mcu.acks_sent += 1
        self.mcu.send(M.ack(frame.type, result, self._ms()))

    def _on_frame(self, frame: Frame) -> None:
        self.mcu.received[M.name_of(frame.type)] += 1
        if frame.is_data:
            return  # an MCU does not take data messages; nothing to acknowledge
        try:
            value = M.decode_command(frame)
        except M.PayloadError:
            self._ack(frame, M.ACK_BAD_FORMAT)
            return
        t = frame.type
        if isinstance(value, M.Request):
            self._request(frame, value)
        elif t == M.MsgType.SET_DIFF_SPEED and isinstance(value, M.DiffSpeeds):
            self._set_speed(value)
            self._ack(frame, 0)
        elif t in (M.MsgType.SET_MAX_SPEED, M.MsgType.SET_MAX_ACCEL) and isinstance(
            value, M.Limits
        ):
            if not (value.forward >= 0 and value.reverse >= 0):
                self._ack(frame, M.ACK_RANGE)
                return
            if t == M.MsgType.SET_MAX_SPEED:
                self.max_speed = (value.forward, value.reverse)
            else:
                self.max_accel = (value.forward, value.reverse)
            self._ack(frame, 0)
        else:
            self._ack(frame, M.ACK_BAD_TYPE)

    def _set_speed(self, s: M.DiffSpeeds) -> None:
        self.speed_commands += 1
        self.last_speed_command = self.time
        if self.timed_out:
            self.timed_out = False
            self._note("speed commands again: timeout cleared")
        if self.faults.estop:
            return

        def limit(v: float) -> float:
            fwd, rev = self.max_speed
            return min(v, fwd) if v >= 0 else max(v, -rev)

        def accel(a: float, v: float, now: float) -> float:
            # The forward limit while speeding up away from 0, the reverse one otherwise.
            top = self.max_accel[0] if abs(v) >= abs(now) else self.max_accel[1]
            return min(abs(a), top) if a else top

        d = self.drive
        left, right = limit(s.left), limit(s.right)
        d.command(
            left, right, accel(s.left_accel, left, d.left), accel(s.right_accel, right, d.right)
        )

    def _request(self, frame: Frame, r: M.Request) -> None:
        kind = r.data_type
        if not self._knows(kind):
            self._ack(frame, M.ACK_BAD_TYPE)
            return
        if r.frequency == M.UNSUBSCRIBE:
            self._subs.pop(kind, None)
            self._ack(frame, 0)
            return
        if r.frequency > self.max_subscription_hz:
            self._ack(frame, M.ACK_OVER_FREQ)
            return
        self._ack(frame, 0)
        if r.frequency == M.ONCE:
            self._send_data(kind)
        else:
            period = 1.0 / r.frequency
            self._subs[kind] = (period, self.time + period)

    def _knows(self, kind: int) -> bool:
        if kind == M.MsgType.ORIENTATION:
            return self.imu
        return kind in _DATA_KINDS

    def _send_data(self, kind: int) -> None:
        ms = self._ms()
        d = self.drive
        if kind == M.MsgType.ENCODERS:
            frame = M.encoders(d.travel, (d.left, d.right), ms)
        elif kind == M.MsgType.DIFF_SPEED:
            frame = M.diff_speeds(M.DiffSpeeds(d.left, d.right, d.left_accel, d.right_accel), ms)
        elif kind == M.MsgType.SYSTEM_STATUS:
            amps = 0.5 + 4.0 * (abs(d.left) + abs(d.right))
            frame = M.system_status(
                M.SystemStatus(
                    ms,
                    (self.voltage, self.voltage - 0.1, self.voltage - 0.1),
                    (amps, amps * 0.45, amps * 0.45),
                    (30.0, 31.0, 35.0, 36.0),
                ),
                ms,
            )
        elif kind == M.MsgType.POWER_SYSTEM:
            cap = self.profile.battery.capacity_wh or 480.0
            # Description byte: the spec lists 2 NiMH, 8 gasoline...; a Husky's is lead-acid
            # (its value is not documented): 1 here, illustrative.
            frame = M.power_system(
                M.PowerSystem((self.battery_percent / 100.0,), (round(cap),), (1,)), ms
            )
        elif kind == M.MsgType.SAFETY_SYSTEM:
            frame = M.safety_status(self.safety_flags, ms)
        elif kind == M.MsgType.PLATFORM_INFO:
            frame = M.platform_info(PLATFORM, ms)
        elif kind == M.MsgType.FIRMWARE_INFO:
            frame = Frame(kind, struct.pack("<BBBBI", 1, 0, 1, 1, 0), 0, ms)
        elif kind in (M.MsgType.MAX_SPEED, M.MsgType.MAX_ACCEL):
            fwd, rev = self.max_speed if kind == M.MsgType.MAX_SPEED else self.max_accel
            frame = Frame(kind, struct.pack("<hh", M.raw(fwd, 100), M.raw(rev, 100)), 0, ms)
        elif kind == M.MsgType.ORIENTATION:
            # Yaw as an IMU reports it: from north, clockwise (radians, x1000).
            yaw = math.remainder(math.pi / 2 - d.yaw, 2 * math.pi)
            frame = M.triple(kind, M.Triple(0.0, 0.0, yaw), ms)
        else:
            return
        self.mcu.send(frame)

    # ------------------------------------------------------------------ the GPS

    def _emit_gps(self) -> None:
        if self.faults.gps_silent:
            return
        if self.gps_protocol == "ubx":
            self.gps.transmit(self._nav_pvt())
            return
        when = GPS_EPOCH + datetime.timedelta(seconds=self.time)
        hms = when.strftime("%H%M%S") + f".{when.microsecond // 10000:02d}"
        date = when.strftime("%d%m%y")
        talker = self.talker
        if not self.gps_has_fix:
            gga = (hms, "", "", "", "", "0", "00", "99.99", "", "M", "", "M", "", "")
            rmc = (hms, "V", "", "", "", "", "", "", date, "", "", "N")
            self.gps.transmit(sentence(talker, "GGA", gga) + sentence(talker, "RMC", rmc))
            return
        lat, lon = self.position
        la, ns = nmea_lat(lat)
        lo, ew = nmea_lon(lon)
        speed = abs(self.drive.speed)
        course = f"{self._course():.1f}" if speed > _COURSE_MPS else ""
        alt = f"{self.frame.alt:.1f}"
        gga = (hms, la, ns, lo, ew, "1", "10", "0.9", alt, "M", "-32.0", "M", "", "")
        rmc = (hms, "A", la, ns, lo, ew, f"{speed / KNOT_MPS:.3f}", course, date, "", "", "A")
        self.gps.transmit(sentence(talker, "GGA", gga) + sentence(talker, "RMC", rmc))

    def _course(self) -> float:
        """Course over ground, degrees from north: the heading, or its opposite in reverse."""
        h = self.heading_deg
        return h if self.drive.speed >= 0 else (h + 180.0) % 360.0

    def _nav_pvt(self) -> bytes:
        when = GPS_EPOCH + datetime.timedelta(seconds=self.time)
        fix = self.gps_has_fix
        lat, lon = self.position if fix else (0.0, 0.0)
        speed = abs(self.drive.speed)
        msg = pyubx2.UBXMessage(
            "NAV",
            "NAV-PVT",
            pyubx2.GET,
            iTOW=int(self.time * 1000) % 604_800_000,
            year=when.year,
            month=when.month,
            day=when.day,
            hour=when.hour,
            min=when.minute,
            second=when.second,
            validDate=1,
            validTime=1,
            fixType=3 if fix else 0,
            gnssFixOk=1 if fix else 0,
            numSV=10 if fix else 0,
            lon=lon,
            lat=lat,
            height=int((self.frame.alt - 32.0) * 1000) if fix else 0,
            hMSL=int(self.frame.alt * 1000) if fix else 0,
            hAcc=1500 if fix else 0xFFFFFFFF,
            vAcc=2500 if fix else 0xFFFFFFFF,
            gSpeed=int(speed * 1000),
            headMot=self._course() if speed > _COURSE_MPS else 0.0,
            velN=int(self.drive.speed * 1000 * math.sin(self.drive.yaw)),
            velE=int(self.drive.speed * 1000 * math.cos(self.drive.yaw)),
        )
        return bytes(msg.serialize())


_DATA_KINDS = frozenset(
    {
        M.MsgType.ENCODERS,
        M.MsgType.DIFF_SPEED,
        M.MsgType.SYSTEM_STATUS,
        M.MsgType.POWER_SYSTEM,
        M.MsgType.SAFETY_SYSTEM,
        M.MsgType.PLATFORM_INFO,
        M.MsgType.FIRMWARE_INFO,
        M.MsgType.MAX_SPEED,
        M.MsgType.MAX_ACCEL,
    }
)


__all__ = [
    "GPS_EPOCH",
    "HuskyFaults",
    "HuskyOptions",
    "HuskySimError",
    "SimGps",
    "SimHusky",
    "SimMcu",
]
