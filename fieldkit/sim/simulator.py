"""The swarm simulator: N robots, each with its own runtime, vehicle model and radio, at 10 Hz.

There is no wall clock in the loop: a tick is 0.1 simulated seconds, and every random draw
comes from generators seeded from the run's seed, so a run is reproducible bit for bit.

Each robot is a `RobotRuntime`, the same one the field node runs (fieldkit/robot): its
tick is the node's tick. The simulator adds what a node gets from the world: the radio
model carries the bundles (radio in), the vehicle model gives the sensors and carries out
the orders (actuators), and the clock is the tick count. For speed, the neighbours of the
whole swarm are computed in one pass before the robots step.

A script error stops that robot's script and puts its vehicle in the safe state (hover, or
stop for a ground robot); the error is kept with its `file:line:col` and simulated time; the
rest of the swarm goes on, and the robot keeps broadcasting its position, as a field node does.

What the scripts log is kept in one list, `Simulation.log`, in time order (tick, then robot
id: the order the robots step in), each line `[  12.300 s] robot 4: text` (`log_line`).
"""

from __future__ import annotations

import contextlib
import gc
import logging
import math
import random
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, cast

import bvm
from fieldkit.errors import ConfigError
from fieldkit.robot import bundle as wirebundle
from fieldkit.robot import bundle_auth, geo
from fieldkit.robot import neighbors as nb
from fieldkit.robot.link_security import MODES, NONE, SIGNED, LinkSecurity
from fieldkit.robot.operator_command import ACCEPTED as COMMAND_ACCEPTED
from fieldkit.robot.operator_command import CommandGate, operator_key_id
from fieldkit.robot.profiles import Profile, load_profile
from fieldkit.robot.rc import RcCommand
from fieldkit.robot.runtime import RobotRuntime
from fieldkit.robot.safety import Order
from fieldkit.robot.script_api import ON_GROUND, Sensors
from fieldkit.sim.attacker import ATTACKS, Attacker
from fieldkit.sim.hugepages import HEAP
from fieldkit.sim.radio import LinkModel, RadioModel, Reception
from fieldkit.sim.updates import SimUpdate, SwarmUpdates
from fieldkit.update.release import Release
from fieldkit.vehicle.kinematics import Vehicle

if TYPE_CHECKING:
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

    from fieldkit.sim.recording import SimRecording

_log = logging.getLogger("fieldkit.sim")

#: The note an update frame travels with on the simulated radio (bundles carry their own).
_UPDATE_FRAME = object()

TICK_S = 0.1  # 10 Hz, ROSBuzz's BUZZRATE

#: The altitude a return to launch climbs to first, as ArduPilot's RTL_ALT default.
RTL_ALT_M = 15.0

#: Where the simulated field is (any point works; scripts see GPS around it).
DEFAULT_ORIGIN = (*geo.DEFAULT_HOME, 0.0)

#: The start grid's pitch, metres, of SimConfig (and so of the experiments).
SPACING_M = 3.0


#: On its default start grid (`default_spacing`), a robot is in radio range of about this
#: many others at most: the experiments' scale (up to 50 robots, all in range).
CROWD = 64


def in_range(robots: int, range_m: float, spacing_m: float) -> float:
    """About how many others each robot of a start grid of pitch `spacing_m` has in radio
    range: what the ticks of a large swarm cost grows with (receptions, neighbour tables)."""
    return min(robots - 1.0, math.pi * range_m**2 / spacing_m**2)


def default_spacing(robots: int, range_m: float) -> float:
    """The start grid's pitch `sim run` uses unless told: SPACING_M (3 m), or, if more than
    CROWD robots would then be in range of one another, the pitch at which each has about
    CROWD in range (a thousand robots all in range of each other cost a million receptions,
    a million neighbour entries and as many swarm lists every tick: a run crawls)."""
    if in_range(robots, range_m, SPACING_M) <= CROWD or not math.isfinite(range_m):
        return SPACING_M
    return round(range_m * math.sqrt(math.pi / CROWD), 1)


def log_line(t: float, robot: int, text: str) -> str:
    """One line of a log: simulated time (fixed width, ms) and robot id before the text."""
    return f"[{t:9.3f} s] robot {robot}: {text}"


def sim_line(t: float, text: str) -> str:
    """A line of the simulator's own (not a robot's) at simulated time t, as `log_line`."""
    return f"[{t:9.3f} s] sim: {text}"


@contextlib.contextmanager
def tuned_memory() -> Iterator[None]:
    """Garbage collection and page size tuned for stepping a swarm (what `Simulation.run`
    steps in).

    Every tick allocates thousands of short-lived tables; the default collector thresholds
    make it rescan the (large, long-lived) VMs over and over. Freeze what exists and collect
    young objects less often: 40-60% faster, same results. And back the heap with huge pages
    (hugepages.py) where it grew, and again after each young collection, which follows its
    growth.
    """
    threshold = gc.get_threshold()
    gc.freeze()
    gc.set_threshold(50_000, 20, 100)
    HEAP.follow()
    gc.callbacks.append(_heap_grown)
    try:
        yield
    finally:
        gc.set_threshold(*threshold)
        gc.unfreeze()
        if _heap_grown in gc.callbacks:
            gc.callbacks.remove(_heap_grown)


