"""What `sim run --update` and `sitl --update` share: the new version's compile and trial,
and the words for what became of the update in the command's last line."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import typer

from fieldkit import resources
from fieldkit.cli.errors import fail
from fieldkit.cli.options import UpdateAt

if TYPE_CHECKING:
    from fieldkit.update.release import Release


def release_for(u: UpdateAt, include_dirs: Sequence[str], profile: str | Sequence[str]) -> Release:
    """An `--update`'s new version, compiled and passed through its trial as `fieldkit
    update` does (a version that fails either is never sent: exit 1, saying why), on
    `profile` (a name, or a team's profiles, each tried)."""
    from fieldkit.errors import FieldkitError
    from fieldkit.sim.trial import trial
    from fieldkit.update.pipeline import build

    try:
        script = resources.find_script(u.script)
        profiles = [profile] if isinstance(profile, str) else list(profile)
        release = build(script, include_dirs, test=lambda p: trial(p, profiles))
    except FieldkitError as e:
        raise fail(f"--update {u.t:g}:{u.script}: {e}") from None
    typer.echo(
        f"update: {u.script} compiled and passed its trial; robot {u.robot} gets it at {u.t:g} s"
    )
    return release


def update_outcome(update: Mapping[str, object]) -> str:
    """A summary's `update` in words: switched by when, rolled back and why, or neither."""
    v = update["version"]
    if update["rolled_back"]:
        return f"update to version {v} rolled back ({update['reason']})"
    if update["all_switched_s"] is not None:
        return f"update to version {v}: every robot switched by {update['all_switched_s']} s"
    return f"update to version {v}: not every robot switched"


def split_versions(versions: Mapping[str, str | None], finished: Sequence[str]) -> list[str]:
    """The distinct versions (hash prefixes) the `finished` robots ended on, if more than
    one: a split swarm; else []."""
    ended = sorted({v for rid, v in versions.items() if rid in finished and v})
    return [v[:12] for v in ended] if len(ended) > 1 else []


__all__ = ["release_for", "split_versions", "update_outcome"]
