"""The VM's Python API, error locations, budgets and the translator's guards.

Most tests run twice: on translated code and on the reference interpreter
(`translate=False`), which must agree.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import pytest

import bvm
from bvm.values import Table, format_value

BOTH = pytest.mark.parametrize("translate", [True, False], ids=["translated", "interpreted"])


def make_vm(
    src: str, translate: bool = True, srcmap: bool = True, **kwargs: object
) -> tuple[bvm.VM, list[str]]:
    """A VM running `src` with a `log` that records its lines (`srcmap=False`: as a .bo
    loaded without its .bpos sidecar, errors located from the .bdb alone)."""
    lines: list[str] = []
    vm = bvm.VM(translate=translate, **kwargs)  # type: ignore[arg-type]
    program = bvm.compile_source(src, "prog.bzz")
    if not srcmap:
        program = bvm.Program(program.bytecode, program.debug, "prog.bo")
    vm.load(program)
    vm.register("log", lambda *args: lines.append("".join(map(format_value, args))))
    vm.execute()
    return vm, lines


# ---------------------------------------------------------------- the Python API


def test_compile_file_load_and_run(tmp_path: Path) -> None:
    script = tmp_path / "s.bzz"
    script.write_text("x = 41\nfunction inc(v) { return v + 1 }\n")
    program = bvm.compile_file(script)
    assert program.bytecode[:8] == b"\x02\x00x\x00inc\x00"  # parameters are not strings
    (tmp_path / "s.bo").write_bytes(program.bytecode)
    (tmp_path / "s.bdb").write_bytes(program.debug)
    loaded = bvm.Program.load(tmp_path / "s.bo")
    assert loaded.bytecode == program.bytecode and loaded.debug == program.debug
    vm = bvm.VM(robot_id=7)
    vm.load(loaded)
    vm.execute()
    assert vm["x"] == 41
    assert vm["id"] == 7
    assert vm.call("inc", vm["x"]) == 42


def test_globals_convert_between_python_and_buzz() -> None:
    vm, _ = make_vm("function total(t) { return reduce(t, function(k, v, a) { return a + v }, 0) }")
    vm["t"] = {"a": 1, "b": 2.5, 3: True}
    assert isinstance(vm.globals["t"], Table)
    assert vm.globals["t"][3] == 1 and vm.globals["t"][3].__class__ is int
    assert vm.call("total", {"x": 1, "y": 2}) == 3
    assert vm["t"] == {"a": 1, "b": 2.5, 3: 1}
    vm["big"] = 2**31  # wraps like a Buzz int
    assert vm["big"] == -(2**31)
    assert vm["unset"] is None


def test_register_python_function() -> None:
    seen = []

    def goto(x, y, z=0.0):
        seen.append((x, y, z))
        return {"ok": True}

    vm, lines = make_vm("function go() { var r = goto(1, 2.5)  log(r.ok) }")
    vm.register("goto", goto)
    vm.call("go")
    assert seen == [(1, 2.5, 0.0)] and lines == ["1"]


def test_register_wrong_argument_count_is_a_buzz_error() -> None:
    vm, _ = make_vm("function go() { return goto(1) }")
    vm.register("goto", lambda x, y: x + y)
    with pytest.raises(bvm.BuzzError, match=r"prog.bzz:1:\d+: .*goto\(\) expected 2 parameters"):
        vm.call("go")


def test_argument_counts_are_checked_alike_for_shared_code_and_wrappers() -> None:
    # The counts are cached by code object (every robot registers closures of the same few
    # functions): closures of one def share them, wrappers of different functions do not.
    import functools

    def wrap(f):  # type: ignore[no-untyped-def]
        @functools.wraps(f)
        def wrapper(*args):  # type: ignore[no-untyped-def]
            return f(*args)

        return wrapper

    def factory(k: int):  # type: ignore[no-untyped-def]
        def add(x, y):  # type: ignore[no-untyped-def]
            return x + y + k

        return add

    for one, two in ((factory(1), factory(2)), (wrap(lambda x: x), wrap(lambda x, y: x))):
        for f, good, bad in ((one, "f(1, 2)", "f(1)"), (two, "f(1, 2)", "f(1, 2, 3)")):
            if f is one and one.__name__ == "<lambda>":
                good, bad = "f(1)", "f(1, 2)"
            vm, _ = make_vm(f"function ok() {{ return {good} }}\nfunction ko() {{ return {bad} }}")
            vm.register("f", f)
            vm.call("ok")
            with pytest.raises(bvm.BuzzError, match=r"f\(\) expected"):
                vm.call("ko")


def test_host_exception_becomes_located_buzz_error() -> None:
    vm, _ = make_vm("function go() {\n  return boom()\n}")
    vm.register("boom", lambda: 1 / 0)
    with pytest.raises(bvm.BuzzError, match=r"prog.bzz:2:10: host function error: ZeroDivision"):
        vm.call("go")
    assert vm.state == "error"
    vm.reset_error()
    assert vm.state == "ready"


def test_missing_and_non_closure_function() -> None:
    vm, _ = make_vm("x = 3")
    with pytest.raises(bvm.BuzzError, match=r"cannot find function 'step\(\)'"):
        vm.call("step")
    vm.reset_error()
    with pytest.raises(bvm.BuzzError, match=r"function 'x\(\)': expected closure, got integer"):
        vm.call("x")


@BOTH
def test_host_function_as_callback(translate: bool) -> None:
    # The reference corrupts its stack here (closure_call runs an extra instruction).
    _, lines = make_vm('t = {.a = 1, .b = 2}\nforeach(t, log)\nlog("after")', translate)
    assert lines == ["a1", "b2", "after"]


# ---------------------------------------------------------------- errors and locations


# The source map puts an error at the failing operation: an operator, the `.` or `[` of an
# index, the start of a call (errors inside a host function too); 1-based columns.
LOCATED = [
    ("x = 1\ny = x + nil\nz = 0", (2, 7), "type mismatch: cannot add integer and nil"),
    ("function f() {\n  return 1 / 0\n}\nf()\nz = 0", (2, 12), "division by zero"),
    ("x = nil\nx.y = 1\nz = 0", (2, 2), "type mismatch: expected table, got nil"),
    ("f = 3\nf(1)\nz = 0", (2, 1), "type mismatch: expected closure, got integer"),
    ("t = {}\nt[nil] = 2\nz = 0", (2, 2), "can't be used as table key"),
    ("s = string.length(3)\nz = 0", (1, 5), "type mismatch: expected string, got integer"),
    ('x = 1\n\nvar z = 3 + "hello"\n\n# a comment\nw = 0', (3, 11), "cannot add integer"),
    ("x = 1\nt = {}\nr = t.a.b", (3, 8), "type mismatch: expected table, got nil"),
    ('x = -"s"', (1, 5), "type mismatch"),
    ("x = !1.5", (1, 5), "expected integer, got float"),
    ("if (nil < 1) {}", (1, 9), "cannot order nil"),
    ("return 1", (1, 1), "return outside a function"),
    ('x = "a"\ny = (1 + 2) * x', (2, 13), "type mismatch"),
]


@BOTH
@pytest.mark.parametrize(("src", "where", "message"), LOCATED)
def test_runtime_errors_name_the_failing_operation(
    translate: bool, src: str, where: tuple[int, int], message: str
) -> None:
    with pytest.raises(bvm.BuzzError) as info:
        make_vm(src, translate)
    err = info.value
    assert err.location == ("prog.bzz", *where), str(err)
    assert message in err.message
    assert str(err).startswith(f"prog.bzz:{where[0]}:{where[1]}: ")


@BOTH
@pytest.mark.parametrize(
    ("src", "where", "message"),
    # Without the source map (a .bo whose .bpos is missing), as the reference: each
    # instruction carries the parser's lookahead token (docs/language.md#annotation-rule),
    # so an error is reported at the token after the failing operation; tput errors at the
    # instruction before the tput, errors inside a host function at its call
    # (docs/bytecode.md#step-loop, #errors).
    [
        ("x = 1\ny = x + nil\nz = 0", (3, 0), "type mismatch: cannot add integer and nil"),
        ("function f() {\n  return 1 / 0\n}\nf()\nz = 0", (3, 0), "division by zero"),
        ("x = nil\nx.y = 1\nz = 0", (2, 6), "type mismatch: expected table, got nil"),
        ("f = 3\nf(1)\nz = 0", (3, 0), "type mismatch: expected closure, got integer"),
        ("t = {}\nt[nil] = 2\nz = 0", (2, 9), "can't be used as table key"),
        ("s = string.length(3)\nz = 0", (2, 0), "type mismatch: expected string, got integer"),
    ],
)
def test_runtime_error_locations_without_the_source_map_are_the_references(
    translate: bool, src: str, where: tuple[int, int], message: str
) -> None:
    with pytest.raises(bvm.BuzzError) as info:
        make_vm(src, translate, srcmap=False)
    err = info.value
    assert err.location is not None
    file, line, col = err.location
    assert file.endswith("prog.bzz")
    assert (line, col) == where, str(err)
    assert message in err.message
    assert str(err).startswith(f"{file}:{line}:{col}: ")


@BOTH
def test_error_in_nested_calls_is_located_in_the_innermost_buzz_frame(translate: bool) -> None:
    # Buzz -> host -> Buzz -> Buzz: each frame on the way out must not move the location
    # the innermost one gave (the interpreter records it as the exception leaves a frame).
    src = (
        "function inner(t) {\n  return t.x.y\n}\n"
        "function middle(v) {\n  var a = 1\n  return inner({})\n}\n"
        "function outer() {\n  var t = {.a = 1}\n  foreach(t, function(k, v) { middle(v) })\n}\n"
    )
    vm, _ = make_vm(src, translate)
    with pytest.raises(bvm.BuzzError, match="expected table, got nil") as info:
        vm.call("outer")
    assert info.value.location == ("prog.bzz", 2, 13), str(info.value)
    # The Buzz call stack, innermost first; the lambda is called through foreach.
    assert str(info.value).splitlines()[1:] == [
        "  in inner, called at prog.bzz:6:10",
        "  in middle, called at prog.bzz:10:31",
        "  in <lambda at prog.bzz:10:14>, called at prog.bzz:10:3",
        "  in outer, called by the host",
    ]


@BOTH
def test_missing_argument_reads_fail_and_extra_arguments_are_ignored(translate: bool) -> None:
    src = "function f(a, b) { return b }\nfunction g(a) { return a }\n"
    vm, _ = make_vm(src, translate)
    assert vm.call("g", 1, 2, 3) == 1
    with pytest.raises(bvm.BuzzError, match="not enough local symbols"):
        vm.call("f", 1)


def test_error_state_blocks_until_reset() -> None:
    vm, _ = make_vm("function bad() { return nil + 1 }\nfunction ok() { return 1 }")
    with pytest.raises(bvm.BuzzError):
        vm.call("bad")
    with pytest.raises(bvm.BuzzError, match="error state"):
        vm.call("ok")
    vm.reset_error()
    assert vm.call("ok") == 1


# ---------------------------------------------------------------- budget


@BOTH
def test_infinite_loop_hits_the_tick_budget(translate: bool) -> None:
    vm, _ = make_vm("function spin() { while (1) {} }", translate, max_ticks=5000)
    with pytest.raises(bvm.BuzzBudgetExceeded, match="5000 loop iterations"):
        vm.call("spin")
    assert vm.error is not None and vm.error.location is not None


def test_tick_budget_is_deterministic_and_resets_per_entry() -> None:
    src = "function count(n) { var i = 0  while (i < n) { i = i + 1 }  return i }"
    vm, _ = make_vm(src, max_ticks=1000)
    assert vm.call("count", 999) == 999
    assert vm.call("count", 999) == 999  # a fresh allowance each entry
    with pytest.raises(bvm.BuzzBudgetExceeded, match="more than 1000 loop iterations"):
        vm.call("count", 1001)


@pytest.mark.parametrize("translate", [True, False], ids=["translated", "interpreted"])
def test_time_budget_stops_runaway_recursion(translate: bool) -> None:
    # No loop at all: exponential recursion is stopped by the time budget.
    src = "function fib(n) { if (n < 2) return n  return fib(n - 1) + fib(n - 2) }"
    vm, _ = make_vm(src, translate, max_seconds=0.05)
    with pytest.raises(bvm.BuzzBudgetExceeded, match="longer than 0.05 s") as info:
        vm.call("fib", 60)
    assert info.value.location is not None  # reported where the script was
    vm.reset_error()
    # And the VM is usable again: with no deadline, so a loaded machine cannot fail this.
    vm.max_seconds = None
    assert vm.call("fib", 10) == 55


def test_time_budget_stops_a_runaway_step() -> None:
    vm, _ = make_vm("function spin() { while (1) {} }", max_seconds=0.05)
    t0 = time.monotonic()
    with pytest.raises(bvm.BuzzBudgetExceeded, match="longer than 0.05 s"):
        vm.call("spin")
    assert time.monotonic() - t0 < 5.0  # generous: only proves it stopped


@pytest.mark.skipif(not hasattr(time, "pthread_getcpuclockid"), reason="no thread CPU clock")
def test_time_budget_counts_processor_time_not_waiting() -> None:
    """A step that waits (a loaded computer, a host call that blocks) is not a runaway:
    a SITL node on a busy machine lost its script to a wall-clock budget."""
    vm, lines = make_vm('function step() { wait()  log("done") }', max_seconds=0.05)
    vm.register("wait", lambda: time.sleep(0.3))  # six allowances of wall time, no CPU
    vm.call("step")
    assert lines == ["done"]


def test_time_budget_never_fires_outside_its_entry() -> None:
    # Deadlines that expire around the end of an entry must not leak into host code.
    src = "function work(n) { var i = 0  while (i < n) { i = i + 1 }  return i }"
    vm, _ = make_vm(src, max_seconds=0.0005)
    outcomes = set()
    for n in range(0, 20000, 400):
        try:
            outcomes.add(vm.call("work", n) == n)
        except bvm.BuzzBudgetExceeded:
            outcomes.add("timeout")
            vm.reset_error()
    assert True in outcomes  # some entries finished in time
    end = time.monotonic() + 0.05
    spins = 0
    while time.monotonic() < end:  # plain Python: any stray timeout would raise here
        spins += 1
    assert spins > 0


def test_doubling_string_is_stopped_before_it_eats_memory() -> None:
    src = 'function grow() { var s = "x"  while (1) { s = string.concat(s, s) } }'
    vm, _ = make_vm(src)
    with pytest.raises(bvm.BuzzError, match="string too long: .*the limit is 16777216"):
        vm.call("grow")


# ---------------------------------------------------------------- recursion


def test_deep_recursion_works() -> None:
    vm, _ = make_vm("function d(n) { if (n == 0) return 0  return 1 + d(n - 1) }")
    assert vm.call("d", 5000) == 5000


@BOTH
def test_deep_recursion_overflow_is_a_clean_error(translate: bool) -> None:
    vm, _ = make_vm("function d(n) { return 1 + d(n + 1) }", translate)
    with pytest.raises(bvm.BuzzError, match="stack overflow"):
        vm.call("d", 0)


# ---------------------------------------------------------------- translator guards


def test_specialized_function_still_right_for_other_types() -> None:
    # Translated for ints on the first call; later floats, strings and tables must take
    # the general path with the right semantics and errors.
    vm, _ = make_vm("function add(a, b) { return a + b }")
    assert vm.call("add", 2147483647, 1) == -2147483648
    assert vm.call("add", 0.5, 0.25) == 0.75
    assert vm.call("add", 16777217, 0.0) == 16777216.0  # int to binary32 first
    with pytest.raises(bvm.BuzzError, match="cannot add string and integer"):
        vm.call("add", "a", 1)


def test_compiled_programs_are_translated_not_interpreted(caplog: pytest.LogCaptureFixture) -> None:
    src = (Path(__file__).parent.parent / "buzz_scripts/examples/hello.bzz").read_text()
    with caplog.at_level(logging.INFO, logger="bvm"):
        vm, _ = make_vm(src)
        vm.call("init")
        vm.call("step")
        vm.call("destroy")
    assert not [r for r in caplog.records if "interpreter" in r.getMessage()]


def test_pushs_past_the_bytecode_strings_names_library_strings() -> None:
    # As in the reference, ids after the program's own strings are the library's names.
    program = bvm.assemble("!1\n'x\n\n\tnop\n\tpushs 0\n\tpushs 1\n\tgstore\n\tdone\n")
    vm = bvm.VM()
    vm.load(program)
    vm.execute()
    assert vm["x"] == "get"


def test_unknown_string_id_is_a_runtime_error() -> None:
    program = bvm.assemble("!1\n'x\n\n\tnop\n\tpushs 0\n\tpushs 4000\n\tgstore\n\tdone\n")
    vm = bvm.VM()
    vm.load(program)
    with pytest.raises(bvm.BuzzError, match="unknown string id: id read = 4000"):
        vm.execute()


def test_empty_program_fails_like_the_reference() -> None:
    vm = bvm.VM()
    with pytest.raises(bvm.BuzzError, match="pc out of range"):
        vm.load(bvm.compile_source(""))


# ---------------------------------------------------------------- budget edge cases


def test_a_timeout_never_escapes_unlocated() -> None:
    # Tight deadlines hit every moment of an entry, the budget's own set-up included.
    vm, _ = make_vm("function f() { return 1 }", max_seconds=0.0002)
    for _ in range(300):
        try:
            assert vm.call("f") == 1
        except bvm.BuzzBudgetExceeded:
            assert vm.state == "error"
            vm.reset_error()


def test_reentrant_call_shares_the_outer_budget() -> None:
    src = (
        "function cb() { return 1 }\n"
        "function spin(n) { var i = 0  while (i < n) { i = i + 1 }  hook()\n"
        "  while (i < 2 * n) { i = i + 1 }  return i }"
    )
    vm, _ = make_vm(src, max_ticks=50_000)
    vm.register("hook", lambda: vm.call("cb"))
    assert vm.call("spin", 20_000) == 40_000
    with pytest.raises(bvm.BuzzBudgetExceeded):
        vm.call("spin", 30_000)  # 60,000 iterations in all, callback or not


def test_a_swallowed_timeout_comes_back() -> None:
    def swallow() -> int:
        try:
            return sum(range(2000))
        except Exception:  # a careless host function
            return 0

    vm, _ = make_vm("function spin() { while (1) { swallow() } }", max_seconds=0.05)
    vm.register("swallow", swallow)
    with pytest.raises(bvm.BuzzBudgetExceeded):
        vm.call("spin")


# ---------------------------------------------------------------- hostile input


def test_cyclic_table_converts_to_python() -> None:
    vm, _ = make_vm("t = {}\nt.me = t\nt.n = 1")
    t = vm["t"]
    assert t["me"] is t and t["n"] == 1


def test_hand_made_bytecode_cannot_grow_a_frame_without_bound() -> None:
    program = bvm.assemble("!0\n\n\tnop\n\tpushnil\n\tlstore 65535\n\tdone\n")
    vm = bvm.VM()
    vm.load(program)
    with pytest.raises(bvm.BuzzError, match="past the limit of 4096"):
        vm.execute()


def test_done_in_the_registration_prologue_is_a_clean_error() -> None:
    vm = bvm.VM()
    with pytest.raises(bvm.BuzzError, match="done in the function-registration prologue"):
        vm.load(bvm.assemble("!0\n\n\tdone\n\tnop\n\tdone\n"))


@BOTH
def test_nan_with_nan_is_nan(translate: bool) -> None:
    # The sign bit of NaN op NaN is unspecified (docs/compat.md); NaN-ness is not.
    src = (
        "function f() { var n = 0.0 / 0.0  var m = -n\n"
        "  return {.a = n + m, .b = m * n, .c = n - m} }"
    )
    vm, _ = make_vm(src, translate)
    for v in vm.call("f").values():
        assert v != v


def test_a_time_budget_leaves_the_interpreter_as_it_found_it() -> None:
    # Withdrawing an already delivered timeout with PyThreadState_SetAsyncExc(NULL) left
    # CPython's async-exception signal set for good: sys.settrace then spun forever. Run in
    # a child process so a regression fails here instead of hanging the suite.
    import subprocess
    import sys as _sys

    child = """
