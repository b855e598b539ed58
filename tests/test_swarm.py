"""Swarms: local membership, its messages, what robots learn of each other, and expiry."""

from __future__ import annotations

import pytest
from buzzhost import hexes, make_robot
from harness import Harness, line

import bvm
from bvm import wire
from fieldkit.sim.radio import LinkModel


def test_membership_api() -> None:
    vm, lines = make_robot(
        """
        s = swarm.create(3)
        log("created ", s.id, " in ", s.in())
        s.join()
        log("joined ", s.in())
        s.select(0)
        log("select 0 ", s.in())
        s.select(256)
        log("select 256 ", s.in())
        s.select(1)
        o = s.others(4)
        log("others ", o.id, " ", o.in())
        a = swarm.create(5)
        u = swarm.union(6, s, a)
        i = swarm.intersection(7, s, a)
        d = swarm.difference(8, s, a)
        log("union ", u.in(), " inter ", i.in(), " diff ", d.in())
        s.leave()
        log("left ", s.in())
        log("id outside ", swarm.id())
        """
    )
    assert lines == [
        "created 3 in 0",
        "joined 1",
        "select 0 0",
        "select 256 0",
        "others 4 0",
        "union 1 inter 0 diff 1",
        "left 0",
        "id outside [nil]",
    ]


def test_exec_runs_only_for_members_and_sets_the_swarm_id() -> None:
    vm, lines = make_robot(
        """
        s = swarm.create(3)
        t = swarm.create(9)
        log("non-member ", s.exec(function() { log("never") return 1 }))
        s.join()
        t.join()
        r = s.exec(function() {
          log("in ", swarm.id())
          t.exec(function() { log("nested ", swarm.id(), " outer ", swarm.id(1)) })
          return 42
        })
        log("result ", r, " after ", swarm.id())
        """
    )
    assert lines == ["non-member [nil]", "in 3", "nested 9 outer 3", "result 42 after [nil]"]


def test_exec_pops_the_swarm_id_when_its_function_fails() -> None:
    vm, _ = make_robot(
        "s = swarm.create(3) s.join() function step() { s.exec(function() { return 1 / 0 }) }"
    )
    with pytest.raises(bvm.BuzzError):
        vm.call("step")
    assert vm.swarms.stack == []


def test_unknown_swarm_id_is_an_error() -> None:
    with pytest.raises(bvm.BuzzError, match="unknown swarm id: 99"):
        make_robot("s = swarm.create(3) s.id = 99 s.join()")


def test_list_join_leave_bytes_and_merging() -> None:
    # JOIN 3 -> 04 0003; a queued LIST absorbs later JOIN/LEAVEs
    # (docs/wire-format.md#message-types, #outgoing-queue).
    vm, _ = make_robot("s = swarm.create(3) s.join()", robot_id=7)
    assert hexes(vm.drain_outbox()) == ["040003"]
    vm, _ = make_robot("s = swarm.create(3) s.join() s.leave() s.join()")
    assert hexes(vm.drain_outbox()) == ["040003"]  # the LEAVE cancelled the JOIN, and back
    vm, _ = make_robot("s = swarm.create(3) s.join() s.leave()")
    assert hexes(vm.drain_outbox()) == ["050003"]


def test_periodic_swarm_list_every_ten_steps() -> None:
    vm, _ = make_robot(
        "a = swarm.create(3) a.join() b = swarm.create(9) function step() {}", robot_id=7
    )
    sent = []
    for _ in range(21):
        vm.call("step")
        sent.append(hexes(vm.drain_outbox()))
    assert sent[0] == ["040003"]
    lists = [i for i, out in enumerate(sent) if out == ["0100010003"]]
    assert lists == [9, 19]  # the 10th and 20th step; only joined swarms are listed
    assert all(out == [] for i, out in enumerate(sent) if i not in (0, 9, 19))


