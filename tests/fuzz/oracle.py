"""The fuzz properties, shared by the hypothesis tests and the campaign runner.

* `check_loader(bo, bdb)`: arbitrary bytes either fail to load with `BuzzLoadError`, or
  load and run (bounded by `max_ticks`) to success or a `BuzzError` -- never another
  exception, never a hang, never an internal Python error dressed up as a Buzz error
  ("host function error: ..." when the only host function is our infallible `log`).
* `run_both(program, functions)`: the translated VM (`translate=True`) and the reference
  interpreter (`translate=False`) must agree exactly: logged lines, outcome (success, or
  the same error class, message and bytecode offset), final globals, and the results of
  calling the program's functions again with ints, then floats, then strings (the
  translator specializes on the types of the first call).

Disagreements that are known VM bugs still open can be classified by `KNOWN_BUGS`
(signature -> predicate) so that a campaign keeps finding new ones.
"""

from __future__ import annotations

import contextlib
import math
import resource
import signal
import struct
import threading
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import bvm
from bvm.values import Closure, Table, Userdata, format_value

#: Arguments of the second round of calls, in this order (the translator specializes on
#: the first call's types, so later rounds take its guard's slow path).
CALL_ROUNDS: tuple[tuple[Any, ...], ...] = (
    (2, 1, 0, -1),
    (1.5, -0.0, 2.5, 0.25),
    ("ab", "1", "", "x"),
    (3, 2.5, "s", None),
)

ROBOT_ID = 3
RNG_SEED = 12345


class Hang(BaseException):
    """An input ran past its wall-clock allowance (BaseException: the VM must not catch it)."""


