"""`fieldkit replay BAG [--verify]`: a recorded flight into a fresh node, compared or reported."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer

from fieldkit.cli.errors import fail, usage_error
from fieldkit.cli.options import KeysOption, load_keys
from fieldkit.cli.output import progress_bar

#: What the autopilot's messages are called in the report, by flavour (MAVLink's otherwise).
_UNITS = {"dji": "DJI frames", "clearpath": "MCU frames"}


def _speed(text: str | None) -> float | None:
    """`--speed X|max`: X times the recorded pace, or as fast as it goes (None)."""
    if text is None:
        return 1.0
    if text == "max":
        return None
    try:
        value = float(text)
    except ValueError:
        raise usage_error(f"--speed must be a number > 0 or max, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise usage_error(f"--speed must be a number > 0 or max, got {text!r}")
    return value


def _dji_key(config: Path | None, key_file: Path | None) -> tuple[str | None, int | None]:
    """An M100's app key and app id for the replay: the node config's [dji] table, or a key
    file alone (the app id is then the recorded one). Exit 1 for one that cannot be read."""
    from fieldkit.node.config import NodeConfigError, load_config
    from fieldkit.vehicle.dji.crypto import AppKeyError, parse_app_key

    if config is not None and key_file is not None:
        raise usage_error("give one of --config and --dji-app-key-file")
    if config is not None:
        try:
            dji = load_config(config).dji
        except NodeConfigError as e:
            raise fail(e) from None
        return (None, None) if dji is None else (dji.app_key, dji.app_id)
    if key_file is None:
        return None, None
    try:
        mode = key_file.stat().st_mode
        key = key_file.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError) as e:
        reason = e.strerror if isinstance(e, OSError) and e.strerror else "not hex text"
        raise fail(f"{key_file}: cannot read the DJI app key: {reason}") from None
    if mode & 0o077:
        raise fail(f"{key_file}: readable by others (mode {mode & 0o777:o}): chmod 600 {key_file}")
    try:
        parse_app_key(key)
    except AppKeyError as e:
        raise fail(f"{key_file}: {e}") from None
    return key, None


def replay_cmd(
    bag: Annotated[Path, typer.Argument(help="The recording (a bag directory, or FILE.bag).")],
    verify: Annotated[
        bool, typer.Option("--verify", help="Compare with what the recorded node did.")
    ] = False,
    speed: Annotated[
        str | None,
        typer.Option(
            "--speed", metavar="X|max", help="X times the recorded pace, or max [default: 1]."
        ),
    ] = None,
    script: Annotated[
        Path | None,
        typer.Option("--script", help="Replay with this script instead (a .bzz or .bo)."),
    ] = None,
    keys: KeysOption = None,
    profile: Annotated[
        str | None,
        typer.Option("--profile", help="Device profile (for a bag that has none: a tlog's)."),
    ] = None,
    include: Annotated[
        list[Path] | None, typer.Option("-I", "--include", help="Extra include directory.")
    ] = None,
    config: Annotated[
        Path | None,
        typer.Option(
            "--config", help="The node config the robot ran with (an M100's [dji] app key)."
        ),
    ] = None,
    dji_app_key_file: Annotated[
        Path | None,
        typer.Option(
            "--dji-app-key-file", help="An M100's app key (64 hex digits), instead of --config."
        ),
    ] = None,
) -> None:
    """Replay BAG into a fresh node through a loopback serial: --verify compares every message
    to the vehicle, radio frame and script state with the recording (exit 1 at the first
    divergence); without it, report what the script did."""
    from fieldkit.cli.node import load_program
    from fieldkit.errors import FieldkitError
    from fieldkit.node.replay import ReplayError, replay
    from fieldkit.record.bag import BagError
    from fieldkit.record.flight_bag import read_flight
    from fieldkit.robot.profiles import ProfileError, load_profile
    from fieldkit.sim.replay import replay_sim

    # The options first, the bag last: a bad option is its own error, whatever the bag.
    pace = _speed(speed)
    robot_keys = load_keys(keys) if keys is not None else None
    program = load_program(script, [str(d) for d in include or []]) if script else None
    app_key, app_id = _dji_key(config, dji_app_key_file)
    prof = None
    if profile is not None:
        try:
            prof = load_profile(profile)
        except (ProfileError, OSError) as e:
            raise fail(e) from None
    try:
        flight = read_flight(bag)
    except (BagError, OSError) as e:
        # A comparing command: input it cannot read is exit 2, as a diff's.
        raise usage_error(f"{bag}: {e}") from None
    total = len(flight.ticks)
    simulated = flight.meta.get("host") == "sim"
    if simulated and not verify:
        raise usage_error(f"{bag}: a simulated robot's recording replays with --verify")
    try:
        with progress_bar(f"replaying {bag.name}", total) as advance:
            if simulated:  # no autopilot bytes: its runtime on its recorded inputs
                report = replay_sim(flight, program=program, keys=robot_keys, progress=advance)
            else:
                report = replay(
                    flight, program=program, profile=prof, keys=robot_keys, verify=verify,
                    speed=pace, progress=advance, dji_app_key=app_key, dji_app_id=app_id,
                )  # fmt: skip
    except ReplayError as e:
        if verify:
            raise usage_error(f"{bag}: {e}") from None
        raise fail(e) from None
    except FieldkitError as e:
        raise fail(e) from None
    if verify:
        unit = _UNITS.get(str(flight.meta.get("flavour", "")), "MAVLink messages")
        checked = (
            f"{report.ticks} ticks, {report.messages} {unit}, "
            f"{report.frames} radio frames, {report.digests} script states"
        )
        if report.divergence is not None:
            typer.echo(f"replay: diverged after {checked} matched")
            raise fail(f"first divergence: {report.divergence}")
        cut = flight.meta.get("cut_at_tick")
        if cut is not None:
            typer.echo(f"replay: the recording stops in tick {cut} (the node died then)")
        typer.echo(f"replay: identical: {checked} ({bag})")
        return
    done = report.replayed
    orders: dict[str, int] = {}
    for t in done:
        if t.order is not None:
            orders[t.order[0]] = orders.get(t.order[0], 0) + 1
    last = done[-1].state if done else None
    for t in done:
        for line in t.log:
            typer.echo(f"[tick {t.tick}] {line}")
    typer.echo(
        f"replay: {report.ticks} ticks; final state {last}; orders "
        f"{', '.join(f'{k} {n}' for k, n in sorted(orders.items())) or 'none'} ({bag})"
    )


__all__ = ["replay_cmd"]
