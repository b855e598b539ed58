"""A recording made up tick by tick, the same every time: what the bag tests write and expect.

`Sample(seed)` gives, for each tick k, the data a node would record in it (`sample.tick_data(k)`):
autopilot reads (real MAVLink frames, split across reads, with line noise between them), a
write, radio frames in and out, and the tick row. `record(writer, ticks)` writes ticks
0..ticks-1 through a `BagWriter`; `check_prefix(reader, sample)` checks that what a reader
returns is exactly ticks 0..K of the sample for some K, and returns K (-1 for none).
Everything derives from `random.Random(f"{seed}:{k}")`, so a child process that records
and the test that reads its bag agree without talking.
"""

from __future__ import annotations

import json
import random
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import all as mavlink2

from fieldkit.record.bag import (
    BagReader,
    BagWriter,
    Meta,
    RadioFrame,
    SerialChunk,
    TickRow,
)

#: Wall time of tick 0 (ns): 2026-01-01, and 100 ms per tick.
T0_NS = 1_767_225_600_000_000_000
TICK_NS = 100_000_000
TICK_S = 0.1
ROBOT = 3


def meta(seed: str) -> Meta:
    """The sample's meta."""
    return Meta(
        robot_id=ROBOT,
        seed=12345,
        profile_toml='name = "solo"\n',
        config_json=json.dumps({"script": "hello.bzz", "seed": seed}),
        script_name="hello.bzz",
        bo=bytes(range(256)) * 3,
        bdb=b"debug-info",
        bpos=b"\x00\x01",
        key_fingerprint="0123456789abcdef",
        started_unix_ns=T0_NS,
    )


@dataclass(frozen=True)
class TickData:
    """What one tick records."""

    rx: list[bytes]
    tx: bytes
    radio_in: list[tuple[int, bytes]]
    radio_out: bytes
    row: TickRow


class Sample:
    """The deterministic recording of seed `seed`."""

    def __init__(self, seed: str) -> None:
        self.seed = seed
        self.meta = meta(seed)
        self._mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self._gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=191)

    def frames(self, k: int) -> list[bytes]:
        """The autopilot's whole frames of tick k (heartbeat, position, battery)."""
        mav = self._mav
        mav.seq = k % 256
        lat, lon = -353_623_344 + 10 * k, 1_491_657_865 - 7 * k
        out = [
            mav.global_position_int_encode(k * 100, lat, lon, 600_000, 1_000 + k, 0, 0, 0, 0),
            mav.sys_status_encode(0, 0, 0, 500, 12_100 - k, 1_000, 80 - k % 80, 0, 0, 0, 0, 0, 0),
        ]
        if k % 10 == 0:
            out.append(mav.heartbeat_encode(2, 3, 0x81, 5, 4))
        return [bytes(m.pack(mav)) for m in out]

    def tick_data(self, k: int) -> TickData:
        """Tick k's data."""
        rng = random.Random(f"{self.seed}:{k}")
        stream = b"".join(
            (rng.randbytes(rng.choice((0, 0, 1, 7))) if rng.random() < 0.3 else b"") + f
            for f in self.frames(k)
        )
        cuts = sorted(rng.sample(range(1, len(stream)), rng.randint(0, 3)))
        rx = [stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True)]
        self._gcs.seq = k % 256
        tx = bytes(self._gcs.heartbeat_encode(6, 8, 0, 0, 4).pack(self._gcs))
        radio_in = [(rng.randint(1, 9), rng.randbytes(rng.randint(1, 60))) for _ in range(2)]
        row = TickRow(
            tick=k,
            clock_s=k * TICK_S,
            unix_ns=T0_NS + k * TICK_NS,
            lat=-35.3623344 + 1e-6 * k,
            lon=149.1657865 - 7e-7 * k,
            alt=10.0 + 0.01 * k,
            north=0.1 * k,
            east=-0.05 * k,
            yaw=rng.random(),
            voltage=12.1 - 0.001 * k,
            battery_percent=80.0 - 0.01 * k,
            status="ok",
            armed=k > 5,
            rc_cmd=rng.choice((0, 0, 1, 2)),
            order_kind=rng.choice(("", "goto", "land")),
            order_args=tuple(rng.random() for _ in range(rng.randint(0, 3))),
            events=tuple(rng.choice(("geofence", "low battery")) for _ in range(rng.randint(0, 2))),
            state=rng.choice(("", "IDLE", "TASK")),
            digest=rng.randbytes(32),
            log=tuple(f"log {k}.{i}" for i in range(rng.randint(0, 2))),
        )
        return TickData(rx, tx, radio_in, rng.randbytes(rng.randint(1, 40)), row)

    def write_tick(self, w: BagWriter, k: int) -> None:
        """Record tick k."""
        d = self.tick_data(k)
        ns = T0_NS + k * TICK_NS
        for chunk in d.rx:
            w.autopilot_rx(k, chunk, ns)
        for sender, data in d.radio_in:
            w.radio_in(k, sender, data, ns)
        w.autopilot_tx(k, d.tx, ns)
        w.radio_out(k, ROBOT, d.radio_out, ns)
        w.tick(d.row)


def record(w: BagWriter, sample: Sample, ticks: int) -> None:
    """Write the meta and ticks 0..ticks-1."""
    w.meta(sample.meta)
    for k in range(ticks):
        sample.write_tick(w, k)


def expected(sample: Sample, ticks: int) -> dict[str, list[Any]]:
    """What a reader should return for ticks 0..ticks-1 (rows without their stamps)."""
    out: dict[str, list[Any]] = {"rx": [], "tx": [], "in": [], "out": [], "ticks": []}
    for k in range(ticks):
        d = sample.tick_data(k)
        out["rx"] += [(k, c) for c in d.rx]
        out["tx"].append((k, d.tx))
        out["in"] += [(k, s, b) for s, b in d.radio_in]
        out["out"].append((k, ROBOT, d.radio_out))
        out["ticks"].append(d.row)
    return out


def read_back(r: BagReader) -> dict[str, list[Any]]:
    """What a reader returns, in the shape of `expected`."""

    def serial(rows: Any) -> list[tuple[int, bytes]]:
        return [(c.tick, c.data) for c in rows if isinstance(c, SerialChunk)]

    def radio(rows: Any) -> list[tuple[int, int, bytes]]:
        return [(f.tick, f.sender, f.data) for f in rows if isinstance(f, RadioFrame)]

    return {
        "rx": serial(r.autopilot_rx()),
        "tx": serial(r.autopilot_tx()),
        "in": radio(r.radio_in()),
        "out": radio(r.radio_out()),
        "ticks": list(r.ticks()),
    }


def check_prefix(r: BagReader, sample: Sample) -> int:
    """Assert that the reader holds exactly ticks 0..K of `sample` (nothing more, nothing
    partial); return K (-1 when it holds no tick)."""
    got = read_back(r)
    last = got["ticks"][-1].tick if got["ticks"] else -1
    want = expected(sample, last + 1)
    for key in want:
        assert got[key] == want[key], f"{key} differs from the sample's ticks 0..{last}"
    assert r.meta == sample.meta
    return last


__all__ = [
    "ROBOT",
    "T0_NS",
    "TICK_NS",
    "TICK_S",
    "Sample",
    "TickData",
    "check_prefix",
    "expected",
    "meta",
    "read_back",
    "record",
]
