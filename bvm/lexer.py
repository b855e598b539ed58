"""Byte-oriented Buzz lexer (Buzz: src/buzz/buzzlex.c), positions exactly as the reference.

Positions: `line` is 1-based and only advances on a newline token or at the end of
a `#` comment (raw newlines inside string literals do not count); `col` is the
0-based byte offset in the line, reset only when `line` advances. Every token
records the realpath of its file, which ends up in the debug info. Errors and the source
map (bvm/srcmap.py) use each token's `where` instead: the true line and a 1-based column,
as editors count them. The reference
turns lexer errors into an end of file; here they are `BuzzCompileError`s.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from typing import NoReturn

from bvm.errors import BuzzCompileError


class Tok(Enum):
    """Token types; the value is the description used in syntax error messages."""

    BLOCKOPEN = "{"
    BLOCKCLOSE = "}"
    PAROPEN = "("
    PARCLOSE = ")"
    IDXOPEN = "["
    IDXCLOSE = "]"
    VAR = "var"
    NIL = "nil"
    IF = "if"
    ELSE = "else"
    FUNCTION = "function"
    RETURN = "return"
    FOR = "for"
    WHILE = "while"
    LANDOR = "and or"
    LNOT = "not"
    ADDSUB = "+ -"
    MULDIV = "* /"
    MOD = "%"
    POW = "^"
    LRSHIFT = "<< >>"
    BANDOR = "& |"
    BNOT = "!"
    CONST = "constant"
    ID = "identifier"
    STRING = "string"
    DOT = "."
    COMMA = ","
    ASSIGN = "="
    CMP = "== != < <= > >="
    EOF = "end of file"


KEYWORDS: dict[str, Tok] = {
    "var": Tok.VAR,
    "nil": Tok.NIL,
    "if": Tok.IF,
    "else": Tok.ELSE,
    "function": Tok.FUNCTION,
    "return": Tok.RETURN,
    "for": Tok.FOR,
    "while": Tok.WHILE,
    "and": Tok.LANDOR,
    "or": Tok.LANDOR,
    "not": Tok.LNOT,
}

_SINGLE: dict[int, Tok] = {
    ord("{"): Tok.BLOCKOPEN,
    ord("}"): Tok.BLOCKCLOSE,
    ord("("): Tok.PAROPEN,
    ord(")"): Tok.PARCLOSE,
    ord("["): Tok.IDXOPEN,
    ord("]"): Tok.IDXCLOSE,
    ord(","): Tok.COMMA,
    ord("."): Tok.DOT,
    ord("+"): Tok.ADDSUB,
    ord("-"): Tok.ADDSUB,
    ord("*"): Tok.MULDIV,
    ord("/"): Tok.MULDIV,
    ord("%"): Tok.MOD,
    ord("^"): Tok.POW,
    ord("&"): Tok.BANDOR,
    ord("|"): Tok.BANDOR,
}

_LETTERS = frozenset(b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz")
_DIGITS = frozenset(b"0123456789")
_IDCHARS = _LETTERS | _DIGITS | {ord("_")}
_CONSTCHARS = _DIGITS | {ord(".")}
_BLANKS = frozenset(b" \t\r")
_ESCAPES = {ord("n"): ord("\n"), ord("t"): ord("\t"), ord("\\"): ord("\\")}

#: Realpath stand-in the reference prints for the end-of-file token.
NULL_FILE = "(null)"


@dataclass(frozen=True, slots=True)
class Token:
    """One token: `text` is the lexeme (the decoded value for strings).

    `line`/`col`/`file` are the reference's position, used for .basm annotations
    (the EOF token is 0, 1, `(null)`). `where` is the place to report errors at:
    (path as opened, true line, 1-based column), every newline counted, as editors
    number them; for EOF it is the end of the last real token.
    `newline_before` tells whether a line break separates it from the previous token.
    """

    kind: Tok
    text: str
    line: int
    col: int
    file: str
    where: tuple[str, int, int]
    newline_before: bool


@dataclass(slots=True)
class _Source:
    """One file on the lexer's include stack."""

    data: bytes
    path: str  # as opened, for error messages and relative includes
    realpath: str
    pos: int = 0
    line: int = 1
    col: int = 0
    # The true position, for error messages and the source map: every newline counts
    # (the reference's `line` misses those inside strings).
    true_line: int = 1
    line_start: int = 0  # byte offset where the true line starts


def decode(raw: bytes) -> str:
    """Bytes -> str the way the project keeps Buzz bytes in text: latin-1, one char a byte."""
    return raw.decode("latin-1")


def _quote_char(byte: int) -> str:
    """A byte shown in a message: printable ASCII as itself, anything else in hex."""
    if 0x20 < byte < 0x7F:
        return f"'{chr(byte)}'"
    return f"byte 0x{byte:02x}"


