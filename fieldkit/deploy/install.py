"""Installing files so that none is ever half-written, and removing exactly them again.

Every file is staged and renamed: written to a temporary file beside its target, with its
final mode (and owner) set before a byte is written, synced, then renamed over the target
(`os.replace`), and the directory synced. A reader, a crash or a power cut sees the old file
or the new one, never a mix, and a key is never readable by others, even for an instant. A
file whose bytes, mode and owner are already right is not touched: deploying twice changes
nothing, not even a modification time.

The manifest (/etc/fieldkit/deploy-manifest.json) names every file, symlink and directory
deploy created, each file with its SHA-256. It is written before any change (listing the
new files and the old ones, each with the hashes it may have while the change is under way)
and again after (the new ones only), so whatever instant a deploy is killed at, the manifest
covers every file on disk, and running deploy again finishes the job. `--uninstall` removes
what the manifest names and nothing else; a file whose bytes changed since (a user's edit)
is kept, and said so.

A lock (flock on /etc/fieldkit/.deploy.lock) keeps two deploys from running at once: the
second fails at once, naming the first one's pid.
"""

from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import os
import shutil
import signal
import stat
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from fieldkit.deploy import DeployError, layout

#: Testing only: `N` SIGKILLs this process right after its Nth change to the file system (a
#: write, rename, mkdir, chmod, chown, symlink or removal), to test that deploy repairs
#: whatever a kill at that instant leaves; `N:STOP` stops it there instead (SIGSTOP), to
#: test what another deploy meets meanwhile.
CRASH_ENV = "FIELDKIT_DEPLOY_CRASH_AFTER"

MANIFEST_FORMAT = "fieldkit-deploy-manifest/1"

#: Where a file deploy installed, then someone changed, is saved before deploy replaces it.
SAVED_SUFFIX = ".fieldkit-old"

Owners = Callable[[str], tuple[int, int]]
"""A user name to (uid, gid): how a live install gives files to the fieldkit user."""


@dataclass(frozen=True)
class Dir:
    """A directory deploy makes (and whose mode, and owner, it keeps right)."""

    path: PurePosixPath
    mode: int
    owner: str | None = None  # a user (and its group); None: whoever runs deploy


@dataclass(frozen=True)
class File:
    """A file deploy installs."""

    path: PurePosixPath
    data: bytes = field(repr=False)  # a key's bytes: never in a repr or a traceback
    mode: int
    owner: str | None = None
    #: A secret's description (`64 hex digits`): what --dry-run shows instead of its bytes.
    secret: str | None = None

    @property
    def sha256(self) -> str:
        """The hex SHA-256 of its bytes."""
        return _sha256(self.data)

    @property
    def is_text(self) -> bool:
        """Whether it is text (printed whole by --dry-run) rather than bytes."""
        if b"\0" in self.data:
            return False
        try:
            self.data.decode("utf-8")
        except UnicodeDecodeError:
            return False
        return True


@dataclass(frozen=True)
class Symlink:
    """A symbolic link deploy makes (`systemctl enable`'s, for an image staged with --root)."""

    path: PurePosixPath
    target: str


Entry = Dir | File | Symlink
"""One thing deploy installs."""


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


# --------------------------------------------------------------------------- the manifest


