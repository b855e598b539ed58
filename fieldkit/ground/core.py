"""The ground station's core, sans-I/O: fed the frames its radio hears and the time, it keeps
the swarm view (every robot's position, state, battery, link, script version), the operator
commands sent and who acknowledged them, and the event log; it returns the frames to send.

What it reads off the air (docs/ground.md):

* bundles (type 2): the sender's position and altitude (the bundle header), heard directly,
  so the link quality (bundles heard over bundles sent, from the header's counter); checked
  under the swarm's bundle key in a signed swarm (`bundle_auth.Verifier`);
* status frames (type 18, `fieldkit.robot.status`): every robot's state, battery, flight
  status, position and last command acted on, relayed robot to robot;
* update frames (type 16): each robot's script version and its place in an update, and the
  verdict of a rollback (a listening `OperatorSession`: this station serves no patch);
* command frames (type 17): the operator's commands as the robots relay them (a hotspot
  sent from another terminal shows on the plot too).

Anything else, or anything malformed, forged or replayed, is counted and logged (once a
robot and reason every few seconds), never raised. A robot whose reported position is
impossible or jumps faster than any vehicle flies is marked `suspect`, its last plausible
position kept.
"""

from __future__ import annotations

import math
import threading
from collections import Counter, deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from fieldkit.robot import bundle as wirebundle
from fieldkit.robot import bundle_auth, geo
from fieldkit.robot.operator_command import (
    ALL,
    COMMAND_FRAME,
    CommandError,
    CommandSigner,
    decode_command,
    is_command,
)
from fieldkit.robot.rc import RC_TASK_ALLOCATE, param_problem
from fieldkit.robot.status import (
    STATUS_FRAME,
    StatusGossip,
    StatusRecord,
    is_status,
    status_key,
)

#: The ground station's default robot id on the radio, as ROSBuzz's ground station.
GROUND_ID = 0
TICK_S = 0.1
#: A robot not heard (directly or through others) for this long is shown as lost.
LOST_S = 10.0
#: Link quality is measured over this window of bundles heard directly.
LINK_WINDOW_S = 5.0
#: Farther than this from the origin a reported position is taken for a lie (or a GPS fault).
MAX_RANGE_M = 20_000.0
#: Faster than this between two reports, a robot's position is taken for a lie.
MAX_SPEED_MS = 60.0
#: A command not acknowledged is sent again this often (robots relay each frame once).
RESEND_S = 2.0
#: The same complaint about one sender is logged at most this often.
COMPLAIN_EVERY_S = 5.0
EVENTS_KEPT = 500
#: Codes the page and `fieldkit cmd` know by name (ROSBuzz's rc codes).
CODES: dict[str, int] = {
    "takeoff": 22,
    "land": 21,
    "gohome": 20,
    "waypoint": 16,
    "task-allocation": 900,
    "coverage": 901,
    "idle": 904,
}
CODE_NAMES = {v: k for k, v in CODES.items()}
#: Hotspot ids of coverage.bzz (RC 16 waypoints with these ids).
HOTSPOT_IDS = range(50, 100)
PHASES = ("running", "standby", "switched", "operator")


class GroundError(ValueError):
    """A command the ground station refuses (what is wrong, for the page and the terminal)."""


@dataclass
class RobotView:
    """What the ground station knows of one robot."""

    id: int
    profile: str | None = None
    state: str | None = None
    script: str | None = None
    battery: int | None = None
    flight_status: int = 0
    alt: float | None = None
    lat: float | None = None
    lon: float | None = None
    east: float | None = None
    north: float | None = None
    last_heard: float | None = None  # any news of it (a bundle, its status, relayed)
    last_direct: float | None = None  # a bundle heard from it directly
    acked: int = 0
    heartbeat: int | None = None
    suspect: str | None = None
    version: int | None = None
    version_hash: str | None = None
    phase: str | None = None
    bundles: deque[tuple[float, int]] = field(default_factory=deque)  # (time, number)
    _where_t: float | None = None

    def link(self, now: float) -> float | None:
        """Bundles heard directly over bundles sent in the last LINK_WINDOW_S, or None."""
        b = self.bundles
        while b and now - b[0][0] > LINK_WINDOW_S:
            b.popleft()
        if not b:
            return None
        sent = (b[-1][1] - b[0][1]) % 0x10000 + 1
        return min(1.0, len(b) / sent)


