"""`fieldkit vehicle-sim`: a simulated vehicle on a pty, a serial port or a URL.

    fieldkit vehicle-sim --profile solo                      # prints a pty path: open it
    fieldkit vehicle-sim --profile husky --port ttySIM       # ./ttySIM -> the pty
    fieldkit vehicle-sim --profile solo --port tcpin:0.0.0.0:5760 --home 45.5,-73.6
    fieldkit vehicle-sim --profile m100 --port auto          # a DJI M100 flight controller
    fieldkit vehicle-sim --profile husky                     # MCU pty, then GPS pty, printed

The profile's `autopilot.flavour` picks the machine: ArduPilot (Copter or Rover) or PX4 (the
Spiri) speaking MAVLink, or for "dji" an M100 flight controller speaking DJI's OPEN protocol
(`fieldkit.vehicle.sim.dji`), which accepts only the app id `--app-id` and the app key
`--app-key` (by default the test pair the tests use; never a real key on a command line), or
for "clearpath" a Husky: its MCU on `--port`, its GPS receiver on `--gps-port`
(`fieldkit.vehicle.sim.husky`).

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
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Protocol

import typer

from fieldkit.cli.errors import fail
from fieldkit.cli.options import parse_home
from fieldkit.cli.signals import stop_on_signals
from fieldkit.robot.profiles import ProfileError, load_profile

if TYPE_CHECKING:
    from fieldkit.robot.profiles import Profile
    from fieldkit.vehicle.pty import PtyPair


class _Machine(Protocol):
    """What `_serve` runs: a simulated machine on its line."""

    def run(self, rate_hz: float, stop: threading.Event) -> None:
        """Step in real time until `stop` is set."""

    def close(self) -> None:
        """Close the line it opened."""


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
    baud: Annotated[
        int | None,
        typer.Option(
            "--baud",
            help="Serial speed for a device path [default: 57600; the profile's for DJI].",
        ),
    ] = None,
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
    app_id: Annotated[
        int | None,
        typer.Option("--app-id", help="DJI only: the app id it accepts [default: the test id]."),
    ] = None,
    app_key: Annotated[
        str | None,
        typer.Option(
            "--app-key",
            help="DJI only: the app key (64 hex digits) it decrypts with [default: the test key].",
        ),
    ] = None,
    rc_mode: Annotated[
        str, typer.Option("--rc-mode", help="DJI only: the RC mode switch at start, P, A or F.")
    ] = "F",
    gps_port: Annotated[
        str | None,
        typer.Option(
            "--gps-port",
            help="A Clearpath base's GPS line: 'auto' (default; a new pty, its path printed "
            "on the line after the MCU's), a bare name linked to it here, or a device path.",
        ),
    ] = None,
) -> None:
    """Run a simulated vehicle: ArduPilot, PX4, a DJI M100 or a Clearpath Husky, by flavour."""

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
    dji = prof.autopilot.flavour == "dji"
    if not dji and (app_id is not None or app_key is not None):
        raise fail(
            f"--app-id and --app-key are for DJI profiles; {prof.name} speaks MAVLink "
            f"(autopilot.flavour {prof.autopilot.flavour})"
        )
    if rc_mode not in ("P", "A", "F"):
        raise fail(f"--rc-mode must be P, A or F, got {rc_mode!r}")
    clearpath = prof.autopilot.flavour == "clearpath"
    if gps_port is not None and not clearpath:
        raise fail(f"--gps-port is for a Clearpath base; {prof.name}'s GPS is its autopilot's")

    made: list[Path] = []  # links we made: only those are ours to remove
    ptys: list[PtyPair] = []
    try:
        device, shown = _pty_or_path(port, made, ptys)
        lines = [shown]
        if clearpath:
            gps, gps_shown = _pty_or_path(gps_port or "auto", made, ptys)
            lines.append(gps_shown)
            sim, banner = _husky_machine(prof, device, gps, home_ll, baud, gps_delay)
            banner = banner.format(mcu=shown, gps=gps_shown)
            where = ""
        elif dji:
            sim, banner = _dji_machine(
                prof, device, home_ll, baud, gps_delay, stream_hz, app_id, app_key, rc_mode
            )
            where = shown
        else:
            sim, banner = _ardupilot_machine(
                prof, device, home_ll, baud, gps_delay, stream_hz, sysid
            )
            where = shown
        if ptys:
            # The paths alone, one a line (a Husky's MCU, then its GPS), for scripts
            # (`read PORT < <(...)`).
            for line in lines:
                print(line, flush=True)
        typer.echo(
            f"vehicle-sim: {banner} at {home_ll[0]},{home_ll[1]}"
            + (f" on {where}" if where else "")
            + "; Ctrl-C to stop",
            err=True,
        )
        _serve(sim, rate)
    finally:
        for link in made:
            try:
                link.unlink()
            except OSError:
                pass
        for pty in ptys:
            pty.close()


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


def _ardupilot_machine(
    prof: Profile,
    device: str | int,
    home: tuple[float, float],
    baud: int | None,
    gps_delay: float,
    stream_hz: float,
    sysid: int,
) -> tuple[_Machine, str]:
    """The simulated MAVLink autopilot (ArduPilot, or PX4 for flavour px4) on its line, and
    its banner's description."""
    from fieldkit.vehicle.sim.ardupilot import VehicleSimError
    from fieldkit.vehicle.sim.vehicle import open_sim_vehicle

    try:
        sim = open_sim_vehicle(
            prof,
            device,
            home=home,
            baud=baud if baud is not None else 57600,
            sysid=sysid,
            gps_fix_delay_s=gps_delay,
            default_rate_hz=stream_hz,
        )
    except VehicleSimError as e:
        raise fail(e) from None
    return sim, f"{prof.name} ({sim.kind}, system {sim.sysid})"


