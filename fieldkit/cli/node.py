"""`fieldkit node`: run a behavior on this robot, against its autopilot and radio."""

from __future__ import annotations

import logging
import math
import re
import socket
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

import bvm
from bvm.errors import BuzzCompileError
from fieldkit import resources
from fieldkit.cli.errors import UsageProblem, error_text, fail, usage_error
from fieldkit.cli.options import (
    CommandOption,
    KeysOption,
    SecurityOption,
    SetOption,
    SetValue,
    load_keys,
    parse_commands,
    parse_sets,
    security_mode,
    warn_if_insecure,
)
from fieldkit.cli.output import out_dir, write_json, wrote

if TYPE_CHECKING:
    from fieldkit.node.config import DjiApp
    from fieldkit.node.journal import Journal
    from fieldkit.node.log import NodeLog
    from fieldkit.node.service import ReloadCheck, ServiceSignals
    from fieldkit.radio.base import RadioLink
    from fieldkit.robot.link_security import LinkSecurity
    from fieldkit.robot.operator_command import CommandGate
    from fieldkit.robot.profiles import Profile
    from fieldkit.robot.rc import RcCommand
    from fieldkit.update.keys import RobotKeys
    from fieldkit.update.store import Committed, VersionStore


def robot_id_from(profile: Profile, given: int | None) -> int:
    """The robot id: --robot-id, else the profile's source (a value, or the hostname's digits)."""
    if given is not None:
        if not 0 <= given <= 255:
            raise fail(f"--robot-id must be 0..255, got {given}")
        return given
    rid = profile.robot_id
    if rid.source == "config" and rid.value is not None:
        return int(rid.value)
    if rid.source == "hostname":
        m = re.search(r"(\d+)$", socket.gethostname())
        if m and int(m.group(1)) <= 255:
            return int(m.group(1))
        raise fail(f"the host name {socket.gethostname()!r} ends in no robot id: use --robot-id")
    raise fail(f"robot_id.source = {rid.source!r}: give --robot-id")


#: What a profile's [radio] table looks like, for a profile whose radio is missing or wrong.
RADIO_HINT = (
    "hint: the node's radio is the profile's [radio] table, e.g. kind = \"xbee\", "
    'port = "/dev/ttyUSB0", baud = 230400, api_mode = 2 (the shipped solo profile has one); '
    'kind = "udp" for a WiFi mesh'
)


def open_node_radio(
    prof: Profile, radio: str | None, rid: int, say: Callable[[str], None]
) -> RadioLink | None:
    """The radio `--radio` names (a URL, or `none`), else the profile's; fail if it won't open."""
    from fieldkit.radio import from_profile, open_radio

    if radio == "none":
        say("radio: none (--radio none): this robot hears no one and no one hears it")
        return None
    settings = prof.radio
    others = "give --radio URL, or --radio none to run without a radio"
    if radio is not None:
        where, hint = radio, ""
    elif settings.kind == "udp":
        where = f"udp port {settings.udp_port}"
        hint = (
            f"\nhint: the {prof.name} profile's [radio] names this port: set "
            f"radio.udp_port in the profile, {others}"
        )
    else:
        where = settings.port
        hint = (
            f"\nhint: the {prof.name} profile's [radio] names this XBee: plug it in, set "
            f"radio.port in the profile, {others}"
        )
    try:
        link = open_radio(radio, rid) if radio is not None else from_profile(settings, rid)
    except (OSError, ValueError) as e:
        raise fail(f"radio {where}: {_reason(e)}{hint}") from None
    say(f"radio: {where}" + ("" if radio is not None else f" ({prof.name} profile)"))
    return link


def _reason(e: BaseException) -> str:
    """Why a port did not open, without pyserial's repetitions of the path."""
    cause = e.__cause__ or e.__context__
    if isinstance(cause, OSError) and cause.strerror:
        return cause.strerror  # pyserial wraps the OSError of open() in its own
    if isinstance(e, OSError) and e.strerror:
        return e.strerror
    return str(e)


