"""A `Flight` into a bag and back: the bag is the storage, the Flight what node and replay use.

`FlightBag(writer)` streams a node's flight into a `BagWriter`: `start(flight)` once the node
is built (the meta, then the start-up bytes the recorder kept), then `tick(t)` for each tick
as it ends (`FlightRecorder(..., keep=False, on_tick=bag.tick)`). `read_flight(path)` reads a
recording back into a Flight for `replay`. The Flight's meta (robot id, seed, home, start
time, the core's clock readings, security state: nothing secret) travels as the bag's
`config_json`; the start-up bytes as autopilot (and GPS) chunks of tick STARTUP_TICK.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from fieldkit.record.bag import BagError, BagReader, BagWriter, Meta, TickRow
from fieldkit.record.flight import Flight, FlightTick

#: The `tick` of the autopilot chunks before the first tick (the field is a uint32).
STARTUP_TICK = 0xFFFFFFFF

#: Flight meta keys that are Meta fields of their own, not part of config_json.
_OWN = ("robot_id", "seed", "script_name")


def _f(v: object) -> float:
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else math.nan


class FlightBag:
    """Streams one node's Flight into a BagWriter."""

    def __init__(self, writer: BagWriter) -> None:
        self.writer = writer
        self.robot_id = 0

    def start(self, flight: Flight) -> None:
        """The meta, then the start-up bytes: once, before the first tick."""
        meta = flight.meta
        self.robot_id = int(meta.get("robot_id", 0))  # type: ignore[call-overload]
        config = {k: v for k, v in meta.items() if k not in _OWN}
        first_ns = int(meta.get("started_unix_ns", 0))  # type: ignore[call-overload]
        w = self.writer
        w.meta(
            Meta(
                robot_id=self.robot_id,
                seed=int(meta.get("seed", 0)),  # type: ignore[call-overload]
                profile_toml=flight.profile_toml,
                config_json=json.dumps(config, sort_keys=True),
                script_name=str(meta.get("script_name", "")),
                bo=flight.bo,
                bdb=flight.bdb,
                bpos=flight.bpos,
                key_fingerprint=str(meta.get("key_fingerprint", "")),
                started_unix_ns=first_ns,
            )
        )
        for chunk in flight.startup_rx:
            w.autopilot_rx(STARTUP_TICK, chunk, first_ns)
        for chunk in flight.startup_tx:
            w.autopilot_tx(STARTUP_TICK, chunk, first_ns)
        for chunk in flight.startup_gps_rx:
            w.gps_rx(STARTUP_TICK, chunk, first_ns)

    def tick(self, t: FlightTick) -> None:
        """One tick's inputs and outputs, then its row (the writer flushes there)."""
        w = self.writer
        ns = t.unix_ns
        wheres = t.radio_where if len(t.radio_where) == len(t.radio_in) else None
        for k, (sender, data) in enumerate(t.radio_in):
            w.radio_in(t.tick, sender, data, ns, None if wheres is None else wheres[k])
        for patch in t.outbox:
            w.outbox(t.tick, patch, ns)
        for chunk in t.autopilot_rx:
            w.autopilot_rx(t.tick, chunk, ns)
        for at in t.stream_s:
            w.stream_send(t.tick, at, ns)
        for chunk in t.autopilot_tx:
            w.autopilot_tx(t.tick, chunk, ns)
        for chunk in t.gps_rx:
            w.gps_rx(t.tick, chunk, ns)
        for data in t.radio_out:
            w.radio_out(t.tick, self.robot_id, data, ns)
        s = t.sensors
        kind, args = t.order if t.order is not None else ("", ())
        w.tick(
            TickRow(
                tick=t.tick,
                clock_s=t.clock_s,
                unix_ns=ns,
                lat=_f(s.get("lat")),
                lon=_f(s.get("lon")),
                alt=_f(s.get("alt")),
                north=_f(s.get("north")),
                east=_f(s.get("east")),
                yaw=_f(s.get("yaw")),
                voltage=_f(s.get("voltage")),
                battery_percent=_f(s.get("battery_percent")),
                status=str(s.get("status", "")),
                armed=bool(s.get("armed", False)),
                rc_cmd=int(s.get("rc_cmd") or 0),  # type: ignore[call-overload]
                order_kind=kind,
                order_args=tuple(float(a) for a in args),
                events=tuple(t.events),
                state=t.state or "",
                digest=t.digest,
                log=tuple(t.log),
            )
        )


