"""The shipped behaviours: the barrier, task allocation and Voronoi coverage.

Two levels: the Buzz pieces on `Harness` with stand-in closures (robots teleport to their
goto_abs targets), and end to end on the simulator (kinematics, radio, script API) at small
scale, with and without 90 % packet loss. Everything is seeded.
"""

from __future__ import annotations

import functools
import math
import random
from collections.abc import Callable
from pathlib import Path

import pytest
from harness import Harness
from hypothesis import given, settings
from hypothesis import strategies as st

import bvm
from bvm.values import f32, format_log
from fieldkit.robot import geo, shapes
from fieldkit.robot import voronoi as vor
from fieldkit.sim import simulator as sim_mod
from fieldkit.sim.radio import LinkModel

SCRIPTS = Path(__file__).resolve().parent.parent / "buzz_scripts"
INCLUDE = SCRIPTS / "include"

BARRIER_PROBE = """
include "barrier.bzz"
function init() {
  T = 0
  OUT = "waiting"
  AT = -1
  if (JOIN == 1) {
    B = barrier_new(KEY, CODE, THRESHOLD)
  }
}
function step() {
  T = T + 1
  if (JOIN == 1) {
    var o = barrier_step(B)
    if (o != OUT) {
      OUT = o
      AT = T
    }
  }
}
"""


def barrier_run(
    ids: list[int],
    *,
    drop: float,
    seed: int,
    threshold: int,
    joiners: set[int] | None = None,
    timeout: int = 300,
    steps: int = 200,
    key: int = 4,
    code: int = 900,
) -> Harness:
    """Robots `ids` in one barrier (only `joiners` take part), over a lossy radio."""
    joiners = set(ids) if joiners is None else joiners

    def setup(rid: int, vm: bvm.VM) -> None:
        vm["JOIN"] = int(rid in joiners)
        vm["KEY"], vm["CODE"], vm["THRESHOLD"] = key, code, threshold
        vm["BARRIER_TIMEOUT"] = timeout

    program = bvm.compile_source(BARRIER_PROBE, str(INCLUDE / "probe.bzz"))
    h = Harness(
        program,
        ids,
        positions={i: (3.0 * i, 0.0, 0.0) for i in ids},
        link=LinkModel(drop=drop),
        seed=seed,
        setup=setup,
        budget_bytes=186,  # ROSBuzz's bundle content per step
        overhead=2,
    )
    h.run(steps)
    assert h.errors == {}
    return h


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_barrier_passes_on_ten_robots_at_half_loss(seed: int) -> None:
    h = barrier_run(list(range(1, 11)), drop=0.5, seed=seed, threshold=10)
    outcomes = {rid: (vm["OUT"], vm["AT"]) for rid, vm in h.vms.items()}
    assert {o for o, _ in outcomes.values()} == {"passed"}
    # The counts go up a tree and the flag comes down it, each hop waiting for its
    # acknowledgement: 12-21 steps over these seeds (the bitsets' flood took up to 20).
    assert max(at for _, at in outcomes.values()) <= 25


@pytest.mark.parametrize("seed", [1, 2])
def test_barrier_passes_at_ninety_percent_loss(seed: int) -> None:
    h = barrier_run(list(range(1, 11)), drop=0.9, seed=seed, threshold=10, steps=300)
    assert {vm["OUT"] for vm in h.vms.values()} == {"passed"}


def test_barrier_times_out_when_a_robot_is_missing() -> None:
    h = barrier_run(list(range(1, 10)), drop=0.5, seed=1, threshold=10, timeout=60, steps=80)
    assert {(vm["OUT"], vm["AT"]) for vm in h.vms.values()} == {("timedout", 60)}


def test_barrier_on_a_sub_swarm() -> None:
    # Robots 1..4 wait for each other; 5..8 do not take part and must not block them.
    h = barrier_run(list(range(1, 9)), drop=0.3, seed=4, threshold=4, joiners={1, 2, 3, 4})
    assert [h.vms[r]["OUT"] for r in range(1, 9)] == ["passed"] * 4 + ["waiting"] * 4


def test_barrier_instances_do_not_share_entries() -> None:
    # ROSBuzz reused one stigmergy: a second barrier with the same code passed on the
    # entries of the first. Here a new key is a new store, so with robot 6 missing the
    # second instance times out even though all 6 passed the first.
    src = BARRIER_PROBE.replace(
        "function step() {\n  T = T + 1",
        "function step() {\n  T = T + 1\n"
        '  if (T == 60 and id != 6) { B = barrier_new(KEY + 1, CODE, THRESHOLD) OUT = "waiting" }',
    )
    program = bvm.compile_source(src, str(INCLUDE / "probe.bzz"))

    def setup(rid: int, vm: bvm.VM) -> None:
        vm["JOIN"], vm["KEY"], vm["CODE"], vm["THRESHOLD"] = 1, 4, 900, 6
        vm["BARRIER_TIMEOUT"] = 50

    h = Harness(program, range(1, 7), link=LinkModel(drop=0.2), seed=5, setup=setup)
    h.run(59)
    assert {vm["OUT"] for vm in h.vms.values()} == {"passed"}
    h.run(60)
    assert [h.vms[r]["OUT"] for r in range(1, 6)] == ["timedout"] * 5


