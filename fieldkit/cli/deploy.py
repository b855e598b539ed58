"""`fieldkit deploy --profile NAME`: install this robot's node as a hardened systemd service.

Everything is checked first (the profile, the devices, the script compiled, the keys, the
interpreter, files in the way), so an error leaves nothing written. `--root DIR` stages the
files under DIR (no root needed, no command run: an SD card's root, a test's directory);
without it deploy needs root and a running systemd, installs under /, makes the user, and
starts the node, waiting for its READY. See docs/deploy.md.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from fieldkit import resources
from fieldkit.cli.errors import fail, usage_error
from fieldkit.cli.output import wrote

if TYPE_CHECKING:
    from fieldkit.deploy.install import Installer


def deploy_cmd(
    profile: Annotated[
        str | None,
        typer.Option("--profile", help="Device profile (a shipped name, or a .toml file)."),
    ] = None,
    root: Annotated[
        Path | None,
        typer.Option(
            "--root",
            metavar="DIR",
            help="Install under DIR instead of / (staging: no root needed, nothing run).",
        ),
    ] = None,
    script: Annotated[
        Path | None,
        typer.Option(
            "--script",
            help="The behavior, a .bzz (with its includes) or a .bo: checked, then installed "
            "to seed the node's state directory.",
        ),
    ] = None,
    robot_id: Annotated[
        int | None,
        typer.Option("--robot-id", help="This robot's id (default: the profile's source)."),
    ] = None,
    autopilot: Annotated[
        str | None,
        typer.Option(
            "--autopilot",
            metavar="DEV_OR_URL",
            help="The autopilot's serial device, or a pymavlink URL (udpin:0.0.0.0:14550); "
            "default: /dev/autopilot with the profile's USB id, else the profile's.",
        ),
    ] = None,
    radio: Annotated[
        str | None,
        typer.Option(
            "--radio",
            metavar="URL",
            help="Radio URL as for `fieldkit node` (serial:///dev/ttyUSB0?baud=230400&api=2, "
            "udp://HOST:PORT, none); default: /dev/xbee with the profile's USB id, else the "
            "profile's.",
        ),
    ] = None,
    gps: Annotated[
        str | None,
        typer.Option(
            "--gps",
            metavar="DEV",
            help="A Clearpath base's GPS receiver (a serial device); default: /dev/gps with "
            "the profile's [usb] gps id, else the profile's [gps] port.",
        ),
    ] = None,
    dji_app_id: Annotated[
        int | None,
        typer.Option(
            "--dji-app-id",
            metavar="N",
            help="An M100 (flavour dji): the developer's app id, from DJI's developer site.",
        ),
    ] = None,
    dji_app_key_file: Annotated[
        Path | None,
        typer.Option(
            "--dji-app-key-file",
            metavar="FILE",
            help="An M100: a file (mode 0600) holding the app key, 64 hex digits; installed "
            "as /etc/fieldkit/dji-app-key, 0600, the service's.",
        ),
    ] = None,
    keys: Annotated[
        Path | None,
        typer.Option(
            "--keys",
            metavar="DIR",
            help="Install the robot's keys from DIR: operator.pub and swarm.key (never "
            "operator.key); the node then runs signed.",
        ),
    ] = None,
    originator: Annotated[
        bool,
        typer.Option(
            "--originator",
            help="Also install the update monitor: a signed patch on each save of the script.",
        ),
    ] = False,
    operator_keys: Annotated[
        Path | None,
        typer.Option(
            "--operator-keys",
            metavar="DIR",
            help="With --originator: the operator's keys, operator.key included.",
        ),
    ] = None,
    dry_run: Annotated[
        bool,
        typer.Option("--dry-run", help="Print every file and command; change nothing."),
    ] = False,
    uninstall: Annotated[
        bool,
        typer.Option(
            "--uninstall",
            help="Remove what deploy installed (state and recordings stay, unless --purge).",
        ),
    ] = False,
    purge: Annotated[
        bool,
        typer.Option(
            "--purge",
            help="With --uninstall: remove /var/lib/fieldkit and /var/log/fieldkit too.",
        ),
    ] = False,
) -> None:
    """Install this robot's node as a hardened systemd service (or stage it under --root)."""
    from bvm.errors import BuzzCompileError, BuzzLoadError
    from fieldkit.deploy.deployment import deploy, system_owners
    from fieldkit.deploy.deployment import dry_run as dry
    from fieldkit.deploy.deployment import uninstall as remove
    from fieldkit.deploy.install import Installer
    from fieldkit.deploy.plan import Machine, Options, make_plan
    from fieldkit.deploy.systemctl import Systemctl, systemd_missing
    from fieldkit.errors import FieldkitError

    if purge and not uninstall:
        raise usage_error("--purge goes with --uninstall")
    if not uninstall and profile is None:
        raise usage_error("Missing option '--profile'")
    live = root is None
    if live and not dry_run:  # a dry run changes nothing: anyone may look
        _check_live(systemd_missing())
    target = Path("/") if root is None else root
    if root is not None and root.exists() and not root.is_dir():
        raise fail(f"--root {root}: not a directory")

    def warn(text: str) -> None:
        """A warning line on stderr."""
        typer.echo(f"warning: {text}", err=True)

    def say(text: str) -> None:
        """A progress line on stderr (stdout has the summary, or the dry run)."""
        typer.echo(text, err=True)

    installer = Installer(target, owners=system_owners if live else None, warn=warn)
    systemctl = Systemctl(say) if live else None
    try:
        if uninstall:
            if dry_run:
                _dry_uninstall(installer)
                return
            changes = remove(installer, systemctl, purge)
            if changes is None:
                typer.echo(f"deploy: nothing to uninstall under {target} (no manifest)")
                return
            for path in changes.removed:
                say(f"removed {path}")
            for note in changes.kept:
                warn(f"kept {note}")
            for path in changes.left:
                say(f"kept {path} (state and recordings: --purge removes them)")
            typer.echo(
                f"deploy: uninstalled from {target}: {len(changes.removed)} removed, "
                f"{len(changes.kept)} kept"
            )
            return
        assert profile is not None
        options = Options(
            profile=profile,
            script=resources.find_script(script) if script is not None else None,
            robot_id=robot_id,
            autopilot=autopilot,
            radio=radio,
            gps=gps,
            keys=keys,
            dji_app_id=dji_app_id,
            dji_app_key_file=dji_app_key_file,
            originator=originator,
            operator_keys=operator_keys,
        )
        plan = make_plan(options, Machine(staging=not live))
        for text in plan.warnings:
            warn(text)
        if dry_run:
            dry(plan, installer, live, typer.echo)
            return
        if root is not None:
            try:
                root.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise fail(f"--root {root}: cannot create: {e.strerror or e}") from None
        changes = deploy(plan, installer, systemctl)
    except (FieldkitError, OSError, BuzzCompileError) as e:
        raise fail(e) from None  # (a compile error says FILE:LINE:COL itself)
    except BuzzLoadError as e:
        raise fail(e, script) from None
    for path in changes.written:
        wrote(path)
    for path in changes.removed:
        say(f"removed {path}")
    running = " and running" if live else ""
    typer.echo(
        f"deploy: {', '.join(plan.units)} ({plan.profile.name} profile, {plan.robot_id}) "
        f"installed{running} under {target}: {len(changes.written)} files "
        f"written, {changes.unchanged} unchanged, {len(changes.removed)} removed"
    )


def _check_live(missing_systemd: str | None) -> None:
    """Without --root: root, and a running systemd."""
    if os.geteuid() != 0:
        raise fail(
            "deploy installs a system service: run as root, or stage with --root DIR "
            "(then copy DIR onto the robot's root)"
        )
    if missing_systemd is not None:
        raise fail(
            f"{missing_systemd}: deploy installs a systemd service\nhint: stage the files "
            "with --root DIR on a machine without systemd"
        )


def _dry_uninstall(installer: Installer) -> None:
    """What --uninstall would remove."""
    manifest = installer.manifest()
    if manifest is None:
        typer.echo(f"nothing to uninstall under {installer.root} (no manifest)")
        return
    for p in sorted(manifest.files) + sorted(manifest.links):
        typer.echo(f"remove {installer.path(p)}")
    for p in sorted(manifest.dirs, reverse=True):
        typer.echo(f"remove {installer.path(p)} (if empty)")


__all__ = ["deploy_cmd"]
