"""Fuzzing the source-map decoder (bvm.srcmap, the .bpos sidecar) with hostile files.

    python -m tests.fuzz.srcmap_fuzz --seconds 60 --seed 1
    python -m tests.fuzz.srcmap_fuzz --replay 1:12345      # one input, verbosely

A sidecar is read from disk beside a .bo that may have come over the air with it, so it is
untrusted. Input k of seed S is made from `random.Random(f"{S}:{k}")`: random bytes, valid
sidecars of real programs (the conformance corpus), and mutations of those (bit flips,
interesting bytes and counts written over count and index fields, truncations, extensions,
splices of two sidecars, a sidecar of another program).

The property, per input (a sidecar and the .bo it claims):

* `srcmap.decode` returns a SourceMap or raises BuzzLoadError naming the file; any other
  exception is a failure;
* an accepted map has its offsets inside the bytecode, its positions and names well
  typed, and encode then decode gives it back (the decoder reads what the encoder writes);
* `Program.load` of the .bo with that sidecar beside it never fails because of it, and an
  error raised by the program is still reported (`str(error)` works, the first line
  unchanged in form) whatever the sidecar says.

Failures are printed with their replay id. The last line is `inputs: N, failures: K`.
"""

from __future__ import annotations

import logging
import random
import struct
import sys
import tempfile
import traceback
from collections.abc import Callable
from functools import cache
from pathlib import Path

import bvm
from bvm import srcmap
from bvm.errors import BuzzLoadError

from . import runner

CORPUS = Path(__file__).resolve().parent.parent / "conformance"

#: Seed programs: a few corpus scripts (functions, lambdas, includes-free) and two made here.
SEED_SCRIPTS = (
    "func_local_recursion_error",
    "err_in_callback",
    "host_step_error",
    "func_closures_by_value",
    "func_closures_in_loops",
)
EXTRA_SOURCES = (
    "x = 1\ny = x + nil\n",
    "function f(a) { return a.b[2] }\nvar g = function() { f(1) }\nfunction step() { g() }\n",
)
INTERESTING_U32 = (0, 1, 2, 0x7F, 0x80, 0xFF, 0xFFFF, 0x10000, 0x7FFFFFFF, 0xFFFFFFFF)


@cache
def seeds() -> tuple[tuple[bytes, bytes], ...]:
    """(bytecode, sidecar) of each seed program."""
    sources = [
        (CORPUS / f"{name}.bzz").read_bytes()
        for name in SEED_SCRIPTS
        if (CORPUS / f"{name}.bzz").exists()
    ]
    sources += [s.encode() for s in EXTRA_SOURCES]
    out = []
    for k, src in enumerate(sources):
        program = bvm.compile_source(src, f"seed{k}.bzz")
        assert program.srcmap is not None
        out.append((program.bytecode, srcmap.encode(program.srcmap, program.bytecode)))
    return tuple(out)


def count_fields(data: bytes) -> list[int]:
    """Offsets of the length and count fields of a valid sidecar (what tampering targets)."""
    fields = [13]  # the file count
    pos = 15
    try:
        (nfiles,) = struct.unpack_from("<H", data, 13)
        for _ in range(nfiles):
            fields.append(pos)
            pos += 2 + struct.unpack_from("<H", data, pos)[0]
        fields.append(pos)
        (npos,) = struct.unpack_from("<I", data, pos)
        pos += 4
        fields += [pos + 14 * i + 4 for i in range(min(npos, 8))]  # file indexes
        pos += 14 * npos
        fields.append(pos)
    except struct.error:
        pass
    return fields


def position_count_at(data: bytes) -> int:
    """The offset of a valid sidecar's position count (after the header and file names)."""
    pos = 15
    for _ in range(struct.unpack_from("<H", data, 13)[0]):
        pos += 2 + struct.unpack_from("<H", data, pos)[0]
    return pos


def mutate(rng: random.Random, data: bytes) -> bytes:
    """One to four random changes."""
    b = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        what = rng.randrange(6)
        if what == 0 and b:
            i = rng.randrange(len(b))
            b[i] ^= 1 << rng.randrange(8)
        elif what == 1 and b:
            b[rng.randrange(len(b))] = rng.choice((0, 1, 0x7F, 0x80, 0xFF))
        elif what == 2:
            del b[rng.randrange(len(b) + 1) :]
        elif what == 3:
            b += bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
        else:
            fields = [f for f in count_fields(bytes(b)) if f + 4 <= len(b)]
            if fields:
                at = rng.choice(fields)
                size = 2 if at == 13 else 4
                value = rng.choice(INTERESTING_U32) & (0xFFFF if size == 2 else 0xFFFFFFFF)
                b[at : at + size] = value.to_bytes(size, "little")
    return bytes(b)


