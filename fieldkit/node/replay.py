"""Replay a recorded flight into a fresh node through a loopback serial, and compare.

`replay(flight)` stands a new `Node` up exactly as the recorded one was (profile, script,
seed, globals, commands, home, start time) with its autopilot link on a real pseudo-terminal
pair: the replay writes the recorded autopilot bytes into the master end, tick by tick, and
the node reads them through pyserial as it would a UART. Its radio hands in the recorded
frames of each tick, its clock gives each tick's recorded time (`TickClock`), and then the
replay compares what the node did with what was recorded:

    autopilot   every MAVLink message the node wrote, decoded, field by field
    radio       every frame sent, byte for byte
    state       the script-state digest after each tick (and BVMSTATE)

and stops at the first divergence. What it takes for a node to replay exactly (docs/replay.md):
one clock reading per tick, seeds from the recording, the same start-up bytes, and the
autopilot core's clock readings at the start of the loop (`AutopilotCore.time_state`),
restored after the start-up bytes are fed. The start-up's own
writes (stream requests, heartbeats while waiting) are not compared: how many there are
depends on how long the vehicle took to answer.
"""

from __future__ import annotations

import fcntl
import os
import struct
import tempfile
import termios
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import bvm
from fieldkit.node.autopilot_port import vehicle_port
from fieldkit.node.clock import TickClock
from fieldkit.node.node import Node
from fieldkit.node.outbox import RecordedOutbox
from fieldkit.node.startup import start_vehicle
from fieldkit.record.compare import (
    Decoder,
    Divergence,
    ReplayError,
    ReplayReport,
    clearpath_frames,
    compare_tick,
    dji_frames,
    mavlink_messages,
)
from fieldkit.record.flight import Flight, FlightRecorder, FlightTick
from fieldkit.record.restore import recorded_profile, recorded_security
from fieldkit.robot.link_security import LinkSecurity
from fieldkit.robot.operator_command import CommandGate
from fieldkit.robot.profiles import Profile
from fieldkit.robot.rc import RcCommand
from fieldkit.update.keys import RobotKeys
from fieldkit.update.release import Release
from fieldkit.update.store import VersionStore
from fieldkit.vehicle.autopilot import AutopilotError
from fieldkit.vehicle.links import VehicleLink, open_link
from fieldkit.vehicle.pty import PtyPair, open_pty

#: How long (real seconds) to wait for bytes written into the pty to reach the node's end.
DELIVERY_TIMEOUT_S = 10.0

#: What a tick's last part fed to the node may hold. A pty's line discipline holds at most
#: 4095 unread bytes (N_TTY's buffer) whatever is written: a tick that read more (a loaded
#: machine reads seconds of telemetry at once) is fed in two parts, the first polled through
#: the link at the tick's time before the node's own poll reads the rest.
LINE_QUEUE_BYTES = 2048


class ReplayClock(TickClock):
    """A TickClock whose ticks begin at the recorded times; between ticks it stands at the
    last of them (the start-up reads `before`)."""

    def __init__(self, before: float) -> None:
        super().__init__(lambda: self._at, lambda: self._unix)
        self._at = before
        self._unix = 0
        self._next: tuple[float, int] | None = None

    def set_next(self, clock_s: float, unix_ns: int) -> None:
        """The time of the tick about to begin."""
        self._next = (clock_s, unix_ns)

    def begin_tick(self) -> float:
        """Begin the tick at its recorded time."""
        if self._next is not None:
            self._at, self._unix = self._next
            self._next = None
        return super().begin_tick()


class ReplayRadio:
    """The node's radio in a replay: hands in each tick's recorded frames, keeps what is sent."""

    def __init__(self) -> None:
        self.inbox: list[tuple[int, bytes]] = []
        self.sent: list[bytes] = []
        self.stats: Counter[str] = Counter()

    def poll(self) -> list[tuple[int, bytes]]:
        """This tick's recorded frames."""
        frames, self.inbox = self.inbox, []
        return frames

    def send(self, data: bytes) -> None:
        """A frame the node sends (the recorder keeps it for the comparison)."""
        self.sent.append(bytes(data))

    def close(self) -> None:
        """Nothing to close."""


