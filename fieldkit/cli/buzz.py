"""`fieldkit compile | run | asm | disasm`: the Buzz language tools, as the reference's bzzc,
bzzrun, bzzasm and bzzdeasm."""

from __future__ import annotations

import contextlib
import logging
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Annotated, Any

import typer

import bvm
from bvm import srcmap
from bvm.errors import (
    BuzzAsmError,
    BuzzBudgetExceeded,
    BuzzCompileError,
    BuzzError,
    BuzzLoadError,
)
from bvm.values import format_log
from fieldkit import resources
from fieldkit.cli.errors import EXIT_FAILURE, fail, report


def _outputs(script: Path, out: Path | None) -> tuple[Path, Path, Path]:
    """The .bo, .bdb and .basm paths: `out` and its siblings, else beside the script."""
    bo = out if out is not None else script.with_suffix(".bo")
    return bo, bo.with_suffix(".bdb"), bo.with_suffix(".basm")


def _write(path: Path, data: bytes) -> None:
    """Write an output file, creating its directory (`-o out/b.bo` with no out/ yet)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)


def compile_cmd(
    script: Annotated[Path, typer.Argument(help="The .bzz source file.")],
    include: Annotated[
        list[Path] | None, typer.Option("-I", "--include", help="Extra include directory.")
    ] = None,
    out: Annotated[Path | None, typer.Option("-o", "--output", help="Output .bo path.")] = None,
    asm: Annotated[bool, typer.Option("--asm", help="Also write the .basm assembly.")] = False,
) -> None:
    """Compile SCRIPT.bzz to .bo bytecode, .bdb debug info and the .bpos source map
    (beside it by default)."""
    dirs = [str(d) for d in include or []]
    try:
        source = _read_source(script)
        program = bvm.compile_source(source, str(script), dirs)
        basm = bvm.compile_to_asm(source, str(script), dirs) if asm else ""
    except (BuzzCompileError, BuzzAsmError) as e:
        raise fail(e) from None
    bo, bdb, basm_path = _outputs(script, out)
    try:
        _write(bo, program.bytecode)
        _write(bdb, program.debug)
        if program.srcmap is not None:  # exact error positions (docs/bytecode.md#bpos-layout)
            _write(bo.with_suffix(".bpos"), srcmap.encode(program.srcmap, program.bytecode))
        if asm:
            basm_path.write_text(basm, encoding="latin-1")
    except OSError as e:
        raise fail(f"{e.filename}: cannot write: {e.strerror}") from None


def _read_source(path: Path) -> bytes:
    """The script's bytes; a file that cannot be read is a compile error at its start."""
    try:
        return path.read_bytes()
    except OSError as e:
        raise BuzzCompileError(str(path), 0, 0, f"cannot read file: {e.strerror or e}") from None


def _log_to(stream: IO[str]) -> Callable[..., None]:
    """`log`: one line in the one format every host prints (bvm.values.format_log)."""
    raw = getattr(stream, "buffer", None)
    if raw is not None:

        def log(*args: Any) -> None:
            raw.write(format_log(args).encode("latin-1", "replace") + b"\n")

    else:

        def log(*args: Any) -> None:
            stream.write(format_log(args) + "\n")

    return log


#: `run`'s default budget: loop iterations in each of the global code, init(), each step()
#: and destroy() (the VM's `max_ticks`). An endless loop ends in about a second; a script
#: that really loops longer asks for more with --max-loops.
DEFAULT_MAX_LOOPS = 10_000_000

#: Globals the robot API provides (docs/script-api.md) that a bare VM leaves nil: a script
#: failing on nil while it names one of them wants --robot-api.
ROBOT_API_GLOBALS = frozenset(
    {
        "pose",
        "flight",
        "battery",
        "rc_goto",
        "cur_goal",
        "ROBOTS",
        "V_TYPE",
        "TARGET_ALTITUDE",
        "uav_takeoff",
        "uav_land",
        "gohome",
        "arm",
        "disarm",
        "goto_abs",
        "storegoal",
        "geofence",
        "voronoi",
        "setgimbal",
        "takepicture",
        "reset_rc",
        "export_map",
        "add_neighborStatus",
        "add_targetrb",
        "load_graph",
        "print",
        "debug",
    }
)

