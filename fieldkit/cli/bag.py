"""`fieldkit bag info`, `bag plot` and `bag from-tlog`: flight recordings (fieldkit.record)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from fieldkit.cli.errors import fail
from fieldkit.cli.output import wrote

app = typer.Typer(
    help="Flight recordings (rosbags, as `--record` writes them): inspect, convert tlogs.",
    no_args_is_help=True,
)


@app.command("info")
def info_cmd(
    bag: Annotated[
        Path, typer.Argument(help="The recording: a directory (ROS 2, MCAP) or a .bag (ROS 1).")
    ],
) -> None:
    """Print what BAG holds: topics with types and counts, duration, robot, script and its
    SHA-256, storage and parts, and any repair a crash made necessary."""
    from fieldkit.record.bag import BagError, BagReader
    from fieldkit.record.info import describe

    try:
        text = describe(BagReader(bag))
    except BagError as e:
        raise fail(e) from None
    typer.echo(text)


@app.command("plot")
def plot_cmd(
    bag: Annotated[
        Path, typer.Argument(help="The recording: a directory (ROS 2, MCAP) or a .bag (ROS 1).")
    ],
    output: Annotated[Path, typer.Option("-o", "--output", help="The PNG to write.")],
) -> None:
    """Draw BAG: the track coloured by the script's state, the altitude, the battery, and the
    script's state over time with the safety supervisor's events."""
    from fieldkit.record.bag import BagError
    from fieldkit.record.plot import plot_bag

    if output.is_dir():
        raise fail(f"-o {output}: is a directory, not a file to write")
    if not output.parent.is_dir():
        raise fail(f"-o {output}: no directory {output.parent}")
    try:
        plot_bag(bag, output)
    except BagError as e:
        raise fail(e) from None
    except OSError as e:
        raise fail(f"-o {output}: cannot write: {e.strerror or e}") from None
    wrote(output)


@app.command("from-tlog")
def from_tlog_cmd(
    tlog: Annotated[Path, typer.Argument(help="A MAVLink telemetry log (.tlog).")],
    output: Annotated[
        Path,
        typer.Option(
            "-o", "--output", help="The bag to write: a new directory, or NAME.bag for ROS 1."
        ),
    ],
) -> None:
    """Convert a MAVLink telemetry log (Mission Planner, MAVProxy) into a bag that
    `fieldkit replay` can feed to a node: its bytes on /autopilot/rx, decoded frames on
    /mavlink/from, GPS on /fix, battery on /battery."""
    from fieldkit.record.bag import BagError
    from fieldkit.record.tlog import TlogError, tlog_to_bag

    try:
        report = tlog_to_bag(tlog, output)
    except (BagError, TlogError) as e:
        raise fail(e) from None
    for part in report.parts:
        wrote(part)
    scan = report.scan
    skipped = (
        f"; skipped {scan.garbage_bytes} bytes of garbage in {scan.garbage_runs} "
        + ("place" if scan.garbage_runs == 1 else "places")
        if scan.garbage_bytes
        else ""
    )
    typer.echo(
        f"{scan.records} records over {report.duration_s:.1f} s: {report.messages} MAVLink "
        f"messages ({report.undecoded} records held none that decode){skipped}; "
        f"{report.fixes} positions, {report.batteries} battery readings; robot {report.robot_id}"
    )


__all__ = ["app"]
