"""Software in the loop: N simulated vehicles, N real field nodes, one simulated radio.

    fieldkit sitl --robots 6 --script buzz_scripts/task_allocation.bzz --out run/
    fieldkit sitl --team solo:2,husky:1,m100:1,spiri:1 --script task_allocation.bzz --out run/

Every robot is the real thing but its vehicle and its radio:

* the simulated machine its profile's `autopilot.flavour` needs
  (`fieldkit.vehicle.sim.machine`: ArduPilot for the Solo, PX4 for the Spiri, the DJI M100's
  flight controller, the Husky's MCU and GPS) on pseudo-terminals, stepped in real time here;
* a `fieldkit node` process, exactly as on the robot's companion computer, opening those ptys
  as its autopilot (and a Husky's GPS) and another pty as its XBee (API mode 1, XbeeMav
  packets); an M100's node gets the test DJI app from a config file's `[dji]` table, as a
  deployed node does;
* the `RadioRelay` here: it reads each node's XBee transmit frames (0x10) and hands them as
  receive frames (0x90) to the robots in range, dropping each with the simulator's
  probability. So the bytes between nodes are the bytes on the air in the field.

The vehicles hold their GPS fix until every node is up and talking to its autopilot, then
all get it at once: nodes wait for a fix before their loop starts, so the swarm starts
together however long each process took to start.

With `ground`, the operator's ground station (`fieldkit.ground`) stands beside robot 1 on the
same relay, with its page and a UDP gateway (`fieldkit cmd --radio`); a run without a length
then lasts until `stop` is set (the command line's Ctrl-C or SIGTERM): every node is told to
stop (SIGTERM, its safe stop) and the results are written as for any run.

Real time, real processes: runs are not reproducible bit for bit (that is the simulator's job).

Outputs in `out/`: `summary.json`; `log.txt`, every node's output in time order, each line
`[2026-11-26T09:03:24.123Z] robot 4: text` (UTC wall time; a line the node did not stamp
itself is stamped when the relay reads it), and the same lines of one robot in
`robotN/log.txt` beside its node's `summary.json`; `trajectories.csv` and `plot.png`
(`fieldkit.sim.tracks`: every robot's position and flight mode once a second from the
swarm's start, and the bytes each put on the air).
"""

from __future__ import annotations

import json
import math
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fieldkit.errors import FieldkitError
from fieldkit.node.log import wall_stamp
from fieldkit.radio.xbee import FrameReader, TransmitRequest, receive_packet
from fieldkit.radio.xbeemav import XbeeMav
from fieldkit.results import write_json
from fieldkit.robot import geo
from fieldkit.robot.profiles import Profile
from fieldkit.robot.rc import RcCommand
from fieldkit.sim.tracks import SAMPLE_S, Tracks, write_tracks
from fieldkit.update.operator import GROUND_ID, OperatorSession
from fieldkit.update.release import Release
from fieldkit.vehicle.pty import PtyPair, open_pty
from fieldkit.vehicle.sim.ardupilot import DEFAULT_HOME
from fieldkit.vehicle.sim.machine import SimMachine, open_sim_machine

if TYPE_CHECKING:
    from fieldkit.ground.live import LiveGround

#: Where robot i's XBee serial numbers start (Digi's OUI prefix, as real modules have).
SERIAL_BASE = 0x0013A20000000000

#: The vehicles are stepped (and the relay serviced) this often, seconds.
STEP_S = 0.05

#: Every node must be up (imports, autopilot heartbeat) within this long, seconds.
STARTUP_S = 120.0

#: After the nodes' run, how long they have to write their summaries, seconds.
WIND_DOWN_S = 30.0

#: A line a node stamped itself: `[UTC time] robot ID: ` (fieldkit node's stdout).
_STAMPED = re.compile(r"\[\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(\.\d+)?Z\] robot \d+: ")