def _in_queue(fd: int) -> int:
    """Bytes waiting to be read on a tty descriptor (TIOCINQ)."""
    return int(struct.unpack("i", fcntl.ioctl(fd, termios.TIOCINQ, b"\0\0\0\0"))[0])


class _Line:
    """The replay's end of the loopback serial: writes the recorded bytes, drains the node's."""

    def __init__(self, master: int, slave_fd: int) -> None:
        self.master = master
        self.slave_fd = slave_fd

    def feed(self, chunks: Sequence[bytes]) -> int:
        """Write `chunks` into the line and wait until the node's end holds them all."""
        total = 0
        for chunk in chunks:
            view = memoryview(chunk)
            while view:
                try:
                    n = os.write(self.master, view)
                except BlockingIOError:
                    self.drain()
                    time.sleep(0.001)
                    continue
                view = view[n:]
                total += n
        return total

    def wait_delivered(self, expected: int) -> bool:
        """Whether the node's end holds `expected` unread bytes (waiting for the kernel)."""
        deadline = time.monotonic() + DELIVERY_TIMEOUT_S
        while _in_queue(self.slave_fd) < expected:
            if time.monotonic() > deadline:
                return False
            self.drain()
            time.sleep(0.0005)
        return True

    def drain(self) -> None:
        """Read and drop what the node wrote (the recorder's tap has it already)."""
        while True:
            try:
                if not os.read(self.master, 65536):
                    return
            except (BlockingIOError, OSError):
                return


def split_for_line(chunks: Sequence[bytes], limit: int) -> tuple[list[bytes], list[bytes]]:
    """`chunks` as (head, rest): `rest` their last `limit` bytes at most, `head` the others
    (empty when all fit), so that `rest` fits the loopback serial's queue whole."""
    rest: list[bytes] = []
    room = limit
    for i in range(len(chunks) - 1, -1, -1):
        chunk = chunks[i]
        if len(chunk) <= room:
            rest.insert(0, chunk)
            room -= len(chunk)
            continue
        head = list(chunks[:i])
        cut = len(chunk) - room
        if cut:
            head.append(chunk[:cut])
        if room:
            rest.insert(0, chunk[cut:])
        return head, rest
    return [], rest


def plan_feeds(lines: Sequence[Sequence[bytes]], limit: int) -> list[list[list[bytes]]]:
    """One tick's bytes for several loopback lines (`lines[i]`: line i's chunks) as the polls
    that read them: each poll a list of chunks per line, at most `limit` bytes on each; the
    last poll is the node's own, the others are read first at the tick's time. A poll reads
    its lines in order, as the link does (a Husky reads its MCU, then its GPS), so every byte
    of a line is read after every earlier line's byte of the same tick, as in the flight."""
    final: list[list[bytes]] = [[] for _ in lines]
    for i in range(len(lines) - 1, -1, -1):
        head, final[i] = split_for_line(lines[i], limit)
        if head:
            earlier = [list(c) for c in lines[:i]] + [head] + [[] for _ in lines[i + 1 :]]
            return [*plan_feeds(earlier, limit), final]
    return [final]


def tap_link(link: VehicleLink, recorder: FlightRecorder) -> None:
    """Point every tap `link` has at `recorder`: the autopilot's bytes both ways, a separate
    GPS receiver's (a Clearpath base), the times its own thread sent (the DJI stream)."""
    link.on_rx, link.on_tx = recorder.autopilot_rx, recorder.autopilot_tx
    if hasattr(link, "on_gps_rx"):
        link.on_gps_rx = recorder.gps_rx
    if hasattr(link, "on_stream"):
        link.on_stream = recorder.stream_sent


