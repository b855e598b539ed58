"""Nothing a tick calls imports a module or compiles on its first call (issue 13, item 11).

A node running coverage missed its 100 ms deadline at its first Voronoi cell: the closure
imported scipy (250-310 ms) inside the tick. The probe below starts a real node (a simulated
ArduPilot on a pty, a UDP radio hearing five neighbours), records `sys.modules`, then runs a
script that calls every closure of the script API and the standard library's swarm parts, and
prints whatever got imported, and how many functions got translated, after start-up. It
runs in a fresh interpreter: this one has imported everything already.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import bvm
from fieldkit.robot import geo
from fieldkit.robot.profiles import load_profile
from fieldkit.robot.script_api import ScriptAPI

TESTS = Path(__file__).resolve().parent

#: Calls every closure the script API installs, with arguments that take their real paths
#: (a region Qhull must hull, a shape that composes letters), from tick 3 on: after start.
EVERY_CLOSURE = """
function init() {
  t = 0
  heard = {}
  neighbors.listen("p", function(topic, value, sender) { heard[sender] = value })
  s = swarm.create(1)
  s.join()
  v = stigmergy.create(1)
}
function step() {
  t = t + 1
  neighbors.broadcast("p", id)
  if (t < 3) { return }
  log("tick", t)
  print("tick", t)
  debug("tick", t)
  uav_takeoff(TARGET_ALTITUDE)
  uav_land()
  gohome()
  arm()
  disarm()
  goto_abs(1.0, 2.0, 0.0, 0.0)
  storegoal(pose.position.latitude, pose.position.longitude, 5.0)
  geofence({.0 = {.x = 50.0, .y = 0.0}, .1 = {.x = 10.0, .y = 10.0},
            .2 = {.x = -10.0, .y = 10.0}, .3 = {.x = -10.0, .y = -10.0},
            .4 = {.x = 10.0, .y = -10.0}})
  # Corners out of order: not convex as given, so the closure asks Qhull for the hull.
  voronoi({.np = 4, .0 = {.x = 30.0, .y = 30.0}, .1 = {.x = -30.0, .y = -30.0},
           .2 = {.x = 30.0, .y = -30.0}, .3 = {.x = -30.0, .y = 30.0},
           .4 = {.x = 0.0, .y = 0.0}, .5 = {.x = 5.0, .y = 3.0}, .6 = {.x = -4.0, .y = 6.0}})
  voronoi({.np = 3, .0 = {.x = 90.0, .y = 90.0}, .1 = {.x = 100.0, .y = 90.0},
           .2 = {.x = 100.0, .y = 100.0}, .3 = {.x = 0.0, .y = 0.0}})
  setgimbal(0.0, 0.0, 0.0, 1.0)
  takepicture()
  reset_rc()
  export_map({})
  add_neighborStatus({})
  add_targetrb(2, 45.5, -73.5)
  g = load_graph("P")
  gg = load_graph("PO")
  n = neighbors.count()
  near = neighbors.filter(function(rid, data) { return data.distance < 100.0 })
  d = neighbors.reduce(function(rid, data, acc) { return acc + data.distance }, 0.0)
  neighbors.foreach(function(rid, data) { x = math.atan(data.elevation, data.azimuth) })
  k = neighbors.kin()
  nk = neighbors.nonkin()
  s.select(t % 2 == 0)
  v.put(id, t)
  w = v.get(id)
  q = string.concat("a", string.tostring(math.sqrt(2.0)), string.sub("abc", 1, 2))
  r = math.rng.uniform(1.0) + math.rng.gaussian(1.0, 2.0)
}
"""

PROBE = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
from rigs import RIG_HOME, SimRig
import bvm
from fieldkit.node.autopilot_port import MavlinkAutopilot
from fieldkit.node.node import Node
from fieldkit.radio import open_radio
from fieldkit.robot import RobotRuntime, geo
from fieldkit.robot.script_api import Sensors

port = int(sys.argv[3])
url = f"udp://127.255.255.255:{port}"
program = bvm.compile_source(sys.argv[2])
rig = SimRig("solo", home=RIG_HOME, gps_fix_delay_s=0.0)
rig.connect()
assert rig.run_until(lambda: rig.link.telemetry.gps_fix_type >= 3, 10.0)
t = rig.link.telemetry
home = (t.lat, t.lon, 0.0)
frame = geo.LocalFrame(*home)
radio = open_radio(url, 1)
node = Node(rig.profile, program, 1, MavlinkAutopilot(rig.link, home), radio, home=home,
            clock=rig.clock, out=lambda text: None)
# Five neighbours: runtimes of their own, their bundles on the same UDP port.
others = []
for rid in range(2, 7):
    runtime = RobotRuntime(
        rid, rig.profile, frame, log_sink=lambda text: None, translate_ahead=True
    )
    sensors = Sensors(lat=home[0] + rid * 1e-5, lon=home[1], alt=0.0, north=rid * 1.1, east=0.0)
    runtime.start(program, sensors)
    others.append((runtime, sensors, open_radio(url, rid)))
# One tick of everything before the snapshot would hide a first-call import: none here.
before = set(sys.modules)
import bvm.vm
translated = []
real_translate = bvm.vm._translate.translate
def counting(*args, **kwargs):
    translated.append(args[1])
    return real_translate(*args, **kwargs)
bvm.vm._translate.translate = counting
errors = []
for _ in range(30):
    for runtime, sensors, link in others:
        for _sender, data in link.poll():
            runtime.receive_bundle(data)
        link.send(runtime.tick(sensors).bundle)
    node.tick()
    rig.tick()
for runtime, _, _ in [(node.runtime, None, None), *others]:
    if runtime.error is not None:
        errors.append(runtime.error)
print(json.dumps({
    "imported": sorted(set(sys.modules) - before),
    "translations": len(translated),
    "errors": errors,
    "heard": sorted(node.runtime.heard),
    "frames_in": node.radio.stats.get("datagrams_in", 0),
    "voronoi_calls": node.runtime.vm.globals.get("t"),
}))
"""


