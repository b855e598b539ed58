"""The thin layer between deploy and systemd: the commands a live install runs, in order,
and the wait for the node's READY or failure.

Every command is a plain program found on PATH (systemctl, systemd-sysusers,
systemd-tmpfiles, udevadm), run with its output captured: a test puts recording fakes of
them first on PATH, since a test machine's PID 1 need not be systemd.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from fieldkit.deploy import DeployError, layout

#: Present when systemd is PID 1 (sd_booted()'s test).
SYSTEMD_RUNTIME_DIR = Path("/run/systemd/system")

#: The programs a live deploy runs.
TOOLS = ("systemctl", "systemd-sysusers", "systemd-tmpfiles", "udevadm")

#: How long deploy waits for the node's READY (or failure) after starting it: the unit's
#: own start timeout is the bound that matters; this one only keeps deploy from hanging.
WAIT_S = 180.0
#: How often it asks systemd meanwhile.
POLL_S = 0.5

Command = list[str]


def systemd_missing(runtime_dir: Path = SYSTEMD_RUNTIME_DIR, path: str | None = None) -> str | None:
    """Why a live deploy cannot run here (systemd not PID 1, a tool missing), or None."""
    if not runtime_dir.is_dir():
        return f"systemd is not running on this machine ({runtime_dir} does not exist)"
    for tool in TOOLS:
        if shutil.which(tool, path=path) is None:
            searched = path if path is not None else os.environ.get("PATH", "")
            return f"{tool} not found (PATH={searched})"
    return None


def sysusers_command() -> Command:
    """Before the files: the fieldkit user (files are given to it), from the sysusers.d text
    on stdin as the file it replaces, the way a package creates its user before installing
    its files."""
    return ["systemd-sysusers", f"--replace={layout.SYSUSERS}", "-"]


def after_files(units: Sequence[str], udev: bool, changed: bool) -> list[Command]:
    """After the files: directories, udev, systemd's reload, the units (re)started."""
    commands = [["systemd-tmpfiles", "--create", str(layout.TMPFILES)]]
    if udev:
        commands += [
            ["udevadm", "control", "--reload"],
            ["udevadm", "trigger", "--action=add", "--subsystem-match=tty"],
            ["udevadm", "settle", "--timeout=30"],
        ]
    commands.append(["systemctl", "daemon-reload"])
    if changed:  # a running node takes the new files only when restarted
        commands.append(["systemctl", "try-restart", *units])
    commands.append(["systemctl", "enable", "--now", *units])
    return commands


def before_removal(units: Sequence[str]) -> list[Command]:
    """Before uninstalling: the units stopped (the node's safe stop) and disabled."""
    return [["systemctl", "disable", "--now", *units]]


def after_removal(udev: bool) -> list[Command]:
    """After uninstalling: systemd and udev forget the removed files."""
    commands = [["systemctl", "daemon-reload"]]
    if udev:
        commands.append(["udevadm", "control", "--reload"])
    return commands


def status_command(unit: str) -> Command:
    """What the status line comes from."""
    return ["systemctl", "show", "-p", "ActiveState,SubState,StatusText", unit]


@dataclass(frozen=True)
class UnitState:
    """A unit's state, as `systemctl show` tells it."""

    active: str  # ActiveState: active, activating, failed, inactive, ...
    sub: str  # SubState: running, start, auto-restart, dead, ...
    status: str  # StatusText: what the node last said (STATUS=)

    @property
    def line(self) -> str:
        """One line for the operator."""
        status = f": {self.status}" if self.status else ""
        return f"{self.active} ({self.sub}){status}"

    @property
    def ready(self) -> bool:
        """Started: for Type=notify, READY=1 was received."""
        return self.active == "active"

    @property
    def failed(self) -> bool:
        """Failed, or failed and waiting to be restarted."""
        return self.active == "failed" or self.sub in ("auto-restart", "failed")


class Systemctl:
    """Runs the commands (output captured; a failure is a DeployError with its stderr)."""

    def __init__(
        self,
        say: Callable[[str], None],
        *,
        env: Mapping[str, str] | None = None,
        sleep: Callable[[float], None] = time.sleep,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """`say` takes a line per command run; `env` is the commands' environment."""
        self.say = say
        self.env = dict(env) if env is not None else None
        self.sleep = sleep
        self.clock = clock

    def run(self, command: Sequence[str], stdin: str | None = None) -> str:
        """Run one command (`stdin` its input); its stdout."""
        self.say(f"run: {' '.join(command)}")
        try:
            done = subprocess.run(
                list(command),
                input=stdin if stdin is not None else "",
                capture_output=True,
                text=True,
                env=self.env,
                check=False,
            )
        except OSError as e:
            raise DeployError(f"`{' '.join(command)}`: {e.strerror or e}") from None
        if done.returncode != 0:
            detail = (done.stderr or done.stdout).strip()
            raise DeployError(
                f"`{' '.join(command)}` failed (exit {done.returncode})"
                + (f": {detail}" if detail else "")
            )
        return done.stdout

    def run_all(self, commands: Sequence[Sequence[str]]) -> None:
        """Run each command in turn; the first failure stops."""
        for command in commands:
            self.run(command)

    def state(self, unit: str) -> UnitState:
        """The unit's state now."""
        fields = {}
        for line in self.run_quiet(status_command(unit)).splitlines():
            key, _, value = line.partition("=")
            fields[key] = value
        return UnitState(
            fields.get("ActiveState", ""), fields.get("SubState", ""), fields.get("StatusText", "")
        )

    def run_quiet(self, command: Sequence[str]) -> str:
        """`run` without its line (a poll would repeat it)."""
        say, self.say = self.say, lambda _: None
        try:
            return self.run(command)
        finally:
            self.say = say

    def wait_ready(self, unit: str, timeout_s: float = WAIT_S) -> UnitState:
        """Wait (bounded) for the unit's READY; DeployError if it fails or never gets there.
        Each new state is said as the status line."""
        deadline = self.clock() + timeout_s
        last = None
        while True:
            state = self.state(unit)
            if state != last:
                self.say(f"{unit}: {state.line}")
                last = state
            if state.ready:
                return state
            if state.failed:
                raise DeployError(
                    f"{unit} did not start: {state.line}\nhint: `journalctl -u {unit}` says "
                    f"why; `systemctl status {unit}`"
                )
            if self.clock() >= deadline:
                raise DeployError(
                    f"{unit} not ready after {timeout_s:g} s: {state.line}\nhint: it may "
                    f"still be waiting for the autopilot or a GPS fix: `journalctl -u {unit} -f`"
                )
            self.sleep(POLL_S)


__all__ = [
    "POLL_S",
    "SYSTEMD_RUNTIME_DIR",
    "Systemctl",
    "TOOLS",
    "UnitState",
    "WAIT_S",
    "after_files",
    "after_removal",
    "sysusers_command",
    "before_removal",
    "status_command",
    "systemd_missing",
]
