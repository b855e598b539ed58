"""The translator agrees with the interpreter, including on programs that once fooled it.

Each case runs translated and interpreted (the reference) and compares what the program
logs, what it returns, and any error's message and location.
"""

from __future__ import annotations

import gc
import re
from pathlib import Path

import pytest

import bvm
from bvm.translate import CodeCache, TranslateOptions
from bvm.values import format_value


def run(
    program: bvm.Program,
    translate: bool,
    call: str | None = None,
    *args: object,
    options: TranslateOptions | None = None,
) -> tuple:
    """(log lines, result or error) of running `program` one way."""
    lines: list[str] = []
    vm = bvm.VM(
        translate=translate, max_ticks=100_000, translate_options=options or TranslateOptions()
    )
    try:
        vm.load(program)
        vm.register("log", lambda *a: lines.append("".join(map(format_value, a))))
        vm.execute()
        result = vm.call(call, *args) if call else None
        return lines, ("ok", result)
    except bvm.BuzzError as e:
        return lines, ("error", e.message, e.offset)


def both(source: str, call: str | None = None, *args: object) -> tuple:
    """Run translated and interpreted; assert they agree; return the outcome."""
    program = bvm.compile_source(source, "t.bzz")
    fast, ref = run(program, True, call, *args), run(program, False, call, *args)
    assert fast == ref
    return fast


def test_replaced_library_function_result_is_not_trusted() -> None:
    # The call site was translated while math.floor was the library's (which returns an
    # int); after the script replaces it, its result may be anything.
    lines, _ = both(
        'function f(x) { if (math.floor(x)) { log("truthy") } else { log("falsy") } }\n'
        "f(1.5)\n"
        "math.floor = function(x) { return nil }\n"
        "f(1.5)\n"
    )
    assert lines == ["truthy", "falsy"]


def test_replaced_library_function_in_an_inline_path() -> None:
    _, outcome = both(
        "function f() { return string.length(string.tostring(12)) }\n"
        "f()\n"
        "string.tostring = function(x) { return {.a = 1} }\n"
        "f()\n"
    )
    assert outcome[0] == "error" and "expected string, got table" in outcome[1]


def test_negative_float_literal_as_a_table_key() -> None:
    lines, _ = both("t = {}\nt[-1.5] = 3\nlog(t[-1.5])\nlog(t[-1.5 + 1])\n")
    assert lines == ["3", "[nil]"]


def test_break_out_of_a_for_body_keeps_its_local_types() -> None:
    # Hand-made bytecode: the `for` body leaves the loop with a local set to nil.
    asm = """!4
'f
'log
'T
'F

\tpushs 0
\tpushcn @__label_1
\tgstore
\tnop

@__label_0
\tpushnil
\tpushs 1
\tgload
\tpushnil
\tpushs 0
\tgload
\tpushi 3
\tpushi 1
\tcallc
\tpushi 1
\tcallc
\tpop
\tdone

@__label_1
\tpushi 1
\tlstore 2
@__label_2
\tlload 1
\tpushi 0
\tgt
\tjumpnz @__label_4
\tjump @__label_5
@__label_3
\tjump @__label_2
@__label_4
\tpushnil
\tlstore 2
\tpushi 1
\tjumpnz @__label_5
\tpushi 5
\tlstore 2
\tjump @__label_3
@__label_5
\tlload 2
\tjumpz @__label_6
\tpushs 2
\tret1
@__label_6
\tpushs 3
\tret1
"""
    program = bvm.assemble(asm)
    assert run(program, True) == run(program, False)
    assert run(program, False)[0] == ["F"]


def test_deeply_nested_loops_translate_in_bounded_work() -> None:
    # Types re-settle at every nesting level; the translator bounds that work (and falls
    # back to the interpreter) instead of taking seconds on the first call.
    k, depth = 7, 5
    lines = ["function f(n) {"]
    for level in range(depth):
        lines.append(" ".join(f"var a{level}_{i} = 0" for i in range(k)))

    def nest(level: int) -> list[str]:
        if level == depth:
            return []
        out = [f"var i{level} = 0", f"while (i{level} < n) {{"]
        if level + 1 < depth:
            out.append(" ".join(f"a{level + 1}_{i} = 0" for i in range(k)))
        out += nest(level + 1)
        out.append(" ".join(f"a{level}_{i} = a{level}_{i + 1}" for i in range(k - 1)))
        out += [f'a{level}_{k - 1} = "s"', f"i{level} = i{level} + 1", "}"]
        return out

    lines += nest(0) + ["return a0_0", "}"]
    assert both("\n".join(lines), "f", 2)[1] == ("ok", 0)


