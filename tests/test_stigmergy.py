"""Virtual stigmergy: local API, message bytes, receive rules, conflicts and convergence."""

from __future__ import annotations

import pytest
from buzzhost import hexes, make_robot
from harness import Harness, line

import bvm
from bvm import wire
from bvm.stdlib.stigmergy import bucket
from fieldkit.sim.radio import LinkModel


def deliver(src: bvm.VM, dst: bvm.VM) -> int:
    """Drain `src`'s outbox into `dst` and process it; the number of payloads."""
    payloads = src.drain_outbox()
    for p in payloads:
        dst.receive(src.robot_id, p)
    dst.process_inbox()
    return len(payloads)


def test_put_get_delete_bytes_match_the_reference() -> None:
    # docs/wire-format.md#message-types, robot 7 (and robot 2 for the delete).
    vm, _ = make_robot(
        """
        v = stigmergy.create(5)
        v.put("k", 42)
        v.put(7, 1.5)
        v.put("t", {.a = 1})
        v.get("missing")
        """,
        robot_id=7,
    )
    assert hexes(vm.drain_outbox()) == [
        "020005030001" + "6b" + "010000002a" + "0001" + "0007",
        "0200050100000007" + "024000000100000001" + "0001" + "0007",
        "020005030001" + "74" + "0401030001610100000001" + "0001" + "0007",
        "030005030007" + "6d697373696e67" + "00" + "0000" + "0007",
    ]
    deleter, _ = make_robot('v = stigmergy.create(5) v.put("k", 1) v.put("k", nil)', robot_id=2)
    assert hexes(deleter.drain_outbox()) == ["020005030001" + "6b" + "00" + "0002" + "0002"]


def test_local_api() -> None:
    vm, lines = make_robot(
        """
        v = stigmergy.create(1)
        log(v.id, " ", v.size(), " ", v.get("x"))
        v.put("x", 1)
        v.put("x", 2)
        v.put(2, "two")
        v.put("gone", 1)
        v.put("gone", nil)
        v.put("never", nil)
        log(v.size(), " ", v.get("x"), " ", v.get(2.0), " ", v.get("gone"))
        v.foreach(function(k, val, robot) { log(k, "=", val, "@", robot) })
        w = stigmergy.create(1)
        log("recreated ", w.size(), " ", v.size())
        """,
        robot_id=4,
    )
    assert lines == [
        "1 0 [nil]",
        "2 2 two [nil]",
        "2=two@4",  # bucket 2 before "x" (djb2 bucket 3), though put later
        "x=2@4",
        "recreated 0 0",
    ]


def test_repeated_puts_queue_only_the_newest() -> None:
    # Three steps each doing put("k") queue only the ts=3 PUT; repeated get("missing") queue one
    # QUERY; broadcasts are all kept (docs/wire-format.md#outgoing-queue).
    vm, _ = make_robot(
        """
        v = stigmergy.create(5)
        function step() {
          v.put("k", 1)
          v.get("missing")
          neighbors.broadcast("b", 1)
        }
        """,
        robot_id=7,
    )
    for _ in range(3):
        vm.call("step")
    out = vm.drain_outbox()
    msgs = [wire.decode(p) for p in out]
    assert [m.type for m in msgs] == [0, 0, 0, 2, 3]
    assert msgs[3].timestamp == 3


def test_get_after_put_is_merged_with_the_queued_put() -> None:
    vm, _ = make_robot('v = stigmergy.create(1) v.put("k", 1) v.get("k")')
    msgs = [wire.decode(p) for p in vm.drain_outbox()]
    assert [(m.type, m.timestamp) for m in msgs] == [(wire.MsgType.VSTIG_PUT, 1)]


def pair(src_a: str, src_b: str, a: int = 2, b: int = 9) -> tuple[bvm.VM, bvm.VM, list[str]]:
    """Robots `a` and `b` running their sources, and the lines robot `b` logs."""
    va, _ = make_robot(src_a, robot_id=a)
    vb, lines = make_robot(src_b, robot_id=b)
    return va, vb, lines


def test_newer_put_replaces_and_is_regossiped() -> None:
    a, b, _ = pair('v = stigmergy.create(5) v.put("k", 1) v.put("k", 2)', "v = stigmergy.create(5)")
    deliver(a, b)
    assert b["v"] and b.stigmergies.stores[5].entries["k"].data == 2
    regossip = [wire.decode(p) for p in b.drain_outbox()]
    # Both PUTs arrive; newest first (LIFO), so ts 2 is stored and re-sent; ts 1 is older.
    assert [(m.value, m.timestamp, m.robot) for m in regossip] == [(2, 2, 2)]