# ------------------------------------------------------------------ stand-in host


class StandIn:
    """A Harness with the script API's closures faked: goto_abs teleports the robot.

    Ground robots (V_TYPE 2), so takeoff is immediate; the host globals are pushed before
    each step as the field node does.
    """

    def __init__(self, script: Path, n: int, *, drop: float, seed: int, **globs: object) -> None:
        self.lines: list[str] = []
        self.rc: dict[int, int] = {}
        self.n = n
        # Harness positions: (x east, y north, z); robots start on a 3 m line going east.
        positions = {i: (3.0 * (i - 1), 0.0, 0.0) for i in range(1, n + 1)}

        def setup(rid: int, vm: bvm.VM) -> None:
            for name in ("uav_takeoff", "uav_land", "gohome", "arm", "disarm", "reset_rc"):
                vm.register(name, lambda *args: None)
            vm.register(
                "log",
                lambda *a, rid=rid: self.lines.append(f"[{rid}] " + format_log(a)),
            )
            vm.register("goto_abs", self._mover(rid))
            vm.register("load_graph", shapes.load_graph)
            vm["V_TYPE"], vm["TARGET_ALTITUDE"], vm["ROBOTS"] = 2, 5.0, n
            for k, v in globs.items():
                vm[k] = v
            self._push(rid, vm)

        program = bvm.compile_file(script)
        self.h = Harness(
            program,
            range(1, n + 1),
            positions=positions,
            link=LinkModel(drop=drop),
            seed=seed,
            setup=setup,
            budget_bytes=186,
            overhead=2,
        )

    def _mover(self, rid: int) -> Callable[..., None]:
        def goto_abs(dx: float, dy: float, dh: float, yaw: float) -> None:
            x, y, z = self.h.positions[rid]
            self.h.positions[rid] = (x + dy, y + dx, z)  # dx north, dy east

        return goto_abs

    def _push(self, rid: int, vm: bvm.VM) -> None:
        x, y, _ = self.h.positions[rid] if hasattr(self, "h") else (3.0 * (rid - 1), 0.0, 0.0)
        vm["pose"] = {
            "position": {"latitude": 0.0, "longitude": 0.0, "altitude": 0.0, "x": y, "y": x},
            "orientation": {"yaw": 0.0},
        }
        vm["flight"] = {"status": 1, "rc_cmd": self.rc.pop(rid, 0)}

    def run(self, steps: int, until: Callable[[], bool] | None = None) -> None:
        for _ in range(steps):
            for rid, vm in self.h.vms.items():
                self._push(rid, vm)
            self.h.step()
            assert self.h.errors == {}
            if until is not None and until():
                return

    def states(self) -> list[str]:
        return [vm["BVMSTATE"] for vm in self.h.vms.values()]


def all_joined(states: list[str]) -> bool:
    return all(s in ("JOINED", "LOCK") for s in states)


@pytest.mark.parametrize(("drop", "seed"), [(0.0, 1), (0.5, 2)])
def test_task_allocation_assigns_distinct_labels(drop: float, seed: int) -> None:
    sim = StandIn(SCRIPTS / "task_allocation.bzz", 6, drop=drop, seed=seed)
    sim.run(5)
    assert sim.states() == ["TURNEDOFF"] * 6
    sim.rc[3] = 900  # any robot can receive the command; the root is still robot 1
    sim.run(600, until=lambda: sim.states() == ["LOCK"] * 6)
    assert sim.states() == ["LOCK"] * 6
    labels = {rid: vm["TA_LABEL"] for rid, vm in sim.h.vms.items()}
    assert sorted(labels.values()) == list(range(6))
    assert labels[1] == 0
    # Each robot sits where its node is, relative to the root.
    ideal = shapes.positions("P")
    rx, ry, _ = sim.h.positions[1]
    for rid, label in labels.items():
        x, y, _ = sim.h.positions[rid]
        assert math.hypot(y - ry - ideal[label][0], x - rx - ideal[label][1]) < 0.3


def test_more_robots_than_tasks_leaves_the_extras_free() -> None:
    sim = StandIn(SCRIPTS / "task_allocation.bzz", 8, drop=0.0, seed=3)
    sim.rc[1] = 900
    sim.run(300)
    states = sim.states()
    assert sorted(states).count("FREE") == 2
    assert sum(s in ("JOINED", "LOCK") for s in states) == 6
    labels = [vm["TA_LABEL"] for vm in sim.h.vms.values() if vm["BVMSTATE"] != "FREE"]
    assert sorted(labels) == list(range(6))