@dataclass
class Manifest:
    """What deploy installed: files (mode, the hashes they may have), symlinks, directories."""

    files: dict[str, tuple[int, tuple[str, ...]]] = field(default_factory=dict)
    links: dict[str, str] = field(default_factory=dict)
    dirs: dict[str, int] = field(default_factory=dict)

    def to_bytes(self) -> bytes:
        """The manifest's file: stable JSON (sorted, no time stamps), so it changes only
        when what it lists changes."""
        doc = {
            "format": MANIFEST_FORMAT,
            "about": "what `fieldkit deploy` installed; `fieldkit deploy --uninstall` "
            "removes these",
            "files": {
                p: {"mode": f"{mode:04o}", "sha256": list(hashes)}
                for p, (mode, hashes) in sorted(self.files.items())
            },
            "symlinks": dict(sorted(self.links.items())),
            "dirs": {p: f"{mode:04o}" for p, mode in sorted(self.dirs.items())},
        }
        return (json.dumps(doc, indent=2, sort_keys=True) + "\n").encode()

    @classmethod
    def from_bytes(cls, data: bytes, where: Path) -> Manifest:
        """Read a manifest; DeployError (naming `where`) if it is not one."""
        try:
            doc = json.loads(data)
            if doc.get("format") != MANIFEST_FORMAT:
                raise ValueError(f"format {doc.get('format')!r}, not {MANIFEST_FORMAT!r}")
            files = {
                str(p): (int(r["mode"], 8), tuple(str(h) for h in r["sha256"]))
                for p, r in doc["files"].items()
            }
            links = {str(p): str(t) for p, t in doc["symlinks"].items()}
            dirs = {str(p): int(m, 8) for p, m in doc["dirs"].items()}
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            raise DeployError(
                f"{where}: not a fieldkit deploy manifest ({e})\nhint: it lists what deploy "
                "installed; restore it, or remove fieldkit's files by hand"
            ) from None
        return cls(files, links, dirs)


# --------------------------------------------------------------------------- the installer


@dataclass
class Changes:
    """What one deploy or uninstall did, as paths on this machine."""

    written: list[Path] = field(default_factory=list)  # new or changed files
    fixed: list[Path] = field(default_factory=list)  # a mode or owner put right
    made: list[Path] = field(default_factory=list)  # directories and symlinks made
    removed: list[Path] = field(default_factory=list)
    kept: list[str] = field(default_factory=list)  # deploy's files kept, and why
    left: list[Path] = field(default_factory=list)  # state and recordings left (no --purge)
    unchanged: int = 0

    @property
    def changed(self) -> bool:
        """Whether anything on disk changed."""
        return bool(self.written or self.fixed or self.made or self.removed)


