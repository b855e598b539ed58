"""The Husky's GPS core (fieldkit.vehicle.clearpath.gps): the spec's sentences, noise, fix loss.

The sentences are section 11's of /shared/spec/clearpath-husky.md, checked there with
`pynmea2.parse(..., check=True)`; the UBX frames are built by pyubx2.
"""

from __future__ import annotations

from collections import Counter

import pytest
import pyubx2

from fieldkit.vehicle import nmea
from fieldkit.vehicle.clearpath.gps import KNOT_MPS, GpsCore, nmea_lat, nmea_lon, sentence
from fieldkit.vehicle.nmea import cut_sentence

GGA = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"
RMC = b"$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A\r\n"
VTG = b"$GPVTG,054.7,T,034.4,M,005.5,N,010.2,K*48\r\n"
GNGGA = b"$GNGGA,101500.00,4723.86452,N,00832.73564,E,4,12,0.62,489.3,M,47.5,M,1.0,0000*6F\r\n"
GNRMC = b"$GNRMC,101500.00,A,4723.86452,N,00832.73564,E,0.020,,251126,,,R,V*06\r\n"
NO_FIX = b"$GPGGA,123520,,,,,0,00,99.99,,M,,M,,*4F\r\n"


class Clock:
    """A clock the test moves."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def gps() -> tuple[GpsCore, Clock]:
    clock = Clock()
    return GpsCore(clock=clock, timeout_s=2.0), clock


def test_spec_sentences_decode_as_the_spec_says() -> None:
    g, _ = gps()
    assert g.receive_data(GGA + RMC) == 2
    f = g.fix
    assert f.fix_type == 3 and f.satellites == 8 and f.hdop == 0.9
    assert f.lat == pytest.approx(48.1173) and f.lon == pytest.approx(11.516667, abs=1e-6)
    assert f.alt_msl_m == 545.4
    assert f.speed_mps == pytest.approx(22.4 * KNOT_MPS) and f.track_deg == 84.4
    g.receive_data(VTG)
    assert f.speed_mps == pytest.approx(10.2 / 3.6) and f.track_deg == 54.7  # degrees, as sent
    g.receive_data(GNGGA + GNRMC)
    assert f.fix_type == 6 and f.satellites == 12  # RTK fixed, multi-GNSS talker
    assert f.lat == pytest.approx(47.397742, abs=1e-6)
    assert f.lon == pytest.approx(8.545594, abs=1e-6)
    assert f.track_deg is None and f.speed_mps == pytest.approx(0.02 * KNOT_MPS)
    assert g.sentences == 5 and g.bad_sentences == 0 and g.garbage_bytes == 0


def test_any_split_gives_the_same_fix() -> None:
    whole, _ = gps()
    whole.receive_data(GGA + RMC)
    pieces, _ = gps()
    for b in GGA + RMC:
        pieces.receive_data(bytes([b]))
    assert pieces.fix == whole.fix and pieces.sentences == 2


def test_garbage_costs_counters_and_one_event_per_streak() -> None:
    g, _ = gps()
    bad_sum = GGA.replace(b"*47", b"*48")
    cut = GGA[:30]  # a sentence cut short by the next one
    noise = b"\x00\xff\xb5\x62\x01\x07\xff\xffxyz"
    assert g.receive_data(noise + bad_sum + cut + GGA + b"garbage\r\n" + RMC) == 2
    assert g.bad_sentences == 2  # the bad checksum and the too-long UBX length
    assert g.garbage_bytes > 0 and g.fix.fix_type == 3
    texts = [e.text for e in g.drain_events()]
    assert texts[0].startswith("gps: unreadable input (UBX length")
    assert texts[1] == "gps: fix (3D, 8 satellites)"
    assert len(texts) == 2  # the checksum failure is in the same streak as the bad frame


def test_cut_sentence_says_wait_skip_or_line() -> None:
    assert cut_sentence(b"$GPGGA,1", 0, 100) is None  # the line end may still come
    assert cut_sentence(b"$" + bytes(100), 0, 100) == (1, False)  # none within reach
    assert cut_sentence(b"xx$GPGGA,1$GPVTG\n", 2, 100) == (10, False)  # cut short
    assert cut_sentence(b"xx" + VTG + GGA, 2, 100) == (2 + len(VTG), True)


def test_the_gps_and_the_inspector_cut_a_stream_alike() -> None:
    """One NMEA de-framer (cut_sentence): the same sentences found, the same refused."""
    stream = b"zz$GPGGA,12" + GGA + b"\x00\x01$$" + VTG + b"$GPXXX,bad*00\r\n" + RMC
    stats: Counter[str] = Counter()
    found = list(nmea.deframe([stream[i : i + 7] for i in range(0, len(stream), 7)], stats))
    assert found == [GGA, VTG, RMC] and stats["bad_frames"] == 1
    g, _ = gps()
    assert g.receive_data(stream) == 3 and g.sentences == 3 and g.bad_sentences == 1


def test_fix_lost_by_quality_status_and_silence() -> None:
    g, clock = gps()
    g.receive_data(GGA)
    assert g.has_fix
    g.receive_data(NO_FIX)
    assert not g.has_fix and g.fix.fix_type == 1 and g.fix_losses == 1
    g.receive_data(GGA)
    g.receive_data(b"$GPRMC,123519,V,,,,,,,230394,,*33\r\n")
    assert not g.has_fix and g.fix_losses == 2
    g.receive_data(GGA)
    clock.now = 1.9
    g.tick()
    assert g.has_fix
    clock.now = 2.1
    g.tick()
    assert not g.has_fix and g.fix_losses == 3
    texts = [e.text for e in g.drain_events()]
    assert texts[-1] == "gps: fix lost (nothing heard for 2.1 s)"
    assert "gps: fix lost (GGA fix quality 0)" in texts
    assert "gps: fix lost (RMC status V (no fix))" in texts


def test_ubx_nav_pvt_and_the_mon_ver_vector() -> None:
    poll = pyubx2.UBXMessage("MON", "MON-VER", pyubx2.POLL).serialize()
    assert bytes(poll) == bytes.fromhex("B5 62 0A 04 00 00 0E 34")  # spec section 11
    g, _ = gps()
    pvt = pyubx2.UBXMessage(
        "NAV", "NAV-PVT", pyubx2.GET, fixType=3, gnssFixOk=1, carrSoln=2, numSV=14,
        lat=45.5017, lon=-73.5673, hMSL=52_500, gSpeed=1500, headMot=271.5,
    ).serialize()  # fmt: skip
    assert g.receive_data(b"\x00" + bytes(poll) + bytes(pvt)) == 2
    f = g.fix
    assert f.fix_type == 6 and f.satellites == 14 and f.alt_msl_m == 52.5
    assert f.lat == pytest.approx(45.5017) and f.lon == pytest.approx(-73.5673)
    assert f.speed_mps == 1.5 and f.track_deg == pytest.approx(271.5)
    assert g.ubx_messages == 2 and g.unused == 1 and g.garbage_bytes == 1
    broken = bytearray(pvt)
    broken[-1] ^= 1
    g.receive_data(bytes(broken))
    assert g.bad_sentences == 1 and g.ubx_messages == 2


def test_rendered_sentences_parse_back() -> None:
    lat, ns = nmea_lat(45.5017)
    lon, ew = nmea_lon(-73.5673)
    assert (lat, ns, lon, ew) == ("4530.10200", "N", "07334.03800", "W")
    assert nmea_lat(-0.99999999999)[0] == "0100.00000"  # 59.99999... minutes round up
    line = sentence("GN", "GGA", ("000000.00", lat, ns, lon, ew, "1", "9", "1.0", "50.0", "M",
                                  "", "M", "", ""))  # fmt: skip
    g, _ = gps()
    assert g.receive_data(line) == 1
    assert g.fix.lat == pytest.approx(45.5017) and g.fix.lon == pytest.approx(-73.5673)
