"""The version store: releases by hash, the committed version, rollback, history, recovery."""

from __future__ import annotations

import itertools
import json
from collections.abc import Callable
from pathlib import Path

import pytest

import bvm
from fieldkit.update.release import Release
from fieldkit.update.store import Committed, StoreError, VersionStore

SOURCES = [
    "function init() { x = 0 }\nfunction step() {\n  x = x + 1\n}\n",
    "function init() { x = 10 }\nfunction step() {\n  x = x + 2\n}\n",
    "function init() { x = 20 }\nfunction step() {\n  x = x + 3\n}\n",
    "function init() { x = 30 }\nfunction step() {\n  x = x + 4\n}\n",
]


@pytest.fixture(scope="module")
def releases() -> list[Release]:
    """Four real compiled versions, each with its debug info and source map."""
    return [Release.from_program(bvm.compile_source(s, f"v{i}.bzz")) for i, s in enumerate(SOURCES)]


def ticking() -> Callable[[], float]:
    """A wall clock one second further at every reading (2026-11-26 onward)."""
    counter = itertools.count()
    return lambda: 1795683804.0 + next(counter)


def store_at(root: Path) -> VersionStore:
    return VersionStore(root, clock=ticking())


def committed_at(store: VersionStore, *versions: tuple[int, Release]) -> Committed:
    """`versions` put and committed in order; the last state."""
    state = None
    for version, release in versions:
        state = store.commit(version, store.put(release), reason=f"to {version}")
    assert state is not None
    return state


def events(store: VersionStore) -> list[tuple[str, int | None]]:
    return [(e["event"], e["version"]) for e in store.history()]


# ------------------------------------------------------------------ releases


def test_a_release_is_stored_once_under_its_hash_and_comes_back_whole(
    tmp_path: Path, releases: list[Release]
) -> None:
    store = store_at(tmp_path)
    r = releases[0]
    assert not store.has(r.hash)
    assert store.put(r) == r.hash
    assert store.put(Release(r.bo, r.bdb, r.bpos)) == r.hash  # the same content again
    assert sorted(p.name for p in store.releases.iterdir()) == [
        f"{r.hash}.bdb",
        f"{r.hash}.bo",
        f"{r.hash}.bpos",
    ]
    assert store.has(r.hash)
    assert store.get(r.hash) == r
    assert store.get(r.hash).program().bytecode == r.bo  # it loads


def test_a_release_without_sidecars_is_stored_without_them(tmp_path: Path) -> None:
    store = store_at(tmp_path)
    r = Release(b"\x00\x00\x00\x00")
    store.put(r)
    assert [p.name for p in store.releases.iterdir()] == [f"{r.hash}.bo"]
    assert store.get(r.hash) == r


def test_a_missing_or_corrupt_release_is_an_error(tmp_path: Path, releases: list[Release]) -> None:
    store = store_at(tmp_path)
    r = releases[0]
    with pytest.raises(StoreError, match=r"release [0-9a-f]{12} is not in the store"):
        store.get(r.hash)
    store.put(r)
    bo = store.path(r.hash)
    data = bytearray(bo.read_bytes())
    data[-1] ^= 1
    bo.write_bytes(bytes(data))
    with pytest.raises(StoreError, match=f"{bo}: corrupt: its bytecode hashes to"):
        store.get(r.hash)
    assert not store.has(r.hash)
    # put() mends it: a release that does not verify is not "stored".
    store.put(r)
    assert store.get(r.hash) == r


def test_a_name_that_is_not_a_hash_never_reaches_the_file_system(tmp_path: Path) -> None:
    store = store_at(tmp_path)
    with pytest.raises(StoreError, match="not a version hash"):
        store.get("../../etc/passwd")


# ------------------------------------------------------------------ commit and rollback


def test_commits_survive_a_reopen_with_their_previous_versions(
    tmp_path: Path, releases: list[Release]
) -> None:
    store = store_at(tmp_path)
    assert store.committed() is None
    first = committed_at(store, (0, releases[0]))
    assert (first.event, first.version, first.highest, first.previous) == ("seeded", 0, 0, ())
    assert first.time == "2026-11-26T09:03:24.000Z"
    state = committed_at(store, (1, releases[1]), (2, releases[2]))
    assert (state.version, state.hash, state.highest) == (2, releases[2].hash, 2)
    assert state.previous == ((1, releases[1].hash), (0, releases[0].hash))
    again = store_at(tmp_path)
    assert again.committed() == state
    assert again.notes == []
    assert events(again) == [("seeded", 0), ("committed", 1), ("committed", 2)]
    assert [e["reason"] for e in again.history()] == ["to 0", "to 1", "to 2"]


def test_a_version_number_is_never_reused(tmp_path: Path, releases: list[Release]) -> None:
    store = store_at(tmp_path)
    committed_at(store, (0, releases[0]), (3, releases[1]))
    store.put(releases[2])
    for v in (2, 3):
        with pytest.raises(StoreError, match=f"cannot commit version {v}: version 3 was"):
            store.commit(v, releases[2].hash, reason="")
    assert store.commit(4, releases[2].hash, reason="").version == 4


