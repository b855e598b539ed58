"""Test helpers: a robot VM running a snippet of Buzz, with a `log` that records lines."""

from __future__ import annotations

import bvm
from bvm.values import format_log


def make_robot(
    src: str, robot_id: int = 0, *, translate: bool = True, run: bool = True
) -> tuple[bvm.VM, list[str]]:
    """A VM for robot `robot_id` running `src` (global code executed when `run`)."""
    lines: list[str] = []
    vm = bvm.VM(robot_id=robot_id, translate=translate, rng_seed=robot_id)
    vm.load(bvm.compile_source(src, "robot.bzz"))
    vm.register("log", lambda *args: lines.append(format_log(args)))
    if run:
        vm.execute()
    return vm, lines


def hexes(payloads: list[bytes]) -> list[str]:
    """Payloads as compact hex strings, for readable assertions."""
    return [p.hex() for p in payloads]
