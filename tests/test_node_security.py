"""Signed nodes over a real UDP radio: what they accept, drop, report and keep on disk."""

from __future__ import annotations

import os
from pathlib import Path

from rigs import RIG_HOME, SimRig

import bvm
from fieldkit.node.autopilot_port import MavlinkAutopilot
from fieldkit.node.node import Node
from fieldkit.node.security import COUNTER_FILE, FLOORS_FILE, node_security
from fieldkit.radio.udp import UdpRadio
from fieldkit.robot import bundle_auth as A
from fieldkit.robot.link_security import NONE, SIGNED
from fieldkit.update.keys import init_keys, load_robot_keys

SRC = """
function step() {
  neighbors.broadcast("hi", id)
  seen = neighbors.count()
}
neighbors.listen("hi", function(topic, value, sender) { heard = value })
"""


def test_signed_nodes_hear_each_other_and_nothing_an_outsider_sends(tmp_path: Path) -> None:
    init_keys(tmp_path / "keys")
    keys = load_robot_keys(tmp_path / "keys")
    port = 26000 + os.getpid() % 2000
    rigs = [SimRig("solo", home=RIG_HOME, gps_fix_delay_s=0.0) for _ in range(3)]
    radios: list[UdpRadio] = []
    lines: dict[int, list[str]] = {1: [], 2: [], 3: []}
    try:
        nodes = []
        modes = {1: SIGNED, 2: SIGNED, 3: NONE}  # robot 3: a plain robot in the swarm
        for rid, r in zip((1, 2, 3), rigs, strict=True):
            r.connect()
            assert r.run_until(lambda r=r: r.link.telemetry.gps_fix_type >= 3, 10.0)
            t = r.link.telemetry
            home = (t.lat, t.lon, 0.0)
            radio = UdpRadio(rid, port=port, group="127.255.255.255")
            radios.append(radio)
            say = lines[rid].append
            security = node_security(rid, modes[rid], keys, tmp_path / f"state{rid}", say)
            nodes.append(
                Node(
                    r.profile,
                    bvm.compile_source(SRC, "hi.bzz"),
                    rid,
                    MavlinkAutopilot(r.link, home),  # type: ignore[arg-type]
                    radio,
                    home=home,  # type: ignore[arg-type]
                    clock=r.clock,
                    out=say,
                    security=security,
                )
            )
        outsider = UdpRadio(9, port=port, group="127.255.255.255")  # no keys
        radios.append(outsider)
        recorded: list[bytes] = []
        for k in range(40):
            for node, r in zip(nodes, rigs, strict=True):
                node.tick()
                r.tick()
            heard = [data for sender, data in outsider.poll() if sender == 1]
            recorded += heard
            if k >= 20 and recorded:
                outsider.send(recorded[k - 20 if k - 20 < len(recorded) else -1])  # replay
                forged = bytearray(recorded[-1])
                forged[50] ^= 1
                outsider.send(bytes(forged))  # edited under the old tag
        one, two, three = nodes
        assert two.runtime.vm["heard"] == 1 and two.runtime.vm["seen"] == 1  # not robot 3
        assert one.runtime.vm["heard"] == 2
        assert three.runtime.vm["seen"] == 0  # it can check no one: it hears no one
        s2 = two.summary()["security"]
        assert isinstance(s2, dict) and s2["mode"] == SIGNED and s2["accepted"] > 20
        rejected = s2["rejected"]
        assert rejected[A.MISSING_TRAILER] > 20  # robot 3's plain bundles
        assert (
            rejected.get(A.BAD_TAG, 0) >= 15
            and rejected.get(A.REPLAYED, 0) + rejected.get(A.TOO_OLD, 0) >= 15
        )
        assert list(s2["mixed"]) == ["3"]
        assert any("mixed security settings: robot 3 sends plain" in x for x in lines[2])
        assert any("robot 1 sends sealed" in x for x in lines[3])
        assert three.summary()["security"]["rejected"]["sealed"] > 20  # type: ignore[index]
        # The counter is on disk, ahead of every counter sent.
        text = (tmp_path / "state1" / COUNTER_FILE).read_text()
        assert int(text.split()[1]) > one.runtime.security.last_counter  # type: ignore[union-attr]
    finally:
        for radio in radios:
            radio.close()
        for r in rigs:
            r.close()


