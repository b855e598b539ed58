"""How the simulator tunes memory for a swarm: huge pages for its heap
(fieldkit/sim/hugepages.py: which mappings are asked for, that the kernel gives them where
it can, that a run is the same with and without them) and the collector around building
and stepping it (simulator.collector_paused, tuned_memory)."""

from __future__ import annotations

import ctypes
import gc
import mmap
import weakref
from pathlib import Path

import pytest

from fieldkit.sim import hugepages
from fieldkit.sim.hugepages import HUGE_PAGE, HugePages, eligible
from fieldkit.sim.simulator import SimConfig, Simulation, tuned_memory

MIB = 1 << 20
SCRIPT = Path(__file__).resolve().parent.parent / "buzz_scripts" / "coverage.bzz"

MAPS = """\
55d0c0a00000-55d0c0a2a000 r--p 00000000 00:21 123  /usr/bin/python3.11
55d0c1000000-55d0c1a00000 rw-p 00000000 00:00 0    [heap]
7f0000000000-7f0000100000 rw-p 00000000 00:00 0
7f0000100000-7f0000700000 rw-p 00000000 00:00 0
7f0001000000-7f0001001000 ---p 00000000 00:00 0
7f0001001000-7f0001801000 rw-p 00000000 00:00 0
7f0002000000-7f0002600000 rw-p 00000000 00:21 99   /tmp/some.file
7f0003000000-7f0003400000 r-xp 00000000 00:00 0
7ffc00000000-7ffc00800000 rw-p 00000000 00:00 0    [stack]
"""


def test_only_the_heap_and_anonymous_arenas_are_asked_for_in_whole_huge_pages() -> None:
    assert eligible(MAPS) == [
        (0x55D0C1000000, 0x55D0C1A00000 & ~(HUGE_PAGE - 1)),  # the heap, its last part cut
        (0x7F0000200000, 0x7F0000600000),  # an arena, cut to the 2 MiB boundaries
    ]
    # Not: the program's text, a 1 MiB arena (less than a huge page), a thread's stack
    # (after its guard page), a file's pages, code, the main stack.


