"""Signed operator commands (fieldkit.robot.operator_command): the frame's bytes, the gate
that relays each valid frame once and acts on each command once (reboots included), and the
sequence files on both ends (docs/security.md#signed-operator-commands)."""

from __future__ import annotations

import hashlib
import hmac
import pickle
import struct
from pathlib import Path

import pytest
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from hypothesis import given
from hypothesis import strategies as st

from fieldkit.errors import FieldkitError
from fieldkit.robot import bundle as B
from fieldkit.robot import bundle_auth as A
from fieldkit.robot import operator_command as C
from fieldkit.robot.rc import RcCommand
from fieldkit.update import keys
from fieldkit.update import packets as pk

OPERATOR = Ed25519PrivateKey.from_private_bytes(bytes(range(32)))
PUB = OPERATOR.public_key()
STRANGER = Ed25519PrivateKey.from_private_bytes(bytes(range(32, 64)))
WAYPOINT = (7.0, 45.5, -73.6, 10.0)


def frame(seq: int, target: int = 3, code: int = 22, params: tuple[float, ...] = ()) -> bytes:
    return C.sign_command(OPERATOR, C.OperatorCommand(seq, target, code, params))


def forged(
    key: Ed25519PrivateKey, cmd: C.OperatorCommand, key_id: bytes = C.operator_key_id(PUB)
) -> bytes:
    """`cmd` signed by `key` under `key_id` (by default, claiming to be the operator)."""
    image = C._image(cmd, key_id)
    return C._swap(image + key.sign(C.DOMAIN + image))


def words(air: bytes) -> list[bytes]:
    return [air[i : i + 8] for i in range(0, len(air), 8)]


def reason_of(gate: C.CommandGate, data: object) -> str | None:
    res = gate.receive(data)  # type: ignore[arg-type]
    assert isinstance(res, C.GateResult)
    if res.reason in (C.BAD_FORMAT, C.UNKNOWN_KEY, C.BAD_SIGNATURE):
        assert res.act is None and res.relay is None
    return res.reason


# ------------------------------------------------------------------ format


@pytest.mark.parametrize(
    "cmd",
    [
        C.OperatorCommand(1, 3, 22),
        C.OperatorCommand(2, C.ALL, 21),
        C.OperatorCommand(3, 0, 16, WAYPOINT),
        C.OperatorCommand(C.MAX_SEQ, 0xFFFE, 0xFFFF, (1.5,)),
        C.OperatorCommand(5, 300, 900, (-0.0, 1e300)),
    ],
)
def test_round_trip(cmd: C.OperatorCommand) -> None:
    air = C.sign_command(OPERATOR, cmd)
    assert len(air) == C.MIN_COMMAND_BYTES + 8 * len(cmd.params) <= C.MAX_COMMAND_BYTES
    assert C.is_command(air)
    got, key_id, message, signature = C.decode_command(air)
    assert got == cmd
    assert key_id == C.operator_key_id(PUB)
    assert message.startswith(C.DOMAIN) and len(signature) == 64
    PUB.verify(signature, message)  # raises if not the operator's signature over the message
    robot = 3 if cmd.target == C.ALL else cmd.target
    res = C.CommandGate(robot, PUB).receive(air)
    assert res == C.GateResult(cmd, air, None)


def test_the_byte_layout_worked_example() -> None:
    """The waypoint command of docs/security.md, field by field on the air."""
    cmd = C.OperatorCommand(0x0102030405, 3, 16, WAYPOINT)
    air = C.sign_command(OPERATOR, cmd)
    assert len(air) == 120 and len(air) <= pk.MAX_FRAME_BYTES
    w = words(air)
    # Word 0, memory: type 17 (u16 LE), format 1, 4 params, target 3 (u16 LE), code 16
    # (u16 LE); on the air the word is reversed: code, target, count, format, type.
    assert w[0] == bytes.fromhex("0010 0003 04 01 0011")
    assert w[0][6:8] == (17).to_bytes(2, "big")  # what is_command reads
    assert w[1] == bytes.fromhex("0000000102030405")  # the sequence number, a u64
    for i, p in enumerate(WAYPOINT):
        assert w[2 + i] == struct.pack(">d", p)  # an f64 word, big-endian on the air
    raw = PUB.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    key_id = hashlib.sha256(raw).digest()[:8]
    assert C.operator_key_id(PUB) == key_id
    assert w[6] == key_id[::-1]
    image = b"".join(x[::-1] for x in w)
    assert image[:56] == (
        bytes.fromhex("1100 01 04 0300 1000 0504030201000000")
        + struct.pack("<4d", *WAYPOINT)
        + key_id
    )
    signature = b"".join(x[::-1] for x in w[7:])
    # Ed25519 is deterministic: the operator's key signs exactly this message to exactly this.
    assert signature == OPERATOR.sign(b"fieldkit-command-v1" + image[:56])
    assert C.decode_command(air)[2:] == (b"fieldkit-command-v1" + image[:56], signature)


