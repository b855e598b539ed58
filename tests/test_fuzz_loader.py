"""Loader fuzzing: any bytes as a .bo/.bdb either fail to load with BuzzLoadError, or load
and run (max_ticks=10_000) to success or a BuzzError -- nothing else, no hang, bounded memory.

Random bytes mostly die in the string table, so most examples mutate real compiled programs
(the conformance corpus): bit flips, truncations, insertions, swaps, and instruction-level
edits (opcode swaps, retargeted jumps and closures, edge-value arguments). The same inputs
run in long campaigns with `python -m tests.fuzz.campaign --mode loader`.

Internal Python errors that the VM wraps as "host function error" BuzzErrors count as
failures (our only host function, `log`, cannot fail). Open bugs are filtered by
`oracle.KNOWN_CRASHES`; the bugs found so far are regression tests at the end of this file.
"""

from __future__ import annotations

import os

import pytest
from fuzz import oracle
from fuzz.choosers import HypothesisChooser
from fuzz.inputs import corpus, random_code
from fuzz.mutate import mutate_bytecode, mutate_debug
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import bvm

# Translations of hostile code can contain Python that is certain to fail, e.g. `'abc'['x']`,
# which CPython flags with a SyntaxWarning at compile time.
pytestmark = pytest.mark.filterwarnings("ignore::SyntaxWarning")

#: Examples per property; FUZZ_EXAMPLES scales them all (the defaults keep the file < 15 s).
SCALE = float(os.environ.get("FUZZ_EXAMPLES", "0") or 0) / 200 or 1.0
FAST = settings(
    deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large]
)

MEMORY_GROWTH_MIB = 512

oracle.warm_up()


def _examples(n: int) -> int:
    return max(1, int(n * SCALE))


def check(bo: bytes, bdb: bytes = b"") -> None:
    """The loader property on both execution paths, within 10 s and bounded memory."""
    rss = oracle.max_rss_mib()
    paths = (True, False)
    try:
        with oracle.deadline(10):
            for translate in paths:
                r = oracle.check_loader(bo, bdb, translate=translate)
                assert r.problem is None, (
                    f"translate={translate}: {r.problem}\n.bo = {bo.hex()}\n.bdb = {bdb.hex()}"
                )
    except oracle.Hang as e:
        raise AssertionError(f"hang: {e}\n.bo = {bo.hex()}\n.bdb = {bdb.hex()}") from None
    grown = oracle.max_rss_mib() - rss
    assert grown < MEMORY_GROWTH_MIB, f"memory grew {grown:.0f} MiB\n.bo = {bo.hex()}"


@settings(FAST, max_examples=_examples(300))
@given(st.binary(max_size=160))
def test_random_bytes_as_bo(bo: bytes) -> None:
    check(bo)


@settings(FAST, max_examples=_examples(150))
@given(st.binary(max_size=160))
def test_random_bytes_as_bdb(bdb: bytes) -> None:
    bo, _ = corpus()[0]
    check(bo, bdb)


@settings(FAST, max_examples=_examples(200))
@given(st.data())
def test_random_code_behind_a_valid_string_table(data: st.DataObject) -> None:
    check(random_code(HypothesisChooser(data)))


@settings(FAST, max_examples=_examples(200))
@given(st.data())
def test_mutated_programs(data: st.DataObject) -> None:
    ch = HypothesisChooser(data)
    bo, bdb = ch.choice(corpus())
    check(mutate_bytecode(ch, bo), bdb if ch.chance(0.5) else b"")


@settings(FAST, max_examples=_examples(100))
@given(st.data())
def test_mutated_debug_info(data: st.DataObject) -> None:
    ch = HypothesisChooser(data)
    bo, bdb = ch.choice(corpus())
    check(bo, mutate_debug(ch, bdb))


def test_truncations_of_a_real_program() -> None:
    """Every prefix of a small real program (the cheapest exhaustive mutation)."""
    bo, bdb = min((p for p in corpus() if len(p[0]) >= 120), key=lambda p: len(p[0]))
    for n in range(len(bo) + 1):
        check(bo[:n], bdb)
    for n in range(0, len(bdb) + 1, 11):
        check(bo, bdb[:n])


# ---------------------------------------------------------------- open bugs (found by fuzzing)


def _run(bo: bytes, translate: bool) -> tuple[list[tuple], str]:
    vm = bvm.VM(max_ticks=10_000, translate=translate)
    logs: list[tuple] = []
    try:
        vm.load(bvm.Program(bo, b"", "/fuzz/repro.bo"))
        vm.register("log", lambda *a: logs.append(a))
        vm.execute()
    except bvm.BuzzError as e:
        return logs, f"{e.message} @ {e.offset}"
    return logs, "ok"


