"""Differential fuzzing: the translator (bvm/translate/) against the reference interpreter.

Hypothesis generates random valid Buzz programs (tests/fuzz/buzzgen.py, the grammar of
docs/language.md#grammar);
each runs with translate=True and translate=False (same rng seed and budget). They must
agree on the logged lines, on success or the error (message and bytecode offset), on the
final globals, and on a second round of calls to every function the program defines, with
ints, then floats, then strings, then a mix (the translator specializes on the first call's
argument types). `FUZZ_EXAMPLES` sets the example count (default 200); long campaigns run
with `python -m tests.fuzz.campaign --mode diff`.

Runs that hit a resource limit (loop budget, stack depth, time) are not compared: the two
paths count these differently (see test_bug_for_loop_ticks_twice_when_interpreted).
Open bugs can be filtered by `oracle.KNOWN_BUGS` and pinned by xfail(strict=True) tests at
the end of this file; delete a filter when its test starts passing.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from fuzz import oracle
from fuzz.buzzgen import generate_program
from fuzz.choosers import HypothesisChooser
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bvm

EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "200") or 200)
CONFORMANCE = Path(__file__).parent / "conformance"

pytestmark = pytest.mark.filterwarnings("ignore::SyntaxWarning")
oracle.warm_up()


def assert_agree(source: str, functions: list[tuple[str, int]]) -> oracle.Verdict:
    """Run the differential check on a source program and fail with a readable report."""
    with oracle.deadline(60):
        verdict = oracle.check_source(source, functions)
    assert verdict.ok, (
        f"translated and interpreted runs disagree ({verdict.kind}):\n{verdict.detail}\n\n"
        f"functions called again: {functions}\n--- program ---\n{source}"
    )
    return verdict


@pytest.mark.long
@settings(
    max_examples=EXAMPLES,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(st.data())
def test_generated_programs_agree(data: st.DataObject) -> None:
    program = generate_program(HypothesisChooser(data))
    functions = [(f.name, f.nparams) for f in program.functions]
    assert_agree(program.source, functions)


def _corpus() -> list[Path]:
    return sorted(CONFORMANCE.glob("*.bzz"))


@pytest.mark.parametrize("script", _corpus(), ids=lambda p: p.stem)
def test_conformance_scripts_agree(
    script: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every conformance script, both ways (init/step/destroy called when defined)."""
    monkeypatch.chdir(tmp_path)  # some scripts write files (io library)
    try:
        program = bvm.compile_source(script.read_bytes(), str(script), [str(CONFORMANCE)])
    except bvm.BuzzCompileError:
        pytest.skip("a compile-error script")
    calls = [(name, 0) for name in ("init", "step", "step", "destroy")]
    t = oracle.run_program(program, calls, translate=True, call_rounds=((),))
    i = oracle.run_program(program, calls, translate=False, call_rounds=((),))
    verdict = oracle.compare(t, i)
    assert verdict.ok, verdict.detail


SHAPES = {
    # Type inference across loop iterations: int -> float -> string.
    "loop-widening": """
        function f(n) {
          var v = 1
          var c = 0
          while (c < 4) { c = c + 1  v = v * 2  if (c == 2) { v = v + 0.5 }
                          if (c == 3) { v = string.tostring(v) } log(v) }
          return v
        }
        log(f(1))
    """,
    # int32 wrap at the edges, small-constant wrap checks, shifts and C division rules.
    "int-edges": """
        x = 2147483647
        log(x + 1, x * 2, -x - 2, (x + 1) / -1, (-2147483648) % -1, 7 % -3, -7 % 3, -7 % -3)
        log(1 << 31, 1 << 32, 1 << -1, -8 >> 1, !0, 16777217 + 0.0, 2147483648 == -2147483648)
        var_x = 0
        for (i = 0, i < 4, i = i + 1) { var_x = var_x + 1073741824 log(var_x) }
    """,
    # binary32 edge values.
    "float-edges": """
        big = 340282346638528859811704183484516925440.0
        log(big * 2.0, -big * 2.0, big * 2.0 - big * 2.0, 0.0 * -1.0, 1.0 / 0.0, -0.0)
        log(0.000000000000000000000000000000000000000000001, 16777217.0, 1.2.3, 1..2)
        log(-0.0 == 0.0, (0.0 / 0.0) == 1, 2 ^ 0.5, (-8) ^ 0.5, 0 ^ -1, -7.5 % 2.0)
    """,
    # Comparisons across types, nil, the strcmp rule and truthiness.
    "comparisons": """
        log(1 == 1.0, "1" == 1, "1.000000" == 1.0, nil == nil, nil != 1, "a" < "b", "b" < "a")
        log({} == {}, 0.0 and 1, "" and 1, nil or 0, not 0, not nil, not "")
        t = {}
        log(t == t, t != {}, log == log, size == size)
    """,
    # Tables: number keys 1 and 1.0 are the same slot, deletion, nested, iteration order.
    "tables": """
        t = {.1 = "a", .2.5 = "b", .x = 3}
        t[1.0] = "c"  t.x = nil  t["y"] = {.z = 1}
        foreach(t, function(k, v) { log(k, v) })
        log(size(t), t.y.z, t[2.5], t.nothere)
        m = map(t, function(k, v) { return k })
        log(size(m), reduce(t, function(k, v, a) { return a + 1 }, 0))
        log(size(filter(t, function(k, v) { return isstring(v) })))
    """,
    # Methods, self binding at tput, lambdas capturing locals by value.
    "closures": """
        obj = {.val = 1, .add = function(d) { self.val = self.val + d return self.val }}
        log(obj.add(2), obj.add(3.5))
        other = {.val = 10}
        other.add = obj.add
        log(other.add(1), obj.val)
        function mk(n) { var c = n return function() { c = c + 1 return c } }
        g = mk(10)
        log(g(), g())
        function outer(x) { var y = x * 2 var h = function(z) { return x + y + z } return h(1) }
        log(outer(1), outer(2.5))
    """,
    # Wrong argument counts: extra arguments are ignored, missing ones fail when read.
    "arity": """
        function two(a, b) { return a }
        log(two(1, 2), two(1, 2, 3), two(1))
        function uses(a, b) { return b }
        log(uses(1))
    """,
    # Built-ins replaced by the script (the translator inlines some library calls).
    "overrides": """
        log(size({.a = 1}), string.length("abc"))
        size = function(x) { return 42 }
        log(size({.a = 1}))
        string = {.length = math.abs}
        log(string.length(-3))
    """,
    # Errors inside callbacks, attributed to the innermost Buzz instruction.
    "callback-error": """
        t = {.a = 1, .b = "x"}
        log(reduce(t, function(k, v, acc) { return acc + v }, 0))
    """,
}


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_shapes_agree(name: str) -> None:
    """Hand-written programs around the translator's specializations."""
    source = "\n".join(line.strip() for line in SHAPES[name].strip().splitlines()) + "\n"
    functions = [("f", 1), ("mk", 1), ("outer", 1), ("two", 2), ("uses", 2)]
    defined = [(n, k) for n, k in functions if f"function {n}(" in source]
    assert_agree(source, defined)


