"""What one robot does each tick, wherever it runs: the simulator, the field node and SITL.

A `RobotRuntime` owns the robot's Buzz VM, its script API, its safety supervisor and the
table of robots it hears. The host (a simulator, a field node) owns the rest: the vehicle,
the radio and the clock. Each tick the data flows one way, and only here:

    radio in    `hear` / `receive_bundle`: Buzz messages to the VM, senders' positions to
                the heard table (any time between two ticks)
    sensors     the host fills a `Sensors` from its vehicle and calls `tick`
    step        process_inbox(), neighbours, the script's globals, step()
    radio out   drain_outbox() within the bundle budget, encoded as one ROSBuzz bundle,
                sealed if the robot's `security` is signed
    actuators   the script's commands through the supervisor: at most one `Order`

`tick` returns the bundle to broadcast and the order for the vehicle; the host sends the
one and carries out the other. A script error stops the script and puts the robot in the
profile's safe state; the runtime goes on (neighbours, bundles with its position, the
supervisor), so the robot stays visible and controllable.

Time is the robot's own tick count: neighbour timeouts and the supervisor count ticks, so
a recorded flight replays the same way. Two hooks serve what is built on the tick: `start`
may be called again to switch to another program (an over-the-air update), keeping the
heard table and the supervisor, and `observer`, if set, sees every tick's `TickRecord`.
"""

from __future__ import annotations

import logging
import random
from collections import Counter
from collections.abc import Callable, Mapping
from enum import Enum
from typing import NamedTuple, cast

import bvm
from bvm.errors import BuzzError
from fieldkit.robot import bundle as wirebundle
from fieldkit.robot import geo
from fieldkit.robot import neighbors as nb
from fieldkit.robot.bundle_auth import CounterError
from fieldkit.robot.link_security import LinkSecurity
from fieldkit.robot.operator_command import CommandGate, SeqFileError, is_command
from fieldkit.robot.profiles import Profile
from fieldkit.robot.rc import RcCommand
from fieldkit.robot.safety import Order, Supervisor
from fieldkit.robot.script_api import V_GROUND, V_UAV, Command, ScriptAPI, Sensors
from fieldkit.robot.status import StatusGossip, StatusRecord, is_status, status_key

_log = logging.getLogger("fieldkit.robot")

#: A repeated supervisor event (a ground robot's script asking to take off every tick) is
#: logged the first time and then once every this many times.
EVENT_LOG_EVERY = 100


class ScriptStatus(Enum):
    """Where the robot's script is: not loaded yet, stepping, or stopped by an error."""

    IDLE = "idle"
    RUNNING = "running"
    STANDBY = "standby"  # loaded, not stepped: an update's barrier holds the robot
    FAILED = "failed"


# Module-level: read every tick by every robot of a swarm.
_RUNNING = ScriptStatus.RUNNING


class TickOutput(NamedTuple):
    """What a tick hands back to its host: a bundle to broadcast and an order to carry out."""

    bundle: bytes
    messages: tuple[bytes, ...]  # the Buzz messages inside `bundle`
    order: Order | None


# A NamedTuple's own constructor is a Python-level call (0.6 us against 0.13 us for this),
# and every robot of a simulated swarm makes one output a tick.
_new_output = cast(
    "Callable[[type[TickOutput], tuple[bytes, tuple[bytes, ...], Order | None]], TickOutput]",
    tuple.__new__,
)


class TickRecord(NamedTuple):
    """One tick as an observer (a recorder) sees it, after the tick ran."""

    tick: int
    sensors: Sensors  # the host's object: copy what must outlive the call
    commands: list[Command]
    order: Order | None
    state: str | None
    events: list[str]