def test_land_command_spreads_and_ends_turned_off() -> None:
    sim = StandIn(SCRIPTS / "task_allocation.bzz", 4, drop=0.3, seed=6, SHAPE="L")
    sim.rc[2] = 900
    sim.run(100)
    assert all(s != "TURNEDOFF" for s in sim.states())
    sim.rc[4] = 21
    sim.run(60)
    assert sim.states() == ["TURNEDOFF"] * 4
    assert any("[4] barrier 900 passed" in line for line in sim.lines)


# ------------------------------------------------------------------ end to end (simulator)


def simulate(
    script: str,
    n: int,
    drop: float,
    seed: int,
    commands: list,
    seconds: float,
    until: Callable[[object], bool] | None = None,
    **globs: object,
):
    """Run the simulator for at most `seconds`, stopping early once `until(sim)` holds."""
    cfg = sim_mod.SimConfig(
        script=SCRIPTS / script,
        robots=n,
        drop=drop,
        seed=seed,
        seconds=seconds,
        commands=commands,
        globals=dict(globs),
    )
    sim = sim_mod.Simulation(cfg)
    total = round(seconds / sim_mod.TICK_S)
    while sim.tick < total:
        sim.step()
        if until is not None and sim.tick % 10 == 0 and until(sim):
            break
    assert [r.error for r in sim.robots.values() if r.error] == []
    return sim


def formed(sim) -> bool:
    return all(r.state == "LOCK" for r in sim.robots.values())


@pytest.mark.parametrize(("drop", "seed"), [(0.0, 1), (0.9, 2), (0.9, 3)])
def test_task_allocation_end_to_end(drop: float, seed: int) -> None:
    rc = sim_mod.RcCommand
    sim = simulate(
        "task_allocation.bzz", 6, drop, seed, [rc(0.5, 1, 22), rc(6.0, 1, 900)], 90.0, formed
    )
    assert formed(sim)
    labels = {r.id: r.vm["TA_LABEL"] for r in sim.robots.values()}
    assert sorted(labels.values()) == list(range(6))
    ideal = shapes.positions("P")
    root = sim.robots[1].vehicle
    for r in sim.robots.values():
        north, east = ideal[labels[r.id]]
        v = r.vehicle
        assert math.hypot(v.y - root.y - north, v.x - root.x - east) < ARRIVE_TOL
        assert v.z == pytest.approx(5.0, abs=0.3)  # flying at the profile's altitude


ARRIVE_TOL = 0.6  # the script's ARRIVED (0.5 m) plus the hold tolerance slack


def test_two_robots_taking_label_0_at_once_leave_it_to_the_lower_id() -> None:
    # 8 robots for the 6 tasks of P: once formed, the root dies; once its last message has
    # aged out, the two robots without a task are made to have lost it long ago (as the
    # robot of label 1 will have), so both take label 0 on the same step.
    rc = sim_mod.RcCommand

    def locked(sim) -> bool:
        return sum(r.state == "LOCK" for r in sim.robots.values()) == 6

    sim = simulate(
        "task_allocation.bzz", 8, 0.0, 1, [rc(0.5, 1, 22), rc(6.0, 1, 900)], 90.0, locked
    )
    assert locked(sim)
    free = sorted(r.id for r in sim.robots.values() if r.vm["TA_LABEL"] == -1)
    assert len(free) == 2
    sim.kill(1)
    for _ in range(60):  # HEARD_TTL (50 steps) and a little
        sim.step()
    for rid in free:
        vm = sim.robots[rid].vm
        vm["TA_ROOT_LOST"] = 0  # the tick it last saw label 0's robot
        vm["TA_ROOT_CHILD"] = 1
    holders: list[list[int]] = []
    for _ in range(round(60 / sim_mod.TICK_S)):
        sim.step()
        robots = sim.robots.values()
        holders.append([r.id for r in robots if r.vm["TA_LABEL"] == 0 and r.state in HELD])
    assert free in holders  # both took it at once...
    assert holders[-1] == [min(free)]  # ...and the higher id gave it up for good
    assert any(f"label 0 belongs to {min(free)}: free again" in line for line in sim.log)
    assert locked(sim)  # and the shape formed again around it


HELD = ("JOINED", "LOCK")


