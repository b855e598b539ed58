"""The in-queue and out-queue: processing order, byte budgets, caps and hostile payloads."""

from __future__ import annotations

import logging

import pytest
from buzzhost import make_robot
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bvm
from bvm import network, wire
from bvm.inbox import Inbox
from bvm.outbox import Outbox

LISTENER = """
order = {}
n = 0
neighbors.listen("m", function(topic, value, sender) {
  order[n] = sender * 1000 + value
  n = n + 1
})
"""


def bcast(value: object, topic: str = "m") -> bytes:
    return wire.encode(wire.Broadcast(topic, value))


def test_senders_in_bucket_order_each_newest_first() -> None:
    # Buckets id % 20, then arrival order; each sender's payloads LIFO
    # (docs/wire-format.md#incoming-queue).
    vm, _ = make_robot(LISTENER)
    for sender, value in [(21, 1), (3, 1), (1, 1), (21, 2), (41, 1), (3, 2)]:
        vm.receive(sender, bcast(value))
    vm.process_inbox()
    order = [vm["order"][i] for i in range(vm["n"])]
    assert order == [21002, 21001, 1001, 41001, 3002, 3001]


def test_budget_stops_at_the_first_message_that_does_not_fit() -> None:
    vm, _ = make_robot(
        "neighbors.broadcast('a', 1) neighbors.broadcast('b', 'xxxxxxxxxx') "
        "neighbors.broadcast('c', 2)"
    )
    first = vm.drain_outbox(budget_bytes=20)  # 9 bytes fit, the 18-byte one does not
    assert [wire.decode(p).topic for p in first] == ["a"]
    second = vm.drain_outbox(budget_bytes=30)
    assert [wire.decode(p).topic for p in second] == ["b", "c"]


def test_per_message_overhead_counts_against_the_budget() -> None:
    vm, _ = make_robot("neighbors.broadcast('a', 1) neighbors.broadcast('c', 2)")
    assert len(vm.drain_outbox(budget_bytes=20, overhead=2)) == 1  # 11 + 11 > 20
    assert len(vm.drain_outbox(budget_bytes=20, overhead=2)) == 1


def test_a_message_larger_than_the_budget_is_dropped_not_blocking(
    caplog: pytest.LogCaptureFixture,
) -> None:
    vm, _ = make_robot(
        "neighbors.broadcast('big', 'y' .. 'x') neighbors.broadcast('a', 1)".replace(
            "'y' .. 'x'", "'" + "x" * 300 + "'"
        )
    )
    with caplog.at_level(logging.ERROR, logger="bvm.net"):
        out = vm.drain_outbox(budget_bytes=190)
    assert [wire.decode(p).topic for p in out] == ["a"]
    assert vm.net.stats["oversize_dropped"] == 1
    assert "larger than the 190-byte budget" in caplog.text


def test_the_out_queue_is_capped() -> None:
    vm, _ = make_robot("function step() { neighbors.broadcast('t', 1) }")
    vm.net.outbox.max_queued = 100
    for _ in range(250):
        vm.call("step")
    assert len(vm.net.outbox) == 100
    assert vm.net.stats["outbox_overflow"] == 150


def test_the_in_queue_is_capped() -> None:
    stats: dict[str, int] = {}
    import collections

    counter: collections.Counter[str] = collections.Counter(stats)
    inbox = Inbox(counter, max_pending=10)
    accepted = [inbox.append(1, b"\x04\x00\x01") for _ in range(15)]
    assert accepted == [True] * 10 + [False] * 5
    assert counter["inbox_overflow"] == 5
    assert len(list(inbox.drain())) == 10
    assert len(inbox) == 0


def test_outbox_vstig_slot_is_shared_by_put_and_query() -> None:
    import collections

    box = Outbox(collections.Counter())
    box.vstig(wire.VstigQuery(1, "k", None, 0, 3), "k")
    box.vstig(wire.VstigPut(1, "k", 5, 1, 3), "k")  # newer: replaces the query
    box.vstig(wire.VstigQuery(1, "k", 5, 1, 3), "k")  # not newer: dropped
    box.vstig(wire.VstigPut(1, 1.0, 5, 1, 3), 1.0)
    box.vstig(wire.VstigPut(1, 1, 6, 2, 3), 1)  # 1 and 1.0 are one key
    out = [wire.decode(p) for p in box.drain()]
    assert [(m.type, m.key, m.timestamp) for m in out] == [(2, "k", 1), (2, 1, 2)]


def test_garbage_payloads_are_counted_and_skipped(caplog: pytest.LogCaptureFixture) -> None:
    vm, _ = make_robot(LISTENER)
    for junk in [b"", b"\x00", b"\x00\x03\x00\x05ab", b"\x07hello", b"\x02\x00", b"\x04\x00"]:
        vm.receive(9, junk)
    vm.receive(9, bcast(5))
    with caplog.at_level(logging.WARNING, logger="bvm.net"):
        vm.process_inbox()
    assert vm.net.stats["decode_errors"] == 6
    assert vm["n"] == 1 and vm["order"] == {0: 9005}
    assert "dropped a message from robot 9" in caplog.text
    assert vm.state != "error"