def free_port() -> int:
    """A UDP port nothing on this machine is bound to now."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def installed_closures() -> set[str]:
    """The closure names the script API installs (beyond a bare VM's)."""
    vm = bvm.VM(robot_id=1)
    vm.load(bvm.compile_source("x = 1"))
    bare = set(vm.globals)
    ScriptAPI(vm).install()
    return {n for n, v in vm.globals.items() if n not in bare and isinstance(v, bvm.Closure)}


def test_the_probe_calls_every_closure_of_the_script_api() -> None:
    """A closure added later without a call in the probe fails here, not in the field."""
    missing = {n for n in installed_closures() if f"{n}(" not in EVERY_CLOSURE}
    assert not missing


def test_a_node_imports_nothing_after_start_up() -> None:
    done = subprocess.run(
        [sys.executable, "-c", PROBE, str(TESTS), EVERY_CLOSURE, str(free_port())],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    got = json.loads(done.stdout.strip().splitlines()[-1])
    assert got["errors"] == []
    assert got["voronoi_calls"] == 30  # every tick ran, closures from tick 3 on
    assert got["frames_in"] > 0 and got["heard"] == [2, 3, 4, 5, 6]
    assert got["imported"] == []
    assert got["translations"] == 0  # translated at start (`VM.prepare`), not in a tick


def test_the_shipped_graphs_are_read_when_the_api_is_installed() -> None:
    """`load_graph` in a tick finds its shape in memory: no file is opened then."""
    from fieldkit.robot import shapes

    shapes._read_dir.cache_clear()
    shapes._compose_cached.cache_clear()  # else an earlier test's "PO" answers from its cache
    vm = bvm.VM(robot_id=1)
    vm.load(bvm.compile_source("x = 1"))
    ScriptAPI(vm).install()
    assert shapes._read_dir.cache_info().currsize == 1
    hits = shapes._read_dir.cache_info().hits
    shapes.graph_table("PO")
    assert shapes._read_dir.cache_info().hits == hits + 1  # composed from what was read


def test_geo_home_is_where_the_simulators_start() -> None:
    """One default home: the simulator's origin (the vehicle simulator's home follows it)."""
    from fieldkit.sim.simulator import DEFAULT_ORIGIN
    from fieldkit.vehicle.sim.ardupilot import DEFAULT_HOME

    assert DEFAULT_ORIGIN[:2] == DEFAULT_HOME == geo.DEFAULT_HOME
    assert load_profile("solo").name == "solo"
