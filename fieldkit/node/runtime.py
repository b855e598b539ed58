"""The field node: one robot's VM against its autopilot and radio, tick after tick.

Each tick, in this order (the order ROSBuzz uses, spec rosbuzz-node.md §1.2):

    radio in    bundles heard since the last tick -> the VM's in-queue, senders' positions
    sensors     the autopilot's telemetry -> the script API's globals
    step        process_inbox(), then the script's step()
    radio out   drain_outbox() into one bundle -> the radio
    actuators   the script's commands -> the safety supervisor -> at most one order to the
                autopilot

The loop keeps the profile's rate against a monotonic clock. A late tick is logged and
counted, never skipped: every tick runs all five phases. A script error puts the robot in
its safe state (the supervisor's failsafe) and the node goes on: it keeps talking to the
autopilot and the radio, so the robot stays visible and controllable.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import bvm
from bvm.errors import BuzzError
from fieldkit import bundle as wirebundle
from fieldkit import geo
from fieldkit.profiles import Profile
from fieldkit.radio.base import RadioLink
from fieldkit.safety import Order, Supervisor, VehicleState
from fieldkit.script_api import IN_AIR, ON_GROUND, V_GROUND, V_UAV, ScriptAPI, Sensors

_log = logging.getLogger("fieldkit.node")

#: A neighbour not heard from for this long is dropped from `neighbors` (as in the simulator).
NEIGHBOR_TIMEOUT_S = 5.0


class AutopilotPort(Protocol):
    """What the node needs of an autopilot link (fieldkit.autopilot.link.Autopilot)."""

    def poll(self) -> None:
        """Read what arrived, progress pending commands, send the periodic heartbeat."""

    def telemetry(self) -> Any:
        """The latest telemetry snapshot."""

    def execute(self, order: Order, frame: geo.LocalFrame) -> None:
        """Start carrying out one order of the supervisor."""

    def counters(self) -> tuple[int, int]:
        """(MAVLink messages received, bad frames)."""


@dataclass(frozen=True)
class Telemetry:
    """The autopilot state the node reads each tick (filled by the autopilot adapter)."""

    lat: float
    lon: float
    alt: float  # relative to home, metres
    yaw: float
    voltage: float
    current: float
    battery_percent: float
    armed: bool
    flying: bool
    heartbeat_age_s: float
    rc_override: bool
    status: int = ON_GROUND


@dataclass(frozen=True)
class ScheduledCommand:
    """A remote-control code for this robot at a time after start (ground-station input)."""

    t: float
    code: int
    params: tuple[float, ...] = ()


class Node:
    """One robot: VM, script API, safety supervisor, autopilot and radio, driven by `tick`."""

    def __init__(
        self,
        profile: Profile,
        program: bvm.Program,
        robot_id: int,
        autopilot: AutopilotPort,
        radio: RadioLink | None,
        *,
        home: tuple[float, float, float],
        commands: Sequence[ScheduledCommand] = (),
        clock: Callable[[], float] = time.monotonic,
        out: Callable[[str], None] = print,
    ) -> None:
        self.profile = profile
        self.robot_id = robot_id
        self.autopilot = autopilot
        self.radio = radio
        self.clock = clock
        self.period = 1.0 / profile.node.loop_rate_hz
        self.frame = geo.LocalFrame(*home)
        self.supervisor = Supervisor(profile, self.frame)
        self.commands = sorted(commands, key=lambda c: c.t)
        self.stats: Counter[str] = Counter()
        self.errors: list[str] = []
        self.state: str | None = None
        self.ticks = 0
        self.late_ticks = 0
        self.heard: dict[int, tuple[float, float, float]] = {}  # id -> (lat, lon, time)
        self.number = 0
        self.started = clock()
        self.vm = bvm.VM(robot_id=robot_id)
        self.vm.max_seconds = max(0.5, 5 * self.period)  # a runaway step cannot stall the loop
        self.api = ScriptAPI(
            self.vm,
            vehicle_type=V_GROUND if profile.is_ground else V_UAV,
            takeoff_altitude=profile.kinematics.takeoff_altitude_m,
            log_sink=lambda _rid, text: out(text),
        )
        self.script_ok = True
        try:
            self.vm.load(program)
            self.api.install()
            self.api.before_step(self._sensors(self._telemetry(), 0, None), [])
            self.vm.execute()
            if self.vm.gload("init") is not None:
                self.vm.call("init")
        except BuzzError as e:
            self._script_failed(e)

    # ------------------------------------------------------------ helpers

    def _telemetry(self) -> Telemetry:
        return self.autopilot.telemetry()  # type: ignore[no-any-return]

    def _script_failed(self, e: BuzzError) -> None:
        self.script_ok = False
        self.errors.append(str(e))
        self.supervisor.script_error(str(e))
        _log.error("script error, robot to its safe state: %s", e)

    def _sensors(self, t: Telemetry, now: float, rc: ScheduledCommand | None) -> Sensors:
        x, y, _ = self.frame.from_gps(t.lat, t.lon, t.alt)
        status = t.status
        return Sensors(
            lat=t.lat,
            lon=t.lon,
            alt=t.alt,
            north=y,
            east=x,
            yaw=t.yaw,
            voltage=t.voltage,
            current=t.current,
            battery_percent=int(t.battery_percent),
            status=status,
            armed=t.armed,
            rc_cmd=rc.code if rc is not None else 0,
            rc_goto=(
                (int(rc.params[0]), rc.params[1], rc.params[2], rc.params[3])
                if rc is not None and rc.code == 16 and len(rc.params) == 4
                else None
            ),
        )

    def _due_command(self, now: float) -> ScheduledCommand | None:
        if self.commands and self.commands[0].t <= now - self.started:
            return self.commands.pop(0)
        return None

    # ------------------------------------------------------------ one tick

    def tick(self) -> None:
        """Run the five phases once."""
        now = self.clock()
        vm = self.vm
        # 1. radio in
        if self.radio is not None:
            for sender, data in self.radio.poll():
                try:
                    b = wirebundle.decode(data)
                except wirebundle.BundleError as e:
                    self.stats["bundle_errors"] += 1
                    _log.warning("bad bundle from robot %d: %s", sender, e)
                    continue
                if b.robot == self.robot_id:
                    continue  # our own, echoed back by a mesh
                self.heard[b.robot] = (b.lat, b.lon, now)
                for payload in b.messages:
                    vm.receive(b.robot, payload)
        # 2. sensors
        self.autopilot.poll()
        t = self._telemetry()
        sensors = self._sensors(t, now, self._due_command(now))
        commands = []
        # 3. step
        if self.script_ok:
            neighbors = []
            for nid, (lat, lon, heard) in list(self.heard.items()):
                if now - heard > NEIGHBOR_TIMEOUT_S:
                    del self.heard[nid]
                    continue
                dist, az = geo.range_bearing(t.lat, t.lon, lat, lon)
                neighbors.append((nid, dist, az, 0.0))
            try:
                vm.process_inbox()
                self.api.before_step(sensors, neighbors)
                vm.call("step")
                commands = self.api.after_step()
                state = vm.globals.get("BVMSTATE")
                self.state = state if state.__class__ is str else None
            except BuzzError as e:
                self._script_failed(e)
        # 4. radio out
        if self.radio is not None:
            messages = vm.drain_outbox(wirebundle.MAX_BUZZ_BYTES, wirebundle.MSG_OVERHEAD)
            if not self.script_ok:
                messages = []
            self.number += 1
            b = wirebundle.Bundle(
                self.robot_id,
                tuple(messages),
                t.lat,
                t.lon,
                t.alt,
                number=self.number,
                time_ns=time.time_ns(),
            )
            self.radio.send(wirebundle.encode(b))
        # 5. actuators
        self.supervisor.submit(commands)
        order = self.supervisor.tick(
            VehicleState(
                sensors.north,
                sensors.east,
                t.alt,
                t.flying,
                t.battery_percent,
                heartbeat_age_s=t.heartbeat_age_s,
                rc_override=t.rc_override,
            )
        )
        for event in self.supervisor.events:
            _log.warning("%s", event)
        self.supervisor.events.clear()
        if order is not None:
            self.autopilot.execute(order, self.frame)
        self.ticks += 1

    # ------------------------------------------------------------ the loop

    def run(
        self, seconds: float | None = None, sleep: Callable[[float], None] = time.sleep
    ) -> None:
        """Tick at the profile's rate until `seconds` have passed (forever if None)."""
        start = self.clock()
        next_tick = start
        while seconds is None or self.clock() - start < seconds:
            self.tick()
            next_tick += self.period
            now = self.clock()
            if now > next_tick:
                self.late_ticks += 1
                late = now - next_tick
                if self.late_ticks <= 10 or self.late_ticks % 100 == 0:
                    _log.warning("tick %d late by %.0f ms", self.ticks, late * 1000)
                # Keep the rate from here: no burst of catch-up ticks after a stall.
                next_tick = now
            else:
                sleep(next_tick - now)

    def summary(self) -> dict[str, object]:
        """What `--out DIR` writes to summary.json."""
        messages, bad = self.autopilot.counters()
        radio = self.radio.stats if self.radio is not None else Counter()
        return {
            "robot_id": self.robot_id,
            "ticks": self.ticks,
            "late_ticks": self.late_ticks,
            "mavlink_messages": messages,
            "mavlink_bad_frames": bad,
            # XBee radios count frames, the UDP radio datagrams.
            "radio_frames_in": radio.get("frames_in", 0) + radio.get("datagrams_in", 0),
            "radio_frames_out": radio.get("frames_out", 0) + radio.get("datagrams_out", 0),
            "radio_bad_frames": radio.get("bad_frames", 0) + radio.get("bad_datagrams", 0),
            "bundle_errors": self.stats["bundle_errors"],
            "decode_errors": self.vm.net.stats["decode_errors"],
            "errors": list(self.errors),
            "final_state": self.state,
            "failsafe": self.supervisor.failsafe,
        }


def flying_status(alt: float, armed: bool) -> int:
    """A flight.status from altitude and arming, for autopilots that give nothing better."""
    return IN_AIR if armed and alt > 0.3 else ON_GROUND
