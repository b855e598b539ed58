"""The incoming message queue of one robot (docs/wire-format.md#incoming-queue).

The reference keeps received payloads in a 20-bucket map keyed by sender id and drains it
sender by sender: buckets in order (`id % 20`), senders of one bucket in the order they
first arrived, and each sender's payloads newest first. fieldkit keeps that order, because
it decides the order listeners run in and the order gossip is re-sent in.

Unlike the reference, the queue is bounded: a flood of messages between two steps cannot
exhaust a robot's memory. Past the cap new payloads are dropped and counted.
"""

from __future__ import annotations

import collections
import logging

_log = logging.getLogger("bvm.net")

#: Payloads held at most between two steps.
MAX_PENDING = 10_000

#: The reference's bucket count: it fixes the order senders are processed in.
BUCKETS = 20


class Inbox:
    """Received payloads waiting for the next step, per sender."""

    def __init__(self, stats: collections.Counter[str], max_pending: int = MAX_PENDING) -> None:
        self.stats = stats
        self.max_pending = max_pending
        self._by_sender: dict[int, list[bytes]] = {}
        self._count = 0

    def __len__(self) -> int:
        """The number of pending payloads."""
        return self._count

    def append(self, sender: int, payload: bytes) -> bool:
        """Queue one payload from robot `sender`; False if the queue is full (dropped)."""
        if self._count >= self.max_pending:
            self.stats["inbox_overflow"] += 1
            if self.stats["inbox_overflow"] == 1:
                _log.warning("in-queue full (%d payloads): dropping", self.max_pending)
            return False
        queue = self._by_sender.get(sender)
        if queue is None:
            self._by_sender[sender] = [payload]
        else:
            queue.append(payload)
        self._count += 1
        return True

    def drain(self) -> list[tuple[int, bytes]]:
        """Remove and return every pending (sender, payload), in the reference's order."""
        by_sender = self._by_sender
        if not by_sender:
            return []
        self._by_sender = {}
        self._count = 0
        if len(by_sender) == 1:  # one sender this step (the common case): no order to find
            [(sender, payloads)] = by_sender.items()
            return [(sender, payload) for payload in reversed(payloads)]
        senders = sorted(by_sender, key=BUCKETS.__rmod__)  # s % BUCKETS; stable: arrival order
        return [(sender, payload) for sender in senders for payload in reversed(by_sender[sender])]
