"""kill -9 of a process that records: the bag reads back everything up to about a second
before the kill, in both storages, across part rotations.

The child (tests/bag_crash_child.py) records the deterministic sample of tests/bagdata.py at
10 ticks per second of its own clock, printing each tick it finished; the test reads a random
number of those lines, SIGKILLs it, and reads the bag. The child may have run a few ticks past
the last line read (a pipe holds a few lines), never fewer: so the bag must hold at least the
ticks up to the last line read, minus the flush interval (one second: 10 ticks, plus the tick
at which the flush comes), and exactly the sample's data for each tick it holds. Parts rotate
every 64 KiB, so kills land before, during and after rotations too.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from bagdata import Sample, check_prefix

from fieldkit.record.bag import MIN_MAX_BYTES, BagReader

CHILD = Path(__file__).with_name("bag_crash_child.py")
#: A child that neither prints nor dies within this is hung (a hang guard, not a timing).
HANG_S = 120
#: The most ticks a kill may lose: a second of them, and the tick a flush waits for.
MAX_LOST_TICKS = 11
KILLS = 10


@pytest.mark.parametrize("name", ["rec", "rec.bag"])
@pytest.mark.parametrize("run", range(KILLS))
def test_a_killed_recording_reads_up_to_the_last_second(
    tmp_path: Path, name: str, run: int
) -> None:
    rng = random.Random(f"{name}:{run}")
    seen_lines = rng.randint(1, 160)
    path = tmp_path / name
    seed = f"kill{run}"
    child = subprocess.Popen(
        [sys.executable, str(CHILD), str(path), seed, str(MIN_MAX_BYTES)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert child.stdout is not None
    last_seen = -1
    try:
        for _ in range(seen_lines):
            line = child.stdout.readline()
            assert line, child.stderr.read().decode() if child.stderr else "child ended"
            last_seen = int(line.split()[1])
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait(HANG_S)
    assert child.returncode == -signal.SIGKILL
    r = BagReader(path)
    last = check_prefix(r, Sample(seed))  # exactly the sample's ticks 0..last, nothing partial
    assert last >= last_seen - MAX_LOST_TICKS, (last, last_seen, r.repairs)
    assert r.repairs, "a killed recording has at least its last part unclosed"
    for part in r.parts[:-1]:
        assert not any(note.startswith(f"{part}: ") for note in r.repairs)  # rotated: whole
