"""The ground station: status frames, the sans-I/O core, its page's HTTP API, and
`fieldkit cmd` reaching a line of simulated robots through one of them (real sockets, a real
subprocess, the real simulator)."""

from __future__ import annotations

import json
import random
import subprocess
import sys
import threading
import urllib.error
import urllib.request
from pathlib import Path

import pytest
from typer.testing import CliRunner

from fieldkit import resources
from fieldkit.cli import app
from fieldkit.ground.core import GroundError, GroundStation
from fieldkit.ground.live import run_live
from fieldkit.ground.station import SimGround, UdpGateway
from fieldkit.ground.web import GroundServer
from fieldkit.robot import bundle as wirebundle
from fieldkit.robot import geo, status
from fieldkit.robot.operator_command import SIGNER_SEQ_FILE, CommandSigner
from fieldkit.robot.status import StatusGossip, StatusRecord
from fieldkit.sim.simulator import SimConfig, Simulation, StartPose
from fieldkit.update.keys import init_keys, load_robot_keys, load_signing_key

HOME = (45.5017, -73.5673)


def _record(robot: int, acked: int = 0, ground: bool = False) -> StatusRecord:
    return StatusRecord(robot, 0, 87, 2, "running", 4.94, acked, 45.5017123, -73.5673456,
                        "JOINED", ground)  # fmt: skip


# ------------------------------------------------------------------ status frames


def test_status_frame_round_trip_sealed_and_plain() -> None:
    key = status.status_key(b"k" * 32)
    records = [_record(3, acked=7), _record(0, ground=True)]
    for k in (None, key):
        data = status.encode(9, records, k)
        assert status.is_status(data) and len(data) == 8 + 40 * 2 + (8 if k else 0)
        sender, back = status.decode(data, k)
        assert sender == 9
        assert back[0].acked == 7 and back[0].state == "JOINED" and back[0].battery == 87
        assert back[0].alt == pytest.approx(4.9) and back[0].lat == pytest.approx(45.5017123)
        assert back[1].ground and not back[0].ground


def test_status_frame_refuses_forged_cut_and_random_bytes() -> None:
    key = status.status_key(b"k" * 32)
    data = status.encode(9, [_record(3)], key)
    flipped = bytearray(data)
    flipped[20] ^= 1
    for bad in (bytes(flipped), data[:-8], status.encode(9, [_record(3)], None)):
        with pytest.raises(status.StatusError):
            status.decode(bad, key)
    with pytest.raises(status.StatusError, match="sealed"):
        status.decode(data, None)
    rng = random.Random(1)
    for _ in range(3000):  # hostile bytes: only StatusError, ever
        junk = bytes(rng.getrandbits(8) for _ in range(rng.choice((8, 48, 56, 88, 211))))
        junk = junk[:6] + b"\x00\x12" + junk[8:] if rng.random() < 0.5 else junk
        try:
            status.decode(junk, key if rng.random() < 0.5 else None)
        except status.StatusError:
            pass


def test_robots_stay_silent_until_a_ground_station_is_heard() -> None:
    robot = StatusGossip(5)
    robot.set_own(_record(5))
    assert all(robot.frame(t) is None for t in range(50))  # a swarm without ground: no bytes
    ground = StatusGossip(0, ground=True)
    ground.set_own(_record(0))
    beacon = ground.frame(0)
    assert beacon is not None
    robot.receive(beacon, 50)
    assert robot.active
    first = robot.frame(50)
    assert first is not None  # at once: a ground station appeared
    assert robot.frame(51) is None  # then once a period
    robot.set_own(_record(5, acked=3))
    assert robot.frame(52) is not None  # an acknowledgement goes at once
    assert robot.frame(53 + status.TTL_TICKS) is None or not robot.active  # ground gone


def test_acks_cross_a_line_of_gossips_one_hop_a_tick() -> None:
    line = [StatusGossip(i) for i in range(1, 6)]
    ground = StatusGossip(0, ground=True)
    ground.set_own(_record(0))
    acked_at: dict[int, int] = {}
    frames = {0: ground.frame(0)}
    for t in range(1, 40):
        heard: dict[int, bytes | None] = {}
        for i, g in enumerate(line, start=1):
            for nb in (i - 1, i + 1):  # a line: each hears its neighbours only
                data = frames.get(nb)
                if data is not None:
                    g.receive(data, t)
            g.set_own(_record(i, acked=1 if t >= 10 else 0))
            heard[i] = g.frame(t)
        data = heard.get(1)
        if data is not None:
            for r in ground.receive(data, t):
                if r.acked >= 1:
                    acked_at.setdefault(r.robot, t)
        frames = {0: ground.frame(t), **heard}
    assert sorted(acked_at) == [1, 2, 3, 4, 5]
    assert max(acked_at.values()) - 10 <= 8  # about a hop a tick, not a period


