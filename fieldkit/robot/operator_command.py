"""Signed operator commands: remote-control codes from the ground station that only the
operator's key can make (docs/security.md#signed-operator-commands).

A robot holds `operator.pub` and the swarm key, never `operator.key`, so a frame signed with
the operator's Ed25519 key can come from the ground station only: neither an outsider with a
radio nor a captured robot can make one. This module owns the command frame's bytes, the
robot's gate (check, relay once, act once) and the two small files that keep sequence numbers
across restarts. It is sans-I/O except for those files (`CommandSeqStore` on a robot,
`CommandSigner` on the operator's machine).

A command frame travels in the same container as a bundle or an update frame: a memory image
of little-endian fields, zero padded to whole 8-byte words, each word serialized big-endian on
the air (every 8-byte group reversed). Its type, 17, is one that ROSBuzz robots ignore.

    bytes 0-1      u16 type = 17 (COMMAND_FRAME)
    byte 2         u8 format = 1
    byte 3         u8 number of params n, 0..4
    bytes 4-5      u16 target robot (0xFFFF = ALL)
    bytes 6-7      u16 code (ROSBuzz's rc codes: 22 take off, 21 land, 20 go home, 900, 901,
                   16 waypoint; any u16)
    bytes 8-15     u64 sequence number, 1..2^48-1
    16..16+8n      n params, f64 each, all finite (code 16: exactly 4, waypoint id, lat,
                   lon, alt)
    next 8 bytes   operator key id: the first 8 bytes of SHA-256 of the raw 32-byte
                   Ed25519 public key
    last 64 bytes  Ed25519 signature over b"fieldkit-command-v1" + every byte of the memory
                   image before it

88 + 8n bytes, 88 to 120: every field ends on a word boundary, so there is no padding and no
byte the signature does not cover. On the air word 0 reads code (2 bytes), target (2), n,
format, type (2), each big-endian, so air bytes 6-7 hold the type (`is_command`), where a
bundle's and an update frame's are.

`CommandGate.receive` takes hostile bytes and never raises on them: it checks the format, the
key id and the signature before it touches any state, then says what to relay (the same
bytes, each valid frame once) and what to act on (a command for this robot whose sequence
number is above the last one acted on, persisted before it is returned).
"""

from __future__ import annotations

import hashlib
import math
import re
import struct
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple, Protocol

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import (
    Ed25519PrivateKey,
    Ed25519PublicKey,
)

from fieldkit.errors import FieldkitError
from fieldkit.robot.rc import RC_WAYPOINT, RcCommand
from fieldkit.update.release import write_atomic

#: payload64 type of a command frame (1 ROSBuzz's OTA, 2 a bundle, 16 an update frame).
COMMAND_FRAME = 17
#: The frame's format number (byte 2).
FORMAT = 1
#: The target that means every robot.
ALL = 0xFFFF
#: Params a command carries at most (a waypoint's four).
MAX_PARAMS = 4
#: Sequence numbers are 48 bits, as the bundles' counters: 1..MAX_SEQ.
MAX_SEQ = (1 << 48) - 1
#: Bytes of the operator key id and of the Ed25519 signature.
KEY_ID_BYTES = 8
SIGNATURE_BYTES = 64
#: A frame without params, and with four: 88 and 120 bytes (an update frame may be 232).
MIN_COMMAND_BYTES = 16 + KEY_ID_BYTES + SIGNATURE_BYTES
MAX_COMMAND_BYTES = MIN_COMMAND_BYTES + 8 * MAX_PARAMS
#: What the signature covers before the image: a command signature is never a patch's.
DOMAIN = b"fieldkit-command-v1"
#: A gate relays a sequence number at most once, and none this far below the highest relayed.
RELAY_WINDOW = 256
#: Where the operator's next sequence number is kept, beside operator.key.
SIGNER_SEQ_FILE = "command.seq"

#: Why a gate refused a frame.
BAD_FORMAT = "bad-format"  # not a command frame of this format (or not one at all)
UNKNOWN_KEY = "unknown-key"  # signed, or claiming to be, by another key than operator.pub
BAD_SIGNATURE = "bad-signature"  # forged, damaged, or edited on the way
REPLAYED = "replayed"  # for this robot, but not above the last sequence number acted on
REASONS = (BAD_FORMAT, UNKNOWN_KEY, BAD_SIGNATURE, REPLAYED)
#: Counted beside the REASONS: acted on, passed on, valid but for other robots.
ACCEPTED = "accepted"
RELAYED = "relayed"
NOT_FOR_ME = "not-for-me"