class NodeOutput:
    """What one node process prints (stdout and stderr, one pipe), cut into stamped lines."""

    def __init__(self, robot: int, fd: int) -> None:
        self.robot = robot
        self.fd = fd
        os.set_blocking(fd, False)
        self.lines: list[str] = []  # every line so far, stamped
        self._partial = b""
        self.closed = False

    def read(self) -> None:
        """Take whatever the node printed since the last call (never blocks)."""
        while not self.closed:
            try:
                data = os.read(self.fd, 65536)
            except BlockingIOError:
                return
            except OSError:
                data = b""
            if not data:  # the node is gone: its last line, even without its newline
                self.closed = True
                data, self._partial = self._partial + b"\n", b""
                if data == b"\n":
                    return
            *complete, self._partial = (self._partial + data).split(b"\n")
            now = wall_stamp(time.time())
            tag = f"[{self.robot}] "  # the script API's robot tag: the stamp names the robot
            for raw in complete:
                text = raw.decode("utf-8", errors="replace").rstrip("\r")
                if not _STAMPED.match(text):
                    if text.startswith(tag):
                        text = text[len(tag) :]
                    text = f"[{now}] robot {self.robot}: {text}"
                self.lines.append(text)


@dataclass
class SitlRobot:
    """One robot of the run: its profile, its simulated machine (on ptys of its own), its
    radio's pty, its node process."""

    id: int
    profile: Profile
    machine: SimMachine
    radio_pty: PtyPair
    reader: FrameReader
    out: Path
    process: subprocess.Popen[bytes] | None = None
    bytes_sent: int = 0
    output: NodeOutput | None = None
    where: tuple[float, float, float] = (0.0, 0.0, 0.0)  # east, north, up in the run's frame


class RadioRelay:
    """Carries XBee frames between the robots' radio ptys: range, drop, bytes counted."""

    def __init__(
        self,
        robots: Sequence[SitlRobot],
        drop: float,
        range_m: float,
        seed: int,
        corrupt: float = 0.0,
        frame: geo.LocalFrame | None = None,
    ) -> None:
        self.robots = list(robots)
        self.drop = drop
        self.corrupt = corrupt  # probability that a delivered frame gets one byte flipped
        self.range_m = range_m
        self.rng = random.Random(seed)
        self.stats: Counter[str] = Counter()
        self.ground: GroundStation | None = None  # an operator's radio beside one robot
        self.live: LivePlace | None = None  # the ground station of --ground, at a place
        # Where everyone is, in one frame: each machine's own frame is its own home's.
        self.frame = frame or geo.LocalFrame(DEFAULT_HOME[0], DEFAULT_HOME[1], 0.0)

    def locate(self) -> None:
        """Read every robot's position once (the range checks of a service use it)."""
        for r in self.robots:
            lat, lon, alt = r.machine.position
            east, north, _ = self.frame.from_gps(lat, lon)
            r.where = (east, north, alt)

    def service(self, now: float = 0.0) -> None:
        """Forward every complete transmit frame the nodes wrote since the last call, and
        what the ground station sends at run time `now`."""
        self.locate()
        for sender in self.robots:
            try:
                data = os.read(sender.radio_pty.master, 65536)
            except (BlockingIOError, OSError):
                continue
            for frame in sender.reader.feed(data):
                if isinstance(frame, TransmitRequest):
                    self._forward(sender, frame.rf_data, now)
                else:
                    self.stats["other_frames"] += 1
        if self.live is not None:
            for rf in self.live.transmissions(now):
                self._deliver(self.live.id, self.live.where, rf, None)

    def _forward(self, sender: SitlRobot, rf: bytes, now: float) -> None:
        sender.bytes_sent += len(rf)
        if self.ground is not None and sender is self.ground.robot:
            self.ground.hear(rf)
        if self.live is not None and math.dist(sender.where, self.live.where) <= self.range_m:
            self.live.hear(sender.id, rf, now)
        self.stats["frames"] += 1
        self._deliver(sender.id, sender.where, rf, sender)

    def _deliver(
        self, sender: int, here: tuple[float, float, float], rf: bytes, skip: SitlRobot | None
    ) -> None:
        """`rf` from radio `sender` at `here` to every robot in range, through the loss."""
        frame = receive_packet(SERIAL_BASE + sender, rf)
        for r in self.robots:
            if r is skip:
                continue
            if math.dist(here, r.where) > self.range_m:
                continue
            if self.drop and self.rng.random() < self.drop:
                self.stats["dropped"] += 1
                continue
            out = frame
            if self.corrupt and self.rng.random() < self.corrupt:
                k = self.rng.randrange(len(frame))
                out = frame[:k] + bytes([frame[k] ^ (1 << self.rng.randrange(8))]) + frame[k + 1 :]
                self.stats["corrupted"] += 1
            try:
                os.write(r.radio_pty.master, out)
                self.stats["delivered"] += 1
            except (BlockingIOError, OSError):
                self.stats["overflow"] += 1  # the node is not reading: a full UART drops


