"""`fieldkit sim ...`: run a script on a simulated swarm, or one of the paper's experiments."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from bvm.errors import BuzzCompileError

if TYPE_CHECKING:
    from contextlib import AbstractContextManager

    from dask.distributed import Client

    from fieldkit.sim.experiments import Plan

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
    burst: Annotated[
        float | None,
        typer.Option("--burst", help="Mean loss burst length in ticks (Gilbert-Elliott)."),
    ] = None,
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
            burst=burst,
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


# ------------------------------------------------------------------ experiments


def _int_option(name: str, text: str | None) -> int | None:
    """Parse an integer option ourselves, so a bad value is an `error:` line, exit 1."""
    if text is None:
        return None
    try:
        return int(text)
    except ValueError:
        raise _fail(f"error: {name} must be an integer, got {text!r}") from None


def _float_option(name: str, text: str | None) -> float | None:
    """Parse a number option ourselves (same reason as `_int_option`)."""
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        raise _fail(f"error: {name} must be a number, got {text!r}") from None
    if value != value:  # NaN passes every range check the wrong way
        raise _fail(f"error: {name} must be a number, got {text!r}")
    return value


def _plan(
    name: str,
    robots: list[int] | None,
    drops: list[float] | None,
    runs: str | None,
    seed: str | None,
    seconds: str | None,
    script: Path | None,
) -> Plan:
    """Validate one experiment's parameters into a Plan; errors exit 1 with `error: ...`."""
    from fieldkit.sim.experiments import ExperimentError, check_script, make_plan

    try:
        plan = make_plan(
            name,
            robots=robots,
            drops=drops,
            runs=_int_option("--runs", runs),
            seed=_int_option("--seed", seed) or 0,
            seconds=_float_option("--seconds", seconds),
            script=script,
        )
        check_script(plan)
    except ExperimentError as e:
        raise _fail(f"error: {e}") from None
    return plan


