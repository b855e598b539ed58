"""`fieldkit compile | run | asm | disasm`: the Buzz language tools, as the reference's bzzc,
bzzrun, bzzasm and bzzdeasm."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import IO, Annotated, Any

import typer

import bvm
from bvm import srcmap
from bvm.errors import BuzzAsmError, BuzzCompileError, BuzzError, BuzzLoadError
from bvm.values import format_value
from fieldkit import resources
from fieldkit.cli.errors import fail


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


def _load(file: Path) -> bvm.Program:
    """A .bo (with its .bdb when present) or a .bzz compiled in memory."""
    if file.suffix == ".bo":
        return bvm.Program.load(file)
    return bvm.compile_source(_read_source(file), str(file))


def _log_to(stream: IO[str]) -> Callable[..., None]:
    """The reference bzzrun `log`: arguments formatted and concatenated, then a newline."""
    raw = getattr(stream, "buffer", None)
    if raw is not None:

        def log(*args: Any) -> None:
            raw.write("".join(map(format_value, args)).encode("latin-1", "replace") + b"\n")

    else:

        def log(*args: Any) -> None:
            stream.write("".join(map(format_value, args)) + "\n")

    return log


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
        program = _load(resources.find_script(file))
    except (BuzzCompileError, BuzzAsmError, BuzzLoadError) as e:
        raise fail(e, file) from None
    except OSError as e:
        raise fail(f"{file}: cannot read: {e.strerror or e}") from None
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
        raise fail(e, file) from None
    finally:
        sys.stdout.flush()


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
