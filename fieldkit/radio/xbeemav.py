"""XbeeMav application packets and fragmentation (docs/bundle.md#xbeemav), and `XBeeRadio`.

Packets (RF data of one XBee frame), byte-compatible with XbeeMav:

* ``'S' | sysid | msgid | words``: a standard packet, when the packet (sysid, msgid and the
  big-endian payload64 words, S = 2 + 8·nwords bytes) is shorter than 250 bytes. Every
  ROSBuzz bundle (≤ 234 bytes) takes this path.
* ``'F' | packet_id | sender address | fragment index | offset (u16 BE) | ≤ 250 bytes``:
  a fragment of a larger packet, cut into 250-byte chunks; packet_id = msgid.
* ``'P' | packet_id | sender address | fragment count``: the end-of-packet ping.
* ``'A' | packet_id | acker address | missing indices...``: the answer to a ping; an empty
  list means complete.

Addresses are 8-bit robot ids. `XbeeMav` is the packet engine, with no I/O and an injected
clock. `fieldkit.radio.xbee_core.XBeeCore` wraps it in `fieldkit.radio.xbee` API frames (serial
bytes and time in, bytes and events out, still no I/O), and `fieldkit.radio.xbee_serial.XBeeRadio`
puts that core on a serial port.

Where we differ from XbeeMav, and why (none of it changes a byte on the air):

* Sizes: packets up to MAX_PACKET = 255 · 250 = 63,750 bytes (XbeeMav's own limit is 64,000,
  but a 256-fragment packet's count does not fit the ping's u8, so it can never complete);
  a packet of exactly 250 bytes is fragmented (XbeeMav silently drops it,
  docs/bundle.md#xbeemav-packet).
* Sending never blocks. Frames wait in queues that `pump()` drains at one frame per
  `interframe_s` on average (100 ms, docs/bundle.md#rate-limit; a token bucket of `burst`
  frames absorbs the node's tick jitter), adapted by ±5 ms after each large packet as
  XbeeMav does, within [½, 2] times the configured value. Acks go first; while a large
  packet is in flight, standard packets and the packet's frames alternate (XbeeMav holds
  standard packets back for the whole transfer, up to 30 s of a robot's heartbeat); the
  standard queue keeps the newest `max_standard_queue` packets (older ones are dropped and
  counted).
* A transfer's rounds: send the pending fragments, ping, wait `round_wait_s` (500 ms) for
  acks, resend what acks report missing (or only the ping when nothing was reported), until
  every known node has acked or `drop_timeout_s` (30 s of wall time; XbeeMav's constant is
  process CPU time) has passed. Known nodes are the robots heard (any packet, 'S' included;
  XbeeMav counts only F/P/A) within `node_ttl_s` (XbeeMav never forgets one, so a robot that
  left makes every later transfer run to the timeout). With no known node a transfer is one
  round. Nodes are identified by the link-level sender id, not the address byte.
* Reassembly: up to `max_partials_per_sender` packets in progress per sender (XbeeMav: 1, a
  new packet id resets it) and `max_partial_bytes` / `max_partials` in all, evicting the
  least recently active; fragments are stored by index and the packet is assembled only when
  the offsets tile it exactly, so duplicated and reordered fragments are harmless; a partial
  packet is dropped `drop_timeout_s` after its first fragment (XbeeMav's cleanup never fires).
  A ping for a packet of which nothing arrived is answered with every index missing
  (XbeeMav stays silent) so the sender resends.
* Duplicates: a delivered packet is remembered (CRC-32 of each fragment) for
  `drop_timeout_s`; its late retransmitted fragments are ignored and its pings acked as
  complete again (XbeeMav can deliver such a packet twice). A fragment whose CRC differs is
  a new packet reusing the id (msgid is 8 bits and ROSBuzz counts at 10 Hz: it wraps in
  25.6 s), which then starts afresh.
* Acks name the acker, not the packet's sender, so two robots sending large packets with the
  same packet id at once would each take the other's acks — as in XbeeMav.
* Payloads must be whole 8-byte words (XbeeMav serializes u64 words; a trailing partial word
  would be read past the end): `submit` refuses others, receivers count and drop them.

Counters (in `stats`): standard_out, fragments_out, pings_out, acks_out, resent_fragments,
standard_in, fragments_in, pings_in, acks_in, delivered, bad_packets (wrong size or tiling),
bad_fragments, bad_pings, bad_acks, unknown_packets (unknown first byte), empty_packets,
duplicate_fragments, conflicting_fragments, late_fragments (of a delivered packet), reacks,
partials_evicted, partials_expired, transfers_done, transfers_timeout, transfers_unacked,
dropped_standard, dropped_large, dropped_acks.
"""

