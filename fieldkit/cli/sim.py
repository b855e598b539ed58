"""`fieldkit sim ...`: run a script on a simulated swarm, or one of the paper's experiments."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, cast

import typer

from bvm.errors import BuzzCompileError
from fieldkit import resources
from fieldkit.cli.errors import fail, usage_error
from fieldkit.cli.options import (
    CommandOption,
    HomeOption,
    KeysOption,
    SecurityOption,
    SetOption,
    UpdateOption,
    load_keys,
    parse_commands,
    parse_home,
    parse_sets,
    parse_updates,
    security_mode,
    warn_if_insecure,
)
from fieldkit.cli.output import count_states, out_dir, progress_bar, write_json, wrote
from fieldkit.cli.signals import stop_on_signals
from fieldkit.cli.updates import release_for, update_outcome

if TYPE_CHECKING:
    from contextlib import AbstractContextManager

    from dask.distributed import Client

    from fieldkit.sim.experiments import Plan
    from fieldkit.sim.simulator import SimConfig
    from fieldkit.sim.tracks import SimRecorder

app = typer.Typer(
    help="Simulate a swarm: many robots, each running the script, over an imperfect radio.",
    no_args_is_help=True,
)


def run_cmd(
    script: Annotated[Path, typer.Argument(help="The behavior, a .bzz file.")],
    robots: Annotated[int, typer.Option("--robots", help="Number of robots (ids 1..N).")],
    out: Annotated[
        Path,
        typer.Option(
            "--out", help="Directory for summary.json, log.txt, trajectories.csv, plot.png."
        ),
    ],
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
    seconds: Annotated[
        float | None,
        typer.Option(
            "--seconds",
            help="Simulated seconds (default 60; with --ground, until Ctrl-C).",
            show_default=False,
        ),
    ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of every random draw.")] = 0,
    command: CommandOption = None,
    profile: Annotated[str, typer.Option("--profile", help="Device profile.")] = "solo",
    home: HomeOption = None,
    spacing: Annotated[
        float | None,
        typer.Option(
            "--spacing",
            metavar="M",
            help="Metres between neighbouring start positions on the grid (default 3, "
            "wider for swarms too big to all hear each other at 3 m: see docs/cli.md).",
            show_default=False,
        ),
    ] = None,
    set_: SetOption = None,
    update: UpdateOption = None,
    security: SecurityOption = None,
    keys: KeysOption = None,
    record: Annotated[
        Path | None,
        typer.Option(
            "--record",
            metavar="DIR",
            help="Record every robot's flight as a rosbag, DIR/robot{ID} (fieldkit replay).",
        ),
    ] = None,
    ros1: Annotated[
        bool, typer.Option("--ros1", help="With --record: ROS 1 bags, DIR/robot{ID}.bag.")
    ] = False,
    attack: Annotated[
        str | None,
        typer.Option(
            "--attack",
            metavar="KIND[,KIND...]",
            help="Add a hostile radio (no keys) in the swarm's middle: replay, forge, "
            "command, flood. summary.json's security says what it sent and what was accepted.",
        ),
    ] = None,
    ground: Annotated[
        bool,
        typer.Option(
            "--ground",
            help="Run in real time with a ground station beside robot 1: its page on "
            "127.0.0.1 and a UDP gateway onto the simulated radio (docs/ground.md).",
        ),
    ] = False,
    ground_port: Annotated[
        int,
        typer.Option("--ground-port", metavar="P", help="With --ground: the page's port."),
    ] = 8080,
    workers: Annotated[
        int | None,
        typer.Option(
            "--workers",
            metavar="W",
            help="Step the swarm in W local worker processes, robots split by where they "
            "start; the same results as one process (with --scheduler: W parts on the cluster).",
            show_default=False,
        ),
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(
            "--scheduler",
            metavar="ADDRESS",
            help="Step the swarm on the workers of a running Dask cluster (tcp://host:8786).",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Run SCRIPT on N simulated robots: OUT/summary.json, log.txt, trajectories.csv, plot.png."""
    from fieldkit.errors import FieldkitError
    from fieldkit.sim.simulator import (
        CROWD,
        ConfigError,
        SimConfig,
        Simulation,
        default_spacing,
        in_range,
    )
    from fieldkit.sim.updates import SimUpdate

    attacks = parse_attacks(attack)
    _check_split(
        workers,
        scheduler,
        {"--ground": ground, "--record": record, "--update": update, "--attack": attack},
    )
    commands = parse_commands(command)
    globals_ = parse_sets(set_)
    lat, lon = parse_home(home)
    updates = parse_updates(update)
    dirs = [str(d) for d in include or []]
    sim_updates = [
        SimUpdate(u.t, release_for(u, dirs, profile), u.robot, u.script.name) for u in updates
    ]
    if ground:
        from fieldkit.cli.ground_sim import ground_keys

        keys = ground_keys(out, keys)
    robot_keys = load_keys(keys) if keys is not None else None
    mode = security_mode(security, robot_keys is not None, _profile_security(profile))
    if seconds is None:
        seconds = None if ground else 60.0
    try:
        config = SimConfig(
            script=resources.find_script(script),
            robots=robots,
            drop=drop,
            burst=burst,
            latency=latency,
            range_m=range_m,
            seconds=1e6 if seconds is None else seconds,
            seed=seed,
            commands=commands,
            profile=profile,
            include_dirs=[str(d) for d in include or []],
            spacing_m=default_spacing(robots, range_m) if spacing is None else spacing,
            origin=(lat, lon, 0.0),
            globals=dict(globals_),
            updates=sim_updates,
            security=mode,
            swarm_key=None if robot_keys is None else robot_keys.swarm_key,
            attacks=attacks,
            operator_pub=None if robot_keys is None else robot_keys.operator_pub,
            update_agents=ground,
        )
        sim = Simulation(config) if workers is None and scheduler is None else None
    except (ConfigError, BuzzCompileError) as e:
        raise fail(e) from None
    crowd = in_range(robots, range_m, config.spacing_m)
    if crowd > 1.25 * CROWD:  # the default grid itself has about CROWD (rounding: a few more)
        # Every tick costs about robots x crowd receptions and neighbour entries.
        typer.echo(
            f"warning: about {crowd:.0f} robots in each robot's {range_m:g} m range "
            f"(--spacing {config.spacing_m:g}): a large swarm runs slowly; a wider "
            "--spacing or a shorter --range keeps it near the default's "
            f"{CROWD}",
            err=True,
        )
    if sim is None:
        warn_if_insecure(mode)
        _run_split(config, workers, scheduler, out, script, globals_, (lat, lon))
        return
    out_dir(out)
    bags: list[Path] = []
    if record is not None:
        out_dir(record, "--record")
        try:
            bags = sim.record(record, ros1=ros1)
        except FieldkitError as e:  # a bag of that name exists already
            raise fail(e) from None
    warn_if_insecure(mode)
    from fieldkit.sim.tracks import SimRecorder

    recorder = SimRecorder(sim)
    try:
        if ground:
            from fieldkit.cli.ground_sim import run_with_ground

            run_with_ground(sim, keys, seconds, ground_port, globals_, recorder.after_step)
        else:
            with (
                stop_on_signals() as stop,
                progress_bar(f"simulating {robots} robots", config.ticks) as advance,
            ):
                sim.run(progress=advance, after_step=recorder.after_step, stop=stop)
    finally:
        sim.close_recording()
    for bag in bags:
        wrote(bag)
    summary = sim.summary()
    _write_run(summary, sim.log, recorder, config, out, script, globals_, (lat, lon))
    if not ground and sim.tick < config.ticks:  # only a stop ends a run before its time
        raise _stopped(summary, config.seconds)


