"""One simulated swarm stepped across processes or machines, bit for bit as in one process.

`sim run --workers N` (local processes) and `--scheduler ADDRESS` (a Dask cluster) split the
robots of ONE swarm into parts, each stepped by a worker, while a coordinator (the process
that runs the command) keeps everything whose order decides a seeded run:

* the radio (`RadioModel`): one `random.Random(seed)` drawn in the order of the broadcasts,
  so every broadcast is made here, in robot-id order, exactly as `Simulation.step` makes them;
* the log and the script errors, merged in (tick, robot id) order;
* the operator's commands of each tick, the bundle figures, `summary.json`.

A worker owns the robots of its part: their runtimes (VM, supervisor, heard table) and
vehicles, built with the same seeds as in one process (`_Part` is a `Simulation` of just
those robots, so every line of a robot's tick is the one-process code). The parts are blocks
of the start grid (`partition`): a robot hears mostly robots of its own block, so most
bundles go back to one worker only.

What crosses a process boundary, per tick and per worker, in one round trip:

* to the worker: the tick, the commands due for its robots, and the broadcasts due with only
  its robots among the receivers (sender, sender's position, the messages the bundle holds,
  its seal counter; the bundle's bytes only where a receiver must parse them: an operator's
  command frame passed on, or `decode_bundles`);
* back: per robot in id order, the bundle it sent (bytes, messages, counter) and its position
  after moving (the next tick's radio geometry); and, only where there are any, its log lines,
  a new script error, the frames it relays, a changed BVMSTATE.

The coordinator builds the next tick's k-d tree of hearers while the workers step, so the
serial part of a tick is the loss draws and bookkeeping of the broadcasts and the (un)pickling.
Neither `--ground`, `--record`, `--update` nor `--attack` is split this way (each watches or
alters every robot's radio inside the tick); `sim run` refuses them with `--workers`.
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import signal
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, cast

import bvm
from fieldkit.errors import FieldkitError
from fieldkit.robot import geo
from fieldkit.robot.rc import RcCommand
from fieldkit.sim.radio import RadioModel, Reception
from fieldkit.sim.simulator import (
    TICK_S,
    BundleTally,
    SimConfig,
    SimRobot,
    Simulation,
    StartPose,
    log_line,
    run_ticks,
    sim_line,
    start_grid,
    tuned_memory,
)
from fieldkit.update.release import Release

if TYPE_CHECKING:
    from multiprocessing.connection import Connection

    from dask.distributed import Client


#: How long closing waits for the local workers to stop on their own, all together, before
#: killing them (a second Ctrl-C must not wait this long per worker).
CLOSE_GRACE_S = 5.0


class DistributedError(FieldkitError, RuntimeError):
    """A worker could not be started or reached, or failed."""


# ------------------------------------------------------------------ the parts


def partition(where: dict[int, tuple[float, float]], parts: int) -> list[list[int]]:
    """Split the robots into `parts` blocks of the plane of nearly equal size: columns by
    east, then rows by north within each column; each block's ids sorted. Neighbours on the
    ground are mostly in one block, so a bundle goes to few workers."""
    ids = sorted(where, key=lambda rid: (where[rid][0], rid))
    cols = max(1, round(math.sqrt(parts)))
    while parts % cols:
        cols -= 1  # a grid of cols x rows blocks, as square as `parts` allows
    rows = parts // cols
    blocks: list[list[int]] = []
    for c in range(cols):
        column = ids[len(ids) * c // cols : len(ids) * (c + 1) // cols]
        column.sort(key=lambda rid: (where[rid][1], rid))
        for r in range(rows):
            blocks.append(sorted(column[len(column) * r // rows : len(column) * (r + 1) // rows]))
    return blocks


#: A robot's turn as the coordinator replays it: (log lines, new error or None, relays).
Extra = tuple[list[str], dict[str, object] | None, list[bytes]]


@dataclass
class PartTick:
    """What a part's robots did in one tick, in the part's id order (see the module doc)."""

    sends: list[tuple[bytes, tuple[bytes, ...], int]]  # (bundle, its messages, seal counter)
    positions: list[tuple[float, float, float]]
    extras: dict[int, Extra]  # only robots that logged, failed or relay something
    states: dict[int, str | None]  # only robots whose BVMSTATE changed
    cpu_s: float = 0.0  # the worker's CPU time for the tick (not its transport)


@dataclass
class PartEnd:
    """A part's robots at the end of a run: what `summary.json` needs of them."""

    states: dict[int, str | None]
    in_failsafe: list[int]
    security: dict[str, Any]


