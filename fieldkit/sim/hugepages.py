"""Huge pages for a big swarm's heap (Linux): fewer address translations per robot tick.

A thousand simulated robots hold about 300 MB of Python objects. Each robot's tick
touches a few kilobytes of its own objects (its VM, tables, radio and vehicle state),
spread over dozens of 4 KiB pages, and by the time its turn comes round again the
processor has forgotten both the data and the page translations: every one of those
pages costs a page-table walk, which under a virtual machine's nested paging is several
memory reads. Backed by 2 MiB pages the same heap needs 512 times fewer translations.

Linux maps anonymous memory with 2 MiB pages where asked (`madvise(MADV_HUGEPAGE)`; the
system's default mode here is "madvise") and, since 6.1, turns the pages already there into
huge ones at once (`MADV_COLLAPSE`). Python's allocator asks for neither, so the
simulator does it for the whole heap when it starts stepping a swarm, and again for what
the heap grew by (`HugePages.back`, called by `simulator.tuned_memory`), where its pages
are all there: a sparse buffer is left alone (a huge page is all in memory). Only the page
size changes, never a value: runs are the same bit for bit. Where the system has no huge
pages, or `FIELDKIT_HUGE_PAGES=0` is set, nothing is done. Measured in
docs/results.md#the-whole-mission-from-the-ground.
"""

from __future__ import annotations

import ctypes
import os
import sys
from pathlib import Path

#: Linux's madvise advice values (include/uapi/asm-generic/mman-common.h).
MADV_HUGEPAGE = 14
MADV_COLLAPSE = 25
#: The huge page size on x86-64 and most arm64 kernels.
HUGE_PAGE = 2 << 20

#: The share of a huge page's small pages that must be in memory before it is asked for.
DENSE = 0.9

_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096
_RESIDENT = bytes(b & 1 for b in range(256))  # mincore's byte -> whether the page is there
_MODE = Path("/sys/kernel/mm/transparent_hugepage/enabled")
_MAPS = Path("/proc/self/maps")


def eligible(maps: str) -> list[tuple[int, int]]:
    """The 2 MiB-aligned parts, at least one huge page long, of the private writable
    anonymous mappings (the heap and the allocator's arenas) in a `/proc/PID/maps` text;
    not threads' stacks (which follow an inaccessible guard page)."""
    out: list[tuple[int, int]] = []
    guard_end = -1  # where the last inaccessible mapping ended
    for line in maps.splitlines():
        fields = line.split()
        if len(fields) < 5:
            continue
        lo_text, _, hi_text = fields[0].partition("-")
        start, end = int(lo_text, 16), int(hi_text, 16)
        after_guard = start == guard_end
        guard_end = end if fields[1] == "---p" else -1
        if fields[1] != "rw-p" or after_guard:
            continue
        path = fields[5] if len(fields) > 5 else ""
        if path and path != "[heap]":
            continue  # a file's pages, the stack, the vDSO: not the objects
        lo = (start + HUGE_PAGE - 1) & ~(HUGE_PAGE - 1)
        hi = end & ~(HUGE_PAGE - 1)
        if hi > lo:
            out.append((lo, hi))
    return out


def supported() -> bool:
    """Whether this system maps memory with huge pages when asked (and it is not off)."""
    if os.environ.get("FIELDKIT_HUGE_PAGES") == "0" or not sys.platform.startswith("linux"):
        return False
    try:
        mode = _MODE.read_text()
    except OSError:
        return False
    return "[never]" not in mode


class HugePages:
    """The process's heap backed by huge pages, part by part as it fills."""

    def __init__(self) -> None:
        self.backed = 0  # bytes asked for so far
        self.collapsed = 0  # of which made huge at once (the rest as pages are touched)
        self.grown = True  # the heap may have grown since `back` last looked
        self._done: set[int] = set()  # the huge pages (their addresses) asked for
        self._libc: ctypes.CDLL | None = None
        if supported():
            libc = ctypes.CDLL(None, use_errno=True)
            libc.madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
            libc.madvise.restype = ctypes.c_int
            libc.mincore.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_char_p]
            libc.mincore.restype = ctypes.c_int
            self._libc = libc

    def follow(self) -> int:
        """`back`, if the heap may have grown since it last looked (a swarm was built, a
        young collection ran); else nothing, at no cost (a part of a distributed swarm
        enters `tuned_memory` every tick)."""
        return self.back() if self.grown else 0

    def back(self) -> int:
        """Ask for huge pages where the heap's pages are all (or nearly all) there and not
        asked for yet; the bytes asked for now (0 where unsupported). Failures are not
        errors: the pages stay small."""
        self.grown = False
        if self._libc is None:
            return 0
        try:
            maps = _MAPS.read_text()
        except OSError:
            return 0
        new = 0
        for lo, hi in eligible(maps):
            for run_lo, run_hi in self._dense_runs(lo, hi):
                if self._libc.madvise(run_lo, run_hi - run_lo, MADV_HUGEPAGE) != 0:
                    continue
                self._done.update(range(run_lo, run_hi, HUGE_PAGE))
                new += run_hi - run_lo
                # The pages already there stay small unless collapsed (khugepaged would
                # take minutes); before Linux 6.1 this fails, and only later pages are huge.
                if self._libc.madvise(run_lo, run_hi - run_lo, MADV_COLLAPSE) == 0:
                    self.collapsed += run_hi - run_lo
        self.backed += new
        return new

    def _dense_runs(self, lo: int, hi: int) -> list[tuple[int, int]]:
        """The runs of huge pages in [lo, hi) not asked for yet whose small pages are at
        least DENSE there. A sparse buffer stays as it is: collapsing fills every hole of
        a huge page with zeros (a 256 MiB mapping touched every 2 MiB would take 256 MiB),
        and the heap's arenas are dense anyway."""
        assert self._libc is not None
        vec = ctypes.create_string_buffer((hi - lo) // _PAGE)
        if self._libc.mincore(lo, hi - lo, vec) != 0:
            return []
        resident = vec.raw.translate(_RESIDENT)  # 1 per page in memory, else 0
        per = HUGE_PAGE // _PAGE
        runs: list[tuple[int, int]] = []
        for k in range(0, len(resident), per):
            at = lo + k * _PAGE
            if at in self._done or resident.count(1, k, k + per) < DENSE * per:
                continue
            if runs and runs[-1][1] == at:
                runs[-1] = (runs[-1][0], at + HUGE_PAGE)
            else:
                runs.append((at, at + HUGE_PAGE))
        return runs


#: The process's one heap.
HEAP = HugePages()

__all__ = ["DENSE", "HEAP", "HUGE_PAGE", "HugePages", "eligible", "supported"]
