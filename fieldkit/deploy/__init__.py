"""`fieldkit deploy`: the node as a hardened systemd service on a robot's companion computer.

One concept per module:

* `layout`: where everything goes on the robot (/etc/fieldkit, /var/lib/fieldkit, ...);
* `links`: the node's autopilot and radio as the service opens them (devices, network, udev);
* `units`: the systemd unit, sysusers.d, tmpfiles.d and udev files, rendered from the
  templates of `fieldkit.systemd` (the repository's `systemd/` folder);
* `config_file`: /etc/fieldkit/fieldkit.toml, the file `fieldkit node --config` reads;
* `script`: the script checked with bvm and the files that install it;
* `plan`: every file, directory and command of one deployment, from its options;
* `install`: staging, the manifest, the lock, uninstall (what touches the file system);
* `systemctl`: the thin layer over systemctl, systemd-sysusers, systemd-tmpfiles, udevadm;
* `doctor`: the field preflight (`fieldkit doctor`): the checks an operator runs before a
  mission.

See docs/deploy.md. This package may import `robot` (profiles) and `update` (keys), never
the command line.
"""

from fieldkit.errors import FieldkitError


class DeployError(FieldkitError):
    """A deployment that cannot go ahead: what is wrong, where, and (a `hint:` line) the fix."""


__all__ = ["DeployError"]
