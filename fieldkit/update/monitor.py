"""Run the update pipeline each time the script, or a file it includes, is saved.

A save is a file that was written and closed, or a file renamed into place, as editors
do (write a temporary file, then rename it over the script). Only those events count:
never a file created or modified, since a file being written is only complete once it is
closed (or renamed), and compiling it earlier would compile half a script. The events of
one save (and of a burst of saves, an editor saving several files at once) are coalesced
into one run: a run starts once no save has come for `DEBOUNCE_S`.

The decisions are sans-I/O (`is_save`, `SaveDebouncer`: events and times in, "run now"
out), tested without a file system. `Monitor` feeds them from a watchdog observer (inotify
on Linux) watching the directories of the watched files, and rebuilds the watch list after
every save, before it runs the pipeline, since the includes may have changed.
"""

from __future__ import annotations

import os
import queue
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import NamedTuple

from watchdog.events import FileSystemEvent, FileSystemEventHandler
from watchdog.observers import Observer
from watchdog.observers.api import BaseObserver, ObservedWatch

from bvm.lexer import included_files

#: Saves closer together than this (seconds) make one run: an editor's several events, or
#: a save of the script and an include together.
DEBOUNCE_S = 0.2


class FsEvent(NamedTuple):
    """One file-system event: watchdog's kind (`moved`, `closed`, `closed_no_write`,
    `created`, `modified`, `deleted`, `opened`), its path, and the new path of a move."""

    kind: str
    src: str
    dest: str = ""


def watch_key(path: str | Path) -> str:
    """How a watched file is named in events: its absolute path with the directory resolved
    (the observer watches the resolved directory; the name itself may be a symlink)."""
    full = os.path.abspath(path)
    return os.path.join(os.path.realpath(os.path.dirname(full)), os.path.basename(full))


def is_save(event: FsEvent, watched: Iterable[str]) -> bool:
    """Whether `event` completes a save of a watched file: written and closed in place, or
    renamed onto it. A file created, modified, opened or closed unwritten is not saved."""
    if event.kind == "moved":
        return event.dest in watched
    if event.kind == "closed":
        return event.src in watched
    return False


class SaveDebouncer:
    """The monitor's decisions: which events are saves, and when a burst of them is over.

    Feed it events with the time they arrived; `due(now)` is True once per burst, when the
    last save of it is `window_s` old. Time is whatever the caller's clock says."""

    def __init__(self, watched: Iterable[str], window_s: float = DEBOUNCE_S) -> None:
        """Watch the files named `watched` (as `watch_key` names them)."""
        self.watched = frozenset(watched)
        self.window_s = window_s
        self._deadline: float | None = None

    def watch(self, watched: Iterable[str]) -> None:
        """Watch these files from now on (a pending run stays pending)."""
        self.watched = frozenset(watched)

    def feed(self, event: FsEvent, now: float) -> bool:
        """Take one event; True if it is a save (a run is then due `window_s` after it)."""
        if not is_save(event, self.watched):
            return False
        self._deadline = now + self.window_s
        return True

    @property
    def deadline(self) -> float | None:
        """When the pending run is due, None if no save is pending."""
        return self._deadline

    def due(self, now: float) -> bool:
        """Whether to run now: a save is pending and none came for `window_s`. True once."""
        if self._deadline is None or now < self._deadline:
            return False
        self._deadline = None
        return True


def watch_list(script: Path, include_dirs: Sequence[str | Path] = ()) -> list[Path]:
    """The files a change of which changes the program: the script and every file it
    includes, as the compiler finds them (the script alone if it cannot be read)."""
    try:
        source = script.read_bytes()
    except OSError:
        return [script]
    files = included_files(source, str(script), [str(d) for d in include_dirs])
    return [Path(f) for f in dict.fromkeys(files)]


class _Forward(FileSystemEventHandler):
    """Watchdog's events, as FsEvents, onto the monitor's queue (from the observer thread)."""

    def __init__(self, out: queue.SimpleQueue[FsEvent | None]) -> None:
        self.out = out

    def on_any_event(self, event: FileSystemEvent) -> None:
        """Forward a file's event; a directory's never saves a script."""
        if not event.is_directory:
            dest = os.fsdecode(event.dest_path) if event.dest_path else ""
            self.out.put(FsEvent(event.event_type, os.fsdecode(event.src_path), dest))


class Monitor:
    """Calls `on_save()` each time the script or one of its includes is saved, until
    `stop()`. The call runs in the thread that called `run()`; saves made while it runs
    make one more run after it. `watched` is the watch list of the last run."""

    def __init__(
        self,
        script: Path,
        include_dirs: Sequence[str | Path] = (),
        *,
        on_save: Callable[[], None],
        window_s: float = DEBOUNCE_S,
    ) -> None:
        """Watch `script` (compiled with `include_dirs`); `on_save` is the pipeline."""
        self.script = script
        self.include_dirs = tuple(include_dirs)
        self.on_save = on_save
        self.window_s = window_s
        # SimpleQueue: `stop()` may be called from a signal handler (its put is reentrant).
        self._events: queue.SimpleQueue[FsEvent | None] = queue.SimpleQueue()
        self._observer: BaseObserver = Observer()
        self._handler = _Forward(self._events)
        self._watches: dict[str, ObservedWatch] = {}
        self.watched: list[Path] = []
        self._core = SaveDebouncer((), window_s)
        self.runs = 0

    def stop(self) -> None:
        """End `run()` (after the run under way, if any); safe from a signal handler."""
        self._events.put(None)

    def run(self, *, first: bool = False) -> None:
        """Watch and run until `stop()`; `first`: run once at once, the watch already set
        (a save made during that run is not missed)."""
        self._rewatch()
        self._observer.start()
        try:
            if first:
                self._run()
            while True:
                deadline = self._core.deadline
                wait = None if deadline is None else max(0.0, deadline - time.monotonic())
                try:
                    event = self._events.get(timeout=wait)
                except queue.Empty:
                    event = FsEvent("timeout", "")
                if event is None:
                    return
                now = time.monotonic()
                self._core.feed(event, now)
                if self._core.due(now):
                    self._run()
        finally:
            self._observer.stop()
            self._observer.join()

    def _run(self) -> None:
        # The watch list first: the run reads the files as they are now, and a save made
        # while it runs (of a newly included file too) makes one more run after it.
        self._rewatch()
        self.runs += 1
        self.on_save()

    def _rewatch(self) -> None:
        """Watch the script and its includes as they are now: new directories are watched
        before old ones are dropped, so no save falls between the two."""
        self.watched = watch_list(self.script, self.include_dirs)
        keys = [watch_key(p) for p in self.watched]
        self._core.watch(keys)
        dirs = {os.path.dirname(k) for k in keys}
        for d in sorted(dirs - self._watches.keys()):
            try:
                self._watches[d] = self._observer.schedule(self._handler, d, recursive=False)
            except OSError:
                continue  # gone since it was read: a later save of the script rewatches
        for d in sorted(self._watches.keys() - dirs):
            self._observer.unschedule(self._watches.pop(d))


__all__ = [
    "DEBOUNCE_S",
    "FsEvent",
    "Monitor",
    "SaveDebouncer",
    "is_save",
    "watch_key",
    "watch_list",
]