class LivePlace:
    """The ground station of `--ground` (`fieldkit.ground.live.LiveGround`: the station, its
    page, its UDP gateway) at one place of the relay's air, on an XBee of its own (XbeeMav
    packets, fragments and acks as a real one): it hears the robots in range, and what the
    station and the gateway send reaches the robots in range."""

    def __init__(self, live: LiveGround, where: tuple[float, float, float]) -> None:
        self.live = live
        self.id = live.station.id
        self.where = where
        self.xbee = XbeeMav(self.id)
        self.msgid = 0
        self.next_tick = 0.0
        self.unsendable = 0  # frames the gateway brought that no XBee packet can carry

    def hear(self, sender: int, rf: bytes, now: float) -> None:
        """The RF data robot `sender` sent: to the station and out of the gateway."""
        data = self.xbee.receive(sender, rf)
        if data is None:
            return
        self.live.station.hear(data, now, sender)
        self.live.gateway.send(sender, data)

    def transmissions(self, now: float) -> list[bytes]:
        """The RF data to put on the air at run time `now`: the station's frames (its ticks
        10 a second), the gateway's, and the XBee's acks, as its pacing lets them go."""
        frames: list[bytes] = []
        if now >= self.next_tick:
            frames += self.live.station.tick(now)
            self.next_tick += 0.1
            if self.next_tick <= now:  # late (a loaded machine): on from now, no catching up
                self.next_tick = now + 0.1
        frames += self.live.gateway.poll()
        for f in frames:
            self.msgid = (self.msgid + 1) & 0xFF
            try:
                self.xbee.submit(f, self.msgid)
            except ValueError:
                self.unsendable += 1
        return self.xbee.pump()


@dataclass(frozen=True)
class SitlUpdate:
    """`--update T:NEW.bzz[:ROBOT]`: at second T of the run, a ground station next to robot
    ROBOT starts serving the signed patch to this release."""

    t: float
    release: Release
    robot: int = 1
    name: str = ""


class GroundStation:
    """The operator's radio beside one robot: it hears that robot and only that robot hears
    it, as `fieldkit update --radio` would from a laptop in the field."""

    def __init__(self, robot: SitlRobot, session: OperatorSession) -> None:
        self.robot = robot
        self.session = session
        self.heard: list[bytes] = []
        self.msgid = 0
        self.ticks = 0
        self.done_s: float | None = None
        self.outcome: tuple[bool, str] | None = None

    def hear(self, rf: bytes) -> None:
        """RF data the robot sent: an XbeeMav standard message's words are the frame."""
        if len(rf) > 3 and rf[0] == ord("S"):
            self.heard.append(rf[3:])

    def service(self, t: float) -> None:
        """Run the session's ticks due by run time `t` (10 a second)."""
        while self.ticks <= t * 10:
            frame = self.session.step(self.ticks, self.heard)
            self.heard = []
            self.ticks += 1
            if frame is not None:
                self.msgid = (self.msgid + 1) & 0xFF
                rf = b"S" + bytes((GROUND_ID, self.msgid)) + frame
                try:
                    os.write(
                        self.robot.radio_pty.master, receive_packet(SERIAL_BASE + GROUND_ID, rf)
                    )
                except (BlockingIOError, OSError):
                    pass  # a full UART drops, as on the air
            if self.outcome is None:
                self.outcome = self.session.outcome()
                if self.outcome is not None:
                    self.done_s = round(self.ticks / 10, 1)


@dataclass
class SitlConfig:
    """One software-in-the-loop run."""

    script: Path
    robots: int
    out: Path
    profile: Profile
    drop: float = 0.0
    corrupt: float = 0.0  # share of delivered frames with a flipped bit (for tests)
    range_m: float = 500.0
    seconds: float | None = 60.0  # None: until `run`'s stop is set
    seed: int = 0
    commands: Sequence[RcCommand] = ()
    include_dirs: Sequence[str] = ()
    spacing_m: float = 4.0
    home: tuple[float, float] = DEFAULT_HOME
    sets: Mapping[str, int | float | str] = field(default_factory=dict)  # node --set
    extra: list[str] = field(default_factory=list)  # more `fieldkit node` arguments
    update: SitlUpdate | None = None  # an over-the-air update during the run
    security: str = "none"  # the nodes' --security; signed needs keys (`keys`, or --update's)
    keys: Path | None = None  # a `fieldkit keys init` directory (else --update makes keys)
    record: Path | None = None  # each node records its flight to record/robot{ID}
    ros1: bool = False  # record ROS 1 bags, record/robot{ID}.bag
    # A heterogeneous team: robot i + 1's profile is team[i] (`robots` of them); empty:
    # every robot is `profile`.
    team: Sequence[Profile] = ()
    ground: LiveGround | None = None  # --ground: the station, page and gateway to place

    def profiles(self) -> list[Profile]:
        """Each robot's profile, robot 1 first."""
        if self.team:
            if len(self.team) != self.robots:
                raise FieldkitError(f"a team of {len(self.team)} for {self.robots} robots")
            return list(self.team)
        return [self.profile] * self.robots


