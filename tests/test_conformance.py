"""The Buzz conformance corpus: every ``tests/conformance/*.bzz`` run through ``fieldkit run``.

Corpus format (one script per behaviour, see the comment at the top of each script):

* ``NAME.bzz`` -- the script. Header comment lines ``# steps: N`` and ``# robot-id: N`` make the
  runner call init()/step() N times/destroy() and set the robot id.
* ``NAME.out`` -- the exact expected stdout (what the script logs).
* ``NAME.err`` -- present when the script must fail (exit code 1). Line 1 is the expected
  location ``LINE:COL``, optionally prefixed by the name of the file it must be in
  (``inc.bzz:LINE:COL``, for included code), or ``*`` when it is not pinned. Line 2 is the
  expected start of the message (the text after ``file:line:col: ``); an empty line 2 accepts
  any message, a line 2 starting with ``~`` is matched as a substring. For a run-time error,
  line 3 is ``at [FILE:]LINE:COL``, the failing operation's position (1-based column, from
  the source map, docs/compat.md V17), checked on the ``.bzz`` run; line 1 is then the
  reference's location (1-based line, 0-based column: docs/language.md#source-positions,
  #annotation-rule, docs/bytecode.md#errors), checked on the script compiled to a ``.bo``
  run without its ``.bpos`` sidecar. For a compile error line 1 is its position (1-based
  column).

The expected outputs were derived from the reference's facts (docs/language.md,
docs/bytecode.md, docs/stdlib.md) plus the lead's compat decisions (scripts named
``compat_*``), not by running the implementation.
Scripts run with a fresh temporary cwd (io files are relative; includes are cwd-relative, so
``tests/conformance/include/`` is copied there).
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

CONFORMANCE = Path(__file__).parent / "conformance"
SCRIPTS = sorted(CONFORMANCE.glob("*.bzz"))

# Scripts for parts of the library that a later issue delivers: they must fail until then
# (strict: the day they pass, this list must shrink).
PENDING: dict[str, str] = {}


def _param(script: Path) -> object:
    reason = PENDING.get(script.stem)
    marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
    return pytest.param(script, id=script.stem, marks=marks)


HEADER_RE = re.compile(r"^#\s*(steps|robot-id):\s*(-?\d+)\s*$")
LOCATED_RE = re.compile(r"^(?P<path>.*?):(?P<line>\d+):(?P<col>\d+): (?P<msg>.*)$")


def _headers(source: str) -> dict[str, int]:
    """The `# steps: N` / `# robot-id: N` header options of a script."""
    found: dict[str, int] = {}
    for line in source.splitlines():
        if not line.startswith("#"):
            break
        m = HEADER_RE.match(line)
        if m:
            found[m.group(1)] = int(m.group(2))
    return found


def _prepare_cwd(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    include = CONFORMANCE / "include"
    if include.is_dir():
        shutil.copytree(include, tmp_path / "include")
    monkeypatch.chdir(tmp_path)


def _message_matches(message: str, expected: str) -> bool:
    if expected.startswith("~"):
        return expected[1:] in message
    return message.startswith(expected)


@pytest.mark.parametrize("script", [_param(s) for s in SCRIPTS])
def test_conformance(script: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from typer.testing import CliRunner

    from fieldkit.cli import app

    source = script.read_text(encoding="latin-1")
    expected_out = script.with_suffix(".out").read_bytes()
    err_file = script.with_suffix(".err")
    headers = _headers(source)

    args = ["run", str(script)]
    if "steps" in headers:
        args += ["--steps", str(headers["steps"])]
    if "robot-id" in headers:
        args += ["--robot-id", str(headers["robot-id"])]

    _prepare_cwd(tmp_path, monkeypatch)
    result = CliRunner().invoke(app, args)
    stdout = result.stdout_bytes
    stderr = result.stderr
    context = (
        f"\n--- exit code: {result.exit_code}\n--- stdout:\n{result.stdout}"
        f"\n--- stderr:\n{stderr}\n--- exception: {result.exception!r}"
    )

    assert stdout == expected_out, f"stdout differs for {script.name}{context}"
    if not err_file.exists():
        assert result.exit_code == 0, f"{script.name} should succeed{context}"
        return

    err_lines = [*err_file.read_text().split("\n"), "", ""]
    location, message, exact = err_lines[0].strip(), err_lines[1], err_lines[2].strip()
    assert result.exit_code == 1, f"{script.name} should fail with exit code 1{context}"
    assert stderr.strip(), f"{script.name} failed without a message{context}"
    if exact:
        assert exact.startswith("at "), f"bad line 3 in {err_file.name}"
        _assert_located(stderr, exact[3:], message, context)
        if location != "*":
            # The reference's location: the compiled .bo run without its source map.
            bo = tmp_path / "compiled" / "script.bo"
            compiled = CliRunner().invoke(app, ["compile", str(script), "-o", str(bo)])
            assert compiled.exit_code == 0, compiled.stderr
            bo.with_suffix(".bpos").unlink()
            result = CliRunner().invoke(app, [args[0], str(bo), *args[2:]])
            context = f"\n--- the .bo without .bpos:\n{result.stderr}"
            assert result.stdout_bytes == expected_out, f"stdout differs{context}"
            assert result.exit_code == 1, f"{script.name} should fail{context}"
            _assert_located(result.stderr, location, message, context)
        return
    lines = stderr.splitlines()
    if location == "*":
        if message:
            ok = any(
                _message_matches(m.group("msg"), message) for m in map(LOCATED_RE.match, lines) if m
            ) or any((message.lstrip("~") in line) for line in lines)
            assert ok, f"expected message {message!r}{context}"
        return
    _assert_located(stderr, location, message, context)


def _assert_located(stderr: str, location: str, message: str, context: str) -> None:
    """Some `file:line:col: message` line of `stderr` is at `location` ([FILE:]LINE:COL)."""
    lines = stderr.splitlines()
    want_file, _, want_pos = location.rpartition(":")
    want_file, _, want_line_text = want_file.rpartition(":")
    want_line, want_col = int(want_line_text), int(want_pos)
    located = [m for m in map(LOCATED_RE.match, lines) if m]
    assert located, f"no `file:line:col: message` line on stderr{context}"
    ok = any(
        m.group("path").endswith(want_file)
        and int(m.group("line")) == want_line
        and int(m.group("col")) == want_col
        and _message_matches(m.group("msg"), message)
        for m in located
    )
    assert ok, f"expected {want_line}:{want_col}: {message!r}{context}"


def test_corpus_is_complete() -> None:
    assert len(SCRIPTS) >= 60, f"only {len(SCRIPTS)} conformance scripts"
    for script in SCRIPTS:
        assert script.with_suffix(".out").exists(), f"{script.name} has no .out"
        assert script.read_text(encoding="latin-1").startswith("#"), (
            f"{script.name} must start with a comment saying what it checks"
        )
        err = script.with_suffix(".err")
        if err.exists():
            lines = [*err.read_text().splitlines(), "", ""]
            loc, exact = lines[0].strip(), lines[2].strip()
            assert loc == "*" or re.fullmatch(r"(?:[\w.-]+:)?\d+:\d+", loc), (
                f"bad location in {err.name}"
            )
            assert not exact or re.fullmatch(r"at (?:[\w.-]+:)?\d+:\d+", exact), (
                f"bad exact location in {err.name}"
            )
    for orphan in CONFORMANCE.glob("*.out"):
        assert orphan.with_suffix(".bzz").exists(), f"{orphan.name} has no script"
    for orphan in CONFORMANCE.glob("*.err"):
        assert orphan.with_suffix(".bzz").exists(), f"{orphan.name} has no script"


# Every opcode of docs/bytecode.md#opcodes.
ALL_OPCODES = [
    "nop", "done", "pushnil", "dup", "pop", "ret0", "ret1", "add", "sub", "mul", "div", "mod",
    "pow", "unm", "land", "lor", "lnot", "band", "bor", "bnot", "lshift", "rshift", "eq", "neq",
    "gt", "gte", "lt", "lte", "gload", "gstore", "pusht", "tput", "tget", "callc", "calls",
    "pushf", "pushi", "pushs", "pushcn", "pushcc", "pushl", "lload", "lstore", "lremove", "jump",
    "jumpz", "jumpnz",
]  # fmt: skip
# Opcodes the compiler never emits (docs/language.md#emission-order, docs/bytecode.md#opcodes):
# `calls` (the "swarm call", which the compiler never emits; swarm calls are made from inside
# the swarm natives) and `pushcc`
# (natives are registered by the VM as global/table values, never referenced as constants,
# so only hand-written assembly contains it). Every other opcode is reachable from source:
# nop/pushcn come from the function-registration prologue, done ends the global code,
# jumpnz comes from `for`, lremove from blocks that declare locals inside functions.
NEVER_EMITTED = {"calls", "pushcc"}

# Every function of docs/stdlib.md, as the dotted name a script calls.
LIBRARY_FUNCTIONS = {
    "type", "int", "float", "clone", "size", "foreach", "map", "reduce", "filter",
    "isnil", "isint", "isfloat", "isstring", "istable", "isclosure", "isuserdata",
    "math.abs", "math.floor", "math.ceil", "math.round", "math.log", "math.log2", "math.log10",
    "math.exp", "math.sqrt", "math.sin", "math.cos", "math.tan", "math.asin", "math.acos",
    "math.atan", "math.min", "math.max",
    "math.rng.setseed", "math.rng.uniform", "math.rng.gaussian", "math.rng.exponential",
    "string.length", "string.sub", "string.concat", "string.tostring", "string.toint",
    "string.tofloat",
    "io.fopen", "io.fclose", "io.fsize", "io.fforeach", "io.fwrite",
}  # fmt: skip
# Library values (not functions) of docs/stdlib.md that the corpus must read.
LIBRARY_VALUES = {"id", "math.pi", "io.errno", "io.error_message"}

_STRIP_RE = re.compile(r"\"(?:\\.|[^\"\\\n])*\"|'(?:\\.|[^'\\\n])*'|#[^\n]*")
_CALL_RE = re.compile(r"(?<![\w.])([A-Za-z]\w*(?:\.[A-Za-z]\w*)*)\s*\(")
_NAME_RE = re.compile(r"(?<![\w.])([A-Za-z]\w*(?:\.[A-Za-z]\w*)*)")


def _code_only(source: str) -> str:
    """The source with string literals and comments blanked out."""
    return _STRIP_RE.sub(" ", source)


def test_corpus_covers_every_opcode(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from bvm.compiler import compile_asm
    from bvm.errors import BuzzCompileError

    _prepare_cwd(tmp_path, monkeypatch)
    used: set[str] = set()
    for script in SCRIPTS:
        try:
            basm = compile_asm(script.read_bytes(), str(script))
        except BuzzCompileError:
            if script.with_suffix(".err").exists():
                continue  # a script that must fail to compile
            raise
        for line in basm.splitlines():
            if line.startswith("\t") and line.strip():
                used.add(line[1:].split("\t")[0].split(" ")[0])
    unknown = used - set(ALL_OPCODES)
    assert not unknown, f"compiler emitted opcodes not in docs/bytecode.md: {sorted(unknown)}"
    missing = set(ALL_OPCODES) - NEVER_EMITTED - used
    assert not missing, f"no conformance script emits: {sorted(missing)}"


def test_corpus_covers_every_library_function() -> None:
    called: set[str] = set()
    named: set[str] = set()
    for script in SCRIPTS:
        code = _code_only(script.read_text(encoding="latin-1"))
        called.update(_CALL_RE.findall(code))
        named.update(_NAME_RE.findall(code))
    missing = LIBRARY_FUNCTIONS - called
    assert not missing, f"library functions never called: {sorted(missing)}"
    missing_values = LIBRARY_VALUES - named
    assert not missing_values, f"library values never read: {sorted(missing_values)}"