class Lexer:
    """Produces the tokens of a main file and of the files it includes, on demand."""

    def __init__(self, source: bytes, path: str, include_dirs: Sequence[str] = ()) -> None:
        main = _Source(source + b"\n", path, _debug_name(path))
        self._stack: list[_Source] = [main]
        self._seen: set[str] = {main.realpath}  # include-once, by realpath
        self._include_dirs = list(include_dirs)
        self._last_end: tuple[str, int, int] = (path, 1, 1)
        self.main_path = path
        self.files: list[str] = [path]  # the main file, then each included one as opened

    def _error(self, src: _Source, pos: int, message: str, hint: str | None = None) -> NoReturn:
        """A compile error at byte `pos` of `src`, at its true line and 1-based column."""
        raise BuzzCompileError(src.path, src.true_line, pos - src.line_start + 1, message, hint)

    def next_token(self) -> Token:
        """Return the next token, skipping statement ends (newlines and `;`)."""
        newline = False
        while self._stack:
            src = self._stack[-1]
            data = src.data
            pos = src.pos
            while pos < len(data) and data[pos] in _BLANKS:
                pos += 1
            src.col += pos - src.pos
            src.pos = pos
            if pos >= len(data):
                self._stack.pop()
                continue
            c = data[pos]
            if c == 0x0A:
                src.pos += 1
                src.line += 1
                src.col = 0
                src.true_line += 1
                src.line_start = src.pos
                newline = True
                continue
            if c == 0x3B:  # ';' is a statement end, which the parser ignores
                src.pos += 1
                src.col += 1
                continue
            if c == 0x23:  # '#': the comment's newline is eaten without a statement end
                end = data.find(b"\n", pos)
                src.pos = (end if end >= 0 else len(data)) + 1
                src.line += 1
                src.col = 0
                src.true_line += 1
                src.line_start = src.pos
                newline = True
                continue
            if data.startswith(b"include", pos) and data[pos + 7 : pos + 8] not in _ID_BYTES:
                self._include(src)
                continue
            tok = self._token(src, newline)
            self._last_end = (src.path, src.true_line, src.pos - src.line_start + 1)
            return tok
        path, line, col = self._last_end
        return Token(Tok.EOF, "", 0, 1, NULL_FILE, (path, line, col), newline)

    def _token(self, src: _Source, newline: bool) -> Token:
        data, start, col = src.data, src.pos, src.col
        c = data[start]
        end = start + 1
        kind: Tok
        if c in _SINGLE:
            kind = _SINGLE[c]
        elif c in b"=!<>":
            nxt = data[end]
            if c in b"<>" and nxt == c:
                kind, end = Tok.LRSHIFT, end + 1
            elif nxt == 0x3D:  # '='
                kind, end = Tok.CMP, end + 1
            elif c == 0x3D:
                kind = Tok.ASSIGN
            elif c == 0x21:
                kind = Tok.BNOT
            else:
                kind = Tok.CMP
        elif c in _LETTERS:
            while data[end] in _IDCHARS:
                end += 1
            kind = KEYWORDS.get(data[start:end].decode("ascii"), Tok.ID)
        elif c in _DIGITS:
            while data[end] in _CONSTCHARS:
                end += 1
            kind = Tok.CONST
        elif c in b"'\"":
            return self._string(src, newline)
        else:
            hint = (
                "identifiers must start with a letter"
                if c == 0x5F
                else "Buzz source is ASCII outside strings and comments"
            )
            self._error(src, start, f"Syntax error: unknown character {_quote_char(c)}", hint)
        text = data[start:end].decode("ascii")
        src.pos = end
        src.col += end - start
        where = (src.path, src.true_line, start - src.line_start + 1)
        return Token(kind, text, src.line, col, src.realpath, where, newline)

    def _string(self, src: _Source, newline: bool) -> Token:
        data, start, col = src.data, src.pos, src.col
        quote = data[start]
        # The reference's closing rule: a quote preceded by a backslash does not
        # close the string unless that backslash is itself preceded by one.
        p = start + 1
        while True:
            p = data.find(quote, p)
            if p < 0:
                self._error(
                    src,
                    start,
                    "Syntax error: string closing quote not found",
                    f"add the closing {chr(quote)} (strings may span lines)",
                )
            if data[p - 1] != 0x5C or data[p - 2] == 0x5C:
                break
            p += 1
        # Deliberate fix: the reference emits one extra byte per escape (read from
        # past the closing quote); we stop at the closing quote.
        out = bytearray()
        i = start + 1
        while i < p:
            b = data[i]
            if b == 0x5C:
                nxt = data[i + 1]
                out.append(_ESCAPES.get(nxt, nxt))
                i += 2
            else:
                out.append(b)
                i += 1
        where = (src.path, src.true_line, start - src.line_start + 1)
        src.pos = p + 1
        src.col += p + 1 - start  # raw newlines inside do not reset the column either
        inner = data.count(b"\n", start, p)
        if inner:  # the true position does move
            src.true_line += inner
            src.line_start = data.rfind(b"\n", start, p) + 1
        return Token(Tok.STRING, decode(bytes(out)), src.line, col, src.realpath, where, newline)

    def _include(self, src: _Source) -> None:
        data, at = src.data, src.pos
        p = src.pos + 7
        while data[p] in b" \t":
            p += 1
        quote = data[p]
        if quote not in b"'\"":
            self._error(
                src, at, "Syntax error: expected string after include", 'write include "file.bzz"'
            )
        end = p + 1
        while data[end] != quote:
            if data[end] == 0x0A:
                self._error(
                    src,
                    at,
                    "Syntax error: expected end of string",
                    "the file name must be quoted on one line",
                )
            end += 1
        name = os.fsdecode(data[p + 1 : end])
        src.col += end + 1 - src.pos
        src.pos = end + 1
        found = self._find(name, src, at)
        if found is None:
            searched = ", ".join(repr(d) for d in self._search_dirs(src))
            self._error(
                src,
                at,
                f"Can't find file '{name}'",
                f"Can't read '{name}' in the working directory nor in: {searched} "
                "(add directories with -I or BUZZ_INCLUDE_PATH)",
            )
        opened, raw = found
        real = _debug_name(opened)
        if real in self._seen:  # include-once: later includes of a file are no-ops
            return
        self._seen.add(real)
        self.files.append(opened)
        self._stack.append(_Source(raw + b"\n", opened, real))

    def _search_dirs(self, src: _Source) -> list[str]:
        env = os.environ.get("BUZZ_INCLUDE_PATH", "")
        dirs = [d for d in env.split(":") if d]
        dirs += self._include_dirs
        dirs.append(os.path.dirname(src.path) or ".")
        return dirs

    def _find(self, name: str, src: _Source, at: int) -> tuple[str, bytes] | None:
        # The reference looks relative to the process cwd first, then BUZZ_INCLUDE_PATH.
        for candidate in [name] + [os.path.join(d, name) for d in self._search_dirs(src)]:
            if not os.path.isfile(candidate):  # regular files only: never block on a device
                continue
            try:
                with open(candidate, "rb") as f:
                    return candidate, f.read()
            except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
                continue
            except OSError as exc:
                self._error(src, at, f"Can't read '{name}': {exc.strerror}")
        return None