_HEAD = struct.Struct("<HBBHHQ")
_RELAY_MASK = (1 << RELAY_WINDOW) - 1
_PARAMS = tuple(struct.Struct(f"<{n}d") for n in range(MAX_PARAMS + 1))


class CommandError(FieldkitError, ValueError):
    """A command that cannot be: `reason` (one of REASONS) and `what` is wrong (and where)."""

    def __init__(self, reason: str, what: str) -> None:
        super().__init__(f"operator command ({reason}): {what}")
        self.reason = reason
        self.what = what

    def __reduce__(self) -> tuple[type[CommandError], tuple[str, str]]:
        """Pickle with both arguments."""
        return (CommandError, (self.reason, self.what))


class SeqFileError(FieldkitError):
    """A sequence file that cannot be used: the file, the problem, a hint."""


def _problem(seq: object, target: object, code: object, params: tuple[object, ...]) -> str | None:
    """What is wrong with these fields, naming the byte of the memory image; None if nothing."""

    def within(v: object, low: int, high: int) -> bool:
        return isinstance(v, int) and not isinstance(v, bool) and low <= v <= high

    if not within(seq, 1, MAX_SEQ):
        return f"sequence number {seq!r} is not in 1..{MAX_SEQ} (at byte 8)"
    if not within(target, 0, 0xFFFF):
        return f"target {target!r} is not a u16 robot id or ALL (at byte 4)"
    if not within(code, 0, 0xFFFF):
        return f"code {code!r} is not a u16 (at byte 6)"
    if len(params) > MAX_PARAMS:
        return f"{len(params)} params, at most {MAX_PARAMS} (at byte 3)"
    for i, p in enumerate(params):
        if not isinstance(p, float) or not math.isfinite(p):
            return f"param {i} is {p!r}, not a finite number (at byte {16 + 8 * i})"
    if code == RC_WAYPOINT and len(params) != 4:
        return (
            f"code 16 (waypoint) with {len(params)} params, 4 expected: id, lat, lon, alt "
            f"(at byte 3)"
        )
    return None


@dataclass(frozen=True)
class OperatorCommand:
    """One remote-control code from the ground station, for one robot or ALL, numbered."""

    seq: int
    target: int
    code: int
    params: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        """Params become floats (a waypoint id may be given as an int); CommandError if a
        field cannot go on the air."""
        try:
            params = tuple(
                float(p) if isinstance(p, int) and not isinstance(p, bool) else p
                for p in self.params
            )
        except TypeError:
            raise CommandError(BAD_FORMAT, f"params {self.params!r} are not a sequence") from None
        object.__setattr__(self, "params", params)
        problem = _problem(self.seq, self.target, self.code, params)
        if problem is not None:
            raise CommandError(BAD_FORMAT, problem)

    def for_robot(self, robot_id: int) -> bool:
        """Whether robot `robot_id` is to act on it (its own id, or ALL)."""
        return self.target == ALL or self.target == robot_id

    def rc(self, robot_id: int, t: float = 0.0) -> RcCommand:
        """The RcCommand robot `robot_id` runs at time `t`; ValueError if not for it."""
        if not self.for_robot(robot_id):
            raise ValueError(f"command {self.seq} is for robot {self.target}, not {robot_id}")
        return RcCommand(t, robot_id, self.code, self.params)


class GateResult(NamedTuple):
    """What a gate made of one frame: the command to act on, the bytes to relay, why not."""

    act: OperatorCommand | None
    relay: bytes | None
    reason: str | None


def _swap(data: bytes) -> bytes:
    """Memory image <-> air bytes: every 8-byte word reversed (its own inverse)."""
    return b"".join(data[i : i + 8][::-1] for i in range(0, len(data), 8))


def is_command(data: bytes) -> bool:
    """Whether air bytes carry the command frame's type (17) in word 0: says nothing more."""
    return (
        isinstance(data, bytes | bytearray)
        and len(data) >= 8
        and data[6] << 8 | data[7] == COMMAND_FRAME
    )


