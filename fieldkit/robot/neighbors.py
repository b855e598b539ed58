"""Who a robot hears, and where they are: the heard table and the one neighbour geometry.

A robot remembers, for every robot whose bundle it received, where that robot was when it
sent (east, north in the robot's local frame, metres) and the tick it was heard. Each tick
the table becomes the script's `neighbors`: distance and azimuth from where the robot is now
to where each sender was (recomputed every tick: ROSBuzz froze them at reception), rounded
to Buzz floats (binary32). A sender not heard for `NEIGHBOR_TIMEOUT_S` leaves the table.

Time is counted in the robot's own ticks, not on a wall clock, so a recorded flight replays
with the same neighbours; at the profile's loop rate a tick is one period.

`columns` does the geometry for any number of robots in one numpy pass: the simulator hands
it the whole swarm, the field node its one robot. Same arithmetic, same bits.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import TypeAlias

import numpy as np

#: A neighbour not heard from for this long is dropped from `neighbors`.
NEIGHBOR_TIMEOUT_S = 5.0

#: (east, north, tick heard) of one sender: where it was when it sent, in the local frame.
Heard: TypeAlias = tuple[float, float, int]

#: A heard table: sender id -> where and when it was last heard.
HeardTable: TypeAlias = dict[int, Heard]

#: One robot's neighbours this tick: ids, distances (m) and azimuths (rad), binary32 values.
Columns: TypeAlias = tuple[list[int], list[float], list[float]]


def timeout_ticks(loop_rate_hz: float) -> int:
    """`NEIGHBOR_TIMEOUT_S` in ticks of a loop running at `loop_rate_hz`."""
    return round(NEIGHBOR_TIMEOUT_S * loop_rate_hz)


def columns(
    tables: Sequence[HeardTable],
    here: Sequence[tuple[float, float]],
    now: int,
    timeout: int,
) -> list[Columns]:
    """Each table's neighbours seen from `here` (east, north) at tick `now`; drops, from the
    tables themselves, the senders last heard more than `timeout` ticks ago."""
    counts = [len(table) for table in tables]
    ids: list[int] = []
    entries: list[Heard] = []
    for table in tables:
        ids.extend(table)
        entries.extend(table.values())
    # (east, north, tick) of every entry in one array: faster than three Python lists.
    flat = np.fromiter(
        itertools.chain.from_iterable(entries), dtype=np.float64, count=3 * len(entries)
    ).reshape(-1, 3)
    stale = flat[:, 2] < now - timeout
    if stale.any():
        owner_of = np.repeat(np.arange(len(tables)), counts)
        for k in np.flatnonzero(stale).tolist():
            del tables[owner_of[k]][ids[k]]
        keep = ~stale
        flat = flat[keep]
        ids = [rid for rid, kept in zip(ids, keep.tolist(), strict=True) if kept]
        counts = np.bincount(owner_of[keep], minlength=len(tables)).tolist()
    origin = np.array(here, dtype=np.float64).reshape(-1, 2)
    east = flat[:, 0] - np.repeat(origin[:, 0], counts)
    north = flat[:, 1] - np.repeat(origin[:, 1], counts)
    # One numpy pass for every robot, rounded to Buzz floats (binary32) at once.
    distances = np.hypot(east, north).astype(np.float32).tolist()
    azimuths = np.arctan2(east, north).astype(np.float32).tolist()
    out: list[Columns] = []
    k = 0
    for n in counts:
        out.append((ids[k : k + n], distances[k : k + n], azimuths[k : k + n]))
        k += n
    return out


__all__ = ["NEIGHBOR_TIMEOUT_S", "Columns", "Heard", "HeardTable", "columns", "timeout_ticks"]
