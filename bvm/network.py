"""One robot's messaging: received payloads in, decoded and dispatched; queued messages out.

The host drives it once per step, in the reference's order (docs/wire-format.md#step-order):

    vm.receive(sender, payload)   # as payloads arrive
    vm.process_inbox()            # apply them: listeners, stigmergy, swarm memberships
    vm.set_neighbors([...])       # this step's neighbors
    vm.call("step")
    vm.drain_outbox(budget)       # what to send now

Nothing a peer sends can raise out of here: a payload that does not decode is counted
(`stats["decode_errors"]`) and logged, and the next one is processed. Errors raised by the
script's own listeners and conflict handlers are script errors and propagate like any.
"""

from __future__ import annotations

import collections
import logging
from typing import TYPE_CHECKING, Any

from bvm import wire
from bvm.errors import BuzzError
from bvm.inbox import Inbox
from bvm.outbox import Outbox
from bvm.values import Table, copy_tree

if TYPE_CHECKING:
    from bvm.host import LibraryHost

_log = logging.getLogger("bvm.net")

# Robots that receive the same bytes (a broadcast heard by every neighbour, in the
# simulator or on a shared host) share one decoding: payload -> (message, whether it holds
# tables). Tables are mutable, so each VM gets its own copy of them (copying a small table
# costs a fraction of decoding it); closures belong to one VM, so messages holding one are
# decoded by every VM. Bounded: cleared when full.
_shared: dict[bytes, tuple[wire.Message, bool]] = {}
_SHARED_MAX = 8192
_SCALARS = (int, float, str, type(None))


def _sharing(msg: wire.Message) -> bool | None:
    """None if the message cannot be shared (it holds a closure); else whether it holds
    tables (then each VM must copy them)."""
    kind = msg.type
    if kind == wire.MsgType.BROADCAST:
        values: tuple[Any, ...] = (msg.value,)  # type: ignore[attr-defined]  # the kind test says which message
    elif kind in (wire.MsgType.VSTIG_PUT, wire.MsgType.VSTIG_QUERY):
        values = (msg.key, msg.value)  # type: ignore[attr-defined]  # the kind test says which message
    else:
        return False
    tables = False
    for v in values:
        if v.__class__ in _SCALARS:
            continue
        if v.__class__ is not Table or not _plain(v):
            return None
        tables = True
    return tables


def _plain(t: Table) -> bool:
    """Whether a table holds only scalars and plain tables (decoded values are trees)."""
    for v in t.values():
        if v.__class__ not in _SCALARS and (v.__class__ is not Table or not _plain(v)):
            return False
    return True


def _private(msg: wire.Message) -> wire.Message:
    """The shared message with tables of this VM's own."""
    if msg.type == wire.MsgType.BROADCAST:
        return wire.Broadcast(msg.topic, copy_tree(msg.value))  # type: ignore[attr-defined]  # the kind test says which message
    return msg.__class__(  # type: ignore[call-arg]  # a VSTIG message: its class takes these fields
        msg.vstig,  # type: ignore[attr-defined]  # the kind test says which message
        copy_tree(msg.key),  # type: ignore[attr-defined]  # the kind test says which message
        copy_tree(msg.value),  # type: ignore[attr-defined]  # the kind test says which message
        msg.timestamp,  # type: ignore[attr-defined]  # the kind test says which message
        msg.robot,  # type: ignore[attr-defined]  # the kind test says which message
    )


