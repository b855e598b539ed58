"""The script API: the closures and per-tick globals a Buzz behavior sees on a robot.

The same API, in the simulator and on the field node, so a script runs unmodified in both.
It is ROSBuzz's (docs/rosbuzz.md#script-api), so ROSBuzz scripts run too, without its bugs:

* `goto_abs(dx, dy, dh, yaw)` latches an absolute target (where the robot is now, plus the
  offset), held until the next command: no creeping when the script stops commanding
  (docs/rosbuzz.md#setpoint-creep);
* commands queue in order (FIFO) instead of overwriting one slot; each goes to the host, which
  checks it against the safety limits before the vehicle sees it;
* numeric arguments accept ints where ROSBuzz demanded floats (a type error there ends the node);
* `ROBOTS` is set before `init()` (ROSBuzz leaves it nil for the first step);
* `voronoi` uses Qhull (scipy) and keeps the region's corners in boundary cells.

Data flows one way. Each tick the host hands in a `Sensors` snapshot and the neighbour list,
`before_step` pushes them into the VM, the script's `step()` runs, and `after_step` returns
the `Command`s the script queued, for the host to actuate.
"""

from __future__ import annotations

import random
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final, Literal, NamedTuple

import bvm
from bvm.errors import BuzzError
from bvm.values import Table, f32, format_log, type_name

# Imported with the API, never inside a tick: the first `voronoi` call used to import
# scipy (250-310 ms) in the middle of a 100 ms tick.
from fieldkit.robot import geo, polygon, shapes, voronoi

#: storegoal refuses goals farther than this (ROSBuzz's rule, docs/rosbuzz.md#limits).
MAX_GOAL_DISTANCE_M = 250.0

#: flight.status codes (ROSBuzz, from mavros ExtendedState). Plain ints: they go into the VM.
FlightStatus = Literal[1, 2, 3, 4]
ON_GROUND: Final = 1
IN_AIR: Final = 2
TAKING_OFF: Final = 3
LANDING: Final = 4
FLIGHT_STATUSES: Final[tuple[FlightStatus, ...]] = (ON_GROUND, IN_AIR, TAKING_OFF, LANDING)

#: V_TYPE values of ROSBuzz scripts.
V_UAV, V_GROUND = 0, 2


@dataclass(slots=True)
class Sensors:
    """What the host knows about its vehicle this tick: the script's globals and the
    supervisor's input come from here, and only from here."""

    lat: float
    lon: float
    alt: float  # metres above the takeoff ground
    north: float  # local frame, metres
    east: float
    yaw: float = 0.0  # radians
    voltage: float = 0.0
    current: float = 0.0
    battery_percent: float = 100.0  # the script sees it as a whole number (`capacity`)
    status: FlightStatus = ON_GROUND
    armed: bool = False
    rc_cmd: int = 0  # a remote-control code received this tick, else 0
    rc_goto: tuple[int, float, float, float] | None = None  # (id, lat, lon, alt) with code 16
    rc_param: int | float | None = None  # another code's first param (900: the root's id)
    heartbeat_age_s: float = 0.0  # since the autopilot was last heard (0 in simulation)
    rc_override: bool = False  # the backup pilot has the vehicle


#: What a script can ask of its vehicle (`Command.kind`).
CommandKind = Literal["takeoff", "land", "rtl", "arm", "disarm", "goto", "gimbal", "picture"]


class Command(NamedTuple):
    """One actuation request from the script, for the host to check and execute.

    kind: "takeoff" (alt), "land", "rtl", "arm", "disarm", "goto" (north, east, alt: an
    absolute local target), "gimbal" (4 values), "picture".
    """

    kind: CommandKind
    args: tuple[float, ...] = ()


def _number(x: Any, what: str) -> float:
    if x.__class__ is float or x.__class__ is int:
        return float(x)
    raise BuzzError(f"type mismatch: {what}: expected a number, got {type_name(x)}")


def _point(t: Any, what: str) -> tuple[float, float]:
    """A {x, y} table as (north, east)."""
    if t.__class__ is not Table:
        raise BuzzError(f"type mismatch: {what}: expected a table {{x, y}}, got {type_name(t)}")
    return _number(t["x"], f"{what}.x"), _number(t["y"], f"{what}.y")


