"""The node's life as a service: signals, readiness and watchdog, reload, the safe stop.

    signals = ServiceSignals()          # from the start: SIGTERM in start-up ends it cleanly
    ... connect, wait for heartbeat and fix, build the Node ...
    service = NodeService(node, notifier, say, reload_check=check)
    ended = service.run(seconds)        # READY=1, then ticks with WATCHDOG=1 and STATUS=
    node.finish(); service.safe_stop(link)   # STOPPING=1, the profile's stop order, its ACK

Signals only set flags (the loop acts at the end of its tick, between two complete ticks):

    SIGTERM, SIGINT   stop: the loop ends, `destroy()` runs, the vehicle gets the profile's
                      `failsafe.on_stop` order and its acknowledgement is awaited; a second
                      one interrupts at once
    SIGHUP            reload: the config file and script are checked again (in a thread,
                      the loop ticking on) with the checks of an update, compile and trial;
                      a refusal is logged and the node flies on unchanged, a pass stops the
                      node safely and restarts it in place (`os.execv`, same pid) on the new
                      settings

Before the node exists (start-up: waiting for the heartbeat or the fix), SIGTERM and SIGINT
raise `StartupStopped` out of the wait: nothing was ordered yet, so the node just closes.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from dataclasses import dataclass
from types import FrameType
from typing import Any

from fieldkit.node.daemon import Notifier, WatchdogPacer
from fieldkit.node.node import Node
from fieldkit.vehicle.autopilot import AutopilotError
from fieldkit.vehicle.links import VehicleLink

#: Seconds the safe stop waits for the autopilot to acknowledge the stop order (the unit's
#: TimeoutStopSec is 30: destroy(), this wait and the summary fit well inside it).
STOP_ACK_TIMEOUT_S = 10.0
#: Ticks between two STATUS= lines (about one a second at 10 Hz).
STATUS_EVERY_TICKS = 10

#: The signals the node handles.
SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

#: A reload check: None if the new settings may run, else why not.
ReloadCheck = Callable[[], str | None]


class StartupStopped(Exception):  # noqa: N818  # a stop, not an error: exit 0
    """SIGTERM or SIGINT arrived before the loop began."""

    def __init__(self, signum: int) -> None:
        """`signum` is the signal that stopped the start-up."""
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


class ServiceSignals:
    """SIGTERM, SIGINT and SIGHUP handlers for the node process, installed on creation
    (main thread only: elsewhere, as in a test's thread, it installs nothing)."""

    def __init__(self) -> None:
        """Install the handlers; `restore()` puts the previous ones back."""
        self.node: Node | None = None
        self.stop_signal: int | None = None
        self.reload_requested = False
        self._saved: dict[int, Any] = {}
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                self._saved[sig] = signal.signal(sig, self._handle)
            # A node restarted in place inherits them blocked (`block_for_restart`): one
            # that came during the restart is delivered now, to these handlers.
            signal.pthread_sigmask(signal.SIG_UNBLOCK, SIGNALS)

    def _handle(self, signum: int, _frame: FrameType | None) -> None:
        if signum == signal.SIGHUP:
            self.reload_requested = True  # start-up reads the file anyway: nothing to do
            return
        if self.stop_signal is not None:  # the second one: at once
            raise KeyboardInterrupt
        self.stop_signal = signum
        if self.node is None:
            raise StartupStopped(signum)
        self.node.stop()

    def block_for_restart(self) -> bool:
        """Hold the signals back across a restart in place (they stay pending through
        execv, and the new process takes them); False if a stop came first: no restart."""
        signal.pthread_sigmask(signal.SIG_BLOCK, SIGNALS)
        return self.stop_signal is None

    def restore(self) -> None:
        """Put back the handlers found on creation."""
        for sig, handler in self._saved.items():
            signal.signal(sig, handler)
        self._saved.clear()


@dataclass
class StopResult:
    """What the safe stop ordered, and whether the autopilot acknowledged it."""

    action: str
    acknowledged: bool
    detail: str


class NodeService:
    """Runs a built node as a service: READY, watchdog pings, status, reload, safe stop."""

    def __init__(
        self,
        node: Node,
        notifier: Notifier,
        signals: ServiceSignals,
        say: Callable[[str], None],
        *,
        reload_check: ReloadCheck | None = None,
    ) -> None:
        """`reload_check` checks the config and script again on SIGHUP (None: SIGHUP is
        refused, as for a node without --config)."""
        self.node = node
        self.notifier = notifier
        self.signals = signals
        self.say = say
        self.reload_check = reload_check
        self.pacer = WatchdogPacer(notifier.watchdog_s)
        self.reloading = False  # a check passed: the node restarts on the new settings
        self._check: threading.Thread | None = None
        self._verdict: list[str | None] = []
        signals.node = node

    def run(self, seconds: float | None) -> None:
        """READY=1, then the loop until a stop signal, the end of `seconds` or a reload
        whose check passed (`reloading`)."""
        node = self.node
        fields = ["READY=1", f"STATUS={node.status_line()}"]
        if self.notifier.watchdog_s is not None:
            # The unit's interval again, after a restart in place that had widened it.
            fields.append(f"WATCHDOG_USEC={round(self.notifier.watchdog_s * 1e6)}")
        self.notifier.send(*fields)
        node.run(seconds, after_tick=self._after_tick)

    def _after_tick(self, now: float) -> None:
        node = self.node
        notifier = self.notifier
        if self.pacer.due(now):
            notifier.send("WATCHDOG=1")
        if node.runtime.ticks % STATUS_EVERY_TICKS == 0:
            notifier.send(f"STATUS={node.status_line()}")
        if self.signals.reload_requested:
            self.signals.reload_requested = False
            self._start_check()
        if self._check is not None and not self._check.is_alive():
            self._finish_check()

    def _start_check(self) -> None:
        if self._check is not None:
            self.say("reload: a check is already running; this SIGHUP is folded into it")
            return
        if self.reload_check is None:
            self.say("warning: reload refused: this node has no --config file to reload")
            return
        self.notifier.send("RELOADING=1", "STATUS=reload: checking the new config and script")
        self.say("reload: checking the config and script (the robot flies on meanwhile)")
        check = self.reload_check

        def work() -> None:
            try:
                self._verdict.append(check())
            except Exception as e:  # noqa: BLE001  # a bug in a check must not kill the node
                self._verdict.append(f"the check failed: {type(e).__name__}: {e}")

        self._check = threading.Thread(target=work, name="reload-check", daemon=True)
        self._check.start()

    def _finish_check(self) -> None:
        self._check = None
        verdict = self._verdict.pop() if self._verdict else "the check gave no verdict"
        if verdict is not None:
            self.say(f"error: reload refused, the node runs on unchanged:\n{verdict}")
            self.notifier.send("READY=1", f"STATUS=reload refused: {verdict.splitlines()[0]}")
            return
        self.say("reload: the new settings checked out; stopping safely to restart on them")
        self.reloading = True
        self.node.stop()

    def safe_stop(self, link: VehicleLink) -> StopResult:
        """STOPPING=1 (unless reloading), then the profile's stop order, awaiting its ACK."""
        if not self.reloading:
            self.notifier.send("STOPPING=1", "STATUS=stopping: ordering the vehicle to stop")
        return stop_vehicle(link, self.node.profile.failsafe.on_stop, self.say)


def stop_vehicle(link: VehicleLink, action: str, say: Callable[[str], None]) -> StopResult:
    """Order the stop `action` (hold, land, or stop: the hold mode) and wait for the ACK."""
    link.cancel_all(f"superseded by the stop order ({action})")
    command = link.land() if action == "land" else link.hold()
    try:
        link.wait_command(command, STOP_ACK_TIMEOUT_S)
    except AutopilotError as e:
        say(f"warning: stop: {action} not acknowledged by the autopilot: {e}")
        return StopResult(action, False, str(e))
    say(f"stop: {action} acknowledged by the autopilot")
    return StopResult(action, True, "acknowledged")


__all__ = [
    "NodeService",
    "ReloadCheck",
    "STOP_ACK_TIMEOUT_S",
    "ServiceSignals",
    "StartupStopped",
    "StopResult",
    "stop_vehicle",
]