def test_a_second_label_0_gives_way_to_root_id_whatever_the_ids() -> None:
    # ROOT_ID 8 holds label 0; a robot with a lower id comes to hold it too (as one that lost
    # sight of the root and took it over would, coming back into range): it must give it up,
    # not the living root, or the whole shape would form again around it.
    rc = sim_mod.RcCommand

    def locked(sim) -> bool:
        return sum(r.state == "LOCK" for r in sim.robots.values()) == 6

    commands = [rc(0.5, 1, 22), rc(6.0, 1, 900)]
    sim = simulate("task_allocation.bzz", 8, 0.0, 1, commands, 90.0, locked, ROOT_ID=8)
    assert locked(sim) and sim.robots[8].vm["TA_LABEL"] == 0
    (rival, *_) = sorted(r.id for r in sim.robots.values() if r.vm["TA_LABEL"] == -1)
    vm = sim.robots[rival].vm
    vm["TA_LABEL"] = 0
    vm["BVMSTATE"] = "JOINED"
    for _ in range(20):
        sim.step()
    assert sim.robots[8].vm["TA_LABEL"] == 0 and sim.robots[8].state == "LOCK"
    assert sim.robots[rival].vm["TA_LABEL"] == -1
    assert any(f"robot {rival}: label 0 belongs to 8: free again" in ln for ln in sim.log)


@pytest.mark.parametrize(("drop", "seed"), [(0.0, 0), (0.5, 1)])
def test_the_root_lost_before_the_lock_still_locks_the_shape(drop: float, seed: int) -> None:
    # 10 robots for P: the root dies 6 s after RC 900, while the shape forms. Another robot
    # takes label 0, the shape forms again around it, and the lock barrier, rooted at the
    # dead robot until then, passes with the new root.
    rc = sim_mod.RcCommand
    sim = simulate("task_allocation.bzz", 10, drop, seed, [rc(1.0, 1, 22), rc(20.0, 1, 900)], 26)
    assert sim.robots[1].vm["TA_LABEL"] == 0
    sim.kill(1)
    total = sim.tick + round(120 / sim_mod.TICK_S)
    while sim.tick < total and sum(r.state == "LOCK" for r in sim.robots.values()) < 6:
        sim.step()
    locked = [r for r in sim.robots.values() if r.state == "LOCK"]
    assert sorted(r.vm["TA_LABEL"] for r in locked) == list(range(6))
    (root,) = [r.id for r in locked if r.vm["TA_LABEL"] == 0]
    assert all(r.vm["TA_LOCK_ROOT"] == root for r in locked)


def _six_locked(sim) -> list[tuple[int, int]]:
    """(label, robot) of the robots in LOCK, by label."""
    return sorted((r.vm["TA_LABEL"], r.id) for r in sim.robots.values() if r.state == "LOCK")


def test_a_command_barrier_that_times_out_leaves_the_labels_as_they_were() -> None:
    # The shape is locked; a robot dies; RC 904 (IDLE) through robot 2 waits in its barrier
    # for the dead robot and times out after 30 s, back to each robot's state. Nobody spoke
    # meanwhile, so every robot's wait for its predecessor (and a FREE robot's for label 0)
    # had run out: label holders gave their labels up and took label 0 over. They resume
    # their waits from the time-out instead.
    rc = sim_mod.RcCommand
    commands = [rc(1.0, 1, 22), rc(15.0, 1, 900), rc(60.0, 2, 904)]
    sim = simulate("task_allocation.bzz", 10, 0.0, 1, commands, 59.9, BARRIER_TIMEOUT=300)
    before = _six_locked(sim)
    assert [label for label, _ in before] == list(range(6))
    (spare,) = [r.id for r in sim.robots.values() if r.state == "FREE"][-1:]
    sim.kill(spare)
    while sim.tick < round(140 / sim_mod.TICK_S):
        sim.step()
    assert any("barrier 904 timed out" in line for line in sim.log)
    assert not any("taken here" in line or "free again" in line for line in sim.log)
    assert _six_locked(sim) == before


def _root_killed_before_its_first_grant(
    drop: float = 0.0, seed: int = 0, more: tuple[tuple[float, int, int], ...] = ()
):
    """10 robots, BARRIER_TIMEOUT 30 s, RC 900 at 20 s: the root dies 0.2 s after taking
    label 0 (its first grant comes 0.4-0.6 s after), while no other robot has a label, then
    RC codes `more` (seconds, robot, code) follow; run until the shape locks or 120 s after
    the kill."""
    rc = sim_mod.RcCommand
    commands = [rc(1.0, 1, 22), rc(20.0, 1, 900), *(rc(t, r, c) for t, r, c in more)]
    sim = simulate("task_allocation.bzz", 10, drop, seed, commands, 20, BARRIER_TIMEOUT=300)
    while sim.robots[1].vm["TA_LABEL"] != 0 and sim.tick < round(60 / sim_mod.TICK_S):
        sim.step()
    sim.step()
    sim.step()
    assert sim.robots[1].vm["TA_LABEL"] == 0
    assert all(r.vm["TA_LABEL"] == -1 for r in sim.robots.values() if r.id != 1)
    assert all(sim.tick * sim_mod.TICK_S < t for t, _, _ in more)
    sim.kill(1)
    total = sim.tick + round(120 / sim_mod.TICK_S)
    while sim.tick < total and len(_six_locked(sim)) < 6:
        sim.step()
    return sim