def _link_meta(node: Node, link: VehicleLink) -> dict[str, object]:
    """What a replay must know of the link: its flavour; for an M100 the app id and the app
    key's fingerprint (never the key), and whether a thread streamed movement control."""
    out: dict[str, object] = {"flavour": node.profile.autopilot.flavour}
    core = getattr(link, "core", None)
    fingerprint = getattr(core, "key_fingerprint", None)
    if out["flavour"] == "dji" and isinstance(fingerprint, str):
        out["dji"] = {
            "app_id": int(getattr(core, "app_id", 0)),
            "key_fingerprint": fingerprint,
            "stream_thread": getattr(link, "_thread", None) is not None,
        }
    return out


def recording_meta(
    node: Node,
    link: VehicleLink,
    *,
    script_name: str,
    seed: int,
    globals_: dict[str, object],
    commands: Sequence[RcCommand],
) -> dict[str, object]:
    """What a recording's meta must hold for `replay` (call it after the node is built and
    before its first tick): the node's identity and options, its home and start time, and
    the autopilot core's clock readings as the loop begins."""
    frame = node.frame
    return (
        {
            "robot_id": node.robot_id,
            "seed": seed,
            "script_name": script_name,
            "globals": dict(globals_),
            "commands": [c.text() for c in commands],
            "home": [frame.lat, frame.lon, frame.alt],
            "started_s": node.started,
            "core_time": link.time_state(),
            "loop_rate_hz": node.profile.node.loop_rate_hz,
            "radio": node.radio is not None,
            "started_unix_ns": node.tick_clock.wall(),
        }
        | ({} if node.outbox is None else {"update_outbox": node.outbox.name})
        | _security_meta(node)
        | _update_meta(node)
        | _link_meta(node, link)
    )


def _update_meta(node: Node) -> dict[str, object]:
    """The version store's state a replay starts from (a node with --state-dir and keys)."""
    store = node.store
    if node.updater is None or store is None:
        return {}
    committed = store.current
    assert committed is not None  # an updater needs one
    return {
        "update": {
            "version": committed.version,
            "highest": committed.highest,
            "bad": sorted(committed.bad),
            "previous": len(committed.previous),
            "patches": len(store.patches()),
        }
    }


def _replay_store(meta: dict[str, object], flight: Flight, root: Path) -> VersionStore | None:
    """A version store in `root` holding what the recorded node's held when its loop began
    (a store of one version: one seeded, or updated to before the flight began)."""
    update = meta.get("update")
    if not isinstance(update, dict):
        return None
    version = int(update.get("version", 0))
    if (
        update.get("previous")
        or update.get("bad")
        or update.get("patches")
        or (int(update.get("highest", version)) != version)
    ):
        raise ReplayError(
            "the recorded node's version store held earlier versions, rolled-back ones or "
            "patches when the flight began: replaying such a store is not built yet"
        )
    store = VersionStore(root)
    store.commit(version, store.put(Release(flight.bo, flight.bdb, flight.bpos)),
                 reason="the recorded version, for a replay")  # fmt: skip
    return store


def _security_meta(node: Node) -> dict[str, object]:
    """The security state a replay starts from: the mode, the key's fingerprint (never the
    key), the next counter, the neighbours' floors, the last operator command acted on."""
    runtime = node.runtime
    security = runtime.security
    out: dict[str, object] = {"security": None if security is None else security.mode}
    if security is not None and security.signed:
        assert security.sealer is not None and security.verifier is not None
        out["key_fingerprint"] = security.sealer.key.fingerprint
        out["counter_start"] = getattr(security.sealer.counters, "upcoming", 1)
        out["floors"] = {str(s): c for s, c in security.verifier.floors().items()}
    if runtime.commands is not None:
        out["command_last_acted"] = runtime.commands.last_acted
    return out


