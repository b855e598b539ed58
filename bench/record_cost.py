"""What recording costs a node per tick, as a share of its 100 ms tick at 10 Hz.

    python bench/record_cost.py [--ticks N] [--repeat R] [--storage mcap|ros1|both]

One tick's worth of data, as a field node records it: three reads from the autopilot (its
telemetry at 10 Hz, ATTITUDE, GLOBAL_POSITION_INT, SYS_STATUS, VFR_HUD, a HEARTBEAT each
second, split at random points, line noise between frames), one write to it (a position
target, and our heartbeat each second), two radio frames in and one out (bundles of 60-180
bytes), then the tick row (with /fix and /battery). N such ticks go through a `BagWriter`
as the node uses it: the default flush (at the first tick boundary a second after the last,
on the ticks' own clock, 0.1 s per tick), syncing in the background thread. The time of each
tick's calls is taken alone (the data is made beforehand), best of R runs for the mean.

Reported per storage: the mean cost of a tick, the 99th percentile and the worst (the ticks
that flush), each as a share of the 100 ms tick (the limit is 10%), and the bytes a second
of flight takes on disk (what sizes the parts and the card). The share is the measured time
over the fixed tick period: a ratio to what a robot has, not to another measurement.
"""

from __future__ import annotations

import argparse
import random
import shutil
import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from pymavlink.dialects.v20 import all as mavlink2

from fieldkit.record.bag import BagReader, BagWriter, Meta, TickRow

TICK_S = 0.1
T0_NS = 1_767_225_600_000_000_000


@dataclass(frozen=True)
class Tick:
    """The calls of one tick."""

    rx: list[bytes]
    tx: bytes
    radio_in: list[tuple[int, bytes]]
    radio_out: bytes
    row: TickRow


def ticks(n: int, seed: int) -> list[Tick]:
    """n ticks of realistic data."""
    rng = random.Random(seed)
    ap = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    me = mavlink2.MAVLink(None, srcSystem=255, srcComponent=191)
    out = []
    for k in range(n):
        msgs = [
            ap.attitude_encode(k * 100, 0.01, 0.02, 1.5, 0.0, 0.0, 0.0),
            ap.global_position_int_encode(k * 100, -353_623_344 + k, 1_491_657_865, 600_000,
                                          10_000, 10, 0, 0, 9000),
            ap.sys_status_encode(0, 0, 0, 500, 12_100, 1_000, 80, 0, 0, 0, 0, 0, 0),
            ap.vfr_hud_encode(1.0, 1.0, 90, 50, 10.0, 0.0),
        ]  # fmt: skip
        if k % 10 == 0:
            msgs.append(ap.heartbeat_encode(2, 3, 0x81, 5, 4))
        stream = b"".join(
            (rng.randbytes(2) if rng.random() < 0.1 else b"") + bytes(m.pack(ap)) for m in msgs
        )
        cuts = sorted(rng.sample(range(1, len(stream)), 2))
        rx = [stream[: cuts[0]], stream[cuts[0] : cuts[1]], stream[cuts[1] :]]
        tx = bytes(
            me.set_position_target_global_int_encode(
                k * 100, 1, 1, 6, 0b1101_1111_1000, -353_623_344, 1_491_657_865, 10.0,
                0, 0, 0, 0, 0, 0, 0, 0,
            ).pack(me)
        )  # fmt: skip
        if k % 10 == 0:
            tx += bytes(me.heartbeat_encode(6, 8, 0, 0, 4).pack(me))
        row = TickRow(
            tick=k,
            clock_s=k * TICK_S,
            unix_ns=T0_NS + k * 100_000_000,
            lat=-35.36 + 1e-7 * k,
            lon=149.16,
            alt=10.0,
            north=float(k),
            east=0.0,
            yaw=1.5,
            voltage=12.1,
            battery_percent=80.0,
            status="ok",
            armed=True,
            rc_cmd=0,
            order_kind="goto",
            order_args=(-35.36, 149.16, 10.0),
            events=(),
            state="TASK",
            digest=rng.randbytes(32),
            log=(f"tick {k}",) if k % 5 == 0 else (),
        )
        radio_in = [(rng.randint(1, 6), rng.randbytes(rng.randint(60, 180))) for _ in range(2)]
        out.append(Tick(rx, tx, radio_in, rng.randbytes(rng.randint(60, 180)), row))
    return out


def record(path: Path, data: list[Tick]) -> tuple[list[float], int]:
    """Record the ticks at `path`; the seconds each tick's calls took, and the bytes written."""
    now = [0.0]
    w = BagWriter(path, clock=lambda: now[0])  # the defaults: flush_s 1.0, fsync on
    w.meta(Meta(robot_id=3, script_name="bench.bzz", bo=bytes(4000), started_unix_ns=T0_NS))
    costs = []
    clock = time.perf_counter
    for t in data:
        ns = t.row.unix_ns
        k = t.row.tick
        start = clock()
        for chunk in t.rx:
            w.autopilot_rx(k, chunk, ns)
        for sender, frame in t.radio_in:
            w.radio_in(k, sender, frame, ns)
        w.autopilot_tx(k, t.tx, ns)
        w.radio_out(k, 3, t.radio_out, ns)
        w.tick(t.row)
        costs.append(clock() - start)
        now[0] = (k + 1) * TICK_S
    w.close()
    size = sum(f.stat().st_size for p in w.parts for f in ([p] if p.is_file() else p.iterdir()))
    assert len(list(BagReader(path).ticks())) == len(data)  # the bench measures a recording
    return costs, size


def measure(n: int, repeat: int, storage: str, seed: int = 1) -> dict[str, float]:
    """Per-tick cost figures (seconds) and bytes per second of flight for one storage."""
    data = ticks(n, seed)
    root = Path(tempfile.mkdtemp(prefix="record-cost-"))
    try:
        runs = []
        size = 0
        for i in range(repeat):
            path = root / (f"r{i}.bag" if storage == "ros1" else f"r{i}")
            costs, size = record(path, data)
            runs.append(costs)
        best = min(runs, key=statistics.fmean)
        ordered = sorted(best)
        return {
            "mean": statistics.fmean(best),
            "p99": ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))],
            "max": ordered[-1],
            "bytes_per_s": size / (n * TICK_S),
        }
    finally:
        shutil.rmtree(root, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--ticks", type=int, default=3000, help="ticks per run (10 per second)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--storage", choices=("mcap", "ros1", "both"), default="both")
    args = ap.parse_args(argv)
    for storage in ("mcap", "ros1") if args.storage == "both" else (args.storage,):
        f = measure(args.ticks, args.repeat, storage)
        share = {k: 100 * f[k] / TICK_S for k in ("mean", "p99", "max")}
        print(
            f"{storage:4s}: {1e3 * f['mean']:.2f} ms per tick = {share['mean']:.2f}% of the "
            f"100 ms tick (p99 {share['p99']:.2f}%, worst {share['max']:.2f}%); "
            f"{f['bytes_per_s'] / 1024:.1f} KiB per second of flight"
        )
    print(f"({args.ticks} ticks, best of {args.repeat}; limit: 10% of the tick)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
