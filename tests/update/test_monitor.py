"""The save monitor: which events are saves (sans-I/O), and a real watchdog observer."""

from __future__ import annotations

import os
import queue
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from fieldkit.update.monitor import (
    FsEvent,
    Monitor,
    SaveDebouncer,
    is_save,
    watch_key,
    watch_list,
)

#: Hang guard: how long a test waits for a run that must come (never a pace).
HANG_S = 60.0

S = "/w/s.bzz"
LIB = "/w/lib.bzz"

# What watchdog reports for an editor's save: a temporary file written, then renamed over.
EDITOR_SAVE = [
    FsEvent("created", "/w/.s.bzz.swp"),
    FsEvent("opened", "/w/.s.bzz.swp"),
    FsEvent("modified", "/w/.s.bzz.swp"),
    FsEvent("closed", "/w/.s.bzz.swp"),
    FsEvent("moved", "/w/.s.bzz.swp", S),
]
# ... and for a write in place: opened, modified (maybe many times), closed.
IN_PLACE = [FsEvent("opened", S), FsEvent("modified", S), FsEvent("modified", S)]
CLOSED = FsEvent("closed", S)


def runs(core: SaveDebouncer, timed: list[tuple[float, FsEvent]], end: float) -> list[float]:
    """Feed events at their times; the times at which a run is due (checked at each event
    and at `end`), as the monitor's loop checks them."""
    out = []
    for now, event in timed:
        if core.due(now):
            out.append(now)
        core.feed(event, now)
    if core.due(end):
        out.append(end)
    return out


def test_an_editor_save_is_one_save_and_a_run_after_the_window() -> None:
    core = SaveDebouncer([S], window_s=0.2)
    assert [core.feed(e, 1.0) for e in EDITOR_SAVE] == [False] * 4 + [True]
    assert core.deadline == pytest.approx(1.2)
    assert not core.due(1.1)
    assert core.due(1.2)
    assert not core.due(5.0)  # once


def test_a_file_being_written_is_never_a_save_until_closed() -> None:
    core = SaveDebouncer([S], window_s=0.0)
    for e in IN_PLACE:
        core.feed(e, 1.0)
    assert core.deadline is None and not core.due(100.0)
    assert core.feed(CLOSED, 2.0) and core.due(2.0)


@pytest.mark.parametrize(
    "event",
    [
        FsEvent("created", S),
        FsEvent("modified", S),
        FsEvent("opened", S),
        FsEvent("closed_no_write", S),  # read by the compiler, say: not a change
        FsEvent("deleted", S),
        FsEvent("moved", S, "/w/s.bzz~"),  # moved away (an editor's backup): not saved yet
        FsEvent("closed", "/w/other.bzz"),  # not watched
        FsEvent("moved", "/w/a", "/w/other.bzz"),
    ],
)
def test_events_that_are_not_saves(event: FsEvent) -> None:
    assert not is_save(event, {S, LIB})


def test_saves_within_the_window_are_one_run_and_later_ones_another() -> None:
    core = SaveDebouncer([S, LIB], window_s=0.5)
    lib_save = FsEvent("moved", "/w/tmp", LIB)
    timed = [(1.0, EDITOR_SAVE[-1]), (1.3, lib_save), (1.6, CLOSED), (3.0, CLOSED)]
    # 1.0, 1.3, 1.6 coalesce (each within 0.5 s of the last): one run at 2.1; then 3.0.
    assert runs(core, timed, end=10.0) == [3.0, 10.0]
    assert runs(SaveDebouncer([S], 0.5), [(1.0, CLOSED), (1.4, CLOSED)], end=1.8) == []
    assert runs(SaveDebouncer([S], 0.5), [(1.0, CLOSED), (1.4, CLOSED)], end=1.9) == [1.9]


def test_the_watch_list_can_change_and_a_pending_run_stays() -> None:
    core = SaveDebouncer([S], window_s=0.0)
    core.feed(CLOSED, 1.0)
    core.watch([LIB])
    assert not core.feed(CLOSED, 1.5)  # no longer watched
    assert core.due(2.0)  # the save before the change still runs
    assert core.feed(FsEvent("closed", LIB), 3.0)


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_the_watch_list_is_the_script_and_what_it_includes(tmp_path: Path) -> None:
    script = write(tmp_path / "s.bzz", 'include "a.bzz"\n# include "ignored.bzz"\nx = 1\n')
    a = write(tmp_path / "lib" / "a.bzz", 'include "b.bzz"\ninclude "a.bzz"\n')
    b = write(tmp_path / "lib" / "b.bzz", "y = 2\n")
    listed = watch_list(script, [tmp_path / "lib"])
    assert [watch_key(p) for p in listed] == [watch_key(p) for p in (script, a, b)]