def _heap_grown(phase: str, info: dict[str, int]) -> None:
    if phase == "stop" and info["generation"] == 0:
        HEAP.back()


@contextlib.contextmanager
def collector_paused() -> Iterator[None]:
    """No garbage collection meanwhile (if it was on): building a swarm makes only objects
    that live as long as it, which every collection would scan in vain (a third to half of
    the start-up of 1,000 robots)."""
    was = gc.isenabled()
    alone = was and gc.get_freeze_count() == 0  # nobody else has objects frozen
    if alone:
        # What earlier swarms left is freed now: they went to the oldest generation
        # uncounted (below, and tuned_memory's unfreeze), so the collector's own
        # heuristics would rarely make the full collection that frees them.
        gc.collect()
    gc.disable()
    try:
        yield
    finally:
        HEAP.grown = True
        if alone:
            # The young generation now holds the whole swarm: the first allocation would
            # scan it all in vain. Straight to the oldest generation instead (freeze, then
            # unfreeze: no scan), where the next build's collection still sees it.
            gc.freeze()
            gc.unfreeze()
        if was:
            gc.enable()


class Steppable(Protocol):
    """A swarm that steps tick by tick: `Simulation`, or one split across workers."""

    tick: int

    def step(self) -> None:
        """One tick of every robot."""


def run_ticks(
    sim: Steppable,
    total: int,
    progress: Callable[[int, int], None] | None = None,
    after_step: Callable[[], None] | None = None,
    stop: threading.Event | None = None,
) -> None:
    """Step `sim` until its tick reaches `total` or `stop` is set (checked between ticks),
    with the tuned collector; `after_step()` and `progress(ticks_done, total)` after every
    tick."""
    with tuned_memory():
        while sim.tick < total and (stop is None or not stop.is_set()):
            sim.step()
            if after_step is not None:
                after_step()
            if progress is not None:
                progress(sim.tick, total)


@dataclass(frozen=True)
class StartPose:
    """Where one robot starts a run and whether it is under way: a run that begins from a
    swarm's known state (east and north in metres from the origin, altitude above it)."""

    east: float
    north: float
    alt: float = 0.0
    flying: bool = False  # a UAV hovers at `alt`; a ground robot starts armed


