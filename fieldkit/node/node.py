"""The field node: one robot's runtime against its vehicle, its radio and a clock.

The tick itself is the robot's (`fieldkit.robot.RobotRuntime`, the same in the simulator);
the node feeds it, in this order:

    outbox      an originator's new patch file (`--update-outbox`) -> the update agent
    radio in    bundles heard since the last tick -> the runtime
    sensors     the vehicle's telemetry -> `Sensors`, plus any remote-control code now due
    step, radio out, actuators: the runtime's tick -> one bundle to the radio, at most one
                order to the vehicle

The loop keeps the profile's rate against a monotonic clock. A late tick is logged and
counted, never skipped: every tick runs all five phases. A script error puts the robot in
its safe state (the supervisor's failsafe) and the node goes on: it keeps talking to the
vehicle and the radio, so the robot stays visible and controllable. `stop()` ends the loop
at the end of a tick (Ctrl-C does that), `finish()` runs the script's `destroy()` and says
whether a script error left the robot in its failsafe.

Everything the node says goes to one `out` (by default a `NodeLog`, which stamps each line
`[UTC time] robot N: `): the script's `log(...)` and the node's own lines, in time order.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Protocol

import bvm
from bvm.digest import state_digest
from fieldkit.node.clock import TickClock
from fieldkit.node.health import LinkHealth, ReportsLinkHealth, radio_health
from fieldkit.node.log import NodeLog
from fieldkit.radio.base import RadioLink
from fieldkit.robot import geo
from fieldkit.robot.bundle_auth import CounterError
from fieldkit.robot.link_security import LinkSecurity
from fieldkit.robot.operator_command import CommandGate
from fieldkit.robot.profiles import Profile
from fieldkit.robot.rc import RcCommand
from fieldkit.robot.runtime import RobotRuntime, ScriptStatus, TickRecord
from fieldkit.robot.vehicle import VehiclePort, sensors_from

if TYPE_CHECKING:
    from fieldkit.node.outbox import PatchSource
    from fieldkit.update.host import RobotUpdater
    from fieldkit.update.keys import RobotKeys
    from fieldkit.update.store import VersionStore


class FlightRecorder(Protocol):
    """What keeps a flight (fieldkit/record/recorder.py): the node calls it through each
    tick, in the tick's order; the autopilot's bytes reach it from the link's taps."""

    def begin_tick(self, tick: int, clock_s: float, unix_ns: int) -> None:
        """Tick `tick` begins at node time `clock_s` (wall time `unix_ns`)."""

    def radio_in(self, sender: int, data: bytes) -> None:
        """A frame the radio handed in this tick."""

    def radio_out(self, data: bytes) -> None:
        """A frame the node sent this tick."""

    def outbox_in(self, data: bytes) -> None:
        """A patch the node read from its outbox this tick (an input, like a radio frame)."""

    def end_tick(self, record: TickRecord, digest: bytes, log: list[str]) -> None:
        """The tick ran: what it saw and did, its script-state digest, its script lines."""


#: Late ticks logged one by one; after that every hundredth (a slow machine must not flood).
LATE_TICKS_LOGGED = 10