def operator_key_id(pub: Ed25519PublicKey) -> bytes:
    """The operator key's 8-byte id: SHA-256 of its raw 32 bytes, first 8."""
    raw = pub.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return hashlib.sha256(raw).digest()[:KEY_ID_BYTES]


def _image(cmd: OperatorCommand, key_id: bytes) -> bytes:
    """The memory image up to the signature."""
    n = len(cmd.params)
    head = _HEAD.pack(COMMAND_FRAME, FORMAT, n, cmd.target, cmd.code, cmd.seq)
    return head + _PARAMS[n].pack(*cmd.params) + key_id


def sign_command(key: Ed25519PrivateKey, cmd: OperatorCommand) -> bytes:
    """The air bytes of `cmd` signed with the operator's key."""
    image = _image(cmd, operator_key_id(key.public_key()))
    return _swap(image + key.sign(DOMAIN + image))


def decode_command(data: bytes) -> tuple[OperatorCommand, bytes, bytes, bytes]:
    """(command, key id, signed message, signature) of air bytes, checking no signature;
    CommandError (bad-format) naming what is wrong and at which byte of the memory image."""
    if not isinstance(data, bytes | bytearray):
        raise CommandError(BAD_FORMAT, f"a command is bytes, not {type(data).__name__}")
    n = len(data)
    if n > MAX_COMMAND_BYTES:
        raise CommandError(BAD_FORMAT, f"{n} bytes, more than a command's {MAX_COMMAND_BYTES}")
    if n < MIN_COMMAND_BYTES or n % 8:
        raise CommandError(
            BAD_FORMAT,
            f"{n} bytes, not a command ({MIN_COMMAND_BYTES} to {MAX_COMMAND_BYTES}, whole words)",
        )
    image = _swap(bytes(data))
    kind, fmt, count, target, code, seq = _HEAD.unpack_from(image)
    if kind != COMMAND_FRAME:
        raise CommandError(
            BAD_FORMAT, f"frame type {kind}, not a command ({COMMAND_FRAME}) (at byte 0)"
        )
    if fmt != FORMAT:
        raise CommandError(
            BAD_FORMAT, f"format {fmt}, this robot reads format {FORMAT} (at byte 2)"
        )
    if count > MAX_PARAMS:
        raise CommandError(BAD_FORMAT, f"{count} params, at most {MAX_PARAMS} (at byte 3)")
    if n != MIN_COMMAND_BYTES + 8 * count:
        raise CommandError(
            BAD_FORMAT,
            f"{count} params in {n} bytes, {MIN_COMMAND_BYTES + 8 * count} expected (at byte 3)",
        )
    params = _PARAMS[count].unpack_from(image, 16)
    problem = _problem(seq, target, code, params)
    if problem is not None:
        raise CommandError(BAD_FORMAT, problem)
    signed = n - SIGNATURE_BYTES
    return (
        OperatorCommand(seq, target, code, params),
        image[signed - KEY_ID_BYTES : signed],
        DOMAIN + image[:signed],
        image[signed:],
    )


# ------------------------------------------------------------------------------ the robot


class SeqStore(Protocol):
    """Where a gate keeps the last sequence number acted on (CommandSeqStore, or in memory)."""

    def load(self) -> int:
        """The last sequence number acted on, 0 if none."""
        ...

    def save(self, n: int) -> None:
        """Make `n` the last sequence number acted on, durably, before returning."""
        ...