@dataclass
class SimConfig:
    """Everything one simulation run depends on."""

    script: Path
    robots: int
    drop: float = 0.0
    burst: float | None = None  # mean burst length in payloads: Gilbert-Elliott drops
    latency: int = 1  # ticks
    range_m: float = 500.0
    seconds: float = 60.0
    seed: int = 0
    commands: Sequence[RcCommand] = ()
    profile: str = "solo"
    include_dirs: Sequence[str] = ()
    spacing_m: float = SPACING_M  # the start grid's pitch on the ground
    origin: tuple[float, float, float] = DEFAULT_ORIGIN
    globals: dict[str, object] = field(default_factory=dict)  # set before the global code
    max_ticks_per_step: int = 1_000_000  # a runaway loop in a script stops that robot
    decode_bundles: bool = False  # parse every received bundle's bytes (slower; for tests)
    first_id: int = 1  # robot ids are first_id..first_id+robots-1 (`fieldkit run --robot-api`)
    program: bvm.Program | None = None  # already compiled (a .bo): `script` only names it
    # Robot id -> where it starts: these robots (as many as `robots`) instead of the grid
    # of ids first_id.. on the ground.
    start: Mapping[int, StartPose] | None = None
    updates: Sequence[SimUpdate] = ()  # over-the-air updates to inject (fieldkit/sim/updates.py)
    security: str = NONE  # signed: every bundle sealed under `swarm_key` (docs/security.md)
    swarm_key: bytes | None = None  # the keys' swarm.key, for `signed`
    attacks: Sequence[str] = ()  # a hostile radio in the swarm's middle (fieldkit/sim/attacker.py)
    # The operator's public key (operator.pub): robots act on radio commands it signed.
    operator_pub: Ed25519PublicKey | None = None
    # Every robot runs the update agent under these keys (swarm_key, operator_pub) even with
    # no `updates`: a ground station's gateway may bring a patch (fieldkit/ground).
    update_agents: bool = False

    def validate(self) -> None:
        """Raise ConfigError for any invalid parameter."""
        if self.robots < 1 or self.robots > 65534:
            raise ConfigError(f"--robots must be between 1 and 65534, got {self.robots}")
        if not 0.0 <= self.drop <= 1.0:
            raise ConfigError(f"--drop must be a probability in [0, 1], got {self.drop}")
        if self.burst is not None and not 1.0 <= self.burst < math.inf:
            raise ConfigError(f"--burst must be a mean of at least 1 tick, got {self.burst}")
        if self.latency < 1:
            raise ConfigError(f"--latency must be at least 1 tick, got {self.latency}")
        if not 0 < self.range_m < math.inf:
            raise ConfigError(f"--range must be > 0 metres, got {self.range_m}")
        if not 0 < self.spacing_m <= 1e5:
            raise ConfigError(f"--spacing must be > 0 metres, got {self.spacing_m}")
        if not 0 < self.seconds <= 1e6:
            raise ConfigError(f"--seconds must be > 0, got {self.seconds}")
        last = self.first_id + self.robots - 1
        if self.start is not None:
            self._validate_start(self.start)
        elif not 0 <= self.first_id <= last <= 65535:
            raise ConfigError(f"robot ids {self.first_id}..{last} are not all in 0..65535")
        ids = set(self.ids())
        for c in self.commands:
            if c.robot not in ids:
                raise ConfigError(
                    f"--command for robot {c.robot}: robots are {_id_range(self.ids())}"
                )
        for u in self.updates:
            if u.robot not in ids:
                raise ConfigError(
                    f"--update at robot {u.robot}: robots are {_id_range(self.ids())}"
                )
            if not 0 <= u.t < self.seconds:
                raise ConfigError(f"--update at {u.t} s: the run lasts {self.seconds:g} s")
        if self.security not in MODES:
            raise ConfigError(
                f"--security must be one of {', '.join(MODES)}, got {self.security!r}"
            )
        if self.security == SIGNED and self.swarm_key is None:
            raise ConfigError("--security signed needs the swarm key: give --keys DIR")
        unknown = sorted(set(self.attacks) - set(ATTACKS))
        if unknown:
            raise ConfigError(f"--attack {','.join(unknown)}: the kinds are {', '.join(ATTACKS)}")

    def _validate_start(self, start: Mapping[int, StartPose]) -> None:
        if len(start) != self.robots:
            raise ConfigError(f"start state of {len(start)} robots for a swarm of {self.robots}")
        for rid, pose in start.items():
            if not 0 <= rid <= 65535:
                raise ConfigError(f"start state: robot id {rid} is not in 0..65535")
            if not all(math.isfinite(v) for v in (pose.east, pose.north, pose.alt)):
                raise ConfigError(f"start state: robot {rid} at a position that is not finite")
            if pose.flying and pose.alt <= 0.0:
                raise ConfigError(
                    f"start state: robot {rid} flies at altitude {pose.alt} m, not above ground"
                )

    @property
    def ticks(self) -> int:
        """The run's length in ticks."""
        return round(self.seconds / TICK_S)

    def ids(self) -> list[int]:
        """The robots' ids, in the order they step: the start state's, else first_id.."""
        if self.start is not None:
            return sorted(self.start)
        return list(range(self.first_id, self.first_id + self.robots))


