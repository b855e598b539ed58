"""Authenticated bundles: a 16-byte trailer that says which robot sent a bundle, and when.

This module owns the sealed bundle's bytes (docs/security.md#authenticated-bundles). It sits
in `fieldkit.robot` beside `bundle.py` because a bundle's bytes are the robot's: the node,
SITL and the simulator must all seal and verify through this one module, so that the
simulator's bandwidth figures include the trailer and its receivers drop what a real robot
would drop. It is sans-I/O except for the two small stores at the end (`CounterStore`,
`FloorStore`), which the node gives a file in its state directory.

A sealed bundle is a bundle's air bytes (`bundle.encode_fields`) followed by two words:

    word A   u64, serialized big-endian like every payload64 word:
             bits 0-7 format (1) | bits 8-15 key id | bits 16-63 counter (u48)
             on the air: counter (6 bytes, big-endian), key id, format
    word B   the first 8 bytes of HMAC-SHA256 under the bundle key, over
             sender (u16, big-endian) || the bundle's air bytes || word A's 8 air bytes

* The **bundle key** is HKDF-SHA256 of the swarm key with info `fieldkit-bundles-v1`: the
  same construction as the update frames' `packets.frame_key` (info `fieldkit-frames-v1`) and
  the same truncated tag as `packets.seal`, but a key of its own, so a tag made for one kind
  of frame never checks out as the other. The **key id** is one byte derived from the same
  swarm key (HKDF, info `fieldkit-bundles-v1 key id`): a robot holding another swarm key is
  reported as `unknown-key` (255 times in 256) rather than as a forger.
* The **sender** is the bundle's own robot id (the u16 the VM attributes its messages to), so
  a tag binds the messages to the robot they claim to come from.
* The **counter** is per sender and strictly increasing; it comes from a `CounterStore`
  (reserved in blocks in a file, so a reboot never reuses one) and never from a clock, so a
  clock jump can neither lock a robot out nor open a replay window.

The byte budget: XbeeMav sends a packet of S = 2 + 8 x words bytes as one standard XBee frame
only while S < 250 (S = 250 is dropped), so a packet has at most 30 words, 240 air bytes. A
sealed bundle is 5 header words + the bundle's words + 2, so the bundle may have 23 words
where ROSBuzz allows 24: its content (header, length prefixes and messages, before padding)
is at most `SEALED_MAX_MSG_SIZE` = 184 bytes instead of 190, and the drain budget
`SEALED_MAX_BUZZ_BYTES` = 180 instead of 186 (`bundle.drain_budget(MAX_PLAIN_AIR_BYTES)`
gives the same). ROSBuzz's 190 already rounds up to 24 words (192 bytes), so giving one word
to the trailer costs 6 bytes of content, not 8.

`Verifier.verify` takes hostile bytes: it returns the plain bundle bytes (ready for
`bundle.decode`) or raises `AuthError` with one of `REASONS`, and counts every outcome in
`counters`. It never raises anything else, and reads nothing before the tag has checked out
but what it needs to find the trailer, the sender and the key: word 0's type, the bundle's
word count and robot id, word A's format and key id.
"""

from __future__ import annotations

import hashlib
import hmac
import re
from array import array
from collections import Counter, OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from fieldkit.errors import FieldkitError
from fieldkit.robot.bundle import BUZZ_MESSAGE, HEADER_WORDS, MIN_AIR_BYTES, RF_PREFIX, XBEE_MAX_RF
from fieldkit.update.release import write_atomic

#: The trailer's format number (the low byte of word A).
FORMAT = 1
#: Bytes the trailer adds to every bundle: two words.
TRAILER_BYTES = 16
#: Bytes of the truncated HMAC-SHA256 tag (word B).
TAG_BYTES = 8
#: The counter's width: 48 bits, as MAVLink 2's timestamp.
COUNTER_BITS = 48
#: The largest counter a sender may use; a sender that reaches it must be re-keyed.
MAX_COUNTER = (1 << COUNTER_BITS) - 1