def _dji_machine(
    prof: Profile,
    device: str | int,
    home: tuple[float, float],
    baud: int | None,
    gps_delay: float,
    stream_hz: float,
    app_id: int | None,
    app_key: str | None,
    rc_mode: str,
) -> tuple[_Machine, str]:
    """The simulated M100 flight controller on its line, and its banner's description."""
    from fieldkit.vehicle.dji.crypto import AppKeyError, parse_app_key
    from fieldkit.vehicle.sim.dji import TEST_APP_ID, TEST_APP_KEY, SimM100Error
    from fieldkit.vehicle.sim.dji_vehicle import SimM100Vehicle

    if app_id is not None and not 0 < app_id <= 0xFFFFFFFF:
        raise fail(f"--app-id must be a positive 32-bit number, got {app_id}")
    if app_key is not None:
        try:
            parse_app_key(app_key)
        except AppKeyError as e:
            raise fail(f"--app-key: {e}") from None
    try:
        sim = SimM100Vehicle(
            prof,
            device,
            baud=baud if baud is not None else prof.autopilot.baud,
            app_id=app_id if app_id is not None else TEST_APP_ID,
            app_key=app_key if app_key is not None else TEST_APP_KEY,
            home=home,
            gps_fix_delay_s=gps_delay,
            broadcast_hz=stream_hz if stream_hz > 0 else None,
            rc_mode=rc_mode,
        )
    except SimM100Error as e:
        raise fail(e) from None
    key = "the test key" if app_key is None else "the given key"
    return sim, (
        f"{prof.name} (DJI M100 flight controller, OPEN protocol; app id {sim.app_id}, {key}; "
        f"RC mode switch {rc_mode})"
    )


def _husky_machine(
    prof: Profile,
    mcu: str | int,
    gps: str | int,
    home: tuple[float, float],
    baud: int | None,
    gps_delay: float,
) -> tuple[_Machine, str]:
    """The simulated Husky, its MCU and its GPS each on a line, and its banner's description
    (with `{mcu}` and `{gps}` for where each line is)."""
    from fieldkit.vehicle.sim.husky import HuskySimError
    from fieldkit.vehicle.sim.husky_pty import SimHuskyPorts

    gps_baud = prof.gps.baud if prof.gps is not None else 19200
    try:
        sim = SimHuskyPorts(
            prof, mcu, gps, baud=baud if baud is not None else prof.autopilot.baud,
            gps_baud=gps_baud, home=home, gps_fix_delay_s=gps_delay,
        )  # fmt: skip
    except HuskySimError as e:
        raise fail(e) from None
    gps_kind = sim.gps_protocol.upper()
    return sim, f"{prof.name} (Clearpath Husky: MCU on {{mcu}}, GPS {gps_kind} on {{gps}})"


def _serve(sim: _Machine, rate: float) -> None:
    """Run `sim` in real time, its log on stderr, until Ctrl-C or SIGTERM; then close it."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("vehicle-sim: %(message)s"))
    logger = logging.getLogger("fieldkit.vehicle_sim")
    logger.addHandler(handler)
    old_level = logger.level
    logger.setLevel(logging.INFO)
    # Ctrl-C and SIGTERM end the run alike, through handlers of their own: a process
    # started in the background of a script inherits SIGINT ignored, and Python then
    # raises no KeyboardInterrupt (a stress run of the suite hung on exactly that).
    with stop_on_signals() as stop:
        try:
            sim.run(rate, stop)
        finally:
            logger.removeHandler(handler)
            logger.setLevel(old_level)
            sim.close()
    typer.echo("vehicle-sim: stopped", err=True)