def test_only_a_stored_release_can_be_committed(tmp_path: Path, releases: list[Release]) -> None:
    store = store_at(tmp_path)
    with pytest.raises(StoreError, match="its release is not stored whole"):
        store.commit(0, releases[0].hash, reason="")
    assert store.committed() is None and store.history() == []


def test_a_rollback_goes_back_to_the_previous_version_and_bars_the_bad_one(
    tmp_path: Path, releases: list[Release]
) -> None:
    store = store_at(tmp_path)
    committed_at(store, (0, releases[0]), (1, releases[1]), (2, releases[2]))
    back = store.rollback(2, reason="barrier timed out")
    assert (back.version, back.hash, back.event) == (1, releases[1].hash, "rolled-back")
    assert back.previous == ((0, releases[0].hash),)
    assert (back.highest, back.bad) == (2, (2,))
    # The floor stays: the next update is version 3, never 2 again.
    with pytest.raises(StoreError, match="cannot commit version 2"):
        store.commit(2, releases[3].hash, reason="")
    last = store.history()[-1]
    assert (last["event"], last["version"], last["rolled_back"]) == ("rolled-back", 1, 2)
    assert last["reason"] == "barrier timed out"
    assert store_at(tmp_path).committed() == back
    # Back once more, then nothing is left to go back to.
    assert store.rollback(1, reason="x", to_hash=releases[0].hash).version == 0
    with pytest.raises(StoreError, match="cannot roll back version 0: no earlier version"):
        store.rollback(0, reason="x")


def test_a_version_never_switched_to_is_only_marked_bad(
    tmp_path: Path, releases: list[Release]
) -> None:
    store = store_at(tmp_path)
    start = committed_at(store, (0, releases[0]), (1, releases[1]))
    state = store.rollback(2, reason="barrier timed out", to_hash=releases[1].hash)
    assert (state.version, state.hash, state.previous) == (1, start.hash, start.previous)
    assert (state.bad, state.highest) == ((2,), 2)
    assert state.reason == "version 2 abandoned: barrier timed out"
    n = len(store.history())
    assert store.rollback(2, reason="again") == state  # the same order twice: no change
    assert len(store.history()) == n


def test_a_rollback_to_another_hash_or_of_an_older_version_writes_nothing(
    tmp_path: Path, releases: list[Release]
) -> None:
    store = store_at(tmp_path)
    state = committed_at(store, (0, releases[0]), (1, releases[1]), (2, releases[2]))
    before = (store.committed_path.read_bytes(), store.history_path.read_bytes())
    with pytest.raises(StoreError, match="cannot roll back version 2 to"):
        store.rollback(2, reason="", to_hash=releases[3].hash)
    with pytest.raises(StoreError, match="this robot runs version 2, a later one"):
        store.rollback(1, reason="")
    with pytest.raises(StoreError, match="runs [0-9a-f]{12} \\(version 2\\)"):
        store.rollback(5, reason="", to_hash=releases[0].hash)
    assert (store.committed_path.read_bytes(), store.history_path.read_bytes()) == before
    assert store.committed() == state


def test_a_rollback_skips_a_previous_version_whose_release_is_gone(
    tmp_path: Path, releases: list[Release]
) -> None:
    store = store_at(tmp_path)
    committed_at(store, (0, releases[0]), (1, releases[1]), (2, releases[2]))
    store.path(releases[1].hash).unlink()
    assert store.rollback(2, reason="").version == 0


# ------------------------------------------------------------------ history and patches


def test_notes_go_to_the_history_and_a_torn_last_line_is_cut_at_open(
    tmp_path: Path, releases: list[Release]
) -> None:
    store = store_at(tmp_path)
    committed_at(store, (0, releases[0]))
    store.note("refused", reason="bad-signature", version=7, hash=None)
    assert store.history()[-1] == {
        "time": "2026-11-26T09:03:26.000Z",
        "event": "refused",
        "version": 7,
        "hash": None,
        "reason": "bad-signature",
    }
    with store.history_path.open("ab") as f:
        f.write(b'{"time": "2026-11-26T09:03:27.000Z", "event": "ref')
    assert events(store) == [("seeded", 0), ("refused", 7)]  # the torn line is skipped
    again = store_at(tmp_path)
    assert again.notes == [f"{again.history_path}: cut a torn last line (50 bytes)"]
    assert again.history_path.read_bytes().endswith(b'"bad-signature"}\n')
    again.note("refused", reason="replayed")
    assert events(again) == [("seeded", 0), ("refused", 7), ("refused", None)]


def test_patches_are_kept_by_version(tmp_path: Path) -> None:
    store = store_at(tmp_path)
    assert store.patches() == []
    store.put_patch(12, b"FKUP twelve")
    store.put_patch(3, b"FKUP three")
    (store.patches_dir / "notes.txt").write_text("not a patch")
    assert store.patches() == [3, 12]
    assert store.patch(12) == b"FKUP twelve"
    with pytest.raises(StoreError, match="no patch kept for version 4"):
        store.patch(4)
    with pytest.raises(StoreError, match="not a version number"):
        store.put_patch(-1, b"")