class _Part(Simulation):
    """A `Simulation` of some robots of a swarm: it steps them exactly as the whole swarm's
    simulation would, but sends nothing itself; what they send goes back to the coordinator."""

    def __init__(self, config: SimConfig) -> None:
        self._turn: list[str] = []  # the current robot's log lines
        self._lines: dict[int, list[str]] = {}
        self._sent: list[tuple[bytes, tuple[bytes, ...], int]] = []
        self._relays: dict[int, list[bytes]] = {}
        super().__init__(config)

    def _sink(self, rid: int) -> Callable[[str], None]:
        prefix = f"[{rid}] "  # as Simulation._sink: the line names the robot already

        def sink(text: str) -> None:
            if text.startswith(prefix):
                text = text[len(prefix) :]
            self._lines.setdefault(rid, []).append(log_line(self.tick * TICK_S, rid, text))

        return sink

    def _send(self, robot: SimRobot, data: bytes, messages: tuple[bytes, ...]) -> None:
        security = robot.runtime.security
        self._sent.append((data, messages, 0 if security is None else security.last_counter))

    def _relay(self, t: int, rid: int, frame: bytes) -> None:
        self._relays.setdefault(rid, []).append(frame)

    def take(self, errors_from: int) -> tuple[dict[int, Extra], list[dict[str, object]]]:
        """The log lines, errors (from index `errors_from`) and relays since the last take."""
        errors = self.errors[errors_from:]
        by_robot = {cast(int, e["robot"]): e for e in errors}
        extras: dict[int, Extra] = {}
        for rid in sorted(set(self._lines) | set(by_robot) | set(self._relays)):
            extras[rid] = (self._lines.get(rid, []), by_robot.get(rid), self._relays.get(rid, []))
        self._lines = {}
        self._relays = {}
        return extras, errors


class SwarmPart:
    """The worker side: the robots of one part, stepped a tick at a time on request."""

    def __init__(self, config: SimConfig, operator_pub: bytes | None) -> None:
        """`config` holds only this part's robots (`start`); `operator_pub` the operator's
        raw public key (key objects do not pickle)."""
        if operator_pub is not None:
            from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

            config = dataclasses.replace(
                config, operator_pub=Ed25519PublicKey.from_public_bytes(operator_pub)
            )
        self.sim = _Part(config)
        self.ids = list(self.sim.robots)
        self._states: dict[int, str | None] = {rid: None for rid in self.ids}
        self._errors = 0

    def started(self) -> PartTick:
        """What the robots did starting (global code and init()): as a tick's result."""
        return self._result()

    def step(self, t: int, receptions: list[Reception], rcs: dict[int, RcCommand]) -> PartTick:
        """Tick `t` for the part's robots: radio in, neighbours, each robot's turn."""
        cpu = time.process_time()
        sim = self.sim
        if sim.tick != t:
            raise RuntimeError(f"part at tick {sim.tick} asked for tick {t}")
        with tuned_memory():
            sim._radio_in(t, receptions)
            neighbors = sim._neighbors(t)
            sim._step_robots(t, rcs, neighbors)
        sim.tick += 1
        result = self._result()
        result.cpu_s = time.process_time() - cpu
        return result

    def _result(self) -> PartTick:
        sim = self.sim
        extras, errors = sim.take(self._errors)
        self._errors += len(errors)
        sends, sim._sent = sim._sent, []
        changed = {}
        last = self._states
        for rid, robot in sim.robots.items():
            state = robot.runtime.state
            if state != last[rid]:
                changed[rid] = last[rid] = state
        return PartTick(
            sends,
            [r.vehicle.position for r in sim.robots.values()],
            extras,
            changed,
        )

    def kill(self, rid: int) -> None:
        """Take robot `rid` of this part out of the swarm between two ticks (`Simulation.kill`)."""
        self.sim.kill(rid)
        self.ids.remove(rid)
        del self._states[rid]

    def finish(self) -> PartEnd:
        """The part's robots now: final states, those in their failsafe, security counters."""
        sim = self.sim
        return PartEnd(
            {rid: r.state for rid, r in sim.robots.items()},
            sim.in_failsafe(),
            cast(dict[str, Any], sim.security_summary()["security"]),
        )