def test_put_for_an_uncreated_vstig_is_dropped() -> None:
    a, b, _ = pair('v = stigmergy.create(5) v.put("k", 1)', "w = stigmergy.create(6)")
    deliver(a, b)
    assert b.drain_outbox() == []


def test_default_conflict_rule_higher_robot_wins_and_loser_is_told() -> None:
    # Robots 2 and 9 both put "k" at ts 1 -> both converge to 9's
    # (docs/wire-format.md#receiving-put).
    src = """
    v = stigmergy.create(5)
    v.onconflictlost(function(k, local) { log("lost ", k, " ", local.data, " ", local.robot) })
    v.put("k", id)
    """
    a, b, lines = pair(src, src)
    out_a = a.drain_outbox()
    out_b = b.drain_outbox()
    for p in out_a:
        b.receive(2, p)
    for p in out_b:
        a.receive(9, p)
    a.process_inbox()
    b.process_inbox()
    for vm in (a, b):
        e = vm.stigmergies.stores[5].entries["k"]
        assert (e.data, e.timestamp, e.robot) == (9, 1, 9)
    assert hexes(a.drain_outbox()) == ["020005030001" + "6b" + "0100000009" + "0001" + "0009"]
    assert b.stigmergies.stores[5].entries["k"].robot == 9
    assert a.net.stats["decode_errors"] == 0


def test_default_conflict_rule_nil_loses() -> None:
    a, b, _ = pair('v = stigmergy.create(5) v.put("k", 1)', "v = stigmergy.create(5)", a=9, b=2)
    # Robot 2 holds a tombstone (nil) for k at ts 1 from robot 3: a non-nil value wins.
    b.receive(3, wire.encode(wire.VstigPut(5, "k", None, 1, 3)))
    b.process_inbox()
    b.drain_outbox()
    deliver(a, b)
    e = b.stigmergies.stores[5].entries["k"]
    assert (e.data, e.robot) == (1, 9)


def test_onconflict_decides_the_winner() -> None:
    src = """
    v = stigmergy.create(5)
    v.onconflict(function(k, local, remote) {
      log("conflict ", k, " local ", local.data, "@", local.robot, " remote ", remote.data,
          "@", remote.robot, " ts ", remote.timestamp)
      # the lower robot id wins here
      if (local.robot < remote.robot) return local
      return remote
    })
    v.put("k", id * 100)
    """
    a, b, lines = pair(src, src)
    deliver(a, b)
    e = b.stigmergies.stores[5].entries["k"]
    assert (e.data, e.timestamp, e.robot) == (200, 1, 2)
    assert lines == ["conflict k local 900@9 remote 200@2 ts 1"]


def test_onconflict_returning_garbage_is_counted_not_fatal() -> None:
    src = 'v = stigmergy.create(5) v.onconflict(function(k, l, r) { return 3 }) v.put("k", id)'
    a, b, _ = pair(src, src)
    deliver(a, b)
    assert b.net.stats["conflict_unresolved"] == 1
    assert b.stigmergies.stores[5].entries["k"].robot == 9  # unchanged


def test_tombstones_are_asymmetric() -> None:
    a, b, _ = pair('v = stigmergy.create(5) v.put("k", 1)', "v = stigmergy.create(5)")
    deliver(a, b)
    b.drain_outbox()
    # Robot 2 deletes its key: it removes the entry, robot 9 stores a nil.
    a.invoke(a.gload("v")["put"], ("k", None))
    assert a.stigmergies.stores[5].entries == {}
    deliver(a, b)
    e = b.stigmergies.stores[5].entries["k"]
    assert (e.data, e.timestamp, e.robot) == (None, 2, 2)
    assert b.invoke(b.gload("v")["size"], ()) == 1


def test_query_is_answered_with_the_newer_value() -> None:
    a, b, _ = pair('v = stigmergy.create(5) v.put("k", 1) v.put("k", 2)', "v = stigmergy.create(5)")
    a.drain_outbox()
    b.invoke(b.gload("v")["get"], ("k",))  # b knows nothing: QUERY (nil, ts 0, robot 9)
    deliver(b, a)
    reply = [wire.decode(p) for p in a.drain_outbox()]
    assert [(m.type, m.value, m.timestamp, m.robot) for m in reply] == [
        (wire.MsgType.VSTIG_PUT, 2, 2, 2)
    ]


