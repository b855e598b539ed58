"""`fieldkit ground` (the operator's ground station and its page) and `fieldkit cmd` (one
operator command from a terminal, waiting for every robot's acknowledgement)."""

from __future__ import annotations

import signal
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from fieldkit.cli.errors import fail, usage_error
from fieldkit.cli.options import HomeOption, parse_home

if TYPE_CHECKING:
    from fieldkit.ground.core import GroundStation

#: `fieldkit cmd`'s radio id by default: not the ground station's (0) nor the update
#: session's (255), so the three can share a radio.
CMD_ID = 254

_RadioOption = Annotated[
    str,
    typer.Option(
        "--radio",
        metavar="URL",
        help="The swarm's radio: serial:///dev/ttyUSB0?baud=230400&api=1 (an XBee) or "
        "udp://HOST:PORT (as fieldkit node --radio; sim run --ground prints its gateway's).",
    ),
]
_GroundKeysOption = Annotated[
    Path | None,
    typer.Option(
        "--keys",
        metavar="DIR",
        help="The operator's key directory (fieldkit keys init): operator.key signs the "
        "commands, swarm.key checks what the robots send.",
    ),
]


def _operator(keys: Path, *, need_signer: bool) -> tuple[Any, Any]:
    """(RobotKeys, CommandSigner or None) of an operator's key directory, or exit 1."""
    from fieldkit.errors import FieldkitError
    from fieldkit.robot.operator_command import SIGNER_SEQ_FILE, CommandSigner
    from fieldkit.update.keys import load_robot_keys, load_signing_key

    try:
        robot_keys = load_robot_keys(keys)
        if not need_signer and not (keys / "operator.key").exists():
            typer.echo(
                f"warning: no {keys / 'operator.key'}: the ground station watches the swarm "
                "but cannot command it",
                err=True,
            )
            return robot_keys, None
        return robot_keys, CommandSigner(load_signing_key(keys), keys / SIGNER_SEQ_FILE)
    except FieldkitError as e:
        raise fail(e) from None


def _open(url: str, robot_id: int) -> Any:
    from fieldkit.radio import open_radio

    try:
        return open_radio(url, robot_id)
    except (OSError, ValueError) as e:
        raise fail(f"--radio {url}: cannot open: {e}") from None


def _check_id(robot_id: int) -> None:
    if not 0 <= robot_id <= 254:
        raise usage_error(f"--robot-id {robot_id}: the ground station's id is 0..254")


def ground_cmd(
    radio: _RadioOption,
    http_port: Annotated[
        int, typer.Option("--http-port", metavar="PORT", help="The page's port on 127.0.0.1.")
    ] = 8080,
    robot_id: Annotated[
        int, typer.Option("--robot-id", help="The ground station's id on the radio.")
    ] = 0,
    keys: _GroundKeysOption = None,
    home: HomeOption = None,
    profile: Annotated[
        str | None,
        typer.Option("--profile", help="Device profile whose geofence the page draws."),
    ] = None,
    shape: Annotated[
        str | None,
        typer.Option("--shape", help="Task graph to draw, placed at robot --root (e.g. P)."),
    ] = None,
    root: Annotated[int, typer.Option("--root", help="The task graph's root robot.")] = 1,
    seconds: Annotated[
        float | None,
        typer.Option("--seconds", help="Stop after this many seconds (default: Ctrl-C)."),
    ] = None,
) -> None:
    """The ground station: hear the swarm, serve its page at http://127.0.0.1:PORT/."""
    from fieldkit.ground.core import GroundStation
    from fieldkit.ground.web import GroundServer

    _check_id(robot_id)
    if not 0 <= http_port < 65536:
        raise usage_error(f"--http-port {http_port}: a port is 0..65535")
    origin = parse_home(home) if home is not None else None
    geofence: tuple[tuple[float, float], ...] = ()
    if profile is not None:
        from fieldkit.robot.profiles import ProfileError, load_profile

        try:
            geofence = load_profile(profile).geofence.polygon
        except (ProfileError, OSError) as e:
            raise fail(f"--profile {profile}: {e}") from None
    robot_keys, signer = (None, None) if keys is None else _operator(keys, need_signer=False)
    if keys is None:
        typer.echo(
            "warning: no --keys: the ground station hears a plain swarm only and cannot "
            "command it (operator commands are signed)",
            err=True,
        )
    station = GroundStation(
        robot_id=robot_id,
        swarm_key=None if robot_keys is None else robot_keys.swarm_key,
        signer=signer,
        operator_pub=None if robot_keys is None else robot_keys.operator_pub,
        origin=origin,
        geofence=geofence,
        shape=shape,
        root_id=root,
    )
    link = _open(radio, robot_id)
    try:
        try:
            server = GroundServer(station, port=http_port)
        except OSError as e:
            raise fail(
                f"--http-port {http_port}: cannot serve the page: {e.strerror or e}\n"
                "  hint: another program uses the port: give --http-port with another one"
            ) from None
        server.start()
        typer.echo(f"ground: page at {server.url} (radio {radio}, id {robot_id})", err=True)
        _serve(station, link, seconds)
        server.stop()
    finally:
        link.close()
    typer.echo(f"ground: {len(station.robots)} robots heard; stopped")