@pytest.mark.parametrize(("drop", "seed"), [(0.0, 0), (0.5, 1)])
def test_a_root_that_dies_before_granting_a_label_is_replaced(drop: float, seed: int) -> None:
    # No robot has a label yet, so none loses a predecessor. The FREE robots that saw
    # label 0 held count it as lost.
    sim = _root_killed_before_its_first_grant(drop, seed)
    assert [label for label, _ in _six_locked(sim)] == list(range(6))


def test_a_lost_root_is_replaced_after_a_command_barrier_times_out() -> None:
    # RC 904 waits for the dead root and times out 30 s later: the robots that saw label 0
    # before the wait still count it seen, and one takes it 20 s after the time-out.
    sim = _root_killed_before_its_first_grant(more=((22.0, 2, 904),))
    assert any("barrier 904 timed out" in line for line in sim.log)
    assert [label for label, _ in _six_locked(sim)] == list(range(6))


def test_a_command_during_a_barrier_resumes_what_that_barrier_would_have() -> None:
    # A second RC 904 5 s into the first one's barrier: when it times out, each robot goes
    # back to its state before the first, not to BARRIERWAIT for good.
    sim = _root_killed_before_its_first_grant(more=((22.0, 2, 904), (27.0, 3, 904)))
    assert not any("-> BARRIERWAIT" in line for line in sim.log)
    assert [label for label, _ in _six_locked(sim)] == list(range(6))


def _new_allocation_after_root_id_died(params: tuple[float, ...]):
    """10 robots hover; robot 1 (ROOT_ID) dies at 10 s; RC 900 with `params` comes through
    robot 2 at 50 s (ROBOTS has dropped to 9 by then); run until six robots lock or 100 s."""
    rc = sim_mod.RcCommand
    commands = [rc(1.0, 1, 22), rc(50.0, 2, 900, params)]
    sim = simulate("task_allocation.bzz", 10, 0.0, 0, commands, 10)
    sim.kill(1)
    while sim.tick < round(100 / sim_mod.TICK_S) and len(_six_locked(sim)) < 6:
        sim.step()
    return sim


def test_a_900_that_names_a_root_forms_the_shape_when_root_id_is_gone() -> None:
    # Nobody ever saw label 0 held in this allocation, so nobody takes it over: a plain
    # 900 leaves every robot FREE. `T:2:900:3` names robot 3 the root.
    plain = _new_allocation_after_root_id_died(())
    assert plain.tick == round(100 / sim_mod.TICK_S)
    assert all(r.state == "FREE" for r in plain.robots.values())
    named = _new_allocation_after_root_id_died((3.0,))
    assert [label for label, _ in _six_locked(named)] == list(range(6))
    assert named.robots[3].vm["TA_LABEL"] == 0
    assert all(r.vm["ROOT_ID"] == 3 for r in named.robots.values())
    assert any("robot 3: root: label 0" in line for line in named.log)


def test_a_900_with_a_root_that_is_not_an_id_is_logged_and_ignored() -> None:
    rc = sim_mod.RcCommand
    commands = [rc(1.0, 1, 22), rc(10.0, 2, 900, (2.5,))]
    sim = simulate("task_allocation.bzz", 6, 0.0, 0, commands, 40, until=formed)
    assert formed(sim) and sim.robots[1].vm["TA_LABEL"] == 0
    assert any("robot 4: ignored root 2.500000: not a robot id" in line for line in sim.log)


#: task_allocation.bzz, but robot 6 (captured, or buggy) broadcasts a "cmd" for the next 900
#: at tick 150 whose `.p` is the value PARAM names.
HOSTILE_900 = """
include "task_allocation.bzz"
ODD = function() { return 1 }
STATE_STEP["IDLE"] = function() {
  if (id == 6 and TICK == 150) {
    var p = nil
    if (PARAM == "closure") { p = ODD }
    if (PARAM == "native") { p = log }
    if (PARAM == "string") { p = "3" }
    if (PARAM == "huge") { p = 2147483647 }
    neighbors.broadcast("cmd", {.v = (CMD_EPOCH + 1) * CMD_RADIX + 900, .o = 6, .p = p})
  }
}
"""


@pytest.mark.parametrize("param", ["closure", "native", "string", "huge"])
def test_a_900_whose_root_is_not_a_number_crashes_no_robot(tmp_path: Path, param: str) -> None:
    # `and` evaluates both sides in Buzz: ordering a closure against 0 was a script error in
    # the first robot to enter the allocation. Only numbers are taken from a neighbour now.
    script = tmp_path / "hostile.bzz"
    script.write_text(HOSTILE_900)
    cfg = sim_mod.SimConfig(
        script=script,
        robots=6,
        seed=1,
        seconds=40.0,
        include_dirs=[str(SCRIPTS)],
        commands=[sim_mod.RcCommand(1.0, 1, 22)],
        globals={"PARAM": param},
    )
    sim = sim_mod.Simulation(cfg)
    sim.run()
    assert [r.error for r in sim.robots.values() if r.error] == []
    assert all(r.vm["ROOT_ID"] == 1 for r in sim.robots.values())
    assert sim.robots[1].vm["TA_LABEL"] == 0
    ignored = [line for line in sim.log if "ignored root 2147483647" in line]
    assert len(ignored) == (6 if param == "huge" else 0)