def test_nothing_is_asked_for_when_the_system_has_no_huge_pages(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    mode = tmp_path / "enabled"
    mode.write_text("always madvise [never]\n")
    monkeypatch.setattr(hugepages, "_MODE", mode)
    assert not hugepages.supported()
    assert HugePages().back() == 0
    mode.write_text("always [madvise] never\n")
    monkeypatch.setenv("FIELDKIT_HUGE_PAGES", "0")
    assert not hugepages.supported()
    assert HugePages().back() == 0


@pytest.mark.skipif(not hugepages.supported(), reason="no transparent huge pages here")
def test_the_heap_is_backed_by_huge_pages_once() -> None:
    pages = HugePages()
    block = bytearray(64 * MIB)  # a heap part of its own, touched
    block[::4096] = b"x" * len(block[::4096])
    asked = pages.back()
    assert asked >= 32 * MIB
    assert pages.back() == 0  # nothing new since
    huge = sum(
        int(line.split()[1])
        for line in Path("/proc/self/smaps_rollup").read_text().splitlines()
        if line.startswith("AnonHugePages:")
    )
    if pages.collapsed:  # Linux >= 6.1 makes them at once
        assert huge * 1024 >= 2 * HUGE_PAGE
    del block


def _mapping_rss_kib(address: int) -> int:
    """The resident KiB of the mapping that holds `address` (from /proc/self/smaps)."""
    inside = False
    for line in Path("/proc/self/smaps").read_text().splitlines():
        head = line.split()[0]
        if "-" in head and all(c in "0123456789abcdef-" for c in head):
            lo, hi = (int(x, 16) for x in head.split("-"))
            inside = lo <= address < hi
        elif inside and line.startswith("Rss:"):
            return int(line.split()[1])
    raise AssertionError("no such mapping")


@pytest.mark.skipif(not hugepages.supported(), reason="no transparent huge pages here")
def test_a_sparse_buffer_is_left_small() -> None:
    # Collapsing fills every hole of a huge page: a buffer touched once every 2 MiB must
    # not be asked for, or its 64 MiB would all come into memory.
    size = 64 * MIB
    sparse = mmap.mmap(-1, size, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    dense = mmap.mmap(-1, size, flags=mmap.MAP_PRIVATE | mmap.MAP_ANONYMOUS)
    for at in range(0, size, HUGE_PAGE):
        sparse[at] = 1
    for at in range(0, size, 4096):
        dense[at] = 1
    where = ctypes.addressof(ctypes.c_char.from_buffer(sparse))
    before = _mapping_rss_kib(where)
    pages = HugePages()
    pages.back()
    assert _mapping_rss_kib(where) - before < 1024  # still about one page per 2 MiB
    dense_at = ctypes.addressof(ctypes.c_char.from_buffer(dense))
    if pages.collapsed:
        assert any(dense_at <= p < dense_at + size for p in pages._done)
    assert not any(where <= p < where + size for p in pages._done)
    sparse.close()
    dense.close()


def test_following_the_heap_costs_nothing_until_it_grew(monkeypatch: pytest.MonkeyPatch) -> None:
    pages = HugePages()
    looked: list[int] = []
    monkeypatch.setattr(pages, "back", lambda: looked.append(1) or 0)
    pages.follow()
    assert looked == [1]  # a new heap may have grown
    pages.grown = False  # what back() leaves
    pages.follow()
    pages.follow()
    assert looked == [1]  # a part of a distributed swarm enters tuned_memory every tick
    monkeypatch.setattr("fieldkit.sim.simulator.HEAP", pages)
    Simulation(SimConfig(script=SCRIPT, robots=2, seconds=1e6, seed=3))
    assert pages.grown  # a build grows it


def test_swarms_dropped_are_freed_when_the_next_is_built() -> None:
    # Built swarms go to the oldest generation uncounted, so nothing would make the full
    # collection that frees the dropped ones: the next build makes it.
    refs = []
    for _ in range(4):
        sim = Simulation(SimConfig(script=SCRIPT, robots=6, seconds=0.3, seed=3))
        sim.run()
        refs.append(weakref.ref(sim))
        del sim
    Simulation(SimConfig(script=SCRIPT, robots=2, seconds=1e6, seed=3))
    assert [r() is None for r in refs] == [True] * 4


def _run(robots: int, ticks: int) -> list[tuple[object, ...]]:
    sim = Simulation(SimConfig(script=SCRIPT, robots=robots, seconds=1e6, seed=3))
    with tuned_memory():
        for _ in range(ticks):
            sim.step()
    return [(r.vehicle.position, r.state, dict(r.vm.counters)) for r in sim.robots.values()]


def test_a_run_is_the_same_with_and_without_huge_pages(monkeypatch: pytest.MonkeyPatch) -> None:
    with_pages = _run(12, 40)
    monkeypatch.setenv("FIELDKIT_HUGE_PAGES", "0")
    off = HugePages()
    monkeypatch.setattr("fieldkit.sim.simulator.HEAP", off)
    assert _run(12, 40) == with_pages
    assert off.backed == 0


def test_tuned_memory_follows_the_heap_after_young_collections(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    calls: list[int] = []

    class Counting(HugePages):
        def back(self) -> int:
            calls.append(1)
            return 0

    monkeypatch.setattr("fieldkit.sim.simulator.HEAP", Counting())
    with tuned_memory():
        assert len(calls) == 1  # on entry
        gc.collect(0)
        assert len(calls) == 2  # after a young collection
        gc.collect(1)
        assert len(calls) == 2  # an older one follows no growth of its own
    gc.collect(0)
    assert len(calls) == 2  # no longer once left


def test_a_built_swarm_goes_to_the_oldest_generation_unscanned() -> None:
    assert gc.isenabled()
    sim = Simulation(SimConfig(script=SCRIPT, robots=8, seconds=1e6, seed=3))
    # Built with the collector paused, then not scanned young (it would be in a younger
    # generation: the young collections run every few hundred allocations), nor left frozen.
    assert any(o is sim.robots for o in gc.get_objects(generation=2))
    assert gc.get_freeze_count() == 0
