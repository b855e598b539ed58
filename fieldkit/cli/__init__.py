"""The `fieldkit` command line: every command, from this package only.

One module per command group (`buzz`: compile, run, asm, disasm; `sim`: sim run, experiment,
sweep; `node`; `vehicle_sim`; `sitl`; `update`; `keys`: keys init; `patch`: patch apply;
`bag`: bag info, plot, from-tlog; `replay`: a recorded flight into a fresh node; `deploy`:
the node as a systemd service; `doctor`: the field preflight; `frames`: frames decode, the
protocol inspector; `ground`: the ground station and its page, `cmd`: one operator command),
`errors` for the one way errors are reported and the exit-code rule, `output` for where
results go.
Library modules never import this package.
"""

from __future__ import annotations

from importlib import metadata
from typing import Annotated

import typer

from fieldkit.cli import (
    bag,
    buzz,
    deploy,
    doctor,
    frames,
    ground,
    keys,
    node,
    patch,
    replay,
    sim,
    sitl,
    update,
    vehicle_sim,
)
from fieldkit.cli.errors import FieldkitGroup

app = typer.Typer(
    cls=FieldkitGroup,
    help="fieldkit: take a Buzz swarm behavior from design to field deployment.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def version_text() -> str:
    """`fieldkit X.Y.Z`: the installed distribution's version, from its package metadata."""
    try:
        return f"fieldkit {metadata.version('fieldkit')}"
    except metadata.PackageNotFoundError:  # imported from a checkout that was never installed
        import fieldkit

        return f"fieldkit {fieldkit.__version__}"


def _print_version(requested: bool) -> None:
    """`--version`: print it and stop, before any command runs."""
    if requested:
        typer.echo(version_text())
        raise typer.Exit(0)


@app.callback()
def _root(
    version: Annotated[
        bool,
        typer.Option(
            "--version", is_eager=True, callback=_print_version, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    """fieldkit: take a Buzz swarm behavior from design to field deployment."""


# In the order `fieldkit --help` has always listed them.
app.command("vehicle-sim")(vehicle_sim.vehicle_sim_cmd)
app.command("node")(node.node_cmd)
app.command("sitl")(sitl.sitl_cmd)
for _name, _command in buzz.COMMANDS.items():
    app.command(_name)(_command)
app.add_typer(sim.app, name="sim")
app.command("update")(update.update_cmd)
app.add_typer(keys.app, name="keys")
app.add_typer(patch.app, name="patch")
app.add_typer(bag.app, name="bag")
app.command("replay")(replay.replay_cmd)
app.command("deploy")(deploy.deploy_cmd)
app.command("doctor")(doctor.doctor_cmd)
app.add_typer(frames.app, name="frames")
app.command("ground")(ground.ground_cmd)
app.command("cmd")(ground.cmd_cmd)


def main() -> None:
    """Console-script entry point."""
    app()


__all__ = ["app", "main", "version_text"]
