"""The `fieldkit` command line: compile, run, assemble and disassemble Buzz programs."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Any

import typer

import bvm
from bvm.errors import BuzzAsmError, BuzzCompileError, BuzzError, BuzzLoadError
from bvm.values import format_value

app = typer.Typer(
    help="fieldkit: take a Buzz swarm behavior from design to field deployment.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _add_subcommands() -> None:
    from fieldkit.sim.cli import sim_app

    app.add_typer(sim_app, name="sim")
    from fieldkit.autopilot.cli import vehicle_sim_cmd

    app.command("vehicle-sim")(vehicle_sim_cmd)
    from fieldkit.node.cli import node_cmd

    app.command("node")(node_cmd)
    from fieldkit.sitl_cli import sitl_cmd

    app.command("sitl")(sitl_cmd)


_add_subcommands()


def _fail(message: str) -> typer.Exit:
    """Print an error on stderr and return the exit to raise."""
    typer.echo(message, err=True)
    return typer.Exit(1)


def _outputs(script: Path, out: Path | None) -> tuple[Path, Path, Path]:
    bo = out if out is not None else script.with_suffix(".bo")
    return bo, bo.with_suffix(".bdb"), bo.with_suffix(".basm")


@app.command("compile")
def compile_cmd(
    script: Annotated[Path, typer.Argument(help="The .bzz source file.")],
    include: Annotated[
        list[Path] | None, typer.Option("-I", "--include", help="Extra include directory.")
    ] = None,
    out: Annotated[Path | None, typer.Option("-o", "--output", help="Output .bo path.")] = None,
    asm: Annotated[bool, typer.Option("--asm", help="Also write the .basm assembly.")] = False,
) -> None:
    """Compile SCRIPT.bzz to .bo bytecode and .bdb debug info (beside it by default)."""
    dirs = [str(d) for d in include or []]
    try:
        basm = bvm.compile_to_asm(_read_source(script), str(script), dirs)
        program = bvm.assemble(basm, str(script))
    except (BuzzCompileError, BuzzAsmError) as e:
        raise _fail(str(e)) from None
    bo, bdb, basm_path = _outputs(script, out)
    try:
        bo.write_bytes(program.bytecode)
        bdb.write_bytes(program.debug)
        if asm:
            basm_path.write_text(basm, encoding="latin-1")
    except OSError as e:
        raise _fail(f"{e.filename}: cannot write: {e.strerror}") from None


def _read_source(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as e:
        raise BuzzCompileError(str(path), 0, 0, f"cannot read file: {e.strerror or e}") from None


def _load(file: Path) -> bvm.Program:
    if file.suffix == ".bo":
        return bvm.Program.load(file)
    return bvm.compile_source(_read_source(file), str(file))


def _log_to(stream: Any) -> Any:
    """The reference bzzrun `log`: arguments formatted and concatenated, then a newline."""
    raw = getattr(stream, "buffer", None)
    if raw is not None:

        def log(*args: Any) -> None:
            raw.write("".join(map(format_value, args)).encode("latin-1", "replace") + b"\n")

    else:

        def log(*args: Any) -> None:
            stream.write("".join(map(format_value, args)) + "\n")

    return log


@app.command("run")
def run_cmd(
    file: Annotated[Path, typer.Argument(help="A .bzz script or a compiled .bo.")],
    robot_id: Annotated[int, typer.Option("--robot-id", help="The robot id (`id`).")] = 0,
    steps: Annotated[
        int | None, typer.Option("--steps", help="Then call init(), step() N times, destroy().")
    ] = None,
    seed: Annotated[
        int | None, typer.Option("--seed", help="Seed math.rng (default: the clock).")
    ] = None,
) -> None:
    """Run a Buzz program: its global code, then optionally init/step/destroy."""
    try:
        program = _load(file)
    except (BuzzCompileError, BuzzAsmError, BuzzLoadError) as e:
        raise _fail(str(e)) from None
    vm = bvm.VM(robot_id=robot_id, rng_seed=seed)
    try:
        vm.load(program)
        log = _log_to(sys.stdout)
        vm.globals["log"] = vm.new_native(lambda _self, *args: log(*args), None, "log")
        vm.execute()
        if steps is not None:
            vm.call("init")
            for _ in range(steps):
                vm.call("step")
            vm.call("destroy")
    except BuzzError as e:
        sys.stdout.flush()
        raise _fail(str(e) if e.location else f"{file}: {e}") from None
    finally:
        sys.stdout.flush()


@app.command("asm")
def asm_cmd(
    file: Annotated[Path, typer.Argument(help="A .basm assembly file.")],
    out: Annotated[Path | None, typer.Option("-o", "--output", help="Output .bo path.")] = None,
) -> None:
    """Assemble FILE.basm into .bo and .bdb."""
    try:
        program = bvm.assemble(file.read_text(encoding="latin-1"), str(file))
    except OSError as e:
        raise _fail(f"{file}: cannot read: {e.strerror}") from None
    except BuzzAsmError as e:
        raise _fail(str(e)) from None
    bo, bdb, _ = _outputs(file, out)
    bo.write_bytes(program.bytecode)
    bdb.write_bytes(program.debug)


@app.command("disasm")
def disasm_cmd(file: Annotated[Path, typer.Argument(help="A .bo bytecode file.")]) -> None:
    """Print the assembly of FILE.bo (uses the .bdb beside it when present)."""
    from bvm.disasm import disassemble

    try:
        bytecode = file.read_bytes()
        bdb = file.with_suffix(".bdb")
        debug = bdb.read_bytes() if bdb.exists() else None
    except OSError as e:
        raise _fail(f"{file}: cannot read: {e.strerror}") from None
    text = disassemble(bytecode, debug)
    sys.stdout.buffer.write(text.encode("latin-1", "replace"))


def main() -> None:
    """Console-script entry point."""
    app()