def test_the_smallest_frame() -> None:
    air = frame(1, 3, 22)
    assert len(air) == C.MIN_COMMAND_BYTES == 88
    assert words(air)[0] == bytes.fromhex("0016 0003 00 01 0011")
    assert words(air)[1] == (1).to_bytes(8, "big")


def test_is_command_tells_types_apart() -> None:
    assert C.is_command(frame(1))
    bundle = B.encode_fields(3, (), 45.5, -73.6, 10.0, 1, 0)
    update = pk.encode(pk.Frame(3, (pk.Verdict(2, pk.Reason.OPERATOR),)))
    for other in (bundle, update, (1).to_bytes(8, "big"), b"", bytes(7), frame(1)[:7]):
        assert not C.is_command(other)
    assert not C.is_command("not bytes")  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("edit", "byte"),
    [
        (lambda m: m.__setitem__(slice(0, 2), b"\x10\x00"), 0),  # type 16
        (lambda m: m.__setitem__(2, 2), 2),  # format 2
        (lambda m: m.__setitem__(3, 5), 3),  # five params
        (lambda m: m.__setitem__(3, 1), 3),  # one param announced, none there
        (lambda m: m.__setitem__(slice(8, 16), bytes(8)), 8),  # sequence number 0
        (lambda m: m.__setitem__(slice(8, 16), (1 << 48).to_bytes(8, "little")), 8),
        (lambda m: m.__setitem__(slice(6, 8), b"\x10\x00"), 3),  # waypoint without params
    ],
)
def test_decode_names_what_and_where(edit: object, byte: int) -> None:
    image = bytearray(C._swap(frame(9)))
    edit(image)  # type: ignore[operator]
    with pytest.raises(C.CommandError) as e:
        C.decode_command(C._swap(bytes(image)))
    assert e.value.reason == C.BAD_FORMAT
    assert f"(at byte {byte})" in e.value.what and e.value.what in str(e.value)


def test_decode_refuses_a_non_finite_param_even_when_signed() -> None:
    cmd = C.OperatorCommand(4, 3, 900, (1.0,))
    image = bytearray(C._image(cmd, C.operator_key_id(PUB)))
    image[16:24] = struct.pack("<d", float("nan"))
    air = C._swap(bytes(image) + OPERATOR.sign(C.DOMAIN + bytes(image)))
    with pytest.raises(C.CommandError, match=r"param 0 .* \(at byte 16\)"):
        C.decode_command(air)
    assert C.CommandGate(3, PUB).receive(air) == (None, None, C.BAD_FORMAT)


def test_decode_sizes() -> None:
    good = frame(1)
    for bad in (b"", good[:-8], good[:-1], good + bytes(8), good * 2, bytes(4096)):
        with pytest.raises(C.CommandError) as e:
            C.decode_command(bad)
        assert e.value.reason == C.BAD_FORMAT
    with pytest.raises(C.CommandError, match="bytes, not str"):
        C.decode_command("x" * 88)  # type: ignore[arg-type]


def test_command_error_pickles() -> None:
    e = C.CommandError(C.BAD_FORMAT, "format 2 (at byte 2)")
    back = pickle.loads(pickle.dumps(e))
    assert (back.reason, back.what, str(back)) == (e.reason, e.what, str(e))
    assert isinstance(back, FieldkitError) and isinstance(back, ValueError)


# ------------------------------------------------------------------ the command