# ------------------------------------------------------------------ the transports


class _Worker(Protocol):
    """One worker holding one `SwarmPart`: a call is sent, its answer collected later."""

    def call(self, method: str, *args: object) -> None:
        """Ask the part to run `method(*args)` (no answer yet)."""

    def result(self) -> Any:
        """The answer to the last call (DistributedError if the part failed)."""

    def stop(self) -> None:
        """Ask the worker to stop, without waiting (safe to call twice)."""

    def close(self, deadline: float) -> None:
        """Stop the worker, by `deadline` (time.monotonic) at the latest (safe twice)."""


def _serve(conn: Connection) -> None:
    """A local worker process: build the part, then answer calls until told to stop."""
    # A Ctrl-C at the terminal reaches the whole process group: the coordinator decides
    # what it means (the run ends between two ticks), the worker keeps answering.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    part: SwarmPart | None = None
    while True:
        try:
            method, args = conn.recv()
        except EOFError:
            return
        if method == "close":
            return
        try:
            if method == "init":
                part = SwarmPart(*args)
                answer: object = None
            else:
                assert part is not None
                answer = getattr(part, method)(*args)
        except Exception as e:  # the coordinator reports it; the worker must not hang
            conn.send(("error", f"{type(e).__name__}: {e}\n{traceback.format_exc()}"))
        else:
            conn.send(("ok", answer))


class _ProcessWorker:
    """A worker process on this machine, answering over a pipe (pickled messages)."""

    def __init__(self, index: int) -> None:
        # spawn: a fresh interpreter, as a remote worker is; nothing inherited by accident.
        ctx = multiprocessing.get_context("spawn")
        self.index = index
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_serve, args=(child,), daemon=True)
        self.process.start()
        child.close()

    def call(self, method: str, *args: object) -> None:
        try:
            self.conn.send((method, args))
        except (OSError, ValueError) as e:
            raise DistributedError(f"worker {self.index} is gone: {e}") from None

    def result(self) -> Any:
        try:
            status, answer = self.conn.recv()
        except (EOFError, OSError):
            code = self.process.exitcode
            raise DistributedError(f"worker {self.index} died (exit code {code})") from None
        if status != "ok":
            raise DistributedError(f"worker {self.index} failed: {answer}")
        return answer

    def stop(self) -> None:
        if self.process.is_alive() and not self.conn.closed:
            try:
                self.conn.send(("close", ()))
            except (OSError, ValueError):
                pass

    def close(self, deadline: float) -> None:
        # A worker in the middle of a big tick reads "close" only after it: it gets until
        # the deadline, which every worker shares, then it is killed (it holds no results).
        self.stop()
        self.process.join(max(0.0, deadline - time.monotonic()))
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.conn.close()


class _DaskWorker:
    """A part held by a Dask actor on one worker of a cluster (calls go worker to client)."""

    def __init__(self, index: int, client: Client, address: str | None) -> None:
        self.index = index
        self.client = client
        self.address = address
        self.actor: Any = None
        self._pending: Any = None

    def call(self, method: str, *args: object) -> None:
        if method == "init":
            where = None if self.address is None else [self.address]
            self._pending = self.client.submit(
                SwarmPart, *args, actor=True, workers=where, pure=False
            )
        else:
            self._pending = getattr(self.actor, method)(*args)

    def result(self) -> Any:
        try:
            answer = self._pending.result()
        except Exception as e:  # whatever the cluster raised: the part's or the network's
            raise DistributedError(f"worker {self.index} failed: {type(e).__name__}: {e}") from e
        if self.actor is None:
            self.actor, answer = answer, None
        return answer

    def stop(self) -> None:
        self.actor = None
        self._pending = None

    def close(self, deadline: float) -> None:
        self.stop()


