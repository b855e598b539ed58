"""Every test runs in its own empty working directory, and property tests draw the same
examples on every run.

Buzz's `io` library opens files relative to the working directory, and the fuzzers run
arbitrary bytecode: nothing a test runs may write into the repository (or anywhere that
matters). Tests find the repository through `__file__`, never through the cwd.

A suite that fails at random cannot gate a landing: hypothesis derives each test's examples
from its name. New examples are the fuzz campaign's job (`python -m tests.fuzz.campaign`),
or set HYPOTHESIS_EXPLORE=1 to draw fresh ones in the suite.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Iterator
from pathlib import Path

import pytest
import typer.testing
from hypothesis import settings
from rigs import RIG_HOME, SimRig

# CliRunner.invoke converts the Typer app into its click commands on every call: ~0.2 s of
# annotation evaluation for fieldkit's ~110 commands and options, more than most invocations
# take, for the same tree each time (a command run from the shell builds it once too).
# Click runs each invocation in a fresh context, so one tree per app serves every test.
typer.testing._get_command = functools.cache(typer.testing._get_command)  # type: ignore[attr-defined]

# No deadline: hypothesis's default (200 ms an example) fails tests at random on a loaded
# machine, and no test may depend on wall-clock speed.
settings.register_profile("deterministic", derandomize=True, deadline=None)
settings.register_profile("explore", derandomize=False, deadline=None)
settings.load_profile("explore" if os.environ.get("HYPOTHESIS_EXPLORE") else "deterministic")


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """`-n auto`: half again as many workers as this process may use cores.

    A third of the suite's time is simulated flights in real time (SITL, nodes against
    simulated autopilots on ptys), which wait on the clock half the time: a worker beyond
    the cores runs other tests meanwhile (on 2 cores: 547 s instead of 625 s, measured).
    """
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, (cores or 1) * 3 // 2)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Tests marked `long` (20 s or more) run first: xdist hands each worker a run of the
    collection in order, and a long test that starts late keeps the whole suite waiting
    for it at the end while the other workers have nothing left to take."""
    items.sort(key=lambda item: item.get_closest_marker("long") is None)


@pytest.fixture(autouse=True)
def _isolated_cwd(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)


@pytest.fixture
def rig() -> Iterator[SimRig]:
    """The solo's simulated ArduPilot and its link on a pty, GPS fixed: where a node starts."""
    r = SimRig("solo", home=RIG_HOME, gps_fix_delay_s=0.0)
    r.connect()
    assert r.run_until(lambda: r.link.telemetry.gps_fix_type >= 3, 10.0)
    yield r
    r.close()