class RobotRuntime:
    """One robot's script, supervisor and heard table, driven one tick at a time."""

    def __init__(
        self,
        robot_id: int,
        profile: Profile,
        frame: geo.LocalFrame,
        *,
        seed: int = 0,
        log_sink: Callable[[str], None] | None = None,
        max_ticks: int | None = None,
        max_seconds: float | None = None,
        graph_loader: Callable[[str], bvm.Table] | None = None,
        translate_ahead: bool = False,
        security: LinkSecurity | None = None,
        commands: CommandGate | None = None,
    ) -> None:
        """`seed` seeds the VM's and the script API's generators (each robot its own);
        `max_ticks` / `max_seconds` bound one step of a runaway script (instructions, for
        a reproducible simulator; wall time, for a node that must keep its loop);
        `translate_ahead` translates the whole script at start (`bvm.VM.prepare`), so that
        no tick compiles: a node's choice (its ticks have deadlines), not the simulator's
        (translations specialized on first calls run a big swarm faster); `security` seals
        the bundles sent and checks those heard (None: plain bytes, as `none` without its
        counters); `commands` checks the operator's signed commands heard on the radio (None:
        such frames are counted and ignored: without operator.pub none can be trusted)."""
        self.id = robot_id
        self.profile = profile
        self.frame = frame
        self.seed = seed
        self.log_sink = log_sink
        self.max_ticks = max_ticks
        self.max_seconds = max_seconds
        self.graph_loader = graph_loader
        self.translate_ahead = translate_ahead
        self.security = security
        self.commands = commands
        #: Operator commands accepted off the radio, run one a tick before any local one.
        self.pending_rc: list[RcCommand] = []
        #: Frames to send besides the bundle (`take_relays`): command frames passed on
        #: unchanged, each valid one once, and this robot's status frames.
        self.relays: list[bytes] = []
        # Status frames (docs/ground.md): silent until a ground station is heard. Sealed
        # under a key derived from the bundle key in a signed swarm.
        sealer = None if security is None else security.sealer
        self.status_gossip = StatusGossip(
            robot_id, None if sealer is None else status_key(sealer.key.secret)
        )
        self.supervisor = Supervisor(profile, frame)
        self.heard: nb.HeardTable = {}
        self.timeout = nb.timeout_ticks(profile.node.loop_rate_hz)
        # The Buzz bytes a bundle may carry: the profile's budget (header included, as
        # ROSBuzz counts its 190 bytes), never more than a bundle holds.
        # A sealed bundle gives one word to its trailer (docs/security.md#the-byte-budget).
        limit = wirebundle.MAX_MSG_SIZE if security is None else security.max_content
        budget = min(profile.radio.per_step_budget_bytes, limit)
        self.budget = budget - wirebundle.BUNDLE_HEADER
        self.ticks = 0
        self.status = ScriptStatus.IDLE
        self.error: str | None = None
        self.state: str | None = None  # the script's BVMSTATE after its last step
        # host-side: bundle_errors, own_echoes, bundles_heard, unsent_bundles
        self.counters: Counter[str] = Counter()
        self.event_counts: Counter[str] = Counter()
        self.observer: Callable[[TickRecord], None] | None = None
        self.globals: dict[str, object] = {}  # the operator's values, set again at a switch
        self.vm, self.api = self._new_vm()

    def _new_vm(self) -> tuple[bvm.VM, ScriptAPI]:
        rid = self.id
        vm = bvm.VM(robot_id=rid, rng_seed=self.seed * 65536 + rid)
        if self.max_ticks is not None:
            vm.max_ticks = self.max_ticks
        if self.max_seconds is not None:
            vm.max_seconds = self.max_seconds
        sink = self.log_sink
        api = ScriptAPI(
            vm,
            vehicle_type=V_GROUND if self.profile.is_ground else V_UAV,
            takeoff_altitude=self.profile.kinematics.takeoff_altitude_m,
            log_sink=None if sink is None else lambda _rid, text: sink(text),
            rng=random.Random(f"api:{self.seed}:{rid}"),
            graph_loader=self.graph_loader,
        )
        return vm, api

    # ------------------------------------------------------------ start

    @property
    def running(self) -> bool:
        """Whether the script is stepping (loaded and not stopped by an error)."""
        return self.status is _RUNNING

    def start(
        self,
        program: bvm.Program,
        sensors: Sensors,
        globals_: Mapping[str, object] | None = None,
    ) -> bool:
        """Load `program` in a fresh VM, run its global code and `init()`; False (and the
        robot in its safe state) if that fails. `globals_` are set before the global code
        and again after it, before `init()`.
        Called again, it switches the robot to another program: the heard table, the
        supervisor and the tick count carry over."""
        if self.status is not ScriptStatus.IDLE:
            self.vm, self.api = self._new_vm()
        self.status = ScriptStatus.RUNNING
        self.state = None
        if self.error is not None:
            self.supervisor.script_restarted()
        self.error = None
        self.supervisor.resume()
        if globals_ is not None:
            self.globals = dict(globals_)
        vm = self.vm
        try:
            vm.load(program)
            self.api.install()
            given = self.globals
            for name, value in given.items():
                vm[name] = value
            self.api.before_step(sensors, [])
            vm.execute()
            # Again after the global code: a value the operator set (`--set`) wins over the
            # script's own default, whether it reads `if (isnil(X))` or assigns X outright.
            for name, value in given.items():
                vm[name] = value
            if vm.gload("init") is not None:
                vm.call("init")
            if self.translate_ahead:
                vm.prepare()
        except BuzzError as e:
            self.fail(e)
        return self.running

    def stand_by(self, reason: str) -> None:
        """Stop stepping the script (it stays loaded) and hold the robot still, until
        `resume` or a `start` of another program; bundles with the position go on."""
        if self.status is _RUNNING:
            self.status = ScriptStatus.STANDBY
            self.supervisor.stand_by(reason)

    def resume(self) -> None:
        """Step the script again after `stand_by`."""
        if self.status is ScriptStatus.STANDBY:
            self.status = _RUNNING
            self.supervisor.resume()

    def destroy(self) -> None:
        """The robot is stopping: run the script's `destroy()`, if it has one and runs."""
        if self.status is _RUNNING and self.vm.gload("destroy") is not None:
            try:
                self.vm.call("destroy")
            except BuzzError as e:
                self.fail(e)
        self.status = ScriptStatus.IDLE if self.error is None else ScriptStatus.FAILED

    def fail(self, e: BuzzError | str) -> None:
        """Stop the script: keep the error, put the robot in the profile's safe state."""
        text = str(e)
        self.status = ScriptStatus.FAILED
        self.error = text
        self.supervisor.script_error(text)
        _log.error("robot %d: script error, robot to its safe state: %s", self.id, text)

    # ------------------------------------------------------------ radio in

    def hear(self, sender: int, where: nb.Heard, messages: tuple[bytes, ...]) -> None:
        """A bundle from `sender`, sent from `where` (east, north, tick): its position to the
        heard table, its Buzz messages to the VM's in-queue. (A host delivering a whole
        swarm's bundles, the simulator, may store a message-less bundle's position into
        `heard` itself: that is all this would do with it.)"""
        self.heard[sender] = where
        if messages and self.status is _RUNNING:
            receive = self.vm.receive
            for payload in messages:
                receive(sender, payload)

    def receive_bundle(self, data: bytes, where: tuple[float, float] | None = None) -> None:
        """A bundle's bytes off the radio; the sender's position is the bundle's GPS unless
        the host knows better (`where`: east, north). A bad bundle costs a counter; with
        `security`, nothing it drops (unsigned, forged, replayed) is decoded at all.
        An operator's command frame (type 17) goes to the command gate instead, a status
        frame (type 18) to the status table."""
        if is_status(data):
            self.status_gossip.receive(data, self.ticks)
            return
        if is_command(data):
            self._operator_command(data)
            return
        security = self.security
        if security is not None:
            opened = security.open(data)
            if opened is None:
                return
            data = opened
        try:
            b = wirebundle.decode(data)
        except wirebundle.BundleError as e:
            self.counters["bundle_errors"] += 1
            _log.warning("robot %d: bad bundle: %s", self.id, e)
            return
        if b.robot == self.id:
            self.counters["own_echoes"] += 1  # our own, echoed back by a mesh
            return
        self.counters["bundles_heard"] += 1
        if where is None:
            east, north, _ = self.frame.from_gps(b.lat, b.lon)
        else:
            east, north = where
        self.hear(b.robot, (east, north, self.ticks), b.messages)

    def _operator_command(self, data: bytes) -> None:
        gate = self.commands
        if gate is None:
            self.counters["commands_unchecked"] += 1
            return
        try:
            result = gate.receive(data)
        except SeqFileError as e:  # cannot persist: acting could repeat after a reboot
            self.counters["commands_unsaved"] += 1
            _log.error("robot %d: operator command not acted on: %s", self.id, e)
            return
        if result.relay is not None:
            self.relays.append(result.relay)
        if result.act is not None:
            cmd = result.act
            self.pending_rc.append(cmd.rc(self.id))
            _log.warning(
                "robot %d: operator command %d accepted: code %d", self.id, cmd.seq, cmd.code
            )

    def take_relays(self) -> list[bytes]:
        """The frames to send besides the bundles, since the last call: command frames
        passed on unchanged, and status frames."""
        relays, self.relays = self.relays, []
        return relays

    # ------------------------------------------------------------ one tick

    def neighbor_columns(self, sensors: Sensors) -> nb.Columns:
        """This robot's neighbours now, from its heard table (stale senders dropped)."""
        here = (sensors.east, sensors.north)
        return nb.columns([self.heard], [here], self.ticks, self.timeout)[0]

    def tick(
        self,
        sensors: Sensors,
        rc: RcCommand | None = None,
        neighbors: nb.Columns | None = None,
        time_ns: int = 0,
    ) -> TickOutput:
        """Step, radio out, actuators: one tick. `neighbors` are this robot's columns if
        the host computed them (a simulator does a swarm at once); `time_ns` goes into
        the bundle's time field (0 where no wall clock should leak, as in simulation)."""
        # sensors: the remote-control code of this tick, if any (the host's, else the
        # operator's oldest signed command heard)
        if rc is None and self.pending_rc:
            rc = self.pending_rc.pop(0)
        if rc is None:
            sensors.rc_cmd = 0
            sensors.rc_goto = sensors.rc_param = None
        else:
            sensors.rc_cmd = rc.code
            sensors.rc_goto = rc.goto
            sensors.rc_param = rc.param
        # step
        commands: list[Command] = []
        vm = self.vm
        if self.status is _RUNNING:
            try:
                vm.process_inbox()
                if neighbors is None:
                    neighbors = self.neighbor_columns(sensors)
                vm.set_neighbor_columns(*neighbors)
                self.api.before_step(sensors, None)
                vm.call("step")
                commands = self.api.after_step()
                state = vm.globals.get("BVMSTATE")
                self.state = state if state.__class__ is str else None
            except BuzzError as e:
                self.fail(e)
        # radio out: a stopped script sends no messages, but its position still goes out
        messages: tuple[bytes, ...] = ()
        if self.status is _RUNNING:
            messages = tuple(vm.drain_outbox(self.budget, wirebundle.MSG_OVERHEAD))
        bundle = wirebundle.encode_fields(
            self.id, messages, sensors.lat, sensors.lon, sensors.alt, self.ticks, time_ns
        )
        if self.security is not None and self.security.signed:
            bundle = self._seal(bundle)
        # actuators
        supervisor = self.supervisor
        supervisor.submit(commands)
        order = supervisor.tick(sensors)
        events = supervisor.events
        if events:
            self._report(events)
            supervisor.events = []
        if self.observer is not None:
            self.observer(
                TickRecord(self.ticks, sensors, commands, order, self.state, list(events))
            )
        gossip = self.status_gossip
        if gossip.active:
            self._report_status(gossip, sensors)
        self.ticks += 1
        return _new_output(TickOutput, (bundle, messages, order))

    def _report_status(self, gossip: StatusGossip, sensors: Sensors) -> None:
        """This robot's status record now, and the status frame due, if any."""
        gate = self.commands
        battery = sensors.battery_percent
        gossip.set_own(
            StatusRecord(
                robot=self.id,
                heartbeat=0,
                battery=round(battery) if 0 <= battery <= 254 else None,
                flight_status=int(sensors.status),
                script=self.status.value,
                alt=sensors.alt,
                acked=0 if gate is None else gate.last_acted,
                lat=sensors.lat,
                lon=sensors.lon,
                state=self.state,
            )
        )
        frame = gossip.frame(self.ticks)
        if frame is not None:
            self.relays.append(frame)

    def _seal(self, bundle: bytes) -> bytes:
        """The bundle sealed; b"" (nothing sent) if no counter can be had: a robot that
        cannot keep its counter must not reuse one, so it falls silent and says so."""
        assert self.security is not None
        try:
            sealed = self.security.seal(bundle)
        except CounterError as e:
            self.counters["unsent_bundles"] += 1
            n = self.counters["unsent_bundles"]
            if n == 1 or n % EVENT_LOG_EVERY == 0:
                _log.error("robot %d: bundle not sent (%d so far): %s", self.id, n, e)
            return b""
        return sealed

    def _report(self, events: list[str]) -> None:
        counts = self.event_counts
        for event in events:
            counts[event] += 1
            n = counts[event]
            if n == 1 or n % EVENT_LOG_EVERY == 0:
                again = f" ({n} times)" if n > 1 else ""
                _log.warning("robot %d: %s%s", self.id, event, again)


__all__ = ["EVENT_LOG_EVERY", "RobotRuntime", "ScriptStatus", "TickOutput", "TickRecord"]