def _check_split(workers: int | None, scheduler: str | None, others: dict[str, object]) -> None:
    """Refuse `--workers`/`--scheduler` with a bad count or with what a split swarm cannot do
    (each of these watches or alters every robot's radio inside the tick)."""
    if workers is None and scheduler is None:
        return
    flag = "--workers" if workers is not None else "--scheduler"
    if workers is not None and not 1 <= workers <= 1024:
        raise fail(f"--workers must be between 1 and 1024, got {workers}")
    for option, given in others.items():
        if given:
            raise fail(f"{flag} cannot be combined with {option}")


def _run_split(
    config: SimConfig,
    workers: int | None,
    scheduler: str | None,
    out: Path,
    script: Path,
    globals_: Mapping[str, object],
    home: tuple[float, float],
) -> None:
    """`sim run` with the robots stepped by workers: the same files as one process."""
    from fieldkit.sim.distributed import DistributedError, DistributedSimulation
    from fieldkit.sim.simulator import ConfigError
    from fieldkit.sim.tracks import SimRecorder

    try:
        sim = DistributedSimulation(config, workers=workers, scheduler=scheduler)
    except (ConfigError, BuzzCompileError, DistributedError) as e:
        raise fail(e) from None
    out_dir(out)
    try:
        recorder = SimRecorder(sim)
        parts = len(sim.parts)
        label = f"simulating {config.robots} robots on {parts} worker{'s' if parts > 1 else ''}"
        with stop_on_signals() as stop, progress_bar(label, config.ticks) as advance:
            sim.run(progress=advance, after_step=recorder.after_step, stop=stop)
        summary = sim.summary()
    except DistributedError as e:
        raise fail(e) from None
    finally:
        sim.close()
    _write_run(summary, sim.log, recorder, config, out, script, globals_, home)
    if sim.tick < config.ticks:  # only a stop ends a run before its time
        raise _stopped(summary, config.seconds)


