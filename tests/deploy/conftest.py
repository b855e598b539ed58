"""Fixtures of the deploy tests: a key directory as `fieldkit keys init` makes it."""

from __future__ import annotations

from pathlib import Path

import pytest

from fieldkit.update.keys import init_keys


@pytest.fixture
def keys(tmp_path: Path) -> Path:
    """An operator's key directory: operator.key, operator.pub, swarm.key."""
    return init_keys(tmp_path / "keys").directory
