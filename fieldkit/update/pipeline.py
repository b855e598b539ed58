"""The originator's pipeline: compile the new script, test it, and make the signed patch.

    release = build(Path("s.bzz"), ["lib"], test=tester)     # BuildError: which step, why
    data = make_patch_file(release, base, 7, signing_key, swarm_key)

A version that does not compile or fails its test never becomes a release, so it can never
be sent. The test is a callable (`fieldkit.sim.trial.trial` with the profiles in use, in
the command line): this package may not import the simulator, and a test of the pipeline
may give its own.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

import bvm
from fieldkit.errors import FieldkitError
from fieldkit.update.patch import make_update
from fieldkit.update.release import Release

#: What tests a compiled version: its script errors as text (empty: it passed).
Tester = Callable[[bvm.Program], list[str]]


class BuildError(FieldkitError):
    """A new version refused before it became a release: `step` ("compile" or "test") and
    the problems found, each naming its place in the script."""

    def __init__(self, step: str, message: str, problems: Sequence[str]) -> None:
        """`message` is the whole text; `problems` the errors it lists."""
        super().__init__(message)
        self.step = step
        self.problems: tuple[str, ...] = tuple(problems)


class NothingToUpdate(FieldkitError):
    """The new version's bytecode is the one the swarm already runs."""


def build(script: Path, include_dirs: Sequence[str | Path] = (), *, test: Tester) -> Release:
    """Compile `script` (with its include directories) and test it: the new release, or
    `BuildError` saying which step failed and why."""
    try:
        program = bvm.compile_file(script, include_dirs=[str(d) for d in include_dirs])
    except bvm.BuzzCompileError as e:
        # Its text starts with path:line:col, as every Buzz source error is reported.
        raise BuildError("compile", str(e), [str(e)]) from None
    problems = test(program)
    if problems:
        n = len(problems)
        listed = "\n".join(_indent(p) for p in problems)
        raise BuildError(
            "test",
            f"{script}: the new version failed its trial in the simulator with "
            f"{n} script error{'s' if n != 1 else ''}, so it is not released:\n{listed}\n"
            "  hint: fix the script and save it again (`fieldkit sim run` shows the whole run)",
            problems,
        )
    return Release.from_program(program)


def _indent(problem: str) -> str:
    """A problem as one item of a list: its lines indented under a dash."""
    first, *rest = problem.splitlines() or [""]
    return "\n".join([f"  - {first}", *(f"    {line}" for line in rest)])


def make_patch_file(
    new: Release,
    base: Release,
    version: int,
    signing_key: Ed25519PrivateKey,
    swarm_key: bytes,
) -> bytes:
    """The signed, encrypted patch that takes a robot running `base` to `new` as `version`
    (docs/update.md); `NothingToUpdate` if the bytecode did not change."""
    if new.hash == base.hash:
        # A version is named by its bytecode's hash: robots would take the "update" for
        # the version they run. A comment or layout change alone changes only the .bdb.
        raise NothingToUpdate(
            f"the same bytecode as the base ({base.hash[:12]}): nothing to update\n"
            "  hint: a change to comments or layout alone does not change the bytecode"
        )
    return make_update(base, new, version, signing_key, swarm_key)


__all__ = ["BuildError", "NothingToUpdate", "Tester", "build", "make_patch_file"]