class Installer:
    """Installs entries under `root` (the robot's / or a staging directory)."""

    def __init__(
        self, root: Path, *, owners: Owners | None = None, warn: Callable[[str], None]
    ) -> None:
        """`owners` resolves the fieldkit user (a live install; None under --root, where
        files keep the owner of whoever runs deploy); `warn` takes warnings."""
        self.root = root
        self.owners = owners
        self.warn = warn
        self._steps = 0
        after, _, how = os.environ.get(CRASH_ENV, "").partition(":")
        self._crash_after = int(after) if after.isdigit() else 0
        self._crash_signal = signal.SIGSTOP if how == "STOP" else signal.SIGKILL

    def path(self, target: PurePosixPath | str) -> Path:
        """Where the robot's `target` is here."""
        return layout.under(self.root, PurePosixPath(target))

    def _step(self) -> None:
        """One change to the file system made (the crash test's hook)."""
        self._steps += 1
        if self._steps == self._crash_after:
            os.kill(os.getpid(), self._crash_signal)

    # ------------------------------------------------------------------ reading

    def manifest(self) -> Manifest | None:
        """The manifest of the last deploy, or None."""
        where = self.path(layout.MANIFEST)
        try:
            data = where.read_bytes()
        except FileNotFoundError:
            return None
        except OSError as e:
            raise DeployError(f"{where}: cannot read: {e.strerror or e}") from None
        return Manifest.from_bytes(data, where)

    def status(self, entry: Entry, manifest: Manifest | None) -> str:
        """`new`, `changed` or `unchanged` (bytes, mode and link target; not owners)."""
        where = self.path(entry.path)
        if isinstance(entry, Symlink):
            if not where.is_symlink():
                return "new"
            return "unchanged" if os.readlink(where) == entry.target else "changed"
        try:
            st = where.lstat()
        except FileNotFoundError:
            return "new"
        if isinstance(entry, Dir):
            return "unchanged" if stat.S_IMODE(st.st_mode) == entry.mode else "changed"
        if not stat.S_ISREG(st.st_mode):
            return "changed"
        same = stat.S_IMODE(st.st_mode) == entry.mode and where.read_bytes() == entry.data
        return "unchanged" if same else "changed"

    def conflicts(self, entries: Sequence[Entry], manifest: Manifest | None) -> list[str]:
        """Why these entries cannot be installed: a file in the way that deploy did not
        install (never overwritten), a file where a directory goes, or the reverse."""
        problems = []
        known = manifest or Manifest()
        for entry in entries:
            where = self.path(entry.path)
            try:
                st = where.lstat()
            except FileNotFoundError:
                continue
            except OSError as e:
                problems.append(f"{where}: cannot read: {e.strerror or e}")
                continue
            key = str(entry.path)
            if isinstance(entry, Dir):
                if not stat.S_ISDIR(st.st_mode):
                    problems.append(f"{where}: is not a directory, where deploy makes one")
            elif isinstance(entry, Symlink):
                if not (stat.S_ISLNK(st.st_mode) and os.readlink(where) == entry.target):
                    if key not in known.links:
                        problems.append(f"{where}: exists, and fieldkit deploy did not make it")
            elif not stat.S_ISREG(st.st_mode):
                problems.append(f"{where}: is not a regular file, where deploy installs one")
            elif key not in known.files and where.read_bytes() != entry.data:
                problems.append(
                    f"{where}: exists, and fieldkit deploy did not install it (it never "
                    "overwrites such a file)"
                )
        return problems

    # ------------------------------------------------------------------ the lock

    @contextmanager
    def locked(self) -> Iterator[list[PurePosixPath]]:
        """Hold the deploy lock (the directories made for it are yielded, for the manifest);
        DeployError at once if another deploy holds it."""
        made = self._parents(layout.LOCK)
        where = self.path(layout.LOCK)
        while True:
            try:
                fd = os.open(where, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600)
            except OSError as e:
                raise DeployError(f"{where}: cannot open the lock: {e.strerror or e}") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                pid = lock_holder(os.fstat(fd).st_ino)
                os.close(fd)
                raise DeployError(
                    f"another fieldkit deploy is running (pid {pid if pid else 'unknown'})\n"
                    f"hint: wait for it to finish (it holds {where})"
                ) from None
            # An uninstall that just ended removed the file we locked: lock the new one.
            held = os.fstat(fd)
            try:
                now = os.stat(where)
            except FileNotFoundError:
                now = None
            if now is not None and (now.st_dev, now.st_ino) == (held.st_dev, held.st_ino):
                break
            os.close(fd)
        try:
            yield made
        finally:
            os.close(fd)

    # ------------------------------------------------------------------ installing

    def install(
        self, entries: Sequence[Entry], old: Manifest | None, made: Sequence[PurePosixPath]
    ) -> Changes:
        """Install `entries` (under the lock), replacing the install `old` describes: files
        of `old` that are not in `entries` are removed. `made`: directories already made
        for this install (the lock's)."""
        old = old or Manifest()
        changes = Changes()
        files = [e for e in entries if isinstance(e, File)]
        links = [e for e in entries if isinstance(e, Symlink)]
        dirs = sorted((e for e in entries if isinstance(e, Dir)), key=lambda d: len(d.path.parts))
        missing = ({str(p) for p in made} | self._missing_dirs(entries)) - set(_LOCK_PARENTS)
        # Before any change: a manifest that covers the old install, the new one and every
        # directory this one makes, each file with the hashes it may have meanwhile.
        intent = Manifest(
            files={p: (mode, hashes) for p, (mode, hashes) in old.files.items()},
            links=dict(old.links),
            dirs={**old.dirs, **{p: 0o755 for p in missing}, **{str(d.path): d.mode for d in dirs}},
        )
        for f in files:
            before = old.files.get(str(f.path), (f.mode, ()))[1]
            intent.files[str(f.path)] = (f.mode, tuple(dict.fromkeys((*before, f.sha256))))
        for link in links:
            intent.links[str(link.path)] = link.target
        self._clear_temporaries(files)
        self._write_manifest(intent)
        for d in dirs:
            self._dir(d, changes)
        for f in files:
            self._file(f, intent.files[str(f.path)][1], changes)
        for link in links:
            self._symlink(link, changes)
        # The old install's leftovers: files, links, then directories no longer wanted.
        wanted = {str(e.path) for e in entries}
        for p, (_, hashes) in sorted(old.files.items(), reverse=True):
            if p not in wanted:
                self._remove_file(p, hashes, changes)
        for p, target in sorted(old.links.items(), reverse=True):
            if p not in wanted:
                self._remove_link(p, target, changes)
        final_dirs = {**{p: m for p, m in intent.dirs.items() if p in wanted or p in missing}}
        for p in sorted(set(old.dirs) - set(final_dirs), key=_depth, reverse=True):
            if not self._needed(p, wanted):
                self._remove_dir(p, changes, quiet=True)
            else:
                final_dirs[p] = old.dirs[p]
        final = Manifest(
            files={str(f.path): (f.mode, (f.sha256,)) for f in files},
            links={str(link.path): link.target for link in links},
            dirs=final_dirs,
        )
        self._write_manifest(final)
        return changes

    def _missing_dirs(self, entries: Sequence[Entry]) -> set[str]:
        """The directories (of entries, and every parent) that do not exist yet."""
        missing = set()
        for entry in entries:
            chain = [entry.path] if isinstance(entry, Dir) else []
            chain += list(entry.path.parents)[:-1]  # up to, not including, /
            for d in chain:
                if not self.path(d).is_dir():
                    missing.add(str(d))
        return missing

    def _needed(self, directory: str, wanted: set[str]) -> bool:
        """Whether a path of this install lies under `directory`."""
        return any(PurePosixPath(p).is_relative_to(directory) for p in wanted)

    def _parents(self, target: PurePosixPath) -> list[PurePosixPath]:
        """Make the missing parents of `target` (0755); those it made."""
        made = []
        for d in reversed(list(target.parents)[:-1]):
            where = self.path(d)
            if where.is_dir():
                continue
            try:
                where.mkdir(mode=0o755)
            except FileExistsError:
                if not where.is_dir():
                    raise DeployError(f"{where}: is not a directory") from None
                continue
            except OSError as e:
                raise DeployError(f"{where}: cannot create: {e.strerror or e}") from None
            os.chmod(where, 0o755)  # whatever the umask
            self._step()
            made.append(d)
        return made

    def _owner(self, owner: str | None) -> tuple[int, int] | None:
        """The (uid, gid) a live install gives an entry, or None to leave it."""
        if owner is None or self.owners is None:
            return None
        return self.owners(owner)

    def _dir(self, d: Dir, changes: Changes) -> None:
        where = self.path(d.path)
        self._parents(d.path)
        if not where.is_dir():
            where.mkdir(mode=d.mode)
            self._step()
            changes.made.append(where)
        self._fix(where, d.mode, self._owner(d.owner), changes, new=where in changes.made)

    def _fix(
        self, where: Path, mode: int, ids: tuple[int, int] | None, changes: Changes, new: bool
    ) -> None:
        """Put the mode and owner of `where` right."""
        st = where.lstat()
        fixed = False
        if ids is not None and (st.st_uid, st.st_gid) != ids:
            os.chown(where, *ids, follow_symlinks=False)
            self._step()
            fixed = True
        if stat.S_IMODE(st.st_mode) != mode:
            os.chmod(where, mode)
            self._step()
            fixed = True
        if fixed and not new:
            changes.fixed.append(where)

    def _file(self, f: File, ours: tuple[str, ...], changes: Changes) -> None:
        where = self.path(f.path)
        self._parents(f.path)
        ids = self._owner(f.owner)
        try:
            current: bytes | None = where.read_bytes()
        except FileNotFoundError:
            current = None
        if current == f.data:
            before = len(changes.fixed)
            self._fix(where, f.mode, ids, changes, new=False)
            changes.unchanged += len(changes.fixed) == before
            return
        if current is not None and _sha256(current) not in ours:
            # Someone changed what deploy installed: keep their version beside the new one.
            saved = where.with_name(where.name + SAVED_SUFFIX)
            self._write(saved, current, stat.S_IMODE(where.stat().st_mode), None)
            self.warn(
                f"{where} was changed since fieldkit deploy installed it: replaced, "
                f"the changed version saved as {saved}"
            )
        self._write(where, f.data, f.mode, ids)
        changes.written.append(where)

    def _write(self, where: Path, data: bytes, mode: int, ids: tuple[int, int] | None) -> None:
        """Stage `data` beside `where` with its final mode and owner, sync, rename."""
        tmp = _temporary(where)
        tmp.unlink(missing_ok=True)
        fd = os.open(
            tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC | os.O_NOFOLLOW, 0o600
        )
        try:
            if ids is not None:
                os.fchown(fd, *ids)
            os.fchmod(fd, mode)
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view) :]
            os.fsync(fd)
        finally:
            os.close(fd)
        self._step()
        os.replace(tmp, where)
        _sync_dir(where.parent)
        self._step()

    def _symlink(self, link: Symlink, changes: Changes) -> None:
        where = self.path(link.path)
        self._parents(link.path)
        if where.is_symlink() and os.readlink(where) == link.target:
            changes.unchanged += 1
            return
        tmp = _temporary(where)
        tmp.unlink(missing_ok=True)
        os.symlink(link.target, tmp)
        self._step()
        os.replace(tmp, where)
        _sync_dir(where.parent)
        self._step()
        changes.made.append(where)

    def _clear_temporaries(self, files: Sequence[File]) -> None:
        """Remove what a killed deploy left staged (a rename never done)."""
        for f in files:
            tmp = _temporary(self.path(f.path))
            if tmp.is_file() or tmp.is_symlink():
                tmp.unlink()
                self._step()

    def _write_manifest(self, manifest: Manifest) -> None:
        where = self.path(layout.MANIFEST)
        data = manifest.to_bytes()
        try:
            if where.read_bytes() == data:
                return
        except FileNotFoundError:
            pass
        self._parents(layout.MANIFEST)
        self._write(where, data, 0o644, None)

    # ------------------------------------------------------------------ removing

    def _remove_file(self, target: str, hashes: Sequence[str], changes: Changes) -> None:
        where = self.path(target)
        try:
            data = where.read_bytes()
        except FileNotFoundError:
            return
        except IsADirectoryError:
            changes.kept.append(f"{where}: a directory now, not the file deploy installed")
            return
        if _sha256(data) not in hashes:
            changes.kept.append(f"{where}: changed since fieldkit deploy installed it")
            return
        where.unlink()
        self._step()
        changes.removed.append(where)

    def _remove_link(self, target: str, points_to: str, changes: Changes) -> None:
        where = self.path(target)
        if not where.is_symlink():
            return
        if os.readlink(where) != points_to:
            changes.kept.append(f"{where}: points elsewhere than deploy made it point")
            return
        where.unlink()
        self._step()
        changes.removed.append(where)

    def _remove_dir(self, target: str, changes: Changes, quiet: bool = False) -> None:
        where = self.path(target)
        try:
            where.rmdir()
        except FileNotFoundError:
            return
        except OSError as e:
            if e.errno in (errno.ENOTEMPTY, errno.EEXIST):
                if not quiet:
                    changes.kept.append(f"{where}: not empty (files deploy did not install)")
                return
            if quiet:  # a parent made for a staging root: never worth failing over
                return
            raise
        self._step()
        changes.removed.append(where)

    def uninstall(self, manifest: Manifest | None, purge: bool) -> Changes:
        """Remove what `manifest` names (under the lock): every file still as deploy wrote
        it, its symlinks, and its directories once empty, except /var/lib/fieldkit and
        /var/log/fieldkit (state, recordings) unless `purge`, which removes them whole.
        Without a manifest (a finished uninstall, or one killed at its very end), only what
        such a kill can leave: the lock and /etc/fieldkit, if that is all it holds."""
        changes = Changes()
        manifest = manifest or Manifest()
        for p, (_, hashes) in sorted(manifest.files.items(), reverse=True):
            if p != str(layout.LOCK):
                self._remove_file(p, hashes, changes)
        for p, target in sorted(manifest.links.items(), reverse=True):
            self._remove_link(p, target, changes)
        if purge:
            self.purge(changes)
        kept_dirs = [] if purge else [str(d) for d in layout.KEPT_DIRS]
        last = [str(layout.ETC_DIR), *_LOCK_PARENTS]
        for p in sorted(manifest.dirs, key=_depth, reverse=True):
            if p in last:
                continue  # it holds the manifest: after it
            if any(PurePosixPath(k).is_relative_to(p) for k in kept_dirs) and p not in kept_dirs:
                continue  # a parent of a kept directory: it stays with it
            if p in kept_dirs:
                if self.path(p).is_dir():
                    changes.left.append(self.path(p))
                continue
            self._remove_dir(p, changes, quiet=not _is_own(p))
        # Last the lock, the manifest (so that a kill before leaves it for the next
        # uninstall), and the directory that held them with the parents made for it.
        lock = self.path(layout.LOCK)
        if lock.is_file() and lock.stat().st_size == 0:
            lock.unlink()
            self._step()
            changes.removed.append(lock)
        where = self.path(layout.MANIFEST)
        if where.is_file():
            where.unlink()
            self._step()
            changes.removed.append(where)
        self._remove_dir(str(layout.ETC_DIR), changes)
        for p in _LOCK_PARENTS:
            # Not listed in the manifest (the lock may have made them before there was
            # one): removed when empty, which the robot's own /etc never is.
            self._remove_dir(p, changes, quiet=True)
        return changes

    def purge(self, changes: Changes) -> None:
        """Remove /var/lib/fieldkit and /var/log/fieldkit whole: state, recordings."""
        for d in layout.KEPT_DIRS:
            where = self.path(d)
            if where.is_dir() and not where.is_symlink():
                shutil.rmtree(where)
                self._step()
                changes.removed.append(where)


