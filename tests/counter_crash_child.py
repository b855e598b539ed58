"""The process tests/test_bundle_auth.py kills: a robot sealing bundles with a CounterStore.

    python counter_crash_child.py COUNTER_FILE COUNT BLOCK

opens a `CounterStore(COUNTER_FILE, BLOCK)`, then COUNT times takes the next counter, seals a
real bundle with it and prints `sent N` (the counter a receiver could now have heard), then
`done`. With COUNTER_CRASH_AT=K in the environment it SIGKILLs itself at its K-th durable
step of a reservation (`os.fsync` of the temporary file, `os.replace`, `os.fsync` of the
directory), before the step runs. It prints `ops N` at the end: the steps a whole run makes.
"""

from __future__ import annotations

import os
import signal
import sys
from typing import Any

from fieldkit.robot.bundle import encode_fields
from fieldkit.robot.bundle_auth import CounterStore, Sealer, bundle_key

CRASH_AT = int(os.environ.get("COUNTER_CRASH_AT", "0"))
_ops = 0
_real_replace = os.replace
_real_fsync = os.fsync


def _step() -> None:
    global _ops
    _ops += 1
    if _ops == CRASH_AT:
        os.kill(os.getpid(), signal.SIGKILL)


def _replace(src: Any, dst: Any, **kw: Any) -> None:
    _step()
    _real_replace(src, dst, **kw)


def _fsync(fd: int) -> None:
    _step()
    _real_fsync(fd)


os.replace = _replace  # type: ignore[assignment]
os.fsync = _fsync


def main() -> None:
    path, count, block = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    sealer = Sealer(5, bundle_key(bytes(range(32))), CounterStore(path, block))
    air = encode_fields(5, [b"\x04\x00\x05"], 45.5, -73.6, 10.0)
    for _ in range(count):
        sealer.seal(air)
        print(f"sent {sealer.last}", flush=True)
    print(f"ops {_ops}")
    print("done", flush=True)


if __name__ == "__main__":
    main()