ConfigOption = Annotated[
    Path | None,
    typer.Option(
        "--config",
        metavar="FILE",
        help="Read the options from FILE's [node] table (fieldkit.toml, as `fieldkit deploy` "
        "writes it); the command line overrides it.",
    ),
]


def node_cmd(
    profile: Annotated[
        str | None, typer.Option("--profile", help="Device profile (name or .toml).")
    ] = None,
    script: Annotated[
        Path | None,
        typer.Option(
            "--script",
            help="The behavior, a .bzz or .bo (with --state-dir: only seeds an empty one).",
        ),
    ] = None,
    autopilot: Annotated[
        str | None,
        typer.Option(
            "--autopilot",
            help="pymavlink URL; a Clearpath base's MCU serial port (default: the profile's).",
        ),
    ] = None,
    gps: Annotated[
        str | None,
        typer.Option(
            "--gps",
            metavar="DEV",
            help="A Clearpath base's GPS receiver serial port (default: the profile's [gps]).",
        ),
    ] = None,
    radio: Annotated[
        str | None,
        typer.Option(
            "--radio",
            help="Radio URL (an XBee: serial:///dev/ttyUSB0?baud=230400&api=2; udp://HOST:PORT), "
            "or none (default: the radio the profile names).",
        ),
    ] = None,
    robot_id: Annotated[int | None, typer.Option("--robot-id", help="This robot's id.")] = None,
    seconds: Annotated[
        float | None, typer.Option("--seconds", help="Stop after T seconds.")
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Write DIR/summary.json.")] = None,
    record: Annotated[
        Path | None,
        typer.Option(
            "--record",
            metavar="PATH",
            help="Record the flight as a rosbag: a directory (ROS 2, MCAP), or PATH.bag (ROS 1).",
        ),
    ] = None,
    record_max_mb: Annotated[
        float | None,
        typer.Option(
            "--record-max-mb",
            help="Stop recording once the bag's parts together reach this size [default: 2048].",
            show_default=False,
        ),
    ] = None,
    include: Annotated[
        list[Path] | None, typer.Option("-I", "--include", help="Extra include directory.")
    ] = None,
    command: CommandOption = None,
    sets: SetOption = None,
    connect_timeout: Annotated[
        float | None,
        typer.Option(
            "--connect-timeout",
            help="Seconds to wait for the autopilot [default: 30].",
            show_default=False,
        ),
    ] = None,
    seed: Annotated[
        int | None,
        typer.Option(
            "--seed",
            help="Seed of the script's random draws (with the robot id) [default: 0].",
            show_default=False,
        ),
    ] = None,
    state_dir: Annotated[
        Path | None,
        typer.Option(
            "--state-dir",
            help="Keep script versions here: the committed one runs, a reboot included.",
        ),
    ] = None,
    keys: KeysOption = None,
    security: SecurityOption = None,
    update_outbox: Annotated[
        Path | None,
        typer.Option(
            "--update-outbox",
            metavar="FILE",
            help="Originate updates: a new or changed patch in FILE (`fieldkit update "
            "--patch-out FILE --watch`) is verified and sent to the swarm (needs --state-dir "
            "and --keys).",
        ),
    ] = None,
    config: ConfigOption = None,
) -> None:
    """Run SCRIPT on this robot: the VM against the autopilot (MAVLink) and the radio."""
    from fieldkit.node.service import ServiceSignals, StartupStopped

    # From here on SIGTERM (systemd's stop) ends even the start-up cleanly.
    signals = ServiceSignals()
    try:
        given = {
            "profile": profile, "script": script, "autopilot": autopilot, "gps": gps,
            "radio": radio,
            "robot_id": robot_id, "seconds": seconds, "out": out, "record": record,
            "record_max_mb": record_max_mb, "include": include, "command": command,
            "set": sets, "connect_timeout": connect_timeout, "seed": seed,
            "state_dir": state_dir, "keys": keys, "security": security,
            "update_outbox": update_outbox,
        }  # fmt: skip
        options = node_options(given, config)
        _node(options, signals)
    except StartupStopped as e:
        typer.echo(f"stopped by {e} during start-up: nothing was ordered to the vehicle")
    finally:
        signals.restore()


@dataclass(frozen=True)
class NodeOptions:
    """The node's options once the config file and the command line are merged and checked."""

    profile: str
    script: Path | None
    autopilot: str | None
    radio: str | None
    robot_id: int | None
    seconds: float | None
    out: Path | None
    record: Path | None
    record_max_mb: float
    include: list[str]
    command: list[str]
    sets: list[str]
    connect_timeout: float
    seed: int
    state_dir: Path | None
    keys: Path | None
    security: str | None
    config: Path | None
    #: The originator's patch file (`--update-outbox`), None for a robot that only receives.
    update_outbox: Path | None = None
    #: What a new flight's bag is pruned against (the config's [record] keep_mb), and where.
    record_keep: tuple[Path, float] | None = None
    #: A Clearpath base's GPS port (--gps): None for the profile's.
    gps: str | None = None
    #: The DJI app an M100 is activated with (the config's [dji]; never on a command line).
    dji: DjiApp | None = None


def node_options(
    given: dict[str, Any], config: Path | None, *, make_dirs: bool = True
) -> NodeOptions:
    """`given` (the command line, None where not given) over the config file's [node].
    `make_dirs` makes the config's record.dir (the node; `fieldkit doctor` only looks)."""
    from fieldkit.node.config import NodeConfigError, load_config
    from fieldkit.node.recording import new_flight_path

    file: dict[str, Any] = {}
    record_settings = None
    dji = None
    if config is not None:
        try:
            loaded = load_config(config)
        except NodeConfigError as e:
            raise fail(e) from None
        file = dict(loaded.node)
        record_settings = loaded.record
        dji = loaded.dji
        for key in ("set", "command"):  # checked as the command line's, named by the file
            try:
                (parse_sets if key == "set" else parse_commands)(file.get(key))
            except UsageProblem as e:
                raise fail(f"{config}: node.{key}: {e.message}") from None

    def pick(key: str) -> Any:
        value = given[key]
        return value if value is not None else file.get(key)

    def path(key: str) -> Path | None:
        value = pick(key)
        return None if value is None else Path(value)

    name = pick("profile")
    if name is None:
        raise usage_error("Missing option '--profile' (or --config FILE with node.profile)")
    record = path("record")
    max_mb = pick("record_max_mb")
    keep = None
    if record is None and record_settings is not None:
        try:  # the folder of all flights is the config's: made if missing
            if make_dirs:
                record_settings.dir.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise fail(f"{config}: record.dir {record_settings.dir}: {e.strerror or e}") from None
        record = new_flight_path(record_settings.dir)
        max_mb = max_mb if max_mb is not None else record_settings.max_mb
        if record_settings.keep_mb is not None:
            keep = (record_settings.dir, record_settings.keep_mb)
    return NodeOptions(
        profile=str(name),
        script=path("script"),
        autopilot=pick("autopilot"),
        radio=pick("radio"),
        robot_id=pick("robot_id"),
        seconds=pick("seconds"),
        out=path("out"),
        record=record,
        record_max_mb=2048.0 if max_mb is None else float(max_mb),
        include=[str(d) for d in pick("include") or []],
        command=list(pick("command") or []),
        # The file's values first, the command line's after them: the last one wins.
        sets=list(file.get("set", [])) + list(given["set"] or []),
        connect_timeout=30.0 if pick("connect_timeout") is None else pick("connect_timeout"),
        seed=pick("seed") or 0,
        state_dir=path("state_dir"),
        keys=path("keys"),
        security=pick("security"),
        config=config,
        update_outbox=path("update_outbox"),
        record_keep=keep,
        gps=pick("gps"),
        dji=dji,
    )


def _node(o: NodeOptions, signals: ServiceSignals) -> None:
    """Check everything that needs no device, open the radio, run the node."""
    from fieldkit.errors import FieldkitError
    from fieldkit.node.log import NodeLog
    from fieldkit.node.security import node_commands, node_security
    from fieldkit.robot.profiles import ProfileError, load_profile

    # Everything that can be checked without a device is, before any port is opened.
    if o.script is None and o.state_dir is None:
        raise usage_error("Missing option '--script' (or --state-dir DIR with a version in it)")
    commands = parse_commands(o.command)  # ROBOT is checked against this node's id below
    globals_ = parse_sets(o.sets)
    seconds = o.seconds
    if seconds is not None and not (math.isfinite(seconds) and seconds > 0):
        raise fail(f"--seconds must be > 0, got {seconds:g}")
    if not (math.isfinite(o.connect_timeout) and o.connect_timeout > 0):
        raise fail(f"--connect-timeout must be > 0, got {o.connect_timeout:g}")
    try:
        prof = load_profile(o.profile)
    except (ProfileError, OSError) as e:
        hint = f"\n{RADIO_HINT}" if re.search(r": radio[.:]", str(e)) else ""
        raise fail(f"{error_text(e)}{hint}") from None
    rid = robot_id_from(prof, o.robot_id)
    for text, c in zip(o.command, commands, strict=True):
        if c.robot != rid:
            raise fail(f"--command {text!r} is for robot {c.robot}, this node is robot {rid}")
    if o.update_outbox is not None and (o.state_dir is None or o.keys is None):
        raise fail(
            f"--update-outbox {o.update_outbox}: originating updates needs the update agent\n"
            "hint: give --state-dir DIR and --keys DIR too (the robot's versions, and the "
            "keys its patches are verified with)"
        )
    script = resources.find_script(o.script) if o.script is not None else None
    say = NodeLog(rid, journal=_journal())
    robot_keys = load_keys(o.keys) if o.keys is not None else None
    mode = security_mode(o.security, robot_keys is not None, prof.radio.security)
    store: VersionStore | None = None
    if o.state_dir is None:
        assert script is not None  # checked above
        program = load_program(script, o.include)
        label = str(script)
    else:
        store, version, program = open_versions(o.state_dir, script, o.include, say)
        label = f"version {version.version} ({version.hash[:12]}…)"
    try:
        link_security = node_security(rid, mode, robot_keys, o.state_dir, say)
        gate = node_commands(rid, robot_keys, o.state_dir)
    except FieldkitError as e:  # no state dir, a damaged counter or floor file
        raise fail(e) from None
    if o.out is not None:
        out_dir(o.out)  # now, not after an hour's run
    if o.record is not None:
        check_record_path(o.record)
        if not (math.isfinite(o.record_max_mb) and o.record_max_mb > 0):
            raise fail(f"--record-max-mb must be > 0, got {o.record_max_mb:g}")
        if o.record_keep is not None:
            from fieldkit.node.recording import prune_flights

            for gone in prune_flights(*o.record_keep, room_mb=o.record_max_mb):
                say(f"recording: removed the oldest flight {gone} (record.keep_mb)")
    # The radio first: a missing XBee fails at once, not after the wait for the autopilot.
    link_radio = open_node_radio(prof, o.radio, rid, say)
    warn_if_insecure(mode)
    say(f"security: {mode}" + ("" if mode == "signed" else " (bundles not authenticated)"))
    try:
        _run(
            prof,
            label,
            program,
            rid,
            autopilot=o.autopilot,
            gps=o.gps,
            dji=o.dji,
            radio=link_radio,
            connect_timeout=o.connect_timeout,
            seconds=seconds,
            commands=commands,
            globals_=globals_,
            seed=o.seed,
            out=o.out,
            say=say,
            store=store,
            keys=robot_keys,
            security=link_security,
            command_gate=gate,
            record=o.record,
            record_max_bytes=int(o.record_max_mb * 2**20),
            script_name=label,
            signals=signals,
            reload_check=None if o.config is None else lambda: check_reload(o),
            update_outbox=o.update_outbox,
        )
    finally:
        if link_radio is not None:
            link_radio.close()


def _journal() -> Journal | None:
    """journald's socket when systemd runs the node with its stdout in the journal."""
    from fieldkit.node.journal import Journal, stdout_is_journal

    return Journal("fieldkit-node") if stdout_is_journal() else None


def check_reload(running: NodeOptions) -> str | None:
    """SIGHUP's check of the config file and script as they are now: None if the node may
    restart on them, else what is wrong (the checks of an update: it compiles, and passes
    the trial in the simulator)."""
    from fieldkit.node.config import NodeConfigError, load_config
    from fieldkit.robot.profiles import ProfileError, load_profile
    from fieldkit.sim.trial import trial

    assert running.config is not None
    try:
        loaded = load_config(running.config)
        name = loaded.node.get("profile", running.profile)
        load_profile(name)
    except (NodeConfigError, ProfileError, OSError) as e:
        return str(e)
    state_dir = loaded.node.get("state_dir")
    script = loaded.node.get("script")
    if state_dir is not None and any(Path(state_dir).glob("*")):
        # A state directory's committed version runs; its script only seeds an empty one.
        return None
    if script is None:
        return f"{running.config}: node.script: missing, and no state directory to run from"
    try:
        program = bvm.compile_file(
            resources.find_script(script), include_dirs=list(loaded.node.get("include", []))
        )
    except BuzzCompileError as e:
        return str(e)
    except OSError as e:
        return f"{script}: cannot read: {e.strerror or e}"
    problems = trial(program, [name])
    return "\n".join(problems) if problems else None


def check_record_path(path: Path) -> None:
    """`--record PATH` must be new, in a directory that exists: checked before any device."""
    if path.exists() or Path(f"{path}_1").exists():
        raise fail(f"--record {path}: exists already\nhint: record to a new path")
    if not path.parent.is_dir():
        raise fail(f"--record {path}: no directory {path.parent}")


def load_program(script: Path, includes: list[str]) -> bvm.Program:
    """The program of a .bzz (compiled) or a .bo (loaded, with its .bdb and .bpos)."""
    try:
        if script.suffix == ".bo":
            return bvm.Program.load(script)
        return bvm.compile_file(script, include_dirs=includes)
    except (BuzzCompileError, bvm.BuzzLoadError) as e:
        raise fail(e, script) from None
    except OSError as e:
        raise fail(f"{script}: cannot read: {e.strerror or e}") from None


def open_versions(
    state_dir: Path, script: Path | None, includes: list[str], say: Callable[[str], None]
) -> tuple[VersionStore, Committed, bvm.Program]:
    """The version store at `state_dir` and the program to run: its committed version, else
    `script` seeded as version 0. Says which version runs and why."""
    from fieldkit.update.release import Release, ReleaseError
    from fieldkit.update.store import StoreError, VersionStore

    try:
        store = VersionStore(state_dir)
        for note in store.notes:  # a recovery, or what a crash left
            say(f"warning: {note}")
        version = store.committed()
        if version is None:
            if script is None:
                raise fail(
                    f"{state_dir}: no committed version to run, and no --script to seed one\n"
                    "hint: give --script PATH once: it becomes version 0, and the state "
                    "directory keeps it"
                )
            if script.suffix == ".bo":
                try:
                    release = Release.read(script)
                    release.program(str(script))  # a .bo that does not load is not seeded
                except (ReleaseError, bvm.BuzzLoadError) as e:
                    raise fail(e, script) from None
            else:
                release = Release.from_program(load_program(script, includes))
            version = store.commit(0, store.put(release), reason=f"seeded from --script {script}")
        elif script is not None:
            say(f"--script {script} not used: {state_dir} holds a committed version "
                "(--script only seeds an empty state directory)")  # fmt: skip
        path = store.path(version.hash)
        program = store.get(version.hash).program(str(path))
    except StoreError as e:
        raise fail(e) from None
    except bvm.BuzzLoadError as e:
        raise fail(e, path) from None
    head = f"running version {version.version} ({version.hash[:12]}…)"
    if version.event == "seeded":
        say(f"{head}, {version.reason}")
    else:
        how = version.event.replace("-", " ")
        say(f"{head}, {how} {version.time}: {version.reason}")
    return store, version, program


def _run(
    prof: Profile,
    label: str,
    program: bvm.Program,
    rid: int,
    *,
    autopilot: str | None,
    radio: RadioLink | None,
    connect_timeout: float,
    seconds: float | None,
    commands: list[RcCommand],
    globals_: dict[str, SetValue],
    seed: int,
    out: Path | None,
    say: NodeLog,
    store: VersionStore | None,
    keys: RobotKeys | None,
    security: LinkSecurity,
    command_gate: CommandGate | None,
    record: Path | None = None,
    record_max_bytes: int = 2**31,
    script_name: str = "",
    signals: ServiceSignals | None = None,
    reload_check: ReloadCheck | None = None,
    gps: str | None = None,
    dji: DjiApp | None = None,
    update_outbox: Path | None = None,
) -> None:
    """Connect to the autopilot, run the loop, stop safely; exit 1 if the script is failed.

    Stopped by a signal, the node orders the profile's stop action and awaits its ACK; a
    reload whose check passed restarts the process in place on the new settings."""
    from fieldkit.node.autopilot_port import vehicle_port
    from fieldkit.node.clock import TickClock
    from fieldkit.node.daemon import Notifier
    from fieldkit.node.node import Node
    from fieldkit.node.outbox import Outbox
    from fieldkit.node.recording import NodeRecording
    from fieldkit.node.service import NodeService, ServiceSignals
    from fieldkit.node.startup import start_vehicle
    from fieldkit.record.bag import BagError
    from fieldkit.vehicle.autopilot import AutopilotError
    from fieldkit.vehicle.links import open_link

    # One time for the node and its autopilot core, frozen for each tick: a tick's decisions
    # (heartbeats, retries, commands due) then depend on its recorded time alone.
    tick_clock = TickClock()
    notifier = Notifier()
    with _logging_to(say):
        try:
            link = open_link(
                prof,
                autopilot,
                gps=gps,
                clock=tick_clock.now,
                dji_app_id=None if dji is None else dji.app_id,
                dji_app_key=None if dji is None else dji.app_key,
                in_tick=lambda: tick_clock.in_tick,
            )
        except AutopilotError as e:
            raise fail(e) from None
        recording = (
            None
            if record is None
            else NodeRecording(record, prof, program, max_total_bytes=record_max_bytes, say=say)
        )
        if recording is not None:
            recording.tap(link)
        try:
            try:
                t = start_vehicle(link, prof, connect_timeout, say)
            except AutopilotError as e:
                raise fail(e) from None
            assert t.lat is not None and t.lon is not None  # what wait_position waited for
            home = (t.home[0], t.home[1], 0.0) if t.home is not None else (t.lat, t.lon, 0.0)
            until = "until stopped" if seconds is None else f"for {seconds:g} s"
            say(f"starting {label} at {prof.node.loop_rate_hz:g} Hz {until}, home "
                f"{home[0]:.7f},{home[1]:.7f}")  # fmt: skip
            node = Node(
                prof,
                program,
                rid,
                vehicle_port(link, home),
                radio,
                home=home,
                commands=commands,
                clock=tick_clock,
                out=say,
                seed=seed,
                globals_=globals_,
                store=store,
                keys=keys,
                security=security,
                command_gate=command_gate,
                recorder=None if recording is None else recording.recorder,
                outbox=None if update_outbox is None else Outbox(update_outbox, say),
            )
            if update_outbox is not None:
                say(f"update outbox: {update_outbox} (a new patch there goes to the swarm)")
            if recording is not None:
                try:
                    recording.begin(node, link, script_name=script_name, seed=seed,
                                    globals_=dict(globals_), commands=commands)  # fmt: skip
                except BagError as e:
                    raise fail(e) from None
                say(f"recording to {record}")
            service = NodeService(
                node,
                notifier,
                signals if signals is not None else ServiceSignals(),
                say,
                reload_check=reload_check,
            )
            service.run(seconds)
            failed = node.finish()
            stopped = service.signals.stop_signal is not None or service.reloading
            if stopped:  # the profile's stop order; a run that is over leaves the vehicle be
                stop = service.safe_stop(link)
        finally:
            link.close()
            if recording is not None:
                recording.close()
                wrote(recording.path)
    why = (
        "reloading"
        if service.reloading
        else "stopped by a signal"
        if service.signals.stop_signal is not None
        else "run over"
    )
    say(f"{why}: {node.runtime.ticks} ticks, {node.late_ticks} late")
    summary = node.summary()
    if stopped:
        summary["stop"] = {"action": stop.action, "acknowledged": stop.acknowledged}
    if out is not None:
        write_json(out / "summary.json", summary)
    if service.reloading and service.signals.block_for_restart():
        if notifier.watchdog_s is not None:
            # No tick pings while the new process waits for the heartbeat and the fix:
            # the watchdog is widened to that wait, and set back at its READY.
            wait_s = connect_timeout + prof.autopilot.gps_fix_timeout_s + RESTART_MARGIN_S
            notifier.send(f"WATCHDOG_USEC={round(wait_s * 1e6)}")
        notifier.close()
        _restart_in_place(say)
    if failed is not None:
        raise fail(
            f"{failed}\nrobot {rid}'s script stopped at this error and the robot ended the run "
            f"in its failsafe (on_script_error = {prof.failsafe.on_script_error})"
        )


#: Seconds a restart in place may take beyond its waits for the heartbeat and the fix (the
#: stream requests' settling, the script's preparation), for the widened watchdog.
RESTART_MARGIN_S = 30.0


@contextmanager
def _logging_to(say: NodeLog) -> Iterator[None]:
    """Route fieldkit's `logging` (runtime, autopilot link) through the node's one writer."""
    root = logging.getLogger("fieldkit")
    ours = logging.getLogger("fieldkit.node")  # the autopilot's events: mode, arming...
    saved = (root.level, root.propagate, root.disabled, ours.level, ours.propagate, ours.disabled)
    handler = say.handler()
    root.addHandler(handler)
    root.setLevel(logging.WARNING)
    root.propagate = False  # each line once, stamped, on stdout
    ours.setLevel(logging.INFO)
    # Whatever a library or an earlier caller in this process did to them, the node's lines
    # must reach its writer: a silenced "fieldkit.node" hides every event of the vehicle.
    root.disabled = ours.disabled = False
    ours.propagate = True
    try:
        yield
    finally:
        root.removeHandler(handler)
        root.setLevel(saved[0])
        root.propagate, root.disabled = saved[1], saved[2]
        ours.setLevel(saved[3])
        ours.propagate, ours.disabled = saved[4], saved[5]


def _restart_in_place(say: NodeLog) -> None:
    """Replace this process by a fresh node with the same command line (same pid, so
    systemd's service goes on): it reads the config and script anew."""
    import os
    import sys

    say("reload: restarting on the new settings")
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(sys.executable, sys.orig_argv)