@pytest.mark.parametrize(
    ("args", "match"),
    [
        ((1, 3, 16, (7.0, 45.5, -73.6)), "code 16 .* 4 expected"),
        ((1, 3, 16, ()), "code 16"),
        ((1, 3, 16, (7.0, 45.5, float("nan"), 10.0)), "param 2 .* not a finite"),
        ((1, 3, 16, (7.0, float("inf"), 0.0, 10.0)), "param 1"),
        ((1, 3, 22, (1.0, 2.0, 3.0, 4.0, 5.0)), "5 params"),
        ((1, 3, 22, ("1",)), "param 0"),
        ((0, 3, 22), "sequence number 0"),
        ((1 << 48, 3, 22), "sequence number"),
        ((True, 3, 22), "sequence number"),
        ((1, -1, 22), "target"),
        ((1, 0x10000, 22), "target"),
        ((1, 3, -1), "code"),
        ((1, 3, 0x10000), "code"),
    ],
)
def test_command_validation(args: tuple[object, ...], match: str) -> None:
    with pytest.raises(C.CommandError, match=match) as e:
        C.OperatorCommand(*args)  # type: ignore[arg-type]
    assert e.value.reason == C.BAD_FORMAT


def test_waypoint_and_rc() -> None:
    cmd = C.OperatorCommand(1, C.ALL, 16, (7, 45.5, -73.6, 10))  # an int id becomes a float
    assert cmd.params == WAYPOINT and all(type(p) is float for p in cmd.params)
    rc = cmd.rc(4, t=12.5)
    assert rc == RcCommand(12.5, 4, 16, WAYPOINT)
    assert rc.goto == (7, 45.5, -73.6, 10.0)
    assert cmd.for_robot(4) and cmd.for_robot(0)
    one = C.OperatorCommand(2, 5, 21)
    assert one.for_robot(5) and not one.for_robot(4)
    assert one.rc(5) == RcCommand(0.0, 5, 21, ())
    with pytest.raises(ValueError, match="for robot 5, not 4"):
        one.rc(4)


# ------------------------------------------------------------------ the gate


def test_every_reason() -> None:
    gate = C.CommandGate(3, PUB)
    good = frame(10)
    assert reason_of(gate, good[:-8]) == C.BAD_FORMAT
    assert reason_of(gate, B.encode_fields(3, (), 45.5, -73.6, 10.0, 1, 0)) == C.BAD_FORMAT
    assert reason_of(gate, forged(STRANGER, C.OperatorCommand(11, 3, 22), b"x" * 8)) == (
        C.UNKNOWN_KEY
    )
    flipped = bytearray(good)
    flipped[-1] ^= 1
    assert reason_of(gate, bytes(flipped)) == C.BAD_SIGNATURE
    assert gate.receive(good).act is not None
    assert reason_of(gate, good) == C.REPLAYED
    assert reason_of(gate, frame(9)) == C.REPLAYED  # below the last acted on
    assert gate.counters == {
        C.BAD_FORMAT: 2,
        C.UNKNOWN_KEY: 1,
        C.BAD_SIGNATURE: 1,
        C.ACCEPTED: 1,
        C.REPLAYED: 2,
        C.RELAYED: 2,  # frame 10 once, frame 9 once
    }
    assert set(gate.counters) <= {C.ACCEPTED, C.RELAYED, C.NOT_FOR_ME, *C.REASONS}
    assert C.REASONS == ("bad-format", "unknown-key", "bad-signature", "replayed")


def test_another_ed25519_key_is_an_unknown_key() -> None:
    """A frame properly signed by someone else's key, under that key's own id."""
    cmd = C.OperatorCommand(1, C.ALL, 21)
    theirs = C.sign_command(STRANGER, cmd)
    gate = C.CommandGate(3, PUB)
    assert gate.receive(theirs) == (None, None, C.UNKNOWN_KEY)
    assert "key id" in (gate.last_what or "")
    # Their own robots take it: the gate is about the key, not the bytes' shape.
    assert C.CommandGate(3, STRANGER.public_key()).receive(theirs).act == cmd