def _stopped(summary: Mapping[str, object], seconds: float) -> typer.Exit:
    """The error of a run of fixed length that Ctrl-C or SIGTERM ended early (a signal after
    its last tick ends nothing): its results are written, and the command fails, saying how
    far it got (a script must not take it for a whole run)."""
    done = cast(float, summary["seconds_simulated"])
    return fail(f"interrupted at {done:g} s of {seconds:g} s: the run so far is written above")


def _write_run(
    summary: dict[str, object],
    log: list[str],
    recorder: SimRecorder,
    config: SimConfig,
    out: Path,
    script: Path,
    globals_: Mapping[str, object],
    home: tuple[float, float],
) -> None:
    """Write a run's summary.json, log.txt, trajectories.csv and plot.png and say how it
    ended (exit 1 if robots ended in their failsafe)."""
    from fieldkit.sim.tracks import write_tracks

    summary["home"] = list(home)
    summary["spacing_m"] = config.spacing_m
    summary["globals"] = globals_
    write_json(out / "summary.json", summary)
    log_path = out / "log.txt"
    try:
        with log_path.open("w", encoding="utf-8") as f:
            for line in log:
                f.write(line + "\n")
        written = write_tracks(
            recorder.tracks, out, f"sim run {script.name}, {config.robots} robots"
        )
    except OSError as e:
        raise fail(f"{e.filename or out}: cannot write: {e.strerror or e}") from None
    for path in (log_path, *written):
        wrote(path)
    errors = cast(list[dict[str, object]], summary["errors"])
    for err in errors:
        typer.echo(f"robot {err['robot']} at {err['t_s']} s: {err['error']}", err=True)
    typer.echo(_run_line(summary, out))
    failed = cast(list[int], summary["in_failsafe"])
    if failed:  # a robot left in its failsafe fails the run (a recovered error does not)
        first = next(e for e in errors if e["robot"] in failed)
        who = (
            f"robot {failed[0]} ended in its failsafe"
            if len(failed) == 1
            else f"robots {', '.join(map(str, failed))} ended in their failsafe"
        )
        raise fail(f"{who} after a script error: robot {first['robot']}: {first['error']}")


def parse_attacks(text: str | None) -> tuple[str, ...]:
    """`--attack KIND[,KIND...]` (an unknown kind is a command-line error, exit 2)."""
    from fieldkit.sim.attacker import ATTACKS

    if text is None:
        return ()
    kinds = tuple(k.strip() for k in text.split(","))
    unknown = [k for k in kinds if k not in ATTACKS]
    if unknown or not kinds:
        raise usage_error(f"--attack {text!r}: the kinds are {','.join(ATTACKS)}")
    return kinds