def read_flight(path: Path | str) -> Flight:
    """The Flight a recording holds (BagError if it is not one a replay can use)."""
    reader = BagReader(path)
    meta = reader.meta
    config = meta.config()
    flight = Flight(
        meta={**config, "robot_id": meta.robot_id, "seed": meta.seed,
              "script_name": meta.script_name},
        profile_toml=meta.profile_toml,
        bo=meta.bo,
        bdb=meta.bdb,
        bpos=meta.bpos,
    )  # fmt: skip
    by_tick: dict[int, FlightTick] = {}
    node_bag = config.get("core_time") is not None
    for row in reader.ticks():
        sensors: dict[str, object] = {
            "lat": row.lat, "lon": row.lon, "alt": row.alt, "north": row.north,
            "east": row.east, "yaw": row.yaw, "voltage": row.voltage,
            "battery_percent": row.battery_percent, "status": row.status,
            "armed": row.armed, "rc_cmd": row.rc_cmd,
        }  # fmt: skip
        by_tick[row.tick] = FlightTick(
            row.tick,
            row.clock_s,
            row.unix_ns,
            digest=row.digest,
            state=row.state or None,
            order=(row.order_kind, tuple(row.order_args)) if row.order_kind else None,
            events=list(row.events),
            log=list(row.log),
            sensors=sensors,
        )

    last_row = max(by_tick, default=-1)
    cut: set[int] = set()  # ticks the recording stopped in (a crash): not replayable

    def at(tick: int, what: str) -> FlightTick | None:
        t = by_tick.get(tick)
        if t is None:
            if node_bag:
                if tick > last_row:  # the node died during this tick: its row never came
                    cut.add(tick)
                    return None
                hint = "the bag is damaged; `fieldkit bag info` shows what it holds"
                raise BagError(path, f"{what} of tick {tick}, which has no tick row", hint)
            # An autopilot log's chunks have no tick rows: a tick is made by its first chunk.
            t = by_tick[tick] = FlightTick(tick, tick / 10.0, 0)
        return t

    for chunk in reader.autopilot_rx():
        if chunk.tick == STARTUP_TICK:
            flight.startup_rx.append(chunk.data)
        elif (t := at(chunk.tick, "autopilot bytes")) is not None:
            t.autopilot_rx.append(chunk.data)
            t.unix_ns = t.unix_ns or chunk.unix_ns
    for chunk in reader.autopilot_tx():
        if chunk.tick == STARTUP_TICK:
            flight.startup_tx.append(chunk.data)
        elif (t := at(chunk.tick, "autopilot bytes")) is not None:
            t.autopilot_tx.append(chunk.data)
    for chunk in reader.gps_rx():
        if chunk.tick == STARTUP_TICK:
            flight.startup_gps_rx.append(chunk.data)
        elif (t := at(chunk.tick, "GPS bytes")) is not None:
            t.gps_rx.append(chunk.data)
    for send in reader.stream_sends():
        if (t := at(send.tick, "a stream send")) is not None:
            t.stream_s.append(send.clock_s)
    for frame in reader.radio_in():
        if (t := at(frame.tick, "a radio frame")) is not None:
            t.radio_in.append((frame.sender, frame.data))
            t.radio_where.append((frame.east, frame.north))  # NaN: a real radio's
    for frame in reader.radio_out():
        if (t := at(frame.tick, "a radio frame")) is not None:
            t.radio_out.append(frame.data)
    for patch in reader.outbox():
        if (t := at(patch.tick, "an outbox patch")) is not None:
            t.outbox.append(patch.data)
    flight.ticks = [by_tick[k] for k in sorted(by_tick)]
    if cut:
        flight.meta["cut_at_tick"] = min(cut)  # what a crash left of the last tick
    return flight


__all__ = ["FlightBag", "STARTUP_TICK", "read_flight"]
