"""Radio traffic of one swarm barrier: the three designs of issue 20 side by side.

    python bench/barrier_traffic.py [--sizes 10,100,1000] [--drop 0] [--seed 0]

Every robot of an N-robot swarm enters one barrier at step 0 with threshold N, and the bench
counts what the robots put on the air until the barrier is over: every robot passed and the
radio went quiet (the lingering after the pass included), or `--max-steps`. It prints, per
size and barrier: steps until the last robot passed, messages sent, bytes sent, the same per
robot, and the growth factor of messages and bytes from the previous size (10x the robots:
a growth of 10 is linear, 100 quadratic).

The barriers: `bench/barrier_flood.bzz` (the shipped `include/barrier.bzz` before issue 20:
one stigmergy key per robot), `bench/barrier_bitsets.bzz` (issue 20's first rewrite:
readiness bitsets gossiped by neighbours) and the shipped `buzz_scripts/include/barrier.bzz`
(counts summed up a tree over the neighbour graph, robots speaking only with news), the
last one twice: rooted at robot 1 (`barrier_new_at`, as states.bzz roots a command's barrier
at the robot the command came from) and with the root elected (`barrier_new`: the lowest id
heard). All run unchanged on the same probe script. Robots stand on a grid at the density
of the deployment (12.2 m apart, 20 m range: about 8 robots in range of each, as
bench/sim_scale.py), ids row by row. Each robot drains its outbox with ROSBuzz's bundle
budget (186 bytes of messages, 2 bytes of framing each), so a busy radio delays messages
instead of losing them; the harness sends each Buzz message as its own packet
(tests/harness.py), so drops, when asked for, are per
message. The old barrier at 1,000 robots takes a few minutes on a 2-core machine.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests"))  # the harness lives with the tests

from harness import QuietHarness  # noqa: E402

sys.path.insert(0, str(ROOT / "bench"))
from bench_args import at_least, probability, sizes  # noqa: E402

import bvm  # noqa: E402
from fieldkit.sim.radio import LinkModel  # noqa: E402

NEW = ROOT / "buzz_scripts" / "include" / "barrier.bzz"
OLD = ROOT / "bench" / "barrier_flood.bzz"
BITSETS = ROOT / "bench" / "barrier_bitsets.bzz"
SPACING_M = 12.2
RANGE_M = 20.0
QUIET_STEPS = 10  # steps without a message after the last pass: the barrier is over

PROBE = """
include "barrier.bzz"
function init() {
  T = 0
  OUT = "waiting"
  AT = -1
  B = NEW_BARRIER
}
function step() {
  T = T + 1
  var o = barrier_step(B)
  if (o != OUT) {
    OUT = o
    AT = T
  }
}
"""


@dataclass
class Traffic:
    """One barrier's cost: steps to the last pass, messages and bytes until quiet."""

    robots: int
    steps_to_pass: int | None
    messages: int
    bytes: int
    wall_s: float


def grid(n: int) -> dict[int, tuple[float, float, float]]:
    """Robots 1..n on a square grid, row by row."""
    side = max(1, round(n**0.5))
    return {
        i: (((i - 1) % side) * SPACING_M, ((i - 1) // side) * SPACING_M, 0.0)
        for i in range(1, n + 1)
    }


def measure(
    barrier: Path, n: int, *, drop: float, seed: int, max_steps: int, root: int | None = None
) -> Traffic:
    """Run one barrier of `n` robots with the barrier file `barrier` (the tree rooted at
    robot `root` if given)."""
    new = "barrier_new(7, 900, THRESHOLD)"
    if root is not None:
        new = f"barrier_new_at(7, 900, THRESHOLD, {root})"
    with tempfile.TemporaryDirectory() as d:
        shutil.copy(barrier, Path(d) / "barrier.bzz")
        program = bvm.compile_source(PROBE.replace("NEW_BARRIER", new), str(Path(d) / "probe.bzz"))

    def setup(rid: int, vm: bvm.VM) -> None:
        vm["THRESHOLD"] = n
        vm["BARRIER_TIMEOUT"] = max_steps

    t0 = time.perf_counter()
    h = QuietHarness(
        program,
        range(1, n + 1),
        positions=grid(n),
        link=LinkModel(range_m=RANGE_M, drop=drop),
        seed=seed,
        setup=setup,
        budget_bytes=186,
        overhead=2,
    )
    passed_at: int | None = None
    quiet = 0
    while h.step_count < max_steps:
        before = h.radio.sent
        h.step()
        if h.errors:
            raise SystemExit(f"script error: {next(iter(h.errors.values()))}")
        if passed_at is None and all(vm["OUT"] == "passed" for vm in h.vms.values()):
            passed_at = h.step_count
        quiet = quiet + 1 if h.radio.sent == before else 0
        if passed_at is not None and quiet >= QUIET_STEPS:
            break
    return Traffic(
        n, passed_at, h.radio.sent, sum(h.radio.bytes_sent.values()), time.perf_counter() - t0
    )


def growth(now: int, before: int | None) -> str:
    """now / before, or a dash."""
    return "-" if not before else f"{now / before:.1f}x"


def main() -> None:
    """Measure both barriers at each size and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=sizes, default=[10, 100, 1000])
    ap.add_argument("--drop", type=probability, default=0.0)
    ap.add_argument("--seed", type=at_least(0), default=0)
    ap.add_argument("--max-steps", type=at_least(1), default=3000)
    ap.add_argument("--only", default="", help="only the barriers whose name holds this")
    args = ap.parse_args()
    print(
        "| barrier | robots | steps to the last pass | messages | bytes | messages/robot"
        " | bytes/robot | growth, messages | growth, bytes | wall s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    barriers: list[tuple[str, Path, int | None]] = [
        ("key per robot (before issue 20)", OLD, None),
        ("bitsets (issue 20, first)", BITSETS, None),
        ("tree, rooted (shipped)", NEW, 1),
        ("tree, elected root (shipped)", NEW, None),
    ]
    chosen = [b for b in barriers if not args.only or args.only in b[0]]
    for name, path, root in chosen:
        prev: Traffic | None = None
        for n in args.sizes:
            t = measure(
                path, n, drop=args.drop, seed=args.seed, max_steps=args.max_steps, root=root
            )
            print(
                f"| {name} | {n} | {t.steps_to_pass if t.steps_to_pass is not None else 'never'}"
                f" | {t.messages:,} | {t.bytes:,} | {t.messages / n:.1f} | {t.bytes / n:,.0f}"
                f" | {growth(t.messages, prev.messages if prev else None)}"
                f" | {growth(t.bytes, prev.bytes if prev else None)} | {t.wall_s:.0f} |",
                flush=True,
            )
            prev = t


if __name__ == "__main__":
    main()