@dataclass
class ScriptAPI:
    """The closures and globals of one robot's VM."""

    vm: bvm.VM
    vehicle_type: int = V_UAV
    takeoff_altitude: float = 10.0
    log_sink: Callable[[int, str], None] | None = None
    rng: random.Random = field(default_factory=lambda: random.Random(0))
    graph_loader: Callable[[str], Table] | None = None
    sensors: Sensors | None = None
    cur_goal: tuple[float, float, float] | None = None
    commands: list[Command] = field(default_factory=list)
    robots: int = 1  # ROBOTS, after hysteresis
    _rising: int = 0
    _falling: int = 0
    _candidate: int = 1
    log_lines: list[str] = field(default_factory=list)

    # ------------------------------------------------------------ installing

    def install(self) -> None:
        """Register every closure and the constant globals (call after `vm.load`)."""
        vm = self.vm
        for name in ("log", "print", "debug"):
            vm.register(name, self._log)
        for name, func in (
            ("uav_takeoff", self._takeoff),
            ("uav_land", lambda: self._queue("land")),
            ("gohome", lambda: self._queue("rtl")),
            ("arm", lambda: self._queue("arm")),
            ("disarm", lambda: self._queue("disarm")),
            ("goto_abs", self._goto_abs),
            ("storegoal", self._storegoal),
            ("geofence", self._geofence),
            ("voronoi", self._voronoi),
            ("setgimbal", self._gimbal),
            ("takepicture", lambda: self._queue("picture")),
            ("reset_rc", self._reset_rc),
            ("export_map", lambda grid: None),
            ("add_neighborStatus", lambda t: None),
            ("add_targetrb", lambda rid, lat, lon: None),
            ("load_graph", self._load_graph),
        ):
            vm.register(name, func)
        if self.graph_loader is None:
            shapes.graph_files()  # read now: `load_graph` in a tick must open no file
        vm["V_TYPE"] = self.vehicle_type
        vm["TARGET_ALTITUDE"] = float(self.takeoff_altitude)
        vm["ROBOTS"] = self.robots

    # ------------------------------------------------------------ each tick

    def before_step(
        self, sensors: Sensors, neighbors: list[tuple[int, float, float, float]] | None
    ) -> None:
        """Push this tick's sensor tables and neighbours into the VM (before `step()`);
        neighbours None: the host has set them (`vm.set_neighbor_columns`)."""
        self.sensors = s = sensors
        if self.cur_goal is None:
            self.cur_goal = (s.lat, s.lon, s.alt)
        g = self.vm.globals
        # Buzz floats are binary32: GPS degrees lose about a metre here, as in ROSBuzz.
        # One C-level conversion rounds them all (this runs for every robot every tick).
        lat, lon, alt, north, east, yaw, volt, amps, glat, glon, galt = array(
            "f",
            (s.lat, s.lon, s.alt, s.north, s.east, s.yaw, s.voltage, s.current, *self.cur_goal),
        )
        # Fresh tables every tick, as ROSBuzz makes them; filled by item stores, a quarter
        # faster than keyword arguments (every robot of a simulated swarm, every tick).
        position = Table()
        position["latitude"] = lat
        position["longitude"] = lon
        position["altitude"] = alt
        position["x"] = north
        position["y"] = east
        orientation = Table()
        orientation["yaw"] = yaw
        g["pose"] = pose = Table()
        pose["position"] = position
        pose["orientation"] = orientation
        g["battery"] = battery = Table()
        battery["voltage"] = volt
        battery["current"] = amps
        battery["capacity"] = int(s.battery_percent)
        g["flight"] = flight = Table()
        flight["status"] = s.status
        flight["rc_cmd"] = s.rc_cmd
        if s.rc_param is not None:  # a fieldkit addition, absent unless given (compat.md)
            flight["rc_param"] = s.rc_param
        if s.rc_goto is not None:
            rid, lat, lon, alt = s.rc_goto
            g["rc_goto"] = Table(
                id=int(rid), latitude=f32(lat), longitude=f32(lon), altitude=f32(alt)
            )
        elif "rc_goto" not in g:
            g["rc_goto"] = Table(id=-1, latitude=0.0, longitude=0.0, altitude=0.0)
        g["cur_goal"] = goal = Table()
        goal["latitude"] = glat
        goal["longitude"] = glon
        goal["altitude"] = galt
        if neighbors is not None:
            self.vm.set_neighbors(neighbors)

    def after_step(self) -> list[Command]:
        """The commands the script queued this tick (in order); updates `ROBOTS`."""
        out = self.commands
        self.commands = []
        self._update_robots(self.vm.peer_count + 1)
        self.vm.globals["ROBOTS"] = self.robots
        return out

    def _update_robots(self, raw: int) -> None:
        # ROSBuzz's hysteresis (docs/rosbuzz.md#swarm-size): an increase after 2 equal readings, a
        # decrease after 150, so a few lost swarm lists do not shrink barriers.
        if raw == self.robots:
            self._rising = self._falling = 0
            return
        if raw != self._candidate:
            self._candidate, self._rising, self._falling = raw, 0, 0
        if raw > self.robots:
            self._rising += 1
            if self._rising >= 2:
                self.robots, self._rising = raw, 0
        else:
            self._falling += 1
            if self._falling >= 150:
                self.robots, self._falling = raw, 0

    # ------------------------------------------------------------ closures

    def _log(self, *args: Any) -> None:
        # The one `log` format (bvm.values.format_log), as `fieldkit run` prints it.
        text = f"[{self.vm.robot_id}] " + format_log(args)
        if self.log_sink is not None:
            self.log_sink(self.vm.robot_id, text)

    def _queue(self, kind: CommandKind, *args: float) -> None:
        self.commands.append(Command(kind, args))

    def _takeoff(self, alt: Any) -> None:
        self._queue("takeoff", _number(alt, "uav_takeoff(alt)"))

    def _here(self) -> Sensors:
        if self.sensors is None:
            raise BuzzError("no position yet: motion commands work from step() on")
        return self.sensors

    def _goto_abs(self, dx: Any, dy: Any, dh: Any, yaw: Any = 0.0) -> None:
        s = self._here()
        north = s.north + _number(dx, "goto_abs(dx)")
        east = s.east + _number(dy, "goto_abs(dy)")
        alt = s.alt + _number(dh, "goto_abs(dh)")
        _number(yaw, "goto_abs(yaw)")
        self._queue("goto", north, east, alt)

    def _set_goal(self, lat: float, lon: float, alt: float) -> bool:
        s = self._here()
        dist, _ = geo.range_bearing(s.lat, s.lon, lat, lon)
        if dist > MAX_GOAL_DISTANCE_M:
            self._log(
                f"goal too far ({dist:.0f} m > {MAX_GOAL_DISTANCE_M:.0f} m): kept the old one"
            )
            return False
        self.cur_goal = (lat, lon, alt)
        self.vm.globals["cur_goal"] = Table(
            latitude=f32(lat), longitude=f32(lon), altitude=f32(alt)
        )
        return True

    def _storegoal(self, lat: Any, lon: Any, alt: Any) -> None:
        self._set_goal(
            _number(lat, "storegoal(lat)"),
            _number(lon, "storegoal(lon)"),
            _number(alt, "storegoal(alt)"),
        )
        self._reset_rc()

    def _reset_rc(self) -> None:
        self.vm.globals["rc_goto"] = Table(id=-1, latitude=0.0, longitude=0.0, altitude=0.0)

    def _relative_goal(self, north: float, east: float) -> None:
        s = self._here()
        lat, lon = geo.offset_gps(s.lat, s.lon, north, east)
        self._set_goal(lat, lon, self.cur_goal[2] if self.cur_goal else s.alt)

    def _geofence(self, t: Any) -> None:
        if t.__class__ is not Table:
            raise BuzzError(f"type mismatch: geofence(t): expected a table, got {type_name(t)}")
        target = _point(t[0], "geofence(t)[0]")
        corners = [_point(t[k], f"geofence(t)[{k}]") for k in range(1, len(t)) if t[k] is not None]
        if len(corners) < 3:
            raise BuzzError("geofence(t): needs the target and at least 3 corners")
        if polygon.inside(target, corners):
            return
        edge = polygon.segment_exit((0.0, 0.0), target, corners)
        if edge is not None:
            self._relative_goal(*edge)

    def _voronoi(self, t: Any) -> Table | None:
        if t.__class__ is not Table:
            raise BuzzError(f"type mismatch: voronoi(t): expected a table, got {type_name(t)}")
        n = t["np"]
        if n.__class__ is not int or n < 0:
            raise BuzzError("voronoi(t): t.np must be the number of boundary vertices")
        boundary = [_point(t[k], f"voronoi(t)[{k}]") for k in range(n)]
        sites = [(0.0, 0.0)]
        k = n + 1
        while t[k] is not None:
            sites.append(_point(t[k], f"voronoi(t)[{k}]"))
            k += 1
        if len(boundary) < 3:
            return None
        # Scripts usually hand over a hull already (either way round): Qhull only if not.
        if voronoi.is_convex_ccw(boundary):
            region = boundary
        elif voronoi.is_convex_ccw(boundary[::-1]):
            region = boundary[::-1]
        else:
            region = voronoi.convex_hull(boundary)
        if len(region) < 3:
            return None
        if not voronoi.inside_hull(region, (0.0, 0.0)):
            goal = voronoi.random_point_in(region, self.rng)
            if goal is not None:  # a region of three corners or more has points
                self._relative_goal(*goal)
            return None
        cell = voronoi.hull_cell(0, sites, region)
        center = voronoi.centroid(cell) if len(cell) >= 3 else None
        if center is None:
            return None
        cx, cy = center
        self._relative_goal(cx / 2.0, cy / 2.0)  # halfway: Lloyd's step, damped as ROSBuzz
        return Table(x=f32(cx), y=f32(cy))

    def _gimbal(self, a: Any, b: Any, c: Any, d: Any) -> None:
        self._queue("gimbal", *(_number(v, "setgimbal") for v in (a, b, c, d)))

    def _load_graph(self, name: Any) -> Table:
        if name.__class__ is not str:
            raise BuzzError(
                f"type mismatch: load_graph(name): expected a string, got {type_name(name)}"
            )
        if self.graph_loader is not None:
            return self.graph_loader(name)
        try:
            return shapes.graph_table(name)
        except (OSError, ValueError) as e:
            raise BuzzError(f"load_graph({name!r}): {e}") from None
