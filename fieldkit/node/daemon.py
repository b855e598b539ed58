"""The node as a systemd service: the notify protocol, and when a watchdog ping is due.

systemd starts the node with `NOTIFY_SOCKET` (a Unix datagram socket) and, with
`WatchdogSec=`, `WATCHDOG_USEC` in its environment. The node tells it:

    READY=1       the autopilot's heartbeat, a GPS fix and the script are up: "started"
    WATCHDOG=1    a tick has just completed: no ping for WatchdogSec and systemd kills
                  and restarts the node (Restart=on-failure)
    STATUS=...    one line for `systemctl status`: tick, state, neighbours, link health
    RELOADING=1   SIGHUP: the new config and script are being checked and switched in
    STOPPING=1    SIGTERM: the safe stop has begun

The protocol is a few lines of text per datagram (sd_notify(3)); a small implementation here
rather than a dependency: the PyPI packages are a 2017 pure-Python one that swallows every
error (sdnotify) or Cython bindings that need libsystemd's headers to build (systemd,
cysystemd), which a companion computer's venv should not need. Without `NOTIFY_SOCKET`
(a terminal, a test) every call does nothing.

Pings come from the loop itself, after a tick, never from a timer thread: a loop stalled
inside a tick sends none, which is what the watchdog is for; a late tick still completes and
pings. `WatchdogPacer` decides when a ping is due (fed the node's time, tested without a
socket): at most every quarter of the watchdog interval, so that with ticks of up to a
quarter interval apart the pings are at most half the interval apart.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Mapping


class Notifier:
    """sd_notify(3) to `NOTIFY_SOCKET`: `send("READY=1", "STATUS=...")`; a no-op without it."""

    def __init__(self, environ: Mapping[str, str] | None = None) -> None:
        """Read `NOTIFY_SOCKET` and `WATCHDOG_USEC` from `environ` (default: os.environ)."""
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        # "@name" is a socket in the abstract namespace: the name starts with a NUL byte.
        self.address = "\0" + address[1:] if address.startswith("@") else address
        self.watchdog_s = watchdog_interval(env)
        self.errors = 0
        self._sock: socket.socket | None = None
        if self.address:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)

    @property
    def enabled(self) -> bool:
        """True when systemd (or a test) listens."""
        return self._sock is not None

    def send(self, *fields: str) -> bool:
        """Send `KEY=value` fields as one datagram; False (counted) if it could not go."""
        if self._sock is None:
            return False
        # A field is one line: a status text with a newline would end the field early.
        text = "\n".join(f.replace("\n", " ") for f in fields)
        try:
            self._sock.sendto(text.encode("utf-8", "replace"), self.address)
        except OSError:
            self.errors += 1  # systemd gone or busy: the node must fly on regardless
            return False
        return True

    def close(self) -> None:
        """Close the socket."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def watchdog_interval(environ: Mapping[str, str]) -> float | None:
    """The watchdog interval systemd asks for, in seconds (None: no watchdog).

    `WATCHDOG_PID`, when set, names the process meant: a child that inherited the
    environment must not ping for its parent."""
    usec = environ.get("WATCHDOG_USEC", "")
    pid = environ.get("WATCHDOG_PID", "")
    if not usec.isdigit() or int(usec) == 0:
        return None
    if pid and (not pid.isdigit() or int(pid) != os.getpid()):
        return None
    return int(usec) / 1e6


class WatchdogPacer:
    """When the loop's next WATCHDOG=1 is due: after a completed tick, at most every
    quarter of the interval (fed the node's clock, so tests need no socket or timer)."""

    def __init__(self, interval_s: float | None) -> None:
        """`interval_s` is WatchdogSec (None: never ping)."""
        self.every_s = None if interval_s is None else interval_s / 4
        self.last: float | None = None
        self.pings = 0

    def due(self, now: float) -> bool:
        """A tick completed at `now`: True if a ping is to be sent now (and counted)."""
        if self.every_s is None:
            return False
        if self.last is not None and now - self.last < self.every_s:
            return False
        self.last = now
        self.pings += 1
        return True


__all__ = ["Notifier", "WatchdogPacer", "watchdog_interval"]
