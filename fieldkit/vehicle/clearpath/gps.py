"""A GPS receiver on its own serial port, without I/O: NMEA 0183 (pynmea2) and u-blox UBX (pyubx2).

    gps = GpsCore(clock=clock, timeout_s=2.0)
    gps.receive_data(bytes_from_the_port)      # sentences and UBX frames, any split, any noise
    gps.tick()                                 # silence -> fix lost
    gps.fix.fix_type, gps.fix.lat, gps.fix.speed_mps, gps.fix.track_deg, gps.fix.satellites
    for event in gps.drain_events(): log(event.text)

The byte stream is cut into NMEA sentences (`$` ... LF, by the inspector's NMEA de-framer,
`fieldkit.vehicle.nmea.cut_sentence`) and UBX frames (`B5 62` class id length payload
checksum); the parsing, checksums included, is the libraries': `pynmea2.parse(...,
check=True)` for sentences, `pyubx2.UBXReader.parse(..., validate=VALCKSUM)` for frames. What
neither accepts is counted (`bad_sentences`, `garbage_bytes`), never raised, and reported once
per streak as a "gps" event.

Sentences used (spec section 11): GGA (fix quality, position, satellites, HDOP, altitude), RMC
(validity, position, speed, course), VTG (speed, course), HDT (true heading of a dual-antenna
receiver); UBX NAV-PVT (all of it in one message). Any talker (GP, GN, GL, GA, GB, IN...).

The fix type uses MAVLink's scale (GPS_FIX_TYPE), so the node reads it as an autopilot's: 0
nothing heard, 1 no fix, 2 2D, 3 3D, 4 DGPS/SBAS, 5 RTK float, 6 RTK fixed. GGA's quality 1
is 3 (a GGA fix carries an altitude), 2 and 9 are 4, 5 is 5, 4 is 6; anything else is no
fix, as in nmea_navsat_driver. A receiver that sends RMC but no GGA gets 2 at best.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import pynmea2
import pyubx2

from fieldkit.vehicle.autopilot import Event
from fieldkit.vehicle.nmea import cut_sentence

KNOT_MPS = 0.514444444444
"""One knot in m/s."""
MAX_SENTENCE = 100
"""Longest line taken for a sentence (NMEA's limit is 82 with CR LF; some receivers run over)."""
MAX_UBX_PAYLOAD = 2048
"""Longest UBX payload taken (NAV-PVT is 92 bytes); a longer claimed length is noise."""
UBX_SYNC = b"\xb5\x62"
"""The two bytes that start a UBX frame."""

# GGA fix quality -> MAVLink GPS_FIX_TYPE (1 = no fix).
_GGA_FIX = {1: 3, 2: 4, 4: 6, 5: 5, 9: 4}
# The fix types that count as a fix at all.
_HAS_FIX = 2


@dataclass
class GpsFix:
    """The receiver's latest solution; None where it has not said."""

    fix_type: int = 0  # GPS_FIX_TYPE: 0 nothing heard, 1 no fix, 2 2D, 3 3D, 4+ DGPS/RTK
    lat: float | None = None  # degrees, WGS84
    lon: float | None = None
    alt_msl_m: float | None = None
    satellites: int | None = None
    hdop: float | None = None
    speed_mps: float | None = None  # over ground
    track_deg: float | None = None  # course over ground, 0..360 from true north
    heading_deg: float | None = None  # true heading (HDT, a dual-antenna receiver)
    last_fix: float | None = None  # clock time of the last position with a fix
    last_heard: float | None = None  # clock time of the last good sentence or frame

    def copy(self) -> GpsFix:
        """An independent snapshot."""
        return replace(self)


class GpsCore:
    """One GPS receiver: bytes and time in, a fix, counters and events out; no I/O."""

    def __init__(
        self,
        *,
        url: str = "gps",
        clock: Callable[[], float] = time.monotonic,
        timeout_s: float = 2.0,
    ) -> None:
        """A receiver not heard yet; silent for `timeout_s` after a fix, its fix is lost."""
        self.url = url
        self._clock = clock
        self.timeout_s = timeout_s
        self.fix = GpsFix()
        self.sentences = 0  # good NMEA sentences
        self.ubx_messages = 0  # good UBX frames
        self.bad_sentences = 0  # NMEA lines or UBX frames the parser refused
        self.garbage_bytes = 0  # bytes outside any sentence or frame
        self.unused = 0  # good but of a kind not read (GSV, GSA, NAV-SAT...)
        self.fix_losses = 0
        self.bytes_received = 0
        self.events: deque[Event] = deque(maxlen=1000)
        self._buf = bytearray()
        self._had_fix = False
        self._bad_streak = False
        self._last_gga: float | None = None

    # ------------------------------------------------------------------ bytes in

    @property
    def messages(self) -> int:
        """Good sentences and frames so far."""
        return self.sentences + self.ubx_messages

    def receive_data(self, data: bytes) -> int:
        """Handle bytes from the receiver (any split); good sentences and frames handled."""
        self.bytes_received += len(data)
        buf = self._buf
        buf += data
        handled = 0
        i = 0
        n = len(buf)
        while i < n:
            b = buf[i]
            if b == 0x24:  # "$"
                cut = cut_sentence(buf, i, MAX_SENTENCE)
                if cut is None:
                    break  # the rest of the line is on its way
                end, whole = cut
                if whole:
                    handled += self._sentence(bytes(buf[i:end]))
                else:  # no line end in reach, or cut short by another sentence
                    self._garbage(end - i)
                i = end
            elif b == 0xB5:
                if n - i < 6:
                    if n - i > 1 and buf[i + 1] != 0x62:
                        self._garbage(1)
                        i += 1
                        continue
                    break
                if buf[i + 1] != 0x62:
                    self._garbage(1)
                    i += 1
                    continue
                length = buf[i + 4] | buf[i + 5] << 8
                if length > MAX_UBX_PAYLOAD:
                    self._bad("UBX length too long")
                    self._garbage(1)
                    i += 1
                    continue
                end = i + 8 + length
                if end > n:
                    break
                if self._ubx(bytes(buf[i:end])):
                    handled += 1
                    i = end
                else:
                    self._garbage(1)
                    i += 1  # rescan: a real frame may start inside the bad one
            else:
                j = buf.find(b"$", i + 1)
                k = buf.find(b"\xb5", i + 1, j if j >= 0 else n)
                j = k if k >= 0 else (j if j >= 0 else n)
                self._garbage(j - i)
                i = j
        del buf[:i]
        return handled

    def _garbage(self, count: int) -> None:
        self.garbage_bytes += count

    def _bad(self, why: str) -> None:
        self.bad_sentences += 1
        if not self._bad_streak:
            # Once per streak: line noise must not flood the log.
            self._bad_streak = True
            self._event(f"{self.url}: unreadable input ({why})")

    def _good(self, now: float) -> None:
        self._bad_streak = False
        self.fix.last_heard = now

    def _sentence(self, line: bytes) -> int:
        try:
            text = line.decode("ascii").strip()
            msg = pynmea2.parse(text, check=True)
        except (pynmea2.ParseError, UnicodeDecodeError, ValueError, TypeError, AttributeError) as e:
            self._bad(_short(e))
            return 0
        now = self._clock()
        kind = getattr(msg, "sentence_type", "")
        try:
            used = self._use_nmea(kind, msg, now)
        except Exception as e:  # a field pynmea2 cannot convert (it parses them lazily)
            self._bad(f"{kind}: {_short(e)}")
            return 0
        self.sentences += 1
        self._good(now)
        if not used:
            self.unused += 1
        return 1

    def _ubx(self, frame: bytes) -> bool:
        try:
            msg = pyubx2.UBXReader.parse(frame, validate=pyubx2.VALCKSUM)
        except Exception as e:  # pyubx2 raises its own errors and plain ones for bad layouts
            self._bad(f"UBX: {_short(e)}")
            return False
        now = self._clock()
        try:
            used = self._use_ubx(msg, now)
        except Exception as e:  # a field that does not convert
            self._bad(f"UBX: {_short(e)}")
            return False
        self.ubx_messages += 1
        self._good(now)
        if not used:
            self.unused += 1
        return True

    # ------------------------------------------------------------------ meaning

    def _use_nmea(self, kind: str, m: Any, now: float) -> bool:
        f = self.fix
        if kind == "GGA":
            self._last_gga = now
            quality = int(m.gps_qual or 0)
            fix_type = _GGA_FIX.get(quality, 1)
            sats = _int(m.num_sats)
            f.satellites = sats
            f.hdop = _float(m.horizontal_dil)
            pos = _position(m) if fix_type >= _HAS_FIX else None
            if pos is None:
                self._set_fix(1, now, f"GGA fix quality {quality}")
                return True
            f.lat, f.lon = pos
            alt = _float(m.altitude)
            f.alt_msl_m = alt
            self._set_fix(fix_type, now)
            return True
        if kind == "RMC":
            valid = m.status == "A"
            pos = _position(m) if valid else None
            if pos is None:
                self._set_fix(1, now, "RMC status V (no fix)")
                return True
            speed = _float(m.spd_over_grnd)
            f.speed_mps = None if speed is None else speed * KNOT_MPS
            f.track_deg = _angle(m.true_course)
            gga_recent = self._last_gga is not None and now - self._last_gga <= self.timeout_s
            if not gga_recent:
                # Without GGA there is no altitude and no quality: a 2D fix at best.
                f.lat, f.lon = pos
                self._set_fix(2, now)
            return True
        if kind == "VTG":
            kmh = _float(m.spd_over_grnd_kmph)
            kts = _float(m.spd_over_grnd_kts)
            if kmh is not None:
                f.speed_mps = kmh / 3.6
            elif kts is not None:
                f.speed_mps = kts * KNOT_MPS
            # In degrees, as sent (nmea_navsat_driver's VTG path forgot the radians).
            f.track_deg = _angle(m.true_track)
            return True
        if kind == "HDT":
            f.heading_deg = _angle(m.heading)
            return True
        return False

    def _use_ubx(self, m: Any, now: float) -> bool:
        if getattr(m, "identity", "") != "NAV-PVT":
            return False
        f = self.fix
        fix_type = int(m.fixType)
        f.satellites = int(m.numSV)
        if not int(m.gnssFixOk) or fix_type not in (2, 3, 4):
            self._set_fix(1, now, f"UBX NAV-PVT fix type {fix_type}")
            return True
        lat, lon = float(m.lat), float(m.lon)
        if not _on_earth(lat, lon):
            self._set_fix(1, now, "UBX NAV-PVT position off the Earth")
            return True
        carr = int(m.carrSoln)
        mav = 2 if fix_type == 2 else (6 if carr == 2 else 5 if carr == 1 else 3)
        f.lat, f.lon = lat, lon
        f.alt_msl_m = float(m.hMSL) / 1000.0
        f.speed_mps = float(m.gSpeed) / 1000.0
        f.track_deg = _angle(m.headMot)
        self._set_fix(mav, now)
        return True

    def _set_fix(self, fix_type: int, now: float, why: str = "") -> None:
        f = self.fix
        f.fix_type = fix_type
        if fix_type >= _HAS_FIX:
            f.last_fix = now
            if not self._had_fix:
                self._had_fix = True
                sats = "" if f.satellites is None else f", {f.satellites} satellites"
                self._event(f"{self.url}: fix ({_FIX_NAMES.get(fix_type, fix_type)}{sats})")
        elif self._had_fix:
            self._lose(why)

    def device_lost(self, why: str) -> None:
        """The receiver's port went away: its fix is lost now, not after the silence timeout."""
        self._buf.clear()  # the rest of a sentence cut by the pull never comes
        if self._had_fix:
            self.fix.fix_type = 1 if self.fix.fix_type else 0
            self._lose(why)

    def _lose(self, why: str) -> None:
        self._had_fix = False
        self.fix_losses += 1
        self.fix.speed_mps = None
        self.fix.track_deg = None
        self._event(f"{self.url}: fix lost ({why})")

    # ------------------------------------------------------------------ time

    def tick(self) -> None:
        """A receiver silent past the timeout has lost its fix."""
        now = self._clock()
        f = self.fix
        heard = f.last_heard if f.last_heard is not None else f.last_fix
        if self._had_fix and heard is not None and now - heard > self.timeout_s:
            f.fix_type = 1 if f.fix_type else 0
            self._lose(f"nothing heard for {now - heard:.1f} s")

    def age(self) -> float:
        """Seconds since the last position with a fix (inf before the first)."""
        last = self.fix.last_fix
        return math.inf if last is None else max(0.0, self._clock() - last)

    @property
    def has_fix(self) -> bool:
        """Whether the receiver has a fix now (2D or better, not timed out)."""
        return self._had_fix and self.fix.fix_type >= _HAS_FIX

    def drain_events(self) -> list[Event]:
        """The events since the last call, oldest first."""
        out = list(self.events)
        self.events.clear()
        return out

    def _event(self, text: str) -> None:
        self.events.append(Event(self._clock(), "gps", text))


_FIX_NAMES = {2: "2D", 3: "3D", 4: "DGPS", 5: "RTK float", 6: "RTK fixed"}


def _short(e: BaseException) -> str:
    """An exception as a short reason (pynmea2 appends the whole field list to its own)."""
    first: Any = e.args[0] if e.args else type(e).__name__
    while isinstance(first, tuple | list) and first:
        first = first[0]  # pynmea2: ((message, fields),) or (message, fields)
    text = str(first)
    return text[:80]


def _float(v: Any) -> float | None:
    """A finite number from a field (pynmea2 gives strings or floats), else None."""
    if v is None or v == "":
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


def _int(v: Any) -> int | None:
    """A whole number from a field, else None."""
    f = _float(v)
    return int(f) if f is not None and 0 <= f < 1000 else None


def _angle(v: Any) -> float | None:
    """A direction in degrees, 0..360, or None."""
    f = _float(v)
    return None if f is None else f % 360.0


def _on_earth(lat: float, lon: float) -> bool:
    return math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90 and -180 <= lon <= 180


def _position(m: Any) -> tuple[float, float] | None:
    """(lat, lon) of a GGA or RMC with both fields present and on the Earth, else None."""
    if not (m.lat and m.lon and m.lat_dir in ("N", "S") and m.lon_dir in ("E", "W")):
        return None
    lat, lon = float(m.latitude), float(m.longitude)
    return (lat, lon) if _on_earth(lat, lon) else None


# ------------------------------------------------------------------ the simulator's side


def nmea_lat(lat: float) -> tuple[str, str]:
    """Latitude as NMEA's ddmm.mmmmm and N/S."""
    a = abs(lat)
    deg = int(a)
    minutes = (a - deg) * 60.0
    if round(minutes, 5) >= 60.0:  # 59.999999 would print as 60.00000
        deg, minutes = deg + 1, 0.0
    return f"{deg:02d}{minutes:08.5f}", "N" if lat >= 0 else "S"


def nmea_lon(lon: float) -> tuple[str, str]:
    """Longitude as NMEA's dddmm.mmmmm and E/W."""
    a = abs(lon)
    deg = int(a)
    minutes = (a - deg) * 60.0
    if round(minutes, 5) >= 60.0:
        deg, minutes = deg + 1, 0.0
    return f"{deg:03d}{minutes:08.5f}", "E" if lon >= 0 else "W"


def sentence(talker: str, kind: str, values: tuple[str, ...]) -> bytes:
    """One sentence rendered by pynmea2, checksum and CR LF included."""
    msg = pynmea2.TalkerSentence.sentence_types[kind](talker, kind, values)
    return str(msg.render(checksum=True, dollar=True, newline=True)).encode("ascii")


__all__ = ["KNOT_MPS", "GpsCore", "GpsFix", "nmea_lat", "nmea_lon", "sentence"]