# ---------------------------------------------------------------- open bugs (found by fuzzing)


def outcomes(source: str, *, max_ticks: int = 200_000) -> tuple[list[str], list[str]]:
    """The event lists of the translated and interpreted runs (no known-bug filtering)."""
    program = bvm.compile_source(source, "/fuzz/repro.bzz")
    t = oracle.run_program(program, [], translate=True, max_ticks=max_ticks)
    i = oracle.run_program(program, [], translate=False, max_ticks=max_ticks)
    return t.events, i.events


def test_negative_float_literal_key() -> None:
    """Found by fuzzing, fixed in cd6edbb: `t[-1.5] = 1` / `t[-1.5]` -- the translator's
    key test was emitted as `-1.5.__class__ is _str`, i.e. -(float) -> "host function
    error: TypeError: bad operand type for unary -: 'type'". Interpreted: ok."""
    t, i = outcomes("t = {}\nt[-1.5] = 1\nlog(t[-1.5])\n")
    assert t == i
    assert "log 1" in t


@pytest.mark.parametrize(
    "source",
    [
        'string.tostring = math.abs\nlog(string.tostring(5) >= "a")\n',
        'string.length = type\nx = string.length("a") + 1\nlog(x)\n',
        "size = type\nlog(size({}) * 2)\n",
    ],
    ids=["tostring", "length", "size"],
)
def test_library_override_keeps_no_inferred_type(source: str) -> None:
    """Found by fuzzing, fixed in cd6edbb: after a script replaced string.tostring /
    string.length / size, the translator still typed the call's result as the library's
    (str/int) and its Python fast path (`x >= 'a'`, `x + 1`) raised a Python TypeError."""
    t, i = outcomes(source)
    assert t == i


def test_to_python_on_cyclic_table() -> None:
    """Found by fuzzing, fixed in cd6edbb: `vm.call("f")` where f returns a table that
    contains itself raised RecursionError from values.to_python."""
    vm = bvm.VM()
    vm.load(bvm.compile_source("function f() { var t = {} t.me = t return t }\n", "/r.bzz"))
    vm.execute()
    result = vm.call("f")
    assert result["me"] is result


@pytest.mark.parametrize("trips", [400, 700])
def test_for_loop_ticks_like_the_interpreter(trips: int) -> None:
    """Found by fuzzing, fixed in cd6edbb: a `for` loop has two backward jumps per
    iteration and the interpreter charged both, the translator one, so with max_ticks=1000
    a 700-trip loop succeeded translated and failed interpreted. Both must now agree on
    success or on a budget error (its offset may differ: see bvm/budget.py)."""
    program = bvm.compile_source(f"for (i = 0, i < {trips}, i = i + 1) {{ x = 1 }}\n", "/r.bzz")
    results = []
    for translate in (True, False):
        vm = bvm.VM(max_ticks=1000, translate=translate)
        vm.load(program)
        try:
            vm.execute()
            results.append("ok")
        except bvm.BuzzBudgetExceeded:
            results.append("budget")
    assert results[0] == results[1]


def test_loop_free_runaway_recursion_is_bounded_by_the_time_budget() -> None:
    """max_ticks counts backward jumps only (docs/compat.md V16), so loop-free code such as
    2^40 calls is bounded by max_seconds, which interrupts the VM wherever it is."""
    source = "function f(n) { if (n > 0) { f(n - 1) f(n - 1) } }\nf(40)\n"
    vm = bvm.VM(max_ticks=10_000, max_seconds=0.2)
    vm.load(bvm.compile_source(source, "/r.bzz"))
    with pytest.raises(bvm.BuzzBudgetExceeded, match="longer than 0.2 s"):
        vm.execute()