def _homes(cfg: SitlConfig) -> list[tuple[float, float]]:
    frame = geo.LocalFrame(cfg.home[0], cfg.home[1], 0.0)
    side = max(1, math.ceil(math.sqrt(cfg.robots)))
    out = []
    for k in range(cfg.robots):
        lat, lon, _ = frame.to_gps((k % side) * cfg.spacing_m, (k // side) * cfg.spacing_m, 0.0)
        out.append((lat, lon))
    return out


def run(
    cfg: SitlConfig,
    progress: Callable[[float, float], None] | None = None,
    *,
    stop: threading.Event | None = None,
    say: Callable[[str], None] | None = None,
) -> dict:
    """Run the swarm for `cfg.seconds` (None: until `stop` is set) and return the summary
    (also written to out/). Setting `stop` ends a run early the same way: every node is
    told to stop (SIGTERM) and writes its summary. `say` hears the run's milestones."""
    cfg.out.mkdir(parents=True, exist_ok=True)
    robots: list[SitlRobot] = []
    stop = stop if stop is not None else threading.Event()
    frame = geo.LocalFrame(cfg.home[0], cfg.home[1], 0.0)
    ran_s = 0.0
    try:
        for k, (home, profile) in enumerate(zip(_homes(cfg), cfg.profiles(), strict=True)):
            rid = k + 1
            radio = open_pty()
            try:
                # The GPS fix is held back until every node is up (see the loop below).
                machine = open_sim_machine(
                    profile, home=home, seed=cfg.seed * 1000 + rid, hold_fix=True
                )
            except BaseException:
                radio.close()
                raise
            robots.append(
                SitlRobot(rid, profile, machine, radio, FrameReader(1), cfg.out / f"robot{rid}")
            )
        relay = RadioRelay(robots, cfg.drop, cfg.range_m, cfg.seed, cfg.corrupt, frame)
        updating = _Updating(cfg, robots) if cfg.update is not None else None
        robot_keys = updating.robot_keys if updating is not None else cfg.keys
        if cfg.security == "signed" and robot_keys is None:
            raise FieldkitError("sitl --security signed needs keys: give --keys DIR")
        if updating is not None:
            relay.ground = updating.ground
        if cfg.ground is not None:
            from fieldkit.ground.live import BESIDE_M

            relay.locate()
            east, north, _ = robots[0].where
            relay.live = LivePlace(cfg.ground, (east - BESIDE_M, north, 0.0))
        for r in robots:
            r.out.mkdir(parents=True, exist_ok=True)
            argv = _node_argv(cfg, r)
            if updating is not None or cfg.security == "signed":
                # Each node's versions and bundle counter, fresh for the run.
                if updating is None:
                    shutil.rmtree(r.out / "state", ignore_errors=True)
                argv += ["--state-dir", str(r.out / "state"), "--keys", str(robot_keys)]
            # A process group of its own: a terminal's Ctrl-C reaches this process alone,
            # which stops every node once, by SIGTERM, as systemd would.
            r.process = subprocess.Popen(
                argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, process_group=0
            )
            assert r.process.stdout is not None
            r.output = NodeOutput(r.id, r.process.stdout.fileno())
        processes = [r.process for r in robots if r.process is not None]
        start = time.monotonic()
        last = start
        released: float | None = None
        stopping = False
        deadline = start + STARTUP_S
        tracker = _Tracker(cfg, robots)
        while any(p.poll() is None for p in processes):
            now = time.monotonic()
            _read_outputs(robots)
            if released is None and all(r.machine.node_heard for r in robots):
                # Every node is up and has spoken to its vehicle: all get their GPS fix
                # now, so their loops, and their --seconds, start together however long
                # each took to start (a loaded machine staggers them by seconds).
                for r in robots:
                    r.machine.release_fix()
                released = now
                deadline = math.inf if cfg.seconds is None else now + cfg.seconds + WIND_DOWN_S
                if say is not None:
                    say(f"sitl: every node is up: {len(robots)} robots start now")
            if stop.is_set() and not stopping:
                # Asked to stop: each node stops as in the field (its safe stop, its
                # summary); the vehicles and the radio run on while they do.
                stopping = True
                if released is not None:
                    ran_s = now - released
                for proc in processes:
                    if proc.poll() is None:
                        proc.send_signal(signal.SIGTERM)
                deadline = min(deadline, now + WIND_DOWN_S)
            if now > deadline:
                for proc in processes:
                    if proc.poll() is None:
                        proc.kill()
                break
            for r in robots:
                r.machine.step(now - last)
            last = now
            relay.service(now - start)
            if released is not None:
                if not stopping:
                    ran_s = now - released
                if updating is not None:
                    updating.service(now - released)
                tracker.sample(now - released)
                if progress is not None and cfg.seconds is not None:
                    progress(min(now - released, cfg.seconds), cfg.seconds)
            time.sleep(STEP_S)
    finally:
        for r in robots:
            if r.process is not None and r.process.poll() is None:
                r.process.kill()
                r.process.wait()
            if r.process is not None and r.process.stdout is not None:
                _read_outputs([r])  # what it printed last, up to the end of its pipe
                r.process.stdout.close()
            r.machine.close()
            r.radio_pty.close()
    _write_logs(cfg, robots)
    what = f"sitl {cfg.script.name}, {cfg.robots} robots"
    write_tracks(tracker.tracks, cfg.out, what)
    seconds = cfg.seconds if cfg.seconds is not None else round(ran_s, 1)
    return _summary(cfg, robots, relay, updating, seconds)


def _node_argv(cfg: SitlConfig, r: SitlRobot) -> list[str]:
    """Robot `r`'s `fieldkit node` command line (keys and state directory aside)."""
    argv = [
        sys.executable, "-m", "fieldkit", "node",
        "--profile", str(r.profile.path or r.profile.name),
        "--script", str(cfg.script),
        *r.machine.node_args(),
        "--radio", f"serial://{r.radio_pty.slave_path}?baud=230400&api=1&unknown=sysid",
        "--robot-id", str(r.id),
        "--out", str(r.out),
        "--seed", str(cfg.seed),
        *(a for d in cfg.include_dirs for a in ("-I", d)),
        *cfg.extra,
    ]  # fmt: skip
    if cfg.seconds is not None:
        argv += ["--seconds", str(cfg.seconds)]
    app = r.machine.app
    if app is not None:
        argv += ["--config", str(_dji_config(r.out, *app))]
    argv += ["--security", cfg.security]
    if cfg.record is not None:
        suffix = ".bag" if cfg.ros1 else ""
        argv += ["--record", str(cfg.record / f"robot{r.id}{suffix}")]
    for name, value in cfg.sets.items():
        argv += ["--set", f"{name}={value}"]  # the node parses it back the same
    for c in cfg.commands:
        if c.robot == r.id:
            # Each node gets its own robot's commands, in the one T:ROBOT:CODE form.
            argv += ["--command", c.text()]
    return argv


def _dji_config(out: Path, app_id: int, app_key: str) -> Path:
    """A node config holding only the DJI app, as a deployed M100's has it: the key in a
    file of its own, readable by the node's user alone (never on a command line)."""
    key = out / "dji-app-key"
    key.unlink(missing_ok=True)
    fd = os.open(key, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w", encoding="ascii") as f:
        f.write(app_key + "\n")
    config = out / "fieldkit.toml"
    config.write_text(
        f"# the simulated M100's test app (fieldkit.vehicle.sim.dji)\n[dji]\n"
        f'app_id = {app_id}\napp_key_file = "{key.name}"\n',
        encoding="utf-8",
    )
    return config


class _Updating:
    """An `--update` run: the keys, the ground station, and when the patch goes out."""

    def __init__(self, cfg: SitlConfig, robots: Sequence[SitlRobot]) -> None:
        import bvm
        from fieldkit.update.keys import (
            OPERATOR_PUB,
            SWARM_KEY,
            init_keys,
            load_robot_keys,
            load_signing_key,
        )

        assert cfg.update is not None
        self.update = cfg.update
        # A run starts from scratch: version 0 everywhere, under keys of its own. What an
        # earlier run left in the same out/ (keys, the nodes' versions) would otherwise be
        # refused (keys are never overwritten) or run instead of --script.
        given = None if cfg.keys is None else cfg.keys.resolve()
        for old in (cfg.out / "keys", cfg.out / "robot-keys", *(r.out / "state" for r in robots)):
            if given is not None and given.is_relative_to(old.resolve()):
                continue  # --keys names an earlier run's keys: keep them, use them
            shutil.rmtree(old, ignore_errors=True)
        # The operator's keys (--keys), else a pair of the run's own.
        keys = cfg.keys if cfg.keys is not None else init_keys(cfg.out / "keys").directory
        # A robot holds the operator's public key and the swarm key, never the signing key.
        self.robot_keys = cfg.out / "robot-keys"
        self.robot_keys.mkdir(mode=0o700, exist_ok=True)
        for name in (OPERATOR_PUB, SWARM_KEY):
            dest = self.robot_keys / name
            dest.write_bytes((keys / name).read_bytes())
            dest.chmod(0o600)
        self.signing_key = load_signing_key(keys)
        self.keys = load_robot_keys(self.robot_keys)
        # What every node seeds its store with from --script: version 0.
        if cfg.script.suffix == ".bo":
            self.base = Release.read(cfg.script)
        else:
            program = bvm.compile_file(cfg.script, include_dirs=list(cfg.include_dirs))
            self.base = Release.from_program(program)
        robot = next((r for r in robots if r.id == cfg.update.robot), None)
        if robot is None:
            raise FieldkitError(f"update at robot {cfg.update.robot}: robots are 1..{len(robots)}")
        self.ground = GroundStation(robot, OperatorSession(self.keys.swarm_key))
        self.injected_s: float | None = None
        self.patch_bytes = 0

    def service(self, t: float) -> None:
        """At run time `t`: send the patch once it is due, and run the ground station."""
        if self.injected_s is None and t >= self.update.t:
            from fieldkit.update.patch import make_update

            patch = make_update(
                self.base, self.update.release, 1, self.signing_key, self.keys.swarm_key
            )
            self.ground.session.send(patch, 1, self.base.hash)
            self.injected_s = round(t, 1)
            self.patch_bytes = len(patch)
        self.ground.service(t)

    def summary(self, nodes: Mapping[str, Any]) -> dict[str, object]:
        """The summary's `update`, from the ground station and the nodes' own figures."""
        sent = sum(int((n.get("update") or {}).get("update_bytes_sent", 0)) for n in nodes.values())
        outcome = self.ground.outcome
        bad = self.ground.session.agent.bad.get(1)
        # The ground station only hears that it was rolled back (a verdict carries a code):
        # the robot that judged it says why (its script error, its barrier's timeout).
        judged = [
            (n.get("update") or {}).get("judged_bad", {}).get("1")
            for _, n in sorted(nodes.items(), key=lambda kv: int(kv[0]))
        ]
        bad = next((j for j in judged if j), bad)
        return {
            "version": 1,
            "injected_s": self.injected_s,
            "all_switched_s": self.ground.done_s if outcome is not None and outcome[0] else None,
            "rolled_back": bad is not None,
            "reason": bad,
            "patch_bytes": self.patch_bytes,
            "update_bytes_sent": sent,
        }


def _read_outputs(robots: Sequence[SitlRobot]) -> None:
    for r in robots:
        if r.output is not None:
            r.output.read()


def _write_logs(cfg: SitlConfig, robots: Sequence[SitlRobot]) -> None:
    """Each robot's lines to robotN/log.txt, and everyone's, in time order, to log.txt."""
    merged: list[str] = []
    for r in robots:
        lines = r.output.lines if r.output is not None else []
        (r.out / "log.txt").write_text("".join(line + "\n" for line in lines), encoding="utf-8")
        merged.extend(lines)
    # The stamps are ISO 8601 UTC of one width: text order is time order (a stable sort
    # keeps each node's own order among equal stamps).
    merged.sort(key=lambda line: line[: line.index("]") + 1])
    (cfg.out / "log.txt").write_text("".join(line + "\n" for line in merged), encoding="utf-8")


class _Tracker:
    """Samples every vehicle once a second from the swarm's start: position (in the frame of
    the run's home), flight mode, and the bytes each robot sent since the last sample."""

    def __init__(self, cfg: SitlConfig, robots: Sequence[SitlRobot]) -> None:
        self.robots = robots
        self.frame = geo.LocalFrame(cfg.home[0], cfg.home[1], 0.0)
        self.tracks = Tracks(
            ids=[r.id for r in robots], home=cfg.home, state_column="mode", load_unit="second"
        )
        self.next_t = 0.0
        self.last_t = 0.0
        self.last_bytes = [0] * len(robots)

    def sample(self, t: float) -> None:
        """Sample if a second has passed since the last sample (t: seconds since the start)."""
        if t < self.next_t:
            return
        positions, modes = [], []
        for r in self.robots:
            m = r.machine
            lat, lon, alt = m.position
            east, north, _ = self.frame.from_gps(lat, lon)
            positions.append((east, north, alt))
            modes.append(m.mode)
        t = round(t, 3)  # wall time: to the millisecond is all it means
        self.tracks.add(t, positions, modes)
        sent = [r.bytes_sent for r in self.robots]
        if t > self.last_t:
            rates = [
                (b - a) / (t - self.last_t) for a, b in zip(self.last_bytes, sent, strict=True)
            ]
            self.tracks.add_load(t, sum(rates) / len(rates), max(rates))
        self.last_t, self.last_bytes = t, sent
        self.next_t = (math.floor(t / SAMPLE_S) + 1) * SAMPLE_S


def _security(cfg: SitlConfig, nodes: Mapping[str, Mapping[str, Any]]) -> dict[str, object]:
    """The nodes' bundle security, added up: accepted, rejected per reason, who is mixed."""
    rejected: dict[str, int] = {}
    accepted = 0
    mixed: set[int] = set()
    for node in nodes.values():
        sec = node.get("security") or {}
        accepted += int(sec.get("accepted", 0))
        for reason, n in (sec.get("rejected") or {}).items():
            rejected[reason] = rejected.get(reason, 0) + int(n)
        mixed.update(int(k) for k in sec.get("mixed") or {})
    return {
        "mode": cfg.security,
        "accepted": accepted,
        "rejected": dict(sorted(rejected.items())),
        "mixed": sorted(mixed),
    }


def _ground_summary(place: LivePlace) -> dict[str, object]:
    """What the ground station of `--ground` heard and sent."""
    station = place.live.station
    return {
        "robots_heard": station.known(),
        "commands": [c.describe() for c in station.commands],
        "gateway": dict(place.live.gateway.counters),
        "unsendable": place.unsendable,
    }


def _summary(
    cfg: SitlConfig,
    robots: list[SitlRobot],
    relay: RadioRelay,
    updating: _Updating | None,
    seconds: float,
) -> dict:
    states: dict[str, object] = {}
    errors: list[dict[str, object]] = []
    nodes: dict[str, dict[str, Any]] = {}
    not_finished: list[int] = []
    in_failsafe: list[int] = []
    for r in robots:
        path = r.out / "summary.json"
        node: dict[str, Any] = {}
        try:
            node = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            lines = r.output.lines if r.output is not None else []
            tail = "\n".join(lines[-20:])[-2000:]
            errors.append({"robot": r.id, "error": f"node did not finish: {tail.strip()}"})
            not_finished.append(r.id)
        states[str(r.id)] = node.get("final_state")
        for e in node.get("errors", []):
            errors.append({"robot": r.id, "error": e})
        if node.get("errors"):  # the node's errors are its script's: it ended in its failsafe
            in_failsafe.append(r.id)
        nodes[str(r.id)] = node
    summary = {
        "robots": cfg.robots,
        "profiles": {str(r.id): r.profile.name for r in robots},
        "seconds": seconds,
        "drop": cfg.drop,
        "home": list(cfg.home),
        "globals": dict(cfg.sets),
        "final_states": states,
        "not_finished": not_finished,
        "in_failsafe": in_failsafe,
        "bytes_sent_per_robot": {str(r.id): r.bytes_sent for r in robots},
        "relay": dict(relay.stats),
        "errors": errors,
        "script_versions": {k: n.get("script_version") for k, n in nodes.items()},
        "update": updating.summary(nodes) if updating is not None else None,
        "security": _security(cfg, nodes),
        "nodes": nodes,
    }
    if relay.live is not None:
        summary["ground"] = _ground_summary(relay.live)
    write_json(cfg.out / "summary.json", summary)
    return summary
