"""`fieldkit node`: run a behavior on this robot, against its autopilot and radio."""

from __future__ import annotations

import logging
import re
import socket
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

import bvm
from bvm.errors import BuzzCompileError
from fieldkit import resources
from fieldkit.cli.errors import fail, usage_error
from fieldkit.cli.options import parse_sets
from fieldkit.cli.output import out_dir, write_json

if TYPE_CHECKING:
    from fieldkit.robot.profiles import Profile


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


def node_cmd(
    profile: Annotated[str, typer.Option("--profile", help="Device profile (name or .toml).")],
    script: Annotated[Path, typer.Option("--script", help="The behavior, a .bzz or .bo.")],
    autopilot: Annotated[
        str | None, typer.Option("--autopilot", help="pymavlink URL (default: the profile's).")
    ] = None,
    radio: Annotated[
        str | None,
        typer.Option("--radio", help="Radio URL (xbee serial, udp://...) or none."),
    ] = None,
    robot_id: Annotated[int | None, typer.Option("--robot-id", help="This robot's id.")] = None,
    seconds: Annotated[
        float | None, typer.Option("--seconds", help="Stop after T seconds.")
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Write DIR/summary.json.")] = None,
    include: Annotated[
        list[Path] | None, typer.Option("-I", "--include", help="Extra include directory.")
    ] = None,
    command: Annotated[
        list[str] | None,
        typer.Option("--command", help="T:CODE[:P...]: a remote-control code at second T."),
    ] = None,
    connect_timeout: Annotated[
        float, typer.Option("--connect-timeout", help="Seconds to wait for the autopilot.")
    ] = 30.0,
    seed: Annotated[
        int, typer.Option("--seed", help="Seed of the script's random draws (with the robot id).")
    ] = 0,
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            metavar="NAME=VALUE",
            help="Set a script global before init() (repeatable), e.g. --set SHAPE=Y.",
        ),
    ] = None,
) -> None:
    """Run SCRIPT on this robot: the VM against the autopilot (MAVLink) and the radio."""
    from fieldkit.node.autopilot_port import MavlinkAutopilot
    from fieldkit.node.node import Node
    from fieldkit.robot.profiles import ProfileError, load_profile
    from fieldkit.vehicle.autopilot import AutopilotError
    from fieldkit.vehicle.link import Autopilot

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        prof = load_profile(profile)
    except (ProfileError, OSError) as e:
        raise fail(e) from None
    rid = robot_id_from(prof, robot_id)
    from fieldkit.errors import ConfigError
    from fieldkit.robot.rc import RcCommand

    try:
        commands = [RcCommand.parse(c, robot=rid) for c in command or []]
    except ConfigError as e:
        raise usage_error(str(e)) from None
    globals_ = parse_sets(set_)
    script = resources.find_script(script)
    try:
        if script.suffix == ".bo":
            program = bvm.Program.load(script)
        else:
            program = bvm.compile_file(script, include_dirs=[str(d) for d in include or []])
    except (BuzzCompileError, bvm.BuzzLoadError) as e:
        raise fail(e, script) from None
    except OSError as e:
        raise fail(f"{script}: cannot read: {e.strerror or e}") from None
    try:
        link = Autopilot.from_profile(prof, autopilot)
        link.wait_heartbeat(connect_timeout)
        link.request_streams(prof.node.loop_rate_hz)
        t = link.wait_gps_fix(prof.autopilot.gps_fix_timeout_s)
    except AutopilotError as e:
        raise fail(e) from None
    home = t.home if t.home is not None else (t.lat or 0.0, t.lon or 0.0, 0.0)
    home = (home[0], home[1], 0.0)
    link_radio = None
    if radio is not None and radio != "none":
        from fieldkit.radio import open_radio

        try:
            link_radio = open_radio(radio, rid)
        except (OSError, ValueError) as e:
            raise fail(f"--radio {radio}: {e}") from None

    def say(text: str) -> None:
        sys.stdout.write(text + "\n")
        sys.stdout.flush()

    node = Node(
        prof,
        program,
        rid,
        MavlinkAutopilot(link, home),
        link_radio,
        home=home,
        commands=commands,
        out=say,
        seed=seed,
        globals_=globals_,
    )
    try:
        node.run(seconds)
    except KeyboardInterrupt:
        pass
    finally:
        node.runtime.destroy()
        link.close()
        if link_radio is not None:
            link_radio.close()
    if out is not None:
        write_json(out_dir(out) / "summary.json", node.summary())
    if node.runtime.error is not None:
        typer.echo(node.runtime.error, err=True)