def make_input(seed: str, k: int) -> tuple[str, bytes, bytes]:
    """Input k of `seed`: (kind, bytecode, sidecar)."""
    rng = random.Random(f"{seed}:{k}")
    pairs = seeds()
    bytecode, sidecar = rng.choice(pairs)
    kind = rng.choice(("valid", "random", "mutate", "mutate", "mutate", "splice", "other"))
    if kind == "random":
        head = sidecar[:13] if rng.random() < 0.7 else b""  # past the header, usually
        sidecar = head + bytes(rng.randrange(256) for _ in range(rng.randint(0, 200)))
    elif kind == "mutate":
        sidecar = mutate(rng, sidecar)
    elif kind == "splice":
        _, other = rng.choice(pairs)
        cut = rng.randrange(len(sidecar) + 1)
        sidecar = sidecar[:cut] + other[rng.randrange(len(other) + 1) :]
    elif kind == "other":
        bytecode = rng.choice(pairs)[0]  # a sidecar beside the wrong .bo: stale
    return kind, bytecode, sidecar


def check(bytecode: bytes, sidecar: bytes) -> tuple[bool, str | None]:
    """(whether the sidecar was accepted, the problem found or None)."""
    try:
        smap = srcmap.decode(sidecar, bytecode, "x.bpos")
    except BuzzLoadError as e:
        if not str(e).startswith("x.bpos: "):
            return False, f"BuzzLoadError does not name the file: {e}"
        return False, _check_load(bytecode, sidecar)
    except Exception:  # noqa: BLE001 - the property: nothing else escapes
        return False, "decode raised: " + traceback.format_exc(limit=-2)
    for offset, (file, line, col) in smap.positions.items():
        if not (0 <= offset < len(bytecode)) or not isinstance(file, str):
            return True, f"bad position {offset}: {(file, line, col)}"
        if not (isinstance(line, int) and isinstance(col, int)):
            return True, f"bad position {offset}: {(file, line, col)}"
    for addr, fn in smap.functions.items():
        if not 0 <= addr < len(bytecode) or not (fn.name is None or isinstance(fn.name, str)):
            return True, f"bad function {addr}: {fn}"
    again = srcmap.decode(srcmap.encode(smap, bytecode), bytecode)
    if again != smap:
        return True, "encode then decode changed the map"
    return True, _check_load(bytecode, sidecar)


def _check_load(bytecode: bytes, sidecar: bytes) -> str | None:
    """Program.load with the sidecar beside the .bo loads, runs, and reports errors."""
    with tempfile.TemporaryDirectory() as tmp:
        bo = Path(tmp) / "p.bo"
        bo.write_bytes(bytecode)
        bo.with_suffix(".bpos").write_bytes(sidecar)
        log = logging.getLogger("bvm")
        log.disabled = True  # the "source map ignored" warnings of a campaign are expected
        try:
            program = bvm.Program.load(bo)
        except Exception:  # noqa: BLE001
            return "Program.load raised: " + traceback.format_exc(limit=-2)
        finally:
            log.disabled = False
    vm = bvm.VM(max_ticks=10_000)
    try:
        vm.load(program)
        vm.execute()
        for name in ("init", "step"):
            if vm.gload(name) is not None:
                vm.call(name)
    except bvm.BuzzError as e:
        text = str(e)
        if not text or not text.splitlines()[0].endswith(e.message):
            return f"error text lost its message: {text!r}"
    except Exception:  # noqa: BLE001
        return "running raised: " + traceback.format_exc(limit=-2)
    return None


class Stats(runner.Stats):
    """What a campaign did."""

    accepted: int = 0

    def details(self) -> list[str]:
        """The kinds of input run and how many were accepted."""
        return [*super().details(), f"accepted (decoded to a map): {self.accepted}"]


def run_one(seed: str, k: int, stats: Stats, out: Callable[[str], None]) -> None:
    """Make input k, check it, and record the outcome."""
    kind, bytecode, sidecar = make_input(seed, k)
    try:
        accepted, problem = check(bytecode, sidecar)
    except Exception:  # noqa: BLE001 - a harness error is reported, not fatal
        accepted, problem = False, "harness error: " + traceback.format_exc(limit=-3)
    stats.kinds[kind] += 1
    stats.accepted += accepted
    if problem is not None:
        text = f"FAILURE [replay {seed}:{k}] ({kind}) {problem}\n  sidecar: {sidecar[:256].hex()}"
        stats.fail(f"{seed}:{k}", text, out, shown=20)


#: run(seed, *, seconds=None, max_inputs=None, start=0, out=print) -> Stats: a campaign.
run = runner.make_run(run_one, Stats, clock_every=16, progress=True)


def replay(spec: str) -> int:
    """Run one input verbosely; 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    kind, bytecode, sidecar = make_input(seed, int(k))
    print(f"input {spec}: {kind}, {len(sidecar)} bytes beside a {len(bytecode)}-byte .bo")
    print(sidecar.hex())
    accepted, problem = check(bytecode, sidecar)
    print("accepted:", accepted)
    print("verdict:", problem or "ok")
    return 1 if problem else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    return runner.main(argv, __doc__, run, replay)


if __name__ == "__main__":
    sys.exit(main())