# ------------------------------------------------------------------ the coordinator


@dataclass(slots=True)
class _Where:
    """A remote robot's vehicle as the coordinator knows it: where it is."""

    x: float
    y: float
    z: float

    @property
    def position(self) -> tuple[float, float, float]:
        """(x east, y north, z up)."""
        return self.x, self.y, self.z


@dataclass(slots=True)
class RemoteRobot:
    """A robot stepped by a worker, as seen from the coordinator (what a recorder samples)."""

    id: int
    vehicle: _Where
    state: str | None = None


@dataclass
class Timings:
    """Where a distributed run's wall time went, seconds: the coordinator's own work, and its
    waits for the workers (their parallel part, plus the transport)."""

    coordinator_s: float = 0.0
    wait_s: float = 0.0
    start_s: float = 0.0
    ticks: int = 0
    # CPU time, which other processes on the machine do not inflate: the coordinator's
    # serial work, and every worker's stepping (their sum: the parallel work).
    coordinator_cpu_s: float = 0.0
    workers_cpu_s: float = 0.0

    def reset(self) -> None:
        """Start counting again (after a warm-up)."""
        self.coordinator_s = self.wait_s = self.coordinator_cpu_s = self.workers_cpu_s = 0.0
        self.ticks = 0


class DistributedSimulation(BundleTally):
    """A `Simulation`'s run (same log, errors, figures, summary) with the robots stepped by
    workers: `workers` local processes, or the workers of the Dask cluster at `scheduler`
    (`workers` parts on it, default one per cluster worker)."""

    def __init__(
        self,
        config: SimConfig,
        *,
        workers: int | None = None,
        scheduler: str | None = None,
        on_log: Callable[[str], None] | None = None,
    ) -> None:
        """Compile, split and start the parts (ConfigError, BuzzCompileError or
        DistributedError: nothing is left running)."""
        config.validate()
        if workers is None and scheduler is None:
            raise ValueError("give workers, scheduler or both")
        program = config.program or bvm.compile_file(
            config.script, include_dirs=tuple(config.include_dirs)
        )
        self.config = config
        self.program = program
        self.on_log = on_log
        self.frame = geo.LocalFrame(*config.origin)
        self.radio = RadioModel(Simulation._link_model(config), seed=config.seed)
        self.tick = 0
        self.log: list[str] = []
        self.errors: list[dict[str, object]] = []
        BundleTally.__init__(self)
        self.timings = Timings()
        self._commands: dict[int, list[RcCommand]] = {}
        for c in config.commands:
            self._commands.setdefault(round(c.t / TICK_S), []).append(c)
        if config.start is not None:
            poses = dict(config.start)
        else:
            poses = {rid: StartPose(x, y) for rid, (x, y) in start_grid(config).items()}
        self.ids = sorted(poses)
        self.robots = {
            rid: RemoteRobot(rid, _Where(poses[rid].east, poses[rid].north, poses[rid].alt))
            for rid in self.ids
        }
        self._client_cm: Any = None
        started = time.perf_counter()
        self._workers: list[_Worker] = []
        try:
            self._workers = self._start_workers(workers, scheduler)
            n = len(self._workers)
            self._check_count(n)
            self.parts = partition({rid: (p.east, p.north) for rid, p in poses.items()}, n)
            self._owner = {rid: k for k, part in enumerate(self.parts) for rid in part}
            pub = config.operator_pub
            raw = None if pub is None else pub.public_bytes_raw()
            for worker, part in zip(self._workers, self.parts, strict=True):
                part_config = dataclasses.replace(
                    config,
                    robots=len(part),
                    start={rid: poses[rid] for rid in part},
                    commands=(),
                    program=program,
                    operator_pub=None,
                )
                worker.call("init", part_config, raw)
            for worker in self._workers:
                worker.result()
            for worker in self._workers:
                worker.call("started")
            self._merge([w.result() for w in self._workers], broadcast=False)
        except BaseException:
            self.close()
            raise
        self.timings.start_s = time.perf_counter() - started

    def _start_workers(self, workers: int | None, scheduler: str | None) -> list[_Worker]:
        if scheduler is None:
            assert workers is not None
            self._check_count(workers)  # before starting any process
            return [_ProcessWorker(k) for k in range(workers)]
        from fieldkit.sim.sweep import SweepError, cluster_client

        self._client_cm = cluster_client(scheduler)
        try:
            client = self._client_cm.__enter__()
        except SweepError as e:
            self._client_cm = None
            raise DistributedError(str(e)) from None
        addresses = sorted(client.scheduler_info()["workers"])
        if not addresses:
            raise DistributedError(f"--scheduler {scheduler}: the cluster has no workers")
        n = len(addresses) if workers is None else workers
        # Round robin: with more parts than cluster workers, some hold two.
        return [_DaskWorker(k, client, addresses[k % len(addresses)]) for k in range(n)]

    def _check_count(self, workers: int) -> None:
        robots = self.config.robots
        if workers > robots:
            raise DistributedError(f"{workers} workers for {robots} robots: at most one each")

    def close(self) -> None:
        """Stop the workers (and leave the cluster); safe to call twice. Every worker is
        asked first, so local ones stop together: at most CLOSE_GRACE_S in all, however
        many (leaving a Dask cluster takes the client's own time-out besides)."""
        deadline = time.monotonic() + CLOSE_GRACE_S
        for worker in self._workers:
            worker.stop()
        for worker in self._workers:
            worker.close(deadline)
        self._workers = []
        if self._client_cm is not None:
            cm, self._client_cm = self._client_cm, None
            cm.__exit__(None, None, None)

    def close_recording(self) -> None:
        """Nothing to close: a distributed run records no bags."""

    # ------------------------------------------------------------ one tick

    def step(self) -> None:
        """Advance every robot by one tick, on the workers."""
        clock = time.perf_counter
        t0 = clock()
        cpu0 = time.process_time()
        t = self.tick
        owner = self._owner
        batches: list[list[Reception]] = [[] for _ in self._workers]
        reparse = self.config.decode_bundles
        for sender, data, pos, receivers, note in self.radio.receptions(t):
            if not (reparse or note is None):
                data = b""  # the note carries what a receiver takes from the bundle
            if len(batches) == 1:
                batches[0].append((sender, data, pos, receivers, note))
                continue
            split: dict[int, list[int]] = {}
            for r in receivers:
                k = owner.get(r)
                if k is not None:
                    mine = split.get(k)
                    if mine is None:
                        split[k] = [r]
                    else:
                        mine.append(r)
            for k, mine in split.items():
                batches[k].append((sender, data, pos, mine, note))
        rcs = {c.robot: c for c in self._commands.get(t, ())}
        for k, worker in enumerate(self._workers):
            part_rcs = {rid: c for rid, c in rcs.items() if owner[rid] == k}
            worker.call("step", t, batches[k], part_rcs)
        # While the workers step: this tick's geometry, where the robots were at its start.
        self.radio.set_positions({rid: r.vehicle.position for rid, r in self.robots.items()})
        self.radio.neighbors(self.ids[0])  # builds every robot's hearers at once
        t1 = clock()
        results = [w.result() for w in self._workers]
        t2 = clock()
        self._merge(results, broadcast=True)
        self.tick += 1
        timings = self.timings
        timings.coordinator_s += (t1 - t0) + (clock() - t2)
        timings.wait_s += t2 - t1
        # Blocked on the workers, the coordinator uses no CPU: all of its CPU time is serial
        # work, the results' unpickling included.
        timings.coordinator_cpu_s += time.process_time() - cpu0
        timings.workers_cpu_s += sum(r.cpu_s for r in results)
        timings.ticks += 1

    def _merge(self, results: Sequence[PartTick], *, broadcast: bool) -> None:
        """The parts' turns in robot-id order: log lines, errors, then the robot's bundle and
        relays onto the radio (as `Simulation._step_robots` makes them, in that order)."""
        t = self.tick
        robots = self.robots
        sends: dict[int, tuple[bytes, tuple[bytes, ...], int]] = {}
        extras: dict[int, Extra] = {}
        for part, result in zip(self.parts, results, strict=True):
            extras.update(result.extras)
            for rid, state in result.states.items():
                robots[rid].state = state
            if broadcast:
                for rid, send, (x, y, z) in zip(part, result.sends, result.positions, strict=True):
                    sends[rid] = send
                    v = robots[rid].vehicle
                    v.x, v.y, v.z = x, y, z
        radio = self.radio
        for rid in self.ids:
            extra = extras.get(rid)
            if extra is not None:
                lines, error, _ = extra
                if error is not None:
                    self.errors.append(error)
                for line in lines:
                    self.log.append(line)
                    if self.on_log is not None:
                        self.on_log(line)
            if not broadcast:
                continue
            data, messages, counter = sends[rid]
            self.tally(data, messages)
            radio.broadcast(t, rid, data, note=(rid, messages, counter))
            if extra is not None:
                for relay in extra[2]:
                    radio.broadcast(t, rid, relay)

    # ------------------------------------------------------------ running

    def kill(self, rid: int) -> RemoteRobot:
        """Take robot `rid` out of the swarm between two ticks, as `Simulation.kill` does
        (the same log line, the same radio: bundles in flight to it are dropped on arrival);
        its worker drops it too. Returns it (KeyError if there is no such robot alive)."""
        robot = self.robots[rid]
        k = self._owner[rid]
        worker = self._workers[k]
        worker.call("kill", rid)
        worker.result()
        del self.robots[rid]
        del self._owner[rid]
        self.ids.remove(rid)
        self.parts[k].remove(rid)
        line = sim_line(self.tick * TICK_S, f"robot {rid} killed")
        self.log.append(line)
        if self.on_log is not None:
            self.on_log(line)
        return robot

    def run(
        self,
        progress: Callable[[int, int], None] | None = None,
        after_step: Callable[[], None] | None = None,
        stop: threading.Event | None = None,
    ) -> None:
        """Run the configured number of simulated seconds, or until `stop`, as
        `Simulation.run`."""
        run_ticks(self, self.config.ticks, progress, after_step, stop)

    def summary(self) -> dict[str, object]:
        """The run's figures, as `Simulation.summary` gives them for the same run."""
        for worker in self._workers:
            worker.call("finish")
        ends: list[PartEnd] = [w.result() for w in self._workers]
        states: dict[int, str | None] = {}
        failsafe: list[int] = []
        for end in ends:
            states.update(end.states)
            failsafe += end.in_failsafe
        launch = Release(self.program.bytecode).hash
        return {
            "robots": self.config.robots,
            "drop": self.config.drop,
            "seed": self.config.seed,
            "seconds_simulated": round(self.tick * TICK_S, 6),
            **self.bundle_figures(),
            "final_states": {str(rid): states[rid] for rid in self.ids},
            "errors": list(self.errors),
            "in_failsafe": sorted(failsafe),
            "script_versions": {str(rid): launch for rid in self.ids},
            "update": None,
            "security": _merge_security([e.security for e in ends]),
        }


def _merge_security(parts: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The swarm's `security` from its parts' (sums of counters, union of ids)."""
    first = parts[0]
    rejected: dict[str, int] = {}
    commands: dict[str, int] = {}
    mixed: set[int] = set()
    accepted = None if first["accepted"] is None else 0
    for part in parts:
        for reason, n in part["rejected"].items():
            rejected[reason] = rejected.get(reason, 0) + n
        for outcome, n in part.get("commands", {}).items():
            commands[outcome] = commands.get(outcome, 0) + n
        mixed.update(part["mixed"])
        if accepted is not None:
            accepted += part["accepted"]
    out: dict[str, Any] = {
        "mode": first["mode"],
        "accepted": accepted,
        "rejected": dict(sorted(rejected.items())),
        "mixed": sorted(mixed),
    }
    if any("commands" in part for part in parts):
        out["commands"] = dict(sorted(commands.items()))
    return out


__all__ = [
    "DistributedError",
    "DistributedSimulation",
    "PartEnd",
    "PartTick",
    "RemoteRobot",
    "SwarmPart",
    "Timings",
    "partition",
]