class Node:
    """One robot in the field: its runtime, vehicle and radio, driven by `tick`."""

    def __init__(
        self,
        profile: Profile,
        program: bvm.Program,
        robot_id: int,
        vehicle: VehiclePort,
        radio: RadioLink | None,
        *,
        home: tuple[float, float, float],
        commands: Sequence[RcCommand] = (),
        clock: Callable[[], float] | TickClock = time.monotonic,
        out: Callable[[str], None] | None = None,
        seed: int = 0,
        globals_: Mapping[str, object] | None = None,
        store: VersionStore | None = None,
        keys: RobotKeys | None = None,
        security: LinkSecurity | None = None,
        command_gate: CommandGate | None = None,
        recorder: FlightRecorder | None = None,
        outbox: PatchSource | None = None,
    ) -> None:
        """`commands` are this robot's remote-control codes (times from start); `out` takes
        each line the node logs, unstamped (default: a `NodeLog` on stdout); `seed` seeds
        the script's generators (with the robot id: each robot its own); `globals_` are
        script globals set before `init()` (`--set`); `store` is the `--state-dir` version
        store `program` came from, `keys` the `--keys` (both None without the options);
        `security` seals and checks the bundles (`node_security`; None: plain bytes);
        `command_gate` checks the operator's signed commands (`node_commands`); `recorder`
        keeps every tick's inputs and outputs (`--record`); `outbox` gives the patches made
        on this robot (`--update-outbox`; it needs `store` and `keys`)."""
        self.profile = profile
        #: What the update agent works with: the robot's versions and its keys.
        self.store = store
        self.keys = keys
        self.robot_id = robot_id
        self.vehicle = vehicle
        self.radio = radio
        #: The node's time: frozen for the length of each tick (fieldkit/node/clock.py).
        self.tick_clock = clock if isinstance(clock, TickClock) else TickClock(clock)
        self.clock = self.tick_clock.now
        self.out: Callable[[str], None] = out if out is not None else NodeLog(robot_id)
        # The script API tags each line `[id] ` for hosts that mix robots in one stream;
        # the node's `out` names its one robot itself.
        self._script_tag = f"[{robot_id}] "
        self.stopping = False
        self.period = 1.0 / profile.node.loop_rate_hz
        self.frame = geo.LocalFrame(*home)
        self.commands = sorted(commands, key=lambda c: c.t)
        self.late_ticks = 0
        self.started = self.clock()
        self.runtime = RobotRuntime(
            robot_id,
            profile,
            self.frame,
            seed=seed,
            log_sink=self._script_log,
            # A runaway step cannot stall the loop.
            max_seconds=max(0.5, 5 * self.period),
            # Nor can a first call's translation (50-110 ms of a tick, measured).
            translate_ahead=True,
            security=security,
            commands=command_gate,
        )
        self.floor_errors = 0
        self.recorder = recorder
        self._record: TickRecord | None = None  # the tick's record, for the recorder
        self._tick_log: list[str] = []  # the script's lines of the tick, for the recorder
        if recorder is not None:
            self.runtime.observer = self._observe
        self.runtime.start(program, sensors_from(vehicle.telemetry(), self.frame), globals_)
        # Over-the-air updates need both the versions (--state-dir) and the keys (--keys).
        self.updater: RobotUpdater | None = None
        if store is not None and keys is not None:
            from fieldkit.node.updates import node_updater

            self.updater = node_updater(self.runtime, store, keys, self.out, seed=seed)
            self._room_for_updates(radio)
        if outbox is not None and self.updater is None:
            raise ValueError("an update outbox needs the update agent: a store and keys")
        self.outbox = outbox

    def _room_for_updates(self, radio: RadioLink | None) -> None:
        """Let an XBee carry a tick's update frame next to its bundle.

        XbeeMav paces a radio at one frame per 100 ms: one bundle a tick at 10 Hz, nothing
        more. An update frame is a packet of its own, so at that pace the queue grows by a
        frame a tick and drops the oldest: half the bundles and update frames lost, the rest
        a second late (seen in SITL: no patch ever got through). Two frames a tick fit.
        """
        from fieldkit.radio.xbee_serial import XBeeRadio

        if isinstance(radio, XBeeRadio):
            engine = radio.engine
            engine.pace(min(engine.base_interframe_s, self.period / 2))

    def _script_log(self, text: str) -> None:
        text = text.removeprefix(self._script_tag)
        if self.recorder is not None:
            self._tick_log.append(text)
        self.out(text)

    def _observe(self, record: TickRecord) -> None:
        self._record = record

    def _due_command(self, now: float) -> RcCommand | None:
        if self.commands and self.commands[0].t <= now - self.started:
            return self.commands.pop(0)
        return None

    # ------------------------------------------------------------ one tick

    def tick(self) -> None:
        """Run the five phases once, at one time (`tick_clock`)."""
        tick_clock = self.tick_clock
        now = tick_clock.begin_tick()
        try:
            self._tick(now, tick_clock.unix_ns)
        finally:
            tick_clock.end_tick()

    def _tick(self, now: float, unix_ns: int) -> None:
        runtime = self.runtime
        updater = self.updater
        recorder = self.recorder
        if isinstance(self.out, NodeLog):
            self.out.tick = runtime.ticks  # the journal's TICK field
        if recorder is not None:
            recorder.begin_tick(runtime.ticks, now, unix_ns)
        # 0. the outbox: a patch made on this robot, verified and spread as if received
        if self.outbox is not None and updater is not None:
            patch = self.outbox.poll(runtime.ticks)
            if patch is not None:
                if recorder is not None:
                    recorder.outbox_in(patch)
                self._originate(patch, updater, self.outbox.name)
        # 1. radio in: update frames to the update agent, bundles to the runtime
        if self.radio is not None:
            for sender, data in self.radio.poll():
                if recorder is not None:
                    recorder.radio_in(sender, data)
                if updater is None or not updater.receive(data):
                    runtime.receive_bundle(data)
        # 2. sensors
        self.vehicle.poll()
        sensors = sensors_from(self.vehicle.telemetry(), self.frame)
        # 3. step: the update's decision (stand by, switch, roll back) first
        if updater is not None:
            updater.before_step(sensors)
        out = runtime.tick(sensors, self._due_command(now), time_ns=unix_ns)
        # 4. radio out: the bundle, then the update frame if there is one
        frame = updater.after_step() if updater is not None else None
        if self.radio is not None:
            if out.bundle:  # b"": no counter could be had (the runtime said why)
                self._send(out.bundle)
            for relay in runtime.take_relays():  # the operator's commands, passed on once
                self._send(relay)
            if frame is not None:
                self._send(frame)
        self._save_floors()
        # 5. actuators
        if out.order is not None:
            self.vehicle.execute(out.order, self.frame)
        if recorder is not None and self._record is not None:
            recorder.end_tick(self._record, state_digest(runtime.vm), self._tick_log)
            self._tick_log = []

    def _originate(self, patch: bytes, updater: RobotUpdater, name: str) -> None:
        """Hand a patch from the outbox to the update agent; its verdict is logged once."""
        from fieldkit.update.agent import digest_of

        held = updater.agent.transfers.get(digest_of(patch))
        if held is not None and held.complete:
            # Made here before (a restart), pulled from a neighbour, or kept by the store:
            # verifying it again would only refuse it as not above the version it made.
            self.out(f"outbox {name}: version {held.version}'s patch, which this robot "
                     "already holds: nothing new")  # fmt: skip
            return
        self.out(f"outbox {name}: a new patch ({len(patch)} bytes): verifying it")
        try:
            updater.inject(patch)
        except Exception as e:  # noqa: BLE001  # a file on disk must never stop the robot
            self.out(f"outbox {name}: patch not handled: {type(e).__name__}: {e}")

    def _send(self, data: bytes) -> None:
        assert self.radio is not None
        self.radio.send(data)
        if self.recorder is not None:
            self.recorder.radio_out(data)

    def _save_floors(self) -> None:
        """The neighbours' counters to disk, about once a minute (a failed save is logged:
        it only matters after a reboot, and a full disk must not stop the robot)."""
        security = self.runtime.security
        if security is None:
            return
        try:
            security.save_floors()
        except CounterError as e:
            self.floor_errors += 1
            if self.floor_errors == 1 or self.floor_errors % 100 == 0:
                self.out(f"bundle floors not saved ({self.floor_errors} times): {e}")

    # ------------------------------------------------------------ the loop

    def run(
        self,
        seconds: float | None = None,
        sleep: Callable[[float], None] = time.sleep,
        after_tick: Callable[[float], None] | None = None,
    ) -> None:
        """Tick at the profile's rate until `seconds` have passed (forever if None) or
        `stop()` is called; `after_tick(now)` runs after each completed tick (the service's
        watchdog ping: a loop stalled inside a tick never reaches it)."""
        start = self.clock()
        next_tick = start
        while not self.stopping and (seconds is None or self.clock() - start < seconds):
            self.tick()
            if after_tick is not None:
                after_tick(self.clock())
            next_tick += self.period
            now = self.clock()
            if now > next_tick:
                self.late_ticks += 1
                late = now - next_tick
                if self.late_ticks <= LATE_TICKS_LOGGED or self.late_ticks % 100 == 0:
                    self.out(f"tick {self.runtime.ticks} late by {late * 1000:.0f} ms")
                # Keep the rate from here: no burst of catch-up ticks after a stall.
                next_tick = now
            elif not self.stopping:
                sleep(next_tick - now)

    def stop(self) -> None:
        """End `run` after the tick in progress (safe from a signal handler: it sets a flag)."""
        self.stopping = True

    def finish(self) -> str | None:
        """The run is over: run the script's `destroy()`. The script error that leaves the
        robot in its failsafe at the end (in the loop, or in `destroy()`), else None."""
        runtime = self.runtime
        failed = runtime.status is ScriptStatus.FAILED
        before = runtime.error
        runtime.destroy()
        if runtime.security is not None:
            # What the neighbours sent up to now: a restart then reopens no replay window.
            try:
                runtime.security.save_floors(now=True)
            except CounterError as e:
                self.out(f"bundle floors not saved at stop: {e}")
        if runtime.error is not before:  # destroy() failed
            failed = True
        return runtime.error if failed else None

    def status_line(self) -> str:
        """One line for `systemctl status`: tick, script state, neighbours, link health."""
        runtime = self.runtime
        heard = sum(1 for _, _, t in runtime.heard.values() if runtime.ticks - t <= runtime.timeout)
        t = self.vehicle.telemetry()
        state = runtime.state or runtime.status.name.lower()
        failsafe = runtime.supervisor.failsafe
        radio = self.radio.stats if self.radio is not None else Counter()
        frames_in = radio.get("frames_in", 0) + radio.get("datagrams_in", 0)
        losses = [
            h.status(name)
            for name, h in (("autopilot", self.autopilot_health()), ("radio", self.radio_health()))
        ]
        return (
            f"tick {runtime.ticks}, state {state}, {heard} neighbours, "
            f"autopilot heartbeat {t.heartbeat_age_s:.1f} s ago, radio {frames_in} frames in"
            + "".join(f", {loss}" for loss in losses if loss is not None)
            + (f", failsafe {failsafe}" if failsafe else "")
            + (f", {self.late_ticks} late ticks" if self.late_ticks else "")
        )

    def autopilot_health(self) -> LinkHealth:
        """The autopilot device's losses (none for a vehicle that cannot lose one)."""
        vehicle = self.vehicle
        if isinstance(vehicle, ReportsLinkHealth):
            return vehicle.link_health(self.clock())
        return LinkHealth()

    def radio_health(self) -> LinkHealth:
        """The radio device's losses (an XBee's; none for a UDP radio or no radio)."""
        return radio_health(self.radio)

    def summary(self) -> dict[str, object]:
        """What `--out DIR` writes to summary.json."""
        messages, bad = self.vehicle.counters()
        radio = self.radio.stats if self.radio is not None else Counter()
        autopilot, radio_loss = self.autopilot_health(), self.radio_health()
        runtime = self.runtime
        return {
            "robot_id": self.robot_id,
            "ticks": runtime.ticks,
            "late_ticks": self.late_ticks,
            "mavlink_messages": messages,
            "mavlink_bad_frames": bad,
            # XBee radios count frames, the UDP radio datagrams.
            "radio_frames_in": radio.get("frames_in", 0) + radio.get("datagrams_in", 0),
            "radio_frames_out": radio.get("frames_out", 0) + radio.get("datagrams_out", 0),
            "radio_bad_frames": radio.get("bad_frames", 0) + radio.get("bad_datagrams", 0),
            # Device loss (a loose cable): outages, seconds down in all, what was dropped.
            "autopilot_outages": autopilot.outages,
            "autopilot_down_s": round(autopilot.down_s, 3),
            "autopilot_bytes_dropped": autopilot.dropped,
            "radio_outages": radio_loss.outages,
            "radio_down_s": round(radio_loss.down_s, 3),
            "radio_frames_dropped_down": radio_loss.dropped,
            "bundle_errors": runtime.counters["bundle_errors"],
            "decode_errors": runtime.vm.counters["decode_errors"],
            "errors": [runtime.error] if runtime.error is not None else [],
            "final_state": runtime.state,
            "failsafe": runtime.supervisor.failsafe,
            "security": None if runtime.security is None else runtime.security.summary(),
            "commands": None if runtime.commands is None else dict(runtime.commands.counters),
        } | self._update_summary()

    def _update_summary(self) -> dict[str, object]:
        """The version the robot runs at the end and what its update agent did."""
        updater = self.updater
        if updater is None:
            return {"script_version": None, "update": None}
        agent = updater.agent
        return {
            "script_version": agent.running_hash,
            "update": {
                "version": agent.version,
                "bad_versions": sorted(agent.bad),
                # Why, where this robot judged it (a version heard of as bad is left out).
                "judged_bad": {str(v): agent.bad[v] for v in sorted(agent.judged)},
                "update_bytes_sent": agent.bytes_sent,
                "counters": dict(sorted(agent.counters.items())),
                "actions": [f"{t}: {type(a).__name__} {a.version}" for t, a in updater.actions],
            },
        }


__all__ = ["FlightRecorder", "Node"]
