"""The `io` table (docs/stdlib.md#io): fopen, fclose, fsize, fforeach, fwrite, errno, error_message.

Files are opened relative to the process's current directory, in binary; Buzz strings map
to bytes one to one (latin-1). Every io call sets `io.errno` and `io.error_message` (the
strerror text, "No error" on success) in the `io` table created by `register`.

Deliberate differences from the reference (see docs/compat.md):

* `io.fforeach(f, fun)` calls fun(line) for every line from the current position (trailing
  "\\n" removed); the reference breaks after the first line. It stops early, without error,
  if fun closes the file.
* A closed or invalid handle is a Buzz error (`type mismatch: expected file, got <type>`,
  `type mismatch: expected open file, got closed file`), never undefined behaviour.
* Opening a directory fails with EISDIR (glibc's fopen succeeds and later reads fail).
"""

from __future__ import annotations

import errno as _errno
import io
import os
from typing import IO, TYPE_CHECKING, Any

from bvm.errors import BuzzError
from bvm.values import Closure, Table, Userdata, format_log, type_name

if TYPE_CHECKING:
    from bvm.host import LibraryHost

_strerror = os.strerror


class BuzzFile:
    """The host object behind a file handle userdata: the open Python file and its path."""

    __slots__ = ("fp", "name")

    def __init__(self, fp: IO[bytes], name: str) -> None:
        self.fp = fp
        self.name = name


def parse_mode(mode: str) -> tuple[int, str] | None:
    """glibc fopen mode -> (os.open flags, Python binary mode); None if invalid (EINVAL).

    The first character must be r, w or a; after it glibc looks at up to six characters:
    '+' (read and write), 'x' (O_EXCL), 'e' (O_CLOEXEC); anything else is ignored.
    """
    if not mode or mode[0] not in "rwa":
        return None
    rest = mode[1:7]
    plus = "+" in rest
    kind = mode[0]
    if kind == "r":
        flags = os.O_RDWR if plus else os.O_RDONLY
    elif kind == "w":
        flags = (os.O_RDWR if plus else os.O_WRONLY) | os.O_CREAT | os.O_TRUNC
    else:
        flags = (os.O_RDWR if plus else os.O_WRONLY) | os.O_CREAT | os.O_APPEND
    if "x" in rest:
        flags |= os.O_EXCL
    flags |= getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0)
    return flags, kind + ("+b" if plus else "b")


def _make_io(vm: LibraryHost, io_table: Table) -> tuple[Any, ...]:
    """The five io natives, reporting errors into `io_table`."""
    call = vm.call_closure

    def ok() -> None:
        io_table["errno"] = 0
        io_table["error_message"] = "No error"

    def fail(code: int) -> None:
        io_table["errno"] = code
        io_table["error_message"] = _strerror(code)

    def handle(f: Any) -> BuzzFile:
        """The open BuzzFile behind a file table, or the Buzz error for a bad one."""
        if f.__class__ is not Table:
            raise BuzzError(f"type mismatch: expected table, got {type_name(f)}")
        h = f.get("handle")
        if h.__class__ is not Userdata or h.value.__class__ is not BuzzFile:
            raise BuzzError(f"type mismatch: expected file, got {type_name(h)}")
        bf = h.value
        if bf.fp.closed:
            raise BuzzError("type mismatch: expected open file, got closed file")
        return bf

    def fopen(_self: Any, path: Any, mode: Any) -> Table | None:
        """io.fopen(path, mode): a file table {handle, name}, or nil (io.errno says why)."""
        if path.__class__ is not str:
            raise BuzzError(f"type mismatch: expected string, got {type_name(path)}")
        if mode.__class__ is not str:
            raise BuzzError(f"type mismatch: expected string, got {type_name(mode)}")
        parsed = parse_mode(mode.split("\0", 1)[0])
        if parsed is None:
            fail(_errno.EINVAL)
            return None
        flags, pymode = parsed
        cpath = path.split("\0", 1)[0].encode("latin-1", "replace")  # C strings end at NUL
        try:
            fd = os.open(cpath, flags, 0o666)
        except OSError as e:
            fail(e.errno or _errno.EIO)
            return None
        try:
            fp = os.fdopen(fd, pymode)
        except OSError as e:
            os.close(fd)
            fail(e.errno or _errno.EIO)
            return None
        ok()
        t = Table()
        t["handle"] = Userdata(BuzzFile(fp, path))
        t["name"] = path
        return t

    def fclose(_self: Any, f: Any) -> None:
        """io.fclose(f): close the file."""
        bf = handle(f)
        try:
            bf.fp.close()
        except OSError as e:
            fail(e.errno or _errno.EIO)
            return None
        ok()
        return None

    def fsize(_self: Any, f: Any) -> int | None:
        """io.fsize(f): the file size in bytes (pending writes included); nil on error."""
        fp = handle(f).fp
        try:
            fp.flush()
            size = os.fstat(fp.fileno()).st_size
        except OSError as e:
            fail(e.errno or _errno.EIO)
            return None
        ok()
        size &= 0xFFFFFFFF
        return size - 0x100000000 if size & 0x80000000 else size

    def fforeach(_self: Any, f: Any, fun: Any) -> None:
        """io.fforeach(f, fun): fun(line) for each remaining line, without its newline."""
        fp = handle(f).fp
        if fun.__class__ is not Closure:
            raise BuzzError(f"type mismatch: expected closure, got {type_name(fun)}")
        readline = fp.readline
        while not fp.closed:
            try:
                raw = readline()
            except io.UnsupportedOperation:  # not open for reading: C reports EBADF
                fail(_errno.EBADF)
                return None
            except OSError as e:
                fail(e.errno or _errno.EIO)
                return None
            if not raw:
                break
            if raw[-1:] == b"\n":
                raw = raw[:-1]
            call(fun, raw.decode("latin-1"))
        ok()
        return None

    def fwrite(_self: Any, *args: Any) -> None:
        """io.fwrite(f, v1, ...): write the values as `log` formats them, then a newline."""
        if len(args) < 2:
            raise BuzzError(
                f"wrong number of local variables: expected at least 2 parameters, got {len(args)}"
            )
        fp = handle(args[0]).fp
        text = format_log(args[1:])
        try:
            fp.write(text.encode("latin-1", "replace") + b"\n")
        except io.UnsupportedOperation:  # not open for writing: C reports EBADF
            fail(_errno.EBADF)
            return None
        except OSError as e:
            fail(e.errno or _errno.EIO)
            return None
        ok()
        return None

    return fopen, fclose, fsize, fforeach, fwrite


def register(vm: LibraryHost) -> None:
    """Register the `io` table (C-function ids 54-58)."""
    new = vm.new_native
    t = Table()
    for name, impl, arity in zip(
        ("fopen", "fclose", "fsize", "fforeach", "fwrite"),
        _make_io(vm, t),
        (2, 1, 1, 2, None),
        strict=True,
    ):
        t[name] = new(impl, arity, name).rebind(t)
    t["errno"] = 0
    t["error_message"] = "No error"
    vm.globals["io"] = t
