"""One robot's messaging: received payloads in, decoded and dispatched; queued messages out.

The host drives it once per step, in the reference's order (wire spec §10.6):

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
from typing import Any

from bvm import wire
from bvm.errors import BuzzError
from bvm.inbox import Inbox
from bvm.outbox import Outbox
from bvm.values import Table

_log = logging.getLogger("bvm.net")

_Vm = Any

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
        values: tuple[Any, ...] = (msg.value,)  # type: ignore[attr-defined]
    elif kind in (wire.MsgType.VSTIG_PUT, wire.MsgType.VSTIG_QUERY):
        values = (msg.key, msg.value)  # type: ignore[attr-defined]
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


def _copy(v: Any) -> Any:
    """A deep copy of a plain decoded value."""
    if v.__class__ is not Table:
        return v
    return Table({k: _copy(x) if x.__class__ is Table else x for k, x in v.items()})


def _private(msg: wire.Message) -> wire.Message:
    """The shared message with tables of this VM's own."""
    if msg.type == wire.MsgType.BROADCAST:
        return wire.Broadcast(msg.topic, _copy(msg.value))  # type: ignore[attr-defined]
    return msg.__class__(  # type: ignore[call-arg]
        msg.vstig,  # type: ignore[attr-defined]
        _copy(msg.key),  # type: ignore[attr-defined]
        _copy(msg.value),  # type: ignore[attr-defined]
        msg.timestamp,  # type: ignore[attr-defined]
        msg.robot,  # type: ignore[attr-defined]
    )


class Network:
    """The in-queue, the out-queue and the counters of one VM."""

    def __init__(self, vm: _Vm) -> None:
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
        for sender, payload in self.inbox.drain():
            hit = _shared.get(payload)
            if hit is not None:
                msg = _private(hit[0]) if hit[1] else hit[0]
            else:
                try:
                    msg = wire.decode(payload, closure=self._closure)
                except wire.DecodeError as e:
                    self._dropped(sender, e)
                    continue
                tables = _sharing(msg)
                if tables is not None:
                    if len(_shared) >= _SHARED_MAX:
                        _shared.clear()
                    # The first decoding stays pristine; this VM works on a copy.
                    _shared[payload] = (msg, tables)
                    if tables:
                        msg = _private(msg)
            self.stats["received"] += 1
            kind = msg.type
            if kind == wire.MsgType.BROADCAST:
                vm.neighbors.deliver(msg.topic, msg.value, sender)
            elif kind == wire.MsgType.VSTIG_PUT:
                vm.stigmergies.on_put(msg)
            elif kind == wire.MsgType.VSTIG_QUERY:
                vm.stigmergies.on_query(msg, payload)
            elif kind == wire.MsgType.SWARM_LIST:
                vm.swarms.on_list(sender, msg.ids)
            elif kind == wire.MsgType.SWARM_JOIN:
                vm.swarms.on_join(sender, msg.swarm)
            else:
                vm.swarms.on_leave(sender, msg.swarm)
        vm.swarms.age()
        vm.stigmergies.end_step()

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