def replay(
    flight: Flight,
    *,
    program: bvm.Program | None = None,
    profile: Profile | None = None,
    keys: RobotKeys | None = None,
    verify: bool = True,
    robot_id: int | None = None,
    speed: float | None = None,
    progress: Callable[[int, int], None] | None = None,
    dji_app_key: str | None = None,
    dji_app_id: int | None = None,
) -> ReplayReport:
    """Replay `flight` into a fresh node and, if `verify`, compare tick by tick.

    `program` replaces the recorded script (the regression test of a change), `profile` the
    recorded profile; `keys` are the robot's, for a signed flight; `dji_app_key` is the M100's
    app key (never in a recording: the node config's), `dji_app_id` its app id if not the
    recorded one; `speed` paces the ticks at that many times the recorded pace (None: as
    fast as they go). A flight without node outputs (an autopilot log converted to a bag)
    replays without `verify`, given a `program` and a `profile`: the node starts once the
    log has given it a heartbeat and a position, and the report keeps what it did
    (`replayed`). ReplayError if the flight lacks what this needs."""
    meta = flight.meta
    node_flight = "core_time" in meta
    if verify and not node_flight:
        raise ReplayError(
            "the bag holds no node outputs to compare (an autopilot log?)\n"
            "hint: replay it without --verify, with --script FILE.bzz and --profile NAME"
        )
    if profile is None:
        if not flight.profile_toml:
            raise ReplayError("the bag holds no device profile\nhint: give --profile NAME")
        profile = recorded_profile(flight.profile_toml)
    if program is None:
        if not flight.bo:
            raise ReplayError("the bag holds no script\nhint: give --script FILE.bzz")
        program = Release(flight.bo, flight.bdb, flight.bpos).program(
            str(meta.get("script_name", "<recorded>"))
        )
    try:
        rid = int(meta.get("robot_id", 1) if robot_id is None else robot_id)  # type: ignore[call-overload]
        seed = int(meta.get("seed", 0))  # type: ignore[call-overload]
        globals_ = dict(meta.get("globals", {}))  # type: ignore[call-overload]
        commands = [RcCommand.parse(str(c)) for c in meta.get("commands", [])]  # type: ignore[attr-defined]
        start = _Start.of(meta) if node_flight else None
    except (KeyError, TypeError, ValueError) as e:
        raise ReplayError(f"the recording's meta lacks what a replay needs: {e}") from None
    dji = _dji_app(profile, meta, dji_app_key, dji_app_id)
    security, gate = recorded_security(meta, rid, keys)
    first = flight.ticks[0].clock_s if flight.ticks else 0.0
    clock = ReplayClock(before=first if start is None else start.started_s)
    with tempfile.TemporaryDirectory() as state:
        store = _replay_store(meta, flight, Path(state))
        if store is not None and keys is None:
            raise ReplayError("the recorded node took over-the-air updates: give --keys DIR")
        return _replay(flight, profile, program, rid, seed, globals_, commands, start,
                       security, gate, clock, verify, speed, progress, store, keys,
                       dji)  # fmt: skip


def _dji_app(
    profile: Profile, meta: dict[str, object], key: str | None, app_id: int | None
) -> tuple[int, str] | None:
    """An M100's (app id, app key) for the replay: the key given (checked against the
    recorded fingerprint), the recorded app id unless another is given."""
    if profile.autopilot.flavour != "dji":
        return None
    recorded = meta.get("dji")
    info: dict[str, object] = dict(recorded) if isinstance(recorded, dict) else {}
    if key is None:
        raise ReplayError(
            "an M100's flight replays with its app key, which the recording never holds\n"
            "hint: give --config FILE (the node config's [dji] table) or --dji-app-key-file FILE"
        )
    from fieldkit.vehicle.dji.core import app_key_fingerprint
    from fieldkit.vehicle.dji.crypto import AppKeyError

    try:
        fingerprint = app_key_fingerprint(key)
    except AppKeyError as e:
        raise ReplayError(f"the DJI app key given: {e}") from None
    want = info.get("key_fingerprint")
    if want is not None and want != fingerprint:
        raise ReplayError(
            f"the flight's M100 was activated with app key {want}; the key given is "
            f"{fingerprint}\nhint: give the node config the robot flew with"
        )
    ident = app_id if app_id is not None else info.get("app_id")
    if not isinstance(ident, int) or ident <= 0:
        raise ReplayError("the recording names no DJI app id\nhint: give --config FILE")
    return ident, key