def test_a_stale_record_does_not_come_back_once_forgotten() -> None:
    g = StatusGossip(1, ttl=20, period=5)
    g.set_own(_record(1))
    old = status.encode(7, [_record(7, ground=True)])
    g.receive(old, 0)
    assert g.active
    g.frame(100)  # expires it
    assert not g.active and 7 not in g.table
    g.receive(old, 101)  # a neighbour still passing it on
    assert 7 not in g.table and not g.active


# ------------------------------------------------------------------ the core


@pytest.fixture
def keys(tmp_path: Path) -> Path:
    init_keys(tmp_path / "keys")
    return tmp_path / "keys"


def _station(keys: Path, **kw: object) -> GroundStation:
    rk = load_robot_keys(keys)
    return GroundStation(
        swarm_key=None,
        signer=CommandSigner(load_signing_key(keys), keys / SIGNER_SEQ_FILE),
        operator_pub=rk.operator_pub,
        origin=HOME,
        **kw,  # type: ignore[arg-type]
    )


def _bundle(robot: int, lat: float, lon: float, number: int = 0) -> bytes:
    return wirebundle.encode_fields(robot, [], lat, lon, 5.0, number)


def test_core_survives_malformed_frames_and_lying_robots(keys: Path) -> None:
    gs = _station(keys)
    gs.hear(_bundle(1, *HOME), 0.0, 1)
    gs.hear(b"\x00" * 7, 0.1, 3)  # not whole words
    gs.hear(b"\xff" * 48, 0.2, 3)  # unknown type
    gs.hear(_bundle(2, *HOME)[:-8] + b"\x01" * 8, 0.3, 2)  # a bundle whose words lie
    gs.hear(_bundle(4, 10.0, 10.0), 0.4, 4)  # thousands of km away
    gs.hear(_bundle(1, HOME[0] + 0.01, HOME[1]), 0.5, 1)  # 1.1 km in half a second
    snap = gs.snapshot()
    robots = {r["id"]: r for r in snap["robots"]}
    assert robots[4]["suspect"].startswith("a position") and robots[4]["east"] is None
    assert robots[1]["suspect"].startswith("a jump") and abs(robots[1]["north"]) < 1
    texts = " ".join(e["text"] for e in snap["events"])
    assert "not whole 8-byte words" in texts and "unknown type" in texts
    assert gs.counters["malformed"] >= 2 and gs.counters["suspect"] == 2
    json.dumps(snap)


def test_core_refuses_commands_it_cannot_send(keys: Path) -> None:
    gs = _station(keys)
    gs.hear(_bundle(1, *HOME), 0.0, 1)
    with pytest.raises(GroundError, match="robot 9 is not in the swarm"):
        gs.command(22, (), 9)
    with pytest.raises(GroundError, match="4 params"):
        gs.command(16, (50, 1.0))
    watcher = GroundStation(origin=HOME)
    with pytest.raises(GroundError, match="--keys"):
        watcher.command(22)
    with pytest.raises(GroundError, match="root robot's id"):
        gs.command(900, (2.5,))
    c = gs.command(22, (), 1)
    sent = [f for f in gs.tick(0.1) if not status.is_status(f)]
    assert sent == [c.frame]  # sent, then again only after RESEND_S
    assert [f for f in gs.tick(0.2) if not status.is_status(f)] == []


def test_the_task_graph_is_drawn_at_the_root_a_900_names(keys: Path) -> None:
    gs = _station(keys, shape="P", root_id=1)
    for rid, north in ((1, 0.0), (3, 20.0)):
        lat, lon = geo.LocalFrame(*HOME, 0.0).to_gps(0.0, north, 0.0)[:2]
        gs.hear(_bundle(rid, lat, lon), 0.0, rid)
    at = lambda: gs.snapshot()["graph"][0]  # noqa: E731  label 0's node
    assert at() == [0.0, 0.0]
    gs.command(900, (3,))
    assert gs.root_id == 3 and at() == [0.0, 20.0]
    gs.command(900)  # a plain 900: the configured root again, as the robots do
    assert gs.root_id == 1 and at() == [0.0, 0.0]


# ------------------------------------------------------------------ the page's API


def _get(url: str) -> tuple[int, dict[str, object]]:
    try:
        with urllib.request.urlopen(url, timeout=10) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


def _post(url: str, body: bytes) -> tuple[int, dict[str, object]]:
    req = urllib.request.Request(url, body, {"Content-Type": "application/json"})
    return _get(req)  # type: ignore[arg-type]


