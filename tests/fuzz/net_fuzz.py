"""Fuzzing a robot's message handling end to end: hostile payloads into running VMs.

    python -m tests.fuzz.net_fuzz --seconds 60 --seed 1
    python -m tests.fuzz.net_fuzz --replay 1:123        # one input, verbosely

Where `wire_fuzz` checks the decoder alone, this feeds the same payload families (valid,
mutated, truncated, spliced, nesting bombs...) to two robots running a script that uses
every primitive: listeners, two stigmergies with a conflict handler, swarms with exec and
kin. Input k of seed S is a batch of 1-24 payloads from random senders, made from
`random.Random(f"{S}:{k}")`; robot A receives them, steps, and sends what it drains (190-byte
budget) to robot B, which steps too. The property, per input:

* nothing raises out of `receive`, `process_inbox`, `step` or `drain_outbox`, and neither VM
  ends in the error state (the script itself never fails on well-typed data);
* the queues stay within their caps and every payload is either applied or counted as a
  decode error.

The last line printed is `inputs: N, failures: K`.
"""

from __future__ import annotations

import logging
import random
import sys
import traceback
from collections.abc import Callable
from dataclasses import dataclass

import bvm

from . import runner
from .wire_fuzz import make_input

SCRIPT = """
v = stigmergy.create(5)
w = stigmergy.create(6)
s = swarm.create(3)
heard = 0
function init() {
  s.join()
  neighbors.listen("m", function(topic, value, sender) { heard = heard + 1 })
  neighbors.listen("cmd", function(topic, value, sender) { last = value })
  v.onconflict(function(k, local, remote) { return remote })
  w.onconflictlost(function(k, local) { heard = heard + 1 })
}
function step() {
  v.put("k", id)
  v.get("missing")
  w.put(heard % 7, heard)
  s.exec(function() { kin = neighbors.kin().count() })
  neighbors.broadcast("m", heard)
}
"""


_PROGRAM: list[bvm.Program] = []

#: Batches two robots live through before fresh ones replace them.
REUSE = 50


def _robot(rid: int) -> bvm.VM:
    if not _PROGRAM:
        _PROGRAM.append(bvm.compile_source(SCRIPT, "fuzzbot.bzz"))
    vm = bvm.VM(robot_id=rid, rng_seed=rid, max_ticks=100_000)
    vm.load(_PROGRAM[0])
    vm.execute()
    vm.call("init")
    return vm


def make_batch(seed: str, k: int) -> list[tuple[int, bytes]]:
    """Input k: (sender id, payload) pairs, payloads from the wire fuzzer's families."""
    rng = random.Random(f"{seed}:{k}")
    batch = []
    for j in range(rng.randint(1, 24)):
        _, payload = make_input(f"{seed}:{k}", j)
        batch.append((rng.choice((0, 1, 2, 3, 21, 255, 65535)), payload[:4096]))
    return batch


def check(
    batch: list[tuple[int, bytes]], robots: tuple[bvm.VM, bvm.VM] | None = None
) -> str | None:
    """Run one batch through two robots (fresh ones unless given): None if the property
    holds, else the problem."""
    a, b = robots if robots is not None else (_robot(1), _robot(2))
    before = a.net.stats["received"] + a.net.stats["decode_errors"]
    try:
        for sender, payload in batch:
            a.receive(sender, payload)
        a.process_inbox()
        a.set_neighbors([(sender, 5.0, 0.0, 0.0) for sender, _ in batch[:5]])
        a.call("step")
        for payload in a.drain_outbox(190, overhead=2):
            b.receive(a.robot_id, payload)
        b.process_inbox()
        b.call("step")
        b.drain_outbox(190, overhead=2)
    except Exception:  # noqa: BLE001 - any escape is what we look for
        return "raised " + traceback.format_exc(limit=-4)
    for vm in (a, b):
        if vm.state == "error":
            return f"robot {vm.robot_id} in error state: {vm.error}"
        if len(vm.net.inbox) or len(vm.net.outbox) > vm.net.outbox.max_queued + 4:
            return f"robot {vm.robot_id}: queues not drained/bounded"
    stats = a.net.stats
    if stats["received"] + stats["decode_errors"] - before != len(batch):
        return f"robot 1 lost payloads: {dict(stats)} for {len(batch)} received"
    return None


@dataclass
class Stats(runner.Stats):
    """What a campaign did."""

    payloads: int = 0


def campaign(
    seed: str,
    *,
    seconds: float | None = None,
    max_inputs: int | None = None,
    out: Callable[[str], None] = print,
) -> Stats:
    """Check batches 0, 1, ... of `seed` until the time or the count runs out."""
    stats = Stats()
    robots = (_robot(1), _robot(2))

    def run_one(k: int) -> None:
        nonlocal robots
        if k % REUSE == 0:  # state carries over a while: gossip builds up, then reset
            robots = (_robot(1), _robot(2))
        batch = make_batch(seed, k)
        problem = check(batch, robots)
        stats.payloads += len(batch)
        if problem is not None:
            stats.fail(f"{seed}:{k}", f"FAILURE [replay {seed}:{k}] {problem}", out, shown=20)

    return runner.campaign(run_one, stats, seconds=seconds, max_inputs=max_inputs)


def run(
    seed: str,
    *,
    seconds: float | None = None,
    max_inputs: int | None = None,
    out: Callable[[str], None] = print,
) -> tuple[int, int, int]:
    """Check batches 0, 1, ... of `seed`: (inputs, payloads, failures)."""
    stats = campaign(seed, seconds=seconds, max_inputs=max_inputs, out=out)
    return stats.inputs, stats.payloads, stats.failures


def replay(spec: str) -> int:
    """Run batch SEED:K verbosely on fresh robots; 1 if it fails."""
    seed, _, k = spec.rpartition(":")
    batch = make_batch(seed, int(k))
    for sender, payload in batch:
        print(f"from {sender}: {payload[:64].hex()}{'...' if len(payload) > 64 else ''}")
    # Replays on fresh robots: a failure that needs earlier batches' state shows with
    # the campaign's REUSE window, so replay K-(K % REUSE) .. K if this passes.
    problem = check(batch)
    print("verdict:", problem or "ok")
    return 1 if problem else 0


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    args = runner.parse_args(
        argv, __doc__, slices=False, replay_help="SEED:K -- run one batch verbosely"
    )
    logging.getLogger("bvm").setLevel(logging.CRITICAL)  # the drops are counted, not shown
    if args.replay:
        return replay(args.replay)
    stats = campaign(args.seed, seconds=args.seconds)
    print(f"payloads: {stats.payloads}")
    # This report has always been just these two lines: the FAILURE lines carry the replay ids.
    return runner.summary(stats, list_failed=False)


if __name__ == "__main__":
    sys.exit(main())