@contextlib.contextmanager
def deadline(seconds: float) -> Iterator[None]:
    """Raise `Hang` in the main thread if the body runs longer than `seconds`."""
    if threading.current_thread() is not threading.main_thread() or seconds <= 0:
        yield
        return

    def on_alarm(signum: int, frame: Any) -> None:
        raise Hang(f"no result after {seconds} s")

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def max_rss_mib() -> float:
    """Peak resident memory of this process so far, in MiB."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def warm_up() -> None:
    """Run a VM once: it raises the recursion limit on its first run (deep Buzz recursion),
    and hypothesis warns when the limit changes during a test."""
    bvm.VM().load(bvm.compile_source("x = 1", "/fuzz/warmup.bzz"))


# ---------------------------------------------------------------- rendering values


def render(x: Any, seen: dict[int, int] | None = None, depth: int = 0) -> str:
    """A canonical, exact text for a Buzz (or `to_python`-converted) value.

    Floats by their bits (so -0.0 and NaN signs count), tables with their keys in
    iteration order, shared and cyclic tables as back references.
    """
    if seen is None:
        seen = {}
    cls = x.__class__
    if x is None:
        return "nil"
    if cls is int:
        return f"i{x}"
    if cls is float:
        return "f" + struct.pack("<d", x).hex() + ("(nan)" if math.isnan(x) else f"({x!r})")
    if cls is str:
        return "s" + repr(x)
    if cls is Table or cls is dict:
        if id(x) in seen:
            return f"<table #{seen[id(x)]}>"
        seen[id(x)] = len(seen)
        if depth > 20:
            return "<deep table>"
        items = ", ".join(
            f"{render(k, seen, depth + 1)}: {render(v, seen, depth + 1)}" for k, v in x.items()
        )
        return ("T{" if cls is Table else "D{") + items + "}"
    if cls is Closure:
        if depth > 20:
            return "<deep closure>"
        rec = ", ".join(render(v, seen, depth + 1) for v in x.actrec)
        return f"{x!r}({rec})"
    if cls is Userdata:
        return "userdata"
    return f"<python {cls.__name__}: {x!r}>"


# ---------------------------------------------------------------- one VM run


@dataclass
class Outcome:
    """Everything observable about one VM run."""

    events: list[str] = field(default_factory=list)  # log lines, results, errors in order
    crash: str | None = None  # a non-Buzz exception or an internal error
    inconclusive: str | None = None  # a budget/recursion limit ended the run
    executed: bool = False


def where(e: BaseException) -> str:
    """The innermost bvm frame of an internal error (the VM wraps Python errors as
    "host function error" BuzzErrors; the original is kept as `__context__`)."""
    inner = e.__context__ if isinstance(e, bvm.BuzzError) and e.__context__ else e
    frames = traceback.extract_tb(inner.__traceback__)
    for fr in reversed(frames):
        if "/bvm/" in fr.filename:
            return f"{fr.filename.rsplit('/bvm/', 1)[1]}:{fr.name}"
    return frames[-1].name if frames else "?"


def _error_text(e: BaseException) -> str:
    if isinstance(e, bvm.BuzzError):
        text = f"{type(e).__name__}[{e.message!r} @ {e.offset}]"
        if _internal(e):
            text += f" in {where(e)}"
        return text
    return f"CRASH {type(e).__name__}: {e} in {where(e)}"


def _is_limit(e: BaseException) -> str | None:
    """The kind of resource limit an error reports, if any."""
    if isinstance(e, bvm.BuzzBudgetExceeded):
        return "budget"
    if isinstance(e, bvm.BuzzError) and e.message.startswith("stack overflow"):
        return "recursion"
    if isinstance(e, bvm.BuzzError) and e.message == "out of memory":
        return "memory"
    return None


def _internal(e: BaseException) -> bool:
    """An internal Python error of the VM (our only host function, `log`, never fails)."""
    if isinstance(e, bvm.BuzzError):
        return e.message.startswith(("host function error", "internal error"))
    return True


def run_program(
    program: bvm.Program,
    functions: Sequence[tuple[str, int]],
    *,
    translate: bool,
    max_ticks: int = 200_000,
    max_seconds: float = 5.0,
    call_rounds: Sequence[tuple[Any, ...]] = CALL_ROUNDS,
) -> Outcome:
    """Load and execute `program`, then call each function once per round of arguments.

    `max_seconds` is a safety net: `max_ticks` counts loop iterations only, so work done
    through calls and callbacks is bounded by time alone.
    """
    out = Outcome()
    ev = out.events
    vm = bvm.VM(
        robot_id=ROBOT_ID,
        rng_seed=RNG_SEED,
        max_ticks=max_ticks,
        max_seconds=max_seconds,
        translate=translate,
    )

    def log(*args: Any) -> None:
        ev.append("log " + "|".join(format_value(a) for a in args))

    def step(what: str, body: Callable[[], Any]) -> bool:
        try:
            r = body()
        except Exception as e:  # noqa: BLE001 - classify everything
            ev.append(f"{what} -> {_error_text(e)}")
            if _internal(e):
                out.crash = out.crash or f"{what}: {_error_text(e)}"
            limit = _is_limit(e)
            if limit is not None:
                out.inconclusive = limit
                return False
            return True
        ev.append(f"{what} -> ok {render(r)}")
        return True

    if not step("load", lambda: vm.load(program)):
        return out
    vm.register("log", log)
    if not step("execute", vm.execute):
        return out
    out.executed = True
    ev.append("globals " + _globals(vm))
    for args in call_rounds:
        for name, nparams in functions:
            vm.reset_error()
            a = tuple(args[k % len(args)] for k in range(nparams))
            if not step(f"call {name}{a!r}", lambda n=name, a=a: vm.call(n, *a)):
                return out
    ev.append("globals " + _globals(vm))
    return out


def _globals(vm: bvm.VM) -> str:
    g = vm.buzz_globals()
    return "{" + ", ".join(f"{k}: {render(g[k])}" for k in sorted(g)) + "}"


# ---------------------------------------------------------------- the properties


@dataclass
class Verdict:
    """The result of one differential check."""

    ok: bool
    kind: str  # "same", "inconclusive:<limit>", "mismatch", "crash", "known:<sig>"
    detail: str = ""
    translated: Outcome | None = None
    interpreted: Outcome | None = None


#: Open VM bugs whose symptom is an internal Python error: known-bug name -> a substring
#: of the crash text. Each is pinned by an xfail(strict=True) test in tests/test_fuzz_*.py;
#: remove the entry once its bug is fixed.
KNOWN_CRASHES: dict[str, str] = {}
# Fixed since (regression tests in tests/test_fuzz_*.py): negative float literal keys,
# `done` in the registration prologue, to_python on cyclic tables, inferred result types
# of replaced library functions, computed global names, entries above their lowest
# address, self-creating lambdas.


def known_crash(text: str | None) -> str | None:
    """The known bug a crash text belongs to, if any."""
    if text:
        for name, needle in KNOWN_CRASHES.items():
            if needle in text:
                return name
    return None


def _known_crash_pred(name: str) -> Callable[[Outcome, Outcome], bool]:
    return lambda t, i: name in (known_crash(t.crash), known_crash(i.crash))


#: Open VM bugs as predicates over (translated, interpreted) outcomes.
KNOWN_BUGS: dict[str, Callable[[Outcome, Outcome], bool]] = {
    name: _known_crash_pred(name) for name in KNOWN_CRASHES
}


def first_difference(a: list[str], b: list[str]) -> str:
    """Where two event lists first differ, as readable text."""
    for i, (x, y) in enumerate(zip(a, b, strict=False)):
        if x != y:
            return f"event {i}:\n  translated:  {x}\n  interpreted: {y}"
    if len(a) != len(b):
        longer, which = (a, "translated") if len(a) > len(b) else (b, "interpreted")
        return f"event {min(len(a), len(b))}: only {which} has: {longer[min(len(a), len(b))]}"
    return "no difference"


def compare(t: Outcome, i: Outcome, *, known: bool = True) -> Verdict:
    """Judge a translated and an interpreted run of the same program.

    With `known`, failures matching a `KNOWN_BUGS` signature are reported as
    `known:<name>` (ok=True) so that a campaign keeps looking for new bugs.
    """
    if known and (t.crash or i.crash or t.events != i.events):
        for name, pred in KNOWN_BUGS.items():
            if pred(t, i):
                detail = first_difference(t.events, i.events)
                return Verdict(True, f"known:{name}", detail, t, i)
    if t.crash or i.crash:
        detail = f"translated: {t.crash}\ninterpreted: {i.crash}"
        return Verdict(False, "crash", detail, t, i)
    if t.events == i.events:
        if t.inconclusive:
            return Verdict(True, f"inconclusive:{t.inconclusive}", "", t, i)
        return Verdict(True, "same", "", t, i)
    if t.inconclusive or i.inconclusive:
        # A limit hit on one side only (or at different points) is a real difference,
        # but resource limits are counted differently by the two paths (see the report).
        kind = f"inconclusive:{t.inconclusive or i.inconclusive}"
        return Verdict(True, kind, first_difference(t.events, i.events), t, i)
    return Verdict(False, "mismatch", first_difference(t.events, i.events), t, i)


def run_both(
    program: bvm.Program,
    functions: Sequence[tuple[str, int]],
    *,
    max_ticks: int = 200_000,
    max_seconds: float = 5.0,
    call_rounds: Sequence[tuple[Any, ...]] = CALL_ROUNDS,
    known: bool = True,
) -> Verdict:
    """Run translated and interpreted, and compare."""
    t = run_program(
        program,
        functions,
        translate=True,
        max_ticks=max_ticks,
        max_seconds=max_seconds,
        call_rounds=call_rounds,
    )
    i = run_program(
        program,
        functions,
        translate=False,
        max_ticks=max_ticks,
        max_seconds=max_seconds,
        call_rounds=call_rounds,
    )
    return compare(t, i, known=known)


def check_source(
    source: str,
    functions: Sequence[tuple[str, int]],
    *,
    max_ticks: int = 200_000,
    max_seconds: float = 5.0,
    path: str = "/fuzz/prog.bzz",
    known: bool = True,
) -> Verdict:
    """Compile Buzz source (it must compile) and run the differential check on it."""
    program = bvm.compile_source(source, path)
    return run_both(program, functions, max_ticks=max_ticks, max_seconds=max_seconds, known=known)


@dataclass
class LoaderResult:
    """What happened to one .bo/.bdb input."""

    stage: str  # "rejected", "load-error", "run-error", "ok"
    problem: str | None = None  # set when the property is violated
    message: str = ""
    known: str | None = None  # the problem is this known bug (problem is then None)


def check_loader(
    bo: bytes,
    bdb: bytes = b"",
    *,
    translate: bool = True,
    max_ticks: int = 10_000,
    known: bool = True,
) -> LoaderResult:
    """The loader property for one input (see the module docstring).

    With `known`, a problem matching `KNOWN_CRASHES` is reported in `.known` instead.
    """
    r = _check_loader(bo, bdb, translate, max_ticks)
    if known and r.problem:
        name = known_crash(r.problem)
        if name:
            return LoaderResult(r.stage, None, r.problem, name)
    return r


def _check_loader(bo: bytes, bdb: bytes, translate: bool, max_ticks: int) -> LoaderResult:
    try:
        program = bvm.Program(bo, bdb, "/fuzz/input.bo")
    except bvm.BuzzLoadError as e:
        return LoaderResult("rejected", None, str(e))
    except Exception as e:  # noqa: BLE001
        return LoaderResult("rejected", f"Program(): {type(e).__name__}: {e}")
    # No max_seconds here: the loader property includes "never a hang", which the caller
    # checks with `deadline()`.
    vm = bvm.VM(robot_id=ROBOT_ID, rng_seed=RNG_SEED, max_ticks=max_ticks, translate=translate)
    stage = "load-error"
    try:
        vm.load(program)
        vm.register("log", lambda *a: None)
        stage = "run-error"
        vm.execute()
        _ = str(vm.error)
    except bvm.BuzzError as e:
        text = str(e)  # formatting must work too (location from arbitrary .bdb records)
        if _internal(e):
            return LoaderResult(stage, f"internal error in {where(e)}: {e.message}", text)
        return LoaderResult(stage, None, text)
    except Exception as e:  # noqa: BLE001
        return LoaderResult(stage, f"{type(e).__name__} in {where(e)}: {e}")
    return LoaderResult("ok")