def test_for_loops_count_the_same_budget_both_ways() -> None:
    # A for iteration is two backward jumps in the bytecode; both paths count them.
    source = (
        "function f(n) { var i  var s = 0  for (i = 0, i < n, i = i + 1) { s = s + i }  return s }"
    )
    program = bvm.compile_source(source)
    for n, fits in ((400, True), (600, False)):
        outcomes = []
        for translate in (True, False):
            vm = bvm.VM(translate=translate, max_ticks=1000)
            vm.load(program)
            vm.execute()
            try:
                outcomes.append(vm.call("f", n) is not None)
            except bvm.BuzzBudgetExceeded:
                outcomes.append(False)
        assert outcomes == [fits, fits]


def test_hostile_deep_stack_is_not_translated_quadratically() -> None:
    n = 5000
    body = "\n".join(["\tpushi 1\n\tlstore 0"] + ["\tlload 0"] * n + ["\tlstore 0"] * n)
    program = bvm.assemble(f"!0\n\n\tnop\n{body}\n\tdone\n")
    assert run(program, True) == run(program, False) == ([], ("ok", None))


def test_code_after_an_if_else_whose_else_returns_still_runs() -> None:
    source = (
        "function f(c) {\n  var x = 0\n  if (c) { x = 1 } else { return 2 }\n"
        "  return x + 10\n}\n"
        'function g(c) {\n  if (c) { return 1 } else { log("else") }\n  return 3\n}\n'
    )
    assert both(source, "f", 1)[1] == ("ok", 11)
    assert both(source, "f", 0)[1] == ("ok", 2)
    assert both(source, "g", 0) == (["else"], ("ok", 3))


# ---------------------------------------------------------------- direct self-calls
# A call of the running closure enters its unguarded body directly, and a body inferred to
# return ints hands anything else back through `_Deopt`. Each case below runs translated
# and interpreted (`both`), and where the interpreter cannot say (budget chunks, stack
# depth) translated with and without self-calls.


def self_called(source: str, call: str, *args: object) -> bool:
    """Whether a translation of the program made a direct self-call body (so that the
    cases here do test it)."""
    vm = bvm.VM()
    vm.load(bvm.compile_source(source, "t.bzz"))
    vm.register("log", lambda *a: None)
    vm.execute()
    try:
        vm.call(call, *args)
    except bvm.BuzzError:
        pass
    return any(re.fullmatch(r"_s\d+_\d+_\d+[SG][a-z]*", name) for name in vm.globals)


FIB = "function fib(n) {\n  if (n < 2) return n\n  return fib(n - 1) + fib(n - 2)\n}\n"


def test_self_call_fib() -> None:
    assert self_called(FIB, "fib", 10)
    assert both(FIB, "fib", 15)[1] == ("ok", 610)
    assert both(FIB, "fib", 3.5)[1] == ("ok", 3.5)  # floats: the guard's general path
    assert both(FIB, "fib", "x")[1][0] == "error"


def test_self_call_sum_wraps_at_int32() -> None:
    source = (
        "function big(n) {\n  if (n < 1) return 2147483000\n"
        "  return big(n - 1) + big(n - 1) + n\n}\n"
        "function neg(n) {\n  if (n < 1) return -2147483000\n  return neg(n - 1) - 1000 * n\n}\n"
    )
    assert self_called(source, "big", 3)
    expected = 2147483000
    for n in range(1, 7):
        expected = (expected * 2 + n + 2**31) % 2**32 - 2**31
    assert both(source, "big", 6)[1] == ("ok", expected)
    assert both(source, "neg", 5)[1][0] == "ok"


