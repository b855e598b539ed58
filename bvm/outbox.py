"""The outgoing message queue of one robot (docs/wire-format.md#outgoing-queue).

Six FIFO queues, drained in strict priority order: BROADCAST, SWARM_LIST, VSTIG_PUT,
VSTIG_QUERY, SWARM_JOIN, SWARM_LEAVE. Messages are serialized when queued, so what goes out
is a snapshot of the values at that moment (the reference deep-clones them) and its size is
known. The merging rules of the reference are kept, since they decide what peers see:

* PUT and QUERY for one (vstig id, key) share one slot: a new one is dropped if the queued
  one is at least as new (timestamp), else it replaces it at the end of its own queue.
* At most one SWARM_LIST is queued; queuing it cancels queued JOIN/LEAVEs, and while it is
  queued a JOIN/LEAVE edits its id list instead of queuing a message.
* A JOIN cancels a queued LEAVE of the same swarm and vice versa; duplicates are not queued.

Two flaws of the reference are fixed without changing any byte on the air (docs/compat.md):
a message larger than the whole byte budget is dropped (counted, logged) instead of
blocking the queue forever, and the queue has a cap (oldest broadcasts go first) instead of
growing without bound when a script broadcasts faster than the radio drains.
"""

from __future__ import annotations

import collections
import logging
from typing import Any

from bvm import wire

_log = logging.getLogger("bvm.net")

#: Queued messages kept at most; past it the oldest broadcast (else put, query) is dropped.
MAX_QUEUED = 4096


class Outbox:
    """Messages waiting to be sent, with the reference's priority and merging rules."""

    def __init__(self, stats: collections.Counter[str], max_queued: int = MAX_QUEUED) -> None:
        self.stats = stats
        self.max_queued = max_queued
        self._broadcasts: collections.deque[bytes] = collections.deque()
        self._list: dict[int, None] | None = None  # the queued SWARM_LIST's ids, if any
        # (vstig id, key) -> payload; dicts keep FIFO order and allow removal from the middle.
        self._puts: dict[tuple[int, Any], bytes] = {}
        self._queries: dict[tuple[int, Any], bytes] = {}
        self._stamps: dict[tuple[int, Any], int] = {}  # timestamp of the queued PUT/QUERY
        self._joins: dict[int, None] = {}
        self._leaves: dict[int, None] = {}

    def __len__(self) -> int:
        """The number of queued messages."""
        return (
            len(self._broadcasts)
            + (self._list is not None)
            + len(self._puts)
            + len(self._queries)
            + len(self._joins)
            + len(self._leaves)
        )

    # ------------------------------------------------------------ queuing

    def broadcast(self, payload: bytes) -> None:
        """Queue a serialized BROADCAST (never merged: every call is a message)."""
        self._broadcasts.append(payload)
        self._bound()

    def vstig(self, msg: wire.VstigPut | wire.VstigQuery, key: Any) -> None:
        """Queue a PUT or QUERY unless one at least as new is queued for the same key.

        `key` is the Buzz key (1 and 1.0 are one key); `msg.key` is what goes on the air.
        """
        slot = (msg.vstig, key)
        queued = self._stamps.get(slot)
        if queued is not None:
            if queued >= msg.timestamp:
                return
            self._puts.pop(slot, None)
            self._queries.pop(slot, None)
        queue = self._puts if msg.type == wire.MsgType.VSTIG_PUT else self._queries
        queue[slot] = wire.encode(msg)
        self._stamps[slot] = msg.timestamp
        self._bound()

    def swarm_list(self, ids: list[int]) -> None:
        """Queue a SWARM_LIST, replacing any queued LIST, JOIN and LEAVE."""
        self._joins.clear()
        self._leaves.clear()
        self._list = dict.fromkeys(ids)

    def join(self, swarm: int) -> None:
        """Queue a SWARM_JOIN (or add the id to the queued LIST)."""
        if self._list is not None:
            self._list[swarm] = None
            return
        self._leaves.pop(swarm, None)
        self._joins[swarm] = None

    def leave(self, swarm: int) -> None:
        """Queue a SWARM_LEAVE (or remove the id from the queued LIST)."""
        if self._list is not None:
            self._list.pop(swarm, None)
            return
        self._joins.pop(swarm, None)
        self._leaves[swarm] = None

    def _bound(self) -> None:
        # Only broadcasts, puts and queries grow with the script's calls; swarm messages
        # are merged per id.
        while len(self._broadcasts) + len(self._puts) + len(self._queries) > self.max_queued:
            if self._broadcasts:
                self._broadcasts.popleft()
            else:
                queue = self._puts or self._queries
                slot = next(iter(queue))
                del queue[slot]
                del self._stamps[slot]
            self.stats["outbox_overflow"] += 1
            if self.stats["outbox_overflow"] == 1 or self.stats["outbox_overflow"] % 1000 == 0:
                _log.warning(
                    "out-queue full (%d messages): dropped the oldest (%d dropped so far)",
                    self.max_queued,
                    self.stats["outbox_overflow"],
                )

    # ------------------------------------------------------------ draining

    def _head(self) -> bytes | None:
        """The payload of the next message to send, in priority order."""
        if self._broadcasts:
            return self._broadcasts[0]
        if self._list is not None:
            return wire.encode(wire.SwarmList(tuple(self._list)))
        for queue in (self._puts, self._queries):
            if queue:
                return queue[next(iter(queue))]
        if self._joins:
            return wire.encode(wire.SwarmJoin(next(iter(self._joins))))
        if self._leaves:
            return wire.encode(wire.SwarmLeave(next(iter(self._leaves))))
        return None

    def _pop(self) -> None:
        """Remove the message `_head` returned."""
        if self._broadcasts:
            self._broadcasts.popleft()
        elif self._list is not None:
            self._list = None
        elif self._puts or self._queries:
            queue = self._puts or self._queries
            slot = next(iter(queue))
            del queue[slot]
            del self._stamps[slot]
        elif self._joins:
            del self._joins[next(iter(self._joins))]
        else:
            del self._leaves[next(iter(self._leaves))]

    def drain(self, budget_bytes: int | None = None, overhead: int = 0) -> list[bytes]:
        """Dequeue the messages to send now, in order, within `budget_bytes`.

        Each message costs its length plus `overhead` (a transport's per-message framing).
        The first message that does not fit stops the drain (it goes first next time),
        except one that could never fit: it is dropped, counted and logged.
        """
        out: list[bytes] = []
        room = budget_bytes
        while True:
            payload = self._head()
            if payload is None:
                break
            cost = len(payload) + overhead
            if budget_bytes is not None and cost > room:  # type: ignore[operator]  # room is an int then
                if cost <= budget_bytes:
                    break
                self._pop()
                self.stats["oversize_dropped"] += 1
                _log.error(
                    "dropped a %d-byte message (type %d): larger than the %d-byte budget",
                    len(payload),
                    payload[0],
                    budget_bytes,
                )
                continue
            self._pop()
            out.append(payload)
            if room is not None:
                room -= cost
        return out
