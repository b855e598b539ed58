"""The safety supervisor: between the script and the vehicle, always on, outside the script.

The script asks; the supervisor decides what the vehicle is told, once per tick. Priority,
highest first (docs/rosbuzz.md#recommendations: operator > safety > script):

1. **Pilot**: an RC override from the backup pilot always wins. The supervisor sends nothing
   while it lasts; the script keeps running but is not obeyed.
2. **Failsafes**: autopilot heartbeat lost longer than the profile allows, a script error,
   a low battery. Each triggers the profile's action (hold, land, rtl, stop) once and latches
   it: the script is not obeyed again until the node is restarted (or, for heartbeat loss,
   until the link is back and the action has been sent).
3. **Script**: its commands in order. A target (`goto`) is checked against the geofence
   (polygon and ceiling) and then followed with a carrot: the setpoint sent each tick is at
   most `max_speed_mps * CARROT_S` metres ahead, so the profile's speed limit holds whatever
   the autopilot's own settings are.

Positions here are in the local frame (north, east, up), metres; the geofence polygon, given
in lat/lon by the profile, is converted once at start.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Final, Literal, NamedTuple, get_args

from fieldkit.robot import geo, polygon
from fieldkit.robot.profiles import FailsafeAction, Profile
from fieldkit.robot.script_api import ON_GROUND, Command, Sensors

#: How far ahead of the vehicle a setpoint may be, in seconds at the profile's top speed.
CARROT_S = 1.0

#: Healthy heartbeat needed, after a heartbeat loss that made the robot hold, before the
#: script gets its robot back.
RECOVERY_S = 3.0

HEARTBEAT_LOST = "autopilot heartbeat lost"

#: A discrete command (takeoff, land...) repeated by the script is re-sent after this long.
RESEND_S = 5.0


#: What the vehicle can be told: go to (north, east, alt), take off (alt), land, return
#: to launch, hold position, arm, disarm.
OrderKind = Literal["goto", "takeoff", "land", "rtl", "hold", "arm", "disarm"]
ORDER_KINDS: Final[tuple[OrderKind, ...]] = get_args(OrderKind)


class Order(NamedTuple):
    """What the vehicle is told this tick: kind and, for "goto"/"takeoff", its numbers.

    A named tuple (immutable, hashable): one is made every tick a vehicle moves."""

    kind: OrderKind
    args: tuple[float, ...] = ()


class Supervisor:
    """Checks and arbitrates every command the script sends to the vehicle."""

    def __init__(self, profile: Profile, frame: geo.LocalFrame) -> None:
        self.profile = profile
        self.ground = profile.is_ground
        self.max_speed = profile.kinematics.max_speed_mps
        self.ceiling = profile.geofence.max_altitude_m if not self.ground else math.inf
        # The fence as (north, east) corners in the local frame.
        self.fence: list[tuple[float, float]] = []
        for lat, lon in profile.geofence.polygon:
            x, y, _ = frame.from_gps(lat, lon, 0.0)
            self.fence.append((y, x))
        self.queue: deque[Command] = deque()
        self.target: tuple[float, float, float] | None = None  # latched absolute goto
        self.failsafe: str | None = None  # the reason, once a failsafe fired
        self.standing_by: str | None = None  # why the script is not obeyed for now (an update)
        self._hold_sent = False
        self.action: FailsafeAction | None = None
        self._action_sent = False
        self.events: list[str] = []  # what the supervisor did and why, for the node's log
        self._healthy = 0  # ticks of healthy heartbeat since a heartbeat-loss failsafe
        self.recovery_ticks = round(RECOVERY_S * profile.node.loop_rate_hz)
        self.resend_ticks = round(RESEND_S * profile.node.loop_rate_hz)
        self._sent: dict[Order, int] = {}  # the last discrete order and when it went out
        self._now = 0  # ticks
        self.clamped = 0  # setpoints changed by the fence or the ceiling
        # How close to a goto target counts as there (the profile's hover accuracy): the
        # setpoint keeps streaming (PX4 needs it); `arrived` tells, asked (not every tick).
        self.accuracy = profile.kinematics.hover_accuracy_m

    # ------------------------------------------------------------ inputs

    def submit(self, commands: list[Command]) -> None:
        """The commands the script queued this tick (ignored once a failsafe has fired)."""
        if self.failsafe is None:
            self.queue.extend(commands)

    def stand_by(self, reason: str) -> None:
        """Hold the vehicle still and obey no script command until `resume` (an update's
        barrier): a UAV holds position, a ground robot stops. Failsafes and the pilot keep
        their priority."""
        self.standing_by = reason
        self._hold_sent = False
        self.queue.clear()
        self.target = None
        # No event: a standby is routine (its host logs why), not a warning for every robot.

    def resume(self) -> None:
        """End a standby: the script's commands are obeyed again."""
        self.standing_by = None

    def script_restarted(self) -> None:
        """A new program replaced the one that failed (an update or its rollback): a
        script-error failsafe is lifted; any other failsafe stands."""
        if self.failsafe is not None and self.failsafe.startswith("script error"):
            self.failsafe = self.action = None
            self.events.append("script restarted: failsafe lifted")

    def script_error(self, message: str) -> None:
        """The script failed: its robot goes to the profile's safe state."""
        self._trip(f"script error: {message}", self.profile.failsafe.on_script_error)

    def _trip(self, reason: str, action: FailsafeAction) -> None:
        if self.failsafe is not None:
            return  # the first failsafe's action stands
        self.failsafe, self.action, self._action_sent = reason, action, False
        self.queue.clear()
        self.target = None
        self.events.append(f"failsafe ({reason}): {action}")

    # ------------------------------------------------------------ one tick

    def tick(self, v: Sensors) -> Order | None:
        """The one order for the vehicle this tick (None: send nothing)."""
        if v.rc_override:
            return None  # the pilot has the vehicle
        fs = self.profile.failsafe
        if v.heartbeat_age_s > self.profile.autopilot.heartbeat_timeout_s:
            self._trip(HEARTBEAT_LOST, fs.on_heartbeat_loss)
            self._action_sent = False  # nothing reaches a silent autopilot: resend when back
            self._healthy = 0
            return None
        if v.status != ON_GROUND and v.battery_percent < fs.low_battery_percent:
            self._trip(f"battery at {v.battery_percent:.0f}%", fs.on_low_battery)
        if self.failsafe is not None:
            if not self._action_sent:
                self._action_sent = True
                action = self.action
                return Order("hold" if action == "stop" or action is None else action)
            if self.failsafe == HEARTBEAT_LOST and self.action in ("hold", "stop"):
                # Holding in the air and the link is back: give the script back its robot
                # after a few healthy seconds (landing or returning is never undone).
                self._healthy += 1
                if self._healthy >= self.recovery_ticks:
                    self.events.append("autopilot link recovered: script resumed")
                    self.failsafe = self.action = None
            return None
        if self.standing_by is not None:
            self.queue.clear()
            if self._hold_sent:
                return None
            self._hold_sent = True
            return Order("hold")
        self._now += 1
        while self.queue:
            c = self.queue.popleft()
            if c.kind == "goto":
                self.target = self._fenced(v, c.args)
                continue  # the carrot below follows the newest target
            if c.kind == "takeoff":
                if self.ground:
                    self.events.append("takeoff refused: ground robot")
                    continue
                order = Order("takeoff", (min(c.args[0], self.ceiling),))
            elif c.kind == "land" or c.kind == "rtl" or c.kind == "arm" or c.kind == "disarm":
                order = Order(c.kind)
            else:
                continue  # camera and other auxiliary commands do not move the vehicle
            # Scripts repeat a command every step until it shows (ROSBuzz's launch calls
            # uav_takeoff each tick): the autopilot gets it once, again only if it has had
            # RESEND_S to act and the script still asks.
            last = self._sent.get(order)
            if last is not None and self._now - last < self.resend_ticks:
                continue
            self._sent = {order: self._now}
            self.target = None
            return order
        if self.target is not None:
            return Order("goto", self._carrot(v, self.target))
        return None

    def arrived(self, v: Sensors) -> bool:
        """Whether the vehicle is at its goto target, within the profile's hover accuracy
        (horizontally, and vertically for a UAV); False without a target."""
        target = self.target
        if target is None:
            return False
        return math.hypot(target[0] - v.north, target[1] - v.east) <= self.accuracy and (
            self.ground or abs(target[2] - v.alt) <= self.accuracy
        )

    def _fenced(self, v: Sensors, target: tuple[float, ...]) -> tuple[float, float, float]:
        north, east, alt = target
        if self.ground:
            alt = 0.0
        elif alt > self.ceiling:
            alt = self.ceiling
            self.clamped += 1
        if self.fence and not polygon.inside((north, east), self.fence):
            here = (v.north, v.east)
            edge = polygon.segment_exit(here, (north, east), self.fence)
            # Outside already (no crossing): stay where we are rather than go further out.
            north, east = edge if edge is not None else here
            self.clamped += 1
            self.events.append("goto clamped to the geofence")
        return north, east, alt

    def _carrot(self, v: Sensors, target: tuple[float, float, float]) -> tuple[float, ...]:
        dn, de = target[0] - v.north, target[1] - v.east
        dist = math.hypot(dn, de)
        reach = self.max_speed * CARROT_S
        if dist <= reach:
            return target
        k = reach / dist
        return (v.north + dn * k, v.east + de * k, target[2])
