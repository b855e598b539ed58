"""`fieldkit doctor`: the field preflight, one line per check, a fix under each failure."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from fieldkit.cli.errors import UsageProblem, fail, usage_error
from fieldkit.cli.node import node_options
from fieldkit.cli.options import parse_commands, parse_sets
from fieldkit.deploy.layout import CONFIG

if TYPE_CHECKING:
    from fieldkit.deploy.doctor import Settings


def load_settings(path: Path) -> Settings:
    """The config file as `fieldkit node --config FILE` reads it (`node_options`, with
    nothing on the command line), as the checks need it; NodeConfigError lists every
    problem, the ones `node_options` would stop at included."""
    from fieldkit.deploy.doctor import Settings
    from fieldkit.node.config import NODE_KEYS, NodeConfigError, load_config

    loaded = load_config(path)
    # What node_options would report (and exit on) is found first, to be reported as
    # this check's lines rather than as an `error:` of its own.
    problems = []
    for key, parse in (("set", parse_sets), ("command", parse_commands)):
        try:
            parse(loaded.node.get(key))
        except UsageProblem as e:
            problems.append(f"{path}: node.{key}: {e.message}")
    if "profile" not in loaded.node:
        problems.append(f'{path}: node.profile: missing (e.g. profile = "solo")')
    if problems:
        raise NodeConfigError(problems)
    try:
        # Doctor reads: a missing record folder is the disk check's to report, not to make.
        o = node_options(dict.fromkeys(NODE_KEYS), path, make_dirs=False)
    except UsageProblem as e:  # none left by the checks above: kept as a config problem
        raise NodeConfigError([f"{path}: {e.message}"]) from None
    return Settings(
        config=path,
        profile=o.profile,
        script=o.script,
        autopilot=o.autopilot,
        radio=o.radio,
        include=tuple(o.include),
        state_dir=o.state_dir,
        keys=o.keys,
        security=o.security,
        record_dir=None if o.record is None else o.record.parent,
        record_max_mb=o.record_max_mb,
        gps=o.gps,
        dji_app=None if o.dji is None else (o.dji.app_id, o.dji.app_key),
    )


def doctor_cmd(
    config: Annotated[
        Path,
        typer.Option("--config", metavar="FILE", help="The node's config file to check."),
    ] = Path(CONFIG),
    timeout: Annotated[
        float,
        typer.Option(
            "--timeout",
            metavar="S",
            help="Longest wait, in seconds, for the autopilot's heartbeat, then for its GPS "
            "fix (the profile's gps_fix_timeout_s if shorter), and for the radio.",
        ),
    ] = 10.0,
    skip: Annotated[
        list[str] | None,
        typer.Option(
            "--skip",
            metavar="NAME",
            help="Do not run check NAME (repeatable): config, profile, serial, autopilot, "
            "radio, script, keys, clock, disk.",
        ),
    ] = None,
) -> None:
    """Check this robot before a mission: config, profile, serial devices, autopilot
    (heartbeat, GPS fix), radio, script, keys, clock and disk; exit 1 if any check fails."""
    from fieldkit.deploy.doctor import CHECKS, Outcome, run_checks

    for name in skip or []:
        if name not in CHECKS:
            raise usage_error(f"--skip {name!r}: no such check (checks: {', '.join(CHECKS)})")
    if not (math.isfinite(timeout) and timeout > 0):
        raise fail(f"--timeout must be > 0, got {timeout:g}")
    results = []
    for result in run_checks(config, load_settings, timeout=timeout, skip=set(skip or [])):
        for line in result.lines():
            typer.echo(line)
        results.append(result)
    outcome = Outcome(tuple(results))
    skipped = outcome.skipped_for_failure
    if outcome.failed:
        names = ", ".join(r.name for r in outcome.failed)
        also = f"; {len(skipped)} skipped because of it" if skipped else ""
        raise fail(
            f"{len(outcome.failed)} of {len(results)} checks failed for {config}: {names}{also}"
            "\nhint: do what each `fix:` line above says, then run fieldkit doctor again"
        )
    passed = sum(r.passed for r in results)
    aside = [r.name for r in results if not r.passed]
    also = f", {len(aside)} skipped ({', '.join(aside)})" if aside else ""
    typer.echo(f"{passed} of {len(results)} checks passed{also}, none failed")


__all__ = ["doctor_cmd", "load_settings"]
