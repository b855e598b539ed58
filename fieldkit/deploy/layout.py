"""Where `fieldkit deploy` puts everything on the robot: the target paths, never prefixed by
`--root` (the files written under `--root DIR` name the robot's own paths inside them)."""

from __future__ import annotations

from pathlib import Path, PurePosixPath

#: The service user and group (sysusers.d), in dialout for the serial ports.
USER = "fieldkit"
SERIAL_GROUP = "dialout"

ETC_DIR = PurePosixPath("/etc/fieldkit")
"""Configuration: read-only to the service."""
CONFIG = ETC_DIR / "fieldkit.toml"
"""The node's config file (`fieldkit node --config`)."""
KEYS_DIR = ETC_DIR / "keys"
"""The robot's keys: operator.pub and swarm.key, never operator.key."""
OPERATOR_KEYS_DIR = ETC_DIR / "operator-keys"
"""An originator's keys (`--originator --operator-keys`): the signing key too."""
DJI_APP_KEY = ETC_DIR / "dji-app-key"
"""An M100's app key (`--dji-app-key-file`): 0600, the fieldkit user's, named by [dji]."""
PROFILES_DIR = ETC_DIR / "profiles"
"""A profile given as a file rather than a shipped name is installed here."""
MANIFEST = ETC_DIR / "deploy-manifest.json"
"""Every file and directory deploy created, with its SHA-256: what `--uninstall` removes."""
LOCK = ETC_DIR / ".deploy.lock"
"""Held (flock) while a deploy or an uninstall runs."""

STATE_DIR = PurePosixPath("/var/lib/fieldkit")
"""The service's state: kept by `--uninstall` unless `--purge`."""
NODE_STATE_DIR = STATE_DIR / "state"
"""The node's version store (`state_dir`): made by the node itself."""
SCRIPT_DIR = STATE_DIR / "script"
"""The script as installed, with its includes (it seeds an empty version store)."""
INCLUDE_DIR = SCRIPT_DIR / "include"
"""Includes found outside the script's folder are installed here (an -I directory)."""
OUTBOX_DIR = STATE_DIR / "outbox"
"""The update monitor's patches and releases (made by its unit's StateDirectory=)."""
OUTBOX_RELEASE = OUTBOX_DIR / "update.bo"
"""The update monitor's base: the latest release, rewritten with each patch."""
OUTBOX_PATCH = OUTBOX_DIR / "update.patch"
"""The latest patch the update monitor wrote."""
LOG_DIR = PurePosixPath("/var/log/fieldkit")
"""Recordings (bags): kept by `--uninstall` unless `--purge`."""
KEPT_DIRS = (STATE_DIR, LOG_DIR)
"""What `--uninstall` leaves in place unless `--purge`."""

UNIT_DIR = PurePosixPath("/etc/systemd/system")
NODE_UNIT = "fieldkit-node.service"
UPDATE_UNIT = "fieldkit-update.service"
WANTS_DIR = UNIT_DIR / "multi-user.target.wants"
"""Where `systemctl enable` puts its symlinks (`WantedBy=multi-user.target`)."""
SYSUSERS = PurePosixPath("/usr/lib/sysusers.d/fieldkit.conf")
TMPFILES = PurePosixPath("/usr/lib/tmpfiles.d/fieldkit.conf")
UDEV_RULES = PurePosixPath("/etc/udev/rules.d/99-fieldkit.rules")

AUTOPILOT_DEVICE = PurePosixPath("/dev/autopilot")
"""The autopilot's serial adapter, named by the udev rule from the profile's USB id."""
RADIO_DEVICE = PurePosixPath("/dev/xbee")
"""The XBee's serial adapter, named by the udev rule from the profile's USB id."""
GPS_DEVICE = PurePosixPath("/dev/gps")
"""A GPS receiver's serial adapter (a Clearpath base's), named by the udev rule."""


def under(root: Path, target: PurePosixPath) -> Path:
    """Where the robot's path `target` is on this machine, with the system at `root`."""
    return root / target.relative_to("/")


__all__ = [
    "AUTOPILOT_DEVICE",
    "CONFIG",
    "DJI_APP_KEY",
    "ETC_DIR",
    "GPS_DEVICE",
    "INCLUDE_DIR",
    "KEPT_DIRS",
    "KEYS_DIR",
    "LOCK",
    "LOG_DIR",
    "MANIFEST",
    "NODE_STATE_DIR",
    "NODE_UNIT",
    "OPERATOR_KEYS_DIR",
    "OUTBOX_DIR",
    "OUTBOX_PATCH",
    "OUTBOX_RELEASE",
    "PROFILES_DIR",
    "RADIO_DEVICE",
    "SCRIPT_DIR",
    "SERIAL_GROUP",
    "STATE_DIR",
    "SYSUSERS",
    "TMPFILES",
    "UDEV_RULES",
    "UNIT_DIR",
    "UPDATE_UNIT",
    "USER",
    "WANTS_DIR",
    "under",
]