def test_global_reassigned_during_recursion() -> None:
    # At depth 3 the global becomes another function returning a float: the direct calls
    # below it return, and every frame above continues with a float.
    # (`/ 2` of an int is a floor division: an int assumed wrongly would show.)
    source = (
        "function g(n) { return 0.5 }\n"
        "function f(n) {\n  if (n < 1) return 0\n  if (n == 3) f = g\n"
        "  return f(n - 1) / 2 + 1\n}\n"
    )
    assert self_called(source, "f", 2)
    assert both(source, "f", 6)[1] == ("ok", 1.90625)
    source += "function h() { var a = f(6)  return a + f(2) }\n"
    assert both(source, "h")[1] == ("ok", 2.40625)
    strings = source.replace("return 0.5", 'return "s"')
    assert both(strings, "f", 6)[1][0] == "error"


def test_global_reassigned_to_an_int_function_and_back() -> None:
    source = (
        "var keep\n"
        "function g(n) { f = keep  return 100 }\n"
        "function f(n) {\n  if (n < 1) return 0\n  if (n == 4) { keep = f  f = g }\n"
        "  var a = f(n - 1)\n  return a + f(n - 2) + 1\n}\n"
    )
    assert self_called(source, "f", 3)
    outcome = both(source, "f", 9)
    assert outcome[1][0] == "ok"


def test_global_reassigned_to_a_non_function_during_recursion() -> None:
    source = (
        "function f(n) {\n  if (n < 1) return 0\n  if (n == 2) f = 7\n  return f(n - 1) + 1\n}\n"
    )
    assert self_called(source, "f", 1)
    _, outcome = both(source, "f", 5)
    assert outcome[0] == "error" and "expected closure, got integer" in outcome[1]


def test_recursion_returning_a_float_on_one_path() -> None:
    source = (
        "function f(n) {\n  if (n == 2) return 0.25\n  if (n < 1) return 1\n"
        "  return f(n - 1) + f(n - 2)\n}\n"
        "function h(n) {\n  if (n < 1) return 0.5\n  return h(n - 1) * 1.5\n}\n"
    )
    assert self_called(source, "f", 5)
    assert both(source, "f", 7)[1][0] == "ok"
    assert both(source, "f", 1)[1] == ("ok", 2)
    assert both(source, "h", 30)[1][0] == "ok"  # inferred float, rounded to binary32


def test_recursion_returning_nil_and_tables() -> None:
    source = (
        "function f(n) {\n  if (n < 1) return nil\n  var r = f(n - 1)\n"
        "  if (r == nil) return {.depth = n}\n  r.depth = r.depth + n\n  return r\n}\n"
        "function c(n) {\n  if (n < 1) return 0\n  if (n == 3) return nil\n"
        "  return c(n - 1) + 1\n}\n"
    )
    assert both(source, "f", 10)[1] == ("ok", {"depth": 55})
    assert both(source, "c", 2)[1] == ("ok", 2)
    _, outcome = both(source, "c", 6)
    assert outcome[0] == "error" and "nil" in outcome[1]


def test_recursive_call_with_another_argument_count() -> None:
    source = (
        "function f(n, m) {\n  if (n < 1) return m\n  if (n == 3) return f(n - 1)\n"
        "  return f(n - 1, m) + 1\n}\n"
        "function g(n) {\n  if (n < 1) return 0\n  return g(n - 1, 1, 2) + 1\n}\n"
    )
    assert self_called(source, "f", 5, 1)
    both(source, "f", 5, 10)
    assert both(source, "f", 2, 10)[1] == ("ok", 12)
    both(source, "g", 4)


def test_error_inside_a_direct_self_call_is_located() -> None:
    source = (
        "function f(n) {\n  if (n < 1) {\n    return n.x\n  }\n"
        "  return f(n - 1) + 1\n}\n"
        "function g(n) {\n  if (n < 1) return 0\n  var t = {}\n  t.x = g(n - 1)\n"
        "  return t.x.y\n}\n"
    )
    assert self_called(source, "f", 3)
    _, outcome = both(source, "f", 5)
    assert outcome[0] == "error" and outcome[2] is not None
    locations = []
    for translated in (True, False):
        vm = bvm.VM(translate=translated)
        vm.load(bvm.compile_source(source, "t.bzz"))
        vm.execute()
        with pytest.raises(bvm.BuzzError) as info:
            vm.call("f", 4)
        locations.append(info.value.location)
    assert locations[0] == locations[1] and locations[0][1] in (3, 4)
    _, outcome = both(source, "g", 3)
    assert outcome[0] == "error"


