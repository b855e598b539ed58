"""A deployment carried out: the files installed under the lock and, on a live system, the
commands around them (the user first, then tmpfiles, udev, systemd, and the wait for the
node's READY); an uninstall the same way round; a dry run that only says all of it."""

from __future__ import annotations

import pwd
from collections.abc import Callable
from pathlib import PurePosixPath

from fieldkit.deploy import DeployError, layout
from fieldkit.deploy.install import Changes, Dir, Entry, Installer, Manifest, Symlink
from fieldkit.deploy.plan import Plan
from fieldkit.deploy.systemctl import (
    Systemctl,
    after_files,
    after_removal,
    before_removal,
    status_command,
    sysusers_command,
)
from fieldkit.deploy.units import sysusers


def system_owners(user: str) -> tuple[int, int]:
    """The fieldkit user's uid and gid, looked up (after systemd-sysusers made it)."""
    try:
        entry = pwd.getpwnam(user)
    except KeyError:
        raise DeployError(
            f"no user {user!r} after systemd-sysusers: {layout.SYSUSERS} should make it"
        ) from None
    return entry.pw_uid, entry.pw_gid


def deploy(plan: Plan, installer: Installer, systemctl: Systemctl | None) -> Changes:
    """Install the plan's files (and, with `systemctl`, make the user, start the units and
    wait for the node's READY). Nothing is written if a file is in the way."""
    problems = installer.conflicts(plan.entries, installer.manifest())
    if problems:
        raise DeployError(
            "\n".join(problems) + "\nhint: move these away (or remove them), then deploy again"
        )
    with installer.locked() as made:
        old = installer.manifest()  # again, under the lock
        _warn_of_what_goes(plan, old, installer)
        if systemctl is not None:
            systemctl.run(sysusers_command(), stdin=sysusers())
        changes = installer.install(plan.entries, old, made)
        _warn_of_the_state(plan, changes, installer)
        if systemctl is not None:
            systemctl.run_all(after_files(plan.units, plan.udev, changes.changed))
            systemctl.wait_ready(layout.NODE_UNIT, timeout_s=plan.node.timeout_start_s + 10)
    return changes


def _warn_of_what_goes(plan: Plan, old: Manifest | None, installer: Installer) -> None:
    """A deploy converges on its options: keys installed before and not given now go, and
    the node then runs unsigned. Said, since that is rarely what one meant."""
    if old is None:
        return
    wanted = {str(e.path) for e in plan.entries}
    for directory, option in (
        (layout.KEYS_DIR, "--keys"),
        (layout.OPERATOR_KEYS_DIR, "--operator-keys"),
    ):
        going = sorted(
            p for p in old.files if PurePosixPath(p).parent == directory and p not in wanted
        )
        if going:
            installer.warn(
                f"removing {', '.join(going)}, installed by the last deploy: give {option} "
                "DIR again to keep them"
            )


def _warn_of_the_state(plan: Plan, changes: Changes, installer: Installer) -> None:
    """A new script only seeds an empty state directory: a robot that ran before keeps
    running its committed version. Said, with the two ways to change it."""
    if plan.script is None or installer.path(plan.script.target) not in changes.written:
        return
    state = installer.path(layout.NODE_STATE_DIR)
    if state.is_dir() and any(state.iterdir()):
        installer.warn(
            f"{state} holds the versions the node ran: it keeps running its committed one, "
            f"not {plan.script.target}; send the new script as an update (fieldkit update), "
            "or start afresh with `fieldkit deploy --uninstall --purge` first"
        )


def uninstall(installer: Installer, systemctl: Systemctl | None, purge: bool) -> Changes | None:
    """Stop and remove what the last deploy installed (None: nothing was installed; with
    `purge`, state and recordings still go)."""
    manifest = installer.manifest()
    if manifest is None:
        changes = installer.uninstall(None, purge)  # what a kill at the very end leaves
        return changes if changes.changed else None
    with installer.locked():
        manifest = installer.manifest() or manifest
        units = _units(manifest)
        if systemctl is not None and units:
            systemctl.run_all(before_removal(units))
        changes = installer.uninstall(manifest, purge)
        if systemctl is not None:
            systemctl.run_all(after_removal(str(layout.UDEV_RULES) in manifest.files))
    return changes


def _units(manifest: Manifest) -> list[str]:
    """The units a manifest installed."""
    return [
        name
        for name in (layout.NODE_UNIT, layout.UPDATE_UNIT)
        if str(layout.UNIT_DIR / name) in manifest.files
    ]


def dry_run(plan: Plan, installer: Installer, live: bool, say: Callable[[str], None]) -> None:
    """Say every file (path, mode, owner, and its text), every directory and symlink, and
    every command a deploy would run; change nothing."""
    manifest = installer.manifest()
    for problem in installer.conflicts(plan.entries, manifest):
        say(f"conflict: {problem}")
    for entry in sorted(plan.entries, key=_order):
        where = installer.path(entry.path)
        state = installer.status(entry, manifest)
        if isinstance(entry, Dir):
            say(f"dir  {where} (mode {entry.mode:04o}{_owner(entry.owner)}, {state})")
        elif isinstance(entry, Symlink):
            say(f"link {where} -> {entry.target} ({state})")
        else:
            say(f"file {where} (mode {entry.mode:04o}{_owner(entry.owner)}, {state})")
            if entry.secret is not None:
                say(f"    <secret: {entry.secret}>")
            elif entry.is_text:
                for line in entry.data.decode().splitlines():
                    say(f"    | {line}")
            else:
                say(f"    ({len(entry.data)} bytes, sha256 {entry.sha256})")
    say(f"file {installer.path(layout.MANIFEST)} (mode 0644: the manifest of the above)")
    if not live:
        say("(no commands: --root stages the files only)")
        return
    say(f"run: {' '.join(sysusers_command())} (before the files)")
    for command in after_files(plan.units, plan.udev, changed=True):
        note = " (if files changed)" if command[1] == "try-restart" else ""
        say(f"run: {' '.join(command)}{note}")
    say(f"run: {' '.join(status_command(layout.NODE_UNIT))} (until active or failed)")


def _owner(owner: str | None) -> str:
    return f", owner {owner}" if owner else ""


def _order(entry: Entry) -> tuple[int, PurePosixPath]:
    """Directories first, by depth, then files and symlinks by path."""
    return (0 if isinstance(entry, Dir) else 1, entry.path)


__all__ = ["deploy", "dry_run", "system_owners", "uninstall"]
