"""The `io` table: fopen, fclose, fsize, fforeach, fwrite, errno, error_message.

Facts: docs/stdlib.md#io.
"""

from __future__ import annotations

import errno
import math
import os
from pathlib import Path
from typing import Any

import pytest

from bvm.errors import BuzzError
from bvm.stdlib.iolib import BuzzFile, parse_mode
from bvm.values import Table, Userdata

try:
    from test_stdlib_install import buzz_fn, call, make_vm
except ImportError:  # tests/ imported as a package
    from tests.test_stdlib_install import buzz_fn, call, make_vm


@pytest.fixture
def vm(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Any:
    monkeypatch.chdir(tmp_path)  # files are relative to the process cwd
    v = make_vm()
    yield v
    for f in list(_opened):
        if not f.closed:
            f.close()
    _opened.clear()


_opened: list[Any] = []


def fopen(vm: Any, path: str, mode: str) -> Any:
    f = call(vm, "io.fopen", path, mode)
    if f is not None:
        _opened.append(f["handle"].value.fp)
    return f


def err(vm: Any) -> tuple[int, str]:
    io = vm.globals["io"]
    return io["errno"], io["error_message"]


# ---------------------------------------------------------------- fopen, fclose


def test_fopen_returns_a_file_table(vm: Any) -> None:
    f = fopen(vm, "out.txt", "w")
    assert f.__class__ is Table
    assert list(f) == ["handle", "name"]
    assert f["name"] == "out.txt"
    assert f["handle"].__class__ is Userdata and f["handle"].value.__class__ is BuzzFile
    assert err(vm) == (0, "No error")
    assert call(vm, "io.fclose", f) is None
    assert err(vm) == (0, "No error")
    assert Path("out.txt").exists()


def test_fopen_missing_file_returns_nil_and_sets_errno(vm: Any) -> None:
    assert fopen(vm, "missing/nothing.txt", "r") is None
    assert err(vm) == (errno.ENOENT, "No such file or directory")
    f = fopen(vm, "ok.txt", "w")  # success resets the error
    assert f is not None and err(vm) == (0, "No error")


@pytest.mark.parametrize("mode", ["", "q", "+r", "bw"])
def test_fopen_invalid_mode_is_einval(vm: Any, mode: str) -> None:
    assert fopen(vm, "x.txt", mode) is None
    assert err(vm) == (errno.EINVAL, os.strerror(errno.EINVAL))
    assert not Path("x.txt").exists()


def test_fopen_errors(vm: Any, tmp_path: Path) -> None:
    assert fopen(vm, "", "r") is None
    assert err(vm)[0] == errno.ENOENT
    (tmp_path / "d").mkdir()
    assert fopen(vm, "d", "r") is None
    assert err(vm) == (errno.EISDIR, "Is a directory")
    Path("exists").write_text("x")
    assert fopen(vm, "exists", "wx") is None
    assert err(vm) == (errno.EEXIST, "File exists")
    assert Path("exists").read_text() == "x"


def test_fopen_argument_types(vm: Any) -> None:
    with pytest.raises(BuzzError) as e:
        call(vm, "io.fopen", 1, "r")
    assert e.value.message == "type mismatch: expected string, got integer"
    with pytest.raises(BuzzError) as e:
        call(vm, "io.fopen", "a", None)
    assert e.value.message == "type mismatch: expected string, got nil"
    with pytest.raises(BuzzError, match="expected 2 parameters, got 1"):
        call(vm, "io.fopen", "a")


@pytest.mark.parametrize(
    "mode,pymode",
    [
        ("r", "rb"),
        ("rb", "rb"),
        ("r+", "r+b"),
        ("rb+", "r+b"),
        ("w", "wb"),
        ("w+", "w+b"),
        ("a", "ab"),
        ("a+", "a+b"),
        ("rw", "rb"),  # glibc ignores unknown characters
        ("wx", "wb"),
        ("re", "rb"),
    ],
)
def test_parse_mode(mode: str, pymode: str) -> None:
    parsed = parse_mode(mode)
    assert parsed is not None and parsed[1] == pymode


def test_parse_mode_flags() -> None:
    assert parse_mode("w")[0] & (os.O_CREAT | os.O_TRUNC) == os.O_CREAT | os.O_TRUNC
    assert parse_mode("a")[0] & os.O_APPEND
    assert parse_mode("wx")[0] & os.O_EXCL
    assert parse_mode("r")[0] & os.O_ACCMODE == os.O_RDONLY
    assert parse_mode("r+")[0] & os.O_ACCMODE == os.O_RDWR
    assert parse_mode("x") is None


def test_paths_are_relative_to_cwd(vm: Any, tmp_path: Path) -> None:
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "data.txt").write_bytes(b"hello\n")
    f = fopen(vm, "sub/data.txt", "r")
    assert call(vm, "io.fsize", f) == 6


# ---------------------------------------------------------------- fwrite, fsize


def test_fwrite_formats_like_log(vm: Any) -> None:
    f = fopen(vm, "log.txt", "w")
    t = Table()
    t[1] = 1
    assert call(vm, "io.fwrite", f, "a", 1, 2.5, None, t, -math.inf, "\xe9") is None
    call(vm, "io.fwrite", f, vm.globals["type"])
    call(vm, "io.fwrite", f, "")
    call(vm, "io.fclose", f)
    assert Path("log.txt").read_bytes() == (
        b"a12.500000[nil][table with 1 elems]-inf\xe9\n[c-closure @11]\n\n"
    )


