"""Virtual stigmergy: a gossiped key-value store per id.

Facts: docs/stdlib.md#stigmergy, docs/wire-format.md#stigmergy.

Each entry holds (data, timestamp, robot): the timestamp is a per-key u16 version counter
and `robot` the robot that wrote the value. A local `put` bumps the version and gossips a
PUT; `get` returns the local value and always gossips a QUERY. A received PUT or QUERY that
is newer replaces the entry and is re-gossiped; an equal version from another robot is a
conflict, resolved by the script's `onconflict` or by the default rule (the higher robot
id wins, a nil value loses). These rules, the tombstones (a deleted key is stored as nil by
receivers) and the forwarding of queries for vstigs a robot has not created are those of
the reference, since every robot of a mixed team must converge on the same table.

Deliberate differences (docs/compat.md): the reference floods a QUERY for a key nobody
holds back and forth forever; fieldkit forwards such a query unchanged only if it has not
seen the same query in the last QUERY_QUIET steps. Method closures are made once (see
bvm/stdlib/swarm.py for why).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

from bvm import wire
from bvm.errors import BuzzError
from bvm.stdlib.base import expected
from bvm.values import Closure, Table, copy_tree, f2i, type_name

if TYPE_CHECKING:
    from bvm.host import LibraryHost

_log = logging.getLogger("bvm.net")

#: Steps a forwarded query must go unseen before the same query is forwarded again.
QUERY_QUIET = 10

#: Forwarded queries remembered at most (oldest forgotten first).
MAX_REMEMBERED = 1024


class Element:
    """One stigmergy entry: the data, its version and the robot that wrote it."""

    __slots__ = ("data", "timestamp", "robot")

    def __init__(self, data: Any, timestamp: int, robot: int) -> None:
        self.data = data
        self.timestamp = timestamp
        self.robot = robot

    def as_table(self) -> Table:
        """The {robot, data, timestamp} table handed to onconflict handlers."""
        t = Table(robot=self.robot, timestamp=self.timestamp)
        if self.data is not None:
            t["data"] = self.data
        return t


def _element(msg: wire.VstigPut | wire.VstigQuery, shared: bool) -> Element:
    """The element a received PUT or QUERY carries, with a value of this VM's own."""
    return Element(copy_tree(msg.value) if shared else msg.value, msg.timestamp, msg.robot)


def bucket(key: Any) -> int:
    """The reference's stigmergy hash bucket of a key (foreach goes bucket by bucket)."""
    cls = key.__class__
    if cls is int:
        return (key & 0xFFFFFFFF) % 10
    if cls is float:
        return (f2i(key) & 0xFFFFFFFF) % 10
    if cls is str:
        h = 5381
        for c in key.encode("latin-1"):
            h = (h * 33 + (c - 256 if c > 127 else c)) & 0xFFFFFFFF  # C's signed char
        return h % 10
    return 0  # nil; tables hash by address in C, which no other robot can reproduce


def check_key(key: Any) -> Any:
    """A stigmergy key: nil, a number (not NaN), a string or a table."""
    cls = key.__class__
    if cls is float and key != key:
        raise BuzzError("type mismatch: NaN can't be used as a stigmergy key")
    if key is not None and cls not in (int, float, str, Table):
        raise BuzzError(f"type mismatch: a {type_name(key)} can't be used as a stigmergy key")
    return key


class VStig:
    """One virtual stigmergy: key -> Element, plus its conflict handlers."""

    __slots__ = ("id", "entries", "onconflict", "onconflictlost")

    def __init__(self, vid: int) -> None:
        self.id = vid
        self.entries: dict[Any, Element] = {}
        self.onconflict: Closure | None = None
        self.onconflictlost: Closure | None = None

    def ordered(self) -> list[tuple[Any, Element]]:
        """Entries in the reference's foreach order (bucket, then insertion)."""
        return sorted(self.entries.items(), key=lambda kv: bucket(kv[0]))