def test_reference_drain_order_for_a_mixed_queue() -> None:
    # docs/wire-format.md#worked-example: robot 7 (vstig 5, swarm 3 joined, swarm 9 created
    # only, puts, a get, 4 broadcasts), after 10 process_outmsgs: 4 BROADCASTs, the LIST (which
    # replaced the queued JOIN), 4 PUTs, 1 QUERY.
    vm, _ = make_robot(
        """
        v = stigmergy.create(5)
        s = swarm.create(3)
        s.join()
        n = swarm.create(9)
        v.put("a", 1) v.put("b", 2) v.put("c", 3) v.put("d", 4)
        v.get("missing")
        neighbors.broadcast("x", 1) neighbors.broadcast("x", 2)
        neighbors.broadcast("y", 3) neighbors.broadcast("z", 4)
        """,
        robot_id=7,
    )
    for _ in range(9):
        vm.swarms.tick()
    out = [wire.decode(p) for p in vm.drain_outbox()]
    assert [m.type for m in out] == [0, 0, 0, 0, 1, 2, 2, 2, 2, 3]
    assert out[4] == wire.SwarmList((3,))


def peers_of(vm: bvm.VM) -> dict[int, list[int]]:
    return {r: sorted(ids) for r, (ids, _age) in vm.swarms.peers.items()}


def test_received_memberships_and_their_expiry() -> None:
    vm, _ = make_robot("x = 1")
    vm.receive(4, wire.encode(wire.SwarmJoin(3)))
    vm.receive(5, wire.encode(wire.SwarmList((3, 7))))
    vm.receive(6, wire.encode(wire.SwarmList(())))  # empty lists are ignored (reference)
    vm.process_inbox()
    assert peers_of(vm) == {4: [3], 5: [3, 7]}
    vm.receive(5, wire.encode(wire.SwarmLeave(3)))
    vm.receive(4, wire.encode(wire.SwarmLeave(3)))  # robot 4 in no swarm: forgotten
    vm.process_inbox()
    assert peers_of(vm) == {5: [7]}
    for _ in range(49):
        vm.process_inbox()
    assert peers_of(vm) == {5: [7]}  # 50 steps without news: still known
    vm.process_inbox()
    assert peers_of(vm) == {}  # the 51st: forgotten


def test_membership_propagates_and_expires_in_a_swarm() -> None:
    src = """
    s = swarm.create(1)
    function init() { if (id % 2 == 0) s.join() }
    function step() {
      # Robot 2 leaves silently at step 30 by no longer being heard (we move it away).
      s.exec(function() { kin = neighbors.kin().count() })
    }
    """
    positions = line(5, spacing=10.0)
    h = Harness(
        bvm.compile_source(src, "s.bzz"),
        range(5),
        positions=positions,
        link=LinkModel(range_m=100.0),
        seed=3,
    )
    h.run(12)
    assert peers_of(h.vms[1]) == {0: [1], 2: [1], 4: [1]}
    assert h.vms[0]["kin"] == 2  # robots 2 and 4 are kin of robot 0
    h.positions[2] = (1e6, 0.0, 0.0)  # out of everyone's range from now on
    h.run(45)
    assert 2 in peers_of(h.vms[1])  # heard 45 steps ago at most... still remembered
    h.run(20)
    assert peers_of(h.vms[1]) == {0: [1], 4: [1]}  # expired: no LIST for over 50 steps
    assert h.vms[0]["kin"] == 1
    assert h.errors == {}


@pytest.mark.parametrize("translate", [True, False], ids=["translated", "interpreted"])
def test_select_and_exec_behave_per_robot(translate: bool) -> None:
    src = """
    evens = swarm.create(1)
    odds = evens.others(2)
    function step() {
      evens.select(id % 2 == 0)
      odds = evens.others(2)
      said = nil
      evens.exec(function() { said = "even" })
      odds.exec(function() { said = "odd" })
    }
    """
    for rid in range(4):
        vm, _ = make_robot(src, robot_id=rid, translate=translate)
        vm.call("step")
        assert vm["said"] == ("even" if rid % 2 == 0 else "odd")
