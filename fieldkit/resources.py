"""The data fieldkit ships: device profiles, Buzz scripts, task graphs, example scripts and
the systemd templates `fieldkit deploy` renders.

They are package data, found through `importlib.resources`, so they are there wherever fieldkit
is installed: in a checkout (`pip install -e .`), where the packages `fieldkit.device_profiles`,
`fieldkit.buzz_scripts` and `fieldkit.systemd` are the repository's top-level
`device_profiles/`, `buzz_scripts/` and `systemd/` folders (setup.py maps them), and in a
wheel, where they are copied under `fieldkit/`. This module is the one place that knows where
they are.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

PROFILES_PACKAGE = "fieldkit.device_profiles"
"""The package whose files are the shipped device profiles (`<name>.toml`)."""
SCRIPTS_PACKAGE = "fieldkit.buzz_scripts"
"""The package whose files are the shipped Buzz scripts, with `include/`, `graphs/`, `examples/`."""
SYSTEMD_PACKAGE = "fieldkit.systemd"
"""The package whose files are the templates of `fieldkit deploy` (units, sysusers, udev)."""


def _directory(package: str) -> Path:
    """The folder of a data package, as a real path (fieldkit is never run from a zip)."""
    root = resources.files(package)
    if not isinstance(root, Path):
        raise RuntimeError(f"{package}: installed as {type(root).__name__}, not as plain files")
    return root


def profile_dir() -> Path:
    """The folder of the shipped device profiles (`solo.toml`, `husky.toml`, ...)."""
    return _directory(PROFILES_PACKAGE)


def script_dir() -> Path:
    """The folder of the shipped Buzz scripts (`task_allocation.bzz`, `coverage.bzz`, ...)."""
    return _directory(SCRIPTS_PACKAGE)


def systemd_dir() -> Path:
    """The folder of the systemd templates (`fieldkit-node.service`, `fieldkit.sysusers`, ...)."""
    return _directory(SYSTEMD_PACKAGE)


def graph_dir() -> Path:
    """The folder of the shipped task graphs (`P.graph`, `O.graph`, ...)."""
    return script_dir() / "graphs"


def example_dir() -> Path:
    """The folder of the shipped example scripts (`hello.bzz`)."""
    return script_dir() / "examples"


def find_script(path: str | Path) -> Path:
    """A script argument as a file: the path if it exists, else the shipped script of that name."""
    # A relative path that names no file from the working directory is looked up among the
    # shipped scripts, so `task_allocation.bzz` or `examples/hello.bzz` work from anywhere;
    # otherwise the path comes back unchanged and opening it reports the missing file.
    # `buzz_scripts/X.bzz`, as the README and docs write it, works outside the checkout too.
    given = Path(path)
    if given.exists() or given.is_absolute():
        return given
    inside = given.parts[1:] if given.parts[:1] == ("buzz_scripts",) else given.parts
    bundled = script_dir().joinpath(*inside) if inside else given
    return bundled if bundled.is_file() else given


__all__ = [
    "PROFILES_PACKAGE",
    "SCRIPTS_PACKAGE",
    "SYSTEMD_PACKAGE",
    "example_dir",
    "find_script",
    "graph_dir",
    "profile_dir",
    "script_dir",
    "systemd_dir",
]
