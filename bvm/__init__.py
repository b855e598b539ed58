"""bvm: the Buzz language for Python — compiler, assembler, disassembler and VM.

    import bvm
    program = bvm.compile_file("script.bzz", include_dirs=["lib"])
    vm = bvm.VM(robot_id=1)
    vm.load(program)
    vm.register("log", print)
    vm.execute()

    # each step, as a robot does (docs/swarm.md):
    vm.receive(sender_id, payload); vm.process_inbox()
    vm.set_neighbors([(robot_id, distance, azimuth, elevation), ...])
    vm.call("step")
    radio.send(vm.drain_outbox(budget_bytes=186))

`bvm.wire` encodes and decodes the messages robots exchange. This package does no device
I/O (beyond the `io` library scripts may call); robots, radios and simulators live in
`fieldkit`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from bvm import wire
from bvm.errors import (
    BuzzAsmError,
    BuzzBudgetExceeded,
    BuzzCompileError,
    BuzzError,
    BuzzLoadError,
    BvmError,
)
from bvm.program import Program
from bvm.values import Closure, Table, Userdata
from bvm.vm import VM, VMState

__all__ = [
    "VM",
    "VMState",
    "BuzzAsmError",
    "BvmError",
    "BuzzBudgetExceeded",
    "BuzzCompileError",
    "BuzzError",
    "BuzzLoadError",
    "Closure",
    "Program",
    "Table",
    "Userdata",
    "assemble",
    "compile_file",
    "compile_source",
    "compile_to_asm",
    "wire",
]


def compile_to_asm(source: bytes | str, path: str, include_dirs: Sequence[str] = ()) -> str:
    """Compile Buzz source to Buzz assembly (.basm text), exactly as the reference bzzparse."""
    from bvm.compiler import compile_asm as _compile

    if isinstance(source, str):
        source = source.encode("utf-8")
    return _compile(source, path, include_dirs)


def assemble(basm: str, path: str = "<asm>") -> Program:
    """Assemble Buzz assembly into a Program (.bo and .bdb bytes)."""
    from bvm.assembler import assemble as _assemble

    bytecode, debug = _assemble(basm, path)
    return Program(bytecode, debug, path)


def compile_source(
    source: bytes | str, path: str = "<buzz>", include_dirs: Sequence[str] = ()
) -> Program:
    """Compile Buzz source text to a Program, with its source map (`program.srcmap`,
    what `fieldkit compile` writes as the .bpos beside the .bo)."""
    from bvm.assembler import assemble_mapped
    from bvm.compiler import compile_marked
    from bvm.srcmap import from_marks

    if isinstance(source, str):
        source = source.encode("utf-8")
    basm, marks = compile_marked(source, path, include_dirs)
    bytecode, debug, op_at, labels = assemble_mapped(basm, path)
    smap = from_marks(marks.positions, marks.functions, op_at, labels)
    return Program(bytecode, debug, path, smap)


def compile_file(path: str | Path, include_dirs: Sequence[str] = ()) -> Program:
    """Compile a .bzz file (with its includes) to a Program."""
    p = Path(path)
    try:
        source = p.read_bytes()
    except OSError as e:
        raise BuzzCompileError(str(p), 0, 0, f"cannot read file: {e.strerror or e}") from None
    return compile_source(source, str(p), include_dirs)