@dataclass
class PendingCommand:
    """A command sent and who acknowledged it."""

    seq: int
    code: int
    params: tuple[float, ...]
    target: int
    frame: bytes
    sent_at: float
    deadline: float
    expected: set[int]
    acked: set[int] = field(default_factory=set)
    last_sent: float = 0.0
    done_at: float | None = None

    @property
    def done(self) -> bool:
        """Every expected robot acknowledged."""
        return bool(self.expected) and self.expected <= self.acked

    def missing(self) -> list[int]:
        """The robots that did not acknowledge yet."""
        return sorted(self.expected - self.acked)

    def describe(self) -> str:
        """`take off (22) to all`, in words."""
        name = CODE_NAMES.get(self.code, "code")
        to = "all" if self.target == ALL else f"robot {self.target}"
        extra = f" {', '.join(f'{p:g}' for p in self.params)}" if self.params else ""
        return f"#{self.seq} {name} ({self.code}){extra} to {to}"


class _Complaints:
    """Rate-limits log lines about one sender and one kind of problem."""

    def __init__(self) -> None:
        self.last: dict[tuple[int, str], float] = {}

    def due(self, who: int, kind: str, now: float) -> bool:
        t = self.last.get((who, kind))
        if t is not None and now - t < COMPLAIN_EVERY_S:
            return False
        if len(self.last) > 4096:
            self.last.clear()
        self.last[(who, kind)] = now
        return True