def test_self_calls_count_the_same_budget() -> None:
    # Loops inside the recursion: the budget runs out at the same point, with the same
    # location, with and without direct self-calls.
    # The second program's frames return through `_Deopt` once the global changes.
    # Returns inside the loop: they settle its iterations first.
    source = (
        "function f(n) {\n  var i = 0\n  var s = 0\n  while (i < 9) {\n    s = s + i\n"
        "    i = i + 1\n    if (i == 4) {\n      if (n < 2) return s\n"
        "      return f(n - 1) + f(n - 2) + s\n    }\n  }\n  return s\n}\n"
    )
    deopt = source.replace(
        "if (n < 2) return s\n", "if (n < 2) return s\n      if (n == 6) f = g\n"
    )
    deopt += "function g(n) {\n  var i = 0\n  while (i < 7) { i = i + 1 }\n  return 0.5\n}\n"
    for text in (source, deopt):
        program = bvm.compile_source(text, "t.bzz")
        assert self_called(text, "f", 5)
        for n in (5, 12, 16, 20):
            for ticks in (100, 5000, 100_000):
                outcomes = []
                for on in (True, False):
                    vm = bvm.VM(max_ticks=ticks, translate_options=TranslateOptions(self_calls=on))
                    vm.load(program)
                    vm.execute()
                    try:
                        outcomes.append(("ok", vm.call("f", n), vm.budget.used))
                    except bvm.BuzzError as e:
                        outcomes.append(("error", e.message, e.offset, vm.budget.used))
                assert outcomes[0] == outcomes[1]


def test_self_calls_keep_the_recursion_depth() -> None:
    # One Python frame per Buzz call either way: the deepest recursion that works is the
    # same, and deeper is the same clean error.
    source = "function d(n) {\n  if (n < 1) return 0\n  return d(n - 1) + 1\n}\n"
    program = bvm.compile_source(source, "t.bzz")
    assert self_called(source, "d", 3)

    def deepest(on: bool) -> int:
        lo, hi = 1, 20_000
        while lo < hi:
            mid = (lo + hi + 1) // 2
            vm = bvm.VM(translate_options=TranslateOptions(self_calls=on))
            vm.load(program)
            vm.execute()
            try:
                vm.call("d", mid)
                lo = mid
            except bvm.BuzzError as e:
                assert "stack overflow" in e.message
                hi = mid - 1
        return lo

    assert 5000 < deepest(True) == deepest(False) < 20_000
    errors = []
    for on in (True, False):
        errors.append(run(program, True, "d", 20_000, options=TranslateOptions(self_calls=on)))
    assert errors[0] == errors[1] and errors[0][1][0] == "error"


def test_self_call_with_captured_variables_and_methods() -> None:
    source = (
        "function mk(k) {\n"
        "  return function(n) { if (n < 1) return k  return rec(n - 1) + k }\n"
        "}\n"
        "rec = mk(3)\n"
        "t = {.f = function(n) { if (n < 1) return 0  return t.f(n - 1) + 2 }}\n"
        "function run() { return rec(5) + t.f(4) }\n"
    )
    assert both(source, "run")[1] == ("ok", 18 + 8)