def _swarm_key(security: str | None, keys: Path | None) -> bytes | None:
    """The swarm key an experiment signs its bundles with (None: `none`)."""
    robot_keys = load_keys(keys) if keys is not None else None
    mode = security_mode(security, robot_keys is not None)
    return robot_keys.swarm_key if robot_keys is not None and mode == "signed" else None


def _profile_security(profile: str) -> str | None:
    """The profile's `[radio] security`, if it loads (a bad profile is reported later)."""
    from fieldkit.robot.profiles import ProfileError, load_profile

    try:
        return load_profile(profile).radio.security
    except (ProfileError, OSError):
        return None


def _run_line(summary: dict[str, object], out: Path) -> str:
    """`sim run`'s last line: what ran, how it ended, and where the results are."""
    states = cast(dict[str, str | None], summary["final_states"])
    errors = cast(list[object], summary["errors"])
    figures = [
        f"{summary['robots']} robots",
        f"{summary['seconds_simulated']:g} s simulated",
        f"final states {count_states(states.values())}",
        f"{len(errors)} script error{'s' if len(errors) != 1 else ''}",
        f"bundles max {summary['max_bundle_bytes']} B, mean {summary['mean_bundle_bytes']} B",
    ]
    update = cast(dict[str, object] | None, summary.get("update"))
    if update is not None:
        figures.append(update_outcome(update))
    return f"sim run: {'; '.join(figures)}; results in {out}"


# ------------------------------------------------------------------ experiments


def _plan(
    name: str,
    robots: list[int] | None,
    drops: list[float] | None,
    runs: int | None,
    seed: int | None,
    seconds: float | None,
    script: Path | None,
    swarm_key: bytes | None = None,
    burst: float | None = None,
) -> Plan:
    """Validate one experiment's parameters into a Plan; errors exit 1 with `error: ...`."""
    from fieldkit.sim.experiments import ExperimentError, check_script, make_plan

    try:
        plan = make_plan(
            name,
            robots=robots,
            drops=drops,
            runs=runs,
            seed=seed or 0,
            seconds=seconds,
            script=script,
            swarm_key=swarm_key,
            burst=burst,
        )
        check_script(plan)
    except ExperimentError as e:
        raise fail(e) from None
    return plan


def _report(name: str, summary: dict[str, object], out: Path) -> None:
    """One line per experiment on stdout: where it went and its headline figures."""
    figures = [
        f"max bundle {summary['max_bundle_bytes']} B",
        f"mean bundle {summary['mean_bundle_bytes']} B",
        f"mean on air {summary['mean_air_bytes_per_step']} B/step",
    ]
    if "joined_fraction" in summary:
        fractions = cast(list[float], summary["joined_fraction"])
        figures.insert(0, f"JOINED at the end: min {min(fractions):.2f}")
    if "tasks_held_fraction" in summary:
        held = cast(list[float], summary["tasks_held_fraction"])
        recovered = cast(list[float | None], summary["recovered_s"])
        times = [t for t in recovered if t is not None]
        slowest = f", the slowest in {max(times):g} s" if times else ""
        figures.insert(0, f"tasks held at the end: min {min(held):.2f}")
        figures.insert(1, f"recovered in {len(times)} of {len(recovered)} runs{slowest}")
    if "final_centroid_distance_m" in summary:
        distances = cast(list[float], summary["final_centroid_distance_m"])
        figures.insert(0, f"final centroid distance: max {max(distances):.2f} m")
    typer.echo(f"{name}: {out} ({'; '.join(figures)})")
    for err in cast(list[dict[str, object]], summary["errors"]):
        typer.echo(
            f"{name}: robots={err['robots']} drop={err['drop']} run={err['run']}: "
            f"robot {err['robot']}: {err['error']}",
            err=True,
        )