def _serve(station: GroundStation, link: Any, seconds: float | None) -> None:
    """Run the station on its radio until `seconds` pass, Ctrl-C or SIGTERM (a normal stop)."""
    from fieldkit.ground.station import run_on_radio

    stop = threading.Event()
    deadline = None if seconds is None else time.monotonic() + seconds
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        run_on_radio(
            station,
            link,
            until=lambda: stop.is_set() or (deadline is not None and time.monotonic() > deadline),
        )
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)


def cmd_cmd(
    code: Annotated[
        str,
        typer.Argument(
            metavar="CODE",
            help="takeoff, land, gohome, waypoint, task-allocation, coverage, idle, or an rc "
            "code (22, 21, 20, 16, 900, 901, 904).",
        ),
    ],
    radio: _RadioOption,
    params: Annotated[
        list[str] | None,
        typer.Argument(
            metavar="[PARAM]...",
            help="Params: a waypoint's ID LAT LON ALT (put -- before them if one is "
            "negative); task-allocation's root robot ID (one that is heard).",
        ),
    ] = None,
    to: Annotated[
        int | None, typer.Option("--to", metavar="ROBOT", help="One robot (default: all).")
    ] = None,
    keys: _GroundKeysOption = None,
    timeout: Annotated[
        float, typer.Option("--timeout", metavar="S", help="Seconds to wait for the acks.")
    ] = 15.0,
    listen: Annotated[
        float,
        typer.Option("--listen", metavar="S", help="Seconds to listen first, to learn the swarm."),
    ] = 3.0,
    robot_id: Annotated[
        int, typer.Option("--robot-id", help="This terminal's id on the radio.")
    ] = CMD_ID,
) -> None:
    """Send one signed operator command; exit 0 once every target robot acknowledged it."""
    from fieldkit.ground.core import CODES, GroundError, GroundStation
    from fieldkit.ground.station import run_on_radio
    from fieldkit.robot.rc import RC_TASK_ALLOCATE, param_problem

    _check_id(robot_id)
    number = CODES.get(code)
    if number is None:
        try:
            number = int(code)
        except ValueError:
            raise usage_error(
                f"CODE {code!r}: one of {', '.join(CODES)}, or an rc code (a number)"
            ) from None
    if not 0 < number < 0x10000:
        raise usage_error(f"CODE {code}: an rc code is 1..65535")
    values = []
    for text in params or []:
        try:
            values.append(float(text))
        except ValueError:
            raise usage_error(f"PARAM {text!r}: a number") from None
    problem = param_problem(number, tuple(values))
    if problem is not None:
        raise usage_error(f"CODE {code} PARAM: {problem}")
    if not 0 < timeout <= 86400 or not 0 <= listen <= 600:
        raise usage_error("--timeout is 0..86400 s and --listen 0..600 s")
    if keys is None:
        raise fail(
            "an operator command must be signed: give --keys DIR (the operator's keys, with "
            "operator.key; fieldkit keys init DIR)"
        )
    robot_keys, signer = _operator(keys, need_signer=True)
    station = GroundStation(
        robot_id=robot_id,
        swarm_key=robot_keys.swarm_key,
        signer=signer,
        operator_pub=robot_keys.operator_pub,
        update_view=False,
    )
    link = _open(radio, robot_id)
    say = lambda text: typer.echo(f"cmd: {text}", err=True)  # noqa: E731
    try:
        t0 = time.monotonic()
        clock = lambda: time.monotonic() - t0  # noqa: E731
        heard = lambda: to is not None and to in station.known()  # noqa: E731
        try:
            run_on_radio(station, link, until=lambda: heard() or clock() > listen, clock=clock)
            known = station.known()
            if to is None and not known:
                raise fail(
                    f"no robot heard on {radio} in {listen:g} s\n  hint: the robots must run "
                    "with the same swarm key (--keys) on this radio's channel"
                )
            root = int(values[0]) if number == RC_TASK_ALLOCATE and values else None
            if root is not None and to is None and root not in known:
                # A root nobody hears would leave every robot FREE: say so before sending
                # (with --to, listening ends once that robot is heard, so not then).
                raise fail(
                    f"task-allocation root {root}: no such robot heard in "
                    f"{listen:g} s (heard: {', '.join(map(str, sorted(known))) or 'none'})"
                    "\n  hint: name a robot that runs, or --listen longer"
                )
            try:
                c = station.command(number, values, to, timeout=timeout)
            except GroundError as e:
                raise fail(f"{e}\n  hint: check the id, or --listen longer") from None
            say(f"sent {c.describe()}, waiting for {', '.join(map(str, sorted(c.expected)))}")
            told: set[int] = set()

            def progress() -> bool:
                for rid in sorted(c.acked - told):
                    told.add(rid)
                    say(f"robot {rid} acknowledged ({station.now - c.sent_at:.1f} s)")
                return c.done or station.now > c.deadline

            run_on_radio(station, link, until=progress, clock=clock)
        except KeyboardInterrupt:
            raise fail("interrupted") from None
    finally:
        link.close()
    if not c.done:
        raise fail(
            f"{c.describe()}: no acknowledgement in {timeout:g} s from robot"
            f"{'s' if len(c.missing()) > 1 else ''} {', '.join(map(str, c.missing()))}"
            f" (acknowledged: {', '.join(map(str, sorted(c.acked))) or 'none'})"
        )
    typer.echo(
        f"cmd: {c.describe()}: acknowledged by {', '.join(map(str, sorted(c.acked)))} "
        f"in {station.now - c.sent_at:.1f} s"
    )


__all__ = ["CMD_ID", "cmd_cmd", "ground_cmd"]
