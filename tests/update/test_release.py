"""A release: the three files of one script version, named by its bytecode's hash."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

import bvm
from fieldkit.update.release import MAX_RELEASE_BYTES, Release, ReleaseError

SOURCE = "function init() { x = 1 }\nfunction step() {\n  x = x + 1\n}\n"


def test_a_release_round_trips_through_files_and_keeps_its_error_positions(
    tmp_path: Path,
) -> None:
    program = bvm.compile_source(SOURCE, "s.bzz")
    release = Release.from_program(program)
    assert release.hash == hashlib.sha256(program.bytecode).hexdigest()
    assert release.bdb and release.bpos
    release.write(tmp_path / "v.bo")
    again = Release.read(tmp_path / "v.bo")
    assert again == release
    loaded = again.program("v.bo")
    assert loaded.srcmap is not None
    assert loaded.bytecode == program.bytecode


def test_writing_a_release_without_a_source_map_removes_a_stale_one(tmp_path: Path) -> None:
    release = Release.from_program(bvm.compile_source(SOURCE, "s.bzz"))
    release.write(tmp_path / "v.bo")
    Release(release.bo, release.bdb).write(tmp_path / "v.bo")
    assert not (tmp_path / "v.bpos").exists()
    assert Release.read(tmp_path / "v.bo").bpos == b""


def test_a_release_larger_than_any_script_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ReleaseError, match="more than any script"):
        Release(b"\0" * (MAX_RELEASE_BYTES + 1))
    big = tmp_path / "big.bo"
    big.write_bytes(b"\0" * (MAX_RELEASE_BYTES + 1))
    with pytest.raises(ReleaseError, match="big.bo: larger than any script"):
        Release.read(big)
    with pytest.raises(ReleaseError, match="cannot read"):
        Release.read(tmp_path / "missing.bo")
