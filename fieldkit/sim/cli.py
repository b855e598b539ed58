"""`fieldkit sim ...`: run a script on a simulated swarm, or one of the paper's experiments."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from bvm.errors import BuzzCompileError

sim_app = typer.Typer(
    help="Simulate a swarm: many robots, each running the script, over an imperfect radio.",
    no_args_is_help=True,
)


def _fail(message: str) -> typer.Exit:
    typer.echo(message, err=True)
    return typer.Exit(1)


def write_json(path: Path, data: object) -> None:
    """Write `data` as stable, human-readable JSON (sorted keys: same run, same bytes)."""
    path.write_text(json.dumps(data, indent=2, sort_keys=True) + "\n", encoding="utf-8")


@sim_app.command("run")
def run_cmd(
    script: Annotated[Path, typer.Argument(help="The behavior, a .bzz file.")],
    robots: Annotated[int, typer.Option("--robots", help="Number of robots (ids 1..N).")],
    out: Annotated[Path, typer.Option("--out", help="Directory for summary.json and logs.")],
    include: Annotated[
        list[Path] | None, typer.Option("-I", "--include", help="Extra include directory.")
    ] = None,
    drop: Annotated[float, typer.Option("--drop", help="Per-link payload loss, 0..1.")] = 0.0,
    latency: Annotated[int, typer.Option("--latency", help="Radio latency in ticks.")] = 1,
    range_m: Annotated[float, typer.Option("--range", help="Radio range in metres.")] = 500.0,
    seconds: Annotated[float, typer.Option("--seconds", help="Simulated seconds.")] = 60.0,
    seed: Annotated[int, typer.Option("--seed", help="Seed of every random draw.")] = 0,
    command: Annotated[
        list[str] | None,
        typer.Option(
            "--command",
            help="T:ROBOT:CODE[:P...] hands a remote-control code to a robot at second T "
            "(22 takeoff, 21 land, 900 task allocation, 901 coverage, 16 waypoint).",
        ),
    ] = None,
    profile: Annotated[str, typer.Option("--profile", help="Device profile.")] = "solo",
) -> None:
    """Run SCRIPT on N simulated robots and write OUT/summary.json."""
    from fieldkit.sim.simulator import ConfigError, RcCommand, SimConfig, Simulation

    try:
        config = SimConfig(
            script=script,
            robots=robots,
            drop=drop,
            latency=latency,
            range_m=range_m,
            seconds=seconds,
            seed=seed,
            commands=[RcCommand.parse(c) for c in command or []],
            profile=profile,
            include_dirs=[str(d) for d in include or []],
        )
        sim = Simulation(config)
    except ConfigError as e:
        raise _fail(f"error: {e}") from None
    except BuzzCompileError as e:
        raise _fail(str(e)) from None
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise _fail(f"--out {out}: cannot create: {e.strerror}") from None
    from fieldkit.sim.progress import progress_bar

    with progress_bar(f"simulating {robots} robots", round(seconds * 10)) as advance:
        sim.run(progress=advance)
    summary = sim.summary()
    write_json(out / "summary.json", summary)
    with (out / "log.txt").open("w", encoding="utf-8") as f:
        for robot in sim.robots.values():
            for line in robot.log:
                f.write(line + "\n")
    for err in summary["errors"]:  # type: ignore[union-attr]
        typer.echo(f"robot {err['robot']}: {err['error']}", err=True)
