"""Every test runs in its own empty working directory.

Buzz's `io` library opens files relative to the working directory, and the fuzzers run
arbitrary bytecode: nothing a test runs may write into the repository (or anywhere that
matters). Tests find the repository through `__file__`, never through the cwd.
"""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(autouse=True)
def _isolated_cwd(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