class GroundStation:
    """The swarm as the ground station sees it, and the commands it sends (sans-I/O)."""

    def __init__(
        self,
        *,
        robot_id: int = GROUND_ID,
        swarm_key: bytes | None = None,
        signer: CommandSigner | None = None,
        operator_pub: Any = None,
        origin: tuple[float, float] | None = None,
        profiles: Mapping[int, str] | None = None,
        default_profile: str | None = None,
        geofence: Sequence[tuple[float, float]] = (),
        shape: str | None = None,
        root_id: int = 1,
        margin: float = 20.0,
        update_view: bool = True,
    ) -> None:
        """`swarm_key` checks sealed bundles and status frames (None: a plain swarm);
        `signer` signs commands (None: this station only watches); `origin` is the local
        frame's (lat, lon) (None: the first robot heard); `geofence` lat/lon corners and
        `shape`/`root_id`/`margin` say what to draw (the task graph, the coverage region)."""
        self.id = robot_id
        self.lock = threading.RLock()
        self.signer = signer
        self.operator_pub = operator_pub
        self.profiles = dict(profiles or {})
        self.default_profile = default_profile
        self.geofence_gps = list(geofence)
        self.shape = shape
        self.root_id = root_id
        self._configured_root = root_id  # what a 900 without a root goes back to
        self.margin = margin
        self.frame: geo.LocalFrame | None = None
        if origin is not None:
            self.frame = geo.LocalFrame(origin[0], origin[1], 0.0)
        self.key = swarm_key
        bkey = bundle_auth.bundle_key(swarm_key) if swarm_key is not None else None
        self.verifier = bundle_auth.Verifier(bkey) if bkey is not None else None
        self.gossip = StatusGossip(
            robot_id, status_key(bkey.secret) if bkey is not None else None, ground=True
        )
        self.session: Any = None
        if swarm_key is not None and update_view:
            from fieldkit.update.operator import OperatorSession

            self.session = OperatorSession(swarm_key, ground_id=robot_id)
        self.robots: dict[int, RobotView] = {}
        self.commands: list[PendingCommand] = []
        self.events: deque[dict[str, Any]] = deque(maxlen=EVENTS_KEPT)
        self.event_count = 0
        self.counters: Counter[str] = Counter()
        self.hotspots: dict[int, tuple[float, float]] = {}  # id -> (lat, lon)
        self.bad_versions: dict[int, str] = {}
        self._complaints = _Complaints()
        self._update_frames: list[bytes] = []
        self._told_phase: dict[int, tuple[int, str]] = {}
        self.now = 0.0
        self.started: float | None = None
        self.on_event: Callable[[dict[str, Any]], None] | None = None

    # ------------------------------------------------------------ the log

    def event(self, text: str, level: str = "info") -> None:
        """One line of the event log."""
        self.event_count += 1
        e = {"n": self.event_count, "t": round(self.now, 1), "level": level, "text": text}
        self.events.append(e)
        if self.on_event is not None:
            self.on_event(e)

    def _complain(self, who: int, kind: str, text: str) -> None:
        self.counters[kind] += 1
        if self._complaints.due(who, kind, self.now):
            self.event(text, "warning")

    # ------------------------------------------------------------ radio in

    def hear(self, data: bytes, now: float, sender: int | None = None) -> None:
        """Bytes heard off the radio at `now` (seconds); `sender` is the link's id if known."""
        with self.lock:
            self.now = now
            self.counters["frames"] += 1
            who = -1 if sender is None else sender
            if not isinstance(data, bytes | bytearray) or len(data) < 8 or len(data) % 8:
                self._complain(
                    who,
                    "malformed",
                    f"malformed frame from {_who(sender)}: "
                    f"{len(data)} bytes, not whole 8-byte words",
                )
                return
            data = bytes(data)
            kind = data[7] | data[6] << 8
            if is_status(data):
                self._status(data, who)
            elif is_command(data):
                self._command_heard(data, who)
            elif kind == 16:
                if self.session is not None:
                    self._update_frames.append(data)
            elif kind == 2:
                self._bundle(data, who)
            else:
                self._complain(who, "unknown", f"frame of unknown type {kind} from {_who(sender)}")

    def _bundle(self, data: bytes, who: int) -> None:
        if self.verifier is not None:
            try:
                data = self.verifier.verify(data)
            except bundle_auth.AuthError as e:
                src = who if e.sender is None else e.sender
                self._complain(src, e.reason, f"bundle from robot {src} dropped: {e.reason}")
                return
        elif bundle_auth.is_sealed(data):
            self._complain(who, "sealed", "sealed bundles heard: give the swarm's keys (--keys)")
            return
        try:
            b = wirebundle.decode(data)
        except wirebundle.BundleError as e:
            self._complain(who, "malformed", f"malformed bundle from {_who(who)}: {e}")
            return
        if b.robot == self.id:
            return
        self.counters["bundles"] += 1
        view = self._view(b.robot)
        view.bundles.append((self.now, b.number))
        view.last_direct = self.now
        view.last_heard = self.now
        self._place(view, b.lat, b.lon, b.alt)

    def _status(self, data: bytes, who: int) -> None:
        news = self.gossip.receive(data, self._tick())
        if not news and self.gossip.counters.get("refused", 0) > self.counters["status_refused"]:
            self.counters["status_refused"] = self.gossip.counters["refused"]
            self._complain(who, "status", f"status frame from {_who(who)} refused (bad or forged)")
            return
        for r in news:
            if r.ground:
                continue
            self._record(r)

    def _record(self, r: StatusRecord) -> None:
        view = self._view(r.robot)
        view.state = r.state
        view.script = r.script
        view.battery = r.battery
        view.flight_status = r.flight_status
        view.heartbeat = r.heartbeat
        view.last_heard = self.now
        if view.last_direct is None or self.now - view.last_direct > 1.0:
            self._place(view, r.lat, r.lon, r.alt)
        else:
            view.alt = r.alt
        if r.acked > view.acked:
            view.acked = r.acked
            for c in self.commands:
                if c.done_at is None and r.acked >= c.seq and r.robot not in c.acked:
                    self._ack(c, r.robot)

    def _ack(self, c: PendingCommand, robot: int) -> None:
        c.acked.add(robot)
        if c.target == ALL and robot not in c.expected:
            c.expected.add(robot)
        if c.done and c.done_at is None:
            c.done_at = self.now
            self.event(
                f"{c.describe()}: acknowledged by {_ids(c.acked)} in {self.now - c.sent_at:.1f} s"
            )

    def _command_heard(self, data: bytes, who: int) -> None:
        try:
            cmd, _key_id, message, signature = decode_command(data)
        except CommandError as e:
            self._complain(who, "malformed", f"malformed command frame from {_who(who)}: {e}")
            return
        if self.operator_pub is not None:
            try:
                self.operator_pub.verify(signature, message)
            except Exception:
                self._complain(who, "forged", f"forged command frame from {_who(who)} ignored")
                return
        mine = any(c.seq == cmd.seq for c in self.commands)
        if cmd.code == 16 and len(cmd.params) == 4 and int(cmd.params[0]) in HOTSPOT_IDS:
            self.hotspots[int(cmd.params[0])] = (cmd.params[1], cmd.params[2])
        if not mine and self._complaints.due(-2, f"seq{cmd.seq}", self.now):
            name = CODE_NAMES.get(cmd.code, "code")
            self.event(f"operator command #{cmd.seq} {name} ({cmd.code}) heard on the radio")

    def _view(self, rid: int) -> RobotView:
        view = self.robots.get(rid)
        if view is None:
            view = RobotView(rid, profile=self.profiles.get(rid, self.default_profile))
            self.robots[rid] = view
            self.event(f"robot {rid} heard")
        return view

    def _place(self, view: RobotView, lat: float, lon: float, alt: float) -> None:
        """A reported position, unless it is impossible or too far from the last one."""
        if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)):
            self._suspect(view, "a position that is not a number")
            return
        if not (-90 <= lat <= 90 and -180 <= lon <= 180) or (lat == 0 and lon == 0):
            self._suspect(view, f"an impossible position ({lat:.5f}, {lon:.5f})")
            return
        if self.frame is None:
            self.frame = geo.LocalFrame(lat, lon, 0.0)
        east, north, _ = self.frame.from_gps(lat, lon)
        far = math.hypot(east, north)
        if far > MAX_RANGE_M or abs(alt) > 10_000:
            self._suspect(view, f"a position {far / 1000:.1f} km from home, {alt:.0f} m up")
            return
        if view.east is not None and view.north is not None and view._where_t is not None:
            dt = max(self.now - view._where_t, TICK_S)
            jump = math.hypot(east - view.east, north - view.north)
            if jump > MAX_SPEED_MS * dt + 5.0:
                self._suspect(view, f"a jump of {jump:.0f} m in {dt:.1f} s")
                return
        view.suspect = None
        view.lat, view.lon, view.alt = lat, lon, alt
        view.east, view.north = east, north
        view._where_t = self.now

    def _suspect(self, view: RobotView, what: str) -> None:
        view.suspect = what
        self._complain(view.id, "suspect", f"robot {view.id} reports {what}: position ignored")

    # ------------------------------------------------------------ commands

    def known(self) -> list[int]:
        """The robots heard recently (directly or through others)."""
        with self.lock:
            return sorted(
                rid
                for rid, v in self.robots.items()
                if v.last_heard is not None and self.now - v.last_heard <= LOST_S
            )

    def command(
        self,
        code: int,
        params: Sequence[float] = (),
        to: int | None = None,
        *,
        timeout: float = 30.0,
        strict: bool = True,
    ) -> PendingCommand:
        """Sign and queue a command for robot `to` (None: every robot); GroundError if it
        cannot be sent. With `strict`, a robot not heard recently is refused."""
        with self.lock:
            if self.signer is None:
                raise GroundError(
                    "this ground station has no operator key: start it with --keys DIR "
                    "(the directory of operator.key, from fieldkit keys init)"
                )
            if isinstance(code, bool) or not isinstance(code, int) or not 0 < code < 0x10000:
                raise GroundError(f"code {code!r}: an rc code is an integer 1..65535")
            params = tuple(float(p) for p in params)
            if code == 16 and len(params) != 4:
                raise GroundError("a waypoint (16) takes 4 params: ID LAT LON ALT")
            if len(params) > 4:
                raise GroundError("at most 4 params, each a finite number")
            problem = param_problem(code, params)
            if problem is not None:
                raise GroundError(problem)
            known = self.known()
            if to is not None:
                if isinstance(to, bool) or not isinstance(to, int) or not 0 <= to < ALL:
                    raise GroundError(f"robot {to!r}: a robot id is 0..65534")
                if strict and to not in known:
                    heard = _ids(known) if known else "none yet"
                    raise GroundError(
                        f"robot {to} is not in the swarm the ground station hears "
                        f"(robots heard: {heard})"
                    )
            target = ALL if to is None else to
            try:
                frame = self.signer.sign(target, code, params)
            except (ValueError, OSError) as e:
                raise GroundError(f"cannot sign the command: {e}") from None
            seq = decode_command(frame)[0].seq
            expected = set(known) if to is None else {to}
            c = PendingCommand(
                seq, code, params, target, frame, self.now, self.now + timeout, expected
            )
            for rid in expected:
                view = self.robots.get(rid)
                if view is not None and view.acked >= seq:
                    c.acked.add(rid)
            self.commands.append(c)
            del self.commands[:-50]
            if code == 16 and int(params[0]) in HOTSPOT_IDS:
                self.hotspots[int(params[0])] = (params[1], params[2])
            if code == RC_TASK_ALLOCATE:  # the task graph is drawn where this 900 roots it
                self.root_id = int(params[0]) if params else self._configured_root
            self.event(f"sent {c.describe()}")
            return c

    # ------------------------------------------------------------ radio out

    def _tick(self) -> int:
        return round(self.now / TICK_S)

    def tick(self, now: float) -> list[bytes]:
        """Time `now` (seconds): the frames to send now."""
        with self.lock:
            self.now = now
            if self.started is None:
                self.started = now
            out: list[bytes] = []
            for c in self.commands:
                if c.done_at is not None or now > c.deadline + RESEND_S:
                    continue
                if now > c.deadline:
                    if c.last_sent <= c.deadline:
                        c.last_sent = now
                        self.event(
                            f"{c.describe()}: no acknowledgement from {_ids(c.missing())}",
                            "warning",
                        )
                    continue
                if c.last_sent == 0.0 or now - c.last_sent >= RESEND_S:
                    c.last_sent = now
                    out.append(c.frame)
            self.gossip.set_own(
                StatusRecord(
                    robot=self.id,
                    heartbeat=0,
                    battery=None,
                    flight_status=0,
                    script="idle",
                    alt=0.0,
                    acked=0,
                    lat=self.frame.lat if self.frame is not None else 0.0,
                    lon=self.frame.lon if self.frame is not None else 0.0,
                    state="GROUND",
                )
            )
            frame = self.gossip.frame(self._tick())
            if frame is not None:
                out.append(frame)
            if self.session is not None:
                self.session.step(self._tick(), self._update_frames)
                self._update_frames = []
                self._update_view()
            return out

    def _update_view(self) -> None:
        session = self.session
        for rid, v in session.robots().items():
            view = self.robots.get(rid)
            if view is None:
                continue
            phase = ("running", "standby", "switched", "operator")[int(v.phase)]
            view.version = v.version
            view.phase = phase
            if self._told_phase.get(rid) != (v.version, phase) and rid in self._told_phase:
                self.event(f"robot {rid}: script version {v.version}, {phase}")
            self._told_phase[rid] = (v.version, phase)
        for version, reason in session.agent.bad.items():
            if version not in self.bad_versions:
                self.bad_versions[version] = str(reason)
                self.event(f"version {version} rolled back: {reason}", "warning")

    # ------------------------------------------------------------ the page's view

    def snapshot(self) -> dict[str, Any]:
        """Everything the page shows, as JSON-able data."""
        with self.lock:
            now = self.now
            robots = []
            for rid in sorted(self.robots):
                v = self.robots[rid]
                age = None if v.last_heard is None else round(now - v.last_heard, 1)
                link = v.link(now)
                robots.append(
                    {
                        "id": rid,
                        "profile": v.profile,
                        "state": v.state,
                        "script": v.script,
                        "battery": v.battery,
                        "flight": v.flight_status,
                        "alt": None if v.alt is None else round(v.alt, 1),
                        "east": None if v.east is None else round(v.east, 2),
                        "north": None if v.north is None else round(v.north, 2),
                        "age": age,
                        "lost": age is None or age > LOST_S,
                        "link": None if link is None else round(link, 2),
                        "direct": v.last_direct is not None and now - v.last_direct <= LOST_S,
                        "acked": v.acked,
                        "suspect": v.suspect,
                        "version": v.version,
                        "phase": v.phase,
                    }
                )
            commands = [
                {
                    "seq": c.seq,
                    "text": c.describe(),
                    "code": c.code,
                    "target": None if c.target == ALL else c.target,
                    "acked": sorted(c.acked),
                    "missing": c.missing(),
                    "done": c.done,
                    "expired": c.done_at is None and now > c.deadline,
                    "age": round(now - c.sent_at, 1),
                }
                for c in self.commands[-10:]
            ]
            return {
                "t": 0.0 if self.started is None else round(now - self.started, 1),
                "ground": self.id,
                "can_command": self.signer is not None,
                "origin": None if self.frame is None else [self.frame.lat, self.frame.lon],
                "robots": robots,
                "commands": commands,
                "events": list(self.events)[-100:],
                "geofence": self._local(self.geofence_gps),
                "graph": self._graph(),
                "region": self._region(),
                "hotspots": self._local(list(self.hotspots.values())),
                "bad_versions": {str(k): v for k, v in self.bad_versions.items()},
                "counters": dict(self.counters),
            }

    def _local(self, points: Iterable[tuple[float, float]]) -> list[list[float]]:
        if self.frame is None:
            return []
        out = []
        for lat, lon in points:
            east, north, _ = self.frame.from_gps(lat, lon)
            out.append([round(east, 2), round(north, 2)])
        return out

    def _graph(self) -> list[list[float]] | None:
        """The task graph's nodes (east, north), placed at the root robot, if known."""
        if self.shape is None:
            return None
        root = self.robots.get(self.root_id)
        if root is None or root.east is None or root.north is None:
            return None
        from fieldkit.robot import shapes

        try:
            pos = shapes.positions(self.shape)
        except Exception:
            return None
        return [
            [round(root.east + e, 2), round(root.north + n, 2)]
            for _k, (n, e) in sorted(pos.items())
        ]

    def _region(self) -> list[list[float]]:
        """The coverage region: the hotspots' hull inflated by the margin (coverage.bzz)."""
        spots = self._local(list(self.hotspots.values()))
        if not spots:
            return []
        from fieldkit.robot.voronoi import convex_hull

        hull = convex_hull([(n, e) for e, n in spots], self.margin)
        return [[round(float(e), 2), round(float(n), 2)] for n, e in hull]

    def pending(self, seq: int) -> PendingCommand | None:
        """The command of sequence number `seq`, if this station sent it."""
        with self.lock:
            return next((c for c in self.commands if c.seq == seq), None)


def _who(sender: int | None) -> str:
    return "an unknown sender" if sender is None or sender < 0 else f"radio {sender}"


def _ids(ids: Iterable[int]) -> str:
    """`1, 2, 5` or `none`."""
    out = sorted(ids)
    return ", ".join(map(str, out)) if out else "none"


__all__ = [
    "CODES",
    "CODE_NAMES",
    "COMMAND_FRAME",
    "GROUND_ID",
    "GroundError",
    "GroundStation",
    "PendingCommand",
    "RobotView",
    "STATUS_FRAME",
]
