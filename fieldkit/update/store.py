"""The version store: a robot's script versions on disk, what it runs after a reboot.

The node's `--state-dir` holds:

    releases/<hash>.bo|.bdb|.bpos   every version received, named by its bytecode's SHA-256
    committed.json                  the committed version: what the node runs at start
    history.jsonl                   one JSON object per event, appended
    patches/<version>.fkup          patches kept for neighbours that catch up

Durability rule: every file is written whole to a temporary file beside it, fsynced, renamed
over the old one and its directory fsynced (`write_atomic`), so a crash leaves the old file or
the new one. A release's bytecode is written after its sidecars: a `.bo` that exists is a
complete release. `committed.json` is the commit point; it is replaced only after the release
it names is stored, and the history line that tells of the change is appended after it (the
store adds a line the process died before writing when it opens). A torn last history line
is cut off at open, and temporary files a crash left behind are removed.

A store that opens on a committed.json that does not parse, or that names a release that is
missing or corrupt, recovers: it goes back to the newest complete, verified version it knows
of (committed.json's previous versions, else the history's) and says so in `notes` and in
the history. Only when no such version exists is it a `StoreError`.
"""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, TypeGuard

from fieldkit.errors import FieldkitError
from fieldkit.update.release import (
    MAX_RELEASE_BYTES,
    SIDECARS,
    Release,
    ReleaseError,
    fsync_dir,
    sha256_hex,
    write_atomic,
)

#: committed.json's format number: a store written by a later fieldkit is refused, not misread.
STORE_FORMAT = 1

#: A version's name: the hex SHA-256 of its bytecode.
_HASH = re.compile(r"[0-9a-f]{64}")

#: What `write_atomic` leaves behind when it dies before its rename.
_TEMP = re.compile(r"\..+\.tmp")

#: The history events that change the committed version (they carry the whole state).
STATE_EVENTS = frozenset({"seeded", "committed", "rolled-back", "recovered"})

#: A patch file's name: its version number.
_PATCH = re.compile(r"(\d+)\.fkup")


class StoreError(FieldkitError):
    """A version store that cannot do what was asked: which file, what is wrong, a hint."""


def utc_stamp(t: float) -> str:
    """`t` (seconds since the epoch) as `2026-11-26T09:03:24.123Z`."""
    whole, ms = divmod(int(t * 1000), 1000)
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(whole)) + f".{ms:03d}Z"


@dataclass(frozen=True)
class Committed:
    """The committed version and what the store knows around it."""

    version: int
    hash: str
    #: Older committed versions (version, hash), newest first: where a rollback goes.
    previous: tuple[tuple[int, str], ...] = ()
    #: The highest version number ever committed or rolled back: the replay floor.
    highest: int = 0
    #: Versions rolled back: never switched to again.
    bad: tuple[int, ...] = ()
    #: When this became the committed version (UTC, `utc_stamp`), how, and why.
    time: str = ""
    event: str = "committed"
    reason: str = ""

    def to_json(self) -> dict[str, Any]:
        """committed.json's object (and a state event's fields in the history)."""
        d = asdict(self)
        d["previous"] = [list(p) for p in self.previous]
        d["bad"] = list(self.bad)
        return d

    @classmethod
    def from_json(cls, d: object) -> Committed:
        """The state in `d`; ValueError if any field is missing or of the wrong shape."""
        if not isinstance(d, dict):
            raise ValueError("not a JSON object")
        version, hash_, highest = d.get("version"), d.get("hash"), d.get("highest")
        if not (_is_version(version) and _is_hash(hash_) and _is_version(highest)):
            raise ValueError("version, hash or highest missing or malformed")
        previous = d.get("previous", [])
        bad = d.get("bad", [])
        if not isinstance(previous, list) or not all(
            isinstance(p, list) and len(p) == 2 and _is_version(p[0]) and _is_hash(p[1])
            for p in previous
        ):
            raise ValueError("previous is not a list of [version, hash]")
        if not isinstance(bad, list) or not all(_is_version(v) for v in bad):
            raise ValueError("bad is not a list of versions")
        texts = [d.get(k, "") for k in ("time", "event", "reason")]
        if not all(isinstance(t, str) for t in texts):
            raise ValueError("time, event or reason is not a string")
        time_, event, reason = (str(t) for t in texts)
        return cls(
            version, hash_, tuple((v, h) for v, h in previous), highest, tuple(bad),
            time_, event, reason,
        )  # fmt: skip