def _mkdir(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise _fail(f"error: --out {out}: cannot create: {e.strerror}") from None


def _report(name: str, summary: dict[str, object], out: Path) -> None:
    """One line per experiment on stdout: where it went and its headline figures."""
    figures = [
        f"max bundle {summary['max_bundle_bytes']} B",
        f"mean bundle {summary['mean_bundle_bytes']} B",
        f"mean on air {summary['mean_air_bytes_per_step']} B/step",
    ]
    if "joined_fraction" in summary:
        fractions = summary["joined_fraction"]
        figures.insert(0, f"JOINED at the end: min {min(fractions):.2f}")  # type: ignore[type-var,arg-type]
    if "final_centroid_distance_m" in summary:
        distances = summary["final_centroid_distance_m"]
        figures.insert(0, f"final centroid distance: max {max(distances):.2f} m")  # type: ignore[type-var,arg-type]
    typer.echo(f"{name}: {out} ({'; '.join(figures)})")
    for err in summary["errors"]:  # type: ignore[union-attr]
        typer.echo(
            f"{name}: robots={err['robots']} drop={err['drop']} run={err['run']}: "
            f"robot {err['robot']}: {err['error']}",
            err=True,
        )


# The options `experiment` and `sweep` share, declared once so their help cannot drift apart.
# They stay text: `_plan` parses them, so a bad value is an `error:` line rather than usage.
_RunsOption = Annotated[
    str | None, typer.Option("--runs", metavar="K", help="Seeded runs per grid cell.")
]
_SeedOption = Annotated[
    str | None, typer.Option("--seed", metavar="S", help="Seed of run 0 (run k: S+k).")
]
_SecondsOption = Annotated[
    str | None,
    typer.Option(
        "--seconds",
        metavar="T",
        help="Simulated seconds per run (default: the experiment's, see docs/results.md).",
    ),
]
_ScriptOption = Annotated[
    Path | None,
    typer.Option(
        "--script",
        help="Behaviour script instead of the shipped one; its directory is the include path.",
    ),
]


@sim_app.command("experiment")
def experiment_cmd(
    name: Annotated[
        str,
        typer.Argument(
            metavar="NAME",
            help="task-allocation, task-allocation-scale, coverage or coverage-scale.",
            show_default=False,
        ),
    ],
    out: Annotated[Path, typer.Option("--out", help="Directory for the results.")],
    robots: Annotated[
        str | None, typer.Option("--robots", metavar="N", help="Only this robot count.")
    ] = None,
    drop: Annotated[
        str | None, typer.Option("--drop", metavar="P", help="Only this drop rate, 0..1.")
    ] = None,
    runs: _RunsOption = None,
    seed: _SeedOption = None,
    seconds: _SecondsOption = None,
    script: _ScriptOption = None,
) -> None:
    """Run one of the paper's experiments; write summary.json, CSVs and plots into OUT."""
    n = _int_option("--robots", robots)
    p = _float_option("--drop", drop)
    plan = _plan(
        name, None if n is None else [n], None if p is None else [p], runs, seed, seconds, script
    )
    _mkdir(out)
    from fieldkit.sim.experiments import run_plan, write_outputs
    from fieldkit.sim.progress import progress_bar

    specs = plan.specs()
    total = sum(s.total_ticks for s in specs)
    with progress_bar(f"{name}: {len(specs)} runs", total) as advance:
        results = run_plan(plan, advance)
    summary = write_outputs(plan, results, out)
    _report(name, summary, out)


@sim_app.command("sweep")
def sweep_cmd(
    out: Annotated[Path, typer.Option("--out", help="Directory: one subdirectory per experiment.")],
    names: Annotated[
        list[str] | None,
        typer.Argument(
            metavar="[NAME]...", help="Experiments to run (default: all four).", show_default=False
        ),
    ] = None,
    robots: Annotated[
        list[str] | None,
        typer.Option("--robots", metavar="N", help="Only these robot counts (repeatable)."),
    ] = None,
    drop: Annotated[
        list[str] | None,
        typer.Option("--drop", metavar="P", help="Only these drop rates (repeatable)."),
    ] = None,
    runs: _RunsOption = None,
    seed: _SeedOption = None,
    seconds: _SecondsOption = None,
    script: _ScriptOption = None,
    scheduler: Annotated[
        str | None,
        typer.Option("--scheduler", help="Address of a running Dask scheduler (tcp://host:8786)."),
    ] = None,
    workers: Annotated[
        str | None, typer.Option("--workers", metavar="W", help="Local cluster workers [2].")
    ] = None,
    threads: Annotated[
        bool, typer.Option("--threads", help="Local cluster of threads instead of processes.")
    ] = False,
) -> None:
    """Run a grid of experiments in parallel on Dask; OUT/NAME/ as `experiment` writes it."""
    from fieldkit.sim.experiments import EXPERIMENTS, write_outputs
    from fieldkit.sim.progress import progress_bar
    from fieldkit.sim.sweep import DEFAULT_WORKERS, SweepError, cluster_client, sweep

    n_workers = _int_option("--workers", workers)
    n_workers = DEFAULT_WORKERS if n_workers is None else n_workers
    if not 1 <= n_workers <= 1024:
        raise _fail(f"error: --workers must be between 1 and 1024, got {n_workers}")
    counts = [_int_option("--robots", r) for r in robots] if robots else None
    drops = [_float_option("--drop", d) for d in drop] if drop else None
    chosen = names or list(EXPERIMENTS)
    plans = [
        _plan(name, counts, drops, runs, seed, seconds, script)  # type: ignore[arg-type]
        for name in dict.fromkeys(chosen)
    ]
    _mkdir(out)
    total = sum(len(p.specs()) for p in plans)

    def client() -> AbstractContextManager[Client]:
        return cluster_client(scheduler, n_workers, processes=not threads)

    try:
        with progress_bar(f"sweep: {total} runs", total) as advance:
            grouped = sweep(plans, client, advance)
    except SweepError as e:
        raise _fail(f"error: {e}") from None
    for plan, results in zip(plans, grouped, strict=True):
        name = plan.experiment.name
        summary = write_outputs(plan, results, out / name)
        _report(name, summary, out / name)