def test_done_in_prologue() -> None:
    """Found by fuzzing, fixed in cd6edbb: 0 strings, `done`, `nop` -- load() stopped at
    `done` with no global start (None) and execute() failed with "host function error:
    TypeError: '<' not supported between instances of 'NoneType' and 'int'"."""
    for translate in (True, False):
        _, outcome = _run(bytes.fromhex("00000100"), translate)
        assert "host function error" not in outcome, outcome
        assert "internal error" not in outcome, outcome


# `f("f")` where f does `lload 1; pushi 5; gstore`: the global's name is the argument.
COMPUTED_GLOBAL_NAME = bytes.fromhex(
    "01006600250000000026240000001d000225000000001c25000000002401000000210401"
    "290100000024050000001d05"
)


def test_bug_computed_global_name() -> None:
    """A gstore whose name is a string-typed non-literal (here an argument specialized as
    str): the translator calls python_name(None) -> "host function error: TypeError:
    expected string or bytes-like object, got 'NoneType'" at offset 33. The interpreter
    sets global f = 5."""
    assert _run(COMPUTED_GLOBAL_NAME, True) == _run(COMPUTED_GLOBAL_NAME, False)


# f logs "a" then jumps *backward* to code that logs "b" and returns.
ENTRY_NOT_LOWEST = bytes.fromhex(
    "040066006c6f6700610062002500000000263b0000001d000225000000001c240000000021"
    "04010225010000001c250300000024010000002104050225010000001c25020000002401"
    "0000002104" + "2c2700000005"
)


def test_bug_function_entry_not_lowest_address() -> None:
    """When a function's entry is not the lowest address reachable from it (hand-made or
    mutated bytecode: a jump back to earlier code), the translated function runs from the
    lowest reachable address instead of its entry: it logs only "b", the interpreter
    logs "a" then "b"."""
    assert _run(ENTRY_NOT_LOWEST, True) == _run(ENTRY_NOT_LOWEST, False)


# A lambda that creates itself (`pushl` of its own address) and calls the new closure with
# one argument: each level's activation record is one slot longer.
SELF_CREATING_LAMBDA = bytes.fromhex(
    "00000002281600000024000000002401000000210401022816000000240000000024010000002106"
)


def test_bug_self_creating_lambda() -> None:
    """The interpreter stops with "stack overflow" after 0.2 s; the translated path makes a
    new Entry and translation for every activation-record length (addr, n_actrec) and
    needs ~50 s and ~900 MiB (RSS) to reach the same error, which it attributes to another
    offset (38 instead of 22). Over-the-air bytecode can stall a robot this way; the
    loader property "never a hang, bounded memory" fails."""
    import bvm.vm as vm_module

    translations: list[int] = []
    real = vm_module._translate.translate

    def counting(*args: object, **kwargs: object) -> object:
        translations.append(1)
        return real(*args, **kwargs)  # type: ignore[arg-type]

    vm_module._translate.translate = counting  # type: ignore[assignment]
    try:
        # A guard against the old hang only (the work is counted below, not timed).
        with oracle.deadline(60):
            outcome = _run(SELF_CREATING_LAMBDA, True)
    except oracle.Hang:
        raise AssertionError("translated run still going after 60 s") from None
    finally:
        vm_module._translate.translate = real
    assert len(translations) <= 2 * vm_module._MAX_SHAPES  # not one per record length
    assert outcome == _run(SELF_CREATING_LAMBDA, False)


# f(1): `if (a) { log("a") jump FAR } else { return 0 }`, unrelated code (`pushi 7; ret1`),
# then FAR: log("b"); return.
JUMP_OVER_UNREACHABLE_CODE = bytes.fromhex(
    "040066006c6f6700610062002500000000262c0000001d000225000000001c24010000002401"
    "00000021040129010000002d4e0000000225010000001c2502000000240100000021042c5a"
    "0000002400000000062407000000060225010000001c25030000002401000000210405"
)


def test_bug_then_branch_jumps_over_unreachable_code() -> None:
    """Found by the loader campaign (seed B3:825, a mutated backward jump): when the `then`
    branch of an if/else ends with a forward `jump` past unreachable code (here another
    function's `pushi 7; ret1`) and the `else` branch returns, the translated function
    returns nil after the `then` branch instead of continuing at the jump target: it logs
    only "a"; the interpreter logs "a" then "b"."""
    assert _run(JUMP_OVER_UNREACHABLE_CODE, True) == _run(JUMP_OVER_UNREACHABLE_CODE, False)
