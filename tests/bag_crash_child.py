"""The process tests/test_bag_crash.py kills: a robot recording its flight at 10 Hz.

    python bag_crash_child.py PATH SEED [MAX_BYTES]

records the deterministic sample of tests/bagdata.py into a bag at PATH (a ROS 1 bag if it
ends in .bag), tick after tick, without end: the writer's clock is the ticks' own (0.1 s
each), so a second of recording is ten ticks whatever the machine's speed. After each tick it
prints `tick K` padded to PAD bytes: a pipe holds only a few such lines, so the child is never
more than a few ticks ahead of what its parent has read when the parent kills it.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bagdata import TICK_S, Sample  # noqa: E402

from fieldkit.record.bag import DEFAULT_MAX_BYTES, BagWriter  # noqa: E402

#: Bytes per progress line.
PAD = 8192


def main() -> None:
    """Record until killed."""
    path, seed = Path(sys.argv[1]), sys.argv[2]
    max_bytes = int(sys.argv[3]) if len(sys.argv) > 3 else DEFAULT_MAX_BYTES
    sample = Sample(seed)
    now = [0.0]
    w = BagWriter(path, max_bytes=max_bytes, flush_s=1.0, clock=lambda: now[0])
    w.meta(sample.meta)
    out = sys.stdout
    k = 0
    while True:
        sample.write_tick(w, k)
        out.write(f"tick {k}".ljust(PAD - 1) + "\n")
        out.flush()
        k += 1
        now[0] = k * TICK_S


if __name__ == "__main__":
    main()
