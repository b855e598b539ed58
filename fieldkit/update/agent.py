"""One robot's side of an over-the-air update: gossip, pull, verify, agree, switch, roll back.

A sans-I/O state machine (docs/update.md#spreading-agreeing-switching-rolling-back): the
host feeds it the update frames the radio heard (`receive`) and the tick count (`tick`); it
answers with at most one frame to broadcast, within its byte budget, and at most one
`Action` for the host to carry out on the robot's runtime. It never touches a port, a
file or a clock.

The protocol, in short:

* Every robot gossips a STATUS (its version, the hash of what it runs, its phase, a
  heartbeat) and, with it, a rotating share of the barrier table (ENTRIES): what it last
  heard of every other robot, newest heartbeat winning, as a virtual stigmergy does.
* A robot holding a patch OFFERs it to a neighbour whose running hash is the patch's base
  and whose version is older. The neighbour pulls it: WANT names the missing chunks, any
  robot holding them answers with CHUNKs (partial holders too, so a patch pipelines down a
  line of robots), lost chunks are asked for again.
* A whole patch is verified (`patch.open_update`: signature, version rules, base, decrypt,
  apply, result hash, bytecode loads). Then the robot stands by (the host holds it still)
  and its barrier entry says it is ready for the new version.
* The barrier passes on a robot when every live entry (a heartbeat newer than `live_ticks`,
  this robot's own included, ground stations excluded) is ready for, or runs, the new
  version; or as soon as a live robot already runs it (the swarm agreed somewhere). The robot
  switches and stays in grace for `grace_ticks`.
* A barrier that does not pass within `barrier_timeout_ticks`, a script error in grace, or
  an operator's order makes a VERDICT: the version is bad. Every robot that hears it leaves
  that version for the one before it (the patch's base: the same on every robot), never goes
  back to it, and passes the verdict on. A bad verdict beats a switch, so the swarm ends on
  one version.
"""

from __future__ import annotations

import hashlib
import logging
import random
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

from fieldkit.update import packets as pk
from fieldkit.update.packets import Phase, Reason

# The patch's own bounds: a robot checks them before it pulls, the verifier again in full.
from fieldkit.update.patch import MAX_PATCH_BYTES, MAX_VERSION_STEP
from fieldkit.update.release import Release

_log = logging.getLogger("fieldkit.update")

#: Refused patch digests remembered (the oldest forgotten first).
REFUSED_KEPT = 256

#: Serial-number arithmetic on the u16 heartbeat: `a` is newer than `b`.
_HALF = 1 << 15


def newer(a: int, b: int) -> bool:
    """Whether u16 heartbeat `a` comes after `b` (wrapping, RFC 1982 style)."""
    return 0 < (a - b) & 0xFFFF < _HALF


@dataclass
class AgentConfig:
    """The update protocol's knobs, in ticks (10 per second) and bytes."""

    #: Update bytes a robot may put on the air per tick, next to its bundle.
    budget_bytes: int = 160
    #: Ticks between STATUS frames when nothing is happening, and while an update is.
    quiet_every: int = 10
    busy_every: int = 2
    #: A robot's heartbeat advances this often (and on every change of phase).
    heartbeat_every: int = 10
    #: An entry whose heartbeat has not advanced for this long is not waited for.
    live_ticks: int = 600
    #: A barrier that sees no robot become ready for this long rolls the version back.
    barrier_timeout_ticks: int = 600
    #: A script error this soon after a switch rolls the version back.
    grace_ticks: int = 100
    #: Ticks between WANTs of a robot pulling a patch, and between OFFERs of a holder.
    want_every: int = 3
    offer_every: int = 5
    #: How long a verdict is repeated after it is learnt.
    verdict_ticks: int = 200
    #: Barrier entries passed on per STATUS at most.
    entries_per_frame: int = 12
    #: An update "goes quiet" this long after the last sign of one.
    busy_ticks: int = 300


