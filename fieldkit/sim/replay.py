"""Replay one simulated robot's recording: its runtime again, on the recorded inputs.

A simulated robot has no autopilot bytes: its inputs are the sensors the simulator gave it,
the frames it heard (and where the simulator put their senders) and the remote-control codes
of its commands; its outputs the frames it sent, the orders its supervisor gave and its
script's state. `replay_sim(flight)` builds the robot's `RobotRuntime` as the simulator did
(profile, origin, seed, globals, first sensors, security) and runs it tick by tick on the
recorded inputs, comparing with `fieldkit.record.compare` what the field replay compares.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import bvm
from bvm.digest import state_digest
from fieldkit.record.compare import ReplayError, ReplayReport, compare_tick
from fieldkit.record.flight import Flight, FlightRecorder, FlightTick
from fieldkit.record.restore import recorded_profile, recorded_security
from fieldkit.robot import geo
from fieldkit.robot import neighbors as nb
from fieldkit.robot.rc import RcCommand
from fieldkit.robot.runtime import RobotRuntime, TickRecord
from fieldkit.robot.script_api import Sensors
from fieldkit.update.keys import RobotKeys
from fieldkit.update.release import Release

#: A tick of the simulator, seconds (fieldkit.sim.simulator.TICK_S).
TICK_S = 0.1


def _sensors(values: dict[str, object]) -> Sensors:
    """Sensors from recorded values (a status read back from a bag as text is a number)."""
    s = Sensors(lat=0.0, lon=0.0, alt=0.0, north=0.0, east=0.0)
    for name, value in values.items():
        if name in ("rc_cmd",) or value is None:
            continue
        if name == "status" and isinstance(value, str):
            value = int(value) if value.lstrip("-").isdigit() else value
        setattr(s, name, value)
    return s


def replay_sim(
    flight: Flight,
    *,
    program: bvm.Program | None = None,
    keys: RobotKeys | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ReplayReport:
    """Run the recorded robot's runtime again on its recorded inputs and compare."""
    meta = flight.meta
    if meta.get("updates"):
        raise ReplayError("the simulation ran an over-the-air update: its replay is not built")
    try:
        rid = int(meta["robot_id"])  # type: ignore[call-overload]
        seed = int(meta.get("seed", 0))  # type: ignore[call-overload]
        lat, lon, alt = (float(x) for x in meta["origin"])  # type: ignore[attr-defined]
        start = dict(meta["start_sensors"])  # type: ignore[call-overload]
        globals_ = dict(meta.get("globals", {}))  # type: ignore[call-overload]
        commands = [RcCommand.parse(str(c)) for c in meta.get("commands", [])]  # type: ignore[attr-defined]
        max_ticks = int(meta.get("max_ticks_per_step", 1_000_000))  # type: ignore[call-overload]
    except (KeyError, TypeError, ValueError) as e:
        raise ReplayError(f"the recording's meta lacks what a replay needs: {e}") from None
    profile = recorded_profile(flight.profile_toml)
    if program is None:
        program = Release(flight.bo, flight.bdb, flight.bpos).program(
            str(meta.get("script_name", "<recorded>"))
        )
    security, gate = recorded_security(meta, rid, keys)
    frame = geo.LocalFrame(lat, lon, alt)
    runtime = RobotRuntime(
        rid, profile, frame, seed=seed, max_ticks=max_ticks, security=security, commands=gate
    )
    got: list[FlightTick] = []
    recorder = FlightRecorder(
        Flight(meta={}, profile_toml="", bo=b""), keep=False, on_tick=got.append
    )
    records: list[TickRecord] = []
    runtime.observer = records.append
    runtime.start(program, _sensors(start), globals_)
    # The simulator's own neighbour timeout (in its 10 Hz ticks), as it computes them.
    timeout = round(nb.NEIGHBOR_TIMEOUT_S / TICK_S)
    due: dict[int, RcCommand] = {round(c.t / TICK_S): c for c in commands}
    report = ReplayReport()
    for n, tick in enumerate(flight.ticks):
        t = tick.tick
        recorder.begin_tick(t, tick.clock_s, tick.unix_ns)
        wheres = tick.radio_where if len(tick.radio_where) == len(tick.radio_in) else []
        for k, (sender, data) in enumerate(tick.radio_in):
            where = wheres[k] if wheres else (math.nan, math.nan)
            recorder.radio_in(sender, data, where)
            runtime.receive_bundle(data, None if math.isnan(where[0]) else where)
        sensors = _sensors(tick.sensors)
        neighbors = None
        if runtime.running:
            here = (sensors.east, sensors.north)
            neighbors = nb.columns([runtime.heard], [here], t, timeout)[0]
        out = runtime.tick(sensors, due.get(t), neighbors)
        if out.bundle:
            recorder.radio_out(out.bundle)
        for relay in runtime.take_relays():
            recorder.radio_out(relay)
        recorder.end_tick(records.pop(), state_digest(runtime.vm), [])
        report.ticks += 1
        report.divergence = compare_tick(tick, got.pop(), report)
        if report.divergence is not None:
            break
        if progress is not None:
            progress(n + 1, len(flight.ticks))
    return report


__all__ = ["replay_sim"]