# The options `experiment` and `sweep` share, declared once so their help cannot drift apart.
# Typed: a value that does not parse is a usage error (exit 2); `_plan` checks the ranges.
_RunsOption = Annotated[
    int | None, typer.Option("--runs", metavar="K", help="Seeded runs per grid cell.")
]
_SeedOption = Annotated[
    int | None, typer.Option("--seed", metavar="S", help="Seed of run 0 (run k: S+k).")
]
_SecondsOption = Annotated[
    float | None,
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


def experiment_cmd(
    name: Annotated[
        str,
        typer.Argument(
            metavar="NAME",
            help="task-allocation, task-allocation-scale, coverage, coverage-scale or"
            " task-allocation-loss.",
            show_default=False,
        ),
    ],
    out: Annotated[Path, typer.Option("--out", help="Directory for the results.")],
    robots: Annotated[
        int | None, typer.Option("--robots", metavar="N", help="Only this robot count.")
    ] = None,
    drop: Annotated[
        float | None, typer.Option("--drop", metavar="P", help="Only this drop rate, 0..1.")
    ] = None,
    burst: Annotated[
        float | None,
        typer.Option(
            "--burst",
            metavar="L",
            help="Losses in bursts of L ticks on average (Gilbert-Elliott) at each drop rate.",
        ),
    ] = None,
    runs: _RunsOption = None,
    seed: _SeedOption = None,
    seconds: _SecondsOption = None,
    script: _ScriptOption = None,
    security: SecurityOption = None,
    keys: KeysOption = None,
) -> None:
    """Run one of the paper's experiments; write summary.json, CSVs and plots into OUT."""
    plan = _plan(
        name,
        None if robots is None else [robots],
        None if drop is None else [drop],
        runs,
        seed,
        seconds,
        script,
        burst=burst,
    )
    plan = dataclasses.replace(plan, swarm_key=_swarm_key(security, keys))
    out_dir(out)
    warn_if_insecure("none" if plan.swarm_key is None else "signed")
    from fieldkit.sim.experiments import run_plan, write_outputs

    specs = plan.specs()
    total = sum(s.total_ticks for s in specs)
    with progress_bar(f"{name}: {len(specs)} runs", total) as advance:
        results = run_plan(plan, advance)
    summary = write_outputs(plan, results, out)
    _report(name, summary, out)


def sweep_cmd(
    out: Annotated[Path, typer.Option("--out", help="Directory: one subdirectory per experiment.")],
    names: Annotated[
        list[str] | None,
        typer.Argument(
            metavar="NAME", help="Experiments to run (default: all four).", show_default=False
        ),
    ] = None,
    robots: Annotated[
        list[int] | None,
        typer.Option("--robots", metavar="N", help="Only these robot counts (repeatable)."),
    ] = None,
    drop: Annotated[
        list[float] | None,
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
        int | None, typer.Option("--workers", metavar="W", help="Local cluster workers [2].")
    ] = None,
    threads: Annotated[
        bool, typer.Option("--threads", help="Local cluster of threads instead of processes.")
    ] = False,
) -> None:
    """Run a grid of experiments in parallel on Dask; OUT/NAME/ as `experiment` writes it."""
    from fieldkit.sim.experiments import write_outputs
    from fieldkit.sim.experiments.catalogue import PAPER_EXPERIMENTS
    from fieldkit.sim.sweep import DEFAULT_WORKERS, SweepError, cluster_client, sweep

    n_workers = DEFAULT_WORKERS if workers is None else workers
    if not 1 <= n_workers <= 1024:
        raise fail(f"--workers must be between 1 and 1024, got {n_workers}")
    chosen = names or list(PAPER_EXPERIMENTS)
    plans = [
        _plan(name, robots or None, drop or None, runs, seed, seconds, script)
        for name in dict.fromkeys(chosen)
    ]
    out_dir(out)
    total = sum(len(p.specs()) for p in plans)

    def client() -> AbstractContextManager[Client]:
        return cluster_client(scheduler, n_workers, processes=not threads)

    try:
        with progress_bar(f"sweep: {total} runs", total) as advance:
            grouped = sweep(plans, client, advance)
    except SweepError as e:
        raise fail(e) from None
    for plan, results in zip(plans, grouped, strict=True):
        name = plan.experiment.name
        summary = write_outputs(plan, results, out / name)
        _report(name, summary, out / name)


#: The commands of this group, in the order `fieldkit sim --help` lists them.
app.command("run")(run_cmd)
app.command("experiment")(experiment_cmd)
app.command("sweep")(sweep_cmd)