def test_chunked_loops_count_the_same_budget() -> None:
    # Loops count their iterations with a `for` over one chunk's counts; the budget must
    # be the same as with the counter they replace: used on success, and on exhaustion
    # the same error at the same place. Around the chunk size (1000 jumps), with early
    # returns, nested loops and `for` loops (two jumps an iteration).
    source = (
        "function w(n, stop) {\n  var i = 0\n  var s = 0\n  while (i < n) {\n"
        "    if (i == stop) return s\n    var j = 0\n    while (j < 3) { s = s + j  j = j + 1 }\n"
        "    i = i + 1\n  }\n  return s\n}\n"
        "function f(n, stop) {\n  var i\n  var s = 0\n  for (i = 0, i < n, i = i + 1) {\n"
        "    if (i == stop) return s\n    s = s + i\n  }\n  return s\n}\n"
    )
    program = bvm.compile_source(source, "t.bzz")
    vms = []
    for chunked in (True, False):  # translated on their first call, either way
        vm = bvm.VM(translate_options=TranslateOptions(chunked_loops=chunked))
        vm.load(program)
        vm.execute()
        vm.call("w", 0, 0)
        vm.call("f", 0, 0)
        vms.append(vm)
    ref = bvm.VM(translate=False)
    ref.load(program)
    ref.execute()
    for call in ("w", "f"):
        for n in (0, 1, 499, 500, 501, 999, 1000, 1001, 2000):
            for stop in (-1, n // 2):
                for ticks in (None, 1000, 1500):
                    outcomes = []
                    for vm in vms:
                        vm.max_ticks = ticks
                        vm.reset_error()
                        try:
                            outcomes.append(("ok", vm.call(call, n, stop), vm.budget.used))
                        except bvm.BuzzError as e:
                            outcomes.append(("error", e.message, e.offset, vm.budget.used))
                    assert outcomes[0] == outcomes[1], (call, n, stop, ticks)
                    if ticks is None and n in (0, 1, 500, 1001):  # (the interpreter is slow)
                        assert ref.call(call, n, stop) == outcomes[0][1]
                        assert ref.budget.used == outcomes[0][2]


def test_every_vm_counts_chunks_with_the_same_tuples() -> None:
    # A chunk's counts are 1,500 ints: made per VM they were a fifth of a translated
    # robot's memory, and cold in the cache each time a swarm's robot ran a loop.
    a, b = bvm.VM(), bvm.VM()
    for name in ("_KS1", "_KS2"):
        assert a.globals[name] is b.globals[name]
    assert a.globals["_KS1"] == tuple(range(1000, 0, -1))
    assert a.globals["_KS2"] == tuple(range(1000, 0, -2))


def test_error_location_survives_an_equal_translation_being_collected() -> None:
    # Two VMs running one script make equal code objects (code compares by value); the
    # line map of the live one must not go with the other.
    program = bvm.compile_source("function f(x) {\n  var t = {}\n  return t.a.b\n}\n", "t.bzz")

    def fresh() -> bvm.VM:
        vm = bvm.VM()
        vm.load(program)
        vm.execute()
        with pytest.raises(bvm.BuzzError):
            vm.call("f", 1)
        vm.reset_error()
        return vm

    first, second = fresh(), fresh()
    del first
    gc.collect()
    with pytest.raises(bvm.BuzzError) as info:
        second.call("f", 1)
    assert info.value.offset is not None
    assert info.value.offset == run(program, False, "f", 1)[1][2]


def test_vms_running_one_program_share_compiled_code_not_globals() -> None:
    """Translations are compiled once per text; each VM runs them on its own globals, and
    errors still point at the source."""
    src = "function f(x) {\n  total = total + x\n  return total / x\n}\n"
    program = bvm.compile_source(src, "shared.bzz")
    vms = []
    for start in (1, 100):
        vm = bvm.VM()
        vm.load(program)
        vm.execute()
        vm["total"] = start
        vms.append(vm)
    assert [vm.call("f", 2) for vm in vms] == [1, 51]  # (1 + 2) / 2 and (100 + 2) / 2
    fa, fb = (vm.gload("f") for vm in vms)
    code_a = vms[0].entry(fa.ref, 1).for_call((2,)).__code__
    code_b = vms[1].entry(fb.ref, 1).for_call((2,)).__code__
    assert code_a is code_b
    vms[1]["total"] = "oops"
    # At the failing operator, as the interpreter puts it.
    with pytest.raises(bvm.BuzzError, match=r"shared\.bzz:2:17: type mismatch"):
        vms[1].call("f", 2)
    assert vms[0].call("f", 2) == 2  # (3 + 2) / 2: untouched by the other VM's error


def test_running_the_global_code_again_keeps_its_bound_names() -> None:
    """The second execute() swaps two library functions the first one bound directly."""
    vm = bvm.VM()
    vm.load(bvm.compile_source("tmp = f\nf = h\nh = tmp\na = f(2.5)\n", "swap.bzz"))
    vm["f"], vm["h"] = vm.gload("isint"), vm.gload("isfloat")
    vm.execute()
    assert vm["a"] == 1  # f was isfloat at the call
    vm.execute()
    assert vm["a"] == 0  # and isint now


def test_error_locations_survive_a_cleared_code_cache() -> None:
    """A translation compiled again after the cache was cleared keeps its line map when
    the VMs holding the earlier copy are gone."""
    options = TranslateOptions(cache=CodeCache(max_size=2))
    src = "function g(x) {\n  var y = x + 1\n  return y.foo\n}\n"
    other = "function h(x) {\n  return x * 3\n}\nfunction k(x) {\n  return x - 3\n}\n"

    def robot(source: str) -> bvm.VM:
        vm = bvm.VM(translate_options=options)
        vm.load(bvm.compile_source(source, "cache.bzz"))
        return vm

    first = robot(src)
    with pytest.raises(bvm.BuzzError, match=r"cache\.bzz:3:11: type mismatch"):
        first.call("g", 1)
    filler = robot(other)
    filler.call("h", 1)
    filler.call("k", 1)  # fills the cache: cleared
    second = robot(src)
    del first
    gc.collect()
    with pytest.raises(bvm.BuzzError, match=r"cache\.bzz:3:11: type mismatch"):
        second.call("g", 1)


@pytest.mark.parametrize("literal", ["-2.5", "-7"])
def test_indexing_a_negative_literal_is_a_type_error(literal: str) -> None:
    """Hand-made bytecode may index a number: `-2.5.__class__` must not negate a class."""
    src = "b = 0\nc = b[1]\n"
    asm = bvm.compile_to_asm(src, "neg.bzz")
    # Index the literal itself instead of the global that holds it.
    head, sep, tail = asm.partition("\tgload\t|2,5")
    assert sep, asm
    prefix = head[: head.rfind("\tpushs")]
    asm = prefix + f"\tpush{'f' if '.' in literal else 'i'} {literal}\t|2,5" + tail
    program = bvm.assemble(asm, "neg.basm")
    for translate in (True, False):
        vm = bvm.VM(translate=translate)
        vm.load(program)
        with pytest.raises(bvm.BuzzError, match="type mismatch"):
            vm.execute()


def test_remainders_of_run_time_values() -> None:
    """`a % b` of values whose types are known only at run time: the int fast path (a
    positive divisor) and the full rule (negative or zero divisors, floats, strings)."""
    src = (
        "function m(t) { return t.a % t.b }\n"
        "function all() {\n"
        "  var cases = {.0 = {.a = 7, .b = 3}, .1 = {.a = -7, .b = 3}, .2 = {.a = 7, .b = -3},\n"
        "    .3 = {.a = -7, .b = -3}, .4 = {.a = 0, .b = 5}, .5 = {.a = 2147483647, .b = 2},\n"
        "    .6 = {.a = -2147483648, .b = 7}, .7 = {.a = 7.5, .b = 2}, .8 = {.a = 7, .b = 2.5},\n"
        "    .9 = {.a = -7.5, .b = 2.0}}\n"
        "  var i = 0\n"
        "  while (i < 10) { log(m(cases[i]))  i = i + 1 }\n"
        "  log(m({.a = 7, .b = 0}))\n"
        "}\n"
    )
    lines, outcome = both(src, "all")
    assert lines[:7] == ["1", "2", "1", "-4", "0", "1", "5"]  # the reference's rule
    assert outcome[0] == "error" and "division by zero" in outcome[1]
    _, outcome = both('function m(a, b) { return a % b }\nm("x", 2)\n')
    assert outcome[0] == "error"


def test_comparisons_with_nil_of_every_kind_of_value() -> None:
    """`x == nil` and `x != nil` for values of unknown type: only nil is nil (0, "", 0.0,
    tables and closures are not)."""
    src = (
        "function isn(t, k) { return t[k] == nil }\n"
        "function nn(t, k) { return nil != t[k] }\n"
        "function all() {\n"
        '  var t = {.i = 0, .f = 0.0, .s = "", .t = {}, .c = function() {}}\n'
        '  var keys = {.0 = "i", .1 = "f", .2 = "s", .3 = "t", .4 = "c", .5 = "absent"}\n'
        "  var k = 0\n"
        "  while (k < 6) { log(isn(t, keys[k]), nn(t, keys[k]))  k = k + 1 }\n"
        "}\n"
    )
    lines, _ = both(src, "all")
    assert lines == ["01", "01", "01", "01", "01", "10"]


# ---------------------------------------------------------------- translating ahead

CONFORMANCE = sorted((Path(__file__).parent / "conformance").glob("*.bzz"))


def run_prepared(program: bvm.Program, call: str | None = None) -> tuple:
    """(log lines, outcome, translations after prepare) of a VM translated ahead: before
    its global code runs, so that the functions the global code calls are the prepared
    translations."""
    import bvm.vm as vm_module

    lines: list[str] = []
    vm = bvm.VM(max_ticks=100_000)
    late: list[int] = []
    real = vm_module._translate.translate
    try:
        vm.load(program)
        vm.register("log", lambda *a: lines.append("".join(map(format_value, a))))
        vm.prepare()

        def counting(*args: object, **kwargs: object) -> object:
            late.append(1)
            return real(*args, **kwargs)  # type: ignore[arg-type]

        vm_module._translate.translate = counting  # type: ignore[assignment]
        vm.execute()  # the global code itself is translated on its first run
        late.clear()
        result = vm.call(call) if call else None
        return lines, ("ok", result), len(late)
    except bvm.BuzzError as e:
        return lines, ("error", e.message, e.offset), len(late)
    finally:
        vm_module._translate.translate = real


LISTENERS = """
seen = {}
function on(topic, value, sender) { seen[sender] = value }
function main() {
  neighbors.listen("a", on)
  neighbors.listen("b", function(topic, value, sender) { seen.b = value })
  var t = {.1 = 3, .2 = 4}
  foreach(t, function(k, v) { seen[k] = v })
  var total = reduce(t, function(k, v, acc) { return acc + v }, 0)
  var m = map(t, function(k, v) { return v * 2 })
  var f = filter(t, function(k, v) { return v > 3 })
  log(total, size(m), size(f))
  return total
}
"""


def test_a_prepared_vm_translates_nothing_later_and_agrees() -> None:
    """`VM.prepare` translates every function a script can create, callbacks included
    (trailing parameters they never read too); later calls compile nothing."""
    program = bvm.compile_source(LISTENERS, "t.bzz")
    lines, outcome, late = run_prepared(program, "main")
    assert late == 0
    ref_lines, ref_outcome = run(program, False, "main")
    assert (lines, outcome) == (ref_lines, ref_outcome) and outcome == ("ok", 7)


@pytest.mark.parametrize("script", CONFORMANCE, ids=[s.stem for s in CONFORMANCE])
def test_the_conformance_corpus_runs_the_same_translated_ahead(script: Path) -> None:
    """Translations made ahead (general, for guessed argument counts) give what the
    interpreter gives, on every conformance script."""
    try:
        program = bvm.compile_file(script, include_dirs=[str(script.parent / "include")])
    except bvm.BuzzCompileError:
        pytest.skip("a compile-error case")
    lines, outcome, _ = run_prepared(program)
    assert (lines, outcome) == run(program, False)


def test_vms_share_a_translation_only_when_it_read_the_same_of_them() -> None:
    """A translation made for one VM is reused by another VM of the program when what it
    read of it (global g: a host function it calls directly) is alike, never otherwise."""
    src = "function h(x) {\n  return x + 1\n}\nfunction f(x) {\n  return g(x)\n}\n"
    program = bvm.compile_source(src, "reads.bzz")
    options = TranslateOptions(cache=CodeCache())
    vms = []
    for g in ("isint", "h", "isint"):
        vm = bvm.VM(translate_options=options)
        vm.load(program)
        vm.execute()
        vm["g"] = vm.gload(g)
        vms.append(vm)
    # In turn: the first translates, the second (g a script function) must not take the
    # first's direct call of isint, the third reuses the first's.
    assert [vm.call("f", 2.5) for vm in vms] == [0, 3.5, 0]
    codes = [vm.entry(vm.gload("f").ref, 1).for_call((2.5,)).__code__ for vm in vms]
    assert codes[0] is codes[2] and codes[1] is not codes[0]
