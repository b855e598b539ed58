"""A hostile radio in the simulator: an outsider in the middle of the swarm, with no keys.

`fieldkit sim run ... --attack replay,forge,command,flood` adds one. It hears the bundles
sent within its radio range (it records them) and transmits, every tick, what its kinds
make (docs/security.md#the-attacker-in-the-simulator):

* `replay`: bundles it recorded, re-sent unchanged REPLAY_DELAY_TICKS later (10-20 s,
  drawn per bundle): genuine bytes, genuine tags, counters the receivers have moved past.
* `forge`: bundles with tags it cannot make: a recorded bundle with one byte of its
  messages or position changed under the old trailer, the same with a fresh counter, random
  tags, another key id, and plain bundles (no trailer) of a robot's id.
* `command`: commands the operator did not give: forged signed-command frames (type 17:
  random signatures, with the operator's key id, which is public, or another), plain and
  forged bundles that carry a Buzz `cmd` broadcast (21 land, 22 take off), and recorded
  command frames re-sent.
* `flood`: full-size forged bundles at the radio's full rate (FLOOD_FRAMES_PER_TICK).

Every draw comes from the attacker's own generators (`attack:SEED`), and its radio is a
`RadioModel` of its own with the swarm's link model, so the swarm's own draws (losses,
scripts) are those of the run without it. Its id on the simulated radio is one no robot
has; the bytes it sends claim real robots' ids.
"""

from __future__ import annotations

import random
from collections import Counter, deque
from collections.abc import Sequence
from typing import Final

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from bvm import wire
from fieldkit.robot import bundle as wirebundle
from fieldkit.robot import bundle_auth as auth
from fieldkit.robot.operator_command import ALL, OperatorCommand, is_command, sign_command
from fieldkit.sim.radio import LinkModel, Position, RadioModel

#: The attack kinds `--attack` takes.
ATTACKS: Final = ("replay", "forge", "command", "flood")
#: A recorded bundle is re-sent this many ticks later at least (and at most twice that):
#: past the receivers' 64-counter replay window.
REPLAY_DELAY_TICKS: Final = 100
#: Recorded bundles kept for replay at most (the oldest go first).
MAX_RECORDED: Final = 4096
#: Bundles each of `replay`, `forge` and `command` sends per tick.
PER_TICK: Final = 2
#: The XBee-PRO 900HP's fastest RF rate, 200 kbit/s, is 25 kB/s: ten 250-byte frames in a
#: 100 ms tick, before the mesh's own overhead (an upper bound of what one radio sends).
FLOOD_FRAMES_PER_TICK: Final = 10