import sys, bvm
vm = bvm.VM(max_seconds=0.1)
vm.load(bvm.compile_source("var i = 0\\nwhile (1) { i = i + 1 }\\n", "r.bzz"))
try:
    vm.execute()
except bvm.BuzzBudgetExceeded:
    pass
events = []
sys.settrace(lambda frame, event, arg: events.append(event))
sum(range(3))
(lambda: 1)()
sys.settrace(None)
print("traced", len(events))
"""
    out = subprocess.run([_sys.executable, "-c", child], capture_output=True, text=True, timeout=60)
    assert out.stdout.startswith("traced "), out.stderr


# ---------------------------------------------------------------- the host API


def test_counters_are_read_only_and_hosts_count_their_own() -> None:
    vm, _ = make_vm("x = 1")
    vm.receive(2, b"\xff")  # not a message
    vm.process_inbox()
    assert vm.counters["decode_errors"] == 1
    assert vm.counters["bundle_errors"] == 0  # never counted
    vm.count("bundle_errors")
    vm.count("bundle_errors", 2)
    assert vm.counters["bundle_errors"] == 3
    with pytest.raises(TypeError):
        vm.counters["sent"] = 5  # type: ignore[index]  # the point: the mapping is read-only


def test_neighbor_columns_are_set_neighbors_without_checks() -> None:
    src = (
        "function n() { return neighbors.count() }\n"
        "function d(i) { return neighbors.get(i).distance }\n"
    )
    slow, _ = make_vm(src)
    fast, _ = make_vm(src)
    slow.set_neighbors([(2, 1.5, 0.25, 0.0), (7, 3.0, -1.0, 0.0)])
    fast.set_neighbor_columns([2, 7], [1.5, 3.0], [0.25, -1.0])
    for vm in (slow, fast):
        assert vm.call("n") == 2
        assert vm.call("d", 7) == 3.0


def test_peer_count_is_the_robots_heard_in_swarm_lists() -> None:
    from bvm import wire

    vm, _ = make_vm("x = 1")
    assert vm.peer_count == 0
    for sender in (3, 4):
        vm.receive(sender, wire.encode(wire.SwarmList((1,))))
    vm.process_inbox()
    assert vm.peer_count == 2


@pytest.mark.parametrize("script", ["task_allocation.bzz", "coverage.bzz"])
def test_the_compiled_prologue_registers_what_interpreting_it_does(script: str) -> None:
    """VM.load runs the compiler's prologue (`pushs; pushcn; gstore` triples, then `nop`)
    as data instead of interpreting it: the same globals, in the same order, as the
    interpreter gives a copy of the program whose prologue is not recognised."""
    root = Path(__file__).resolve().parent.parent / "buzz_scripts"
    program = bvm.compile_file(root / script, [str(root)])
    plan = program.registrations()
    assert plan is not None and len(plan[0]) > 10  # the fast path is taken
    interpreted = bvm.compile_file(root / script, [str(root)])
    interpreted._plan = False  # not recognised: the interpreter runs it
    assert interpreted.registrations() is None

    def registered(p: bvm.Program) -> list[tuple[str, object]]:
        vm = bvm.VM()
        vm.load(p)
        return [
            (k, (v.ref, v.native, v.actrec) if isinstance(v, bvm.Closure) else v)
            for k, v in vm.globals.items()
            if not k.startswith("_") and not isinstance(v, Table)  # not the translator's
        ]

    assert registered(program) == registered(interpreted)


def test_a_prologue_the_compiler_did_not_write_is_interpreted() -> None:
    # A `pushi` among the triples: not the compiler's pattern, so no plan.
    program = bvm.assemble("!0\n\n\tpushi 1\n\tpop\n\tnop\n\tdone\n")
    assert program.registrations() is None
    vm = bvm.VM()
    vm.load(program)
    vm.execute()
