"""Fuzzing the lexer and parser: bad source only ever raises BuzzCompileError.

Whatever compiles must also assemble, and its bytecode must survive a
disassemble/assemble round trip.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bvm.assembler import assemble
from bvm.compiler import compile_source
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
        text = compile_source(source, P)
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


@pytest.mark.parametrize("source", VALID)
def test_corpus_compiles(source: bytes) -> None:
    text = compile_source(source, P)
    bo, bdb = assemble(text)
    assert assemble(disassemble(bo, bdb)) == (bo, bdb)


PATHOLOGICAL = {
    "parens": b"(" * 50_000,
    "indexes": b"x = " + b"[" * 20_000,
    "calls": b"f(" * 20_000,
    "returns": b"return\n" * 3_000,
    "fallbacks": b"function f() {" + b"if (x) return\n y = 1\n" * 1_000 + b"}",
    "long": b"x = 1\n" * 20_000 + b"_",
}


@pytest.mark.parametrize("source", PATHOLOGICAL.values(), ids=PATHOLOGICAL.keys())
def test_pathological_inputs_are_handled(source: bytes) -> None:
    check(source)