def test_a_plain_900_goes_back_to_the_configured_root() -> None:
    # Each 900 says who the root is, so a robot restarted since `T:2:900:3` (its ROOT_ID the
    # configured 1 again) agrees with the others on the next, plain, 900.
    rc = sim_mod.RcCommand
    commands = [rc(1.0, 1, 22), rc(10.0, 2, 900, (3.0,)), rc(40.0, 2, 900)]
    sim = simulate("task_allocation.bzz", 8, 0.0, 0, commands, 39)
    assert all(r.vm["ROOT_ID"] == 3 for r in sim.robots.values())
    sim.robots[5].vm["ROOT_ID"] = 1  # as robot 5's script would be after a restart
    while sim.tick < round(70 / sim_mod.TICK_S):
        sim.step()
    assert all(r.vm["ROOT_ID"] == 1 for r in sim.robots.values())
    assert [label for label, _ in _six_locked(sim)] == list(range(6))
    assert sim.robots[1].vm["TA_LABEL"] == 0


def test_a_takeoff_barrier_that_times_out_enters_the_auto_state() -> None:
    # A robot dead before takeoff: the takeoff's barrier times out and the others go on
    # to AUTO_STATE alone. TASK_ALLOCATE must be entered (its graph loaded, a state of
    # its own), not only named.
    rc = sim_mod.RcCommand
    commands = [rc(1.0, 1, 22)]
    sim = simulate(
        "task_allocation.bzz",
        6,
        0.0,
        1,
        commands,
        0.1,
        AUTO_STATE="TASK_ALLOCATE",
        BARRIER_TIMEOUT=100,
    )
    sim.kill(6)
    while sim.tick < round(40 / sim_mod.TICK_S):
        sim.step()
    assert any("barrier 22 timed out" in line for line in sim.log)
    assert sim.robots[1].vm["TA_LABEL"] == 0
    assert all(r.state != "TASK_ALLOCATE" for r in sim.robots.values())


REENTRY_PROBE = """
include "include/states.bzz"
COMMAND_STATE[905] = "X"
ENTERED = 0
STATE_ENTER["X"] = function() { ENTERED = ENTERED + 1 }
function init() { flow_init() }
function step() { flow_step() }
function destroy() {}
"""


def test_a_command_to_the_state_a_robot_is_in_resumes_it_on_a_time_out(tmp_path: Path) -> None:
    # RC 905 takes the robots to X; robot 4 dies; RC 905 again waits for it and times out.
    # The robots go back to X as they left it: its entry (coverage's DEPLOY resets its goal)
    # runs once, not again as the takeoff's time-out, which goes on to a state not entered.
    script = tmp_path / "probe.bzz"
    script.write_text(REENTRY_PROBE)
    rc = sim_mod.RcCommand
    cfg = sim_mod.SimConfig(
        script=script,
        robots=4,
        seed=1,
        seconds=60.0,
        commands=[rc(1.0, 1, 22), rc(15.0, 1, 905), rc(25.0, 1, 905)],
        include_dirs=(str(SCRIPTS),),
        globals={"BARRIER_TIMEOUT": 100},
    )
    sim = sim_mod.Simulation(cfg)
    while sim.tick < round(20 / sim_mod.TICK_S):
        sim.step()
    assert all(r.state == "X" for r in sim.robots.values())
    sim.kill(4)
    while sim.tick < round(60 / sim_mod.TICK_S):
        sim.step()
    assert any("barrier 905 timed out" in line for line in sim.log)
    assert [(r.state, r.vm["ENTERED"]) for r in sim.robots.values()] == [("X", 1)] * 3


def test_task_allocation_from_the_ground_with_one_command() -> None:
    # RC 900 on the ground: barrier, takeoff, then allocation (no separate RC 22).
    rc = sim_mod.RcCommand
    sim = simulate("task_allocation.bzz", 6, 0.2, 4, [rc(1.0, 6, 900)], 60.0, formed, SHAPE="Y")
    assert formed(sim)


def test_ground_robots_skip_takeoff() -> None:
    rc = sim_mod.RcCommand
    cfg = sim_mod.SimConfig(
        script=SCRIPTS / "task_allocation.bzz",
        robots=6,
        seed=5,
        seconds=60.0,
        commands=[rc(0.5, 1, 22), rc(3.0, 1, 900)],
        profile="husky",
    )
    sim = sim_mod.Simulation(cfg)
    while sim.tick < 600 and not formed(sim):
        sim.step()
    assert formed(sim)
    assert all(r.vehicle.z == 0.0 for r in sim.robots.values())