# ------------------------------------------------------------------ crashes and recovery


def test_temporary_files_and_orphan_sidecars_are_removed_at_open(
    tmp_path: Path, releases: list[Release]
) -> None:
    store = store_at(tmp_path)
    committed_at(store, (0, releases[0]))
    r = releases[1]
    leftovers = [
        tmp_path / ".committed.json.tmp",
        store.releases / f".{r.hash}.bo.tmp",
        store.releases / f"{r.hash}.bdb",  # a put that died before its .bo
        store.patches_dir / ".4.fkup.tmp",
    ]
    for p in leftovers:
        p.write_bytes(b"half")
    again = store_at(tmp_path)
    assert not any(p.exists() for p in leftovers)
    assert again.notes == [f"{tmp_path}: removed 4 file(s) a crash left half-written"]
    assert again.committed() is not None and again.has(releases[0].hash)


def test_a_commit_whose_history_line_was_never_written_is_recorded_at_open(
    tmp_path: Path, releases: list[Release]
) -> None:
    store = store_at(tmp_path)
    state = committed_at(store, (0, releases[0]), (1, releases[1]))
    lines = store.history_path.read_bytes().splitlines(keepends=True)
    store.history_path.write_bytes(b"".join(lines[:-1]))  # died after committed.json
    again = store_at(tmp_path)
    assert again.committed() == state
    last = again.history()[-1]
    assert (last["event"], last["version"], last["late"]) == ("committed", 1, True)
    assert len(store_at(tmp_path).history()) == 2  # recorded once, not at every open


@pytest.mark.parametrize(
    "damage",
    [b"", b'{"format": 1, "version": 1, "ha', b"\xff\xfe", b"[]", b'{"format": 1}'],
    ids=["empty", "torn", "not-utf8", "not-an-object", "fields-missing"],
)
def test_a_corrupt_committed_json_is_rebuilt_from_the_history(
    tmp_path: Path, releases: list[Release], damage: bytes
) -> None:
    store = store_at(tmp_path)
    state = committed_at(store, (0, releases[0]), (1, releases[1]))
    store.committed_path.write_bytes(damage)
    again = store_at(tmp_path)
    got = again.committed()
    assert got is not None
    assert (got.version, got.hash, got.previous, got.highest) == (
        1,
        state.hash,
        state.previous,
        1,
    )
    assert got.event == "recovered" and "committed.json: it does not parse" in got.reason
    assert len(again.notes) == 1 and "recovered version 1" in again.notes[0]
    assert again.history()[-1]["event"] == "recovered"
    assert store_at(tmp_path).committed() == got  # and it is committed.json again


def test_a_missing_release_falls_back_to_the_newest_whole_previous_version(
    tmp_path: Path, releases: list[Release]
) -> None:
    store = store_at(tmp_path)
    committed_at(store, (0, releases[0]), (1, releases[1]), (2, releases[2]), (3, releases[3]))
    store.rollback(3, reason="script error")  # 3 is bad: never a candidate
    store.path(releases[2].hash).unlink()
    store.path(releases[1].hash).write_bytes(b"rot")
    again = store_at(tmp_path)
    got = again.committed()
    assert got is not None
    assert (got.version, got.hash, got.previous, got.bad) == (0, releases[0].hash, (), (3,))
    # The floor comes down to the versions kept (and the bad ones): 1 and 2 may come again.
    assert got.highest == 3
    assert "version 2" in got.reason and "missing or corrupt" in got.reason
    assert "recovered version 0" in again.notes[-1]  # (after: the orphan sidecars removed)


def test_a_release_lost_while_running_is_noticed_by_committed(
    tmp_path: Path, releases: list[Release]
) -> None:
    store = store_at(tmp_path)
    committed_at(store, (0, releases[0]), (1, releases[1]))
    store.path(releases[1].hash).unlink()
    got = store.committed()
    assert got is not None and (got.version, got.event, got.highest) == (0, "recovered", 0)


@pytest.mark.parametrize("how", ["release-gone", "json-corrupt-no-history"])
def test_nothing_usable_is_an_error_with_a_hint(
    tmp_path: Path, releases: list[Release], how: str
) -> None:
    store = store_at(tmp_path)
    committed_at(store, (0, releases[0]))
    if how == "release-gone":
        store.path(releases[0].hash).unlink()
        match = r"version 0 \([0-9a-f]{12}\) is unusable .* no earlier version is stored whole"
    else:
        store.committed_path.write_text("{")
        store.history_path.unlink()
        match = "committed.json: it does not parse .* the history names no committed version"
    with pytest.raises(StoreError, match=match) as e:
        store_at(tmp_path)
    assert "hint: move" in str(e.value) and "--script" in str(e.value)


def test_a_store_from_a_later_fieldkit_is_refused_not_misread(
    tmp_path: Path, releases: list[Release]
) -> None:
    store = store_at(tmp_path)
    committed_at(store, (0, releases[0]))
    data = json.loads(store.committed_path.read_text())
    store.committed_path.write_text(json.dumps(data | {"format": 2}))
    with pytest.raises(StoreError, match="format 2, this fieldkit reads format 1"):
        store_at(tmp_path)
