"""What the deploy tests share: a listing of a tree that tells any change, the commands run
in-process and as real processes, and the scripts and keys they deploy."""

from __future__ import annotations

import hashlib
import os
import stat
import subprocess
import sys
from pathlib import Path

from click.testing import Result
from typer.testing import CliRunner

from fieldkit import resources
from fieldkit.cli import app

runner = CliRunner()

#: The shipped example: no includes.
HELLO = resources.example_dir() / "hello.bzz"
#: The shipped task allocation: includes three levels deep, in include/.
TASKS = resources.script_dir() / "task_allocation.bzz"

#: A Debian-like interpreter outside any home: ProtectHome=yes (the Pi's /usr/bin/python3).
SYSTEM_PYTHON = "/usr/bin/python3"

Listing = dict[str, tuple[str, ...]]


def listing(root: Path, mtimes: bool = True) -> Listing:
    """Every entry under `root` (root itself too): its kind, mode, SHA-256 or link target,
    and (with `mtimes`) a file's modification time: whatever deploy could change."""
    out: Listing = {}
    if not root.exists():
        return out
    for path in [root, *sorted(root.rglob("*"))]:
        st = path.lstat()
        rel = str(path.relative_to(root))
        mode = f"{stat.S_IMODE(st.st_mode):04o}"
        if stat.S_ISLNK(st.st_mode):
            out[rel] = ("link", os.readlink(path))
        elif stat.S_ISDIR(st.st_mode):
            out[rel] = ("dir", mode)
        else:
            digest = hashlib.sha256(path.read_bytes()).hexdigest()
            out[rel] = ("file", mode, digest) + ((str(st.st_mtime_ns),) if mtimes else ())
    return out


def dji_app_key(directory: Path, text: str | None = None, mode: int = 0o600) -> Path:
    """A DJI app key file: the simulated M100's test key (or `text`), mode `mode`."""
    from fieldkit.vehicle.sim.dji import TEST_APP_KEY

    path = directory / "dji-app-key.txt"
    path.write_text((TEST_APP_KEY if text is None else text) + "\n")
    path.chmod(mode)
    return path


def m100(key: Path, *more: str | Path) -> tuple[str, ...]:
    """The options of an M100 deployment: the test app id, the key file `key`."""
    from fieldkit.vehicle.sim.dji import TEST_APP_ID

    return ("--profile", "m100", "--robot-id", "2", "--dji-app-id", str(TEST_APP_ID),
            "--dji-app-key-file", str(key), *(str(m) for m in more))  # fmt: skip


#: A Husky: MCU, XBee and GPS receiver, all on USB adapters (three udev rules).
HUSKY = ("--profile", "husky", "--robot-id", "3")


def deploy(*args: str | Path) -> Result:
    """`fieldkit deploy ARGS` in this process."""
    return runner.invoke(app, ["deploy", *(str(a) for a in args)])


def fieldkit(
    *args: str | Path, env: dict[str, str] | None = None, prefix: tuple[str, ...] = ()
) -> subprocess.Popen[str]:
    """`fieldkit ARGS` as a real process (stdout and stderr piped)."""
    environ = {**os.environ, **(env or {})}
    argv = [*prefix, sys.executable, "-m", "fieldkit", *(str(a) for a in args)]
    return subprocess.Popen(
        argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=environ
    )


def errors(stderr: str) -> list[str]:
    """The `error:` lines."""
    return [line for line in stderr.splitlines() if line.startswith("error: ")]
