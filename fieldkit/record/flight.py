"""One robot's flight as data: every input and output of every tick, in memory.

A `Flight` is what a recording holds and what a replay needs (docs/recording.md):

    meta          robot id, seed, home, the script's globals and commands, the node's start
                  time, the autopilot core's clock readings when the loop began, security
    profile_toml  the device profile, as text
    bo, bdb, bpos the script as it ran
    startup_rx/tx the autopilot's bytes before the first tick (heartbeat, streams, GPS fix)
    startup_gps_rx  a GPS receiver's bytes before the first tick (a base with its own GPS)
    ticks         per tick: its time, the radio frames in and out, the patches read from the
                  outbox (an originator's), the autopilot's bytes in and out, a separate GPS
                  receiver's bytes in, the times at which the link's own thread sent a frame
                  (the M100's movement stream), the script-state digest, the state, the
                  order, the supervisor's events, the script's lines, the sensors

`FlightRecorder` builds one from a node's hooks (`fieldkit.node.node.FlightRecorder`) and the
autopilot link's byte taps; each finished tick also goes to `on_tick`, so that a bag writer
can stream a long flight without keeping it (`keep=False`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from fieldkit.robot.runtime import TickRecord

#: The tick number of the autopilot's bytes before the first tick (start-up).
STARTUP = -1

#: The sensor fields a tick keeps (fieldkit.robot.script_api.Sensors).
SENSOR_FIELDS = (
    "lat",
    "lon",
    "alt",
    "north",
    "east",
    "yaw",
    "voltage",
    "current",
    "battery_percent",
    "status",
    "armed",
    "rc_cmd",
)


@dataclass
class FlightTick:
    """Everything one tick took in and gave out."""

    tick: int
    clock_s: float
    unix_ns: int
    radio_in: list[tuple[int, bytes]] = field(default_factory=list)
    #: Where each sender of `radio_in` was (east, north), when the host knew better than the
    #: bundle's GPS (the simulator; NaN for a frame whose sender it did not place); empty
    #: from a node.
    radio_where: list[tuple[float, float]] = field(default_factory=list)
    radio_out: list[bytes] = field(default_factory=list)
    #: Patches the node read from its outbox at the start of the tick (`--update-outbox`).
    outbox: list[bytes] = field(default_factory=list)
    autopilot_rx: list[bytes] = field(default_factory=list)
    autopilot_tx: list[bytes] = field(default_factory=list)
    #: Bytes read from a GPS receiver on a port of its own (a Clearpath base's), in order.
    gps_rx: list[bytes] = field(default_factory=list)
    #: The clock times (s) at which the link's own thread sent a frame before this tick's
    #: poll (the DJI movement stream); the frames' bytes are in `autopilot_tx`.
    stream_s: list[float] = field(default_factory=list)
    digest: bytes = b""
    state: str | None = None
    order: tuple[str, tuple[float, ...]] | None = None
    events: list[str] = field(default_factory=list)
    log: list[str] = field(default_factory=list)
    sensors: dict[str, object] = field(default_factory=dict)


@dataclass
class Flight:
    """A whole recording: what a replay needs, and nothing secret."""

    meta: dict[str, object]
    profile_toml: str
    bo: bytes
    bdb: bytes = b""
    bpos: bytes = b""
    startup_rx: list[bytes] = field(default_factory=list)
    startup_tx: list[bytes] = field(default_factory=list)
    startup_gps_rx: list[bytes] = field(default_factory=list)
    ticks: list[FlightTick] = field(default_factory=list)


class FlightRecorder:
    """A node's flight recorder: builds FlightTicks from the node's hooks and the taps."""

    def __init__(
        self,
        flight: Flight,
        *,
        keep: bool = True,
        on_tick: Callable[[FlightTick], None] | None = None,
    ) -> None:
        """Ticks go into `flight.ticks` if `keep`, and to `on_tick` as each one ends."""
        self.flight = flight
        self.keep = keep
        self.on_tick = on_tick
        self.current: FlightTick | None = None  # the tick running, if one is
        self.started = False  # a first tick began: start-up is over
        # Bytes crossing the port between two ticks: they count as the next tick's (a replay
        # feeds a tick's bytes before it runs, so the core sees them in the same order).
        self._next = FlightTick(0, 0.0, 0)

    # the autopilot link's taps
    def autopilot_rx(self, data: bytes) -> None:
        """Bytes read from the autopilot (before the first tick: start-up)."""
        self._bucket(self.flight.startup_rx, "rx").append(bytes(data))

    def autopilot_tx(self, data: bytes) -> None:
        """Bytes written to the autopilot."""
        self._bucket(self.flight.startup_tx, "tx").append(bytes(data))

    def gps_rx(self, data: bytes) -> None:
        """Bytes read from a GPS receiver on its own port (before the first tick: start-up)."""
        self._bucket(self.flight.startup_gps_rx, "gps").append(bytes(data))

    def stream_sent(self, clock_s: float) -> None:
        """The link's own thread sent a frame at `clock_s` (its bytes come to `autopilot_tx`).
        Start-up's are not kept: a replay restores the core's clock readings after it."""
        if self.current is not None or self.started:
            (self.current or self._next).stream_s.append(float(clock_s))

    def _bucket(self, startup: list[bytes], way: str) -> list[bytes]:
        t = self.current
        if t is None:
            if not self.started:
                return startup
            t = self._next
        return t.autopilot_rx if way == "rx" else t.autopilot_tx if way == "tx" else t.gps_rx

    # the node's hooks
    def begin_tick(self, tick: int, clock_s: float, unix_ns: int) -> None:
        """A tick begins."""
        self.started = True
        n = self._next
        self.current = FlightTick(
            tick, clock_s, unix_ns, autopilot_rx=n.autopilot_rx, autopilot_tx=n.autopilot_tx,
            gps_rx=n.gps_rx, stream_s=n.stream_s,
        )  # fmt: skip
        self._next = FlightTick(0, 0.0, 0)

    def radio_in(self, sender: int, data: bytes, where: tuple[float, float] | None = None) -> None:
        """A frame the radio handed in (`where` the sender was, if the host knows)."""
        cur = self.current
        assert cur is not None
        cur.radio_in.append((sender, bytes(data)))
        if where is not None:
            cur.radio_where.append(where)

    def radio_out(self, data: bytes) -> None:
        """A frame the node sent."""
        assert self.current is not None
        self.current.radio_out.append(bytes(data))

    def outbox_in(self, data: bytes) -> None:
        """A patch the node read from its outbox."""
        assert self.current is not None
        self.current.outbox.append(bytes(data))

    def end_tick(self, record: TickRecord, digest: bytes, log: list[str]) -> None:
        """The tick ran."""
        cur = self.current
        assert cur is not None
        cur.digest = digest
        cur.state = record.state
        cur.order = None if record.order is None else (record.order.kind, record.order.args)
        cur.events = list(record.events)
        cur.log = list(log)
        s = record.sensors
        cur.sensors = {name: getattr(s, name, None) for name in SENSOR_FIELDS}
        if self.keep:
            self.flight.ticks.append(cur)
        self.current = None
        if self.on_tick is not None:
            self.on_tick(cur)


__all__ = ["Flight", "FlightRecorder", "FlightTick", "SENSOR_FIELDS", "STARTUP"]
