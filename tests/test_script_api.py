"""The script API: closures queue commands, globals reach the script, ROSBuzz's bugs fixed."""

from __future__ import annotations

import pytest

import bvm
from fieldkit.robot import geo
from fieldkit.robot.polygon import inside, segment_exit
from fieldkit.robot.script_api import Command, ScriptAPI, Sensors

HERE = (45.5, -73.6)


def robot(src: str, rid: int = 3) -> tuple[bvm.VM, ScriptAPI, list[str]]:
    lines: list[str] = []
    vm = bvm.VM(robot_id=rid)
    vm.load(bvm.compile_source(src, "api.bzz"))
    api = ScriptAPI(vm, takeoff_altitude=12.0, log_sink=lambda _r, text: lines.append(text))
    api.install()
    vm.execute()
    return vm, api, lines


def sensors(north: float = 10.0, east: float = -5.0, alt: float = 8.0, **kw: object) -> Sensors:
    lat, lon = geo.offset_gps(*HERE, north, east)
    return Sensors(lat=lat, lon=lon, alt=alt, north=north, east=east, **kw)  # type: ignore[arg-type]


def test_goto_abs_latches_an_absolute_target() -> None:
    vm, api, _ = robot("function step() { goto_abs(1.5, 2, -1.0, 0.0) }")
    api.before_step(sensors(), [])
    vm.call("step")
    assert api.after_step() == [Command("goto", (11.5, -3.0, 7.0))]
    # A later tick without a goto_abs queues nothing: the vehicle keeps the absolute target.
    api.before_step(sensors(north=11.0), [])
    assert api.after_step() == []


def test_commands_queue_in_order_with_int_arguments() -> None:
    vm, api, _ = robot("function step() { arm() uav_takeoff(10) uav_land() gohome() disarm() }")
    api.before_step(sensors(), [])
    vm.call("step")
    assert [c.kind for c in api.after_step()] == ["arm", "takeoff", "land", "rtl", "disarm"]


def test_globals_reach_the_script() -> None:
    vm, api, _ = robot(
        """
        function step() {
          seen = {.alt = pose.position.altitude, .x = pose.position.x, .st = flight.status,
                  .rc = flight.rc_cmd, .bat = battery.capacity, .goal = rc_goto.id,
                  .n = neighbors.count(), .robots = ROBOTS, .vt = V_TYPE,
                  .ta = TARGET_ALTITUDE}
        }
        """
    )
    api.before_step(
        sensors(status=2, rc_cmd=900, battery_percent=77, rc_goto=(55, 45.5, -73.6, 10.0)),
        [(4, 12.0, 0.5, 0.0)],
    )
    vm.call("step")
    assert vm["seen"] == {
        "alt": 8.0,
        "x": 10.0,
        "st": 2,
        "rc": 900,
        "bat": 77,
        "goal": 55,
        "n": 1,
        "robots": 1,
        "vt": 0,
        "ta": 12.0,
    }


def test_robots_follows_swarm_membership_with_hysteresis() -> None:
    vm, api, _ = robot("s = swarm.create(1) s.join() function step() {}")
    api.before_step(sensors(), [])
    for peer in (4, 5):
        vm.receive(peer, bvm.wire.encode(bvm.wire.SwarmJoin(1)))
    vm.process_inbox()
    vm.call("step")
    api.after_step()
    assert vm["ROBOTS"] == 1  # one reading of 3 is not enough
    api.after_step()
    assert vm["ROBOTS"] == 3
    vm.swarms.peers.clear()
    for _ in range(149):
        api.after_step()
    assert vm["ROBOTS"] == 3  # a decrease needs 150 readings
    api.after_step()
    assert vm["ROBOTS"] == 1


def test_storegoal_refuses_far_goals() -> None:
    vm, api, lines = robot(
        """
        function step() {
          var near = pose.position.latitude + 0.0005
          storegoal(near, pose.position.longitude, 10.0)
          first = cur_goal.latitude
          storegoal(pose.position.latitude + 0.01, pose.position.longitude, 10.0)
          second = cur_goal.latitude
        }
        """
    )
    api.before_step(sensors(), [])
    vm.call("step")
    assert vm["first"] == vm["second"] != api.sensors.lat  # type: ignore[union-attr]
    assert any("too far" in line for line in lines)


def test_log_prefixes_the_robot_id() -> None:
    # The values joined with nothing between them, as `fieldkit run` prints them (compat H2).
    vm, api, lines = robot("log('state ', 3, ' ', 1.5, nil)", rid=7)
    assert lines == ["[7] state 3 1.500000[nil]"]


def test_type_errors_say_which_argument() -> None:
    vm, api, _ = robot("function step() { goto_abs('a', 0, 0, 0) }")
    api.before_step(sensors(), [])
    with pytest.raises(bvm.BuzzError, match=r"goto_abs\(dx\): expected a number, got string"):
        vm.call("step")


def test_polygon_helpers() -> None:
    square = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)]
    assert inside((5.0, 5.0), square) and inside((10.0, 5.0), square)
    assert not inside((11.0, 5.0), square) and not inside((5.0, -0.1), square)
    assert segment_exit((5.0, 5.0), (15.0, 5.0), square) == pytest.approx((10.0, 5.0))
    assert segment_exit((2.0, 2.0), (3.0, 3.0), square) is None


@pytest.mark.parametrize("clockwise", [False, True])
def test_voronoi_returns_the_cell_centroid_and_sets_the_goal_halfway(clockwise: bool) -> None:
    corners = ".0 = {.x = -10.0, .y = -10.0}, .1 = {.x = 10.0, .y = -10.0}, "
    corners += ".2 = {.x = 10.0, .y = 10.0}, .3 = {.x = -10.0, .y = 10.0}"
    vm, api, _ = robot(
        f"""
        function step() {{
          var corners = {{ {corners} }}
          var t = {{.np = 4}}
          var k = 0
          while (k < 4) {{
            if ({int(clockwise)} == 1) t[k] = corners[3 - k] else t[k] = corners[k]
            k = k + 1
          }}
          t[4] = {{.x = 0.0, .y = 0.0}}
          t[5] = {{.x = 10.0, .y = 0.0}}
          c = voronoi(t)
        }}
        """
    )
    s = sensors(north=0.0, east=0.0)
    api.before_step(s, [])
    vm.call("step")
    assert vm["c"]["x"] == pytest.approx(-2.5) and vm["c"]["y"] == pytest.approx(0.0, abs=1e-6)
    lat, lon, _ = api.cur_goal  # type: ignore[misc]
    north, east = geo.ned_offset(s.lat, s.lon, lat, lon)
    assert north == pytest.approx(-1.25, abs=1e-3) and east == pytest.approx(0.0, abs=1e-3)