from __future__ import annotations

import time
import zlib
from collections import Counter, OrderedDict, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from itertools import islice
from typing import Any

from fieldkit.errors import FrameError

from . import xbee
from .base import check_robot_id

FRAGMENT_DATA = 250
"""Packet bytes per fragment."""
FRAGMENT_HEADER = 6
"""'F', packet id, sender address, fragment index, offset (u16 BE)."""
STANDARD_LIMIT = 250
"""Packets (sysid + msgid + words) shorter than this travel as one 'S' packet."""
MAX_FRAGMENTS = 255
"""The ping's fragment count is a u8."""
MAX_PACKET = MAX_FRAGMENTS * FRAGMENT_DATA
"""The largest packet (sysid + msgid + words): 63,750 bytes."""
MAX_DATA = (MAX_PACKET - 2) // 8 * 8
"""The largest payload (whole words) `submit` takes: 63,744 bytes."""
MAX_RF_DATA = FRAGMENT_HEADER + FRAGMENT_DATA
"""The largest RF data the protocol produces: a full fragment, 256 bytes."""
MAX_ACK_MISSING = MAX_RF_DATA - 3
"""Missing indices one ack lists at most (the rest are asked for in the next round)."""
DEFAULT_BAUD = 230400
"""XbeeMav's and the profiles' baud rate (docs/bundle.md#xbeemav-settings)."""

STANDARD = b"S"[0]
"""First byte of a standard packet."""
FRAGMENT = b"F"[0]
"""First byte of a fragment."""
PING = b"P"[0]
"""First byte of an end-of-packet ping."""
ACK = b"A"[0]
"""First byte of an ack."""


def sender_byte(rf: bytes) -> int | None:
    """The sender id an XbeeMav packet names itself (sysid of 'S', address of F/P/A), or None."""
    if len(rf) >= 3 and rf[0] in (FRAGMENT, PING, ACK, STANDARD):
        return rf[1] if rf[0] == STANDARD else rf[2]
    return None


def msgid_of(data: bytes) -> int | None:
    """ROSBuzz's msgid for air bytes: the low 8 bits of a BUZZ_MESSAGE's message number."""
    if len(data) >= 8 and data[6] == 0 and data[7] == 2:  # word 0, big-endian: lane 0 = type 2
        return data[5]
    return None


def describe_packet(rf: bytes) -> dict[str, Any]:
    """The fields of one XbeeMav packet, the RF data of one frame, as JSON values.

    Keys: type ("S", "F", "P" or "A"), then for S sysid, msgid, payload64 (the words, each
    as 16 hex digits, big-endian as on the air); for F packet_id, address, index, offset,
    data (hex); for P packet_id, address, count; for A packet_id, address, missing (the
    indices; empty: complete). FrameError, naming the first bad byte, for exactly the
    packets `XbeeMav.receive` counts as bad, empty or unknown (tests hold the two together).
    """
    rf = bytes(rf)
    n = len(rf)
    if n == 0:
        raise FrameError("empty packet", 0)
    kind = rf[0]
    if kind == STANDARD:
        if n < 3:
            raise FrameError(f"standard packet of {n} bytes: 'S', sysid, msgid, then words", n)
        size = n - 3
        if size == 0:
            raise FrameError("standard packet without payload words", 3)
        if size % 8:
            raise FrameError(f"payload of {size} bytes ends in a partial word", n - size % 8)
        words = [rf[i : i + 8].hex() for i in range(3, n, 8)]
        return {"type": "S", "sysid": rf[1], "msgid": rf[2], "payload64": words}
    if kind == FRAGMENT:
        if n <= FRAGMENT_HEADER:
            what = f"fragment of {n} bytes: a {FRAGMENT_HEADER}-byte header, then data"
            raise FrameError(what, n)
        if n > MAX_RF_DATA:
            what = f"fragment of {n - FRAGMENT_HEADER} data bytes, at most {FRAGMENT_DATA}"
            raise FrameError(what, MAX_RF_DATA)
        index = rf[3]
        if index >= MAX_FRAGMENTS:
            raise FrameError(f"fragment index {index}, at most {MAX_FRAGMENTS - 1}", 3)
        offset = rf[4] << 8 | rf[5]
        if offset + n - FRAGMENT_HEADER > MAX_PACKET:
            what = f"fragment at offset {offset} ends past the largest packet ({MAX_PACKET})"
            raise FrameError(what, 4)
        return {
            "type": "F",
            "packet_id": rf[1],
            "address": rf[2],
            "index": index,
            "offset": offset,
            "data": rf[FRAGMENT_HEADER:].hex(),
        }
    if kind == PING:
        if n != 4:
            raise FrameError(f"ping of {n} bytes: 'P', packet id, address, count", min(n, 4))
        if rf[3] == 0:
            raise FrameError("ping for a packet of 0 fragments", 3)
        return {"type": "P", "packet_id": rf[1], "address": rf[2], "count": rf[3]}
    if kind == ACK:
        if n < 3:
            raise FrameError(f"ack of {n} bytes: 'A', packet id, address, missing...", n)
        return {"type": "A", "packet_id": rf[1], "address": rf[2], "missing": list(rf[3:])}
    raise FrameError(f"0x{kind:02x} is not an XbeeMav packet type (S, F, P, A)", 0)