class Network:
    """The in-queue, the out-queue and the counters of one VM."""

    def __init__(self, vm: LibraryHost) -> None:
        self.vm = vm
        self.stats: collections.Counter[str] = collections.Counter()
        self.inbox = Inbox(self.stats)
        self.outbox = Outbox(self.stats)

    def broadcast(self, topic: str, value: Any) -> None:
        """Queue a BROADCAST of a snapshot of `value` (neighbors.broadcast)."""
        try:
            payload = wire.encode(wire.Broadcast(topic, value))
        except wire.EncodeError as e:
            raise BuzzError(f"neighbors.broadcast: cannot send {topic!r}: {e}") from None
        self.outbox.broadcast(payload)

    def receive(self, sender: int, payload: bytes) -> None:
        """Queue one received payload from robot `sender` (processed at the next step)."""
        if not isinstance(sender, int) or not 0 <= sender <= 0xFFFF:
            raise ValueError(f"sender id must be an int in 0..65535, got {sender!r}")
        self.inbox.append(sender, bytes(payload))

    def process_inbox(self) -> None:
        """Apply every queued payload, in the reference's order, then age swarm records."""
        vm = self.vm
        stigmergies, swarms = vm.stigmergies, vm.swarms
        on_put, on_query, deliver = stigmergies.on_put, stigmergies.on_query, vm.neighbors.deliver
        shared = _shared
        received = 0
        tables: bool | None  # whether the message holds tables; None: it cannot be shared
        try:
            for sender, payload in self.inbox.drain():
                hit = shared.get(payload)
                if hit is not None:
                    msg, tables = hit
                    # Stigmergy copies a shared value only if it keeps it (it usually has
                    # that version already); a listener always gets its own.
                    if tables and (msg.type == 0 or msg.key.__class__ is Table):  # type: ignore[attr-defined]  # the kind test says which message
                        msg = _private(msg)
                        tables = False
                else:
                    try:
                        msg = wire.decode(payload, closure=self._closure)
                    except wire.DecodeError as e:
                        self._dropped(sender, e)
                        continue
                    tables = _sharing(msg)
                    if tables is not None:
                        if len(shared) >= _SHARED_MAX:
                            shared.clear()
                        # This VM keeps its decoding; the others share a pristine copy.
                        shared[payload] = (_private(msg) if tables else msg, tables)
                    tables = False
                received += 1
                # MsgType is an IntEnum: compare plain ints, most frequent kinds first.
                kind = msg.type
                if kind == 3:  # VSTIG_QUERY
                    on_query(msg, payload, tables)  # type: ignore[arg-type]  # by its kind
                elif kind == 2:  # VSTIG_PUT
                    on_put(msg, tables)  # type: ignore[arg-type]  # by its kind
                elif kind == 0:  # BROADCAST
                    deliver(msg.topic, msg.value, sender)  # type: ignore[attr-defined]  # the kind test says which message
                elif kind == 1:  # SWARM_LIST
                    swarms.on_list(sender, msg.ids)  # type: ignore[attr-defined]  # the kind test says which message
                elif kind == 4:  # SWARM_JOIN
                    swarms.on_join(sender, msg.swarm)  # type: ignore[attr-defined]  # the kind test says which message
                else:
                    swarms.on_leave(sender, msg.swarm)  # type: ignore[attr-defined]  # the kind test says which message
        finally:
            # Counted even when a listener's error ends the step early.
            self.stats["received"] += received
        self.age()

    def age(self) -> None:
        """`process_inbox` with nothing received: the swarm records and the stigmergies'
        forwarding memory still age by one step."""
        self.vm.swarms.age()
        self.vm.stigmergies.end_step()

    def _dropped(self, sender: int, e: wire.DecodeError) -> None:
        self.stats["decode_errors"] += 1
        n = self.stats["decode_errors"]
        if n <= 20 or n % 1000 == 0:  # a flood of garbage must not flood the log too
            _log.warning(
                "robot %d: dropped a message from robot %d (%d so far): %s",
                self.vm.robot_id,
                sender,
                n,
                e,
            )

    def drain(self, budget_bytes: int | None = None, overhead: int = 0) -> list[bytes]:
        """This step's messages to send (queues the periodic swarm list first)."""
        self.vm.swarms.tick()
        out = self.outbox.drain(budget_bytes, overhead)
        self.stats["sent"] += len(out)
        return out

    def _closure(self, native: bool, ref: int) -> Any:
        """A received closure value: a closure of this VM, or nil if `ref` is not one."""
        vm = self.vm
        if native:
            if 0 <= ref < len(vm.natives) and vm.natives[ref] is not None:
                return vm.native_closure(ref)
        elif vm.program is not None and vm.program.code_start <= ref < len(vm.program.bytecode):
            return vm.make_closure(ref, (None,))
        self.stats["bad_closures"] += 1
        return None
