"""Neighbour poses made on first use: which programs qualify, and that a script sees exactly
what it would see with the tables made every step."""

from __future__ import annotations

import struct

import pytest
from buzzhost import make_robot
from hypothesis import given
from hypothesis import strategies as st

import bvm
from bvm import wire
from bvm.digest import state_digest
from bvm.sweep import MAX_SWEPT_BYTES
from bvm.values import f32, format_log

# Every query method, identities included: `get` twice gives the same table, and the table
# `get` gave is the one `foreach` and `poses`-carrying derived tables hand out afterwards.
QUERIES = """
function step() {
  var a = neighbors.get(3)
  log("get3 ", a, " same ", a == neighbors.get(3), " f ", neighbors.get(3.0) == a)
  if (a != nil) { a.seen = 1 }
  log("count ", neighbors.count(), " get99 ", neighbors.get(99), " gets ", neighbors.get("x"))
  neighbors.foreach(function(rid, d) {
    log("each ", rid, " ", d.distance, " ", d.azimuth, " ", d.elevation, " ", d.seen,
        " ", d == neighbors.get(rid))
  })
  var near = neighbors.filter(function(rid, d) { return d.distance < 50.0 })
  log("near ", near.count(), " ", near.get(3) == a)
  log("sum ", neighbors.reduce(function(rid, d, acc) { return acc + d.distance }, 0.0))
  log("map ", neighbors.map(function(rid, d) { return rid }).count())
  log("kin ", neighbors.kin().count(), " nonkin ", neighbors.nonkin().count())
}
"""

COUNT_ONLY = """
function step() {
  log("count ", neighbors.count(), " get ", neighbors.get(2))
}
"""


def _robot(src: str, lazy: bool, translate: bool) -> tuple[bvm.VM, list[str]]:
    vm, lines = make_robot(src, 1, translate=translate)
    assert vm.neighbors.lazy  # the program reads `neighbors` only through its methods
    vm.neighbors.lazy = lazy
    return vm, lines


def _columns(raw: list[tuple[int, float, float]]) -> tuple[list[int], list[float], list[float]]:
    seen: dict[int, tuple[float, float]] = {}
    for rid, d, a in raw:
        seen.setdefault(rid, (f32(d), f32(a)))
    return list(seen), [v[0] for v in seen.values()], [v[1] for v in seen.values()]


STEPS = st.lists(
    st.lists(
        st.tuples(
            st.integers(0, 8),
            st.floats(0, 100, allow_nan=False, width=32),
            st.floats(-3.0, 3.0, allow_nan=False, width=32),
        ),
        max_size=6,
    ),
    min_size=1,
    max_size=4,
)


@pytest.mark.parametrize("translate", [True, False], ids=["translated", "interpreted"])
@pytest.mark.parametrize("src", [QUERIES, COUNT_ONLY], ids=["queries", "count-only"])
@given(steps=STEPS)
def test_lazy_poses_are_what_eager_tables_give(
    translate: bool, src: str, steps: list[list[tuple[int, float, float]]]
) -> None:
    lazy, lazy_lines = _robot(src, True, translate)
    eager, eager_lines = _robot(src, False, translate)
    for raw in steps:
        for vm in (lazy, eager):
            vm.set_neighbor_columns(*_columns(raw))
            vm.call("step")
        assert lazy_lines == eager_lines
        # The digest settles what is pending: a recording sees the same state.
        assert state_digest(lazy) == state_digest(eager)


def test_a_step_that_reads_no_neighbour_makes_no_table() -> None:
    vm, lines = _robot(COUNT_ONLY, True, True)
    vm.set_neighbor_columns([2, 4], [f32(1.5), f32(2.5)], [0.0, 0.0])
    vm.call("step")
    assert lines == ["count 2 get [table with 3 elems]"]
    assert "poses" not in vm.neighbors.table  # only the one entry `get` asked for exists
    poses = vm.neighbors.poses()
    assert poses is not None and sorted(poses) == [2, 4]
    assert poses[4]["distance"] == 2.5


