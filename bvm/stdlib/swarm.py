"""The `swarm` table (docs/stdlib.md#swarm, docs/wire-format.md#swarms): dynamic sub-swarms.

Local state: swarm id (u16) -> membership flag (u8). Remote knowledge, learned from
SWARM_LIST/JOIN/LEAVE messages: robot id -> (its swarm ids, age in steps); a record not
refreshed for more than 50 steps is forgotten. `s.exec(f)` runs f with the swarm's id on a
stack that `swarm.id()` and `neighbors.kin()`/`nonkin()` read.

Deliberate differences from the reference (docs/compat.md): swarm tables share one set of
six method closures, made on first use, instead of six fresh C functions per table (which
grow the function list without bound); `swarm.id(depth)` honours its argument with one
argument (the reference only with two).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from bvm.errors import BuzzError
from bvm.stdlib.base import expected
from bvm.values import Closure, Table

if TYPE_CHECKING:
    from bvm.host import LibraryHost

#: Steps without news from a robot after which its swarm memberships are forgotten.
MAX_AGE = 50

#: Steps between the periodic SWARM_LIST messages.
LIST_PERIOD = 10


def _swarm_id(x: Any) -> int:
    """A swarm id argument: an int, truncated to u16 as the reference does."""
    if x.__class__ is not int:
        raise expected("integer", x)
    return x & 0xFFFF


class Swarms:
    """Swarm membership of one VM, its knowledge of other robots', and the exec stack."""

    def __init__(self, vm: LibraryHost) -> None:
        self.vm = vm
        self.flags: dict[int, int] = {}
        # robot -> (its swarm ids, the step of its last news), oldest news first
        self.peers: dict[int, tuple[dict[int, None], int]] = {}
        self.now = 0  # steps processed
        self.stack: list[int] = []
        self.countdown = LIST_PERIOD
        self._methods: list[tuple[str, Closure]] | None = None

    # ------------------------------------------------------------ queries

    def current(self) -> int | None:
        """The swarm whose exec is running (innermost), or None."""
        return self.stack[-1] if self.stack else None

    def peer_in(self, robot: int, swarm: int) -> bool:
        """Whether robot `robot` is known (from its messages) to be in swarm `swarm`."""
        record = self.peers.get(robot)
        return record is not None and swarm in record[0]

    def member_ids(self) -> list[int]:
        """The swarms this robot is in, in creation order."""
        return [sid for sid, flag in self.flags.items() if flag]

    # ------------------------------------------------------------ messages

    def _refresh(self, robot: int, ids: dict[int, None]) -> None:
        # Re-inserted, so the dict stays ordered by the time of last news (see `age`).
        self.peers.pop(robot, None)
        self.peers[robot] = (ids, self.now)

    def on_list(self, robot: int, ids: tuple[int, ...]) -> None:
        """A SWARM_LIST from `robot`: its memberships (an empty list is ignored, as in C)."""
        if ids:
            self._refresh(robot, dict.fromkeys(ids))

    def on_join(self, robot: int, swarm: int) -> None:
        """A SWARM_JOIN from `robot`."""
        record = self.peers.get(robot)
        ids = record[0] if record else {}
        ids[swarm] = None
        self._refresh(robot, ids)

    def on_leave(self, robot: int, swarm: int) -> None:
        """A SWARM_LEAVE from `robot`: forget the robot once it is in no swarm."""
        record = self.peers.get(robot)
        if record is None:
            return
        ids = record[0]
        ids.pop(swarm, None)
        if ids:
            self._refresh(robot, ids)
        else:
            del self.peers[robot]

    def age(self) -> None:
        """One step passed: forget the robots with no news for more than MAX_AGE steps."""
        self.now += 1
        peers = self.peers
        # Oldest news first: stop at the first record still young (O(forgotten) a step).
        while peers:
            robot = next(iter(peers))
            if self.now - peers[robot][1] <= MAX_AGE:
                break
            del peers[robot]

    def tick(self) -> None:
        """Called once per step before sending: every LIST_PERIOD steps, queue a LIST."""
        self.countdown -= 1
        if self.countdown <= 0:
            self.countdown = LIST_PERIOD
            if self.flags:
                self.vm.net.outbox.swarm_list(self.member_ids())

    # ------------------------------------------------------------ script side

    def _set(self, sid: int, flag: int) -> None:
        self.flags[sid] = flag
        if flag:
            self.vm.net.outbox.join(sid)
        else:
            self.vm.net.outbox.leave(sid)

    def _flag(self, t: Any) -> tuple[int, int]:
        """The (id, flag) of a swarm table; an id never created is an error."""
        sid: Any = t["id"] if t.__class__ is Table else None
        flag = self.flags.get(sid) if sid.__class__ is int else None
        if flag is None:
            raise BuzzError(f"unknown swarm id: {sid}")
        return sid, flag

    def _table(self, sid: int) -> Table:
        """A swarm table {id, others, join, leave, in, select, exec} for a known id."""
        if self._methods is None:
            self._methods = [
                (name, self.vm.new_native(impl, arity, f"swarm.{name}"))
                for name, impl, arity in self._swarm_methods()
            ]
        t = Table()
        t["id"] = sid
        for name, closure in self._methods:
            t[name] = closure.rebind(t)
        return t

    def _swarm_methods(self) -> list[tuple[str, Any, int]]:
        vm = self.vm

        def s_others(t: Any, other: Any) -> Table:
            _, flag = self._flag(t)
            sid = _swarm_id(other)
            self.flags[sid] = 0 if flag else 1
            if not flag:
                vm.net.outbox.join(sid)
            return self._table(sid)

        def s_join(t: Any) -> None:
            self._set(self._flag(t)[0], 1)

        def s_leave(t: Any) -> None:
            self._set(self._flag(t)[0], 0)

        def s_in(t: Any) -> int:
            return self._flag(t)[1]

        def s_select(t: Any, cond: Any) -> None:
            sid, _ = self._flag(t)
            if cond.__class__ is not int:
                raise expected("integer", cond)
            self._set(sid, cond & 0xFF)

        def s_exec(t: Any, f: Any) -> Any:
            sid, flag = self._flag(t)
            if f.__class__ is not Closure:
                raise expected("closure", f)
            if not flag:
                return None
            self.stack.append(sid)
            try:
                return vm.invoke(f, ())
            finally:
                self.stack.pop()

        return [
            ("others", s_others, 1),
            ("join", s_join, 0),
            ("leave", s_leave, 0),
            ("in", s_in, 0),
            ("select", s_select, 1),
            ("exec", s_exec, 1),
        ]

    def register(self) -> None:
        """Register the global `swarm` table (C-function ids 28-32, docs/stdlib.md)."""
        vm = self.vm

        def create(_t: Any, x: Any) -> Table:
            sid = _swarm_id(x)
            self.flags.setdefault(sid, 0)
            return self._table(sid)

        def combine(rule: Any) -> Any:
            def impl(_t: Any, x: Any, s1: Any, s2: Any) -> Table:
                sid = _swarm_id(x)
                flag = 1 if rule(self._flag(s1)[1], self._flag(s2)[1]) else 0
                self.flags[sid] = flag
                if flag:
                    vm.net.outbox.join(sid)
                return self._table(sid)

            return impl

        def s_id(_t: Any, *args: Any) -> Any:
            depth = args[0] if args else 0
            if depth.__class__ is not int:
                raise expected("integer", depth)
            if not 0 <= depth < len(self.stack):
                return None
            return self.stack[-1 - depth]

        t = Table()
        for name, impl, arity in (
            ("create", create, 1),
            ("union", combine(lambda a, b: a or b), 3),
            ("intersection", combine(lambda a, b: a and b), 3),
            ("difference", combine(lambda a, b: a and not b), 3),
            ("id", s_id, None),
        ):
            t[name] = vm.new_native(impl, arity, f"swarm.{name}").rebind(t)
        vm.globals["swarm"] = t
