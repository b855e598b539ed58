"""`fieldkit vehicle-sim`: a simulated autopilot on a pty, a serial port or a URL.

The profile's `autopilot.flavour` picks the machine: PX4 for "px4" (the Spiri), ArduPilot
(Copter, or Rover for a ground profile) otherwise.

    fieldkit vehicle-sim --profile solo                      # prints a pty path: open it
    fieldkit vehicle-sim --profile husky --port ttySIM       # ./ttySIM -> the pty
    fieldkit vehicle-sim --profile solo --port tcpin:0.0.0.0:5760 --home 45.5,-73.6

With `--port auto` (the default) or any bare name, a pseudo-terminal is created and its path
is the first line on stdout, for the node (`autopilot.url`) to open; a bare name other than
"auto" is also made a symbolic link to it in the current directory. A path (`/dev/ttyUSB1`)
or a pymavlink connection string (`tcpin:`, `udpout:`...) is opened as it is. Runs until
Ctrl-C (or SIGTERM); what the vehicle does is logged on stderr.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from fieldkit.cli.errors import fail
from fieldkit.cli.options import parse_home
from fieldkit.robot.profiles import ProfileError, load_profile

if TYPE_CHECKING:
    from fieldkit.vehicle.pty import PtyPair
    from fieldkit.vehicle.sim.vehicle import SimVehicle


def _is_pty_request(port: str) -> bool:
    """A bare name (no directory, no URL scheme) asks for a new pty."""
    return "/" not in port and ":" not in port and "\\" not in port


def vehicle_sim_cmd(
    profile: Annotated[
        str, typer.Option("--profile", help="Device profile: a name (solo, husky...) or a .toml.")
    ],
    port: Annotated[
        str,
        typer.Option(
            "--port",
            help="'auto' (or a bare name, linked to it here): a new pty, path printed; "
            "a device path; or a pymavlink URL such as tcpin:0.0.0.0:5760.",
        ),
    ] = "auto",
    home: Annotated[
        str | None,
        typer.Option(
            "--home",
            help="Where the vehicle boots: LAT,LON in degrees (default: fieldkit's home in "
            "Montreal, 45.5017,-73.5673, geo.DEFAULT_HOME).",
        ),
    ] = None,
    baud: Annotated[int, typer.Option("--baud", help="Serial speed for a device path.")] = 57600,
    rate: Annotated[float, typer.Option("--rate", help="Physics steps per second.")] = 50.0,
    gps_delay: Annotated[
        float, typer.Option("--gps-delay", help="Seconds from boot to a 3D GPS fix.")
    ] = 2.0,
    stream_hz: Annotated[
        float,
        typer.Option(
            "--stream-hz",
            help="Telemetry rate before anyone asks (0: heartbeats only, until the node "
            "requests streams).",
        ),
    ] = 0.0,
    sysid: Annotated[int, typer.Option("--sysid", help="MAVLink system id.")] = 1,
) -> None:
    """Run a simulated autopilot: PX4 for a px4 profile, else ArduPilot (Copter or Rover)."""
    # Imported here: pymavlink is slow to import, and every fieldkit command loads this file.
    from fieldkit.vehicle.pty import open_pty
    from fieldkit.vehicle.sim.ardupilot import VehicleSimError
    from fieldkit.vehicle.sim.vehicle import open_sim_vehicle

    home_ll = parse_home(home)
    try:
        prof = load_profile(profile)
    except (ProfileError, OSError) as e:
        raise fail(e) from None
    if not (math.isfinite(rate) and rate > 0):
        raise fail(f"--rate must be > 0, got {rate}")
    if not (math.isfinite(gps_delay) and gps_delay >= 0):
        raise fail(f"--gps-delay must be >= 0, got {gps_delay}")
    if not (math.isfinite(stream_hz) and stream_hz >= 0):
        raise fail(f"--stream-hz must be >= 0, got {stream_hz}")
    if not 1 <= sysid <= 255:
        raise fail(f"--sysid must be in 1..255, got {sysid}")

    pty: PtyPair | None = None
    link: Path | None = None  # set once we have made it: only then is it ours to remove
    try:
        if _is_pty_request(port):
            wanted = Path(port) if port != "auto" else None
            if wanted is not None and (wanted.exists() or wanted.is_symlink()):
                raise fail(f"{port} already exists: remove it or choose another name")
            try:
                pty = open_pty()
            except OSError as e:
                raise fail(f"cannot create a pty: {e.strerror or e}") from None
            device: str | int = pty.master
            if wanted is not None:
                try:
                    wanted.symlink_to(pty.slave_path)
                except OSError as e:
                    raise fail(f"cannot create {port}: {e.strerror or e}") from None
                link = wanted
        else:
            device = port
        try:
            sim = open_sim_vehicle(
                prof,
                device,
                home=home_ll,
                baud=baud,
                sysid=sysid,
                gps_fix_delay_s=gps_delay,
                default_rate_hz=stream_hz,
            )
        except VehicleSimError as e:
            raise fail(e) from None
        _serve(sim, prof.name, home_ll, port, pty, link, rate)
    finally:
        if link is not None:
            try:
                link.unlink()
            except OSError:
                pass
        if pty is not None:
            pty.close()


def _serve(
    sim: SimVehicle,
    name: str,
    home: tuple[float, float],
    port: str,
    pty: PtyPair | None,
    link: Path | None,
    rate: float,
) -> None:
    """Print where to connect, run in real time until Ctrl-C or SIGTERM, then close."""
    if pty is not None:
        # First line on stdout: the path alone, for scripts (`read PORT < <(...)`).
        print(os.path.abspath(link) if link is not None else pty.slave_path, flush=True)
    kind = sim.kind
    where = pty.slave_path if pty is not None else port
    typer.echo(
        f"vehicle-sim: {name} ({kind}, system {sim.sysid}) at {home[0]},{home[1]} on {where}; "
        "Ctrl-C to stop",
        err=True,
    )
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("vehicle-sim: %(message)s"))
    logger = logging.getLogger("fieldkit.vehicle_sim")
    logger.addHandler(handler)
    old_level = logger.level
    logger.setLevel(logging.INFO)
    stop = threading.Event()
    # Ctrl-C and SIGTERM end the run alike. SIGINT gets a handler of its own: a process
    # started in the background of a script inherits SIGINT ignored, and Python then
    # raises no KeyboardInterrupt (a stress run of the suite hung on exactly that).
    old = {
        sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)
    }
    try:
        sim.run(rate, stop)
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)
        logger.removeHandler(handler)
        logger.setLevel(old_level)
        sim.close()
    typer.echo("vehicle-sim: stopped", err=True)