def start_grid(config: SimConfig) -> dict[int, tuple[float, float]]:
    """Where each robot of a run without a start state begins (east, north): a square grid
    of `spacing_m`, each spot jittered by up to 0.2 m, drawn from the run's seed."""
    rng = random.Random(f"layout:{config.seed}")
    side = max(1, math.ceil(math.sqrt(config.robots)))
    out = {}
    for k, rid in enumerate(config.ids()):
        x = (k % side) * config.spacing_m + rng.uniform(-0.2, 0.2)
        y = (k // side) * config.spacing_m + rng.uniform(-0.2, 0.2)
        out[rid] = (x, y)
    return out


def _id_range(ids: list[int]) -> str:
    """`1..5` for consecutive ids, else the list: how an error names the robots."""
    if ids == list(range(ids[0], ids[0] + len(ids))):
        return f"{ids[0]}..{ids[-1]}"
    return ", ".join(map(str, ids))


class RadioPeer(Protocol):
    """A radio beside the simulated swarm (`Simulation.peers`): a ground station."""

    def overhear(self, t: int, sender: int, data: bytes, where: tuple[float, float, float]) -> None:
        """A frame robot `sender` sent from `where` at tick `t`."""

    def transmissions(self, t: int) -> list[tuple[bytes, list[int]]]:
        """The frames it sends at tick `t`, each with the robots that hear it."""
        ...


class SimRobot:
    """One simulated robot: its runtime (script, supervisor, heard table) and its vehicle."""

    __slots__ = ("id", "runtime", "vehicle", "home", "sensors")

    def __init__(self, rid: int, runtime: RobotRuntime, vehicle: Vehicle) -> None:
        self.id = rid
        self.runtime = runtime
        self.vehicle = vehicle
        self.home = (vehicle.x, vehicle.y)
        self.sensors = Sensors(lat=0.0, lon=0.0, alt=0.0, north=0.0, east=0.0)  # this tick's

    @property
    def vm(self) -> bvm.VM:
        """The robot's Buzz VM."""
        return self.runtime.vm

    @property
    def error(self) -> str | None:
        """The script error that stopped this robot, if any."""
        return self.runtime.error

    @property
    def state(self) -> str | None:
        """The script's BVMSTATE after its last step."""
        return self.runtime.state

    @property
    def in_failsafe(self) -> bool:
        """Whether a script error stopped the script and nothing restarted it: the robot is
        in its failsafe. (An error a restart recovered leaves `error` set, this False.)"""
        return self.runtime.error is not None and not self.runtime.running


class BundleTally:
    """The bundles a swarm sent: the largest and total Buzz content (ROSBuzz's 190-byte
    quantity), the bytes on the air (trailers included) and how many."""

    def __init__(self) -> None:
        self.max_bundle = 0
        self.total_bundle = 0
        self.air_bytes = 0
        self.bundles = 0

    def tally(self, data: bytes, messages: tuple[bytes, ...]) -> None:
        """Count one bundle: its bytes on the air and the messages it holds."""
        size = wirebundle.block_size(messages)
        if size > self.max_bundle:
            self.max_bundle = size
        self.total_bundle += size
        self.bundles += 1
        self.air_bytes += len(data)

    def bundle_figures(self) -> dict[str, object]:
        """`max_bundle_bytes`, `mean_bundle_bytes`, `mean_bundle_air_bytes` of summary.json."""
        n = self.bundles
        return {
            "max_bundle_bytes": self.max_bundle,
            "mean_bundle_bytes": round(self.total_bundle / n, 3) if n else 0,
            "mean_bundle_air_bytes": round(self.air_bytes / n, 3) if n else 0,
        }


class Simulation(BundleTally):
    """A seeded, tick-driven swarm simulation of one script on N robots."""

    def __init__(self, config: SimConfig, *, on_log: Callable[[str], None] | None = None) -> None:
        """`on_log`, if given, sees every log line as it is made (see `log_line`)."""
        config.validate()
        self.config = config
        try:
            self.profile: Profile = load_profile(config.profile)
        except (OSError, ValueError) as e:
            raise ConfigError(f"--profile {config.profile!r}: {e}") from None
        self.program = config.program or bvm.compile_file(
            config.script, include_dirs=tuple(config.include_dirs)
        )
        self.frame = geo.LocalFrame(*config.origin)
        self.radio = RadioModel(self._link_model(config), seed=config.seed)
        self.tick = 0
        self.on_log = on_log
        self.log: list[str] = []  # every robot's log lines, in time order
        #: `record(DIR)`: every robot's flight into a bag (fieldkit/sim/recording.py). Set
        #: before any robot starts: a script logs from its global code on.
        self.recording: SimRecording | None = None
        # Script errors as they happened: robot, simulated time, the error.
        self.errors: list[dict[str, object]] = []
        self._failed: set[int] = set()  # robots whose error is in `errors`
        BundleTally.__init__(self)
        self._commands: dict[int, list[RcCommand]] = {}
        for c in config.commands:
            self._commands.setdefault(round(c.t / TICK_S), []).append(c)
        self.robots: dict[int, SimRobot] = {}
        agent_keys = None
        if config.update_agents and not config.updates and config.swarm_key is not None:
            from fieldkit.update.keys import RobotKeys

            if config.operator_pub is not None:
                agent_keys = RobotKeys(config.operator_pub, config.swarm_key)
        self.updates = (
            SwarmUpdates(
                list(config.updates),
                Release.from_program(self.program),
                seed=config.seed,
                tick_s=TICK_S,
                keys=agent_keys,
            )
            if config.updates or agent_keys is not None
            else None
        )
        # Each robot's radio-in, bound once: a tick delivers thousands of bundles.
        self._hear: dict[int, Callable[[int, nb.Heard, tuple[bytes, ...]], None]] = {}
        self._heard: dict[int, nb.HeardTable] = {}
        # signed: each robot's replay window, fed every bundle it hears (see `step`).
        self._admit: dict[int, Callable[[int, int], bool]] = {}
        pub = config.operator_pub
        key = None
        if config.security == SIGNED and config.swarm_key is not None:
            key = bundle_auth.bundle_key(config.swarm_key)
        #: Hostile frames the robots accepted (a bundle decoded, a command acted on).
        self.accepted_from_attacker = 0
        grid = start_grid(config) if config.start is None else {}
        # Every object made here lives as long as the swarm: no collection meanwhile.
        with collector_paused():
            for rid in config.ids():
                pose = None if config.start is None else config.start[rid]
                if pose is None:
                    x, y = grid[rid]
                    vehicle = Vehicle.from_profile(self.profile, x=x, y=y)
                else:
                    vehicle = Vehicle.from_profile(self.profile, x=pose.east, y=pose.north)
                    if pose.flying:
                        vehicle.start_flying(pose.alt)
                security = (
                    None
                    if key is None
                    # A simulated robot never reboots: its counters need no file.
                    else LinkSecurity.signed_with(rid, key, bundle_auth.MemoryCounter())
                )
                runtime = RobotRuntime(
                    rid,
                    self.profile,
                    self.frame,
                    seed=config.seed,
                    log_sink=self._sink(rid),
                    max_ticks=config.max_ticks_per_step,
                    security=security,
                    commands=None if pub is None else CommandGate(rid, pub),
                )
                robot = SimRobot(rid, runtime, vehicle)
                self.robots[rid] = robot
                self._hear[rid] = runtime.hear
                self._heard[rid] = runtime.heard
                if security is not None:
                    self._admit[rid] = security.admit
                if not runtime.start(self.program, self._sensors(robot), config.globals):
                    self._note_error(robot)
                if self.updates is not None:
                    self.updates.attach(runtime, self._sink(rid))
        self.attacker = self._attacker(config) if config.attacks else None
        #: Radios beside the swarm (a ground station, a UDP gateway: fieldkit/ground): each
        #: `overhear(t, sender, data, position)`s every frame sent and says what it sends at
        #: tick t, and to which robots, with `transmissions(t)`.
        self.peers: list[RadioPeer] = []

    def _attacker(self, config: SimConfig) -> Attacker:
        """The hostile radio, at the middle of the swarm's start positions."""
        robots = list(self.robots.values())
        pub = config.operator_pub
        middle = (
            sum(r.vehicle.x for r in robots) / len(robots),
            sum(r.vehicle.y for r in robots) / len(robots),
            2.0,
        )
        taken = set(self.robots)
        radio_id = next(i for i in range(65535, -1, -1) if i not in taken)
        return Attacker(
            config.attacks,
            seed=config.seed,
            link=self.radio.model,
            position=middle,
            radio_id=radio_id,
            robot_ids=sorted(taken),
            origin=(self.frame.lat, self.frame.lon),
            operator_key_id=None if pub is None else operator_key_id(pub),
        )

    @staticmethod
    def _link_model(config: SimConfig) -> LinkModel:
        if config.burst is None or config.drop == 0.0:
            return LinkModel(range_m=config.range_m, drop=config.drop, latency=config.latency)
        try:
            return LinkModel.bursty(
                config.drop, config.burst, range_m=config.range_m, latency=config.latency
            )
        except ValueError as e:
            raise ConfigError(f"--drop {config.drop} with --burst {config.burst}: {e}") from None

    def _sink(self, rid: int) -> Callable[[str], None]:
        """Robot `rid`'s log: one list for the swarm, each line stamped when it is made."""

        prefix = f"[{rid}] "  # the script API's own robot tag: the line names the robot

        def sink(text: str) -> None:
            if text.startswith(prefix):
                text = text[len(prefix) :]
            if self.recording is not None:
                self.recording.log(rid, text)
            line = log_line(self.tick * TICK_S, rid, text)
            self.log.append(line)
            if self.on_log is not None:
                self.on_log(line)

        return sink

    def _note_error(self, robot: SimRobot) -> None:
        """Keep a robot's new script error, with when it happened, and log it."""
        self._failed.add(robot.id)
        error = robot.error
        self.errors.append({"robot": robot.id, "t_s": round(self.tick * TICK_S, 6), "error": error})
        self._sink(robot.id)(f"script error, robot to its safe state: {error}")

    # ------------------------------------------------------------ one tick

    def _sensors(self, robot: SimRobot) -> Sensors:
        """The robot's sensors this tick, in the one Sensors it keeps (rewritten each tick:
        nobody holds on to last tick's, and a swarm would otherwise make one per robot)."""
        v = robot.vehicle
        s = robot.sensors
        s.lat, s.lon = geo.offset_gps(self.frame.lat, self.frame.lon, v.y, v.x)
        s.alt = v.z
        s.north = v.y
        s.east = v.x
        s.yaw = v.yaw
        s.voltage = v.voltage
        s.battery_percent = v.battery_percent
        s.status = v.status
        s.armed = v.armed
        return s

    def _radio_in(self, t: int, receptions: Sequence[Reception]) -> None:
        """The broadcasts due at tick t into their receivers: positions to the heard tables,
        messages to the VMs (a swarm split across processes feeds each part its own)."""
        robots = self.robots
        rec = self.recording
        reparse = self.config.decode_bundles
        for sender, data, pos, receivers, sent in receptions:
            if rec is not None:
                where = None if sent is _UPDATE_FRAME else (pos[0], pos[1])
                rec.heard(sender, data, where, receivers)
            if sent is _UPDATE_FRAME:
                self._receive_update(data, receivers)
                continue
            if reparse or sent is None:
                for receiver in receivers:
                    robot = robots.get(receiver)
                    if robot is not None:
                        robot.runtime.receive_bundle(data, (pos[0], pos[1]))
                continue
            src, messages, counter = cast(tuple[int, tuple[bytes, ...], int], sent)  # _send's
            # Where the sender was when it sent (its position in the shared local frame,
            # which is its bundle's GPS); one entry shared by every receiver: never modified.
            entry = (pos[0], pos[1], t)
            if counter:
                # Sealed: the simulator made the tag with the key every robot holds, so it
                # would check out; each receiver's replay window still sees the counter.
                receivers = [r for r in receivers if self._admit[r](src, counter)]
            if messages:
                for receiver in receivers:
                    hear = self._hear.get(receiver)
                    if hear is not None:
                        hear(src, entry, messages)
            else:
                # Most bundles carry no message: only the position goes to the heard table
                # (the runtime's fast path for a host delivering a swarm's bundles).
                for receiver in receivers:
                    heard = self._heard.get(receiver)
                    if heard is not None:
                        heard[src] = entry

    def step(self) -> None:
        """Advance every robot by one tick."""
        t = self.tick
        robots = self.robots
        rec = self.recording
        if rec is not None:
            rec.begin(t, t * TICK_S)
        # 1. radio in
        self._radio_in(t, self.radio.receptions(t))
        if self.attacker is not None:
            self._hostile_in(t)
        if self.peers:
            self._peers_in(t)
        rcs: dict[int, RcCommand] = {c.robot: c for c in self._commands.get(t, ())}
        positions = {r.id: r.vehicle.position for r in robots.values()}
        self.radio.set_positions(positions)
        if self.attacker is not None:
            self.attacker.transmit(t, positions)
        # A robot's own vehicle moves only in its turn, after it stepped: so every robot's
        # neighbours can be computed now, for the whole swarm at once.
        neighbors = self._neighbors(t)
        if self.updates is not None:
            self._step_updating(t, rcs, neighbors)
            return
        self._step_robots(t, rcs, neighbors)
        self.tick += 1

    def _step_robots(
        self, t: int, rcs: dict[int, RcCommand], neighbors: dict[int, nb.Columns]
    ) -> None:
        """2.-5. for every robot in id order: sensors, step, radio out, actuators."""
        rec = self.recording
        for robot in self.robots.values():
            # 2.-5. sensors, step, radio out, actuators: the robot's own tick
            runtime = robot.runtime
            out = runtime.tick(self._sensors(robot), rcs.get(robot.id), neighbors.get(robot.id))
            if runtime.error is not None and robot.id not in self._failed:
                self._note_error(robot)
            self._send(robot, out.bundle, out.messages)
            if runtime.relays:
                for relay in runtime.take_relays():  # operator commands, passed on once
                    self._relay(t, robot.id, relay)
            if out.order is not None:
                self._actuate(robot, out.order)
            robot.vehicle.step(TICK_S)
            if rec is not None:
                rec.end(robot.id, self)

    def _step_updating(
        self, t: int, rcs: dict[int, RcCommand], neighbors: dict[int, nb.Columns]
    ) -> None:
        """The robots' ticks when updates run: the same phases, with the update agent's
        decision before the step and its frame after it (fieldkit/update/host.py)."""
        updates = self.updates
        assert updates is not None
        for line in updates.inject_due(t):
            self._log_line(t, line)
        for robot in self.robots.values():
            runtime = robot.runtime
            updater = updates.updaters[robot.id]
            sensors = self._sensors(robot)
            updater.before_step(sensors)
            if runtime.error is None:
                self._failed.discard(robot.id)  # a new version started: it may fail anew
            out = runtime.tick(sensors, rcs.get(robot.id), neighbors.get(robot.id))
            if runtime.error is not None and robot.id not in self._failed:
                self._note_error(robot)
            self._send(robot, out.bundle, out.messages)
            if runtime.relays:
                for relay in runtime.take_relays():  # operator commands, passed on once
                    self._relay(t, robot.id, relay)
            frame = updater.after_step()
            if frame is not None:
                room = self.radio.room(t, robot.id)
                if room is None or len(frame) <= room:
                    self.radio.broadcast(t, robot.id, frame, note=_UPDATE_FRAME)
                    if self.attacker is not None:
                        self.attacker.record(t, frame, robot.vehicle.position)
                    for peer in self.peers:
                        peer.overhear(t, robot.id, frame, robot.vehicle.position)
                    if self.recording is not None:
                        self.recording.sent(robot.id, frame)
            if out.order is not None:
                self._actuate(robot, out.order)
            robot.vehicle.step(TICK_S)
            if self.recording is not None:
                self.recording.end(robot.id, self)
        updates.after_tick(t)
        self.tick += 1

    def _relay(self, t: int, rid: int, frame: bytes) -> None:
        """An operator command frame robot `rid` passes on."""
        self.radio.broadcast(t, rid, frame)
        if self.recording is not None:
            self.recording.sent(rid, frame)
        for peer in self.peers:
            peer.overhear(t, rid, frame, self.robots[rid].vehicle.position)

    def record(self, out: Path, *, ros1: bool = False) -> list[Path]:
        """Record every robot's flight from now on, one bag each in `out` (ROS 2 with MCAP,
        or `ros1` bags; BagError if one exists already); the bags' paths. Call before `run`;
        `close_recording` after."""
        from fieldkit.sim.recording import SimRecording

        self.recording = SimRecording(self, out, ros1=ros1)
        return list(self.recording.paths)

    def close_recording(self) -> None:
        """Finish the bags `record` opened."""
        if self.recording is not None:
            self.recording.close()

    def _hostile_in(self, t: int) -> None:
        """The attacker's frames due now, through each receiver's whole radio-in path (an
        update frame to its update agent, as on a node); counts, by attack kind, those a
        robot accepted: a bundle past its checks, a command acted on."""
        assert self.attacker is not None
        robots = self.robots
        updaters = self.updates.updaters if self.updates is not None else {}
        accepted = self.attacker.accepted
        for _sender, data, _pos, receivers, kind in self.attacker.radio.receptions(t):
            if self.recording is not None:
                self.recording.heard(self.attacker.id, data, None, receivers)
            for receiver in receivers:
                robot = robots.get(receiver)
                if robot is None:
                    continue
                updater = updaters.get(receiver)
                if updater is not None and updater.receive(data):
                    continue  # the update's own rules make a replayed frame harmless
                runtime = robot.runtime
                # Accepted: past the verifier (signed) or decoded and heard (none), or a
                # command acted on.
                counters = (
                    runtime.counters if runtime.security is None else runtime.security.counters
                )
                key = "bundles_heard" if runtime.security is None else bundle_auth.ACCEPTED
                gate = runtime.commands
                before = counters[key] + (0 if gate is None else gate.counters[COMMAND_ACCEPTED])
                runtime.receive_bundle(data)
                after = counters[key] + (0 if gate is None else gate.counters[COMMAND_ACCEPTED])
                if after > before:
                    accepted[cast(str, kind)] += after - before
                    self.accepted_from_attacker += after - before

    def _peers_in(self, t: int) -> None:
        """The peers' frames due now, through each receiver's whole radio-in path."""
        robots = self.robots
        updaters = self.updates.updaters if self.updates is not None else {}
        for peer in self.peers:
            for data, receivers in peer.transmissions(t):
                for receiver in receivers:
                    robot = robots.get(receiver)
                    if robot is None:
                        continue
                    updater = updaters.get(receiver)
                    if updater is not None and updater.receive(data):
                        continue
                    robot.runtime.receive_bundle(data)

    def _receive_update(self, data: bytes, receivers: Sequence[int]) -> None:
        updaters = self.updates.updaters if self.updates is not None else {}
        for receiver in receivers:
            updater = updaters.get(receiver)
            if updater is not None:
                updater.receive(data)

    def _log_line(self, t: int, text: str) -> None:
        """A line of the simulator's own (not a robot's) in the run's log."""
        line = sim_line(t * TICK_S, text)
        self.log.append(line)
        if self.on_log is not None:
            self.on_log(line)

    def _neighbors(self, t: int) -> dict[int, nb.Columns]:
        """Each running robot's neighbours at tick t, for the whole swarm in one pass: from
        where the robot is to where each sender was when it sent."""
        owners = [r for r in self.robots.values() if r.runtime.running]
        columns = nb.columns(
            [r.runtime.heard for r in owners],
            [(r.vehicle.x, r.vehicle.y) for r in owners],
            t,
            round(nb.NEIGHBOR_TIMEOUT_S / TICK_S),
        )
        return {r.id: c for r, c in zip(owners, columns, strict=True)}

    def _send(self, robot: SimRobot, data: bytes, messages: tuple[bytes, ...]) -> None:
        self.tally(data, messages)
        # The real bytes travel (and are counted); the note of what they hold spares the
        # receivers parsing them again.
        security = robot.runtime.security
        counter = 0 if security is None else security.last_counter
        self.radio.broadcast(self.tick, robot.id, data, note=(robot.id, messages, counter))
        if self.recording is not None:
            self.recording.sent(robot.id, data)
        if self.attacker is not None:
            self.attacker.record(self.tick, data, robot.vehicle.position)
        for peer in self.peers:
            peer.overhear(self.tick, robot.id, data, robot.vehicle.position)

    @staticmethod
    def _actuate(robot: SimRobot, order: Order) -> None:
        """The supervisor's order to the simulated vehicle."""
        v = robot.vehicle
        kind = order.kind
        if kind == "goto":
            north, east, alt = order.args
            v.goto(east, north, alt)
        elif kind == "takeoff":
            if not v.armed:
                v.arm()
            v.takeoff(order.args[0])
        elif kind == "land":
            v.land()
        elif kind == "arm":
            v.arm()
        elif kind == "disarm":
            v.disarm()
        elif kind == "rtl":
            # As the autopilot's RTL mode does (the node sends a mode change).
            v.return_home(robot.home[0], robot.home[1], RTL_ALT_M)
        else:  # hold
            v.hold()

    # ------------------------------------------------------------ running

    def run(
        self,
        progress: Callable[[int, int], None] | None = None,
        after_step: Callable[[], None] | None = None,
        stop: threading.Event | None = None,
    ) -> None:
        """Run the configured number of simulated seconds, or until `stop` is set;
        `after_step()` (a recorder) and `progress(ticks_done, ticks_total)` are called after
        every tick."""
        run_ticks(self, self.config.ticks, progress, after_step, stop)

    def kill(self, rid: int) -> SimRobot:
        """Take robot `rid` out of the swarm between two ticks, as a hardware loss or a flat
        battery would: it neither steps nor sends again, and nobody hears it any more (bundles
        already in flight to it are dropped on arrival). Returns the dead robot (KeyError if
        there is no such robot alive)."""
        robot = self.robots.pop(rid)
        self._hear.pop(rid, None)
        self._heard.pop(rid, None)
        # Its replay window (signed runs) stays: deliveries already in flight still pass it.
        self._log_line(self.tick, f"robot {rid} killed")
        return robot

    def in_failsafe(self) -> list[int]:
        """The robots a script error left in their failsafe (stopped, not restarted), by id."""
        return [r.id for r in self.robots.values() if r.in_failsafe]

    def summary(self) -> dict[str, object]:
        """The run's figures, as `summary.json` holds them."""
        return (
            {
                "robots": self.config.robots,
                "drop": self.config.drop,
                "seed": self.config.seed,
                "seconds_simulated": round(self.tick * TICK_S, 6),
                **self.bundle_figures(),
                "final_states": {str(r.id): r.state for r in self.robots.values()},
                # Every script error, in time order; those not recovered left their robot in
                # its failsafe, listed in `in_failsafe`.
                "errors": list(self.errors),
                "in_failsafe": self.in_failsafe(),
            }
            | self.update_summary()
            | self.security_summary()
        )

    def security_summary(self) -> dict[str, object]:
        """`security`: the mode, what the robots dropped (per reason, every reception
        counted), and with an attacker what it sent and how much of it was accepted."""
        rejected: dict[str, int] = {}
        accepted = 0
        mixed: set[int] = set()
        for r in self.robots.values():
            security = r.runtime.security
            if security is None:
                continue
            for reason, n in security.rejected().items():
                rejected[reason] = rejected.get(reason, 0) + n
            accepted += security.counters[bundle_auth.ACCEPTED]
            mixed.update(security.mixed)
        out: dict[str, object] = {
            "mode": self.config.security,
            # Bundles past the checks (a plain swarm checks nothing, so counts nothing).
            "accepted": accepted if self.config.security == SIGNED else None,
            "rejected": dict(sorted(rejected.items())),
            "mixed": sorted(mixed),
        }
        gates = [r.runtime.commands for r in self.robots.values() if r.runtime.commands]
        if gates:
            # Operator commands heard on the radio: what the robots' gates made of them.
            totals: dict[str, int] = {}
            for gate in gates:
                for outcome, n in gate.counters.items():
                    totals[outcome] = totals.get(outcome, 0) + n
            out["commands"] = dict(sorted(totals.items()))
        if self.attacker is not None:
            bad = sum(r.runtime.counters["bundle_errors"] for r in self.robots.values())
            if bad:
                out["rejected"] = dict(sorted({**rejected, "undecodable": bad}.items()))
            out["attacker"] = self.attacker.summary()
            out["accepted_from_attacker"] = self.accepted_from_attacker
            # Frames the attacker made up (not recorded ones re-sent): never accepted.
            out["forgeries_accepted"] = sum(
                n for kind, n in self.attacker.accepted.items() if kind != "replay"
            )
        return {"security": out}

    def update_summary(self) -> dict[str, object]:
        """`script_versions` (robot id to the hex SHA-256 of the bytecode it runs) and
        `update` (what became of the last injected update; None without one)."""
        if self.updates is None:
            launch = Release(self.program.bytecode).hash
            return {"script_versions": {str(r): launch for r in self.robots}, "update": None}
        records = self.updates.records
        sent = self.updates.bytes_sent()
        out: dict[str, object] = {
            "script_versions": self.updates.versions(),
            "update": records[-1].summary(sent) if records else None,
        }
        if len(records) > 1:
            out["updates"] = [r.summary(sent) for r in records]
        return out


__all__ = [
    "ConfigError",
    "RcCommand",
    "SimConfig",
    "Simulation",
    "StartPose",
    "TICK_S",
    "ON_GROUND",
    "SPACING_M",
    "CROWD",
    "default_spacing",
    "in_range",
    "log_line",
    "sim_line",
    "start_grid",
    "tuned_memory",
    "run_ticks",
    "BundleTally",
    "Steppable",
]
