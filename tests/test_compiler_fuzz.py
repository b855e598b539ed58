"""Fuzzing the lexer and parser: bad source only ever raises BuzzCompileError.

Whatever compiles must also assemble, and its bytecode must survive a
disassemble/assemble round trip.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bvm.assembler import assemble
from bvm.compiler import compile_asm
from bvm.disasm import disassemble
from bvm.errors import BuzzCompileError

P = "/nonexistent/fuzz/prog.bzz"

VALID = [
    b"x = 3.14\ny = -0.5\nz = 1.",
    b"function f(x) { if(x) return\n y = 2\n return 3 }",
    b'function f(x) { if(x) return\n log("after") }',
    b"function fact(n) { if (n <= 1) { return 1 } else { return n * fact(n - 1) } }\nlog(fact(5))",
    b"t = {.a = 1, .7 = {.b = nil}, .f = function(y) { return self.a + y }}\nt.f(2)\n",
    b"i = 0 while (i < 3) { var_x = i i = i + 1 } for (i = 0, i < 10, i = i + 1) log(!i)",
    b'function g(a, b) "doc" { var c = function(d) { return a + d } return c(b)[1].x }',
    b"if (not a == b and c) { x = -x^2 % 3 << 1 & 7 } else if (a) y = ((1 != 2) or nil)",
    b"s = swarm.create(1)\ns.exec(function() { neighbors.foreach(function(r, d) { log(r) }) })",
]

TOKENS = [
    "var", "function", "if", "else", "while", "for", "return", "and", "or", "not", "nil",
    "x", "y", "f", "self", "t", "1", "2.5", "1.2.3", "007", "'s'", '"q\\tq"', "{", "}", "(",
    ")", "[", "]", ".", ",", "=", "==", "!=", "<", "<=", ">", ">=", "<<", ">>", "+", "-", "*",
    "/", "%", "^", "&", "|", "!", ";", "\n", "# c\n",
]  # fmt: skip


def check(source: bytes) -> None:
    """The fuzz property for one source text."""
    try:
        text = compile_asm(source, P)
    except BuzzCompileError as exc:
        assert isinstance(exc.line, int) and isinstance(exc.col, int)
        assert exc.path == P
        assert str(exc).startswith(f"{P}:{exc.line}:{exc.col}: ")
        return
    bo, bdb = assemble(text, "<fuzz>")
    assert assemble(disassemble(bo, bdb))[0] == bo


@settings(max_examples=250, deadline=None)
@given(st.binary(max_size=120))
def test_random_bytes(source: bytes) -> None:
    check(source)


@settings(max_examples=400, deadline=None)
@given(st.lists(st.sampled_from(TOKENS), max_size=40))
def test_token_soup(tokens: list[str]) -> None:
    check(" ".join(tokens).encode())


@st.composite
def mutated(draw: st.DrawFn) -> bytes:
    source = bytearray(draw(st.sampled_from(VALID)))
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["delete", "insert", "replace", "token"]))
        at = draw(st.integers(0, len(source)))
        if kind == "delete" and source:
            del source[min(at, len(source) - 1) : at + draw(st.integers(1, 5))]
        elif kind == "insert":
            source[at:at] = draw(st.binary(min_size=1, max_size=3))
        elif kind == "replace" and at < len(source):
            source[at] = draw(st.integers(0, 255))
        else:
            source[at:at] = (" " + draw(st.sampled_from(TOKENS)) + " ").encode()
    return bytes(source)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated())
def test_mutated_programs(source: bytes) -> None:
    check(source)


# -- grammar-valid programs: must compile, assemble and round-trip --------------------

NAMES = st.sampled_from(["x", "y", "t", "f", "log", "self"])
ATOMS = st.sampled_from(["0", "1", "2.5", "007", "1.2.3", "nil", '"s"', "'q'", '"a\\tb"'])
BINOPS = st.sampled_from(["+", "-", "*", "/", "%", "^", "<<", ">>", "&", "|"])
CMPOPS = st.sampled_from(["==", "!=", "<", "<=", ">", ">="])


def _compose(parts: tuple[str, ...]) -> str:
    return "".join(parts)


def _expressions(children: st.SearchStrategy[str]) -> st.SearchStrategy[str]:
    cond = st.one_of(
        children,
        st.tuples(children, st.just(" "), CMPOPS, st.just(" "), children).map(_compose),
        st.tuples(st.just("not "), children).map(_compose),
        st.tuples(children, st.sampled_from([" and ", " or "]), children).map(_compose),
    )
    args = st.lists(cond, max_size=3).map(", ".join)
    return st.one_of(
        st.tuples(children, st.just(" "), BINOPS, st.just(" "), children).map(_compose),
        st.tuples(st.sampled_from(["-", "+", "!"]), children).map(_compose),
        st.tuples(st.just("("), cond, st.just(")")).map(_compose),
        st.tuples(NAMES, st.just("("), args, st.just(")")).map(_compose),
        st.tuples(NAMES, st.just("."), NAMES, st.just("("), args, st.just(")")).map(_compose),
        st.tuples(NAMES, st.just("["), children, st.just("]")).map(_compose),
        st.tuples(NAMES, st.just("("), args, st.just(")("), args, st.just(")")).map(_compose),
        st.tuples(st.just("({.a = "), children, st.just(", .7 = "), children, st.just("})")).map(
            _compose
        ),
        st.tuples(st.just("function(a, b) { return "), cond, st.just(" }")).map(_compose),
    )


EXPRESSIONS = st.recursive(st.one_of(ATOMS, NAMES), _expressions, max_leaves=5)


def _statements(children: st.SearchStrategy[str]) -> st.SearchStrategy[str]:
    block = st.lists(children, max_size=3).map(lambda s: "{ " + "\n".join(s) + " }")
    cond = st.tuples(EXPRESSIONS, st.sampled_from([" == ", " and ", " < "]), EXPRESSIONS).map(
        _compose
    )
    return st.one_of(
        st.tuples(st.just("if ("), cond, st.just(") "), block).map(_compose),
        st.tuples(st.just("if ("), cond, st.just(") "), block, st.just(" else "), children).map(
            _compose
        ),
        st.tuples(st.just("while ("), cond, st.just(") "), block).map(_compose),
        st.tuples(st.just("for (x = 0, "), cond, st.just(", x = x + 1) "), block).map(_compose),
    )


SIMPLE_STATEMENTS = st.one_of(
    st.tuples(NAMES, st.just(" = "), EXPRESSIONS).map(_compose),
    st.tuples(NAMES, st.just(".k = "), EXPRESSIONS).map(_compose),
    st.tuples(NAMES, st.just("["), EXPRESSIONS, st.just("] = "), EXPRESSIONS).map(_compose),
    st.tuples(NAMES, st.just("("), EXPRESSIONS, st.just(")")).map(_compose),
)
STATEMENTS = st.recursive(SIMPLE_STATEMENTS, _statements, max_leaves=4)
FUNCTIONS = st.tuples(
    st.just("function g(a, b) {\n"),
    st.lists(STATEMENTS, max_size=3).map("\n".join),
    st.just("\nreturn "),
    EXPRESSIONS,
    st.just("\n}"),
).map(_compose)
PROGRAMS = st.lists(st.one_of(STATEMENTS, FUNCTIONS, st.just("var v = 1")), max_size=5).map(
    "\n".join
)


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(PROGRAMS)
def test_grammar_valid_programs_compile_and_round_trip(program: str) -> None:
    text = compile_asm(program.encode(), P)
    bo, bdb = assemble(text, "<fuzz>")
    assert assemble(disassemble(bo, bdb)) == (bo, bdb)


@pytest.mark.parametrize("source", VALID)
def test_corpus_compiles(source: bytes) -> None:
    text = compile_asm(source, P)
    bo, bdb = assemble(text)
    assert assemble(disassemble(bo, bdb)) == (bo, bdb)


PATHOLOGICAL = {
    "parens": b"(" * 50_000,
    "indexes": b"x = " + b"[" * 20_000,
    "calls": b"f(" * 20_000,
    "returns": b"return\n" * 3_000,
    "fallbacks": b"function f() {" + b"if (x) return\n y = 1\n" * 300 + b"}",
    "long": b"x = 1\n" * 20_000 + b"_",
}


@pytest.mark.parametrize("source", PATHOLOGICAL.values(), ids=PATHOLOGICAL.keys())
def test_pathological_inputs_are_handled(source: bytes) -> None:
    check(source)