#: XbeeMav sends a packet (sysid, msgid, words: 2 + air bytes) as one standard frame only
#: while it is under 250 bytes: whole words, 30 of them, 240 air bytes.
MAX_SEALED_AIR_BYTES = 8 * ((XBEE_MAX_RF - 1 - 2) // 8)
#: The largest bundle (air bytes) that can still be sealed: 28 words.
MAX_PLAIN_AIR_BYTES = MAX_SEALED_AIR_BYTES - TRAILER_BYTES
#: The bundle content limit for sealed bundles (ROSBuzz's MAX_MSG_SIZE is 190): the 23
#: bundle words left after the 5 header words and the trailer.
SEALED_MAX_MSG_SIZE = MAX_PLAIN_AIR_BYTES - 8 * HEADER_WORDS
#: The drain_outbox budget for sealed bundles (bundle.MAX_BUZZ_BYTES is 186).
SEALED_MAX_BUZZ_BYTES = SEALED_MAX_MSG_SIZE - 4
#: The smallest sealed bundle: an empty step (6 words) and the trailer.
MIN_SEALED_AIR_BYTES = MIN_AIR_BYTES + TRAILER_BYTES

#: The replay window: a counter up to this far below the highest seen is accepted once.
WINDOW = 64
#: Senders whose replay windows a Verifier keeps; the least recently heard is evicted.
MAX_SENDERS = 1024
#: Counters a CounterStore reserves per write: at 10 bundles a second, one write per 1000 s.
COUNTER_BLOCK = 10_000
#: A FloorStore saves when a sender's highest counter has moved this far since the last save.
FLOOR_EVERY = 600

#: Why a Verifier rejected bytes.
MISSING_TRAILER = "missing-trailer"  # a plain bundle: a ROSBuzz robot, or `--security none`
BAD_FORMAT = "bad-format"  # not a sealed bundle of this format (or not a bundle at all)
UNKNOWN_KEY = "unknown-key"  # sealed under another swarm key
BAD_TAG = "bad-tag"  # forged, damaged, or edited on the way
REPLAYED = "replayed"  # a counter of this sender already accepted
TOO_OLD = "too-old"  # a counter below this sender's replay window
REASONS = (MISSING_TRAILER, BAD_FORMAT, UNKNOWN_KEY, BAD_TAG, REPLAYED, TOO_OLD)
#: The counter of bundles accepted (beside the REASONS).
ACCEPTED = "accepted"

_WINDOW_MASK = (1 << WINDOW) - 1


class AuthError(FieldkitError, ValueError):
    """Bytes a Verifier rejected: `reason` (one of REASONS), the claimed `sender` if known."""

    def __init__(self, reason: str, what: str, sender: int | None = None) -> None:
        who = "" if sender is None else f" from robot {sender}"
        super().__init__(f"bundle{who} rejected ({reason}): {what}")
        self.reason = reason
        self.what = what
        self.sender = sender

    def __reduce__(self) -> tuple[type[AuthError], tuple[str, str, int | None]]:
        """Pickle with all three arguments."""
        return (AuthError, (self.reason, self.what, self.sender))


class CounterError(FieldkitError):
    """A counter or floor file that cannot be used, or counters run out: the file, the
    problem, a hint."""


@dataclass(frozen=True, repr=False)
class BundleKey:
    """The key that seals bundles, and its one-byte id (`bundle_key(swarm_key)` makes it)."""

    secret: bytes
    id: int
    #: 16 hex digits naming the key (the id is its first byte): what a FloorStore is tied to.
    fingerprint: str
    _mac: hmac.HMAC = field(compare=False)

    def __repr__(self) -> str:
        """Never the secret."""
        return f"BundleKey(id={self.id})"

    def tag(self, sender: int, air: bytes, word_a: bytes) -> bytes:
        """The first TAG_BYTES of HMAC-SHA256 over sender || air || word A."""
        # A copy of the keyed state skips the two key-block hashes every tag would redo.
        mac = self._mac.copy()
        mac.update(sender.to_bytes(2, "big"))
        mac.update(air)
        mac.update(word_a)
        return mac.digest()[:TAG_BYTES]


def _hkdf(swarm_key: bytes, info: bytes, length: int) -> bytes:
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.kdf.hkdf import HKDF

    return HKDF(algorithm=hashes.SHA256(), length=length, salt=None, info=info).derive(swarm_key)


def bundle_key(swarm_key: bytes) -> BundleKey:
    """The bundle key and key id derived from the swarm key (`RobotKeys.swarm_key`)."""
    if not isinstance(swarm_key, bytes) or len(swarm_key) < 16:
        raise ValueError("the swarm key is bytes, at least 16 of them (keys.load_robot_keys)")
    secret = _hkdf(swarm_key, b"fieldkit-bundles-v1", 32)
    name = _hkdf(swarm_key, b"fieldkit-bundles-v1 key id", 8)
    return BundleKey(secret, name[0], name.hex(), hmac.new(secret, digestmod=hashlib.sha256))


def word_a(key_id: int, counter: int) -> bytes:
    """Word A's air bytes: counter (u48), key id, format, as a big-endian u64."""
    return (FORMAT | key_id << 8 | counter << 16).to_bytes(8, "big")


def _type(air: bytes) -> int:
    """payload64 word 0's low u16 (2 for a bundle): memory bytes 0-1 are air bytes 7, 6."""
    return air[6] << 8 | air[7]


def _nwords(air: bytes) -> int:
    """The bundle header's word count: memory bytes 40-41, air bytes 47, 46."""
    return air[46] << 8 | air[47]


def bundle_sender(air: bytes) -> int:
    """The bundle header's robot id (memory bytes 42-43, air bytes 45, 44) of air bytes."""
    return air[44] << 8 | air[45]


def is_sealed(data: bytes) -> bool:
    """Whether `data` is shaped like a sealed bundle (type 2, the trailer where the bundle's
    word count puts it): how a receiver tells a signed neighbour from a plain one. Says
    nothing of the tag."""
    n = len(data)
    return (
        MIN_SEALED_AIR_BYTES <= n <= MAX_SEALED_AIR_BYTES
        and n % 8 == 0
        and _type(data) == BUZZ_MESSAGE
        and n == 8 * (HEADER_WORDS + _nwords(data)) + TRAILER_BYTES
    )


# ------------------------------------------------------------------------------ sending


class CounterSource(Protocol):
    """Where a Sealer takes its counters: each call returns a larger one than the last."""

    def next(self) -> int:
        """The next counter (strictly greater than every one returned before)."""
        ...


class MemoryCounter:
    """Counters 1, 2, 3, ... in memory: for a simulated robot, which never reboots."""

    def __init__(self, start: int = 1) -> None:
        if not 0 < start <= MAX_COUNTER:
            raise ValueError(f"start must be in 1..{MAX_COUNTER}, got {start}")
        self._next = start

    @property
    def upcoming(self) -> int:
        """The counter `next()` returns next."""
        return self._next

    def next(self) -> int:
        """The next counter."""
        c = self._next
        if c > MAX_COUNTER:
            raise CounterError(f"counters exhausted (past {MAX_COUNTER}): re-key the swarm")
        self._next = c + 1
        return c


class Sealer:
    """Seals one robot's bundles: `seal(air)` appends the trailer with the next counter."""

    def __init__(self, sender: int, key: BundleKey, counter_source: CounterSource) -> None:
        if not isinstance(sender, int) or not 0 <= sender <= 0xFFFF:
            raise ValueError(f"sender must be a u16, got {sender!r}")
        self.sender = sender
        self.key = key
        self.counters = counter_source
        #: The counter of the last bundle sealed (0 before the first).
        self.last = 0

    def seal(self, air: bytes) -> bytes:
        """`air` (a bundle's air bytes from `bundle.encode_fields`, robot `sender`, content
        within SEALED_MAX_MSG_SIZE) followed by the trailer; ValueError if it is not one."""
        n = len(air)
        if n > MAX_PLAIN_AIR_BYTES:
            raise ValueError(
                f"a bundle of {n} air bytes cannot be sealed (at most {MAX_PLAIN_AIR_BYTES}): "
                f"drain the outbox with budget_bytes={SEALED_MAX_BUZZ_BYTES}"
            )
        if n < MIN_AIR_BYTES or n % 8 or _type(air) != BUZZ_MESSAGE:
            raise ValueError(f"{n} bytes that are not a bundle's air bytes (bundle.encode_fields)")
        if n != 8 * (HEADER_WORDS + _nwords(air)):
            raise ValueError(f"{n} bytes for a bundle whose header says {_nwords(air)} words")
        if bundle_sender(air) != self.sender:
            raise ValueError(f"a bundle of robot {bundle_sender(air)}, sealed by {self.sender}")
        counter = self.counters.next()
        if not self.last < counter <= MAX_COUNTER:
            raise CounterError(
                f"counter {counter} after {self.last}: counters must increase, up to "
                f"{MAX_COUNTER} (re-key the swarm when they run out)"
            )
        self.last = counter
        a = word_a(self.key.id, counter)
        return air + a + self.key.tag(self.sender, air, a)


# ------------------------------------------------------------------------------ receiving


class _Window:
    """One sender's replay state: the highest counter accepted, and which of the WINDOW
    counters below it were (bit d-1 for highest - d)."""

    __slots__ = ("highest", "seen")

    def __init__(self, highest: int, seen: int) -> None:
        self.highest = highest
        self.seen = seen


class Verifier:
    """Checks sealed bundles: the tag, then each sender's replay window; counts every outcome.

    `floors` (sender -> counter, e.g. `FloorStore.load()` after a reboot) makes every counter
    up to a sender's floor count as already seen. Memory is bounded: at most `max_senders`
    windows (the least recently accepted sender is evicted), and an evicted sender's highest
    counter is kept as its floor (one u64 per possible u16 id, allocated at the first
    eviction), so an eviction never lets a counter be accepted twice.
    """

    def __init__(
        self,
        key: BundleKey,
        *,
        floors: Mapping[int, int] | None = None,
        max_senders: int = MAX_SENDERS,
    ) -> None:
        if max_senders < 1:
            raise ValueError(f"max_senders must be at least 1, got {max_senders}")
        self.key = key
        self.max_senders = max_senders
        #: Outcomes: ACCEPTED and each of REASONS.
        self.counters: Counter[str] = Counter()
        self._windows: OrderedDict[int, _Window] = OrderedDict()
        self._evicted: array[int] | None = None  # floors of evicted senders, by id
        for sender, floor in (floors or {}).items():
            if not 0 <= sender <= 0xFFFF or not 0 <= floor <= MAX_COUNTER:
                raise ValueError(f"floor {floor!r} of sender {sender!r} out of range")
            if floor:
                self._remember(sender, _Window(floor, _WINDOW_MASK))

    def _reject(self, reason: str, what: str, sender: int | None = None) -> AuthError:
        self.counters[reason] += 1
        return AuthError(reason, what, sender)

    def verify(self, data: bytes) -> bytes:
        """The plain bundle air bytes of a sealed bundle accepted now; AuthError otherwise."""
        if not isinstance(data, bytes | bytearray | memoryview):
            raise self._reject(BAD_FORMAT, f"bytes expected, not {type(data).__name__}")
        n = data.nbytes if isinstance(data, memoryview) else len(data)
        if n > MAX_SEALED_AIR_BYTES + 8:
            # Checked before anything is copied, so a huge hostile input costs nothing.
            raise self._reject(BAD_FORMAT, f"{n} bytes, more than any bundle")
        data = bytes(data)
        if n < MIN_AIR_BYTES or n % 8 or _type(data) != BUZZ_MESSAGE:
            raise self._reject(BAD_FORMAT, f"{n} bytes that are not a bundle (type 2, words)")
        sender = bundle_sender(data)
        plain = 8 * (HEADER_WORDS + _nwords(data))
        if n == plain:
            raise self._reject(MISSING_TRAILER, "a plain bundle, without a trailer", sender)
        if n != plain + TRAILER_BYTES or n > MAX_SEALED_AIR_BYTES:
            raise self._reject(
                BAD_FORMAT, f"{n} bytes for a bundle of {plain} and a trailer", sender
            )
        air, a, tag = data[:plain], data[plain : plain + 8], data[plain + 8 :]
        head = int.from_bytes(a, "big")
        if head & 0xFF != FORMAT:
            raise self._reject(BAD_FORMAT, f"trailer format {head & 0xFF}, not {FORMAT}", sender)
        key_id = head >> 8 & 0xFF
        if key_id != self.key.id:
            raise self._reject(
                UNKNOWN_KEY, f"key id {key_id}, this swarm's is {self.key.id}", sender
            )
        if not hmac.compare_digest(tag, self.key.tag(sender, air, a)):
            raise self._reject(BAD_TAG, "the tag is not this swarm key's", sender)
        self.admit(sender, head >> 16)
        return air

    def admit(self, sender: int, counter: int) -> None:
        """Pass `counter` of `sender` through the replay window, for a bundle whose tag has
        checked out (`verify` does both), or raise AuthError (replayed, too-old).

        A host that made the bundle itself and shares this key (the simulator, which seals
        every robot's bundles) may call it without the tag check: the tag would pass."""
        self._accept(sender, counter)
        self.counters[ACCEPTED] += 1

    def _accept(self, sender: int, counter: int) -> None:
        """Record `counter` of `sender` as seen, or raise AuthError (replayed, too-old)."""
        w = self._windows.get(sender)
        if w is None:
            floor = 0 if self._evicted is None else self._evicted[sender]
            if not floor:
                self._remember(sender, _Window(counter, 0))
                return
            # Back after an eviction: every counter up to its old highest counts as seen.
            w = _Window(floor, _WINDOW_MASK)
        if counter > w.highest:
            shift = counter - w.highest
            w.seen = (w.seen << shift | 1 << (shift - 1)) & _WINDOW_MASK if shift <= WINDOW else 0
            w.highest = counter
        else:
            d = w.highest - counter
            if d == 0:
                raise self._reject(REPLAYED, f"counter {counter} again", sender)
            if d > WINDOW:
                raise self._reject(
                    TOO_OLD, f"counter {counter}, {d} below the highest {w.highest}", sender
                )
            bit = 1 << (d - 1)
            if w.seen & bit:
                raise self._reject(REPLAYED, f"counter {counter} again", sender)
            w.seen |= bit
        self._remember(sender, w)

    def _remember(self, sender: int, w: _Window) -> None:
        """Store `w` as the sender's window, most recent last; evict the oldest past the cap."""
        self._windows[sender] = w
        self._windows.move_to_end(sender)
        if len(self._windows) > self.max_senders:
            old, ow = self._windows.popitem(last=False)
            if self._evicted is None:
                self._evicted = array("Q", bytes(8 * 0x10000))
            self._evicted[old] = max(self._evicted[old], ow.highest)

    def floors(self) -> dict[int, int]:
        """Each sender's highest counter seen (what `FloorStore.save` keeps), evicted ones too."""
        out: dict[int, int] = {}
        if self._evicted is not None:
            out = {s: c for s, c in enumerate(self._evicted) if c}
        for s, w in self._windows.items():
            out[s] = max(out.get(s, 0), w.highest)
        return out

    def tracked(self) -> int:
        """Senders with a replay window now (at most max_senders)."""
        return len(self._windows)


# ------------------------------------------------------------------------------ stores

_COUNTER_TAG = "fieldkit-bundle-counter-v1"
_COUNTER_LINE = re.compile(rf"{_COUNTER_TAG} ([0-9]{{1,15}})\n")
_FLOOR_TAG = "fieldkit-bundle-floors-v1"
_FLOOR_LINE = re.compile(r"([0-9]{1,5}) ([0-9]{1,15})")
_MAX_STORE_BYTES = 2 * 1024 * 1024


def _read_small(path: Path, what: str) -> str | None:
    """The text of `path`, None if it does not exist; CounterError if it cannot be read."""
    try:
        with path.open("rb") as f:
            data = f.read(_MAX_STORE_BYTES + 1)
    except FileNotFoundError:
        return None
    except OSError as e:
        raise CounterError(f"{path}: cannot read the {what}: {e.strerror or e}") from None
    if len(data) > _MAX_STORE_BYTES:
        raise CounterError(f"{path}: larger than any {what}")
    try:
        return data.decode("ascii")
    except UnicodeDecodeError:
        return ""


class CounterStore:
    """A robot's bundle counters, durable across reboots with one write per `block` counters.

    The file holds one line, `fieldkit-bundle-counter-v1 END`: every counter handed out is
    below END, and END is written (`write_atomic`: fsync, rename, fsync the directory) before
    the first counter of a block is handed out. After a reboot the robot starts at END, so it
    never sends a counter twice whatever instant it died at; it skips what was left of the
    block. No clock is involved. A missing file is a first start (counters from 1); a damaged
    one is a CounterError, never a silent restart (restarting low would get the robot's
    bundles dropped as replays by every neighbour that remembers it).
    """

    def __init__(self, path: Path | str, block: int = COUNTER_BLOCK) -> None:
        if block < 1:
            raise ValueError(f"block must be at least 1, got {block}")
        self.path = Path(path)
        self.block = block
        #: Reservations written since open (one per block).
        self.writes = 0
        text = _read_small(self.path, "bundle counter file")
        if text is None:
            start = 1
        else:
            m = _COUNTER_LINE.fullmatch(text)
            if m is None or not 1 <= int(m.group(1)) <= MAX_COUNTER + 1:
                raise CounterError(
                    f"{self.path}: not a bundle counter file (one line `{_COUNTER_TAG} N`)\n"
                    f"hint: it is the robot's own; restore it from a backup no older than the "
                    f"robot's last run, or re-key the swarm and delete it"
                )
            start = int(m.group(1))
        self._next = start
        self._end = start  # nothing reserved yet in this run

    def next(self) -> int:
        """The next counter, reserving a block on disk first when the last one is used up."""
        c = self._next
        if c >= self._end:
            if c > MAX_COUNTER:
                raise CounterError(f"{self.path}: counters exhausted: re-key the swarm")
            end = min(c + self.block, MAX_COUNTER + 1)
            try:
                write_atomic(self.path, f"{_COUNTER_TAG} {end}\n".encode())
            except OSError as e:
                raise CounterError(
                    f"{self.path}: cannot reserve counters: {e.strerror or e}\n"
                    f"hint: the state directory must be writable"
                ) from None
            self._end = end
            self.writes += 1
        self._next = c + 1
        return c

    @property
    def upcoming(self) -> int:
        """The counter `next()` returns next (a recording keeps it, for a replay)."""
        return self._next

    @property
    def reserved_end(self) -> int:
        """The end of the block reserved on disk (what a reboot starts at)."""
        return self._end


class FloorStore:
    """A receiver's memory of each sender's highest counter, saved at a low rate.

    After a reboot, `Verifier(key, floors=store.load())` rejects everything up to what was
    saved. `save_if_due(verifier.floors())` writes (`write_atomic`) only when a sender moved
    `every` counters past its saved floor (or was not saved yet), so a swarm at 10 Hz costs
    about one write a minute. What it leaves open is in docs/security.md#receiver-reboot.
    The file names the key's fingerprint: floors saved under another swarm key are not
    loaded (bundles of the old key fail the tag anyway, and a re-key must also clear any
    floor a captured robot pushed up). A missing file is an empty memory; a damaged one a
    CounterError.
    """

    def __init__(self, path: Path | str, key: BundleKey, every: int = FLOOR_EVERY) -> None:
        if every < 1:
            raise ValueError(f"every must be at least 1, got {every}")
        self.path = Path(path)
        self.key = key
        self.every = every
        #: Whether the last load found floors of another key (and ignored them).
        self.other_key = False
        #: Saves since open.
        self.writes = 0
        self._saved: dict[int, int] = {}

    def load(self) -> dict[int, int]:
        """The floors last saved (sender -> counter); {} without a file."""
        text = _read_small(self.path, "bundle floor file")
        if text is None:
            self._saved = {}
            return {}
        lines = text.split("\n")
        bad = CounterError(
            f"{self.path}: not a bundle floor file (`{_FLOOR_TAG} KEY`, then `SENDER COUNTER` "
            f"lines)\nhint: delete it: the receiver then forgets its neighbours' counters, "
            f"which only reopens the replay window of a receiver reboot (docs/security.md)"
        )
        head = lines[0].split(" ")
        if len(head) != 2 or head[0] != _FLOOR_TAG or lines[-1] != "":
            raise bad
        self.other_key = head[1] != self.key.fingerprint
        if self.other_key:
            self._saved = {}
            return {}
        floors: dict[int, int] = {}
        for line in lines[1:-1]:
            m = _FLOOR_LINE.fullmatch(line)
            if m is None:
                raise bad
            s, c = int(m.group(1)), int(m.group(2))
            if s > 0xFFFF or c > MAX_COUNTER:
                raise bad
            floors[s] = c
        self._saved = dict(floors)
        return floors

    def due(self, floors: Mapping[int, int]) -> bool:
        """Whether some sender moved `every` counters past what was saved."""
        saved = self._saved
        every = self.every
        return any(c - saved.get(s, 0) >= every for s, c in floors.items())

    def save(self, floors: Mapping[int, int]) -> None:
        """Write `floors` now (keeping the higher of saved and new per sender)."""
        merged = dict(self._saved)
        for s, c in floors.items():
            merged[s] = max(merged.get(s, 0), c)
        body = "".join(f"{s} {c}\n" for s, c in sorted(merged.items()))
        try:
            write_atomic(self.path, f"{_FLOOR_TAG} {self.key.fingerprint}\n{body}".encode())
        except OSError as e:
            raise CounterError(f"{self.path}: cannot save: {e.strerror or e}") from None
        self._saved = merged
        self.writes += 1

    def save_if_due(self, floors: Mapping[int, int]) -> bool:
        """`save(floors)` if `due(floors)`; whether it wrote."""
        if not self.due(floors):
            return False
        self.save(floors)
        return True


#: The XBee RF bytes of the largest sealed bundle ('S', sysid, msgid, words): within 250.
MAX_SEALED_RF_BYTES = RF_PREFIX + MAX_SEALED_AIR_BYTES

__all__ = [
    "ACCEPTED",
    "AuthError",
    "BAD_FORMAT",
    "BAD_TAG",
    "BundleKey",
    "COUNTER_BLOCK",
    "CounterError",
    "CounterSource",
    "CounterStore",
    "FLOOR_EVERY",
    "FORMAT",
    "FloorStore",
    "MAX_COUNTER",
    "MAX_PLAIN_AIR_BYTES",
    "MAX_SEALED_AIR_BYTES",
    "MAX_SEALED_RF_BYTES",
    "MAX_SENDERS",
    "MIN_SEALED_AIR_BYTES",
    "MISSING_TRAILER",
    "MemoryCounter",
    "REASONS",
    "REPLAYED",
    "SEALED_MAX_BUZZ_BYTES",
    "SEALED_MAX_MSG_SIZE",
    "Sealer",
    "TAG_BYTES",
    "TOO_OLD",
    "TRAILER_BYTES",
    "UNKNOWN_KEY",
    "Verifier",
    "WINDOW",
    "bundle_key",
    "bundle_sender",
    "is_sealed",
    "word_a",
]
