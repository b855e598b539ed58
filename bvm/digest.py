"""A digest of a VM's script state: what a recording keeps per tick to check a replay.

`state_digest(vm)` hashes (SHA-256) the script's globals in a canonical order: names sorted,
table entries sorted by key, numbers by exact value (floats by their hex form), closures by
the code address they run (not by object identity), shared and cyclic tables by the order
they were first met. Two VMs that ran the same program on the same inputs have the same
digest, in any process; a single changed value anywhere in the globals changes it. Host
functions (native closures the host installs) are skipped: they are the host's, not state.
"""

from __future__ import annotations

import hashlib
import struct
from typing import Any

from bvm.values import Closure, Table, Userdata

_KEY_ORDER = {int: 0, float: 1, str: 2}


def _key(k: Any) -> tuple[int, Any]:
    return (_KEY_ORDER.get(type(k), 3), k if type(k) in _KEY_ORDER else repr(k))


class _Walker:
    """Feeds one canonical byte form of values into a hash."""

    def __init__(self) -> None:
        self.h = hashlib.sha256()
        self.seen: dict[int, int] = {}  # id(table) -> order first met

    def value(self, v: Any) -> None:
        h = self.h
        t = type(v)
        if v is None:
            h.update(b"n")
        elif t is bool:  # not a Buzz type, but a host may set one
            h.update(b"b1" if v else b"b0")
        elif t is int:
            h.update(b"i%d;" % v)
        elif t is float:
            h.update(b"f" + v.hex().encode() + b";")
        elif t is str:
            data = v.encode("utf-8", "surrogatepass")
            h.update(b"s" + struct.pack("<I", len(data)) + data)
        elif isinstance(v, Table):
            k = self.seen.get(id(v))
            if k is not None:
                h.update(b"@%d;" % k)
                return
            self.seen[id(v)] = len(self.seen)
            h.update(b"t%d{" % len(v))
            for key in sorted(v, key=_key):
                item = v[key]
                if item is None:
                    continue
                self.value(key)
                self.value(item)
            h.update(b"}")
        elif isinstance(v, Closure):
            h.update(b"%s%d;" % (b"C" if v.native else b"c", v.ref))
        elif isinstance(v, Userdata):
            h.update(b"u")
        else:
            h.update(b"?" + type(v).__name__.encode())


def state_digest(vm: Any) -> bytes:
    """The 32-byte SHA-256 digest of `vm`'s script globals (host functions left out)."""
    walker = _Walker()
    vm.settle()  # what the host left to be made on first use is state too
    globals_ = vm.globals
    for name in sorted(globals_):
        v = globals_[name]
        if v is None or (isinstance(v, Closure) and v.native):
            continue
        walker.value(name)
        walker.value(v)
    return walker.h.digest()


__all__ = ["state_digest"]
