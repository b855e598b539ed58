"""The `neighbors` table: situated communication.

Facts: docs/stdlib.md#neighbors, docs/wire-format.md#neighbors.

The host replaces `neighbors.poses` every step with the robots it currently hears, as
robot id -> {distance, azimuth, elevation}. Methods (self = the table they are called on):
get count foreach map reduce filter kin nonkin, and on the global table only, broadcast
listen ignore. map/filter/kin/nonkin return new neighbors-like tables with their own
`poses` and the eight query methods.

Deliberate difference from the reference (docs/compat.md): the reference registers eight
fresh C functions for every derived table, so a script calling `neighbors.map` each step
grows the VM's function list forever. fieldkit makes those eight closures once, on first
use (so they get the ids the reference gives the first ones) and binds copies to each table.
"""

from __future__ import annotations

from array import array
from typing import TYPE_CHECKING, Any

from bvm.stdlib.base import expected
from bvm.values import Closure, Table

if TYPE_CHECKING:
    from bvm.host import LibraryHost
    from bvm.program import Program

POSES = "poses"

#: The global table's methods: a program that reads `neighbors` only through these never
#: sees its `poses` but through them.
NEIGHBOR_METHODS = frozenset(
    ("get", "filter", "kin", "nonkin", "foreach", "map", "reduce", "count")
    + ("broadcast", "listen", "ignore")
)


def methods_only(program: Program) -> bool:
    """Whether `program` reads the global `neighbors` only through its methods, so that
    its `poses` may be filled when a method first needs them."""
    reads = program.member_reads("neighbors")
    return reads is not None and reads <= NEIGHBOR_METHODS


def _pose(distance: float, azimuth: float) -> Table:
    """One neighbour's entry of `poses` from a simulator's columns (elevation 0)."""
    # Item stores: a third faster than keyword arguments (every neighbour of a swarm).
    entry = Table()
    entry["distance"] = distance
    entry["azimuth"] = azimuth
    entry["elevation"] = 0.0
    return entry


