"""`fieldkit sitl`: N simulated autopilots, N real nodes and a radio relay on this machine."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from fieldkit import resources
from fieldkit.cli.errors import fail, usage_error
from fieldkit.cli.output import out_dir, progress_bar, wrote


def sitl_cmd(
    robots: Annotated[int, typer.Option("--robots", help="Number of robots (ids 1..N).")],
    script: Annotated[Path, typer.Option("--script", help="The behavior, a .bzz file.")],
    out: Annotated[Path, typer.Option("--out", help="Directory for summary.json and logs.")],
    profile: Annotated[str, typer.Option("--profile", help="Device profile.")] = "solo",
    drop: Annotated[float, typer.Option("--drop", help="Radio frame loss, 0..1.")] = 0.0,
    seconds: Annotated[float, typer.Option("--seconds", help="Seconds to run.")] = 60.0,
    include: Annotated[
        list[Path] | None, typer.Option("-I", "--include", help="Extra include directory.")
    ] = None,
    command: Annotated[
        list[str] | None,
        typer.Option("--command", help="T:ROBOT:CODE[:P...]: a remote-control code at second T."),
    ] = None,
    seed: Annotated[
        int, typer.Option("--seed", help="Seed of the radio's drops and of the nodes' scripts.")
    ] = 0,
) -> None:
    """Run SCRIPT on N real nodes against simulated autopilots, over a simulated radio."""
    import bvm
    from bvm.errors import BuzzCompileError
    from fieldkit.errors import ConfigError
    from fieldkit.robot.profiles import ProfileError, load_profile
    from fieldkit.robot.rc import RcCommand
    from fieldkit.sitl import SitlConfig, run

    commands = []
    for text in command or []:  # first: a command line that does not parse is exit 2
        try:
            commands.append(RcCommand.parse(text))
        except ConfigError as e:
            raise usage_error(str(e)) from None
    for text, c in zip(command or [], commands, strict=True):
        if not 1 <= c.robot <= robots:
            raise fail(f"--command {text!r}: robots are 1..{robots}")
    if not 1 <= robots <= 64:
        raise fail(f"--robots must be 1..64 (one process each), got {robots}")
    if not 0.0 <= drop <= 1.0:
        raise fail(f"--drop must be a probability in [0, 1], got {drop}")
    if not 0 < seconds <= 1e6:  # (inf would overflow the progress count, nan never end)
        raise fail(f"--seconds must be > 0 and at most 1e6, got {seconds}")
    script = resources.find_script(script)
    if not script.is_file():
        raise fail(f"--script {script}: no such file")
    try:
        prof = load_profile(profile)
    except (ProfileError, OSError) as e:
        raise fail(e) from None
    dirs = [str(d) for d in include or []] or [str(script.resolve().parent)]
    if script.suffix != ".bo":
        # Compile once here: a broken script is one `error: path:line:col` line, not N nodes
        # that fail to start and a summary of None states.
        try:
            bvm.compile_file(script, include_dirs=dirs)
        except BuzzCompileError as e:
            raise fail(e) from None
    out_dir(out)  # an --out that is a file fails here, with `error:`
    cfg = SitlConfig(
        script=script.resolve(),
        robots=robots,
        out=out,
        profile=prof,
        drop=drop,
        seconds=seconds,
        seed=seed,
        commands=commands,
        include_dirs=dirs,
    )
    with progress_bar(f"SITL: {robots} robots", round(seconds)) as advance:
        summary = run(cfg, progress=lambda done, total: advance(round(done), round(total)))
    states = summary["final_states"]
    typer.echo(f"{robots} robots, {seconds:g} s: final states {states}")
    sent = summary["bytes_sent_per_robot"]
    typer.echo(f"bytes sent per robot: {sent}")
    for err in summary["errors"]:
        typer.echo(f"robot {err['robot']}: {err['error']}", err=True)
    wrote(out / "summary.json")
    missing = [rid for rid, state in states.items() if state is None]
    if missing:  # a node that did not run to the end fails the run (issue 13's honest exit)
        raise fail(f"robots {', '.join(missing)} did not run to the end: see {out}/robotN/log.txt")