ROBOT_API_HINT = "this script uses the robot API; run it with --robot-api"


def run_cmd(
    file: Annotated[Path, typer.Argument(help="A .bzz script or a compiled .bo.")],
    robot_id: Annotated[
        int | None,
        typer.Option("--robot-id", help="The robot id (`id`) (default: 0; 1 with --robot-api)."),
    ] = None,
    steps: Annotated[
        int | None,
        typer.Option(
            "--steps",
            metavar="N",
            help="Then call init() (if defined), step() N times, destroy() (if defined).",
        ),
    ] = None,
    seed: Annotated[
        int | None, typer.Option("--seed", help="Seed math.rng (default: the clock).")
    ] = None,
    robot_api: Annotated[
        bool,
        typer.Option(
            "--robot-api",
            help="Give the script the robot API of one simulated robot (pose, flight, "
            "uav_takeoff...), as `sim run` does; each step is a 0.1 s tick.",
        ),
    ] = False,
    max_loops: Annotated[
        int,
        typer.Option(
            "--max-loops",
            help="Loop iterations allowed to the global code, init(), each step() and "
            "destroy(): a script that loops longer stops with an error.",
        ),
    ] = DEFAULT_MAX_LOOPS,
    include: Annotated[
        list[Path] | None, typer.Option("-I", "--include", help="Extra include directory.")
    ] = None,
) -> None:
    """Run a Buzz program: its global code, then optionally init/step/destroy."""
    if steps is not None and steps < 0:
        raise fail(f"--steps must be >= 0, got {steps}")
    if max_loops < 1:
        raise fail(f"--max-loops must be >= 1, got {max_loops}")
    path = resources.find_script(file)
    dirs = [str(d) for d in include or []]
    try:
        if path.suffix == ".bo":
            program = bvm.Program.load(path)
        else:
            program = bvm.compile_source(_read_source(path), str(path), dirs)
    except (BuzzCompileError, BuzzAsmError, BuzzLoadError) as e:
        raise fail(e, file) from None
    except OSError as e:
        raise fail(f"{file}: cannot read: {e.strerror or e}") from None
    try:
        if robot_api:
            rid = 1 if robot_id is None else robot_id
            _run_robot(path, program, rid, steps or 0, seed, max_loops)
        else:
            rid = 0 if robot_id is None else robot_id
            _run_bare(path, program, rid, steps, seed, max_loops)
    except KeyboardInterrupt as e:  # Ctrl-C: where the script was, not a traceback
        sys.stdout.flush()
        where = _where(e, program)
        raise fail(f"interrupted at {where}" if where else f"{file}: interrupted") from None
    finally:
        sys.stdout.flush()


def _run_bare(
    path: Path,
    program: bvm.Program,
    robot_id: int,
    steps: int | None,
    seed: int | None,
    max_loops: int,
) -> None:
    """The reference bzzrun's host: the VM, its standard library and `log`, nothing else."""
    vm = bvm.VM(robot_id=robot_id, rng_seed=seed, max_ticks=max_loops)
    try:
        vm.load(program)
        log = _log_to(sys.stdout)
        vm.globals["log"] = vm.new_native(lambda _self, *args: log(*args), None, "log")
        vm.execute()
        if steps is not None:
            # As the simulator and the node: init() and destroy() only if the script has them.
            if vm.gload("init") is not None:
                vm.call("init")
            for _ in range(steps):
                vm.call("step")
            if vm.gload("destroy") is not None:
                vm.call("destroy")
    except BuzzError as e:
        sys.stdout.flush()
        report(e, path)
        if isinstance(e, BuzzBudgetExceeded):
            _hint(f"raise the budget with --max-loops N (now {max_loops})")
        elif "nil" in e.message and _uses_robot_api(program, vm.globals):
            _hint(ROBOT_API_HINT)
        raise typer.Exit(EXIT_FAILURE) from None


