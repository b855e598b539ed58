"""`fieldkit vehicle-sim`: a simulated vehicle, speaking its profile's protocol, on a pty.

    fieldkit vehicle-sim --profile solo                      # prints a pty path: open it
    fieldkit vehicle-sim --profile solo --port ttySIM        # ./ttySIM -> the pty
    fieldkit vehicle-sim --profile solo --port tcpin:0.0.0.0:5760 --home 45.5,-73.6
    fieldkit vehicle-sim --profile husky                     # MCU pty, then GPS pty, printed

The flavour picks the machine: ArduPilot (Copter, or Rover for a ground profile) for
"ardupilot", a Clearpath Husky (its MCU on `--port`, its GPS receiver on `--gps-port`) for
"clearpath" (fieldkit.vehicle.sim.husky).

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
from fieldkit.robot.profiles import Profile, ProfileError, load_profile

if TYPE_CHECKING:
    from fieldkit.vehicle.pty import PtyPair
    from fieldkit.vehicle.sim.husky_pty import SimHuskyPorts
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
    gps_port: Annotated[
        str | None,
        typer.Option(
            "--gps-port",
            help="A Clearpath base's GPS line: 'auto' (default; a new pty, its path printed "
            "on the line after the MCU's), a bare name linked to it here, or a device path.",
        ),
    ] = None,
) -> None:
    """Run a simulated vehicle: ArduPilot (Copter, Rover) or a Clearpath Husky (MCU + GPS)."""
    # Imported here: pymavlink is slow to import, and every fieldkit command loads this file.
    from fieldkit.vehicle.pty import open_pty
    from fieldkit.vehicle.sim.ardupilot import VehicleSimError
    from fieldkit.vehicle.sim.vehicle import SimVehicle

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
    if prof.autopilot.flavour == "clearpath":
        _husky(prof, port, gps_port or "auto", home_ll, baud, rate, gps_delay)
        return
    if gps_port is not None:
        raise fail(f"--gps-port is for a Clearpath base; {prof.name}'s GPS is its autopilot's")

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
            sim = SimVehicle(
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
    kind = "ArduPilot Rover" if sim.ground else "ArduCopter"
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


def _pty_or_path(name: str, made: list[Path], ptys: list[PtyPair]) -> tuple[str | int, str]:
    """A line for the simulator: (pty master or device path, the path to print or show)."""
    from fieldkit.vehicle.pty import open_pty

    if not _is_pty_request(name):
        return name, name
    wanted = Path(name) if name != "auto" else None
    if wanted is not None and (wanted.exists() or wanted.is_symlink()):
        raise fail(f"{name} already exists: remove it or choose another name")
    try:
        pty = open_pty()
    except OSError as e:
        raise fail(f"cannot create a pty: {e.strerror or e}") from None
    ptys.append(pty)
    if wanted is None:
        return pty.master, pty.slave_path
    try:
        wanted.symlink_to(pty.slave_path)
    except OSError as e:
        raise fail(f"cannot create {name}: {e.strerror or e}") from None
    made.append(wanted)
    return pty.master, os.path.abspath(wanted)


def _husky(
    prof: Profile,
    port: str,
    gps_port: str,
    home: tuple[float, float],
    baud: int,
    rate: float,
    gps_delay: float,
) -> None:
    """A simulated Husky: its MCU on `port`, its GPS on `gps_port`; each pty's path printed
    (the MCU's first, the GPS's on the next line), run until Ctrl-C or SIGTERM."""
    from fieldkit.vehicle.sim.husky import HuskySimError
    from fieldkit.vehicle.sim.husky_pty import SimHuskyPorts

    made: list[Path] = []
    ptys: list[PtyPair] = []
    try:
        mcu, mcu_shown = _pty_or_path(port, made, ptys)
        gps, gps_shown = _pty_or_path(gps_port, made, ptys)
        gps_baud = prof.gps.baud if prof.gps is not None else 19200
        # --baud's default is MAVLink's 57600: the MCU's line is the profile's unless told.
        mcu_baud = prof.autopilot.baud if baud == 57600 else baud
        try:
            sim = SimHuskyPorts(
                prof, mcu, gps, baud=mcu_baud, gps_baud=gps_baud, home=home,
                gps_fix_delay_s=gps_delay,
            )  # fmt: skip
        except HuskySimError as e:
            raise fail(e) from None
        if isinstance(mcu, int) or isinstance(gps, int):
            # The paths alone, MCU first, for scripts (`read MCU; read GPS`).
            print(mcu_shown, flush=True)
            print(gps_shown, flush=True)
        typer.echo(
            f"vehicle-sim: {prof.name} (Clearpath Husky: MCU on {mcu_shown}, GPS "
            f"{sim.gps_protocol.upper()} on {gps_shown}) at {home[0]},{home[1]}; Ctrl-C to stop",
            err=True,
        )
        _run_until_stopped(sim, rate)
    finally:
        for link in made:
            try:
                link.unlink()
            except OSError:
                pass
        for pty in ptys:
            pty.close()


def _run_until_stopped(sim: SimHuskyPorts, rate: float) -> None:
    """Run `sim` in real time, its log on stderr, until Ctrl-C or SIGTERM; then close it."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("vehicle-sim: %(message)s"))
    logger = logging.getLogger("fieldkit.vehicle_sim")
    logger.addHandler(handler)
    old_level = logger.level
    logger.setLevel(logging.INFO)
    stop = threading.Event()
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