class Neighbors:
    """The neighbors state of one VM: topic listeners and the derived-table methods."""

    def __init__(self, vm: LibraryHost) -> None:
        self.vm = vm
        self.listeners: dict[str, Closure] = {}
        self.table = Table()  # the global `neighbors`
        self._derived_methods: list[tuple[str, Closure]] | None = None
        #: Whether `poses` may be filled on first use: set at load when the program
        #: reads the global `neighbors` only through its methods (Program.member_reads).
        self.lazy = False
        self._pending: tuple[list[int], list[float], list[float]] | None = None
        self._entries: dict[int, Table] = {}  # of the pending columns, made by `get`

    # ------------------------------------------------------------ host side

    def set(self, entries: list[tuple[int, float, float, float]]) -> None:
        """Replace this step's neighbors: (robot id, distance, azimuth, elevation) each."""
        self._pending = None
        poses = Table()
        # One C-level conversion rounds every number to binary32 (Buzz floats).
        values = array("f", [v for e in entries for v in e[1:4]])
        if len(values) != 3 * len(entries):
            raise ValueError("a neighbor entry is (id, distance, azimuth, elevation)")
        rounded = iter(values)
        for e, distance, azimuth, elevation in zip(
            entries, rounded, rounded, rounded, strict=False
        ):
            rid = e[0]
            if rid.__class__ is not int or not 0 <= rid <= 0xFFFF:
                raise ValueError(f"neighbor id must be an int in 0..65535, got {rid!r}")
            poses[rid] = Table(distance=distance, azimuth=azimuth, elevation=elevation)
        self.table[POSES] = poses

    def set_columns(self, ids: list[int], distances: list[float], azimuths: list[float]) -> None:
        """`set` for values already rounded to binary32 and valid, distinct ids, elevations
        0: what a simulator computes for a whole swarm at once. The lists are kept, not
        copied, until the next call. With `lazy`, the tables are made
        when a method first needs them: most steps of most robots need none or few."""
        if self.lazy:
            if len(ids) != len(distances) or len(ids) != len(azimuths):
                raise ValueError("neighbour columns of different lengths")
            self._pending = (ids, distances, azimuths)
            if self._entries:
                self._entries = {}
            self.table.pop(POSES, None)
            return
        self.table[POSES] = self._poses(ids, distances, azimuths)

    def _poses(self, ids: list[int], distances: list[float], azimuths: list[float]) -> Table:
        """The `poses` table of these columns (with the entries `get` made already)."""
        made = self._entries
        poses = Table()
        for rid, distance, azimuth in zip(ids, distances, azimuths, strict=True):
            entry = made.get(rid) if made else None
            poses[rid] = _pose(distance, azimuth) if entry is None else entry
        return poses

    def _settle(self) -> None:
        """Fill `poses` from the pending columns."""
        pending = self._pending
        if pending is not None:
            self.table[POSES] = self._poses(*pending)
            self._pending = None
            self._entries = {}

    def stop_lazy(self) -> None:
        """Make `poses` now and every step from now on (code the sweep did not see may
        read the table directly)."""
        self._settle()
        self.lazy = False

    def poses(self) -> Table | None:
        """This step's `poses` table of the global `neighbors` (made now if pending)."""
        self._settle()
        return self.table.get(POSES)

    def _pending_entry(self, rid: Any) -> Table | None:
        """`get(rid)` on the global table while its columns are pending: the one entry,
        the same table for every call this step and in `poses` if it is made later."""
        assert self._pending is not None
        ids, distances, azimuths = self._pending
        made = self._entries
        entry = made.get(rid)
        if entry is None:
            try:
                i = ids.index(rid)  # == as the table's lookup compares (3.0 finds 3)
            except ValueError:
                return None
            made[rid] = entry = _pose(distances[i], azimuths[i])
        return entry

    # ------------------------------------------------------------ script side

    def _derived(self, poses: Table) -> Table:
        """A neighbors-like table over `poses`, with the eight query methods."""
        if self._derived_methods is None:
            self._derived_methods = [
                (name, self.vm.new_native(impl, arity, f"neighbors.{name}"))
                for name, impl, arity in self._query_methods()
            ]
        t = Table()
        for name, closure in self._derived_methods:
            t[name] = closure.rebind(t)
        t[POSES] = poses
        return t

    def _query_methods(self) -> list[tuple[str, Any, int]]:
        """(name, implementation, arity) of get filter kin nonkin foreach map reduce count."""
        vm = self.vm
        failed = vm.call_failed
        table = self.table

        def poses_of(t: Any) -> Table:
            if t is table and self._pending is not None:
                self._settle()
            p = t[POSES] if t.__class__ is Table else None
            return p if p.__class__ is Table else Table()

        # Each runs a Buzz closure per neighbor: `f.fn(f, ...)` inline, one Python call per
        # entry, with wrong argument counts and non-closures left to `vm.call_failed`.
        def n_get(t: Any, rid: Any) -> Any:
            if t is table and self._pending is not None:
                return self._pending_entry(rid)
            return poses_of(t)[rid]

        def n_count(t: Any) -> int:
            if t is table and self._pending is not None:
                return len(self._pending[0])
            return len(poses_of(t))

        def n_foreach(t: Any, f: Any) -> None:
            for rid, data in list(poses_of(t).items()):
                try:
                    f.fn(f, rid, data)
                except (TypeError, AttributeError) as e:
                    failed(e, f, (rid, data))

        def n_map(t: Any, f: Any) -> Table:
            out = Table()
            for rid, data in list(poses_of(t).items()):
                try:
                    r = f.fn(f, rid, data)
                except (TypeError, AttributeError) as e:
                    r = failed(e, f, (rid, data))
                if r is not None:
                    out[rid] = r
            return self._derived(out)

        def n_reduce(t: Any, f: Any, acc: Any) -> Any:
            for rid, data in list(poses_of(t).items()):
                try:
                    acc = f.fn(f, rid, data, acc)
                except (TypeError, AttributeError) as e:
                    acc = failed(e, f, (rid, data, acc))
            return acc

        def n_filter(t: Any, f: Any) -> Table:
            out = Table()
            for rid, data in list(poses_of(t).items()):
                try:
                    r = f.fn(f, rid, data)
                except (TypeError, AttributeError) as e:
                    r = failed(e, f, (rid, data))
                if r is not None and (r.__class__ is not int or r != 0):
                    out[rid] = data
            return self._derived(out)

        def n_kin(t: Any) -> Table:
            swarm = vm.swarms.current()
            poses = poses_of(t)
            if swarm is None:
                return self._derived(Table(poses))
            member = vm.swarms.peer_in
            return self._derived(Table((r, d) for r, d in poses.items() if member(r, swarm)))

        def n_nonkin(t: Any) -> Table:
            swarm = vm.swarms.current()
            if swarm is None:
                return self._derived(Table())
            member = vm.swarms.peer_in
            poses = poses_of(t)
            return self._derived(Table((r, d) for r, d in poses.items() if not member(r, swarm)))

        return [
            ("get", n_get, 1),
            ("filter", n_filter, 1),
            ("kin", n_kin, 0),
            ("nonkin", n_nonkin, 0),
            ("foreach", n_foreach, 1),
            ("map", n_map, 1),
            ("reduce", n_reduce, 2),
            ("count", n_count, 0),
        ]

    def register(self) -> None:
        """Create the global `neighbors` table (C-function ids 0-10, docs/stdlib.md)."""
        vm = self.vm

        def n_broadcast(_t: Any, topic: Any, value: Any) -> None:
            if topic.__class__ is not str:
                raise expected("string", topic)
            vm.net.broadcast(topic, value)

        def n_listen(_t: Any, topic: Any, f: Any) -> None:
            if topic.__class__ is not str:
                raise expected("string", topic)
            if f.__class__ is not Closure:
                raise expected("closure", f)
            self.listeners[topic] = f

        def n_ignore(_t: Any, topic: Any) -> None:
            if topic.__class__ is not str:
                raise expected("string", topic)
            self.listeners.pop(topic, None)

        t = self.table
        for name, impl, arity in [
            *self._query_methods(),
            ("broadcast", n_broadcast, 2),
            ("listen", n_listen, 2),
            ("ignore", n_ignore, 1),
        ]:
            t[name] = vm.new_native(impl, arity, f"neighbors.{name}").rebind(t)
        vm.globals["neighbors"] = t

    def deliver(self, topic: str, value: Any, sender: int) -> None:
        """A received BROADCAST: call the topic's listener as f(topic, value, sender id)."""
        f = self.listeners.get(topic)
        if f is None:
            return
        self.vm.invoke(f, (topic, value, sender))
