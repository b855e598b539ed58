"""`fieldkit sitl`: N simulated vehicles, N real nodes and a radio relay on this machine."""

from __future__ import annotations

import threading
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

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
from fieldkit.cli.output import count_states, out_dir, progress_bar, wrote
from fieldkit.cli.signals import stop_on_signals
from fieldkit.cli.updates import release_for, split_versions, update_outcome

if TYPE_CHECKING:
    from fieldkit.ground.live import LiveGround
    from fieldkit.robot.profiles import Profile
    from fieldkit.sitl import SitlConfig

#: The most robots a run takes (a node process each).
MAX_ROBOTS = 64


def parse_team(text: str) -> list[tuple[str, int]]:
    """`--team NAME:COUNT[,NAME:COUNT]...` as (profile, count) pairs, in order: a form that
    does not parse is exit 2; a count below 1 or a team too big, exit 1."""
    team: list[tuple[str, int]] = []
    for part in text.split(","):
        name, sep, count = part.strip().rpartition(":")
        if not sep or not name or not count.strip().lstrip("+-").isdigit():
            raise usage_error(
                f"--team {text!r}: expected NAME:COUNT[,NAME:COUNT]... such as "
                f"solo:2,husky:1 (COUNT a whole number), got {part.strip()!r}"
            )
        n = int(count)
        if n < 1:
            raise fail(f"--team {text!r}: {name}: COUNT must be a positive integer, got {n}")
        team.append((name, n))
    total = sum(n for _, n in team)
    if total > MAX_ROBOTS:
        raise fail(
            f"--team {text!r}: {total} robots; a run takes at most {MAX_ROBOTS} "
            "(robot ids 1..64, a node process each)"
        )
    return team


def _team_profiles(team: list[tuple[str, int]], text: str) -> list[Profile]:
    """Each robot's profile, robot 1 first (a profile named twice is loaded once)."""
    from fieldkit.robot.profiles import ProfileError, load_profile

    loaded: dict[str, Profile] = {}
    out: list[Profile] = []
    for name, n in team:
        if name not in loaded:
            try:
                loaded[name] = load_profile(name)
            except (ProfileError, OSError) as e:
                raise fail(f"--team {text!r}: {e}") from None
        out += [loaded[name]] * n
    return out