def test_query_with_a_newer_value_is_stored_and_gossiped() -> None:
    b, _ = make_robot("v = stigmergy.create(5)", robot_id=9)
    b.receive(3, wire.encode(wire.VstigQuery(5, "k", 7, 4, 3)))
    b.process_inbox()
    e = b.stigmergies.stores[5].entries["k"]
    assert (e.data, e.timestamp, e.robot) == (7, 4, 3)
    assert [wire.decode(p).type for p in b.drain_outbox()] == [wire.MsgType.VSTIG_PUT]


def test_query_for_an_uncreated_vstig_is_forwarded_unchanged() -> None:
    b, _ = make_robot("x = 1", robot_id=9)
    q = wire.encode(wire.VstigQuery(5, "k", 7, 4, 3))
    b.receive(3, q)
    b.process_inbox()
    assert b.drain_outbox() == [q]


def test_query_for_a_key_nobody_holds_does_not_bounce_forever() -> None:
    # The reference ping-pongs such a query between robots forever
    # (docs/wire-format.md#gossip-consequences).
    a, b, _ = pair('v = stigmergy.create(5) v.get("missing")', "v = stigmergy.create(5)")
    sent = []
    for _ in range(50):
        sent.append(deliver(a, b) + deliver(b, a))
    assert sum(sent) <= 4, sent
    assert sent[-10:] == [0] * 10


def test_foreach_follows_the_reference_bucket_order() -> None:
    # nil 0, int u32 % 10, float trunc, string djb2 over signed chars (docs/stdlib.md#stigmergy).
    assert [bucket(k) for k in (None, 13, -1, 7.9, -1.5)] == [0, 3, 5, 7, 5]
    assert bucket("a") == (5381 * 33 + 97) % 10
    assert bucket("\xe9") == ((5381 * 33 - 23) & 0xFFFFFFFF) % 10


def test_closure_keys_are_a_runtime_error() -> None:
    with pytest.raises(bvm.BuzzError, match="can't be used as a stigmergy key"):
        make_robot("v = stigmergy.create(1) v.put(log, 1)")


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_ten_robots_on_a_lossy_line_converge(seed: int) -> None:
    # Several robots write, some the same keys at the same time (conflicts), over a line
    # where each robot hears only its two neighbours and half the payloads are lost.
    src = """
    v = stigmergy.create(1)
    lost = 0
    function init() {
      v.onconflictlost(function(k, local) { lost = lost + 1 })
      if (id == 0) { v.put("shared", 0)  v.put("a", "zero") }
      if (id == 9) { v.put("shared", 9)  v.put("b", 9.5) }
      if (id == 4) { v.put("shared", 4)  v.put(7, {.x = 4}) }
      if (id == 6) { v.put("a", "six") }
    }
    function step() {
      # Buzz gossip floods each change once; periodic queries repair what the losses ate.
      v.get("shared")  v.get("a")  v.get("b")  v.get(7)
    }
    """
    h = Harness(
        bvm.compile_source(src, "vstig.bzz"),
        range(10),
        positions=line(10, spacing=10.0),
        link=LinkModel(range_m=12.0, drop=0.5),
        seed=seed,
    )
    h.run(200)
    assert h.errors == {}
    tables = []
    for rid in range(10):
        store = h.vms[rid].stigmergies.stores[1]
        tables.append(
            {
                k: (bvm.values.to_python(e.data), e.timestamp, e.robot)
                for k, e in store.entries.items()
            }
        )
    assert all(t == tables[0] for t in tables), tables
    # The spec's rule: equal versions -> the higher robot id wins.
    assert tables[0] == {
        "shared": (9, 1, 9),
        "a": ("six", 1, 6),
        "b": (9.5, 1, 9),
        7: ({"x": 4}, 1, 4),
    }
    assert h.vms[0]["lost"] == 2  # robot 0 lost "shared" and "a"
    assert h.vms[4]["lost"] == 1
    assert h.vms[9]["lost"] == 0


def test_the_harness_is_reproducible_bit_for_bit() -> None:
    src = """
    v = stigmergy.create(1)
    function step() { v.put(id, math.rng.uniform(1000)) v.get((id + 1) % 5) }
    """
    runs = []
    for _ in range(2):
        h = Harness(
            bvm.compile_source(src, "r.bzz"),
            range(5),
            positions=line(5, 10.0),
            link=LinkModel(range_m=15.0, drop=0.3, jitter=2),
            seed=11,
        )
        h.run(30)
        runs.append(
            [
                sorted(
                    (repr(k), e.data, e.timestamp, e.robot)
                    for k, e in vm.stigmergies.stores[1].entries.items()
                )
                for vm in h.vms.values()
            ]
            + [h.radio.sent, h.radio.dropped]
        )
    assert runs[0] == runs[1]
