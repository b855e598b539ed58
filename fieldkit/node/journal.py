"""journald's native protocol: a log line with its priority and the node's own fields.

Under systemd the node's stdout is a stream into the journal (`JOURNAL_STREAM` names it),
which keeps the text but gives every line the same priority and no fields. Sent instead as
a datagram to journald's socket, each line carries `PRIORITY` (so `journalctl -p warning`
shows the warnings and errors only) and the fields an operator filters on:
`journalctl ROBOT_ID=3`, or `TICK=` to line a log up with a recording.

A datagram is `KEY=value` lines; a value holding a newline is sent as `KEY`, a newline,
its length as a 64-bit little-endian number, the bytes and a newline (systemd's
"native protocol", documented in systemd's journal-native-protocol page). A datagram that
cannot go (journald restarting, a line too long for one) is written to stdout instead, with
the `<N>` priority prefix journald reads off a stream: a line is never lost.
"""

from __future__ import annotations

import os
import socket
import struct
import sys
from collections.abc import Mapping

JOURNAL_SOCKET = "/run/systemd/journal/socket"
"""Where journald listens for native-protocol datagrams."""

ERR, WARNING, NOTICE, INFO = 3, 4, 5, 6
"""syslog priorities, as journald stores them."""


def priority_of(text: str) -> int:
    """A node line's priority, from how it begins (`error:`, `warning:`), else info."""
    if text.startswith("error"):
        return ERR
    if text.startswith("warning"):
        return WARNING
    return INFO


def encode(fields: Mapping[str, str]) -> bytes:
    """Fields as one native-protocol datagram."""
    out = bytearray()
    for key, value in fields.items():
        data = value.encode("utf-8", "replace")
        if b"\n" in data:
            out += key.encode() + b"\n" + struct.pack("<Q", len(data)) + data + b"\n"
        else:
            out += key.encode() + b"=" + data + b"\n"
    return bytes(out)


def stdout_is_journal(environ: Mapping[str, str] | None = None) -> bool:
    """True when stdout is the journal stream systemd gave this process (`JOURNAL_STREAM`
    is `DEVICE:INODE` of it; a shell redirect in between breaks the match)."""
    env = os.environ if environ is None else environ
    dev, _, ino = env.get("JOURNAL_STREAM", "").partition(":")
    if not (dev.isdigit() and ino.isdigit()):
        return False
    try:
        st = os.fstat(sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        return False
    return st.st_dev == int(dev) and st.st_ino == int(ino)


class Journal:
    """Sends lines to journald with a priority and fields; `send` False: write it yourself."""

    def __init__(self, identifier: str, address: str = JOURNAL_SOCKET) -> None:
        """`identifier` is the SYSLOG_IDENTIFIER (the name `journalctl -t` takes)."""
        self.identifier = identifier
        self.address = address
        self.failures = 0
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    def send(self, message: str, priority: int, fields: Mapping[str, str]) -> bool:
        """One line to the journal; False (counted) if it could not be sent."""
        datagram = encode(
            {
                "MESSAGE": message,
                "PRIORITY": str(priority),
                "SYSLOG_IDENTIFIER": self.identifier,
                **fields,
            }
        )
        try:
            self._sock.sendto(datagram, self.address)
        except OSError:
            self.failures += 1
            return False
        return True

    def close(self) -> None:
        """Close the socket."""
        self._sock.close()


__all__ = [
    "ERR",
    "INFO",
    "JOURNAL_SOCKET",
    "Journal",
    "NOTICE",
    "WARNING",
    "encode",
    "priority_of",
    "stdout_is_journal",
]