def sitl_cmd(
    script: Annotated[Path, typer.Option("--script", help="The behavior, a .bzz file.")],
    out: Annotated[
        Path,
        typer.Option(
            "--out",
            help="Directory for summary.json, log.txt, trajectories.csv, plot.png, robotN/.",
        ),
    ],
    robots: Annotated[
        int | None,
        typer.Option("--robots", help="Number of robots (ids 1..N), all of --profile."),
    ] = None,
    team: Annotated[
        str | None,
        typer.Option(
            "--team",
            metavar="NAME:COUNT[,NAME:COUNT]...",
            help="A mixed team instead of --robots: profiles and counts, ids 1..N in this "
            "order (solo:2,husky:1,m100:1,spiri:1).",
        ),
    ] = None,
    profile: Annotated[
        str | None, typer.Option("--profile", help="Device profile of --robots [default: solo].")
    ] = None,
    drop: Annotated[float, typer.Option("--drop", help="Radio frame loss, 0..1.")] = 0.0,
    seconds: Annotated[
        float | None,
        typer.Option("--seconds", help="Seconds to run (default 60; with --ground, until Ctrl-C)."),
    ] = None,
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
    ground: Annotated[
        bool,
        typer.Option(
            "--ground",
            help="A ground station beside robot 1: its page on 127.0.0.1 and a UDP gateway "
            "onto the SITL radio (docs/ground.md).",
        ),
    ] = False,
    ground_port: Annotated[
        int,
        typer.Option("--ground-port", metavar="P", help="With --ground: the page's port."),
    ] = 8080,
) -> None:
    """Run SCRIPT on N real nodes against simulated vehicles, over a simulated radio."""
    import bvm
    from bvm.errors import BuzzCompileError
    from fieldkit.robot.profiles import ProfileError, load_profile
    from fieldkit.sitl import SitlConfig, SitlUpdate

    commands = parse_commands(command)  # first: a command line that does not parse is exit 2
    sets = parse_sets(set_)
    home_ll = parse_home(home)
    updates = parse_updates(update)
    members = parse_team(team) if team is not None else None
    if members is not None and robots is not None:
        raise fail("--team and --robots: give one (--team says how many robots of each)")
    if members is not None and profile is not None:
        raise fail("--team and --profile: give one (--team names each robot's profile)")
    if members is None and robots is None:
        raise fail("give --robots N (of --profile, solo by default) or --team NAME:COUNT,...")
    n = robots if robots is not None else sum(c for _, c in members or [])
    if seconds is None and not ground:
        seconds = 60.0
    if len(updates) > 1:
        raise fail(
            f"--update given {len(updates)} times: sitl sends one update per run\n"
            "hint: `fieldkit sim run` takes several"
        )
    for u in updates:
        if not 1 <= u.robot <= n:
            raise fail(f"--update at robot {u.robot}: robots are 1..{n}")
        if seconds is not None and u.t >= seconds:
            raise fail(f"--update at {u.t:g} s: the run is {seconds:g} s long (see --seconds)")
    for text, c in zip(command or [], commands, strict=True):
        if not 1 <= c.robot <= n:
            raise fail(f"--command {text!r}: robots are 1..{n}")
    if not 1 <= n <= MAX_ROBOTS:
        raise fail(f"--robots must be 1..{MAX_ROBOTS} (one process each), got {n}")
    if not 0.0 <= drop <= 1.0:
        raise fail(f"--drop must be a probability in [0, 1], got {drop}")
    if seconds is not None and not 0 < seconds <= 1e6:  # (inf would overflow the count)
        raise fail(f"--seconds must be > 0 and at most 1e6, got {seconds}")
    if not 0 <= ground_port <= 65535:
        raise fail(f"--ground-port must be 0..65535 (0: any free port), got {ground_port}")
    script = resources.find_script(script)
    if not script.is_file():
        raise fail(f"--script {script}: no such file")
    if members is not None:
        assert team is not None
        profiles = _team_profiles(members, team)
    else:
        try:
            profiles = [load_profile(profile or "solo")] * n
        except (ProfileError, OSError) as e:
            raise fail(e) from None
    prof = profiles[0]
    names = list(dict.fromkeys(str(p.path or p.name) for p in profiles))
    if keys is not None:
        load_keys(keys)  # a wrong, missing or world-readable key: said now, naming the file
    if ground:
        from fieldkit.cli.ground_sim import ground_keys

        keys = ground_keys(out, keys)  # operator commands are signed: a run with keys
    # --update makes keys of its own when none are given: such a run has keys too.
    securities = {p.radio.security for p in profiles}
    profile_security = securities.pop() if len(securities) == 1 else None
    mode = security_mode(security, keys is not None or bool(updates), profile_security)
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
        sitl_update = SitlUpdate(u.t, release_for(u, dirs, names), u.robot, u.script.name)
    out_dir(out)  # an --out that is a file fails here, with `error:`
    if record is not None:
        out_dir(record, "--record")
        suffix = ".bag" if ros1 else ""
        taken = [
            f"robot{i}{suffix}" for i in range(1, n + 1) if (record / f"robot{i}{suffix}").exists()
        ]
        if taken:
            raise fail(f"--record {record}: {', '.join(taken)} exist already\n"
                       f"hint: record to a new directory")  # fmt: skip
    warn_if_insecure(mode)
    cfg = SitlConfig(
        script=script.resolve(),
        robots=n,
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
        team=profiles if members is not None else (),
    )
    live = cfg.ground = _open_ground(cfg, keys, ground_port, sets) if ground else None
    try:
        with stop_on_signals() as stop:
            if seconds is None:
                typer.echo(f"sitl: {n} robots until Ctrl-C", err=True)
                summary = _run(cfg, stop, None)
            else:
                with progress_bar(f"SITL: {n} robots", round(seconds)) as advance:
                    summary = _run(cfg, stop, advance)
    finally:
        if live is not None:
            live.close()
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


def _run(
    cfg: SitlConfig, stop: threading.Event, advance: Callable[[int, int], None] | None
) -> dict[str, Any]:
    """`fieldkit.sitl.run`, its failures as `error:` lines."""
    from fieldkit.errors import FieldkitError
    from fieldkit.sitl import run

    def say(text: str) -> None:
        typer.echo(text, err=True)

    def progress(done: float, total: float) -> None:
        if advance is not None:
            advance(round(done), round(total))

    try:
        return dict(run(cfg, progress=progress, stop=stop, say=say))
    except (OSError, FieldkitError) as e:  # no pty, no process, keys, an unwritable result
        raise fail(e) from None


def _open_ground(
    cfg: SitlConfig, keys: Path | None, port: int, sets: Mapping[str, object]
) -> LiveGround:
    """The ground station of `--ground`, its page served and its gateway open, announced."""
    from fieldkit.cli.ground_sim import announce, drawing, port_taken
    from fieldkit.ground.live import make_station, serve
    from fieldkit.update.keys import load_robot_keys

    robot_keys = load_robot_keys(keys) if keys is not None else None
    signed = cfg.security == "signed" and robot_keys is not None
    profiles = cfg.profiles()
    station = make_station(
        keys,
        swarm_key=robot_keys.swarm_key if signed and robot_keys is not None else None,
        operator_pub=None if robot_keys is None else robot_keys.operator_pub,
        origin=cfg.home,
        profiles={i + 1: p.name for i, p in enumerate(profiles)},
        geofence=profiles[0].geofence.polygon,
        **drawing(sets, cfg.script.name),
    )
    try:
        live = serve(station, http_port=port)
    except OSError as e:
        raise port_taken(port, e) from None
    live.server.start()
    announce(live, keys)
    return live


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
