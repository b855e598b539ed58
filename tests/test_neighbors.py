"""The `neighbors` primitive: host feed, queries, derived tables, broadcast and listen."""

from __future__ import annotations

import math

import pytest
from buzzhost import hexes, make_robot
from harness import Harness, line

import bvm
from bvm import wire
from fieldkit.sim.radio import LinkModel

BOTH = pytest.mark.parametrize("translate", [True, False], ids=["translated", "interpreted"])

GEOMETRY = [(1, 10.0, 0.0, 0.0), (2, 20.0, math.pi / 2, 0.0), (5, 5.0, -1.0, 0.0)]


@BOTH
def test_queries_over_a_known_geometry(translate: bool) -> None:
    vm, lines = make_robot(
        """
        function step() {
          log("count ", neighbors.count())
          log("get2 ", neighbors.get(2).distance, " ", neighbors.get(2).azimuth)
          log("get9 ", neighbors.get(9))
          var far = neighbors.filter(function(rid, d) { return d.distance > 7.0 })
          log("far ", far.count(), " ", far.get(5))
          var dm = neighbors.map(function(rid, d) { return d.distance * 2.0 })
          log("map ", dm.get(1), " ", dm.get(5))
          log("sum ", neighbors.reduce(function(rid, d, acc) { return acc + d.distance }, 0.0))
          log("ids ", neighbors.reduce(function(rid, d, acc) { return acc + rid }, 0))
          neighbors.foreach(function(rid, d) { log("each ", rid) })
          log("chained ", neighbors.filter(function(r, d) { return r != 1 }).map(
              function(r, d) { return r }).reduce(function(r, v, a) { return a + v }, 100))
        }
        """,
        translate=translate,
    )
    vm.set_neighbors(GEOMETRY)
    vm.call("step")
    assert lines == [
        "count 3",
        "get2 20.000000 1.570796",
        "get9 [nil]",
        "far 2 [nil]",
        "map 20.000000 10.000000",
        "sum 35.000000",
        "ids 8",
        "each 1",
        "each 2",
        "each 5",
        "chained 107",
    ]


def test_filter_keeps_entries_whose_result_is_true() -> None:
    # Buzz truth: nil and the integer 0 are false; 0.0 and "" are true.
    vm, lines = make_robot(
        """
        function step() {
          var f = neighbors.filter(function(rid, d) {
            if (rid == 1) return 0
            if (rid == 2) return 0.0
            return nil
          })
          log(f.count(), " ", f.get(2).distance)
        }
        """
    )
    vm.set_neighbors(GEOMETRY)
    vm.call("step")
    assert lines == ["1 20.000000"]


def test_neighbors_are_replaced_each_step() -> None:
    vm, lines = make_robot("function step() { log(neighbors.count(), neighbors.get(1)) }")
    vm.set_neighbors(GEOMETRY)
    vm.call("step")
    vm.set_neighbors([(7, 1.0, 0.0, 0.0)])
    vm.call("step")
    vm.set_neighbors([])
    vm.call("step")
    assert lines == ["3[table with 3 elems]", "1[nil]", "0[nil]"]


def test_before_any_host_feed_there_are_no_neighbors() -> None:
    vm, lines = make_robot("log(neighbors.count(), neighbors.get(1))")
    assert lines == ["0[nil]"]


def test_kin_and_nonkin_outside_exec() -> None:
    vm, lines = make_robot(
        "function step() { log(neighbors.kin().count(), ' ', neighbors.nonkin().count()) }"
    )
    vm.set_neighbors(GEOMETRY)
    vm.call("step")
    assert lines == ["3 0"]


def test_kin_and_nonkin_inside_exec_follow_received_memberships() -> None:
    # Robot 1 tells robot 0 it joined swarm 4; robot 2 joined swarm 5 only.
    peer1, _ = make_robot("s = swarm.create(4)  s.join()", robot_id=1)
    peer2, _ = make_robot("s = swarm.create(5)  s.join()", robot_id=2)
    vm, lines = make_robot(
        """
        s = swarm.create(4)
        s.join()
        function step() {
          s.exec(function() {
            log("kin ", neighbors.kin().reduce(function(r, d, a) { return a + r }, 0))
            log("nonkin ", neighbors.nonkin().reduce(function(r, d, a) { return a + r }, 0))
            var not1 = neighbors.filter(function(r, d) { return r != 1 })
            log("kin of filtered ", not1.kin().count())
          })
        }
        """
    )
    for peer in (peer1, peer2):
        for payload in peer.drain_outbox():
            vm.receive(peer.robot_id, payload)
    vm.process_inbox()
    vm.set_neighbors([(1, 1.0, 0.0, 0.0), (2, 2.0, 0.0, 0.0), (5, 5.0, 0.0, 0.0)])
    vm.call("step")
    assert lines == ["kin 1", "nonkin 7", "kin of filtered 0"]