def test_received_closures_must_name_a_function_of_this_vm() -> None:
    vm, _ = make_robot(
        LISTENER.replace("sender * 1000 + value", "value") + "function f() { return 7 }"
    )
    good = vm.gload("f")
    vm.receive(1, bcast(good))
    vm.receive(2, bytes.fromhex("00 03 0001 6d 05 01 7fffffff"))  # bytecode ref out of range
    vm.receive(3, bytes.fromhex("00 03 0001 6d 05 00 00001000"))  # no such C function
    vm.process_inbox()
    got = vm.gload("order")
    assert vm.gload("n") == 3
    assert vm.invoke(got[0], ()) == 7  # robot 1's closure (bucket 1, first) works
    assert got[1] is None and got[2] is None  # robots 2 and 3 sent closures of nothing
    assert vm.net.stats["bad_closures"] == 2


@settings(max_examples=300, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.binary(max_size=64), max_size=8))
def test_random_payloads_never_raise(payloads: list[bytes]) -> None:
    vm, _ = make_robot(
        "v = stigmergy.create(5) s = swarm.create(3) s.join() "
        "neighbors.listen('m', function(t, v, s) { x = v })"
    )
    for k, p in enumerate(payloads):
        vm.receive(k, p)
    vm.process_inbox()
    vm.drain_outbox(190)
    assert vm.state != "error"


@settings(max_examples=200)
@given(st.binary(min_size=1, max_size=40), st.integers(0, 39), st.integers(0, 255))
def test_mutated_valid_messages_never_raise(tail: bytes, where: int, byte: int) -> None:
    vm, _ = make_robot("v = stigmergy.create(5) neighbors.listen('m', function(t, v, s) { })")
    for msg in (
        wire.VstigPut(5, "k", 1.5, 3, 2),
        wire.VstigQuery(5, "k", None, 0, 2),
        wire.Broadcast("m", 4),
        wire.SwarmList((1, 2)),
    ):
        good = bytearray(wire.encode(msg))
        good[where % len(good)] = byte
        vm.receive(1, bytes(good) + tail[: where % 3])
    vm.process_inbox()
    assert vm.state != "error"


@pytest.mark.parametrize(
    "expr,words",
    [
        ("neighbors.broadcast('t', big)", "255"),
        ("neighbors.broadcast('t', long)", "65535"),
        ("v.put('k', big)", "255"),
        ("v.put(long, 1)", "65535"),
        ("cyc = {} cyc.me = cyc neighbors.broadcast('t', cyc)", "deep"),
        ("function mk(x) { return function() { return x } } neighbors.broadcast('t', mk(1))", ""),
    ],
)
def test_unsendable_values_are_a_runtime_error(expr: str, words: str) -> None:
    src = f"""
    v = stigmergy.create(1)
    big = {{}}
    var i = 0
    while (i < 300) {{ big[i] = i  i = i + 1 }}
    long = "x"
    while (string.length(long) < 70000) {{ long = string.concat(long, long) }}
    {expr}
    """
    with pytest.raises(bvm.BuzzError, match=f"cannot send.*{words}"):
        make_robot(src)


def test_robots_share_decodings_but_each_owns_its_tables() -> None:
    # A table value is decoded once, but each robot gets its own copy: one robot's listener
    # changing it must not be seen by the others, nor by the shared decoding.
    src = "neighbors.listen('t', function(topic, v, s) { v.mine = id  v.in.n = id  got = v })"
    robots = [make_robot(src, robot_id=rid)[0] for rid in (1, 2, 3)]
    payload = wire.encode(wire.Broadcast("t", bvm.Table(x=1, **{"in": bvm.Table(n=0)})))
    for vm in robots:
        vm.receive(9, payload)
        vm.process_inbox()
    for rid, vm in enumerate(robots, 1):
        assert vm["got"]["x"] == 1 and vm["got"]["mine"] == rid and vm["got"]["in"]["n"] == rid
    shared, tables = network._shared[payload]
    assert tables and dict(shared.value["in"]) == {"n": 0} and "mine" not in shared.value
    scalar = wire.encode(wire.VstigPut(1, "k", 5, 1, 9))
    robots[0].receive(9, scalar)
    robots[0].process_inbox()
    assert network._shared.get(scalar) == (wire.VstigPut(1, "k", 5, 1, 9), False)


def test_messages_holding_closures_are_never_shared() -> None:
    # A received closure is resolved against the receiving VM's own functions.
    c = bvm.values.Closure(3, True, (None,), None)
    assert network._sharing(wire.Broadcast("t", c)) is None
    assert network._sharing(wire.VstigPut(1, "k", bvm.Table(f=c), 1, 9)) is None
    assert network._sharing(wire.VstigPut(1, "k", bvm.Table(f=1.5), 1, 9)) is True
    assert network._sharing(wire.SwarmList((1, 2))) is False


def test_a_shared_stigmergy_value_is_copied_by_each_robot_that_keeps_it() -> None:
    src = "v = stigmergy.create(1)"
    robots = [make_robot(src, robot_id=rid)[0] for rid in (1, 2)]
    payload = wire.encode(wire.VstigPut(1, "k", bvm.Table(pos=bvm.Table(x=1)), 1, 9))
    for vm in robots:
        vm.receive(9, payload)
        vm.process_inbox()
    a, b = (vm.stigmergies.stores[1].entries["k"].data for vm in robots)
    assert a is not b and a["pos"] is not b["pos"]
    a["pos"]["x"] = 5  # one robot's script changing what it got
    assert b["pos"]["x"] == 1
    assert network._shared[payload][0].value["pos"]["x"] == 1