def _decoder(profile: Profile, dji: tuple[int, str] | None) -> Decoder:
    """How the autopilot's bytes of this flavour are compared: messages, field by field."""
    flavour = profile.autopilot.flavour
    if flavour == "dji":
        assert dji is not None
        return dji_frames(dji[1])
    if flavour == "clearpath":
        return clearpath_frames
    return mavlink_messages


def _replay(
    flight: Flight,
    profile: Profile,
    program: bvm.Program,
    rid: int,
    seed: int,
    globals_: dict[str, object],
    commands: list[RcCommand],
    start: _Start | None,
    security: LinkSecurity | None,
    gate: CommandGate | None,
    clock: ReplayClock,
    verify: bool,
    speed: float | None,
    progress: Callable[[int, int], None] | None,
    store: VersionStore | None,
    keys: RobotKeys | None,
    dji: tuple[int, str] | None,
) -> ReplayReport:
    meta = flight.meta
    clearpath = profile.autopilot.flavour == "clearpath"
    ptys: list[PtyPair] = []
    try:
        # The autopilot's line, and a GPS receiver's of its own (a Clearpath base's).
        for _ in range(2 if clearpath else 1):
            ptys.append(open_pty())
        try:
            link = open_link(
                profile,
                ptys[0].slave_path,
                gps=ptys[1].slave_path if clearpath else None,
                clock=clock.now,
                dji_app_id=None if dji is None else dji[0],
                dji_app_key=None if dji is None else dji[1],
                dji_stream_thread=False,  # its recorded sends are made again, at their times
            )
        except AutopilotError as e:
            raise ReplayError(f"cannot open the replay's link: {e}") from None
        if hasattr(link, "release_on_close"):
            link.release_on_close = False  # a replay has no aircraft to hand back
        try:
            lines = [_Line(p.master, p.slave_fd) for p in ptys]
            run = _Replay(flight, link, lines, clock, verify, _decoder(profile, dji), profile)
            ticks = run.start(start)
            outbox = _recorded_outbox(flight, ticks)
            if outbox is not None and store is None:
                raise ReplayError(
                    "the recorded node read patches from its outbox, but the recording says "
                    "nothing of its version store: it cannot be replayed"
                )
            node = Node(
                profile,
                program,
                rid,
                vehicle_port(link, run.home),
                run.radio if meta.get("radio", True) else None,
                home=run.home,
                commands=commands,
                clock=clock,
                out=lambda _line: None,
                seed=seed,
                globals_=globals_,
                recorder=run.recorder,
                security=security,
                command_gate=gate,
                store=store,
                keys=keys if store is not None else None,
                outbox=outbox,
            )
            return run.ticks(node, ticks, speed, progress)
        finally:
            link.close()
    finally:
        for p in ptys:
            p.close()


def _recorded_outbox(flight: Flight, ticks: list[FlightTick]) -> RecordedOutbox | None:
    """The patches the recorded node read from its outbox, by tick (None: it read none)."""
    patches = {t.tick: t.outbox for t in ticks if t.outbox}
    if not patches:
        return None
    return RecordedOutbox(patches, str(flight.meta.get("update_outbox", "the recorded outbox")))


@dataclass(frozen=True)
class _Start:
    """Where a recorded node's loop began: its home, its start time, its core's clocks."""

    home: tuple[float, float, float]
    started_s: float
    core_time: dict[str, object]

    @classmethod
    def of(cls, meta: dict[str, object]) -> _Start:
        """From a recording's meta (KeyError, TypeError, ValueError if it lacks them)."""
        lat, lon, alt = (float(x) for x in meta["home"])  # type: ignore[attr-defined]
        return cls((lat, lon, alt), float(meta["started_s"]), dict(meta["core_time"]))  # type: ignore[arg-type, call-overload]


class _StartupOver(AutopilotError):
    """The recorded start-up bytes are all in, and a start-up wait still waits."""


