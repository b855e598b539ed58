"""The XBee radio's protocol core: serial bytes and time in, API frames and events out; no I/O.

`XBeeCore` is one robot's end of an XBee line in the manner of h11: it never touches a port or
reads a clock. Its caller (the transport, `fieldkit.radio.xbee_serial.XBeeRadio`, or a test)
feeds it what came off the line and the time, and takes back the frames to write:

    core = XBeeCore(robot_id, id_map=..., now=clock())
    core.submit(air_bytes)                          # a bundle to broadcast
    for event in core.receive_data(port.read(), clock()):
        ...                                         # PacketReceived, TransmitReport, ModemEvent
    for frame in core.frames_to_send(clock()):      # 0x10 frames, paced by XbeeMav's rules
        port.write(frame)

Inside, `fieldkit.radio.xbee.FrameReader` de-frames the line, the `IdTable` names the sender of
each receive packet (0x90), `fieldkit.radio.xbeemav.XbeeMav` reassembles, acks and paces the
packets, and `transmit_request` frames what it sends exactly as XbeeMav does. Nothing a line
delivers raises: bad frames, strangers and malformed packets only move counters in `stats`.

Counters (in `stats`, shared with the reader and the engine): bytes_in, tx_status, tx_failed
(status frames reporting a delivery failure), modem_status, ignored_frames (other frame types),
unknown_senders, dropped_unknown.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from .base import IdTable, UnknownSenders, check_policy, check_robot_id
from .xbee import (
    API_MODES,
    XBEEMAV_DEST16,
    FrameReader,
    ModemStatus,
    ReceivePacket,
    TransmitStatus,
    transmit_request,
)
from .xbeemav import XbeeMav, msgid_of, sender_byte


@dataclass(frozen=True, slots=True)
class PacketReceived:
    """A payload from robot `sender`: an 'S' packet, or a fragmented packet now complete."""

    sender: int
    data: bytes


@dataclass(frozen=True, slots=True)
class TransmitReport:
    """The module's transmit status (0x8B) for one of our frames: status 0 is delivered."""

    frame_id: int
    delivery_status: int

    @property
    def failed(self) -> bool:
        """Whether the module reports a delivery failure."""
        return self.delivery_status != 0


@dataclass(frozen=True, slots=True)
class ModemEvent:
    """A modem status frame (0x8A): 0 hardware reset, 1 watchdog reset, ..."""

    status: int


RadioEvent = PacketReceived | TransmitReport | ModemEvent
"""What `XBeeCore.receive_data` reports."""


class XBeeCore:
    """One robot's XbeeMav node on an XBee API line, without I/O: fed bytes and time."""

    def __init__(
        self,
        robot_id: int,
        *,
        api_mode: int = 1,
        id_map: IdTable | Mapping[str, int] | Mapping[int, int] | None = None,
        unknown: str = "drop",
        frame_id: int = 1,
        dest16: int = XBEEMAV_DEST16,
        idle_flush_s: float = 0.1,
        now: float = 0.0,
        stats: Counter[str] | None = None,
        **engine_options: Any,
    ) -> None:
        """A node at time `now`; `engine_options` (`interframe_s`, ...) go to `XbeeMav`.

        `id_map` maps XBee serials to robot ids; `unknown` says what to do with frames from
        other serials (see `fieldkit.radio.base`). `idle_flush_s`: how long the line must be
        quiet before a partial frame counts as truncated.
        """
        if api_mode not in API_MODES:
            raise ValueError(f"API mode must be 1 or 2, got {api_mode!r}")
        self.robot_id = check_robot_id(robot_id)
        self.api_mode = api_mode
        self.ids = id_map if isinstance(id_map, IdTable) else IdTable(id_map)
        self.unknown: UnknownSenders = check_policy(unknown)
        self.frame_id = frame_id
        self.dest16 = dest16
        self.idle_flush_s = idle_flush_s
        self.stats: Counter[str] = Counter() if stats is None else stats
        # The engine reads time through a clock: make it the time this core was last fed, so
        # its timers follow the caller's time and never the wall clock.
        self._now = now
        self.reader = FrameReader(api_mode, stats=self.stats)
        self.engine = XbeeMav(robot_id, clock=self._fed_time, stats=self.stats, **engine_options)
        self._last_rx = now
        self._msgid = 0

    def _fed_time(self) -> float:
        return self._now

    def submit(self, data: bytes) -> None:
        """Queue one bundle's air bytes (whole 8-byte words) for broadcast; ValueError if not.

        The msgid is a BUZZ_MESSAGE's message number as ROSBuzz derives it (so a bundle leaves
        in the very frame ROSBuzz's XbeeMav would write), otherwise a counter of our own.
        """
        msgid = msgid_of(data)
        if msgid is None:
            self._msgid = (self._msgid + 1) & 0xFF
            msgid = self._msgid
        self.engine.submit(data, msgid)

    def receive_data(self, data: bytes, now: float) -> list[RadioEvent]:
        """What the line delivered by `now` (b"" if nothing): the events it completes.

        An empty `data` still matters: once the line has been quiet for `idle_flush_s`, a
        partial frame is abandoned as truncated so it cannot hold back later frames.
        """
        self._now = now
        if data:
            self.stats["bytes_in"] += len(data)
            self._last_rx = now
            frames = self.reader.feed(data)
        elif self.reader.pending and now - self._last_rx >= self.idle_flush_s:
            frames = self.reader.flush()
        else:
            return []
        events: list[RadioEvent] = []
        for frame in frames:
            if isinstance(frame, ReceivePacket):
                got = self._received(frame)
                if got is not None:
                    events.append(got)
            elif isinstance(frame, TransmitStatus):
                self.stats["tx_status"] += 1
                if frame.delivery_status:
                    self.stats["tx_failed"] += 1
                events.append(TransmitReport(frame.frame_id, frame.delivery_status))
            elif isinstance(frame, ModemStatus):
                self.stats["modem_status"] += 1
                events.append(ModemEvent(frame.status))
            else:
                self.stats["ignored_frames"] += 1
        return events

    def frames_to_send(self, now: float) -> list[bytes]:
        """The API frames (0x10) due by `now`, as XbeeMav's pacing allows; call every tick."""
        self._now = now
        return [
            transmit_request(rf, frame_id=self.frame_id, dest16=self.dest16, api_mode=self.api_mode)
            for rf in self.engine.pump()
        ]

    def reset(self) -> None:
        """Forget a partial frame (the port was reopened: its rest will never come)."""
        self.reader.reset()

    def _received(self, frame: ReceivePacket) -> PacketReceived | None:
        sender = self.ids.lookup(frame.source64)
        if sender is None:
            self.stats["unknown_senders"] += 1
            if self.unknown == "drop":
                self.stats["dropped_unknown"] += 1
                return None
            sender = sender_byte(frame.rf_data)
            if sender is None:
                self.stats["dropped_unknown"] += 1  # not an XbeeMav packet: no id to take
                return None
        data = self.engine.receive(sender, frame.rf_data)
        return None if data is None else PacketReceived(sender, data)
