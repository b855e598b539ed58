"""`fieldkit sitl`: N simulated autopilots, N real nodes and a radio relay on this machine."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from fieldkit import resources
from fieldkit.cli.errors import fail
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
from fieldkit.cli.output import count_states, out_dir, progress_bar, wrote
from fieldkit.cli.updates import release_for, split_versions, update_outcome


def sitl_cmd(
    robots: Annotated[int, typer.Option("--robots", help="Number of robots (ids 1..N).")],
    script: Annotated[Path, typer.Option("--script", help="The behavior, a .bzz file.")],
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            help="Directory for summary.json, log.txt, trajectories.csv, plot.png, robotN/.",
        ),
    ],
    profile: Annotated[str, typer.Option("--profile", help="Device profile.")] = "solo",
    drop: Annotated[float, typer.Option("--drop", help="Radio frame loss, 0..1.")] = 0.0,
    seconds: Annotated[float, typer.Option("--seconds", help="Seconds to run.")] = 60.0,
    include: Annotated[
        list[Path] | None, typer.Option("-I", "--include", help="Extra include directory.")
    ] = None,
    command: CommandOption = None,
    seed: Annotated[
        int, typer.Option("--seed", help="Seed of the radio's drops and of the nodes' scripts.")
    ] = 0,
    home: HomeOption = None,
    set_: SetOption = None,
    update: UpdateOption = None,
    security: SecurityOption = None,
    keys: KeysOption = None,
    record: Annotated[
        Path | None,
        typer.Option(
            "--record",
            metavar="DIR",
            help="Each node records its flight as a rosbag, DIR/robot{ID} (fieldkit replay).",
        ),
    ] = None,
    ros1: Annotated[
        bool, typer.Option("--ros1", help="With --record: ROS 1 bags, DIR/robot{ID}.bag.")
    ] = False,
) -> None:
    """Run SCRIPT on N real nodes against simulated autopilots, over a simulated radio."""
    import bvm
    from bvm.errors import BuzzCompileError
    from fieldkit.errors import FieldkitError
    from fieldkit.robot.profiles import ProfileError, load_profile
    from fieldkit.sitl import SitlConfig, SitlUpdate, run

    commands = parse_commands(command)  # first: a command line that does not parse is exit 2
    sets = parse_sets(set_)
    home_ll = parse_home(home)
    updates = parse_updates(update)
    if len(updates) > 1:
        raise fail(
            f"--update given {len(updates)} times: sitl sends one update per run\n"
            "hint: `fieldkit sim run` takes several"
        )
    for u in updates:
        if not 1 <= u.robot <= robots:
            raise fail(f"--update at robot {u.robot}: robots are 1..{robots}")
        if u.t >= seconds:
            raise fail(f"--update at {u.t:g} s: the run is {seconds:g} s long (see --seconds)")
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
    if keys is not None:
        load_keys(keys)  # a wrong, missing or world-readable key: said now, naming the file
    # --update makes keys of its own when none are given: such a run has keys too.
    mode = security_mode(security, keys is not None or bool(updates), prof.radio.security)
    dirs = [str(d) for d in include or []] or [str(script.resolve().parent)]
    if script.suffix != ".bo":
        # Compile once here: a broken script is one `error: path:line:col` line, not N nodes
        # that fail to start and a summary of None states.
        try:
            bvm.compile_file(script, include_dirs=dirs)
        except BuzzCompileError as e:
            raise fail(e) from None
    sitl_update = None
    for u in updates:  # compiled and tried before any node starts: a bad one is never sent
        sitl_update = SitlUpdate(u.t, release_for(u, dirs, profile), u.robot, u.script.name)
    out_dir(out)  # an --out that is a file fails here, with `error:`
    if record is not None:
        out_dir(record, "--record")
        suffix = ".bag" if ros1 else ""
        taken = [
            f"robot{i}{suffix}"
            for i in range(1, robots + 1)
            if (record / f"robot{i}{suffix}").exists()
        ]
        if taken:
            raise fail(f"--record {record}: {', '.join(taken)} exist already\n"
                       f"hint: record to a new directory")  # fmt: skip
    warn_if_insecure(mode)
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
        home=home_ll,
        sets=sets,
        update=sitl_update,
        security=mode,
        keys=keys,
        record=record,
        ros1=ros1,
    )
    with progress_bar(f"SITL: {robots} robots", round(seconds)) as advance:
        try:
            summary = run(cfg, progress=lambda done, total: advance(round(done), round(total)))
        except (OSError, FieldkitError) as e:  # no pty, no process, keys, an unwritable result
            raise fail(e) from None
    for name in ("summary.json", "log.txt", "trajectories.csv", "plot.png"):
        wrote(out / name)
    for err in summary["errors"]:
        typer.echo(f"robot {err['robot']}: {err['error']}", err=True)
    typer.echo(_sitl_line(summary, out))
    # An honest exit (issue 13): a node that did not run to the end, or whose script error
    # left its robot in the failsafe, fails the run.
    problems = []
    missing = summary["not_finished"]
    if missing:
        problems.append(f"{_robots(missing)} did not run to the end (see {out}/robotN/log.txt)")
    failed = summary["in_failsafe"]
    if failed:
        first = next(e for e in summary["errors"] if e["robot"] in failed)
        verb = "its" if len(failed) == 1 else "their"
        problems.append(
            f"{_robots(failed)} ended in {verb} failsafe after a script error: "
            f"robot {first['robot']}: {first['error']}"
        )
    finished = [k for k in summary["script_versions"] if int(k) not in missing]
    split = split_versions(summary["script_versions"], finished)
    if split:
        problems.append(
            f"the swarm ended split between versions {', '.join(split)} "
            "(script_versions in summary.json)"
        )
    if problems:
        raise fail("; ".join(problems))


def _robots(ids: list[int]) -> str:
    """`robot 3` or `robots 3, 5`."""
    return f"robot {ids[0]}" if len(ids) == 1 else f"robots {', '.join(map(str, ids))}"


def _sitl_line(summary: dict[str, Any], out: Path) -> str:
    """`sitl`'s last line: what ran, how it ended, the radio, and where the results are."""
    sent = list(summary["bytes_sent_per_robot"].values())
    relay = summary["relay"]
    errors = len(summary["errors"])
    figures = [
        f"{summary['robots']} robots",
        f"{summary['seconds']:g} s",
        f"final states {count_states(summary['final_states'].values())}",
        f"{errors} error{'s' if errors != 1 else ''}",
        f"bytes sent per robot: mean {sum(sent) / max(1, len(sent)):.0f}, "
        f"max {max(sent, default=0)}",
        f"relay {relay.get('frames', 0)} frames, {relay.get('dropped', 0)} dropped",
    ]
    if summary.get("update") is not None:
        figures.append(update_outcome(summary["update"]))
    return f"sitl: {'; '.join(figures)}; results in {out}"
