"""Runtime errors at the failing operation, with the Buzz call stack (docs/compat.md V17).

The positions come from the source map (bvm/srcmap.py, the .bpos sidecar); every execution
path of the VM must report the same ones, and every host shows the same text.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

import bvm
from bvm import srcmap
from bvm import translate as bvm_translate
from bvm.compiler import build
from bvm.translate import TranslateOptions
from fieldkit.cli import app
from fieldkit.robot import RobotRuntime, Sensors, geo
from fieldkit.robot.profiles import load_profile

runner = CliRunner()

# The issue's two examples (issue 13, item 4).
LINE_3 = 'x = 1\n\nvar z = 3 + "hello"\n\n# a comment\nw = 2\n'
LAST_STATEMENT = "x = 1\ny = 0\nz = x / y\n"

NESTED = """\
function ratio(a, b) {
  return a / b
}
function mean(t) {
  return ratio(t.sum, t.n)
}
function init() {}
function step() {
  var stats = { .sum = 4, .n = 0 }
  log(mean(stats))
}
"""

# The ways a Buzz function can run (docs/architecture.md): the translator with and without
# its optimizations, and the reference interpreter.
PATHS: dict[str, dict[str, Any]] = {
    "translated": {},
    "no self-calls": {"translate_options": TranslateOptions(self_calls=False)},
    "unchunked loops": {"translate_options": TranslateOptions(chunked_loops=False)},
    "interpreted": {"translate": False},
}
ON_EVERY_PATH = pytest.mark.parametrize("path", list(PATHS))


def run_cli(tmp_path: Path, src: str, *args: str) -> tuple[int, str, Path]:
    script = tmp_path / "s.bzz"
    script.write_text(src)
    result = runner.invoke(app, ["run", str(script), *args])
    return result.exit_code, result.stderr, script


def failing(src: str, path: str = "translated", call: str | None = None) -> bvm.BuzzError:
    """The error running `src` (its global code, then `call`) raises on that path."""
    vm = bvm.VM(**PATHS[path])
    vm.load(bvm.compile_source(src, "p.bzz"))
    vm.register("log", lambda *args: None)
    with pytest.raises(bvm.BuzzError) as info:
        vm.execute()
        if call is not None:
            vm.call(call)
    return info.value


# ---------------------------------------------------------------- what a user sees


def test_the_issue_example_is_reported_at_its_own_line(tmp_path: Path) -> None:
    # The reference (and fieldkit before) said line 6, the next statement.
    status, stderr, script = run_cli(tmp_path, LINE_3)
    assert status == 1
    assert stderr == f"error: {script}:3:11: type mismatch: cannot add integer and string\n"


def test_an_error_in_the_last_statement_has_a_location(tmp_path: Path) -> None:
    # The reference (and fieldkit before) said `(null):0:1: division by zero`.
    status, stderr, script = run_cli(tmp_path, LAST_STATEMENT)
    assert status == 1
    assert stderr == f"error: {script}:3:7: division by zero\n"


def test_run_prints_the_call_stack_under_the_error(tmp_path: Path) -> None:
    status, stderr, script = run_cli(tmp_path, NESTED, "--steps", "1")
    assert status == 1
    assert stderr.splitlines() == [
        f"error: {script}:2:12: division by zero",
        f"  in ratio, called at {script}:5:10",
        f"  in mean, called at {script}:10:7",
        "  in step, called by the host",
    ]


def test_a_bo_with_its_sidecar_needs_no_source(tmp_path: Path) -> None:
    script = tmp_path / "s.bzz"
    script.write_text(NESTED)
    assert runner.invoke(app, ["compile", str(script)]).exit_code == 0
    script.unlink()
    result = runner.invoke(app, ["run", str(tmp_path / "s.bo"), "--steps", "1"])
    assert result.exit_code == 1
    assert result.stderr.splitlines()[:2] == [
        f"error: {script}:2:12: division by zero",
        f"  in ratio, called at {script}:5:10",
    ]


def test_a_bo_without_its_sidecar_is_located_as_the_reference_does(tmp_path: Path) -> None:
    script = tmp_path / "s.bzz"
    script.write_text(NESTED)
    assert runner.invoke(app, ["compile", str(script)]).exit_code == 0
    (tmp_path / "s.bpos").unlink()
    result = runner.invoke(app, ["run", str(tmp_path / "s.bo"), "--steps", "1"])
    assert result.exit_code == 1
    real = script.resolve()
    # The .bdb's entries: the token after each operation, 0-based columns; names from the
    # load-time prologue.
    assert result.stderr.splitlines() == [
        f"error: {real}:3:0: division by zero",
        f"  in ratio, called at {real}:6:0",
        f"  in mean, called at {real}:10:17",
        "  in step, called by the host",
    ]


@pytest.mark.parametrize(
    ("damage", "warning"),
    [
        (lambda b: b[:20], "truncated"),
        (lambda b: b"XPOS" + b[4:], "not a .bpos file"),
        (lambda b: b + b"\0", "after the end"),
    ],
    ids=["truncated", "bad magic", "trailing bytes"],
)
def test_a_corrupt_sidecar_is_ignored_with_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, damage: Any, warning: str
) -> None:
    program = bvm.compile_source(LAST_STATEMENT, "s.bzz")
    assert program.srcmap is not None
    bo = tmp_path / "s.bo"
    bo.write_bytes(program.bytecode)
    bo.with_suffix(".bdb").write_bytes(program.debug)
    bo.with_suffix(".bpos").write_bytes(damage(srcmap.encode(program.srcmap, program.bytecode)))
    with caplog.at_level(logging.WARNING, logger="bvm"):
        loaded = bvm.Program.load(bo)
    assert loaded.srcmap is None
    assert any("source map ignored" in r.message and warning in r.message for r in caplog.records)
    vm = bvm.VM()
    vm.load(loaded)
    with pytest.raises(bvm.BuzzError, match=r"^\(null\):0:1: division by zero$"):
        vm.execute()  # the reference's location (the end-of-file token)


def test_a_stale_sidecar_is_ignored(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """A .bo replaced (an update) beside the sidecar of the old one: its positions would lie."""
    old = bvm.compile_source(LAST_STATEMENT, "s.bzz")
    new = bvm.compile_source("q = 1\n" + LAST_STATEMENT, "s.bzz")
    assert old.srcmap is not None
    bo = tmp_path / "s.bo"
    bo.write_bytes(new.bytecode)
    bo.with_suffix(".bpos").write_bytes(srcmap.encode(old.srcmap, old.bytecode))
    with caplog.at_level(logging.WARNING, logger="bvm"):
        assert bvm.Program.load(bo).srcmap is None
    assert "stale" in caplog.text


def test_the_bo_and_bdb_bytes_are_the_references(tmp_path: Path) -> None:
    """The source map is extra: compile_source and `fieldkit compile` give the bytes of
    the reference-identical compiler (compiler.build, checked against the reference)."""
    script = tmp_path / "s.bzz"
    script.write_text(NESTED)
    bo, bdb = build(NESTED.encode(), str(script))
    program = bvm.compile_source(NESTED, str(script))
    assert (program.bytecode, program.debug) == (bo, bdb)
    assert runner.invoke(app, ["compile", str(script)]).exit_code == 0
    assert (tmp_path / "s.bo").read_bytes() == bo
    assert (tmp_path / "s.bdb").read_bytes() == bdb
    assert (tmp_path / "s.bpos").read_bytes() == srcmap.encode(program.srcmap, bo)  # type: ignore[arg-type]


def test_text_compiled_without_a_file_is_named_buzz() -> None:
    vm = bvm.VM()
    vm.load(bvm.compile_source(LAST_STATEMENT))
    with pytest.raises(bvm.BuzzError, match=r"^<buzz>:3:7: division by zero$"):
        vm.execute()
    assert b"<buzz>" in bvm.compile_source(LAST_STATEMENT).debug  # no working directory


# ---------------------------------------------------------------- every execution path


@ON_EVERY_PATH
@pytest.mark.parametrize(("src", "where"), [(LINE_3, (3, 11)), (LAST_STATEMENT, (3, 7))])
def test_top_level_errors(path: str, src: str, where: tuple[int, int]) -> None:
    err = failing(src, path)
    assert err.location == ("p.bzz", *where)
    assert err.stack == []  # no function: no stack lines
    assert "\n" not in str(err)


@ON_EVERY_PATH
def test_nested_calls(path: str) -> None:
    err = failing(NESTED, path, "step")
    assert str(err).splitlines() == [
        "p.bzz:2:12: division by zero",
        "  in ratio, called at p.bzz:5:10",
        "  in mean, called at p.bzz:10:7",
        "  in step, called by the host",
    ]


CLOSURES = """\
var shape = { .w = 2 }
shape.area = function() { return self.w * self.h }
function init() {
  var scale = function(k) { return shape.area() * k }
  var t = { .a = 1 }
  foreach(t, function(key, value) {
    scale(value)
  })
}
"""


@ON_EVERY_PATH
def test_closures_and_lambdas(path: str) -> None:
    err = failing(CLOSURES, path, "init")
    assert str(err).splitlines() == [
        "p.bzz:2:41: type mismatch: cannot multiply integer and nil",
        "  in shape.area, called at p.bzz:4:36",
        "  in scale, called at p.bzz:7:5",
        "  in <lambda at p.bzz:6:14>, called at p.bzz:6:3",
        "  in init, called by the host",
    ]


SELF_CALLS = """\
function down(n) {
  if (n == 0) return 1 / n
  return down(n - 1)
}
"""


@ON_EVERY_PATH
def test_recursion_is_folded(path: str) -> None:
    vm = bvm.VM(**PATHS[path])
    vm.load(bvm.compile_source(SELF_CALLS, "p.bzz"))
    vm.execute()
    with pytest.raises(bvm.BuzzError) as info:
        vm.call("down", 30)
    assert str(info.value).splitlines() == [
        "p.bzz:2:24: division by zero",
        "  in down, called at p.bzz:3:10",
        "  ... the same call 29 more times",
        "  in down, called by the host",
    ]


@ON_EVERY_PATH
def test_a_call_rejected_by_a_specialized_entry_is_one_frame(path: str) -> None:
    """Called with ints first (a translation specialized on them), then with a string:
    the entry forwards to the general translation, which must not show twice."""
    vm = bvm.VM(**PATHS[path])
    vm.load(bvm.compile_source("function twice(x) {\n  return x * 2\n}\n", "p.bzz"))
    vm.execute()
    assert vm.call("twice", 4) == 8
    with pytest.raises(bvm.BuzzError) as info:
        vm.call("twice", "s")
    assert str(info.value).splitlines() == [
        "p.bzz:2:12: type mismatch: cannot multiply string and integer",
        "  in twice, called by the host",
    ]


@ON_EVERY_PATH
def test_a_loop_out_of_budget_points_at_its_loop(path: str) -> None:
    src = "function spin() {\n  var i = 0\n  while (1) {\n    i = i + 1\n  }\n}\n"
    vm = bvm.VM(max_ticks=5000, **PATHS[path])
    vm.load(bvm.compile_source(src, "p.bzz"))
    vm.execute()
    with pytest.raises(bvm.BuzzBudgetExceeded) as info:
        vm.call("spin")
    assert info.value.location == ("p.bzz", 3, 3)
    assert str(info.value).splitlines()[1:] == ["  in spin, called by the host"]


@ON_EVERY_PATH
def test_errors_inside_host_functions_point_at_the_call(path: str) -> None:
    src = "function go(v) {\n  var r = 1 + math.sqrt(v)\n  return r\n}\n"
    vm = bvm.VM(**PATHS[path])
    vm.load(bvm.compile_source(src, "p.bzz"))
    vm.execute()
    assert vm.call("go", 4.0) == 3.0  # the inline fast path first
    with pytest.raises(bvm.BuzzError) as info:
        vm.call("go", "four")
    assert info.value.location == ("p.bzz", 2, 15)


def test_the_interpreter_fallback_of_a_translating_vm(monkeypatch: pytest.MonkeyPatch) -> None:
    """Code the translator declines runs on the interpreter inside a translating VM."""

    def decline(*_: Any, **__: Any) -> Any:
        raise bvm_translate.NotStructured("declined for the test")

    monkeypatch.setattr(bvm_translate, "translate", decline)
    err = failing(NESTED, "translated", "step")
    assert str(err).splitlines()[:3] == [
        "p.bzz:2:12: division by zero",
        "  in ratio, called at p.bzz:5:10",
        "  in mean, called at p.bzz:10:7",
    ]
    assert err.offset is not None and err.op_offset == err.offset  # `div` moves oldpc first


def test_the_references_offset_is_kept_beside_the_exact_one() -> None:
    """`offset` stays the reference's oldpc (a tget's error: the instruction before it)."""
    err = failing("t = nil\nx = t.a\n")
    program = bvm.compile_source("t = nil\nx = t.a\n", "p.bzz")
    assert err.op_offset is not None and err.offset is not None
    assert program.decode(err.op_offset).op.mnemonic == "tget"  # type: ignore[union-attr]
    assert program.decode(err.offset).next == err.op_offset  # type: ignore[union-attr]


# ---------------------------------------------------------------- the robot hosts


def robot(src: str) -> RobotRuntime:
    home = geo.DEFAULT_HOME
    r = RobotRuntime(1, load_profile("solo"), geo.LocalFrame(*home), seed=0)
    sensors = Sensors(lat=home[0], lon=home[1], alt=0.0, north=0.0, east=0.0)
    r.start(bvm.compile_source(src, "robot.bzz"), sensors)
    return r


def test_the_runtime_keeps_the_stack_of_an_init_error() -> None:
    r = robot("function init() {\n  x = helper()\n}\nfunction helper() {\n  return x.a.b\n}\n")
    assert r.error is not None
    assert r.error.splitlines() == [
        "robot.bzz:5:11: type mismatch: expected table, got nil",
        "  in helper, called at robot.bzz:2:7",
        "  in init, called by the host",
    ]


def test_the_runtime_keeps_the_stack_of_a_step_error(caplog: pytest.LogCaptureFixture) -> None:
    r = robot(NESTED)
    assert r.error is None
    home = geo.DEFAULT_HOME
    with caplog.at_level(logging.ERROR):
        r.tick(Sensors(lat=home[0], lon=home[1], alt=0.0, north=0.0, east=0.0))
    assert r.error is not None
    assert r.error.splitlines()[0] == "robot.bzz:2:12: division by zero"
    assert r.error.splitlines()[-1] == "  in step, called by the host"
    assert "  in ratio, called at robot.bzz:5:10" in caplog.text  # and in the log