def test_the_operators_key_id_with_a_bad_signature() -> None:
    cmd = C.OperatorCommand(1, C.ALL, 21)
    gate = C.CommandGate(3, PUB)
    assert gate.receive(forged(STRANGER, cmd)) == (None, None, C.BAD_SIGNATURE)
    # A genuine frame edited under its signature: retargeted, renumbered, recoded.
    for at, value in ((4, b"\x04\x00"), (8, b"\x02"), (6, b"\x15\x00")):
        image = bytearray(C._swap(frame(1, 3, 22)))
        image[at : at + len(value)] = value
        assert gate.receive(C._swap(bytes(image))) == (None, None, C.BAD_SIGNATURE)
    assert gate.last_acted == 0 and gate.counters[C.RELAYED] == 0


def test_a_captured_robot_cannot_make_an_accepted_command(tmp_path: Path) -> None:
    """Everything a robot's key directory allows, and every genuine frame it heard, edited:
    no gate acts on any of it or relays it."""
    paths = keys.init_keys(tmp_path / "operator")
    operator = keys.load_signing_key(paths.directory)
    robot_dir = tmp_path / "robot"
    robot_dir.mkdir()
    for f in paths.robot_files:
        (robot_dir / f.name).write_bytes(f.read_bytes())
        (robot_dir / f.name).chmod(0o600)
    loot = keys.load_robot_keys(robot_dir)  # what taking the robot apart gives
    assert not (robot_dir / keys.OPERATOR_KEY).exists()
    pub, swarm = loot.operator_pub, loot.swarm_key
    op_id = C.operator_key_id(pub)
    heard = C.sign_command(operator, C.OperatorCommand(5, 2, 21))  # land robot 2
    gate = C.CommandGate(4, pub)
    assert gate.receive(heard) == (None, heard, None)  # not for 4: relayed, counted

    want = C.OperatorCommand(6, C.ALL, 21)  # land everyone
    own = Ed25519PrivateKey.generate()
    image = C._image(want, op_id)
    attempts = [
        C.sign_command(own, want),  # its own key
        forged(own, want, op_id),  # its own key, the operator's id
        C._swap(image + hmac.new(swarm, C.DOMAIN + image, "sha512").digest()),  # swarm MAC
        C._swap(image + C._swap(heard)[-64:]),  # a heard signature
        A.Sealer(2, A.bundle_key(swarm), A.MemoryCounter()).seal(
            B.encode_fields(2, (bytes.fromhex("00 03 0003 636d64 01 00000015"),), 0, 0, 0, 1, 0)
        ),  # a sealed bundle with a `cmd` broadcast: valid Buzz traffic, not a command frame
        pk.seal(pk.encode(pk.Frame(2, ())), pk.frame_key(swarm)),  # a sealed update frame
    ]
    heard_image = C._swap(heard)
    for at, value in ((4, b"\xff\xff"), (4, b"\x04\x00"), (8, b"\x06"), (6, b"\x16\x00")):
        edited = bytearray(heard_image)
        edited[at : at + len(value)] = value
        attempts.append(C._swap(bytes(edited)))
    for data in attempts:
        res = gate.receive(data)
        assert res.act is None and res.relay is None and res.reason in C.REASONS, data.hex()
    assert gate.receive(heard) == (None, None, None)  # heard again: neither relayed nor acted
    assert gate.counters[C.ACCEPTED] == 0 and gate.counters[C.RELAYED] == 1


def test_relay_once() -> None:
    gate = C.CommandGate(3, PUB)
    theirs = frame(1, target=2)
    assert gate.receive(theirs) == (None, theirs, None)
    assert gate.receive(bytearray(theirs)) == (None, None, None)
    mine = frame(2, target=3)
    res = gate.receive(mine)
    assert res.act is not None and res.relay == mine and type(res.relay) is bytes
    assert gate.receive(mine) == (None, None, C.REPLAYED)
    everyone = frame(3, target=C.ALL)
    assert gate.receive(everyone).relay == everyone
    assert gate.receive(everyone) == (None, None, C.REPLAYED)
    # An old one never relayed by this gate: refused to act, relayed once (others may need it).
    assert gate.receive(frame(5, target=3)).act is not None
    late = frame(4, target=C.ALL)
    assert gate.receive(late) == (None, late, C.REPLAYED)
    assert gate.receive(late) == (None, None, C.REPLAYED)
    assert gate.counters == {
        C.RELAYED: 5,
        C.NOT_FOR_ME: 2,
        C.ACCEPTED: 3,
        C.REPLAYED: 4,
    }


