"""Input makers shared by the hypothesis tests and the campaign: one input per chooser.

* `source_input(ch)` -- a generated Buzz program (see buzzgen) and its functions;
* `loader_input(ch)` -- a (.bo, .bdb) pair: random bytes, a random code section behind a
  valid string table, or a mutant of a real compiled program (the conformance corpus or a
  freshly generated program), with the .bdb sometimes mutated too.
"""

from __future__ import annotations

import functools
import struct
from pathlib import Path

import bvm

from .buzzgen import GeneratedProgram, generate_program
from .choosers import Chooser
from .mutate import mutate_bytecode, mutate_debug

CONFORMANCE = Path(__file__).resolve().parents[1] / "conformance"


@functools.lru_cache(maxsize=1)
def corpus() -> tuple[tuple[bytes, bytes], ...]:
    """(.bo, .bdb) of every conformance script that compiles (the mutation seeds)."""
    out = []
    for path in sorted(CONFORMANCE.glob("*.bzz")):
        try:
            p = bvm.compile_source(path.read_bytes(), str(path), [str(CONFORMANCE)])
        except Exception:  # noqa: BLE001 - scripts that test compile errors
            continue
        out.append((p.bytecode, p.debug))
    if not out:  # the corpus is missing: fall back to one small program
        p = bvm.compile_source("x = 1\nfunction f(a) { return a + x }\nlog(f(2))\n", "/s.bzz")
        out.append((p.bytecode, p.debug))
    return tuple(out)


def source_input(ch: Chooser) -> GeneratedProgram:
    """A generated Buzz program."""
    return generate_program(ch)


def random_code(ch: Chooser) -> bytes:
    """A valid string table followed by random instructions."""
    strings = [b"x", b"f", b"log", b"t"][: ch.integer(0, 4)]
    head = struct.pack("<H", len(strings)) + b"".join(s + b"\0" for s in strings)
    code = bytearray()
    if ch.chance(0.5):
        code.append(0)  # the prologue's nop
    for _ in range(ch.integer(0, 12)):
        op = ch.integer(0, 48)
        code.append(op)
        if 35 <= op <= 46:
            if ch.chance(0.5):
                arg = ch.integer(0, len(head) + 70)
            else:
                arg = ch.choice([0, 1, 0xFFFFFFFF, 0x7FFFFFFF, 0x80000000, 0xFFFF])
            code += struct.pack("<I", arg)
    code.append(1)  # done
    if ch.chance(0.8):
        code.append(0)
    return head + bytes(code)


def loader_input(ch: Chooser) -> tuple[bytes, bytes, str]:
    """A (.bo, .bdb, origin) triple for the loader property."""
    r = ch.integer(0, 9)
    if r == 0:
        return ch.raw(ch.integer(0, 64)), b"", "random"
    if r == 1:
        return random_code(ch), b"", "random-code"
    if r <= 5:
        bo, bdb = ch.choice(corpus())
        origin = "corpus"
    else:
        g = generate_program(ch, max_statements=25)
        try:
            p = bvm.compile_source(g.source, "/fuzz/gen.bzz")
        except bvm.BuzzCompileError:
            return random_code(ch), b"", "random-code"
        bo, bdb = p.bytecode, p.debug
        origin = "generated"
    bo = mutate_bytecode(ch, bo)
    if ch.chance(0.2):
        bdb = mutate_debug(ch, bdb)
    elif ch.chance(0.2):
        bdb = b""
    return bo, bdb, origin
