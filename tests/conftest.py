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

import os
from pathlib import Path

import pytest
from hypothesis import settings

settings.register_profile("deterministic", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile("explore" if os.environ.get("HYPOTHESIS_EXPLORE") else "deterministic")


@pytest.fixture(autouse=True)
def _isolated_cwd(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