def test_relay_bound() -> None:
    gate = C.CommandGate(3, PUB)
    assert gate.receive(frame(300, target=9)).relay is not None
    assert gate.receive(frame(44, target=9)).relay is None  # 256 below the highest
    assert gate.receive(frame(45, target=9)).relay is not None  # 255 below
    assert gate.receive(frame(45, target=9)).relay is None
    for seq in range(301, 1301):
        assert gate.receive(frame(seq, target=9)).relay is not None
    assert gate.receive(frame(1044, target=9)).relay is None  # within the window, seen
    assert gate.receive(frame(1000, target=9)).relay is None  # below the window
    assert gate._relay_seen.bit_length() <= C.RELAY_WINDOW  # memory: one 256-bit map
    # A jump to the very last number clears the map instead of shifting it by 2^48 bits.
    assert gate.receive(frame(C.MAX_SEQ, target=9)).relay is not None
    assert gate._relay_seen == 1 and gate.receive(frame(1300, target=9)).relay is None
    assert gate.counters[C.RELAYED] == 1 + 1 + 1000 + 1


def test_act_once_across_a_reboot(tmp_path: Path) -> None:
    path = tmp_path / "state" / "command.seq"
    store = C.CommandSeqStore(path)
    assert store.load() == 0
    gate = C.CommandGate(3, PUB, store)
    land = frame(5, target=C.ALL, code=21)
    res = gate.receive(land)
    assert res.act == C.OperatorCommand(5, C.ALL, 21) and res.relay == land
    assert path.read_text() == "fieldkit-command-seq-v1 5\n"  # on disk when it returned

    rebooted = C.CommandGate(3, PUB, C.CommandSeqStore(path))
    assert rebooted.last_acted == 5
    # Replayed after the reboot: not acted on; relayed once more (relay memory is not kept).
    assert rebooted.receive(land) == (None, land, C.REPLAYED)
    assert rebooted.receive(land) == (None, None, C.REPLAYED)
    assert rebooted.receive(frame(4, target=3)).act is None
    assert rebooted.receive(frame(6, target=3)).act is not None
    assert C.CommandSeqStore(path).load() == 6


def test_after_a_reboot_old_frames_are_not_relayed(tmp_path: Path) -> None:
    """The relay window restarts at the last acted number: 256 below it is old news."""
    store = C.CommandSeqStore(tmp_path / "command.seq")
    store.save(1000)
    gate = C.CommandGate(3, PUB, store)
    assert gate.receive(frame(744, target=9)) == (None, None, None)
    assert gate.receive(frame(745, target=9)).relay is not None
    assert gate.receive(frame(1000, target=3)) == (None, frame(1000, target=3), C.REPLAYED)
    assert gate.receive(frame(1001, target=3)).act is not None


def test_a_store_that_cannot_save_acts_on_nothing(tmp_path: Path) -> None:
    """Persist before acting: if the write fails, the command is not returned, and the gate
    is as before (the same frame acts once the disk is back)."""
    state = tmp_path / "state"
    state.mkdir()
    gate = C.CommandGate(3, PUB, C.CommandSeqStore(state / "command.seq"))
    state.rmdir()
    state.write_text("a file where the state directory was")
    land = frame(1, code=21)
    with pytest.raises(C.SeqFileError, match="command.seq: cannot save"):
        gate.receive(land)
    assert gate.last_acted == 0 and sum(gate.counters.values()) == 0
    state.unlink()
    res = gate.receive(land)
    assert res.act is not None and res.relay == land
    assert (state / "command.seq").read_text() == "fieldkit-command-seq-v1 1\n"


@pytest.mark.parametrize(
    "text",
    [
        b"",
        b"garbage\n",
        b"fieldkit-command-seq-v1 5",  # no newline: a torn write would look like this
        b"fieldkit-command-seq-v1 -5\n",
        b"fieldkit-command-seq-v1 5\nmore\n",
        b"fieldkit-command-next-v1 5\n",  # the operator's file, on a robot
        b"fieldkit-command-seq-v1 281474976710656\n",  # 2^48
        b"fieldkit-command-seq-v1 \xff\n",
    ],
)
def test_a_damaged_seq_store_is_an_error(tmp_path: Path, text: bytes) -> None:
    path = tmp_path / "command.seq"
    path.write_bytes(text)
    with pytest.raises(C.SeqFileError) as e:
        C.CommandSeqStore(path).load()
    assert str(path) in str(e.value) and "\nhint: " in str(e.value)
    assert isinstance(e.value, FieldkitError)
    with pytest.raises(C.SeqFileError):
        C.CommandGate(3, PUB, C.CommandSeqStore(path))


