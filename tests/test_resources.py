"""fieldkit.resources: where the shipped profiles, scripts and graphs are, and script lookup."""

from __future__ import annotations

from pathlib import Path

import pytest

from fieldkit import resources


def test_the_shipped_data_is_found_through_the_package() -> None:
    """Profiles, scripts, includes, graphs and examples are all in their packages' folders."""
    assert (resources.profile_dir() / "solo.toml").is_file()
    assert (resources.script_dir() / "task_allocation.bzz").is_file()
    assert (resources.script_dir() / "include" / "states.bzz").is_file()
    assert (resources.graph_dir() / "P.graph").is_file()
    assert (resources.example_dir() / "hello.bzz").is_file()


def test_a_bare_name_is_the_shipped_script(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """From a directory without such a file, a relative name resolves to the shipped script."""
    monkeypatch.chdir(tmp_path)
    shipped = resources.find_script("task_allocation.bzz")
    assert shipped == resources.script_dir() / "task_allocation.bzz"
    assert resources.find_script("examples/hello.bzz") == resources.example_dir() / "hello.bzz"
    # As the README writes it, from outside the checkout:
    assert resources.find_script("buzz_scripts/task_allocation.bzz") == shipped


def test_a_local_file_wins_and_a_missing_one_stays_as_given(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The user's own file of the same name is used; an unknown name is returned unchanged."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "task_allocation.bzz").write_text("function init() {}\n")
    assert resources.find_script("task_allocation.bzz") == Path("task_allocation.bzz")
    assert resources.find_script("nope.bzz") == Path("nope.bzz")
    assert resources.find_script(tmp_path / "x.bzz") == tmp_path / "x.bzz"