class CommandGate:
    """One robot's door for command frames: checks them, relays each valid one once, acts
    on each command for this robot at most once, even across reboots (with a store)."""

    def __init__(
        self, robot_id: int, operator_pub: Ed25519PublicKey, store: SeqStore | None = None
    ) -> None:
        if not isinstance(robot_id, int) or not 0 <= robot_id < ALL:
            raise ValueError(f"robot id must be a u16 other than ALL ({ALL}), got {robot_id!r}")
        self.robot_id = robot_id
        self.operator_pub = operator_pub
        self.key_id = operator_key_id(operator_pub)
        self.store = store
        #: The last sequence number acted on (persisted in `store` before acting).
        self.last_acted = 0 if store is None else store.load()
        if not 0 <= self.last_acted <= MAX_SEQ:
            raise SeqFileError(f"{store}: last sequence number {self.last_acted} out of range")
        #: Outcomes: ACCEPTED, each of REASONS, NOT_FOR_ME; and RELAYED.
        self.counters: Counter[str] = Counter()
        #: Why the last frame was refused, in words (for a log line), or None.
        self.last_what: str | None = None
        # Relay memory: the highest sequence number relayed and a bitmap of which of the
        # RELAY_WINDOW below it were (bit d for highest - d). After a reboot it starts at the
        # last one acted on: what lies 256 below that is old news, and what is above it is
        # relayed at most once more per reboot.
        self._relay_high = self.last_acted
        self._relay_seen = 0

    def _refuse(self, reason: str, what: str) -> GateResult:
        self.counters[reason] += 1
        self.last_what = what
        return GateResult(None, None, reason)

    def _signature_ok(self, signature: bytes, message: bytes) -> bool:
        """Whether the operator's key made `signature` over `message`."""
        try:
            self.operator_pub.verify(signature, message)
        except InvalidSignature:
            return False
        return True

    def _relay_fresh(self, seq: int) -> bool:
        """Whether `seq` was not relayed yet and is within the window."""
        d = self._relay_high - seq
        if d < 0:
            return True
        if d >= RELAY_WINDOW:
            return False
        return not self._relay_seen >> d & 1

    def _mark_relayed(self, seq: int) -> None:
        d = self._relay_high - seq
        if d < 0:
            # A jump past the window clears the map: never shift by up to 2^48 bits.
            shift = -d
            if shift < RELAY_WINDOW:
                self._relay_seen = self._relay_seen << shift & _RELAY_MASK
            else:
                self._relay_seen = 0
            self._relay_high = seq
            d = 0
        self._relay_seen |= 1 << d

    def _persist(self, seq: int) -> None:
        """Make `seq` the last acted on: on disk first, so a reboot cannot act twice."""
        if self.store is not None:
            self.store.save(seq)
        self.last_acted = seq

    def receive(self, data: bytes) -> GateResult:
        """What to do with bytes heard on the radio; never raises on hostile bytes (only a
        store that cannot save raises, SeqFileError, and then nothing is acted on)."""
        try:
            cmd, key_id, message, signature = decode_command(data)
        except CommandError as e:
            return self._refuse(BAD_FORMAT, e.what)
        if key_id != self.key_id:
            return self._refuse(
                UNKNOWN_KEY, f"key id {key_id.hex()}, the operator's is {self.key_id.hex()}"
            )
        if not self._signature_ok(signature, message):
            return self._refuse(BAD_SIGNATURE, "the signature is not the operator key's")
        relay = self._relay_fresh(cmd.seq)
        act = cmd.for_robot(self.robot_id) and cmd.seq > self.last_acted
        if act:
            self._persist(cmd.seq)  # may raise: then nothing below happened
        if relay:
            self._mark_relayed(cmd.seq)
            self.counters[RELAYED] += 1
        out = bytes(data) if relay else None
        if act:
            self.counters[ACCEPTED] += 1
            self.last_what = None
            return GateResult(cmd, out, None)
        if not cmd.for_robot(self.robot_id):
            self.counters[NOT_FOR_ME] += 1
            self.last_what = None
            return GateResult(None, out, None)
        self.counters[REPLAYED] += 1
        self.last_what = f"sequence number {cmd.seq}, the last acted on is {self.last_acted}"
        return GateResult(None, out, REPLAYED)


# ------------------------------------------------------------------------------ files

_STORE_TAG = "fieldkit-command-seq-v1"
_SIGNER_TAG = "fieldkit-command-next-v1"
_MAX_FILE_BYTES = 4096


