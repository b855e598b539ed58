"""systemd unit templates, sysusers.d, tmpfiles.d and udev rules that `fieldkit deploy`
renders (package data `fieldkit.systemd`; see fieldkit/deploy/units.py and docs/deploy.md)."""