def _run_robot(
    path: Path,
    program: bvm.Program,
    robot_id: int,
    steps: int,
    seed: int | None,
    max_loops: int,
) -> None:
    """One robot of the simulator (its runtime, script API, supervisor and vehicle) at
    the default home: global code and init(), `steps` ticks, destroy()."""
    from fieldkit.errors import ConfigError
    from fieldkit.sim.simulator import TICK_S, SimConfig, Simulation

    log = _log_to(sys.stdout)
    config = SimConfig(
        script=path,
        program=program,
        robots=1,
        first_id=robot_id,
        seconds=max(steps, 1) * TICK_S,
        seed=seed or 0,
        max_ticks_per_step=max_loops,
    )
    with _robot_warnings():
        try:
            sim = Simulation(config, on_log=log)
        except ConfigError as e:
            raise fail(e) from None
        robot = sim.robots[robot_id]
        for _ in range(steps):
            if not robot.runtime.running:
                break
            sim.step()
        robot.runtime.destroy()
    if robot.error is not None:
        sys.stdout.flush()
        report(robot.error)
        if isinstance(robot.vm.error, BuzzBudgetExceeded):
            _hint(f"raise the budget with --max-loops N (now {max_loops})")
        raise typer.Exit(EXIT_FAILURE)


@contextlib.contextmanager
def _robot_warnings() -> Iterator[None]:
    """The runtime's and supervisor's warnings (a failsafe, a refused command) on stderr as
    `warning: ...`; its log of a script error is left out: `run` reports that as `error:`."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("warning: %(message)s"))
    handler.addFilter(lambda record: record.levelno < logging.ERROR)
    logger = logging.getLogger("fieldkit")
    level = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.removeHandler(handler)
        logger.setLevel(level)


def _hint(text: str) -> None:
    """A hint under an error line, indented as the compiler's."""
    typer.echo(f"  hint: {text}", err=True)


def _uses_robot_api(program: bvm.Program, globals_: dict[str, Any]) -> bool:
    """Whether the program names a robot-API global that is nil here."""
    return any(name in ROBOT_API_GLOBALS and globals_.get(name) is None for name in program.strings)


def _where(e: BaseException, program: bvm.Program) -> str | None:
    """`file:line:col` of the Buzz code `e` was raised in, if it was raised in a script."""
    from bvm.vm import raised_at

    location = raised_at(e, program)
    if location is None:
        return None
    file, line, col = location
    return f"{file}:{line}:{col}"


def asm_cmd(
    file: Annotated[Path, typer.Argument(help="A .basm assembly file.")],
    out: Annotated[Path | None, typer.Option("-o", "--output", help="Output .bo path.")] = None,
) -> None:
    """Assemble FILE.basm into .bo and .bdb."""
    try:
        program = bvm.assemble(file.read_text(encoding="latin-1"), str(file))
    except OSError as e:
        raise fail(f"{file}: cannot read: {e.strerror}") from None
    except BuzzAsmError as e:
        raise fail(e) from None
    bo, bdb, _ = _outputs(file, out)
    try:
        _write(bo, program.bytecode)
        _write(bdb, program.debug)
    except OSError as e:
        raise fail(f"{e.filename}: cannot write: {e.strerror}") from None


def disasm_cmd(file: Annotated[Path, typer.Argument(help="A .bo bytecode file.")]) -> None:
    """Print the assembly of FILE.bo (uses the .bdb beside it when present)."""
    from bvm.disasm import disassemble

    try:
        bytecode = file.read_bytes()
        bdb = file.with_suffix(".bdb")
        debug = bdb.read_bytes() if bdb.exists() else None
    except OSError as e:
        raise fail(f"{file}: cannot read: {e.strerror}") from None
    try:
        text = disassemble(bytecode, debug)
    except BuzzLoadError as e:  # a truncated .bo, or a corrupt .bdb beside it
        raise fail(e, file) from None
    sys.stdout.buffer.write(text.encode("latin-1", "replace"))


#: The commands of this group, in the order `fieldkit --help` lists them.
COMMANDS: dict[str, Callable[..., None]] = {
    "compile": compile_cmd,
    "run": run_cmd,
    "asm": asm_cmd,
    "disasm": disasm_cmd,
}
