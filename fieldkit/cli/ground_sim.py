"""`fieldkit sim run ... --ground` (the simulation in real time with a ground station, its
page and a UDP gateway, fieldkit/ground/live.py) and `fieldkit sitl ... --ground` (the same
beside a SITL swarm): the command-line side both share."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import typer

from fieldkit.cli.errors import fail
from fieldkit.cli.output import out_dir
from fieldkit.cli.signals import stop_on_signals

if TYPE_CHECKING:
    from fieldkit.ground.live import LiveGround
    from fieldkit.sim.simulator import Simulation


def ground_keys(out: Path, keys: Path | None) -> Path:
    """The keys a ground run signs with: `--keys`, else OUT/keys (made now if absent):
    operator commands must be signed, so a run with a ground station is a signed run."""
    if keys is not None:
        return keys
    from fieldkit.errors import FieldkitError
    from fieldkit.update.keys import KeyPaths, init_keys

    out_dir(out)
    made = out / "keys"
    paths = KeyPaths(made)
    if all(p.exists() for p in (paths.operator_key, paths.operator_pub, paths.swarm_key)):
        return made
    try:
        init_keys(made)
    except FieldkitError as e:
        raise fail(e) from None
    typer.echo(
        f"ground: keys for the run made in {made} (give --keys {made} to fieldkit cmd)", err=True
    )
    return made


def drawing(globals_: Mapping[str, object], script_name: str) -> dict[str, Any]:
    """What the page draws for this run (`make_station`'s shape, root_id, margin): the task
    graph of `--set SHAPE` (task allocation's "P" by default) at ROOT_ID, coverage's MARGIN."""
    shape = globals_.get("SHAPE")
    if shape is None and "task_allocation" in script_name:
        shape = "P"
    root = globals_.get("ROOT_ID", 1)
    margin = globals_.get("MARGIN", 20.0)
    return {
        "shape": None if shape is None else str(shape),
        "root_id": root if isinstance(root, int) else 1,
        "margin": float(margin) if isinstance(margin, int | float) else 20.0,
    }


def port_taken(http_port: int, e: OSError) -> typer.Exit:
    """The `error:` of a page (or gateway) that cannot be served."""
    return fail(
        f"--ground-port {http_port}: cannot serve the page: {e.strerror or e}\n"
        "  hint: another program uses the port: give --ground-port with another one"
    )


def announce(live: LiveGround, keys: Path | None) -> None:
    """Tell the operator where the page and the radio gateway are (stderr)."""
    for line in live.banner(keys):
        typer.echo(line, err=True)


def run_with_ground(
    sim: Simulation,
    keys: Path | None,
    seconds: float | None,
    http_port: int,
    globals_: Mapping[str, object],
    after_step: Callable[[], None],
) -> None:
    """Run `sim` in real time with its ground station until `seconds` (None: Ctrl-C or
    SIGTERM, a normal end: the results are written as for any run)."""
    from fieldkit.ground.live import attach, run_live
    from fieldkit.sim.simulator import tuned_memory

    # The handlers go in before the banner: a Ctrl-C once the operator has seen it is a
    # normal end, never an interrupted command.
    with stop_on_signals() as stop:
        try:
            live = attach(
                sim, keys, http_port=http_port, **drawing(globals_, sim.config.script.name)
            )
        except OSError as e:
            raise port_taken(http_port, e) from None
        until = "until Ctrl-C" if seconds is None else f"for {seconds:g} s"
        announce(live, keys)
        typer.echo(f"ground: simulating {sim.config.robots} robots in real time {until}", err=True)
        try:
            with tuned_memory():
                run_live(sim, seconds, stop=stop, after_step=after_step)
        except KeyboardInterrupt:  # a second Ctrl-C: a normal end all the same
            stop.set()
        finally:
            live.close()
    if stop.is_set():
        typer.echo("ground: stopped", err=True)