# ------------------------------------------------------------------ actions


@dataclass(frozen=True)
class Standby:
    """Hold the robot still: a verified version waits for the swarm's agreement."""

    version: int


@dataclass(frozen=True)
class Resume:
    """Leave standby and go on with the running version (the update was abandoned)."""

    version: int
    reason: str


@dataclass(frozen=True)
class Switch:
    """Start `release` (its global code and init()) as version `version`."""

    version: int
    release: Release
    reason: str


@dataclass(frozen=True)
class Rollback:
    """Leave bad version `bad` and start `release`, version `version`, again."""

    version: int
    release: Release
    bad: int
    reason: str


Action = Standby | Resume | Switch | Rollback


# ------------------------------------------------------------------ state


@dataclass
class _Peer:
    """What this robot knows of another: its newest heartbeat and barrier entry."""

    heartbeat: int
    phase: Phase
    version: int  # the version its barrier entry names (running, or the one it stands by for)
    fresh_at: int  # local tick its heartbeat last advanced
    changed_at: int  # local tick its entry last changed
    sent_at: int = -1  # local tick this robot last passed the entry on
    running: bytes = b""  # SHORT hash of what it runs, when heard from it directly


@dataclass
class _Transfer:
    """A patch this robot holds, whole or in part."""

    digest: bytes
    version: int
    total: int
    base: bytes  # SHORT hash of the version it applies to
    chunks: dict[int, bytes] = field(default_factory=dict)
    offered_at: int = -1  # the last tick a neighbour offered it (while pulling it)
    # The last tick we offered it (serving): kept apart from `offered_at`, or a neighbour's
    # STATUS asking for an offer would also stop our own WANTs (a pull stalled for good on
    # a paced radio, where chunks come slower than the neighbours' STATUS frames).
    served_at: int = -1
    asked: dict[int, int] = field(default_factory=dict)  # chunk -> tick a neighbour asked

    @property
    def count(self) -> int:
        """Chunks in the whole patch."""
        return -(-self.total // pk.CHUNK_BYTES)

    @property
    def complete(self) -> bool:
        """Whether every chunk is here."""
        return len(self.chunks) == self.count

    def data(self) -> bytes:
        """The whole patch (only when complete)."""
        return b"".join(self.chunks[i] for i in range(self.count))


def short(hex_hash: str) -> bytes:
    """The on-air form of a version's hash: its first 8 bytes."""
    return bytes.fromhex(hex_hash)[: pk.SHORT]


def digest_of(patch: bytes) -> bytes:
    """A patch's identity on the air: the first 8 bytes of its SHA-256."""
    return hashlib.sha256(patch).digest()[: pk.SHORT]


#: Verifies a whole patch against the running release: (version, new release), or raises an
#: error with a `.reason` (fieldkit.update.patch.PatchError).
Verifier = Callable[[bytes, Release, int], tuple[int, Release]]


class UpdateAgent:
    """One robot's update protocol: frames and ticks in, a frame and actions out."""

    def __init__(
        self,
        robot_id: int,
        version: int,
        release: Release | None,
        verify: Verifier,
        *,
        previous: list[tuple[int, Release]] | None = None,
        highest: int = 0,
        bad: dict[int, str] | None = None,
        config: AgentConfig | None = None,
        seed: int = 0,
        frame_key: bytes | None = None,
    ) -> None:
        """`release` is what the robot runs as `version` (None: a ground station, which
        serves patches and is never waited for); `previous` the versions before it, newest
        first (rollback targets); `highest` and `bad` what the store remembers;
        `frame_key` (`packets.frame_key` of the swarm key) seals every frame sent and is
        checked on every frame heard. Every host gives it; only tests of the protocol
        alone leave it out."""
        self.frame_key = frame_key
        self.id = robot_id
        self.version = version
        self.release = release
        self.verify = verify
        self.previous = list(previous or [])
        self.highest = max(highest, version)
        self.bad: dict[int, str] = dict(bad or {})
        self.config = config or AgentConfig()
        self.rng = random.Random(f"update:{seed}:{robot_id}")
        self.phase = Phase.OPERATOR if release is None else Phase.RUNNING
        self.target = 0
        self.since = 0  # tick the phase began
        self.staged: tuple[int, Release] | None = None
        self.heartbeat = 0
        self.peers: dict[int, _Peer] = {}
        self.transfers: dict[bytes, _Transfer] = {}
        # Digests that failed verification: never pulled again (the newest REFUSED_KEPT).
        self.refused: dict[bytes, None] = {}
        self.verdicts: dict[int, tuple[Reason, int]] = {}  # bad version -> reason, until tick
        # The bad versions this robot judged itself (its script error, its barrier's timeout,
        # an order given to it), not heard of: its `bad` text is the first-hand reason.
        self.judged: set[int] = set()
        self.counters: Counter[str] = Counter()
        self.events: list[str] = []  # what happened, for the host's log (host empties it)
        self.verified: list[tuple[int, bytes]] = []  # patches that checked out (host empties it)
        self.bytes_sent = 0
        self.now = 0
        self._busy_until = -1
        self._progress_at = 0  # tick the barrier last saw a robot become ready
        self._waiting = 1 << 30  # live robots not ready, at the last look
        # A bad version this robot cannot leave (nothing older to run): noted once, not
        # retried every tick.
        self._stuck_on: int | None = None
        self._last_status = -(10**9)
        self._last_want = -(10**9)

    # ------------------------------------------------------------ inputs

    @property
    def running_hash(self) -> str:
        """The hex hash of what this robot runs ('' for a ground station)."""
        return self.release.hash if self.release is not None else ""

    def inject(self, patch: bytes) -> bool:
        """A whole patch handed over locally (the originator): verify it as if received."""
        t = _Transfer(digest_of(patch), 0, len(patch), b"")
        for i in range(0, len(patch), pk.CHUNK_BYTES):
            t.chunks[i // pk.CHUNK_BYTES] = patch[i : i + pk.CHUNK_BYTES]
        return self._complete(t, local=True)

    def hold(self, patch: bytes, version: int, base_hash: str) -> None:
        """Serve `patch` (version `version`, built on `base_hash`) to robots that need it,
        without applying it here (a ground station, or a patch kept from the store)."""
        t = _Transfer(digest_of(patch), version, len(patch), short(base_hash))
        for i in range(0, len(patch), pk.CHUNK_BYTES):
            t.chunks[i // pk.CHUNK_BYTES] = patch[i : i + pk.CHUNK_BYTES]
        self.transfers[t.digest] = t

    def order_rollback(self, version: int) -> None:
        """The operator's order: version `version` is bad, everyone leaves it."""
        self._learn_bad(version, Reason.OPERATOR, "ordered by the operator")

    def script_failed(self, error: str) -> None:
        """The host's script stopped on an error: in grace, that rolls the version back."""
        if self.phase is Phase.GRACE:
            self._learn_bad(self.version, Reason.SCRIPT_ERROR, f"robot {self.id}: {error}")

    def receive(self, data: bytes, sender_hint: int | None = None) -> None:
        """An update frame off the radio (a bad one costs a counter, nothing more)."""
        try:
            if self.frame_key is not None:
                data = pk.unseal(data, self.frame_key)
            frame = pk.decode(data)
        except pk.FrameError as e:
            self.counters["bad_frames"] += 1
            _log.debug("robot %d: bad update frame: %s", self.id, e)
            return
        sender = frame.sender
        if sender == self.id:
            self.counters["own_echoes"] += 1
            return
        # Verdicts first: a STATUS in the same frame only says that a version is bad, the
        # verdict says why.
        for r in frame.records:
            if isinstance(r, pk.Verdict):
                self._learn_bad(r.version, r.reason, f"heard from robot {sender}", heard=True)
        for r in frame.records:
            if isinstance(r, pk.Status):
                self._on_status(sender, r)
            elif isinstance(r, pk.Entries):
                for entry in r.entries:
                    if entry.robot != self.id:
                        self._note(entry.robot, entry.heartbeat, entry.phase, entry.version)
            elif isinstance(r, pk.Offer):
                self._on_offer(r)
            elif isinstance(r, pk.Want):
                self._on_want(r)
            elif isinstance(r, pk.Chunk):
                self._on_chunk(r)

    def _note(self, robot: int, heartbeat: int, phase: Phase, version: int) -> None:
        p = self.peers.get(robot)
        if p is None:
            self.peers[robot] = _Peer(heartbeat, phase, version, self.now, self.now)
        elif newer(heartbeat, p.heartbeat):
            if (p.phase, p.version) != (phase, version):
                p.changed_at = self.now
            p.heartbeat, p.phase, p.version, p.fresh_at = heartbeat, phase, version, self.now

    def _on_status(self, sender: int, s: pk.Status) -> None:
        entry = s.target if s.phase in (Phase.STANDBY, Phase.GRACE) else s.version
        self._note(sender, s.heartbeat, s.phase, entry)
        self.peers[sender].running = s.running
        if s.bad and s.bad not in self.bad:
            self._learn_bad(s.bad, None, f"robot {sender} says it was rolled back", heard=True)
        if s.phase is not Phase.OPERATOR and s.phase is not Phase.GRACE:
            self._offer_to(s)
        if s.phase is not Phase.RUNNING or s.target:
            self._busy()

    def _offer_to(self, s: pk.Status) -> None:
        """A neighbour runs `s.running`: note every patch we hold that it could use."""
        for t in self.transfers.values():
            if t.base == s.running and t.version > s.version and t.version not in self.bad:
                t.served_at = -1  # offer it at the next chance (the neighbour needs it)

    def _wants(self, version: int, base: bytes) -> bool:
        """Whether this robot should pull a patch to `version` built on `base`."""
        return (
            self.release is not None
            and self.phase is Phase.RUNNING
            and self.staged is None
            and self.version < version <= max(self.version, self.highest) + MAX_VERSION_STEP
            and version not in self.bad
            and base == short(self.release.hash)
        )

    def _on_offer(self, o: pk.Offer) -> None:
        t = self.transfers.get(o.digest)
        if t is not None:
            if not t.complete:
                t.offered_at = self.now
            return
        if o.digest in self.refused or not self._wants(o.version, o.base):
            return
        if not 0 < o.total <= MAX_PATCH_BYTES:
            self.counters["refused_too_large"] += 1
            self._refused(o.digest)
            self.events.append(f"patch offer of {o.total} bytes refused: larger than any patch")
            return
        # One pull at a time: a newer offer replaces an unfinished older one.
        for d, old in list(self.transfers.items()):
            if not old.complete and old.version < o.version:
                del self.transfers[d]
        if any(not x.complete for x in self.transfers.values()):
            return
        self.transfers[o.digest] = _Transfer(
            o.digest, o.version, o.total, o.base, offered_at=self.now
        )
        self.events.append(f"pulling version {o.version} ({o.total} bytes)")
        self._busy()

    def _on_want(self, w: pk.Want) -> None:
        t = self.transfers.get(w.digest)
        if t is None:
            return
        for i in w.chunks():
            if i in t.chunks:
                t.asked[i] = self.now
        self._busy()

    def _on_chunk(self, c: pk.Chunk) -> None:
        t = self.transfers.get(c.digest)
        if t is None or t.complete or c.index in t.chunks:
            return
        expected = min(pk.CHUNK_BYTES, t.total - c.index * pk.CHUNK_BYTES)
        if c.index >= t.count or len(c.data) != expected:
            self.counters["bad_chunks"] += 1
            return
        t.chunks[c.index] = c.data
        self._busy()
        if t.complete:
            self._complete(t, local=False)

    def _complete(self, t: _Transfer, *, local: bool) -> bool:
        """A whole patch: verify it; on success stage it and keep it to serve."""
        data = t.data()
        if digest_of(data) != t.digest:
            self._refuse(t, "bad-digest", "its bytes do not match the digest it was offered by")
            return False
        release = self.release
        if release is None:
            self._refuse(t, "no-base", "a ground station runs no version to patch")
            return False
        try:
            version, new = self.verify(data, release, max(self.version, self.highest))
        except Exception as e:  # a PatchError: anything else would be a verifier bug
            reason = getattr(e, "reason", "bad-patch")
            self._refuse(t, reason, str(e))
            return False
        if version in self.bad:
            self._refuse(t, "rolled-back", f"version {version} was rolled back")
            return False
        t.version, t.base = version, short(release.hash)
        self.transfers[t.digest] = t
        self.staged = (version, new)
        self.verified.append((version, data))
        self.highest = max(self.highest, version)
        self.counters["patches_verified"] += 1
        how = "made here" if local else "received"
        self.events.append(f"version {version} ({new.hash[:12]}) {how} and verified")
        self._busy()
        return True

    def _refuse(self, t: _Transfer, reason: str, detail: str) -> None:
        self.transfers.pop(t.digest, None)
        self._refused(t.digest)
        self.counters[f"refused_{reason}"] += 1
        self.events.append(f"patch refused ({reason}): {detail}")

    def _refused(self, digest: bytes) -> None:
        self.refused[digest] = None
        if len(self.refused) > REFUSED_KEPT:
            del self.refused[next(iter(self.refused))]

    def _learn_bad(
        self, version: int, reason: Reason | None, detail: str, *, heard: bool = False
    ) -> None:
        """Version `version` is bad; a verdict with a reason is passed on for a while. A
        version that could never be accepted (past the fast-forward bound) is ignored: the
        list stays bounded whatever a sender claims."""
        if version in self.bad or version <= 0:
            return
        if version > max(self.version, self.highest) + MAX_VERSION_STEP:
            return
        if not heard:
            self.judged.add(version)
        if reason is None:
            self.bad[version] = detail
        else:
            self.bad[version] = f"{reason.name.lower().replace('_', ' ')}: {detail}"
            self.verdicts[version] = (reason, self.now + self.config.verdict_ticks)
        self.events.append(f"version {version} rolled back ({self.bad[version]})")
        for d, t in list(self.transfers.items()):
            if t.version == version:
                del self.transfers[d]
        self._busy()

    def _busy(self) -> None:
        self._busy_until = self.now + self.config.busy_ticks

    # ------------------------------------------------------------ one tick

    def tick(self, now: int) -> Action | None:
        """Decide, at tick `now`, what the host does to the robot (None: nothing)."""
        self.now = now
        cfg = self.config
        if now % cfg.heartbeat_every == 0:
            self.heartbeat = (self.heartbeat + 1) & 0xFFFF
        if self.release is None:
            return None
        action: Action | None = None
        phase = self.phase
        leave = self.version in self.bad and self.version != self._stuck_on
        if phase is Phase.GRACE and leave:
            action = self._roll_back()
        elif phase is Phase.RUNNING and leave:
            action = self._roll_back()
        elif phase is Phase.STANDBY:
            if self.target in self.bad:
                action = self._resume(self.bad[self.target])
            elif self._agreed():
                action = self._switch("the swarm agreed")
            elif now - self._progress_at > cfg.barrier_timeout_ticks:
                seconds = cfg.barrier_timeout_ticks / 10
                waiting = ", ".join(str(r) for r in self._not_ready()[:8])
                self._learn_bad(
                    self.target,
                    Reason.BARRIER_TIMEOUT,
                    f"no robot became ready for {seconds:g} s (waiting for robots {waiting})",
                )
                action = self._resume(self.bad[self.target])
        elif phase is Phase.GRACE and now - self.since > cfg.grace_ticks:
            self._enter(Phase.RUNNING, 0)
            self.events.append(f"version {self.version} passed its grace period")
        elif phase is Phase.RUNNING and self.staged is not None:
            version = self.staged[0]
            if version in self.bad:
                self.staged = None
            elif self._someone_runs(version):
                action = self._switch("catching up: the swarm runs it")
            else:
                self._enter(Phase.STANDBY, version)
                action = Standby(version)
        return action

    def _enter(self, phase: Phase, target: int) -> None:
        self.phase, self.target, self.since = phase, target, self.now
        self._progress_at, self._waiting = self.now, 1 << 30
        self.heartbeat = (self.heartbeat + 1) & 0xFFFF  # the news travels as a newer entry

    def live(self) -> dict[int, _Peer]:
        """The robots heard recently (a heartbeat newer than `live_ticks`), by id: those a
        barrier waits for (ground stations excluded)."""
        horizon = self.now - self.config.live_ticks
        return {
            rid: p
            for rid, p in self.peers.items()
            if p.fresh_at >= horizon and p.phase is not Phase.OPERATOR
        }

    def _not_ready(self) -> list[int]:
        """The live robots not (yet) standing by for, or running, the target version."""
        return [rid for rid, p in self.live().items() if p.version != self.target]

    def _agreed(self) -> bool:
        """The barrier: every live robot stands by for, or runs, the target version. A
        robot more ready than before restarts the timeout: a big swarm is slow, not stuck."""
        waiting = len(self._not_ready())
        if waiting < self._waiting:
            self._progress_at = self.now
        self._waiting = waiting
        return waiting == 0 or self._someone_runs(self.target)

    def _someone_runs(self, version: int) -> bool:
        return any(
            p.version == version and p.phase in (Phase.RUNNING, Phase.GRACE)
            for p in self.live().values()
        )

    def _switch(self, reason: str) -> Switch:
        assert self.staged is not None and self.release is not None
        version, release = self.staged
        self.previous.insert(0, (self.version, self.release))
        self.version, self.release, self.staged = version, release, None
        self._enter(Phase.GRACE, version)
        self.events.append(f"switched to version {version} ({release.hash[:12]}): {reason}")
        return Switch(version, release, reason)

    def _resume(self, reason: str) -> Resume:
        target = self.target
        self.staged = None
        self._enter(Phase.RUNNING, 0)
        return Resume(target, reason)

    def _roll_back(self) -> Rollback | None:
        bad = self.version
        reason = self.bad[bad]
        if not self.previous:
            self._stuck_on = bad
            self._enter(Phase.RUNNING, 0)
            self.events.append(f"version {bad} is bad but this robot has nothing older to run")
            return None
        version, release = self.previous.pop(0)
        self.version, self.release, self.staged = version, release, None
        self._enter(Phase.RUNNING, 0)
        self.events.append(f"rolled back from version {bad} to {version}: {reason}")
        return Rollback(version, release, bad, reason)

    # ------------------------------------------------------------ radio out

    def frame(self) -> bytes | None:
        """This tick's update frame, within the byte budget (None: nothing to send)."""
        cfg = self.config
        now = self.now
        # Padding rounds a frame up to whole words, and no frame exceeds MAX_FRAME_BYTES:
        # the room is what is left of the budget in whole words, after word 0.
        tag = pk.TAG_BYTES if self.frame_key is not None else 0
        room = min(cfg.budget_bytes, pk.MAX_FRAME_BYTES) // 8 * 8 - 8 - tag
        records: list[pk.Record] = []

        def add(record: pk.Record, size: int) -> bool:
            nonlocal room
            if size > room:
                return False
            records.append(record)
            room -= size
            return True

        busy = now <= self._busy_until
        every = cfg.busy_every if busy else cfg.quiet_every
        if now - self._last_status >= every:
            self._last_status = now
            add(self._status(), pk.STATUS_BYTES)
        for version, (reason, until) in list(self.verdicts.items()):
            if now > until:
                del self.verdicts[version]
            elif now % 5 == 0:
                add(pk.Verdict(version, reason), pk.VERDICT_BYTES)
        self._serve(add)
        self._pull(add)
        self._offer(add)
        if records and (busy or now == self._last_status):
            self._entries(add, room)
        if not records:
            return None
        data = pk.encode(pk.Frame(self.id, tuple(records)))
        if self.frame_key is not None:
            data = pk.seal(data, self.frame_key)
        self.bytes_sent += len(data)
        return data

    def _status(self) -> pk.Status:
        running = short(self.release.hash) if self.release is not None else bytes(pk.SHORT)
        bad = max(self.bad, default=0)
        return pk.Status(self.version, running, self.phase, self.target, bad, self.heartbeat)

    def _serve(self, add: Callable[[pk.Record, int], bool]) -> None:
        """Answer one asked-for chunk (a random one, so holders answering the same WANT
        rarely send the same chunk)."""
        horizon = self.now - 3 * self.config.want_every
        for t in self.transfers.values():
            asked = [i for i, at in t.asked.items() if at >= horizon]
            t.asked = {i: t.asked[i] for i in asked}
            if not asked:
                continue
            i = asked[int(self.rng.random() * len(asked))]
            data = t.chunks[i]
            if add(pk.Chunk(t.digest, i, data), pk.chunk_bytes(len(data))):
                del t.asked[i]
                self.counters["chunks_sent"] += 1
            return

    def _pull(self, add: Callable[[pk.Record, int], bool]) -> None:
        if self.now - self._last_want < self.config.want_every:
            return
        for t in self.transfers.values():
            if t.complete or self.now - t.offered_at > 10 * self.config.want_every:
                continue
            missing = [i for i in range(t.count) if i not in t.chunks]
            first = missing[0]
            bitmap = 0
            for i in missing:
                if i - first < pk.WANT_WINDOW:
                    bitmap |= 1 << (i - first)
            if add(pk.Want(t.digest, first, bitmap), pk.WANT_BYTES):
                self._last_want = self.now
            return

    def _offer(self, add: Callable[[pk.Record, int], bool]) -> None:
        for t in self.transfers.values():
            if t.version in self.bad or not t.chunks:
                continue
            if t.served_at >= 0 and self.now - t.served_at < self.config.offer_every:
                continue
            if not self._needed(t):
                continue
            if add(pk.Offer(t.digest, t.version, t.total, t.base), pk.OFFER_BYTES):
                t.served_at = self.now
            return

    def _needed(self, t: _Transfer) -> bool:
        """Whether a live neighbour runs an older version than `t` (it may need it)."""
        return any(p.version < t.version for p in self.live().values())

    def _entries(self, add: Callable[[pk.Record, int], bool], room: int) -> None:
        n = min(self.config.entries_per_frame, (room - 3) // pk.ENTRY_BYTES)
        if n <= 0:
            return
        # What changed since we last passed it on first, then the longest unsent.
        live = sorted(
            self.live().items(), key=lambda kv: (kv[1].sent_at > kv[1].changed_at, kv[1].sent_at)
        )
        chosen = live[:n]
        if not chosen:
            return
        entries = tuple(pk.Entry(rid, p.heartbeat, p.phase, p.version) for rid, p in chosen)
        if add(pk.Entries(entries), pk.entries_bytes(len(entries))):
            for _, p in chosen:
                p.sent_at = self.now


__all__ = [
    "Action",
    "AgentConfig",
    "MAX_PATCH_BYTES",
    "MAX_VERSION_STEP",
    "Resume",
    "Rollback",
    "Standby",
    "Switch",
    "UpdateAgent",
    "Verifier",
    "digest_of",
    "newer",
    "short",
]