def test_a_broken_include_chain_still_watches_what_was_read(tmp_path: Path) -> None:
    script = write(tmp_path / "s.bzz", 'include "a.bzz"\ninclude "missing.bzz"\n')
    a = write(tmp_path / "a.bzz", "x = $\n")  # a lexical error: a is still watched
    assert [watch_key(p) for p in watch_list(script)] == [watch_key(p) for p in (script, a)]
    a.write_text("x = 1\n")  # now the missing include stops the list
    assert [watch_key(p) for p in watch_list(script)] == [watch_key(p) for p in (script, a)]
    gone = tmp_path / "gone.bzz"
    assert watch_list(gone) == [gone]


# ------------------------------------------------------------------ a real observer


class Watching:
    """A Monitor running in a thread; each run records the script's and the include's text.

    Exactly one run per save, without timing: the coalescing window is 0, so a run comes
    for every save event, in the order of the events; `finish()` saves the script one last
    time and waits for that run, so every earlier event has had its run by then, and the
    runs recorded are all the runs the saves made."""

    def __init__(self, script: Path, lib: Path) -> None:
        self.script = script
        self.lib = lib
        self.history: list[tuple[str, str]] = []
        self.seen: queue.Queue[tuple[str, str]] = queue.Queue()
        self.monitor = Monitor(script, [], on_save=self._record, window_s=0.0)
        self.thread = threading.Thread(target=self.monitor.run, kwargs={"first": True})

    def _record(self) -> None:
        texts = (self.script.read_text(), self.lib.read_text())
        self.history.append(texts)
        self.seen.put(texts)

    def next_run(self) -> tuple[str, str]:
        """The next run's view of the files (fails if none comes within the hang guard)."""
        return self.seen.get(timeout=HANG_S)

    def finish(self) -> list[tuple[str, str]]:
        """One last save, its run, stop: every run the earlier saves made, in order."""
        last = self.script.read_text() + "# last\n"
        editor_save(self.script, last)
        while self.next_run()[0] != last:
            pass
        self.stop()
        return self.history[:-1]

    def stop(self) -> None:
        self.monitor.stop()
        self.thread.join(HANG_S)
        assert not self.thread.is_alive()


@pytest.fixture
def watching(tmp_path: Path) -> Iterator[Watching]:
    script = write(tmp_path / "s.bzz", 'include "lib.bzz"\n# v0\n')
    lib = write(tmp_path / "lib.bzz", "# lib v0\n")
    w = Watching(script, lib)
    w.thread.start()
    assert w.next_run() == ('include "lib.bzz"\n# v0\n', "# lib v0\n")  # watching now
    yield w
    w.stop()


def editor_save(path: Path, text: str) -> None:
    """Save as editors do: a temporary file beside it, written and closed, renamed over."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def test_each_kind_of_save_is_exactly_one_run(watching: Watching) -> None:
    editor_save(watching.script, 'include "lib.bzz"\n# v1\n')
    assert watching.next_run() == ('include "lib.bzz"\n# v1\n', "# lib v0\n")
    watching.script.write_text('include "lib.bzz"\n# v2\n')  # in place
    assert watching.next_run() == ('include "lib.bzz"\n# v2\n', "# lib v0\n")
    editor_save(watching.lib, "# lib v1\n")  # an included file
    assert watching.next_run() == ('include "lib.bzz"\n# v2\n', "# lib v1\n")
    assert watching.finish() == [
        ('include "lib.bzz"\n# v0\n', "# lib v0\n"),  # the first run, as the watch starts
        ('include "lib.bzz"\n# v1\n', "# lib v0\n"),
        ('include "lib.bzz"\n# v2\n', "# lib v0\n"),
        ('include "lib.bzz"\n# v2\n', "# lib v1\n"),
    ]


def test_a_half_written_file_does_not_run(watching: Watching) -> None:
    with watching.script.open("w") as f:
        f.write('include "lib.bzz"\n# half')
        f.flush()  # on disk, modified, still open
        editor_save(watching.lib, "# lib v1\n")  # a save of another file while it is open
        assert watching.next_run() == ('include "lib.bzz"\n# half', "# lib v1\n")
        f.write(" and the rest\n")
        f.flush()
    assert watching.next_run() == ('include "lib.bzz"\n# half and the rest\n', "# lib v1\n")
    assert len(watching.finish()) == 3  # the first run, the lib's save, the close


def test_the_watch_list_follows_the_includes(watching: Watching, tmp_path: Path) -> None:
    other = write(tmp_path / "sub" / "other.bzz", "# other v0\n")
    editor_save(watching.script, 'include "sub/other.bzz"\n')
    watching.next_run()
    watched = {watch_key(p) for p in watching.monitor.watched}
    assert watch_key(other) in watched and watch_key(watching.lib) not in watched
    editor_save(watching.lib, "# lib v1, not included any more\n")  # no run
    editor_save(other, "# other v1\n")  # in a directory watched since the last run
    assert watching.next_run() == ('include "sub/other.bzz"\n', "# lib v1, not included any more\n")
    assert len(watching.finish()) == 3  # the first run, the script's save, the other's