def test_page_api_serves_the_view_and_clear_errors(keys: Path) -> None:
    gs = _station(keys)
    gs.hear(_bundle(1, *HOME), 0.0, 1)
    server = GroundServer(gs, port=0)
    server.start()
    try:
        base = server.url
        with urllib.request.urlopen(base, timeout=10) as r:
            assert b"fieldkit ground station" in r.read()
        with urllib.request.urlopen(base + "static/app.js", timeout=10) as r:
            assert b"EventSource" in r.read()
        status_code, view = _get(base + "api/state")
        assert status_code == 200 and [r["id"] for r in view["robots"]] == [1]  # type: ignore[index]
        for body, text in (
            (b"not json", "Expecting value"),
            (b'{"code": "fly"}', "unknown command"),
            (b'{"code": 22, "to": 7}', "robot 7 is not in the swarm"),
            (b'{"code": 22, "to": "x"}', "a robot id"),
        ):
            code, answer = _post(base + "api/command", body)
            assert code == 400 and text in str(answer["error"])
        code, answer = _post(base + "api/command", b'{"code": "takeoff"}')
        assert code == 200 and answer["seq"] == 1
        # two streams at once, one dropped halfway: the server goes on serving
        streams = [urllib.request.urlopen(base + "api/stream", timeout=10) for _ in range(2)]
        assert streams[0].readline().startswith(b"data: {")
        streams[0].close()
        assert streams[1].readline().startswith(b"data: {")
        streams[1].close()
        assert _get(base + "api/state")[0] == 200
        assert _get(base + "api/nothing")[0] == 404
    finally:
        server.stop()


# ------------------------------------------------------------------ fieldkit cmd, multi-hop


def test_cmd_reaches_a_line_of_five_through_robot_1(keys: Path, tmp_path: Path) -> None:
    """The ground station (and its gateway) hears robot 1 only; robots 10 m apart hear their
    neighbours only: the command hops down the line and every robot's ack hops back."""
    rk = load_robot_keys(keys)
    start = {i: StartPose(east=10.0 * (i - 1), north=0.0) for i in range(1, 6)}
    cfg = SimConfig(
        script=resources.find_script("task_allocation.bzz"),
        robots=5,
        range_m=12.0,
        seconds=1e6,
        start=start,
        security="signed",
        swarm_key=rk.swarm_key,
        operator_pub=rk.operator_pub,
    )
    sim = Simulation(cfg)
    gateway = UdpGateway(0)
    peer = SimGround(sim, GroundStation(swarm_key=rk.swarm_key, origin=HOME), (-8.0, 0, 0),
                     gateway=gateway)  # fmt: skip
    sim.peers.append(peer)
    assert [r for r, robot in sim.robots.items() if peer._in_range(robot.vehicle.position)] == [1]
    stop = threading.Event()
    runner = threading.Thread(target=run_live, args=(sim, 120.0), kwargs={"stop": stop})
    runner.start()
    try:
        done = subprocess.run(
            [sys.executable, "-m", "fieldkit", "cmd", "takeoff", "--radio", gateway.url,
             "--keys", str(keys), "--timeout", "30"],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        acted = [r.runtime.commands.last_acted for r in sim.robots.values()]  # type: ignore[union-attr]
        # A root nobody hears would leave every robot FREE: refused before sending.
        rootless = subprocess.run(
            [sys.executable, "-m", "fieldkit", "cmd", "task-allocation", "9", "--radio",
             gateway.url, "--keys", str(keys), "--listen", "3"],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
    finally:
        stop.set()
        runner.join(60)
        gateway.close()
    assert done.returncode == 0, done.stderr
    assert "acknowledged by 1, 2, 3, 4, 5" in done.stdout
    assert rootless.returncode == 1, rootless.stderr
    assert "error: task-allocation root 9: no such robot heard in 3 s (heard: 1" in (
        rootless.stderr
    )
    assert [r.runtime.commands.last_acted for r in sim.robots.values()] == acted  # type: ignore[union-attr]
    for rid in range(1, 6):
        assert sim.robots[rid].runtime.commands is not None
        assert sim.robots[rid].runtime.commands.last_acted >= 1
    # A robot that does not exist: a clear error naming who is there, exit 1.
    missing = subprocess.run(
        [sys.executable, "-m", "fieldkit", "cmd", "land", "--to", "9", "--radio", gateway.url,
         "--keys", str(keys), "--listen", "0.5"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert missing.returncode == 1
    assert "error:" in missing.stderr and "Traceback" not in missing.stderr


@pytest.mark.parametrize(
    ("params", "problem"),
    [(["2.5"], "900's param is the root robot's id (0..65535), got 2.5"),
     (["--", "-1"], "got -1"), (["1e40"], "within a float's range")],
)  # fmt: skip
def test_cmd_refuses_a_root_that_is_no_robot_id(params: list[str], problem: str) -> None:
    result = CliRunner().invoke(
        app, ["cmd", "task-allocation", "--radio", "udp://127.0.0.1:9", *params]
    )
    assert result.exit_code == 2, result.output
    assert problem in result.stderr