@functools.cache
def _coverage_program() -> bvm.Program:
    return bvm.compile_file(SCRIPTS / "coverage.bzz")


def coverage_vm() -> bvm.VM:
    """coverage.bzz loaded (global code run), for calling its functions directly."""
    vm = bvm.VM(robot_id=1)
    vm.load(_coverage_program())
    vm.register("log", lambda *args: None)
    vm.execute()
    return vm


def test_buzz_hull_matches_the_python_hull() -> None:
    rng = random.Random(8)
    vm = coverage_vm()
    for n in (3, 4, 10, 40):
        pts = [(rng.uniform(-50, 50), rng.uniform(-50, 50)) for _ in range(n)]
        pts.append(pts[0])  # a duplicate
        pts.append(((pts[1][0] + pts[2][0]) / 2, (pts[1][1] + pts[2][1]) / 2))  # on an edge?
        hull = vm.call("hull_of", [{"x": x, "y": y} for x, y in pts], len(pts))
        got = [(hull[k]["x"], hull[k]["y"]) for k in range(len(hull))]
        want = vor.convex_hull([(f32(x), f32(y)) for x, y in pts])
        assert len(got) == len(want)
        assert vor.area(got) == pytest.approx(vor.area(want), rel=1e-5)  # both CCW
        assert all(min(math.dist(g, w) for w in want) < 1e-4 for g in got)


def test_buzz_region_is_the_inflated_hull_of_the_metric() -> None:
    vm = coverage_vm()
    centers = [(0.0, 0.0), (40.0, 10.0), (15.0, 60.0), (20.0, 20.0)]
    vm["HS_LOCAL"] = {k: {"x": x, "y": y} for k, (x, y) in enumerate(centers)}
    vm["HS_KEYS"] = list(range(len(centers)))
    vm["HS_COUNT"] = len(centers)
    vm.call("cov_build_region")
    region = vm["REGION"]
    got = [(region[k]["x"], region[k]["y"]) for k in range(vm["REGION_N"])]
    want = vor.convex_hull(centers, margin=20.0)
    assert vor.area(got) == pytest.approx(vor.area(want), rel=1e-5)
    assert all(min(math.dist(g, w) for w in want) < 1e-3 for g in got)


# coverage.bzz's region as first written: every corner tested against every earlier one,
# through the vec2 functions. The script now skips pairs that cannot be duplicates and
# writes the arithmetic out; its regions must be the same, bit for bit.
REGION_AS_FIRST_WRITTEN = """
include "include/vec2.bzz"
function is_new(pts, n, pt) {
  var k = 0
  var fresh = 1
  while (k < n) {
    if (vec_length(vec_sub(pts[k], pt)) < 0.001) {
      fresh = 0
    }
    k = k + 1
  }
  return fresh
}
function hull(pts, n) {
  var start = 0
  var i = 1
  while (i < n) {
    if (pts[i].x < pts[start].x) {
      start = i
    } else {
      if (pts[i].x == pts[start].x and pts[i].y < pts[start].y) {
        start = i
      }
    }
    i = i + 1
  }
  var out = {}
  var h = 0
  var p = start
  var more = 1
  while (more == 1) {
    out[h] = pts[p]
    h = h + 1
    var q = (p + 1) % n
    var r = 0
    while (r < n) {
      var turn = vec_cross3(pts[p], pts[q], pts[r])
      if (turn < 0.0) {
        q = r
      } else {
        var far = (vec_length(vec_sub(pts[r], pts[p])) > vec_length(vec_sub(pts[q], pts[p])))
        if (turn == 0.0 and far) {
          q = r
        }
      }
      r = r + 1
    }
    p = q
    if (p == start or h >= n) {
      more = 0
    }
  }
  return out
}
function region(centres, count, margin, sides) {
  var pts = {}
  var n = 0
  var k = 0
  while (k < count) {
    var s = 0
    while (s < sides) {
      var corner = vec_add(centres[k], vec_polar(margin, 2.0 * math.pi * s / sides))
      if (is_new(pts, n, corner) == 1) {
        pts[n] = corner
        n = n + 1
      }
      s = s + 1
    }
    k = k + 1
  }
  return hull(pts, n)
}
"""