class Stigmergies:
    """The virtual stigmergies of one VM and the gossip rules that keep them converging."""

    def __init__(self, vm: LibraryHost) -> None:
        self.vm = vm
        self.stores: dict[int, VStig] = {}
        self._methods: list[tuple[str, Closure]] | None = None
        self._forwarded: dict[bytes, int] = {}  # query payload -> step last seen
        self._step = 0

    # ------------------------------------------------------------ sending

    def _send(self, kind: type, vid: int, key: Any, e: Element) -> None:
        msg = kind(vid, key, e.data, e.timestamp, e.robot)
        try:
            self.vm.net.outbox.vstig(msg, key)
        except wire.EncodeError as err:
            raise BuzzError(f"stigmergy {vid}: cannot send key {key!r}: {err}") from None

    # ------------------------------------------------------------ receiving

    def on_put(self, msg: wire.VstigPut, shared: bool = False) -> None:
        """A received PUT (docs/wire-format.md#receiving-put). `shared`: its tables are other
        robots' too, so a value kept here is copied first."""
        vs = self.stores.get(msg.vstig)
        if vs is None:
            return  # not created here: dropped, not propagated (as the reference)
        local = vs.entries.get(msg.key)
        ts = msg.timestamp
        if local is None or local.timestamp < ts:
            remote = _element(msg, shared)
            self._store(vs, msg.key, remote)
            self._send(wire.VstigPut, vs.id, msg.key, remote)
        elif local.timestamp == ts and local.robot != msg.robot:
            self._conflict(vs, msg.key, local, _element(msg, shared))

    def on_query(self, msg: wire.VstigQuery, payload: bytes, shared: bool = False) -> None:
        """A received QUERY (docs/wire-format.md#receiving-query); `shared` as for on_put."""
        vs = self.stores.get(msg.vstig)
        local = vs.entries.get(msg.key) if vs is not None else None
        if vs is None or (local is None and msg.value is None):
            self._forward(msg, payload)
            return
        ts = msg.timestamp
        if local is None or local.timestamp < ts:
            remote = _element(msg, shared)
            self._store(vs, msg.key, remote)
            self._send(wire.VstigPut, vs.id, msg.key, remote)
        elif local.timestamp > ts:
            self._send(wire.VstigPut, vs.id, msg.key, local)  # the reply
        elif local.robot != msg.robot:
            self._conflict(vs, msg.key, local, _element(msg, shared))

    def _forward(self, msg: wire.VstigQuery, payload: bytes) -> None:
        """Re-send a query unchanged, unless the same one was seen lately (ends ping-pong)."""
        seen = self._forwarded.pop(payload, None)
        self._forwarded[payload] = self._step  # refreshed: moves to the newest end
        if len(self._forwarded) > MAX_REMEMBERED:
            del self._forwarded[next(iter(self._forwarded))]
        if seen is not None and self._step - seen <= QUERY_QUIET:
            self.vm.net.stats["queries_not_forwarded"] += 1
            return
        self.vm.net.outbox.vstig(msg, msg.key)

    def end_step(self) -> None:
        """One step passed (for the forwarding memory)."""
        self._step += 1

    def _store(self, vs: VStig, key: Any, e: Element) -> None:
        # Keep the original key object so 7 and 7.0 stay one entry with its first key.
        vs.entries[key] = e

    def _conflict(self, vs: VStig, key: Any, local: Element, remote: Element) -> None:
        """Equal versions from two robots: pick a winner, store it and gossip it."""
        vm = self.vm
        if vs.onconflict is not None:
            r = vm.invoke(vs.onconflict, (key, local.as_table(), remote.as_table()))
            robot = r["robot"] if r.__class__ is Table else None
            if robot.__class__ is not int:
                vm.net.stats["conflict_unresolved"] += 1
                _log.warning(
                    "stigmergy %d key %r: onconflict must return a table with an int robot",
                    vs.id,
                    key,
                )
                return
            winner = Element(r["data"], local.timestamp, robot & 0xFFFF)
        elif (local.data is None) == (remote.data is None):
            winner = local if local.robot > remote.robot else remote
        else:
            winner = local if local.data is not None else remote
        vs.entries[key] = winner
        if winner.robot != vm.robot_id and local.robot == vm.robot_id:
            if vs.onconflictlost is not None:
                vm.invoke(vs.onconflictlost, (key, local.as_table()))
        self._send(wire.VstigPut, vs.id, key, winner)

    # ------------------------------------------------------------ script side

    def _store_of(self, t: Any) -> VStig:
        vid = t["id"] if t.__class__ is Table else None
        vs = self.stores.get(vid) if vid.__class__ is int else None
        if vs is None:
            raise BuzzError(f"unknown virtual stigmergy id: {vid}")
        return vs

    def _table(self, vid: int) -> Table:
        if self._methods is None:
            self._methods = [
                (name, self.vm.new_native(impl, arity, f"stigmergy.{name}"))
                for name, impl, arity in self._vstig_methods()
            ]
        t = Table()
        t["id"] = vid
        for name, closure in self._methods:
            t[name] = closure.rebind(t)
        return t

    def _vstig_methods(self) -> list[tuple[str, Any, int]]:
        vm = self.vm
        failed = vm.call_failed

        def v_foreach(t: Any, f: Any) -> None:
            vs = self._store_of(t)
            if f.__class__ is not Closure:
                raise expected("closure", f)
            for key, e in vs.ordered():
                try:
                    f.fn(f, key, e.data, e.robot)
                except (TypeError, AttributeError) as err:
                    failed(err, f, (key, e.data, e.robot))

        def v_size(t: Any) -> int:
            return len(self._store_of(t).entries)

        def v_put(t: Any, key: Any, value: Any) -> None:
            vs = self._store_of(t)
            check_key(key)
            e = vs.entries.get(key)
            me = vm.robot_id
            if e is not None:
                if value is None:
                    self._send(wire.VstigPut, vs.id, key, Element(None, _inc(e.timestamp), me))
                    del vs.entries[key]
                    return
                e.data, e.timestamp, e.robot = value, _inc(e.timestamp), me
                self._send(wire.VstigPut, vs.id, key, e)
            elif value is not None:
                e = vs.entries[key] = Element(value, 1, me)
                self._send(wire.VstigPut, vs.id, key, e)

        def v_get(t: Any, key: Any) -> Any:
            vs = self._store_of(t)
            check_key(key)
            e = vs.entries.get(key)
            if e is None:
                self._send(wire.VstigQuery, vs.id, key, Element(None, 0, vm.robot_id))
                return None
            self._send(wire.VstigQuery, vs.id, key, e)
            return e.data

        def v_onconflict(t: Any, f: Any) -> None:
            if f.__class__ is not Closure:
                raise expected("closure", f)
            self._store_of(t).onconflict = f

        def v_onconflictlost(t: Any, f: Any) -> None:
            if f.__class__ is not Closure:
                raise expected("closure", f)
            self._store_of(t).onconflictlost = f

        return [
            ("foreach", v_foreach, 1),
            ("size", v_size, 0),
            ("put", v_put, 2),
            ("get", v_get, 1),
            ("onconflict", v_onconflict, 1),
            ("onconflictlost", v_onconflictlost, 1),
        ]

    def register(self) -> None:
        """Register the global `stigmergy` table (C-function id 27, docs/stdlib.md)."""

        def create(_t: Any, x: Any) -> Table:
            if x.__class__ is not int:
                raise expected("integer", x)
            vid = x & 0xFFFF
            self.stores[vid] = VStig(vid)  # re-creating discards the old one (reference)
            return self._table(vid)

        t = Table()
        t["create"] = self.vm.new_native(create, 1, "stigmergy.create").rebind(t)
        self.vm.globals["stigmergy"] = t


def _inc(timestamp: int) -> int:
    """The next version of a key: u16, wrapping as the reference does."""
    return (timestamp + 1) & 0xFFFF