class Attacker:
    """The hostile radio: `record` what it hears, `transmit` each tick; counts what it sent."""

    def __init__(
        self,
        kinds: Sequence[str],
        *,
        seed: int,
        link: LinkModel,
        position: Position,
        radio_id: int,
        robot_ids: Sequence[int],
        origin: tuple[float, float],
        operator_key_id: bytes | None = None,
    ) -> None:
        """`position` is where it stands (metres, the simulator's frame); `radio_id` its id
        on the simulated radio (no robot's); `origin` the field's (lat, lon), for the
        positions it claims; `operator_key_id` the operator key's public id, if known."""
        unknown = sorted(set(kinds) - set(ATTACKS))
        if unknown or not kinds:
            raise ValueError(f"attack kinds are {', '.join(ATTACKS)}; got {', '.join(unknown)}")
        self.kinds = tuple(k for k in ATTACKS if k in kinds)
        self.position = position
        self.id = radio_id
        self.robot_ids = list(robot_ids)
        self.origin = origin
        self.operator_key_id = operator_key_id or b"\0" * 8
        self.rng = random.Random(f"attack:{seed}")
        # Its own radio: the swarm's link model, its own loss draws.
        self.radio = RadioModel(link, seed=self.rng.getrandbits(64))
        self._hear = random.Random(f"attack-hear:{seed}")
        self._key = Ed25519PrivateKey.from_private_bytes(self.rng.randbytes(32))  # its own
        self._link = link
        #: Bytes recorded for replay: (tick due, data).
        self._recorded: deque[tuple[int, bytes]] = deque()
        self._commands: list[bytes] = []  # recorded command frames
        self._bundles: list[bytes] = []  # a few recent bundles to edit (forge)
        #: Frames sent, by kind.
        self.sent: Counter[str] = Counter()
        #: Receptions a robot accepted, by kind (the simulator counts them).
        self.accepted: Counter[str] = Counter()

    # ------------------------------------------------------------ what it hears

    def record(self, t: int, data: bytes, sender_at: Position) -> None:
        """A frame sent at tick t from `sender_at`: recorded if in range and not lost."""
        if not self.radio.in_range(self.position, sender_at):
            return
        link = self._link
        if link.drop and self._hear.random() < link.drop:
            return
        if is_command(data):
            if len(self._commands) < 64:
                self._commands.append(data)
            return
        if "replay" in self.kinds and len(self._recorded) < MAX_RECORDED:
            # Full: later bundles go unrecorded until the oldest are re-sent (dropping the
            # oldest instead would, in a big swarm, drop each before it is due).
            delay = REPLAY_DELAY_TICKS + self.rng.randrange(REPLAY_DELAY_TICKS)
            self._recorded.append((t + delay, data))
        bundles = self._bundles
        bundles.append(data)
        if len(bundles) > 64:
            del bundles[: len(bundles) - 64]

    # ------------------------------------------------------------ what it sends

    def transmit(self, t: int, positions: dict[int, Position]) -> None:
        """Put this tick's hostile frames on its radio (the robots at `positions` hear them
        by the link model; `receptions(t)` of `self.radio` delivers them)."""
        radio = self.radio
        radio.set_positions({**positions, self.id: self.position})
        for kind in self.kinds:
            for data in getattr(self, f"_{kind}")(t):
                self.sent[kind] += 1
                radio.broadcast(t, self.id, data, note=kind)  # what it is, for the counts

    def _replay(self, t: int) -> list[bytes]:
        out: list[bytes] = []
        recorded = self._recorded
        while recorded and recorded[0][0] <= t and len(out) < PER_TICK:
            out.append(recorded.popleft()[1])
        return out

    def _forge(self, t: int) -> list[bytes]:
        rng = self.rng
        out = []
        for _ in range(PER_TICK):
            how = rng.randrange(5)
            base = rng.choice(self._bundles) if self._bundles else None
            if base is not None and auth.is_sealed(base) and how < 2:
                data = bytearray(base)
                if how == 0:  # an edited message or position, under the old trailer
                    data[rng.randrange(16, len(base) - auth.TRAILER_BYTES)] ^= 1 << rng.randrange(8)
                else:  # the same bundle, a fresh counter under the old tag
                    end = len(base) - auth.TRAILER_BYTES
                    counter = int.from_bytes(base[end : end + 6], "big") + 1000
                    data[end : end + 6] = counter.to_bytes(6, "big")
                out.append(bytes(data))
            elif how == 4:
                out.append(self._bundle(t, (), sealed=False))  # plain: no trailer
            else:
                out.append(self._bundle(t, self._junk_messages(), key_id=None if how < 3 else -1))
        return out

    def _command(self, t: int) -> list[bytes]:
        rng = self.rng
        out = [self._command_frame(t)]
        cmd = wire.encode(wire.Broadcast("cmd", rng.choice((21, 22, 20, 900))))
        out.append(self._bundle(t, (cmd,), sealed=rng.random() < 0.5))
        if self._commands and rng.random() < 0.2:
            out.append(rng.choice(self._commands))
        return out

    def _flood(self, t: int) -> list[bytes]:
        big = (self.rng.randbytes(auth.SEALED_MAX_BUZZ_BYTES - wirebundle.MSG_OVERHEAD),)
        return [self._bundle(t, big) for _ in range(FLOOD_FRAMES_PER_TICK)]

    # ------------------------------------------------------------ the bytes

    def _junk_messages(self) -> tuple[bytes, ...]:
        rng = self.rng
        return tuple(rng.randbytes(rng.randint(1, 40)) for _ in range(rng.randint(0, 3)))

    def _bundle(
        self,
        t: int,
        messages: tuple[bytes, ...],
        *,
        sealed: bool = True,
        key_id: int | None = None,
    ) -> bytes:
        """A bundle of a real robot's id near the swarm, with a trailer it made up:
        the swarm's key id (public: it is on every bundle) or another (`key_id=-1`)."""
        rng = self.rng
        robot = rng.choice(self.robot_ids)
        lat, lon = self.origin
        air = wirebundle.encode_fields(
            robot, messages, lat + rng.uniform(-1e-4, 1e-4), lon + rng.uniform(-1e-4, 1e-4), 5.0, t
        )
        if not sealed:
            return air
        kid = rng.randrange(256) if key_id == -1 else self._key_id()
        counter = rng.randrange(1, 1 << 20)
        return air + auth.word_a(kid, counter) + rng.randbytes(auth.TAG_BYTES)

    def _key_id(self) -> int:
        """The swarm's key id as heard on a recorded sealed bundle (else a guess)."""
        for data in reversed(self._bundles):
            if auth.is_sealed(data):
                return data[-auth.TRAILER_BYTES + 6]
        return self.rng.randrange(256)

    def _command_frame(self, t: int) -> bytes:
        """A command frame signed by a key of its own: land, take off or a waypoint; mostly
        claiming the operator's key id (public: it is on every command), so it fails the
        signature check rather than the key check."""
        rng = self.rng
        code = rng.choice((21, 22, 16))
        params = (1.0, *self.origin, 10.0) if code == 16 else ()
        target = rng.choice((*self.robot_ids[:4], ALL))
        cmd = OperatorCommand(rng.randrange(1, 1 << 40), target, code, params)
        data = sign_command(self._key, cmd)
        if rng.random() < 0.3:
            return data  # its own key id: unknown-key
        # The key id is the word before the 8-word signature (words reversed on the air).
        at = len(data) - 8 * 9
        return data[:at] + self.operator_key_id[::-1] + data[at + 8 :]

    def summary(self) -> dict[str, object]:
        """What it sent, and what robots accepted, by kind."""
        return {
            "kinds": list(self.kinds),
            "sent": dict(self.sent),
            "accepted": dict(self.accepted),
        }


__all__ = ["ATTACKS", "Attacker", "FLOOD_FRAMES_PER_TICK", "REPLAY_DELAY_TICKS"]