def test_fsize_counts_pending_writes(vm: Any) -> None:
    f = fopen(vm, "s.txt", "w")
    assert call(vm, "io.fsize", f) == 0
    call(vm, "io.fwrite", f, "12345")
    assert call(vm, "io.fsize", f) == 6
    assert err(vm) == (0, "No error")


def test_append_mode(vm: Any) -> None:
    Path("a.txt").write_bytes(b"one\n")
    f = fopen(vm, "a.txt", "a")
    call(vm, "io.fwrite", f, "two")
    call(vm, "io.fclose", f)
    assert Path("a.txt").read_bytes() == b"one\ntwo\n"


def test_w_truncates(vm: Any) -> None:
    Path("t.txt").write_bytes(b"old content\n")
    f = fopen(vm, "t.txt", "w")
    assert call(vm, "io.fsize", f) == 0


def test_fwrite_arity(vm: Any) -> None:
    f = fopen(vm, "w.txt", "w")
    with pytest.raises(BuzzError) as e:
        call(vm, "io.fwrite", f)
    assert e.value.message == (
        "wrong number of local variables: expected at least 2 parameters, got 1"
    )


def test_fwrite_to_a_read_only_file_sets_ebadf(vm: Any) -> None:
    Path("r.txt").write_bytes(b"x\n")
    f = fopen(vm, "r.txt", "r")
    assert call(vm, "io.fwrite", f, "nope") is None
    assert err(vm) == (errno.EBADF, "Bad file descriptor")
    assert Path("r.txt").read_bytes() == b"x\n"


# ---------------------------------------------------------------- fforeach


def lines_of(vm: Any, f: Any) -> list[str]:
    seen: list[str] = []
    assert call(vm, "io.fforeach", f, buzz_fn(lambda line: seen.append(line))) is None
    return seen


def test_fforeach_calls_back_for_every_line(vm: Any) -> None:
    Path("l.txt").write_bytes(b"first\nsecond line\n\nlast\r\nno newline at end")
    f = fopen(vm, "l.txt", "r")
    assert lines_of(vm, f) == ["first", "second line", "", "last\r", "no newline at end"]
    assert err(vm) == (0, "No error")
    assert lines_of(vm, f) == []  # at end of file now


def test_fforeach_bytes_map_to_latin1(vm: Any) -> None:
    Path("b.txt").write_bytes(bytes(range(256)).replace(b"\n", b""))
    f = fopen(vm, "b.txt", "r")
    (line,) = lines_of(vm, f)
    assert line == bytes(range(256)).replace(b"\n", b"").decode("latin-1")
    assert len(line) == 255


def test_fforeach_empty_file(vm: Any) -> None:
    Path("e.txt").write_bytes(b"")
    assert lines_of(vm, fopen(vm, "e.txt", "r")) == []


def test_write_then_read_back(vm: Any) -> None:
    f = fopen(vm, "rw.txt", "w+")
    for i in range(3):
        call(vm, "io.fwrite", f, "line ", i)
    call(vm, "io.fclose", f)
    assert lines_of(vm, fopen(vm, "rw.txt", "r")) == ["line 0", "line 1", "line 2"]


def test_fforeach_stops_when_the_callback_closes_the_file(vm: Any) -> None:
    Path("c.txt").write_bytes(b"1\n2\n3\n")
    f = fopen(vm, "c.txt", "r")
    seen: list[str] = []

    def cb(line: str) -> None:
        seen.append(line)
        call(vm, "io.fclose", f)

    call(vm, "io.fforeach", f, buzz_fn(cb))
    assert seen == ["1"]


def test_fforeach_on_a_write_only_file_sets_ebadf(vm: Any) -> None:
    f = fopen(vm, "wo.txt", "w")
    assert lines_of(vm, f) == []
    assert err(vm) == (errno.EBADF, "Bad file descriptor")


def test_fforeach_needs_a_closure(vm: Any) -> None:
    Path("n.txt").write_bytes(b"x\n")
    f = fopen(vm, "n.txt", "r")
    with pytest.raises(BuzzError) as e:
        call(vm, "io.fforeach", f, "print")
    assert e.value.message == "type mismatch: expected closure, got string"


# ---------------------------------------------------------------- bad handles


@pytest.mark.parametrize(
    "fname,extra", [("fclose", ()), ("fsize", ()), ("fforeach", ("CB",)), ("fwrite", ("x",))]
)
def test_closed_and_invalid_handles_are_buzz_errors(vm: Any, fname: str, extra: tuple) -> None:
    args = tuple(buzz_fn(lambda line: None) if a == "CB" else a for a in extra)
    f = fopen(vm, "h.txt", "w")
    call(vm, "io.fclose", f)
    with pytest.raises(BuzzError) as e:
        call(vm, f"io.{fname}", f, *args)
    assert e.value.message == "type mismatch: expected open file, got closed file"

    for bad, msg in (
        (5, "type mismatch: expected table, got integer"),
        (None, "type mismatch: expected table, got nil"),
        (Table(), "type mismatch: expected file, got nil"),
        (_table(handle="not a file"), "type mismatch: expected file, got string"),
        (_table(handle=Userdata(object())), "type mismatch: expected file, got userdata"),
    ):
        with pytest.raises(BuzzError) as e:
            call(vm, f"io.{fname}", bad, *args)
        assert e.value.message == msg


def _table(**entries: Any) -> Table:
    t = Table()
    t.update(entries)
    return t


def test_errno_lives_in_the_io_table_even_for_rebound_methods(vm: Any) -> None:
    other = Table()
    other["open"] = vm.globals["io"]["fopen"].rebind(other)
    assert vm.call_closure(other["open"], "nope/none", "r") is None
    assert err(vm)[0] == errno.ENOENT
    assert "errno" not in other
