"""Whether the ground station keeps up with a big swarm: 100 robots at 10 Hz, in one run.

    python bench/ground_throughput.py [--robots N] [--seconds T] [--signed] [--seed S]

N robots each send a bundle every 0.1 s (sealed with --signed, as a deployed swarm does: the
station then checks every tag), a third of them with Buzz messages up to the full budget,
and, once a second, a status frame of five records (their own and four passed on). The
station hears every one of them (the worst case: a ground station in range of the whole
swarm), ticks at 10 Hz, and makes the page's view four times a second (what the stream
sends, whatever the number of pages). Reported: the processing time over the time it stands
for (a ratio below 1 keeps up; the margin is what is left for the radio and the page's
server), per bundle and per view, and the size of one view on the stream.
"""

from __future__ import annotations

import argparse
import json
import random
import time

from fieldkit.ground.core import GroundStation
from fieldkit.robot import bundle as B
from fieldkit.robot import bundle_auth as A
from fieldkit.robot import geo, status
from fieldkit.robot.status import StatusRecord

HOME = geo.DEFAULT_HOME


def traffic(
    robots: int, seconds: float, seed: int, swarm_key: bytes | None
) -> list[list[tuple[int, bytes]]]:
    """Per tick, the (sender, air bytes) the station hears: bundles and status frames."""
    rng = random.Random(seed)
    bkey = A.bundle_key(swarm_key) if swarm_key is not None else None
    skey = status.status_key(bkey.secret) if bkey is not None else None
    sealers = {
        r: A.Sealer(r, bkey, A.MemoryCounter()) for r in range(1, robots + 1) if bkey is not None
    }
    budget = A.SEALED_MAX_BUZZ_BYTES if bkey is not None else B.MAX_BUZZ_BYTES
    ticks = []
    beats = dict.fromkeys(range(1, robots + 1), 0)

    def where(r: int, t: int) -> tuple[float, float]:
        return geo.offset_gps(*HOME, (r // 10) * 5.0, (r % 10) * 5.0 + 0.01 * t)

    for t in range(round(seconds * 10)):
        heard = []
        for r in range(1, robots + 1):
            lat, lon = where(r, t)
            kind = r % 3
            if kind == 0:
                messages: tuple[bytes, ...] = ()
            elif kind == 1:
                messages = tuple(rng.randbytes(rng.randint(3, 24)) for _ in range(3))
            else:
                messages = (rng.randbytes(budget - B.MSG_OVERHEAD),)
            data = B.encode_fields(r, messages, lat, lon, 5.0, t)
            heard.append((r, data if bkey is None else sealers[r].seal(data)))
            if (t + r) % 10 == 0:
                beats[r] += 1
                recs = []
                for k in range(status.MAX_RECORDS):
                    other = (r + k - 1) % robots + 1  # its own record, then four passed on
                    olat, olon = where(other, t)
                    recs.append(
                        StatusRecord(
                            other, beats[r], 80, 2, "running", 5.0, 0, olat, olon, "JOINED"
                        )
                    )
                heard.append((r, status.encode(r, recs, skey)))
        ticks.append(heard)
    return ticks


def measure(robots: int, seconds: float, seed: int, signed: bool) -> dict[str, object]:
    """Run the station on the traffic; its figures."""
    swarm_key = random.Random(seed).randbytes(32) if signed else None
    ticks = traffic(robots, seconds, seed, swarm_key)
    station = GroundStation(swarm_key=swarm_key, origin=HOME, update_view=False)
    hear_s = view_s = 0.0
    views = 0
    view_bytes = 0
    frames = 0
    for t, heard in enumerate(ticks):
        now = t * 0.1
        t0 = time.perf_counter()
        for sender, data in heard:
            station.hear(data, now, sender)
        station.tick(now)
        t1 = time.perf_counter()
        hear_s += t1 - t0
        frames += len(heard)
        if t % 25 == 0 or t % 25 == 12 or t % 25 == 6 or t % 25 == 18:  # ~4 Hz
            t2 = time.perf_counter()
            view_bytes = len(json.dumps(station.snapshot(), separators=(",", ":")))
            view_s += time.perf_counter() - t2
            views += 1
    busy = hear_s + view_s
    return {
        "robots": robots,
        "seconds": seconds,
        "signed": signed,
        "frames": frames,
        "robots_in_view": len(station.robots),
        "ratio": round(busy / seconds, 4),
        "us_per_frame": round(hear_s / frames * 1e6, 1),
        "ms_per_view": round(view_s / views * 1e3, 2),
        "view_bytes": view_bytes,
        "counters": dict(station.counters),
    }


def main(argv: list[str] | None = None) -> dict[str, object]:
    """Measure and print one line of figures (and the JSON)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robots", type=int, default=100)
    ap.add_argument("--seconds", type=float, default=30.0)
    ap.add_argument("--signed", action="store_true")
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args(argv)
    r = measure(a.robots, a.seconds, a.seed, a.signed)
    print(
        f"ground station, {r['robots']} robots at 10 Hz{' signed' if a.signed else ''}: "
        f"processing / real time {r['ratio']} ({r['us_per_frame']} us a frame, "
        f"{r['ms_per_view']} ms a view of {r['view_bytes']} bytes at 4 Hz)"
    )
    print(json.dumps(r, sort_keys=True))
    return r


if __name__ == "__main__":
    main()
