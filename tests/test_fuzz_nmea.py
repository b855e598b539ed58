"""GPS input (NMEA, UBX) fuzzing: a short deterministic campaign slice.

Long campaigns: `python -m tests.fuzz.nmea_fuzz --count 500000 --seed S` (see that module).
"""

from __future__ import annotations

import random

import pytest
from fuzz import nmea_fuzz

from fieldkit.vehicle.clearpath.gps import GpsCore

GGA = b"$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\r\n"


def test_campaign_slice() -> None:
    """500 fixed inputs: no failure; sentences, UBX frames and every kind of noise hit."""
    lines: list[str] = []
    stats = nmea_fuzz.run("ci", max_inputs=500, out=lines.append)
    assert stats.inputs == 500
    assert stats.failures == 0, "\n".join(lines)
    kinds = set(stats.kinds)
    assert {"nmea", "ubx", "flip", "checksum", "cut", "ubx-checksum", "random"} <= kinds


def test_check_can_fail_when_noise_swallows_sentences(monkeypatch: pytest.MonkeyPatch) -> None:
    """A reader that loses a good sentence behind each bad one is caught by the count."""
    original = GpsCore._bad

    def lossy(self: GpsCore, why: str) -> None:
        original(self, why)
        self.sentences -= 1  # as if the next good sentence were eaten with the bad one

    monkeypatch.setattr(GpsCore, "_bad", lossy)
    stream = GGA.replace(b"*47", b"*48") + GGA + GGA
    problem = nmea_fuzz.check(random.Random(0), stream, 2, 2, True)
    assert problem is not None and "counted" in problem
