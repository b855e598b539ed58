"""The script `fieldkit deploy --script` installs: checked with bvm before anything is
written, then the files that install it under /var/lib/fieldkit/script/.

A `.bzz` is compiled (a compile error is `file:line:col`), then installed with every file it
includes: those in the script's folder keep their place beside it (so `include
"include/states.bzz"` still finds its file), those found elsewhere (an -I directory, the
working directory) go into script/include/, an include directory of the node. The copy is
compiled again as the service will compile it (from a scratch copy of that layout, with no
BUZZ_INCLUDE_PATH) and must give the same bytecode, or deploy refuses. A `.bo` is loaded
(bytecode and debug info checked) and installed with its `.bdb` and `.bpos`.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

import bvm
from bvm.lexer import included_files
from fieldkit.deploy import DeployError, layout
from fieldkit.update.release import SIDECARS, Release, ReleaseError


@dataclass(frozen=True)
class ScriptInstall:
    """A checked script and the files that install it."""

    source: Path  # the file given
    target: PurePosixPath  # the installed script (the node's `script`)
    files: dict[PurePosixPath, bytes]  # every file to install, by target path
    has_includes: bool
    bytecode_hash: str  # the hex SHA-256 of its bytecode: the version's name

    @property
    def is_source(self) -> bool:
        """A .bzz (which the update monitor can watch), not a .bo."""
        return self.target.suffix == ".bzz"


def prepare(path: Path) -> ScriptInstall:
    """Check `path` (a .bzz or a .bo) and collect its files; BuzzCompileError, BuzzLoadError
    or DeployError say what is wrong."""
    if path.suffix == ".bo":
        return _bytecode(path)
    if path.suffix != ".bzz":
        raise DeployError(f"{path}: a script is a .bzz (Buzz source) or a .bo (bytecode)")
    return _source(path)


def _bytecode(path: Path) -> ScriptInstall:
    """A .bo with its sidecars, loaded as the node loads it."""
    try:
        release = Release.read(path)
        release.program(str(path))
    except ReleaseError as e:
        raise DeployError(str(e)) from None
    except bvm.BuzzLoadError as e:
        raise DeployError(f"{path}: {e}") from None
    target = layout.SCRIPT_DIR / path.name
    files = {target: release.bo}
    for suffix, data in zip(SIDECARS, (release.bdb, release.bpos), strict=True):
        if data:
            files[target.with_suffix(suffix)] = data
    return ScriptInstall(path, target, files, False, release.hash)


def _source(path: Path) -> ScriptInstall:
    """A .bzz and its includes, compiled here and again from the layout they install to."""
    program = bvm.compile_file(path)
    opened = included_files(path.read_bytes(), str(path))
    home = Path(os.path.realpath(path.parent))
    files: dict[PurePosixPath, bytes] = {}
    origin: dict[PurePosixPath, str] = {}
    target = layout.SCRIPT_DIR / path.name
    for i, name in enumerate(opened):
        real = Path(os.path.realpath(name))
        if i == 0:
            where = target
        elif real.is_relative_to(home):
            where = layout.SCRIPT_DIR.joinpath(*real.relative_to(home).parts)
        else:
            where = layout.INCLUDE_DIR / real.name
        if where in origin and origin[where] != str(real):
            raise DeployError(
                f"{path}: includes {origin[where]} and {real}, which would both install as "
                f"{where}\nhint: give the included files different names"
            )
        origin[where] = str(real)
        try:
            files[where] = real.read_bytes()
        except OSError as e:
            raise DeployError(f"{real}: cannot read: {e.strerror or e}") from None
    has_includes = len(files) > 1
    again = _compile_installed(files, target, has_includes)
    if again != program.bytecode:
        raise DeployError(
            f"{path}: its installed copy under {layout.SCRIPT_DIR} compiles to other bytecode "
            "(an include found through the working directory or BUZZ_INCLUDE_PATH, whose name "
            "does not find it from there)\nhint: keep the included files beside the script, "
            "or in a folder under it, and include them by that relative name"
        )
    return ScriptInstall(path, target, files, has_includes, Release(program.bytecode).hash)


def _compile_installed(
    files: dict[PurePosixPath, bytes], target: PurePosixPath, has_includes: bool
) -> bytes:
    """The bytecode of the installed layout, compiled as the service compiles it: from its
    working directory (/var/lib/fieldkit), with the include directory, no BUZZ_INCLUDE_PATH."""
    with tempfile.TemporaryDirectory(prefix="fieldkit-deploy-") as scratch:
        root = Path(scratch)
        for where, data in files.items():
            staged = layout.under(root, where)
            staged.parent.mkdir(parents=True, exist_ok=True)
            staged.write_bytes(data)
        workdir = layout.under(root, layout.STATE_DIR)
        include = [str(layout.under(root, layout.INCLUDE_DIR))] if has_includes else []
        with _as_the_service(workdir):
            try:
                return bvm.compile_file(layout.under(root, target), include).bytecode
            except bvm.BuzzCompileError as e:
                raise DeployError(
                    f"{target.name}: its installed copy does not compile: "
                    f"{_unstaged(str(e), root)}\nhint: keep the included files beside the "
                    "script, or in a folder under it, and include them by that relative name"
                ) from None


@contextmanager
def _as_the_service(workdir: Path) -> Iterator[None]:
    """Run in `workdir` with no BUZZ_INCLUDE_PATH, as the service does (then restore both)."""
    old_cwd = os.getcwd()
    old_path = os.environ.pop("BUZZ_INCLUDE_PATH", None)
    try:
        os.chdir(workdir)
        yield
    finally:
        os.chdir(old_cwd)
        if old_path is not None:
            os.environ["BUZZ_INCLUDE_PATH"] = old_path


def _unstaged(text: str, root: Path) -> str:
    """A message about the scratch copy, with the robot's paths in it."""
    return text.replace(str(root), "")


__all__ = ["ScriptInstall", "prepare"]