def _is_version(v: object) -> TypeGuard[int]:
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


def _is_hash(h: object) -> TypeGuard[str]:
    return isinstance(h, str) and _HASH.fullmatch(h) is not None


class VersionStore:
    """A node's state directory: releases by hash, the committed version, history, patches."""

    def __init__(self, root: Path, *, clock: Callable[[], float] = time.time) -> None:
        """Open (creating) the store at `root`: remove a crash's temporary files, cut a torn
        history line, and recover if the committed version is unusable (see `notes`)."""
        self.root = Path(root)
        self.clock = clock
        #: What opening found and did (a recovery, files cleaned): for the node to log.
        self.notes: list[str] = []
        self.releases = self.root / "releases"
        self.patches_dir = self.root / "patches"
        self.committed_path = self.root / "committed.json"
        self.history_path = self.root / "history.jsonl"
        try:
            for d in (self.releases, self.patches_dir):
                d.mkdir(parents=True, exist_ok=True)
            fsync_dir(self.root)
        except OSError as e:
            raise StoreError(
                f"{self.root}: cannot create the state directory: {e.strerror or e}"
            ) from None
        self._clean()
        self._state = self._open_state()

    # ------------------------------------------------------------ releases

    def path(self, hash: str) -> Path:
        """Where the release `hash` keeps its bytecode (its sidecars are beside it)."""
        if not _is_hash(hash):
            raise StoreError(f"{hash!r} is not a version hash (64 lowercase hex digits)")
        return self.releases / f"{hash}.bo"

    def put(self, release: Release) -> str:
        """Store `release` (once: a hash already stored is left as it is); its hash."""
        h = release.hash
        bo = self.path(h)
        if self.has(h):
            return h
        try:
            # The sidecars first, the bytecode last: a .bo that exists is a whole release.
            for suffix, data in zip(SIDECARS, (release.bdb, release.bpos), strict=True):
                side = bo.with_suffix(suffix)
                if data:
                    write_atomic(side, data)
                else:
                    side.unlink(missing_ok=True)  # a crashed put's, for another .bdb
            write_atomic(bo, release.bo)
        except OSError as e:
            raise StoreError(f"{bo}: cannot write the release: {e.strerror or e}") from None
        return h

    def get(self, hash: str) -> Release:
        """The release `hash`, its bytecode re-hashed; StoreError if missing or corrupt."""
        bo = self.path(hash)
        if not bo.exists():
            raise StoreError(f"{bo}: release {hash[:12]} is not in the store")
        try:
            release = Release.read(bo)
        except ReleaseError as e:
            raise StoreError(str(e)) from None
        if release.hash != hash:
            raise StoreError(
                f"{bo}: corrupt: its bytecode hashes to {release.hash[:12]}, not {hash[:12]}"
            )
        return release

    def has(self, hash: str) -> bool:
        """Whether the release `hash` is stored, whole and verified."""
        try:
            self.get(hash)
        except StoreError:
            return False
        return True

    # ------------------------------------------------------------ the committed version

    @property
    def current(self) -> Committed | None:
        """The committed version as last written, not re-verified (cheap: for every tick)."""
        return self._state

    def committed(self) -> Committed | None:
        """The committed version (None in an empty store), its release verified first: if it
        went missing or corrupt since, the store recovers (see the module's doc)."""
        state = self._state
        if state is not None and not self.has(state.hash):
            self._state = state = self._recover(
                state, f"its release {self.path(state.hash)} is missing or corrupt"
            )
        return state

    def commit(self, version: int, hash: str, *, reason: str) -> Committed:
        """Make the stored release `hash` the committed version `version` (the first one
        is "seeded"); the committed one before it becomes the newest previous. A version
        must be higher than any committed or rolled back before: StoreError otherwise."""
        if not _is_version(version):
            raise StoreError(f"version {version!r} is not a version number (an int >= 0)")
        if not self.has(hash):
            raise StoreError(
                f"{self.path(hash)}: cannot commit version {version}: its release is not "
                "stored whole (put it first)"
            )
        now = utc_stamp(self.clock())
        old = self._state
        if old is None:
            new = Committed(version, hash, (), version, (), now, "seeded", reason)
        else:
            if version <= old.highest:
                raise StoreError(
                    f"{self.committed_path}: cannot commit version {version}: version "
                    f"{old.highest} was accepted before (a version number is never reused)"
                )
            previous = ((old.version, old.hash), *old.previous)
            new = Committed(version, hash, previous, version, old.bad, now, "committed", reason)
        self._write_state(new)
        return new

    def rollback(self, bad_version: int, *, reason: str, to_hash: str | None = None) -> Committed:
        """Give up `bad_version` for good. If it is the committed version, the newest
        previous version not bad and stored whole becomes the committed one; a version
        not yet committed (a switch that never happened) is only marked bad. With `to_hash`,
        the version this ends on must be that one (StoreError otherwise, nothing written).
        Rolling back a version already bad and not running changes nothing."""
        old = self._state
        if old is None:
            raise StoreError(f"{self.root}: nothing committed, nothing to roll back")
        if bad_version < old.version:
            raise StoreError(
                f"cannot roll back version {bad_version}: this robot runs version "
                f"{old.version}, a later one"
            )
        if bad_version in old.bad and bad_version != old.version:
            self._check_target(old, to_hash, bad_version)
            return old
        bad = tuple(sorted({*old.bad, bad_version}))
        highest = max(old.highest, bad_version)
        now = utc_stamp(self.clock())
        previous = [p for p in old.previous if p[0] != bad_version]
        if bad_version == old.version:
            for i, (v, h) in enumerate(previous):
                if v in bad or (to_hash is not None and h != to_hash) or not self.has(h):
                    continue
                rest = tuple(previous[i + 1 :])
                new = Committed(v, h, rest, highest, bad, now, "rolled-back", reason)
                break
            else:
                to = f" to {to_hash[:12]}" if to_hash is not None else ""
                raise StoreError(
                    f"{self.committed_path}: cannot roll back version {bad_version}{to}: no "
                    "earlier version is stored whole"
                )
        else:
            self._check_target(old, to_hash, bad_version)
            new = replace(
                old, previous=tuple(previous), highest=highest, bad=bad, time=now,
                event="rolled-back", reason=f"version {bad_version} abandoned: {reason}",
            )  # fmt: skip
        self._write_state(new, version=bad_version)
        return new

    def _check_target(self, state: Committed, to_hash: str | None, bad_version: int) -> None:
        if to_hash is not None and to_hash != state.hash:
            raise StoreError(
                f"cannot roll back version {bad_version} to {to_hash[:12]}: this robot runs "
                f"{state.hash[:12]} (version {state.version})"
            )

    # ------------------------------------------------------------ history

    def note(
        self, event: str, *, reason: str, version: int | None = None, hash: str | None = None
    ) -> None:
        """Append an event that changes no version (a refused patch, say) to the history."""
        self._append({"event": event, "version": version, "hash": hash, "reason": reason})

    def history(self) -> list[dict[str, Any]]:
        """Every event, oldest first (a line that does not parse is skipped)."""
        try:
            data = self.history_path.read_bytes()
        except FileNotFoundError:
            return []
        except OSError as e:
            raise StoreError(f"{self.history_path}: cannot read: {e.strerror or e}") from None
        events = []
        for line in data.splitlines():
            try:
                event = json.loads(line)
            except ValueError:
                continue
            if isinstance(event, dict):
                events.append(event)
        return events

    # ------------------------------------------------------------ patches

    def put_patch(self, version: int, data: bytes) -> None:
        """Keep the patch that made `version`, for neighbours that catch up."""
        path = self._patch_path(version)
        try:
            write_atomic(path, data)
        except OSError as e:
            raise StoreError(f"{path}: cannot write: {e.strerror or e}") from None

    def patch(self, version: int) -> bytes:
        """The patch kept for `version`; StoreError if none is."""
        path = self._patch_path(version)
        try:
            return path.read_bytes()
        except OSError as e:
            raise StoreError(f"{path}: no patch kept for version {version}: "
                             f"{e.strerror or e}") from None  # fmt: skip

    def patches(self) -> list[int]:
        """The versions whose patch is kept, lowest first."""
        found = (_PATCH.fullmatch(p.name) for p in self.patches_dir.iterdir())
        return sorted(int(m.group(1)) for m in found if m)

    def _patch_path(self, version: int) -> Path:
        if not _is_version(version):
            raise StoreError(f"version {version!r} is not a version number (an int >= 0)")
        return self.patches_dir / f"{version}.fkup"

    # ------------------------------------------------------------ inside

    def _write_state(self, state: Committed, version: int | None = None) -> None:
        """committed.json (the commit point), then the history line telling of it."""
        data = {"format": STORE_FORMAT, **state.to_json()}
        try:
            write_atomic(self.committed_path, (json.dumps(data, indent=1) + "\n").encode())
        except OSError as e:
            raise StoreError(f"{self.committed_path}: cannot write: {e.strerror or e}") from None
        self._state = state
        self._append(_state_event(state, version))

    def _append(self, event: dict[str, Any]) -> None:
        """One line at the end of the history, fsynced (its directory too, when new)."""
        line = json.dumps({"time": utc_stamp(self.clock()), **event}) + "\n"
        try:
            new = not self.history_path.exists()
            fd = os.open(self.history_path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
            try:
                os.write(fd, line.encode())
                os.fsync(fd)
            finally:
                os.close(fd)
            if new:
                fsync_dir(self.root)
        except OSError as e:
            raise StoreError(f"{self.history_path}: cannot append: {e.strerror or e}") from None

    def _clean(self) -> None:
        """Remove what a crash left: temporary files, sidecars whose .bo was never written,
        a torn last history line."""
        removed = 0
        try:
            for d in (self.root, self.releases, self.patches_dir):
                for p in d.iterdir():
                    if _TEMP.fullmatch(p.name) or (
                        d == self.releases
                        and p.suffix in SIDECARS
                        and not p.with_suffix(".bo").exists()
                    ):
                        p.unlink()
                        removed += 1
                if removed:
                    fsync_dir(d)
            if removed:
                self.notes.append(
                    f"{self.root}: removed {removed} file(s) a crash left half-written"
                )
            self._cut_torn_line()
        except OSError as e:
            raise StoreError(f"{self.root}: cannot tidy the state directory: "
                             f"{e.strerror or e}") from None  # fmt: skip

    def _cut_torn_line(self) -> None:
        try:
            data = self.history_path.read_bytes()
        except FileNotFoundError:
            return
        if data and not data.endswith(b"\n"):
            keep = data.rfind(b"\n") + 1
            with self.history_path.open("r+b") as f:
                f.truncate(keep)
                os.fsync(f.fileno())
            self.notes.append(
                f"{self.history_path}: cut a torn last line ({len(data) - keep} bytes)"
            )

    def _open_state(self) -> Committed | None:
        """The committed state at open, made usable and its history complete."""
        events = [e for e in self.history() if e.get("event") in STATE_EVENTS]
        try:
            raw = self.committed_path.read_bytes()
        except FileNotFoundError:
            raw = None
        except OSError as e:
            raise StoreError(f"{self.committed_path}: cannot read: {e.strerror or e}") from None
        if raw is None and not events:
            return None  # a new store
        problem = None
        state = None
        if raw is None:
            problem = "it is missing"
        else:
            try:
                data = json.loads(raw)
                fmt = data.get("format") if isinstance(data, dict) else None
                if _is_version(fmt) and fmt > STORE_FORMAT:
                    raise StoreError(
                        f"{self.committed_path}: format {fmt}, this fieldkit reads format "
                        f"{STORE_FORMAT}: hint: run the fieldkit that wrote it"
                    )
                if fmt != STORE_FORMAT:
                    raise ValueError(f"format {fmt!r}, not {STORE_FORMAT}")
                state = Committed.from_json(data)
            except ValueError as e:
                problem = f"it does not parse ({e})"
        if state is None:
            last = _last_state(events)
            if last is None:
                raise StoreError(
                    f"{self.committed_path}: {problem}, and the history names no committed "
                    f"version: hint: move {self.root} away and start the node with --script "
                    "to seed a new store"
                )
            return self._recover(last, f"{self.committed_path.name}: {problem}", whole=True)
        if not events or not _same(_last_state(events), state):
            # The process died between committed.json and its history line.
            self._append(_state_event(state, None) | {"late": True})
        if not self.has(state.hash):
            return self._recover(
                state, f"its release {self.path(state.hash)} is missing or corrupt"
            )
        return state

    def _recover(self, state: Committed, why: str, *, whole: bool = False) -> Committed:
        """Go back to the newest version of `state` (itself when `whole`, else its previous
        ones) that is stored whole; record and note it. StoreError if there is none."""
        candidates: Iterable[tuple[int, str]] = (
            ((state.version, state.hash), *state.previous) if whole else state.previous
        )
        chain = [p for p in candidates if p[0] not in state.bad]
        for i, (v, h) in enumerate(chain):
            if not self.has(h):
                continue
            # The floor comes down to what is kept: a lost later version can be pulled again.
            highest = state.highest if whole and i == 0 else max([v, *state.bad])
            reason = (
                f"version {state.version} ({state.hash[:12]}) unusable: {why}; back to the "
                f"newest version stored whole"
            )
            if whole and i == 0:
                reason = f"rebuilt from the history: {why}"
            new = Committed(
                v, h, tuple(chain[i + 1 :]), highest, state.bad,
                utc_stamp(self.clock()), "recovered", reason,
            )  # fmt: skip
            self._write_state(new)
            self.notes.append(f"{self.root}: recovered version {v} ({h[:12]}): {reason}")
            return new
        raise StoreError(
            f"{self.root}: version {state.version} ({state.hash[:12]}) is unusable ({why}) and "
            f"no earlier version is stored whole: hint: move {self.root} away and start the "
            "node with --script to seed a new store"
        )


def _state_event(state: Committed, version: int | None) -> dict[str, Any]:
    """The history line of a state change (`version`: the one rolled back, if not the new)."""
    d = state.to_json()
    # The fields every event has first (`_append` puts the time before them), as people read.
    event = {k: d.pop(k) for k in ("event", "version", "hash", "reason")} | d
    if version is not None and version != state.version:
        event["rolled_back"] = version
    return event


def _last_state(events: list[dict[str, Any]]) -> Committed | None:
    """The last state the history records whole."""
    for event in reversed(events):
        try:
            return Committed.from_json(event)
        except ValueError:
            continue
    return None


def _same(a: Committed | None, b: Committed) -> bool:
    return a is not None and (a.version, a.hash, a.time, a.event) == (
        b.version, b.hash, b.time, b.event,
    )  # fmt: skip


__all__ = [
    "MAX_RELEASE_BYTES",
    "STATE_EVENTS",
    "STORE_FORMAT",
    "Committed",
    "StoreError",
    "VersionStore",
    "sha256_hex",
    "utc_stamp",
]