def describe_frame(frame: bytes, api_mode: int = 1) -> dict[str, Any]:
    """`describe_packet` of RF data, or of the RF data of a whole XBee API frame (it starts
    with 0x7e, which no packet does): then the frame's own fields are under "xbee" and
    every FrameError offset counts from the frame's first byte."""
    frame = bytes(frame)
    if frame[:1] != bytes((xbee.START,)):
        return describe_packet(frame)
    return xbee.describe_inside(frame, describe_packet, api_mode)


@dataclass
class _Transfer:
    """One large packet being sent."""

    packet_id: int
    fragments: list[bytes]
    ping: bytes
    started: float
    deadline: float
    todo: deque[int]
    ping_due: bool = True
    pinged: bool = False
    waiting_until: float | None = None
    rounds: int = 0
    acked: set[int] = field(default_factory=set)
    missing: set[int] = field(default_factory=set)


@dataclass
class _Partial:
    """One large packet being received."""

    first: float
    frags: dict[int, tuple[int, bytes]] = field(default_factory=dict)
    size: int = 0


@dataclass
class _Delivered:
    """A packet recently delivered: when, and each fragment's CRC-32."""

    at: float
    crcs: tuple[int, ...]


class XbeeMav:
    """The XbeeMav packet protocol for one node: no I/O, an injected clock, bounded memory.

    `submit` queues a payload, `receive` takes the RF data of one received frame and returns
    the payload it completes (if any), `pump` returns the RF data of the frames due now.
    """

    def __init__(
        self,
        address: int,
        *,
        clock: Callable[[], float] = time.monotonic,
        stats: Counter[str] | None = None,
        interframe_s: float = 0.1,
        burst: int = 2,
        adapt_s: float = 0.005,
        round_wait_s: float = 0.5,
        drop_timeout_s: float = 30.0,
        node_ttl_s: float = 60.0,
        max_partials_per_sender: int = 2,
        max_partials: int = 64,
        max_partial_bytes: int = 1 << 20,
        max_delivered: int = 256,
        max_standard_queue: int = 10,
        max_large_queue: int = 4,
        max_ack_queue: int = 32,
    ) -> None:
        self.address = check_robot_id(address)
        self.clock = clock
        self.stats: Counter[str] = Counter() if stats is None else stats
        if interframe_s < 0 or burst < 1:
            raise ValueError("interframe_s must be >= 0 and burst >= 1")
        self.base_interframe_s = float(interframe_s)
        self.interframe_s = float(interframe_s)
        self.burst = burst
        self.adapt_s = adapt_s
        self.round_wait_s = round_wait_s
        self.drop_timeout_s = drop_timeout_s
        self.node_ttl_s = node_ttl_s
        self.max_partials_per_sender = max(1, max_partials_per_sender)
        self.max_partials = max(1, max_partials)
        self.max_partial_bytes = max(MAX_PACKET, max_partial_bytes)
        self.max_delivered = max_delivered
        self._standard: deque[bytes] = deque(maxlen=max(1, max_standard_queue))
        self._large: deque[tuple[bytes, int]] = deque(maxlen=max(1, max_large_queue))
        self._acks: deque[bytes] = deque(maxlen=max(1, max_ack_queue))
        self._transfer: _Transfer | None = None
        self._transfer_turn = False
        self._tokens = float(burst)
        self._last_refill = clock()
        self._nodes: dict[int, float] = {}
        self._partials: OrderedDict[tuple[int, int], _Partial] = OrderedDict()
        self._partial_bytes = 0
        self._per_sender: Counter[int] = Counter()
        self._delivered: OrderedDict[tuple[int, int], _Delivered] = OrderedDict()

    # ------------------------------------------------------------------ state

    @property
    def partial_bytes(self) -> int:
        """Bytes held in packets being reassembled."""
        return self._partial_bytes

    @property
    def partials(self) -> int:
        """Packets being reassembled."""
        return len(self._partials)

    @property
    def queued(self) -> int:
        """Frames and packets waiting to be sent (a transfer in flight counts as one)."""
        return (
            len(self._standard) + len(self._large) + len(self._acks) + (self._transfer is not None)
        )

    @property
    def transferring(self) -> bool:
        """Whether a large packet is being sent."""
        return self._transfer is not None

    def known_nodes(self) -> set[int]:
        """The other robots heard within `node_ttl_s`: those whose acks a transfer waits for."""
        now = self.clock()
        return {n for n, t in self._nodes.items() if now - t <= self.node_ttl_s}

    # ------------------------------------------------------------------ sending

    def pace(self, interframe_s: float) -> None:
        """From now on, one frame per `interframe_s` on average (the adaptation after large
        packets keeps within [1/2, 2] times it); ValueError if negative."""
        if interframe_s < 0:
            raise ValueError("interframe_s must be >= 0")
        self.base_interframe_s = self.interframe_s = float(interframe_s)

    def submit(self, data: bytes, msgid: int, sysid: int | None = None) -> None:
        """Queue one payload (whole big-endian words) for broadcast; ValueError if it cannot go.

        `sysid` defaults to this node's address, as ROSBuzz sets sysid = robot id.
        """
        data = bytes(data)
        if not data or len(data) % 8:
            raise ValueError(f"payload of {len(data)} bytes: must be whole 8-byte words")
        if len(data) > MAX_DATA:
            raise ValueError(f"payload of {len(data)} bytes, more than MAX_DATA={MAX_DATA}")
        packet = bytes((self.address if sysid is None else sysid & 0xFF, msgid & 0xFF)) + data
        if len(packet) < STANDARD_LIMIT:
            if len(self._standard) == self._standard.maxlen:
                self.stats["dropped_standard"] += 1
            self._standard.append(b"S" + packet)
        else:
            if len(self._large) == self._large.maxlen:
                self.stats["dropped_large"] += 1
            self._large.append((packet, msgid & 0xFF))

    def pump(self) -> list[bytes]:
        """The RF data of the frames due now, as pacing allows (call every tick)."""
        now = self.clock()
        self._expire(now)
        self._advance(now)
        if self.interframe_s > 0:
            self._tokens = min(
                float(self.burst), self._tokens + (now - self._last_refill) / self.interframe_s
            )
        else:
            self._tokens = float(self.burst)
        self._last_refill = now
        out: list[bytes] = []
        # (a hair under 1: fake clocks step in floats that do not add up exactly)
        while self._tokens >= 1 - 1e-9 or self.interframe_s <= 0:
            rf = self._next_frame(now)
            if rf is None:
                break
            out.append(rf)
            if self.interframe_s > 0:
                self._tokens -= 1
            self._advance(now)
        return out

    def _next_frame(self, now: float) -> bytes | None:
        if self._acks:
            self.stats["acks_out"] += 1
            return self._acks.popleft()
        t = self._transfer
        ready = t is not None and t.waiting_until is None and (bool(t.todo) or t.ping_due)
        if self._standard and not (ready and self._transfer_turn):
            self._transfer_turn = True
            self.stats["standard_out"] += 1
            return self._standard.popleft()
        if not ready or t is None:
            return None
        self._transfer_turn = False
        if t.todo:
            self.stats["fragments_out"] += 1
            return t.fragments[t.todo.popleft()]
        t.ping_due = False
        t.pinged = True
        t.waiting_until = now + self.round_wait_s
        self.stats["pings_out"] += 1
        return t.ping

    def _advance(self, now: float) -> None:
        """Start the next large packet, or move the current one to its next round or its end."""
        t = self._transfer
        if t is None:
            if not self._large:
                return
            packet, pid = self._large.popleft()
            chunks = [packet[o : o + FRAGMENT_DATA] for o in range(0, len(packet), FRAGMENT_DATA)]
            fragments = [
                bytes((FRAGMENT, pid, self.address, i)) + (i * FRAGMENT_DATA).to_bytes(2, "big") + c
                for i, c in enumerate(chunks)
            ]
            ping = bytes((PING, pid, self.address, len(chunks)))
            self._transfer = _Transfer(
                pid, fragments, ping, now, now + self.drop_timeout_s, deque(range(len(chunks)))
            )
            return
        known = self.known_nodes()
        if t.pinged and known and known <= t.acked:
            self._finish("transfers_done", t.rounds + 1)
        elif t.waiting_until is not None and now >= t.waiting_until:
            t.rounds += 1
            if not known:
                self._finish("transfers_unacked", 0)
            elif now >= t.deadline:
                self._finish("transfers_timeout", 0)
            else:
                t.todo = deque(sorted(t.missing))
                self.stats["resent_fragments"] += len(t.todo)
                t.missing.clear()
                t.ping_due = True
                t.waiting_until = None
        elif now >= t.deadline + self.round_wait_s:
            # Still sending long after the deadline (a huge packet behind a slow queue).
            self._finish("transfers_timeout", 0)

    def _finish(self, outcome: str, rounds: int) -> None:
        self.stats[outcome] += 1
        self._transfer = None
        if rounds and self.base_interframe_s > 0:
            # XbeeMav: faster after a one-round transfer, slower after one that needed more.
            step = -self.adapt_s if rounds == 1 else self.adapt_s
            lo, hi = self.base_interframe_s / 2, self.base_interframe_s * 2
            self.interframe_s = min(hi, max(lo, self.interframe_s + step))
        self._advance(self.clock())

    # ------------------------------------------------------------------ receiving

    def receive(self, sender: int, rf: bytes) -> bytes | None:
        """Handle the RF data of one frame from robot `sender`; the payload it completes, if any.

        Never raises: whatever `rf` holds only moves counters (and may queue an ack).
        """
        if not rf:
            self.stats["empty_packets"] += 1
            return None
        now = self.clock()
        kind = rf[0]
        if kind not in (STANDARD, FRAGMENT, PING, ACK):
            self.stats["unknown_packets"] += 1
            return None
        if sender != self.address:
            if sender not in self._nodes and len(self._nodes) >= 4096:
                self._forget_nodes(now)
            self._nodes[sender] = now
        if kind == STANDARD:
            self.stats["standard_in"] += 1
            data = rf[3:]
            if len(rf) < 3 or not data or len(data) % 8:
                self.stats["bad_packets"] += 1
                return None
            self.stats["delivered"] += 1
            return bytes(data)
        self._expire(now)
        if kind == FRAGMENT:
            self._fragment(sender, rf, now)
            return None
        if kind == PING:
            return self._ping(sender, rf, now)
        self._ack(sender, rf)
        return None

    def _forget_nodes(self, now: float) -> None:
        for n in [n for n, t in self._nodes.items() if now - t > self.node_ttl_s]:
            del self._nodes[n]
        while len(self._nodes) >= 4096:
            del self._nodes[next(iter(self._nodes))]

    def _fragment(self, sender: int, rf: bytes, now: float) -> None:
        self.stats["fragments_in"] += 1
        if len(rf) <= FRAGMENT_HEADER or len(rf) > MAX_RF_DATA:
            self.stats["bad_fragments"] += 1
            return
        pid, index = rf[1], rf[3]
        offset = rf[4] << 8 | rf[5]
        chunk = bytes(rf[FRAGMENT_HEADER:])
        if index >= MAX_FRAGMENTS or offset + len(chunk) > MAX_PACKET:
            self.stats["bad_fragments"] += 1
            return
        key = (sender, pid)
        done = self._delivered.get(key)
        if done is not None:
            if index < len(done.crcs) and zlib.crc32(chunk) == done.crcs[index]:
                self.stats["late_fragments"] += 1
                return
            del self._delivered[key]  # a new packet reusing the id
        partial = self._partials.get(key)
        if partial is None:
            partial = self._new_partial(key, now)
        else:
            self._partials.move_to_end(key)
        old = partial.frags.get(index)
        if old is not None:
            if old == (offset, chunk):
                self.stats["duplicate_fragments"] += 1
                return
            self.stats["conflicting_fragments"] += 1
            partial.size -= len(old[1])
            self._partial_bytes -= len(old[1])
        partial.frags[index] = (offset, chunk)
        partial.size += len(chunk)
        self._partial_bytes += len(chunk)
        while self._partial_bytes > self.max_partial_bytes:
            # Never the current one: it alone fits (255 fragments of <= 250 bytes <= the cap).
            victim = next((k for k in self._partials if k != key), None)
            if victim is None:
                break
            self._drop_partial(victim, "partials_evicted")

    def _new_partial(self, key: tuple[int, int], now: float) -> _Partial:
        sender = key[0]
        if self._per_sender[sender] >= self.max_partials_per_sender:
            victim = next(k for k in self._partials if k[0] == sender)
            self._drop_partial(victim, "partials_evicted")
        if len(self._partials) >= self.max_partials:
            self._drop_partial(next(iter(self._partials)), "partials_evicted")
        partial = _Partial(now)
        self._partials[key] = partial
        self._per_sender[sender] += 1
        return partial

    def _drop_partial(self, key: tuple[int, int], why: str | None) -> _Partial:
        partial = self._partials.pop(key)
        self._partial_bytes -= partial.size
        self._per_sender[key[0]] -= 1
        if not self._per_sender[key[0]]:
            del self._per_sender[key[0]]
        if why:
            self.stats[why] += 1
        return partial

    def _ping(self, sender: int, rf: bytes, now: float) -> bytes | None:
        self.stats["pings_in"] += 1
        if len(rf) != 4 or not 0 < rf[3] <= MAX_FRAGMENTS:
            self.stats["bad_pings"] += 1
            return None
        pid, count = rf[1], rf[3]
        key = (sender, pid)
        done = self._delivered.get(key)
        partial = self._partials.get(key)
        if partial is None:
            if done is not None and len(done.crcs) == count:
                self.stats["reacks"] += 1
                self._queue_ack(pid, ())
            else:
                self._queue_ack(pid, range(count))
            return None
        frags = partial.frags
        missing = [i for i in range(count) if i not in frags]
        if missing:
            self._queue_ack(pid, missing)
            return None
        self._drop_partial(key, None)
        packet = self._assemble(frags, count)
        if packet is None:
            self.stats["bad_packets"] += 1
            self._queue_ack(pid, range(count))
            return None
        crcs = tuple(zlib.crc32(frags[i][1]) for i in range(count))
        self._delivered[key] = _Delivered(now, crcs)
        self._delivered.move_to_end(key)
        while len(self._delivered) > self.max_delivered:
            self._delivered.popitem(last=False)
        self._queue_ack(pid, ())
        self.stats["delivered"] += 1
        return packet[2:]

    @staticmethod
    def _assemble(frags: dict[int, tuple[int, bytes]], count: int) -> bytes | None:
        """The packet if fragments 0..count-1 tile it exactly and it holds whole words."""
        if len(frags) != count:
            return None  # fragments beyond the ping's count: not the packet the ping announces
        parts = []
        at = 0
        for i in range(count):
            offset, chunk = frags[i]
            if offset != at:
                return None
            parts.append(chunk)
            at += len(chunk)
        packet = b"".join(parts)
        if len(packet) < 10 or (len(packet) - 2) % 8:
            return None
        return packet

    def _queue_ack(self, pid: int, missing: Iterable[int]) -> None:
        listed = bytes(islice(missing, MAX_ACK_MISSING))
        if len(self._acks) == self._acks.maxlen:
            self.stats["dropped_acks"] += 1
        self._acks.append(bytes((ACK, pid, self.address)) + listed)

    def _ack(self, sender: int, rf: bytes) -> None:
        self.stats["acks_in"] += 1
        if len(rf) < 3:
            self.stats["bad_acks"] += 1
            return
        t = self._transfer
        if t is None or rf[1] != t.packet_id or not t.pinged:
            return
        n = len(t.fragments)
        missing = {i for i in rf[3:] if i < n}
        if len(rf) == 3:
            t.acked.add(sender)
        elif missing:
            t.missing |= missing
        else:
            self.stats["bad_acks"] += 1

    def _expire(self, now: float) -> None:
        limit = now - self.drop_timeout_s
        stale = [k for k, p in self._partials.items() if p.first < limit]
        for k in stale:
            self._drop_partial(k, "partials_expired")
        while self._delivered:
            k, d = next(iter(self._delivered.items()))
            if d.at >= limit:
                break
            del self._delivered[k]