#: The parents of /etc/fieldkit (made, if missing, before the lock is held; never listed).
_LOCK_PARENTS = [str(p) for p in list(layout.ETC_DIR.parents)[:-1]]


def _is_own(target: str) -> bool:
    """Whether a directory is fieldkit's own (its contents matter to say), not a parent
    such as /etc/systemd/system that a staging root needed."""
    return "fieldkit" in PurePosixPath(target).name


def _depth(target: str) -> int:
    return len(PurePosixPath(target).parts)


def _temporary(where: Path) -> Path:
    """Where a file is staged: beside it (one file system, so the rename is atomic), under
    one name per file (the lock keeps two deploys apart), hidden."""
    return where.with_name(f".{where.name}.fieldkit-tmp")


def _sync_dir(directory: Path) -> None:
    """Make a rename in `directory` durable."""
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def lock_holder(inode: int, locks: Path = Path("/proc/locks")) -> int | None:
    """The pid holding a flock on the file with this inode (from /proc/locks), or None."""
    try:
        lines = locks.read_text().splitlines()
    except OSError:
        return None
    for line in lines:
        fields = line.split()
        # "1: FLOCK  ADVISORY  WRITE 1234 08:01:5678 0 EOF"; waiters are marked "->".
        if len(fields) < 6 or fields[1] == "->" or fields[1] != "FLOCK":
            continue
        if fields[5].rsplit(":", 1)[-1] == str(inode) and fields[4].isdigit():
            return int(fields[4])
    return None


__all__ = [
    "CRASH_ENV",
    "Changes",
    "Dir",
    "Entry",
    "File",
    "Installer",
    "Manifest",
    "SAVED_SUFFIX",
    "Symlink",
    "lock_holder",
]