class _Replay:
    """One replay's moving parts: the lines, the radio, the recorder of what the node does."""

    def __init__(
        self,
        flight: Flight,
        link: VehicleLink,
        lines: list[_Line],
        clock: ReplayClock,
        verify: bool,
        decode: Decoder,
        profile: Profile,
    ) -> None:
        self.flight = flight
        self.profile = profile
        self.link = link
        self.lines = lines
        self.clock = clock
        self.verify = verify
        self.decode = decode
        self.radio = ReplayRadio()
        self.done: list[FlightTick] = []
        self.recorder = FlightRecorder(
            Flight(meta={}, profile_toml="", bo=b""), keep=False, on_tick=self.done.append
        )
        self.home = (0.0, 0.0, 0.0)
        self.consumed = 0
        tap_link(link, self.recorder)
        rx, gps = self.recorder.autopilot_rx, self.recorder.gps_rx
        link.on_rx = lambda data: self._count(rx, data)
        if hasattr(link, "on_gps_rx"):
            link.on_gps_rx = lambda data: self._count(gps, data)

    def _count(self, tap: Callable[[bytes], None], data: bytes) -> None:
        self.consumed += len(data)
        tap(data)

    def _drain(self) -> None:
        for line in self.lines:
            line.drain()

    def _feed(self, parts: Sequence[Sequence[bytes]]) -> int:
        """Write each line's part and wait until the node's ends hold them all; the bytes."""
        total = 0
        for line, chunks in zip(self.lines, parts, strict=False):
            want = line.feed(chunks)
            if not line.wait_delivered(want):
                raise ReplayError("the recorded bytes did not come through the loopback serial")
            total += want
        return total

    def _read_all(self, expected: int, what: str) -> None:
        """Poll the link until it has read `expected` bytes fed since the count was reset."""
        deadline = time.monotonic() + DELIVERY_TIMEOUT_S
        while self.consumed < expected:
            self.link.poll(0.01)
            self._drain()
            if time.monotonic() > deadline:
                raise ReplayError(
                    f"{what}: the recorded autopilot bytes did not come through the loopback "
                    f"serial ({self.consumed} of {expected} in {DELIVERY_TIMEOUT_S:g} s)"
                )

    def _poll_fed(self, parts: Sequence[Sequence[bytes]], what: str) -> None:
        """Feed `parts` (one list of chunks per line) and poll until the link read them."""
        self.consumed = 0
        self._read_all(self._feed(parts), what)

    def _pre_read(self, tick: FlightTick, head: Sequence[Sequence[bytes]]) -> None:
        """Poll `head`, a tick's first bytes, through the link at the tick's recorded time:
        what the node's own poll in that tick would have done with them first."""
        self.recorder.started = True  # what it reads and writes now belongs to the tick
        self.clock.set_next(tick.clock_s, tick.unix_ns)
        self.clock.begin_tick()
        try:
            self._poll_fed(head, f"tick {tick.tick}")
        finally:
            self.clock.end_tick()

    def _inputs(self, tick: FlightTick) -> list[list[bytes]]:
        """A tick's bytes per line: the autopilot's, then a GPS receiver's of its own."""
        return [tick.autopilot_rx, tick.gps_rx][: len(self.lines)]

    def start(self, start: _Start | None) -> list[FlightTick]:
        """Feed the start-up; the ticks left for the node. A recorded node's start-up is its
        own, then its core's clock readings; an autopilot log's runs until the vehicle has
        given a heartbeat and a position (those ticks are not the node's)."""
        link, flight = self.link, self.flight
        if start is not None:
            self._startup(flight)
            link.drain_events()
            link.set_time_state(start.core_time)
            self.home = start.home
            self.recorder.started = True  # what the link sends from now is the ticks'
            return flight.ticks
        for k, tick in enumerate(flight.ticks):
            t = link.telemetry
            if t.last_heartbeat is not None and t.lat is not None and t.lon is not None:
                self.home = (t.lat, t.lon, 0.0)
                link.drain_events()
                self.recorder.started = True  # what follows belongs to the node's ticks
                return flight.ticks[k:]
            self.clock.set_next(tick.clock_s, tick.unix_ns)
            self.clock.begin_tick()
            try:
                self.consumed = 0
                fed = zip(self.lines, self._inputs(tick), strict=True)
                total = sum(line.feed(chunks) for line, chunks in fed)
                self._read_all(total, f"tick {tick.tick}")
            finally:
                self.clock.end_tick()
        raise ReplayError("the autopilot log never gives a heartbeat and a GPS position")

    def _startup(self, flight: Flight) -> None:
        """The node's own start-up (`start_vehicle`) on the recorded start-up bytes: each
        time one of its waits would wait, the next recorded read of each line comes in. So
        the link sends what the recorded node sent, in the same order, and a core whose
        answers match by sequence number (an M100's activation and authority) has sent each
        request before its answer arrives. Reads left over are fed after it."""
        queues = [list(flight.startup_rx), list(flight.startup_gps_rx)][: len(self.lines)]
        fed = [0]  # bytes handed in by the last idle() and not yet read

        def idle() -> None:
            parts = [[q.pop(0)] if q else [] for q in queues]
            if not any(parts):
                raise _StartupOver("the recorded start-up bytes ran out")
            self.consumed = 0
            fed[0] = self._feed(parts)

        try:
            start_vehicle(self.link, self.profile, 30.0, lambda _line: None, idle=idle,
                          poll_interval=0.0)  # fmt: skip
        except AutopilotError as e:
            raise ReplayError(
                f"start-up: the recorded node's start-up does not replay on its bytes ({e})"
            ) from None
        self._read_all(fed[0], "start-up")
        while any(queues):
            self._poll_fed([[q.pop(0)] if q else [] for q in queues], "start-up")
        self.link.poll(0.0)
        self._drain()

    def _stream(self, tick: FlightTick) -> None:
        """The frames the recorded link's thread sent before this tick, sent again at their
        recorded times (the link's own `stream_at`; its thread is off in a replay)."""
        if not tick.stream_s:
            return
        stream_at = getattr(self.link, "stream_at", None)
        if stream_at is None:
            raise ReplayError(
                f"tick {tick.tick}: the recording holds sends of a link thread this "
                f"flavour's link does not have"
            )
        for at in tick.stream_s:
            stream_at(at)  # none due: the comparison finds the frame missing

    def ticks(
        self,
        node: Node,
        ticks: list[FlightTick],
        speed: float | None,
        progress: Callable[[int, int], None] | None,
    ) -> ReplayReport:
        """Run the node through `ticks`; compare each with the recording if verifying."""
        report = ReplayReport()
        clock = self.clock
        wall0 = time.monotonic()
        for n, tick in enumerate(ticks):
            if speed is not None and n:
                ahead = (tick.clock_s - ticks[0].clock_s) / speed - (time.monotonic() - wall0)
                if ahead > 0:
                    time.sleep(ahead)
            self.radio.inbox = list(tick.radio_in)
            self._stream(tick)
            *heads, last = plan_feeds(self._inputs(tick), LINE_QUEUE_BYTES)
            for head in heads:
                self._pre_read(tick, head)
            try:
                self._feed(last)
            except ReplayError:
                raise ReplayError(
                    f"tick {tick.tick}: the recorded autopilot bytes did not arrive"
                ) from None
            clock.set_next(tick.clock_s, tick.unix_ns)
            node.tick()
            self._drain()
            report.ticks += 1
            mine = self.done.pop()
            if self.verify:
                report.divergence = compare_tick(tick, mine, report, self.decode)
                if report.divergence is not None:
                    break
            else:
                report.replayed.append(mine)
            if progress is not None:
                progress(n + 1, len(ticks))
        return report


__all__ = [
    "Divergence",
    "recording_meta",
    "ReplayClock",
    "ReplayError",
    "ReplayRadio",
    "ReplayReport",
    "plan_feeds",
    "replay",
    "split_for_line",
    "tap_link",
]