def test_gate_arguments() -> None:
    for bad in (-1, C.ALL, 0x10000):
        with pytest.raises(ValueError, match="robot id"):
            C.CommandGate(bad, PUB)


@given(st.binary(max_size=300))
def test_never_raises_on_random_bytes(data: bytes) -> None:
    gate = C.CommandGate(3, PUB)
    res = gate.receive(data)
    assert res.act is None and res.relay is None and res.reason in C.REASONS
    C.is_command(data)


@given(st.integers(0, 119), st.integers(0, 7))
def test_every_single_bit_flip_is_refused(at: int, bit: int) -> None:
    air = bytearray(frame(7, target=C.ALL, code=16, params=WAYPOINT))
    air[at] ^= 1 << bit
    res = C.CommandGate(3, PUB).receive(bytes(air))
    assert res.act is None and res.relay is None and res.reason in C.REASONS


def test_never_raises_on_other_types() -> None:
    gate = C.CommandGate(3, PUB)
    for data in (None, "text", 17, memoryview(frame(1)), [1, 2], bytes(10**6)):
        assert gate.receive(data) == (None, None, C.BAD_FORMAT)  # type: ignore[arg-type]
    assert gate.counters == {C.BAD_FORMAT: 6}


# ------------------------------------------------------------------ the operator's end


def test_signer_persists_its_numbers(tmp_path: Path) -> None:
    path = tmp_path / "keys" / C.SIGNER_SEQ_FILE
    signer = C.CommandSigner(OPERATOR, path)
    assert signer.next_seq == 1
    frames = [signer.sign(3, 22), signer.sign(C.ALL, 16, WAYPOINT), signer.sign(3, 21)]
    assert [C.decode_command(f)[0].seq for f in frames] == [1, 2, 3]
    assert path.read_text() == "fieldkit-command-next-v1 4\n"
    # A new signer (the next CLI run, or one after a crash) goes on from the file.
    again = C.CommandSigner(OPERATOR, path)
    assert C.decode_command(again.sign(3, 20))[0].seq == 4
    # Two signers on one file never hand out the same number.
    assert C.decode_command(signer.sign(3, 20))[0].seq == 5
    assert C.decode_command(again.sign(3, 20))[0].seq == 6
    gate = C.CommandGate(3, PUB)
    assert [gate.receive(f).act is not None for f in frames] == [True, True, True]


def test_signer_refuses_a_bad_command_without_using_a_number(tmp_path: Path) -> None:
    path = tmp_path / C.SIGNER_SEQ_FILE
    signer = C.CommandSigner(OPERATOR, path)
    with pytest.raises(C.CommandError, match="code 16"):
        signer.sign(3, 16, (1.0, 2.0, 3.0))
    with pytest.raises(C.CommandError, match="target"):
        signer.sign(-1, 22)
    assert not path.exists()
    assert C.decode_command(signer.sign(3, 22))[0].seq == 1


def test_signer_with_a_damaged_file(tmp_path: Path) -> None:
    path = tmp_path / C.SIGNER_SEQ_FILE
    path.write_text("fieldkit-command-next-v1 x\n")
    with pytest.raises(C.SeqFileError) as e:
        C.CommandSigner(OPERATOR, path)
    assert str(path) in str(e.value) and "\nhint: " in str(e.value)
    path.write_text(f"fieldkit-command-next-v1 {C.MAX_SEQ + 1}\n")
    with pytest.raises(C.SeqFileError, match="exhausted"):
        C.CommandSigner(OPERATOR, path).sign(3, 22)


def test_all_public_names_have_docstrings() -> None:
    for name in C.__all__:
        obj = getattr(C, name)
        if callable(obj):
            assert obj.__doc__ and obj.__doc__.strip(), name