def test_a_rebooted_node_counts_on_and_its_neighbour_remembers(tmp_path: Path) -> None:
    init_keys(tmp_path / "keys")
    keys = load_robot_keys(tmp_path / "keys")
    from fieldkit.robot import bundle as B

    sender = node_security(1, SIGNED, keys, tmp_path / "s1", lambda _l: None)
    receiver = node_security(2, SIGNED, keys, tmp_path / "s2", lambda _l: None)
    sent = [sender.seal(B.encode_fields(1, (), 45.5, -73.5, 0.0, k)) for k in range(700)]
    for data in sent:
        assert receiver.open(data) is not None
    assert receiver.save_floors()  # 600 counters past nothing saved: due
    assert (tmp_path / "s2" / FLOORS_FILE).exists()
    # Both reboot: the sender starts past its reserved block, the receiver from its floors.
    sender = node_security(1, SIGNED, keys, tmp_path / "s1", lambda _l: None)
    receiver = node_security(2, SIGNED, keys, tmp_path / "s2", lambda _l: None)
    assert all(receiver.open(data) is None for data in sent)  # the old ones, replayed
    fresh = sender.seal(B.encode_fields(1, (), 45.5, -73.5, 0.0, 0))
    assert sender.last_counter > 700 and receiver.open(fresh) is not None


def test_signed_without_keys_or_state_dir_or_with_a_damaged_counter_says_what(
    tmp_path: Path,
) -> None:
    import pytest

    from fieldkit.errors import FieldkitError

    init_keys(tmp_path / "keys")
    keys = load_robot_keys(tmp_path / "keys")
    with pytest.raises(FieldkitError, match="--keys"):
        node_security(1, SIGNED, None, tmp_path / "s", print)
    with pytest.raises(FieldkitError, match="--state-dir"):
        node_security(1, SIGNED, keys, None, print)
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / COUNTER_FILE).write_text("fieldkit-bundle-counter-v1 banana\n")
    with pytest.raises(FieldkitError, match="bundle.counter: not a bundle counter file"):
        node_security(1, SIGNED, keys, tmp_path / "s", print)


GOT = """
function step() { if (flight.rc_cmd != 0) { got = flight.rc_cmd  n = n + 1 } }
n = 0
"""


def test_a_node_acts_on_the_operators_signed_command_once_and_relays_it(tmp_path: Path) -> None:
    from fieldkit.node.security import COMMAND_SEQ_FILE, node_commands
    from fieldkit.robot.operator_command import ALL, CommandSigner, OperatorCommand, sign_command
    from fieldkit.update.keys import load_signing_key

    init_keys(tmp_path / "keys")
    keys = load_robot_keys(tmp_path / "keys")
    signer = CommandSigner(load_signing_key(tmp_path / "keys"), tmp_path / "keys" / "command.seq")
    port = 28000 + os.getpid() % 2000
    rig = SimRig("solo", home=RIG_HOME, gps_fix_delay_s=0.0)
    radio = UdpRadio(1, port=port, group="127.255.255.255")
    ground = UdpRadio(200, port=port, group="127.255.255.255")
    try:
        rig.connect()
        assert rig.run_until(lambda: rig.link.telemetry.gps_fix_type >= 3, 10.0)
        t = rig.link.telemetry
        home = (t.lat, t.lon, 0.0)
        state = tmp_path / "state"
        node = Node(
            rig.profile,
            bvm.compile_source(GOT, "got.bzz"),
            1,
            MavlinkAutopilot(rig.link, home),  # type: ignore[arg-type]
            radio,
            home=home,  # type: ignore[arg-type]
            clock=rig.clock,
            out=lambda _l: None,
            security=node_security(1, SIGNED, keys, state, lambda _l: None),
            command_gate=node_commands(1, keys, state),
        )
        land = signer.sign(ALL, 21)
        forged = sign_command(load_signing_key(tmp_path / "keys"), OperatorCommand(99, 1, 22))
        forged = forged[:-1] + bytes([forged[-1] ^ 1])  # one bit of the signature
        relayed: list[bytes] = []
        for k in range(30):
            if k in (5, 10):
                ground.send(land)  # the second time: heard again, not acted on again
            if k == 15:
                ground.send(forged)
            node.tick()
            rig.tick()
            relayed += [d for s, d in ground.poll() if s == 1 and d == land]
        assert node.runtime.vm["got"] == 21 and node.runtime.vm["n"] == 1
        assert relayed == [land]  # passed on unchanged, once
        counters = node.summary()["commands"]
        assert isinstance(counters, dict)
        assert counters["accepted"] == 1 and counters["replayed"] == 1
        assert counters["bad-signature"] == 1
        assert (state / COMMAND_SEQ_FILE).read_text().split()[1] == "1"
    finally:
        radio.close()
        ground.close()
        rig.close()