def test_derived_tables_do_not_grow_the_function_list() -> None:
    vm, _ = make_robot(
        """
        function step() {
          var m = neighbors.map(function(r, d) { return d })
          var f = m.filter(function(r, d) { return 1 }).kin().nonkin()
        }
        """
    )
    vm.set_neighbors(GEOMETRY)
    vm.call("step")
    after_first = len(vm.natives)
    for _ in range(50):
        vm.call("step")
    assert len(vm.natives) == after_first


def test_broadcast_bytes_match_the_reference() -> None:
    # Robot 7's neighbors.broadcast("cmd", 22), and "f" = -0.1, and nil
    # (docs/wire-format.md#message-types).
    vm, _ = make_robot(
        'neighbors.broadcast("cmd", 22) neighbors.broadcast("f", -0.1) '
        'neighbors.broadcast("f", nil)',
        robot_id=7,
    )
    assert hexes(vm.drain_outbox()) == [
        "00030003636d640100000016",
        "0003000166" + "02b33332fffffffffd",
        "000300016600",
    ]


def test_broadcast_sends_a_snapshot_of_the_value() -> None:
    vm, _ = make_robot("t = {.a = 1} neighbors.broadcast('t', t) t.a = 2")
    sender = vm
    rx, lines = make_robot(
        "neighbors.listen('t', function(topic, v, sender) { log(topic, ' ', v.a, ' ', sender) })",
        robot_id=3,
    )
    for p in sender.drain_outbox():
        rx.receive(0, p)
    rx.process_inbox()
    assert lines == ["t 1 0"]


def test_broadcast_topic_must_be_a_string() -> None:
    with pytest.raises(bvm.BuzzError, match="expected string, got integer"):
        make_robot("neighbors.broadcast(1, 2)")


def test_listen_ignore_and_relisten() -> None:
    rx, lines = make_robot(
        """
        neighbors.listen("a", function(t, v, s) { log("first ", v) })
        neighbors.listen("a", function(t, v, s) { log("second ", v, " from ", s) })
        neighbors.listen("b", function(t, v, s) { log("b ", v) })
        neighbors.ignore("b")
        """
    )
    for topic, value in (("a", 1), ("b", 2), ("c", 3)):
        rx.receive(4, wire.encode(wire.Broadcast(topic, value)))
    rx.process_inbox()
    assert lines == ["second 1 from 4"]


def test_broadcast_reaches_only_robots_in_range() -> None:
    src = """
    heard = {}
    function init() { neighbors.listen("hi", function(t, v, s) { heard[s] = v }) }
    function step() { neighbors.broadcast("hi", id * 10) }
    """
    h = Harness(
        bvm.compile_source(src, "hi.bzz"),
        range(5),
        positions=line(5, spacing=10.0),
        link=LinkModel(range_m=15.0),
        seed=0,
    )
    h.run(3)
    assert h.errors == {}
    assert h.vms[0]["heard"] == {1: 10}
    assert h.vms[2]["heard"] == {1: 10, 3: 30}
    assert h.vms[4]["heard"] == {3: 30}


def test_neighbors_in_the_harness_have_distance_and_azimuth() -> None:
    src = """
    function step() {
      seen = neighbors.map(function(r, d) { return d.distance * 1000.0 + d.azimuth }).poses
    }
    """
    positions = {0: (0.0, 0.0, 0.0), 1: (0.0, 10.0, 0.0), 2: (10.0, 0.0, 0.0)}
    h = Harness(bvm.compile_source(src, "n.bzz"), range(3), positions=positions)
    h.step()
    seen = h.vms[0]["seen"]
    assert seen[1] == pytest.approx(10000.0)  # due north: azimuth 0
    assert seen[2] == pytest.approx(10000.0 + math.pi / 2, rel=1e-6)  # east: +pi/2
