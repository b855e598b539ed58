"""`fieldkit sim run ... --record DIR`: one bag per simulated robot, `DIR/robot{ID}`.

Each robot's flight is recorded as a field node's is (fieldkit/record/), minus the autopilot
bytes a simulated vehicle does not have: per tick its time, the frames it heard (with where
the simulator put each sender), the frames it sent, the sensors its script saw, the order its
supervisor gave, its script-state digest and its script's lines. The meta holds what the
robot started from (the simulator's seed, the profile, the field's origin, the robot's
first sensors, the commands), so `fieldkit replay` can run the robot's runtime again and
compare (`fieldkit/sim/replay.py`).

Recording draws no random number and changes nothing a robot sees: a recorded run is the
run without recording, bit for bit.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from bvm.digest import state_digest
from fieldkit.record.bag import BagWriter
from fieldkit.record.flight import SENSOR_FIELDS, Flight, FlightRecorder
from fieldkit.record.flight_bag import FlightBag
from fieldkit.robot.runtime import TickRecord
from fieldkit.update.release import Release

if TYPE_CHECKING:
    from fieldkit.sim.simulator import Simulation

#: What a simulated robot's recording says it is (the replay tells the hosts apart by it).
HOST = "sim"


class SimRecording:
    """The recorders and bag writers of a simulation's robots."""

    def __init__(self, sim: Simulation, out: Path, *, ros1: bool = False) -> None:
        """One bag per robot in `out` (created): `robot{ID}` (ROS 2, MCAP), or `robot{ID}.bag`
        with `ros1`; BagError if one exists already."""
        out.mkdir(parents=True, exist_ok=True)
        profile = sim.profile
        text = profile.path.read_text(encoding="utf-8") if profile.path is not None else ""
        release = Release.from_program(sim.program)
        self.recorders: dict[int, FlightRecorder] = {}
        self.writers: list[BagWriter] = []
        self._records: dict[int, TickRecord] = {}
        self._logs: dict[int, list[str]] = {}
        self.paths: list[Path] = []
        try:
            for rid, robot in sim.robots.items():
                flight = Flight(_meta(sim, rid), text, release.bo, release.bdb, release.bpos)
                path = out / f"robot{rid}{'.bag' if ros1 else ''}"
                # A simulation does not crash mid-tick as a robot does: flush at the end.
                writer = BagWriter(path, flush_s=None, fsync=False)
                self.writers.append(writer)
                self.paths.append(path)
                bag = FlightBag(writer)
                bag.start(flight)
                recorder = FlightRecorder(flight, keep=False, on_tick=bag.tick)
                self.recorders[rid] = recorder
                self._logs[rid] = []
                robot.runtime.observer = self._observer(rid)
        except BaseException:
            self.close()
            raise

    def _observer(self, rid: int) -> Callable[[TickRecord], None]:
        def observe(record: TickRecord) -> None:
            self._records[rid] = record

        return observe

    def log(self, rid: int, text: str) -> None:
        """A line robot `rid`'s script logged (in its tick)."""
        lines = self._logs.get(rid)
        if lines is not None:
            lines.append(text)

    def begin(self, tick: int, clock_s: float) -> None:
        """A tick begins for every robot."""
        for recorder in self.recorders.values():
            recorder.begin_tick(tick, clock_s, 0)

    def heard(
        self,
        sender: int,
        data: bytes,
        where: tuple[float, float] | None,
        receivers: Sequence[int],
    ) -> None:
        """A frame the radio delivered to `receivers` now (`where` its sender was)."""
        at = (float("nan"), float("nan")) if where is None else where
        recorders = self.recorders
        for receiver in receivers:
            recorder = recorders.get(receiver)
            if recorder is not None:
                recorder.radio_in(sender, data, at)

    def sent(self, rid: int, data: bytes) -> None:
        """A frame robot `rid` put on the air."""
        self.recorders[rid].radio_out(data)

    def end(self, rid: int, sim: Simulation) -> None:
        """Robot `rid`'s tick ran."""
        record = self._records.pop(rid, None)
        if record is None:
            return
        runtime = sim.robots[rid].runtime
        lines, self._logs[rid] = self._logs[rid], []
        self.recorders[rid].end_tick(record, state_digest(runtime.vm), lines)

    def close(self) -> None:
        """Close every bag."""
        for writer in self.writers:
            writer.close()


def _meta(sim: Simulation, rid: int) -> dict[str, object]:
    """What robot `rid` started from, for its replay."""
    config = sim.config
    robot = sim.robots[rid]
    s = robot.sensors
    return {
        "host": HOST,
        "robot_id": rid,
        "seed": config.seed,
        "script_name": config.script.name,
        "globals": dict(config.globals),
        "commands": [c.text() for c in config.commands if c.robot == rid],
        "origin": [sim.frame.lat, sim.frame.lon, sim.frame.alt],
        "start_sensors": {name: getattr(s, name) for name in SENSOR_FIELDS},
        "max_ticks_per_step": config.max_ticks_per_step,
        "tick_s": 0.1,
        # As a node's recording says it: None for a robot without a LinkSecurity.
        "security": None if robot.runtime.security is None else robot.runtime.security.mode,
        "radio": True,
        "updates": bool(config.updates),
    } | _security(sim, rid)


def _security(sim: Simulation, rid: int) -> dict[str, object]:
    """A signed robot's starting counter and key fingerprint (never the key), and its
    command gate's state: what its replay starts from."""
    runtime = sim.robots[rid].runtime
    out: dict[str, object] = {}
    security = runtime.security
    if security is not None and security.sealer is not None:
        out["key_fingerprint"] = security.sealer.key.fingerprint
        out["counter_start"] = security.last_counter + 1
        out["floors"] = {}
    if runtime.commands is not None:
        out["command_last_acted"] = runtime.commands.last_acted
    return out


__all__ = ["HOST", "SimRecording"]
