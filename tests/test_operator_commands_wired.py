"""Signed operator commands in the tick: acted on once, relayed once, forgeries refused;
and a script's own `cmd` broadcasts still spreading inside a signed swarm."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

import bvm
from fieldkit.robot import geo
from fieldkit.robot.operator_command import (
    ALL,
    CommandGate,
    CommandSeqStore,
    OperatorCommand,
    sign_command,
)
from fieldkit.robot.profiles import load_profile
from fieldkit.robot.rc import RcCommand
from fieldkit.robot.runtime import RobotRuntime
from fieldkit.robot.script_api import Sensors
from fieldkit.sim.simulator import SimConfig, Simulation

OPERATOR = Ed25519PrivateKey.from_private_bytes(b"\x01" * 32)
CAPTURED = Ed25519PrivateKey.from_private_bytes(b"\x02" * 32)  # not the operator's

SAYS = """
function step() { if (flight.rc_cmd != 0) { got = flight.rc_cmd  n = n + 1 } }
n = 0
"""


def sensors() -> Sensors:
    return Sensors(lat=45.5, lon=-73.5, alt=0.0, north=0.0, east=0.0)


def robot(rid: int, gate: CommandGate | None) -> RobotRuntime:
    rt = RobotRuntime(rid, load_profile("solo"), geo.LocalFrame(45.5, -73.5, 0.0), commands=gate)
    assert rt.start(bvm.compile_source(SAYS, "says.bzz"), sensors())
    return rt


def test_a_signed_command_is_acted_on_once_and_relayed_once(tmp_path: Path) -> None:
    pub = OPERATOR.public_key()
    one = robot(1, CommandGate(1, pub, CommandSeqStore(tmp_path / "one.seq")))
    two = robot(2, CommandGate(2, pub))
    land = sign_command(OPERATOR, OperatorCommand(5, ALL, 21))
    one.receive_bundle(land)
    one.tick(sensors())
    assert one.vm["got"] == 21 and one.vm["n"] == 1
    relayed = one.take_relays()
    assert relayed == [land] and one.take_relays() == []  # unchanged, once
    two.receive_bundle(relayed[0])  # robot 2 was out of the ground station's range
    two.tick(sensors())
    assert two.vm["got"] == 21
    one.receive_bundle(land)  # heard again (robot 2's relay, or a replay)
    one.tick(sensors())
    assert one.vm["n"] == 1 and one.relays == []
    # After a reboot the store still knows sequence 5.
    again = robot(1, CommandGate(1, pub, CommandSeqStore(tmp_path / "one.seq")))
    again.receive_bundle(land)
    again.tick(sensors())
    assert again.vm["n"] == 0


def test_forged_commands_are_refused_and_without_a_gate_ignored() -> None:
    pub = OPERATOR.public_key()
    one = robot(1, CommandGate(1, pub))
    forged = sign_command(CAPTURED, OperatorCommand(9, ALL, 22))  # a captured robot's try
    one.receive_bundle(forged)
    one.tick(sensors())
    assert one.vm["n"] == 0 and one.relays == []
    assert one.commands is not None and one.commands.counters["unknown-key"] == 1
    plain = robot(2, None)  # no operator.pub: nothing can be checked, nothing acted on
    plain.receive_bundle(sign_command(OPERATOR, OperatorCommand(1, ALL, 22)))
    plain.tick(sensors())
    assert plain.vm["n"] == 0 and plain.counters["commands_unchecked"] == 1


SPREAD = """
neighbors.listen("cmd", function(topic, value, sender) { if (value == 22) BVMSTATE = "GOT" })
function init() { BVMSTATE = "WAIT" }
function step() {
  if (flight.rc_cmd == 22) BVMSTATE = "GOT"
  if (BVMSTATE == "GOT") neighbors.broadcast("cmd", 22)
}
"""


@pytest.mark.parametrize("security", ["signed", "none"])
def test_a_scripts_cmd_broadcast_spreads_in_a_signed_swarm_as_in_a_plain_one(
    tmp_path: Path, security: str
) -> None:
    script = tmp_path / "spread.bzz"
    script.write_text(SPREAD)
    logging.disable(logging.WARNING)
    try:
        sim = Simulation(
            SimConfig(
                script=script,
                robots=6,
                seconds=5.0,
                drop=0.3,
                commands=[RcCommand(1.0, 1, 22)],  # robot 1 only
                security=security,
                swarm_key=b"s" * 32,
                operator_pub=OPERATOR.public_key(),
            )
        )
        sim.run()
    finally:
        logging.disable(logging.NOTSET)
    assert set(sim.summary()["final_states"].values()) == {"GOT"}  # type: ignore[union-attr]
