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
the heap grew by (`HugePages.back`, called by `simulator.tuned_memory`). Only the page
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
    """The process's heap backed by huge pages, part by part as it grows."""

    def __init__(self) -> None:
        self.enabled = supported()
        self.backed = 0  # bytes asked for so far
        self.collapsed = 0  # of which made huge at once (the rest as pages are touched)
        self._done: set[tuple[int, int]] = set()
        self._madvise = None
        if self.enabled:
            libc = ctypes.CDLL(None, use_errno=True)
            self._madvise = libc.madvise
            self._madvise.argtypes = [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int]
            self._madvise.restype = ctypes.c_int

    def back(self) -> int:
        """Ask for huge pages for every part of the heap not asked for yet; the bytes asked
        for now (0 where unsupported). Failures are not errors: the pages stay small."""
        if self._madvise is None:
            return 0
        try:
            maps = _MAPS.read_text()
        except OSError:
            return 0
        new = 0
        for lo, hi in eligible(maps):
            if (lo, hi) in self._done:
                continue
            self._done.add((lo, hi))
            if self._madvise(lo, hi - lo, MADV_HUGEPAGE) != 0:
                continue
            new += hi - lo
            # The pages already there stay small unless collapsed (khugepaged would take
            # minutes); before Linux 6.1 this fails, and only pages made later are huge.
            if self._madvise(lo, hi - lo, MADV_COLLAPSE) == 0:
                self.collapsed += hi - lo
        self.backed += new
        return new


#: The process's one heap.
HEAP = HugePages()

__all__ = ["HEAP", "HUGE_PAGE", "HugePages", "eligible", "supported"]