def test_columns_of_different_lengths_are_refused() -> None:
    vm, _ = _robot(COUNT_ONLY, True, True)
    with pytest.raises(ValueError, match="different lengths"):
        vm.set_neighbor_columns([1, 2], [1.0], [0.0, 0.0])


def _reads(src: str) -> frozenset[str] | None:
    return bvm.compile_source(src, "r.bzz").member_reads("neighbors")


@pytest.mark.parametrize(
    ("src", "reads"),
    [
        ("function step() { neighbors.get(1) }", frozenset({"get"})),
        ("var g = neighbors.get\nfunction step() { g(1) }", frozenset({"get"})),
        ("function step() { log(neighbors.poses) }", frozenset({"poses"})),
        ("function step() { log(neighbors.count(), neighbors.kin()) }", {"count", "kin"}),
        ("var n = neighbors\nfunction step() { n.get(1) }", None),
        ("function step() { foreach(neighbors, function(k, v) {}) }", None),
        ("function step() { log(size(neighbors)) }", None),
        ("function step() { neighbors.get = nil }", None),
        ("function step() { neighbors.poses = {} }", None),
        ("function f(t) { return t }\nfunction step() { f(neighbors).get(1) }", None),
        ("function step() { math.cos(1.0) }", frozenset()),
    ],
)
def test_which_programs_read_neighbors_only_through_methods(
    src: str, reads: frozenset[str] | set[str] | None
) -> None:
    assert _reads(src) == (frozenset(reads) if reads is not None else None)


def _asm_reads(body: str) -> frozenset[str] | None:
    program = bvm.assemble(f"!3\n'neighbors\n'get\n'step\n{body}", "r.basm")
    return program.member_reads("neighbors")


def test_a_global_read_by_a_computed_name_counts_as_any_use() -> None:
    # `gload` of whatever is on the stack: it may be "neighbors".
    assert _asm_reads("\tpushs 0\n\tpushs 1\n\tpop\n\tdup\n\tgload\n\tpop\n\tdone\n") is None
    plain = _asm_reads("\tpushs 0\n\tgload\n\tpushs 1\n\ttget\n\tpop\n\tdone\n")
    assert plain == frozenset({"get"})


def test_a_jump_into_a_member_read_counts_as_any_use() -> None:
    # Jumping to the `pushs get` would run `tget` on whatever the other path left.
    body = (
        "\tpushi 1\n\tjumpz @__label_1\n\tpushs 0\n\tgload\n@__label_1\n\tpushs 1\n\ttget\n"
        "\tpop\n\tdone\n"
    )
    assert _asm_reads(body) is None


def test_a_method_calls_copy_of_the_table_must_reach_the_call_unread() -> None:
    # `neighbors.get(5)`: the `dup` leaves the table in the self slot `callc` pops unread.
    call = "\tpushs 0\n\tgload\n\tdup\n\tpushs 1\n\ttget\n\tpushi 5\n\tpushi 1\n\tcallc\n"
    assert _asm_reads(call + "\tpop\n\tdone\n") == frozenset({"get"})
    # Hand-made code that pops down to that copy could keep the table: any use.
    leak = "\tpushs 0\n\tgload\n\tdup\n\tpushs 1\n\ttget\n\tpop\n\tpop\n\tdone\n"
    assert _asm_reads(leak) is None
    # A call of no arguments pops it as its self slot too.
    bare = "\tpushs 0\n\tgload\n\tdup\n\tpushs 1\n\ttget\n\tpushi 0\n\tcallc\n\tdone\n"
    assert _asm_reads(bare) == frozenset({"get"})
    # A count of more arguments than were pushed takes the copy as an argument: any use.
    wide = "\tpushs 0\n\tgload\n\tdup\n\tpushs 1\n\ttget\n\tpushi 2\n\tcallc\n\tdone\n"
    assert _asm_reads(wide) is None


def test_nested_method_calls_read_only_through_methods() -> None:
    assert _reads("function step() { neighbors.get(neighbors.count() + 1) }") == frozenset(
        {"get", "count"}
    )
    assert _reads(
        "function step() { neighbors.foreach(function(r, d) { neighbors.get(r) }) }"
    ) == frozenset({"get", "foreach"})


