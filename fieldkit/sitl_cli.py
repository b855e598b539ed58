"""`fieldkit sitl`: N simulated autopilots, N real nodes and a radio relay on this machine."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def _fail(message: str) -> typer.Exit:
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(1)


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
    seed: Annotated[int, typer.Option("--seed", help="Seed of the radio's drops.")] = 0,
) -> None:
    """Run SCRIPT on N real nodes against simulated autopilots, over a simulated radio."""
    from fieldkit.profiles import ProfileError, load_profile
    from fieldkit.sim.progress import progress_bar
    from fieldkit.sitl import SitlConfig, run

    if not 1 <= robots <= 64:
        raise _fail(f"--robots must be 1..64 (one process each), got {robots}")
    if not 0.0 <= drop <= 1.0:
        raise _fail(f"--drop must be a probability in [0, 1], got {drop}")
    if not seconds > 0:
        raise _fail(f"--seconds must be > 0, got {seconds}")
    if not script.is_file():
        raise _fail(f"--script {script}: no such file")
    try:
        prof = load_profile(profile)
    except (ProfileError, OSError) as e:
        raise _fail(str(e)) from None
    from fieldkit.errors import ConfigError
    from fieldkit.robot.rc import RcCommand

    commands = []
    for text in command or []:
        try:
            c = RcCommand.parse(text)
        except ConfigError as e:
            raise _fail(str(e)) from None
        if not 1 <= c.robot <= robots:
            raise _fail(f"--command {text!r}: robots are 1..{robots}")
        commands.append(c)
    dirs = [str(d) for d in include or []] or [str(script.resolve().parent)]
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