_ID_BYTES = frozenset(bytes([b]) for b in _IDCHARS)


def _debug_name(path: str) -> str:
    """The realpath as it goes into .basm text: its file-system bytes, one char a byte.

    A source that is no file (`<buzz>`, the default name of compiled text) keeps its name:
    the working directory has nothing to do with it."""
    if path.startswith("<") and path.endswith(">"):
        return path
    return decode(os.fsencode(os.path.realpath(path)))


class TokenStream:
    """Tokens cached by index, so the parser can backtrack and recompile cheaply.

    A lexer error is stored in place of the token and raised whenever the parser
    reaches that index, which is where the reference would have seen its EOF.
    """

    def __init__(self, lexer: Lexer) -> None:
        self._lexer = lexer
        self._tokens: list[Token | BuzzCompileError] = []

    def __getitem__(self, index: int) -> Token:
        tokens = self._tokens
        while len(tokens) <= index:
            last = tokens[-1] if tokens else None
            if isinstance(last, BuzzCompileError) or (last is not None and last.kind is Tok.EOF):
                tokens.append(last)
                continue
            try:
                tokens.append(self._lexer.next_token())
            except BuzzCompileError as exc:
                tokens.append(exc)
        item = tokens[index]
        if isinstance(item, BuzzCompileError):
            raise item
        return item


def included_files(source: bytes, path: str, include_dirs: Sequence[str] = ()) -> list[str]:
    """The files compiling `source` reads: `path`, then every file it includes (directly or
    not) as opened, each once. A lexical error ends the list where it stopped the lexer:
    the file with the error is in it (what a watcher of the script must watch)."""
    lexer = Lexer(source, path, include_dirs)
    try:
        while lexer.next_token().kind is not Tok.EOF:
            pass
    except BuzzCompileError:
        pass
    return list(lexer.files)


def tokenize(source: bytes, path: str, include_dirs: Sequence[str] = ()) -> list[Token]:
    """All tokens of a program up to and including EOF (statement ends skipped)."""
    stream = TokenStream(Lexer(source, path, include_dirs))
    out: list[Token] = []
    while True:
        tok = stream[len(out)]
        out.append(tok)
        if tok.kind is Tok.EOF:
            return out