RECEIVER = """
var s = "poses"
function step() { log("count ", neighbors.count()) }
neighbors.listen("f", function(t, v, s) { log("got ", v()) })
"""


def _op(op: int, arg: int | None = None) -> bytes:
    return bytes([op]) + (struct.pack("<i", arg) if arg is not None else b"")


@pytest.mark.parametrize("translate", [True, False], ids=["translated", "interpreted"])
def test_a_closure_received_into_code_the_sweep_did_not_see(translate: bool) -> None:
    # A peer sends a closure whose offset lies past a byte the sweep could not decode,
    # where `neighbors.poses` is read directly: the robot must see it as if made eagerly.
    base = bvm.compile_source(RECEIVER, "r.bzz")
    nb, po = base.strings.index("neighbors"), base.strings.index("poses")
    hidden = _op(37, nb) + _op(28) + _op(37, po) + _op(32) + _op(6)  # pushs gload pushs tget ret1
    program = bvm.Program(base.bytecode + b"\xff" + hidden, base.debug, "r.bo")
    assert program.member_reads("neighbors") == frozenset({"count", "listen"})
    closure = wire.WireClosure(False, len(base.bytecode) + 1)
    payload = wire.encode(wire.Broadcast(topic="f", value=closure))
    outputs = []
    for lazy in (True, False):
        vm = bvm.VM(robot_id=1, translate=translate)
        vm.load(program)
        assert vm.neighbors.lazy
        vm.neighbors.lazy = lazy
        lines: list[str] = []
        vm.register("log", lambda *a, out=lines: out.append(format_log(a)))
        vm.execute()
        for _ in range(2):
            vm.receive(7, payload)
            vm.process_inbox()
            vm.set_neighbor_columns([2, 3], [f32(1.0), f32(2.0)], [0.0, 0.0])
            vm.call("step")
        outputs.append(lines)
        assert not vm.neighbors.lazy  # that code may read anything from now on
    assert (
        outputs[0] == outputs[1] == ["got [nil]", "count 2", "got [table with 2 elems]", "count 2"]
    )


def test_the_host_reading_neighbors_sees_its_poses() -> None:
    vm, _ = _robot(COUNT_ONLY, True, True)
    vm.set_neighbor_columns([2], [f32(1.5)], [0.0])
    assert vm["neighbors"]["poses"] == {2: {"distance": 1.5, "azimuth": 0.0, "elevation": 0.0}}
    vm.set_neighbor_columns([4], [f32(2.5)], [0.0])
    assert sorted(vm.buzz_globals()["neighbors"]["poses"]) == [4]


def test_deeply_nested_method_calls_and_large_programs() -> None:
    # Each call's copy is followed in one pass, however deep the nesting.
    depth = 300
    body = "\tpushs 0\n\tgload\n\tdup\n\tpushs 1\n\ttget\n" * depth + "\tpushi 0\n\tcallc\n"
    body += "\tpushi 1\n\tcallc\n" * (depth - 1) + "\tpop\n\tdone\n"
    assert _asm_reads(body) == frozenset({"get"})
    # Past MAX_SWEPT_BYTES nothing is swept: any use.
    small = bvm.compile_source("function step() { neighbors.count() }", "s.bzz")
    big = bvm.Program(small.bytecode + bytes(MAX_SWEPT_BYTES), small.debug, "big.bo")
    assert small.member_reads("neighbors") == frozenset({"count"})
    assert big.member_reads("neighbors") is None


@given(code=st.binary(min_size=1, max_size=400))
def test_the_sweep_survives_any_code(code: bytes) -> None:
    # Any bytes after a valid string table: an answer, never an exception.
    base = bvm.compile_source("function step() { neighbors.get(1) }", "f.bzz")
    program = bvm.Program(base.bytecode[: base.code_start] + code, b"", "fuzz.bo")
    use = program.global_use("neighbors")
    assert use.keys is None or use.keys <= {"get"} | set(program.strings)
    assert not use.enters_cleanly(-1) and not use.enters_cleanly(len(program.bytecode))