@pytest.mark.parametrize(
    ("centres", "margin"),
    [
        ([(0.0, 0.0), (40.0, 10.0), (15.0, 60.0), (20.0, 20.0)], 20.0),  # near and far
        ([(0.0, 0.0), (40.0, 0.0), (40.0, 40.0)], 20.0),  # corners that coincide
        ([(5.0, 5.0), (5.0, 5.0), (90.0, -30.0)], 20.0),  # one hotspot twice
        ([(0.0, 0.0), (30.0, 0.0), (0.0, 30.0)], 0.0),  # no margin: eight equal corners
        ([(0.0, 0.0), (30.0, 0.0), (0.0, 30.0)], 0.004),  # corners 3 mm apart
        ([(0.0, 0.0), (30.0, 0.0), (0.0, 30.0)], -20.0),  # a negative margin
    ],
)
def test_region_is_the_one_first_written(centres: list[tuple[float, float]], margin: float) -> None:
    assert_region_as_first_written(centres, margin)


@settings(max_examples=40, deadline=None)
@given(
    centres=st.lists(
        st.tuples(st.integers(-60, 60).map(float), st.integers(-60, 60).map(float)),
        min_size=1,
        max_size=5,
    ),
    margin=st.sampled_from([0.0, 0.004, 5.0, 20.0, 35.0]),
)
def test_random_regions_are_the_ones_first_written(
    centres: list[tuple[float, float]], margin: float
) -> None:
    # Whole-metre centres make collinear corners and exact ties, where the gift wrapping's
    # choices are most fragile.
    assert_region_as_first_written(centres, margin)


@functools.cache
def _region_reference() -> bvm.Program:
    return bvm.compile_source(REGION_AS_FIRST_WRITTEN, "ref.bzz", [str(SCRIPTS)])


def assert_region_as_first_written(centres: list[tuple[float, float]], margin: float) -> None:
    """coverage.bzz builds, from these hotspots, the region the first written code built."""
    reference = bvm.VM(robot_id=1)
    reference.load(_region_reference())
    reference.execute()
    table = {k: {"x": f32(x), "y": f32(y)} for k, (x, y) in enumerate(centres)}
    want = reference.call("region", table, len(centres), f32(margin), 8)
    vm = coverage_vm()
    vm["MARGIN"] = f32(margin)
    vm["HS_LOCAL"] = table
    vm["HS_KEYS"] = list(range(len(centres)))
    vm["HS_COUNT"] = len(centres)
    vm.call("cov_build_region")
    got = vm["REGION"]
    assert [(p["x"], p["y"]) for p in got.values()] == [(p["x"], p["y"]) for p in want.values()]


HOTSPOTS_EN = [(-10.0, -10.0), (30.0, -10.0), (30.0, 30.0), (-10.0, 30.0), (10.0, 45.0)]
FAR_HOTSPOTS_EN = [(60.0, 10.0), (100.0, 10.0), (80.0, 50.0)]


def coverage_run(drop: float, seed: int, hotspots: list[tuple[float, float]] = HOTSPOTS_EN):
    """6 robots: takeoff, the hotspots to two different robots, DEPLOY; until settled."""
    rc = sim_mod.RcCommand
    frame = geo.LocalFrame(*sim_mod.DEFAULT_ORIGIN)
    cmds = [rc(0.5, 1, 22)]
    seen = []  # the hotspots as robots get them: rc_goto holds binary32 lat/lon
    for k, (east, north) in enumerate(hotspots):
        lat, lon, _ = frame.to_gps(east, north, 0.0)
        cmds.append(rc(2.0 + 0.5 * k, 1 + k % 2, 16, (50.0 + k, lat, lon, 5.0)))
        x, y, _ = frame.from_gps(f32(lat), f32(lon), 0.0)
        seen.append((x, y))
    boundary = vor.convex_hull(seen, margin=20.0)

    def settled(sim) -> bool:
        pts = [(r.vehicle.x, r.vehicle.y) for r in sim.robots.values()]
        speeds = [math.hypot(r.vehicle.vx, r.vehicle.vy) for r in sim.robots.values()]
        return (
            sim.tick > 200
            and max(vor.centroid_distances(pts, boundary)) < 0.5
            and (max(speeds) < 0.05)
        )

    cmds.append(rc(6.0, 3, 901))
    sim = simulate("coverage.bzz", 6, drop, seed, cmds, 120.0, settled)
    pts = [(r.vehicle.x, r.vehicle.y) for r in sim.robots.values()]
    return sim, vor.centroid_distances(pts, boundary)


@pytest.mark.parametrize(("drop", "seed"), [(0.0, 1), (0.9, 2)])
def test_coverage_end_to_end(drop: float, seed: int) -> None:
    sim, dists = coverage_run(drop, seed)
    assert all(r.state == "DEPLOY" for r in sim.robots.values())
    assert all(r.vm["HS_COUNT"] == len(HOTSPOTS_EN) for r in sim.robots.values())
    assert max(dists) < 1.0


def test_coverage_brings_robots_in_from_outside_the_region() -> None:
    # The region is 40+ m away from the takeoff grid: every robot starts outside it, goes
    # to a random point inside (the voronoi closure), then Lloyd's algorithm takes over.
    sim, dists = coverage_run(0.5, 3, FAR_HOTSPOTS_EN)
    assert max(dists) < 1.0
