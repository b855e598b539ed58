"""Pseudo-terminals: the serial line between a simulated machine and the code that drives it."""

from __future__ import annotations

import os
import tty
from dataclasses import dataclass


@dataclass
class PtyPair:
    """A pseudo-terminal: the vehicle writes the master, the node opens `slave_path`."""

    master: int
    slave_path: str
    slave_fd: int  # kept open so the master never reads EIO before the node opens the slave

    def close(self) -> None:
        """Close both ends."""
        for fd in (self.master, self.slave_fd):
            try:
                os.close(fd)
            except OSError:
                pass


def open_pty() -> PtyPair:
    """A new raw pty pair; the master is non-blocking (a full line drops bytes, as a UART)."""
    master, slave = os.openpty()
    # Raw on the slave side: no echo (the vehicle would read its own frames back), no CR/LF
    # translation, no XON/XOFF eating 0x11/0x13 bytes of binary frames.
    tty.setraw(slave)
    os.set_blocking(master, False)
    return PtyPair(master, os.ttyname(slave), slave)
