"""`fieldkit keys init DIR`: the operator's signing key pair and the swarm's encryption key."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from fieldkit.cli.errors import fail
from fieldkit.cli.output import wrote

app = typer.Typer(
    help="Keys for over-the-air updates: the operator's signing key and the swarm key.",
    no_args_is_help=True,
)


@app.command("init")
def init_cmd(
    directory: Annotated[Path, typer.Argument(help="Directory for the three key files.")],
) -> None:
    """Create DIR/operator.key, DIR/operator.pub and DIR/swarm.key (never overwrites)."""
    from fieldkit.update.keys import KeyFileError, init_keys

    try:
        paths = init_keys(directory)
    except KeyFileError as e:
        raise fail(e) from None
    for path in (paths.operator_key, paths.operator_pub, paths.swarm_key):
        wrote(path)
    pub, swarm = paths.robot_files
    typer.echo(
        f"robots need {pub} and {swarm} (copy them to each robot's --keys directory);\n"
        f"{paths.operator_key} signs updates: keep it on this machine, never on a robot"
    )


__all__ = ["app"]
