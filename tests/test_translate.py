"""The translator agrees with the interpreter, including on programs that once fooled it.

Each case runs translated and interpreted (the reference) and compares what the program
logs, what it returns, and any error's message and location.
"""

from __future__ import annotations

import bvm
from bvm.values import format_value


def run(program: bvm.Program, translate: bool, call: str | None = None, *args: object) -> tuple:
    """(log lines, result or error) of running `program` one way."""
    lines: list[str] = []
    vm = bvm.VM(translate=translate, max_ticks=100_000)
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