def _read_number(path: Path, tag: str, what: str, hint: str) -> int | None:
    """The N of a file holding one line `TAG N`; None if there is no file."""
    try:
        with path.open("rb") as f:
            data = f.read(_MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        return None
    except OSError as e:
        raise SeqFileError(
            f"{path}: cannot read the {what}: {e.strerror or e}\nhint: {hint}"
        ) from None
    m = re.fullmatch(rb"(\S+) ([0-9]{1,15})\n", data)
    if m is None or m.group(1) != tag.encode() or int(m.group(2)) > MAX_SEQ + 1:
        raise SeqFileError(
            f"{path}: not a {what} (one line `{tag} N`, N up to {MAX_SEQ})\nhint: {hint}"
        )
    return int(m.group(2))


def _write_number(path: Path, tag: str, n: int, what: str) -> None:
    try:
        write_atomic(path, f"{tag} {n}\n".encode())
    except OSError as e:
        raise SeqFileError(
            f"{path}: cannot save the {what}: {e.strerror or e}\n"
            f"hint: the directory must be writable"
        ) from None


class CommandSeqStore:
    """A robot's last acted sequence number in a file (`fieldkit-command-seq-v1 N`).

    A missing file is a first start (0). A damaged one is a SeqFileError, never a silent 0:
    a robot that forgot what it acted on would act again on a replayed command.
    """

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)

    def __repr__(self) -> str:
        """The file."""
        return f"CommandSeqStore({str(self.path)!r})"

    def load(self) -> int:
        """The last sequence number acted on; 0 without a file."""
        n = _read_number(
            self.path,
            _STORE_TAG,
            "command sequence file",
            "it is the robot's own record of the last operator command it acted on: restore "
            "it from a backup, or write the line with the operator's last sequence number",
        )
        if n is not None and n > MAX_SEQ:
            raise SeqFileError(
                f"{self.path}: sequence number {n} above {MAX_SEQ}\nhint: no operator key "
                f"signs above it; restore the file from a backup"
            )
        return n or 0

    def save(self, n: int) -> None:
        """Write `n` (write_atomic: it is on disk when this returns)."""
        if not 0 <= n <= MAX_SEQ:
            raise ValueError(f"sequence number {n} not in 0..{MAX_SEQ}")
        _write_number(self.path, _STORE_TAG, n, "command sequence number")


class CommandSigner:
    """The operator's side: signs commands with sequence numbers that never repeat, the next
    one kept in `seq_path` (`fieldkit-command-next-v1 N`, e.g. command.seq beside
    operator.key) and saved before a signed frame is handed out."""

    def __init__(self, key: Ed25519PrivateKey, seq_path: Path | str) -> None:
        self.key = key
        self.seq_path = Path(seq_path)
        self._next = self._load()

    def _load(self) -> int:
        n = _read_number(
            self.seq_path,
            _SIGNER_TAG,
            "command sequence file",
            "it keeps the operator's next command number: restore it, or write the line "
            "with a number above every command sent so far (robots refuse lower ones)",
        )
        return 1 if n is None else max(n, 1)

    @property
    def next_seq(self) -> int:
        """The sequence number the next `sign` will use (at least)."""
        return max(self._next, self._load())

    def sign(self, target: int, code: int, params: tuple[float, ...] = ()) -> bytes:
        """The air bytes of a new command, its number saved as used before they are returned;
        CommandError if the fields cannot go on the air."""
        # The file is re-read so that two signers on one key directory never share a number.
        seq = self.next_seq
        if seq > MAX_SEQ:
            raise SeqFileError(
                f"{self.seq_path}: command numbers exhausted\nhint: create new operator keys"
            )
        cmd = OperatorCommand(seq, target, code, tuple(params))
        frame = sign_command(self.key, cmd)
        _write_number(self.seq_path, _SIGNER_TAG, seq + 1, "next command number")
        self._next = seq + 1
        return frame


__all__ = [
    "ACCEPTED",
    "ALL",
    "BAD_FORMAT",
    "BAD_SIGNATURE",
    "COMMAND_FRAME",
    "CommandError",
    "CommandGate",
    "CommandSeqStore",
    "CommandSigner",
    "DOMAIN",
    "FORMAT",
    "GateResult",
    "KEY_ID_BYTES",
    "MAX_COMMAND_BYTES",
    "MAX_PARAMS",
    "MAX_SEQ",
    "MIN_COMMAND_BYTES",
    "NOT_FOR_ME",
    "OperatorCommand",
    "REASONS",
    "RELAYED",
    "RELAY_WINDOW",
    "REPLAYED",
    "SIGNATURE_BYTES",
    "SIGNER_SEQ_FILE",
    "SeqFileError",
    "SeqStore",
    "UNKNOWN_KEY",
    "decode_command",
    "is_command",
    "operator_key_id",
    "sign_command",
]
