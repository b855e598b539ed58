"""One script version's files, as an update carries them: bytecode, debug info, source map.

A version is named by the hex SHA-256 of its bytecode (`Release.hash`): the name robots
gossip, patches build on and `summary.json` reports. The debug info and the source map
travel with it, so that after an update a script error still points at the right line.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import bvm
from bvm import srcmap
from fieldkit.errors import FieldkitError

#: A release (bytecode, debug info and source map together) larger than any script could be.
MAX_RELEASE_BYTES = 1024 * 1024

#: The sidecars beside a .bo, in the order a release holds them.
SIDECARS = (".bdb", ".bpos")

#: Beside a release's .bo: the version number it was sent as (one line, an integer).
VERSION_SUFFIX = ".version"


class ReleaseError(FieldkitError, ValueError):
    """Files that do not make a release: what and where."""


def sha256_hex(data: bytes) -> str:
    """The hex SHA-256 of `data`."""
    return hashlib.sha256(data).hexdigest()


@dataclass(frozen=True)
class Release:
    """One script version's files: bytecode, debug info, source map (b"" when absent)."""

    bo: bytes
    bdb: bytes = b""
    bpos: bytes = b""

    def __post_init__(self) -> None:
        size = len(self.bo) + len(self.bdb) + len(self.bpos)
        if size > MAX_RELEASE_BYTES:
            raise ReleaseError(
                f"a release of {size} bytes, more than any script ({MAX_RELEASE_BYTES})"
            )

    @cached_property
    def hash(self) -> str:
        """The hex SHA-256 of the bytecode: this version's name everywhere."""
        return sha256_hex(self.bo)

    @property
    def size(self) -> int:
        """Bytes of the three files together."""
        return len(self.bo) + len(self.bdb) + len(self.bpos)

    @classmethod
    def from_program(cls, program: bvm.Program) -> Release:
        """The release of a compiled program (its source map encoded as a .bpos)."""
        smap = program.srcmap
        bpos = srcmap.encode(smap, program.bytecode) if smap is not None else b""
        return cls(program.bytecode, program.debug, bpos)

    def program(self, path: str = "<update>") -> bvm.Program:
        """The loaded program; `bvm.BuzzLoadError` if the bytes are not one."""
        program = bvm.Program(self.bo, self.bdb, path)
        if self.bpos:
            program.srcmap = srcmap.decode(self.bpos, self.bo, path)
        return program

    @classmethod
    def read(cls, bo_path: Path) -> Release:
        """X.bo, with the X.bdb and X.bpos beside it when they exist."""
        parts = [_read(bo_path)]
        for suffix in SIDECARS:
            side = bo_path.with_suffix(suffix)
            parts.append(_read(side) if side.exists() else b"")
        return cls(*parts)

    def write(self, bo_path: Path) -> None:
        """X.bo and its sidecars, each written whole then renamed into place (a sidecar
        this release lacks is removed, so no stale one is read with the new bytecode)."""
        write_atomic(bo_path, self.bo)
        for suffix, data in zip(SIDECARS, (self.bdb, self.bpos), strict=True):
            side = bo_path.with_suffix(suffix)
            if data:
                write_atomic(side, data)
            else:
                side.unlink(missing_ok=True)


def _read(path: Path) -> bytes:
    try:
        with path.open("rb") as f:
            data = f.read(MAX_RELEASE_BYTES + 1)
    except OSError as e:
        raise ReleaseError(f"{path}: cannot read: {e.strerror or e}") from None
    if len(data) > MAX_RELEASE_BYTES:
        raise ReleaseError(f"{path}: larger than any script ({MAX_RELEASE_BYTES} bytes)")
    return data


def read_version(bo_path: Path, hint: str) -> int:
    """The version number recorded beside a .bo (X.version), 0 when there is none;
    ReleaseError (with `hint`) if the file holds anything but one integer."""
    path = bo_path.with_suffix(VERSION_SUFFIX)
    try:
        text = path.read_text(encoding="ascii", errors="replace").strip()
    except FileNotFoundError:
        return 0
    except OSError as e:
        raise ReleaseError(f"{path}: cannot read: {e.strerror or e}") from None
    if not text.isdigit():
        raise ReleaseError(
            f"{path}: expected a version number (one integer), got {text[:40]!r}\n  hint: {hint}"
        )
    return int(text)


def write_version(bo_path: Path, version: int) -> Path:
    """Record `version` beside a .bo (X.version, written whole then renamed); its path."""
    path = bo_path.with_suffix(VERSION_SUFFIX)
    write_atomic(path, f"{version}\n".encode())
    return path


def write_atomic(path: Path, data: bytes) -> None:
    """Write `path` so that a crash leaves the old file or the new one, never a mix: a
    temporary file beside it, fsync, rename over, fsync the directory."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with tmp.open("wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    fsync_dir(path.parent)


def fsync_dir(path: Path) -> None:
    """Make a directory's entries (a rename, a new file) survive a power cut."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


__all__ = [
    "MAX_RELEASE_BYTES",
    "Release",
    "ReleaseError",
    "SIDECARS",
    "fsync_dir",
    "VERSION_SUFFIX",
    "read_version",
    "write_version",
    "sha256_hex",
    "write_atomic",
]
