"""Lexer: token kinds, reference positions, string bugs (fixed) and lexer errors.

Facts: docs/language.md#lexer.
"""

from __future__ import annotations

import os

import pytest

from bvm.errors import BuzzCompileError
from bvm.lexer import Tok, tokenize

PATH = "/nonexistent/dir/prog.bzz"


def toks(src: bytes) -> list[tuple[str, str]]:
    return [(t.kind.name, t.text) for t in tokenize(src, PATH)]


def positions(src: bytes) -> list[tuple[str, int, int]]:
    return [(t.text or t.kind.name, t.line, t.col) for t in tokenize(src, PATH)]


def lex_error(src: bytes) -> BuzzCompileError:
    with pytest.raises(BuzzCompileError) as info:
        tokenize(src, PATH)
    return info.value


def test_operators_and_punctuation() -> None:
    assert toks(b"a<<=b>>c<=d!e!=f==g=h") == [
        ("ID", "a"),
        ("LRSHIFT", "<<"),
        ("ASSIGN", "="),
        ("ID", "b"),
        ("LRSHIFT", ">>"),
        ("ID", "c"),
        ("CMP", "<="),
        ("ID", "d"),
        ("BNOT", "!"),
        ("ID", "e"),
        ("CMP", "!="),
        ("ID", "f"),
        ("CMP", "=="),
        ("ID", "g"),
        ("ASSIGN", "="),
        ("ID", "h"),
        ("EOF", ""),
    ]
    kinds = [t.kind for t in tokenize(b"{}()[],.+-*/%^&|<>", PATH)]
    assert kinds == [
        Tok.BLOCKOPEN, Tok.BLOCKCLOSE, Tok.PAROPEN, Tok.PARCLOSE, Tok.IDXOPEN, Tok.IDXCLOSE,
        Tok.COMMA, Tok.DOT, Tok.ADDSUB, Tok.ADDSUB, Tok.MULDIV, Tok.MULDIV, Tok.MOD, Tok.POW,
        Tok.BANDOR, Tok.BANDOR, Tok.CMP, Tok.CMP, Tok.EOF,
    ]  # fmt: skip


def test_keywords_and_identifiers() -> None:
    src = b"var if else function return for while and or not nil self x_1 Var"
    kinds = [t.kind.name for t in tokenize(src, PATH)][:-1]
    assert kinds == [
        "VAR", "IF", "ELSE", "FUNCTION", "RETURN", "FOR", "WHILE",
        "LANDOR", "LANDOR", "LNOT", "NIL", "ID", "ID", "ID",
    ]  # fmt: skip


def test_numbers_keep_their_text() -> None:
    # No exponents, no leading dot; a constant is digits and dots.
    assert toks(b"1e5 .5 1.2.3 007 1..2")[:-1] == [
        ("CONST", "1"),
        ("ID", "e5"),
        ("DOT", "."),
        ("CONST", "5"),
        ("CONST", "1.2.3"),
        ("CONST", "007"),
        ("CONST", "1..2"),
    ]


def test_positions_are_reference_ones() -> None:
    # 1-based lines, 0-based byte columns, tab counts as one column.
    assert positions(b"x = 1\n\tyy(2)") == [
        ("x", 1, 0), ("=", 1, 2), ("1", 1, 4),
        ("yy", 2, 1), ("(", 2, 3), ("2", 2, 4), (")", 2, 5), ("EOF", 0, 1),
    ]  # fmt: skip


def test_semicolons_are_statement_ends_and_comments_end_lines() -> None:
    assert positions(b"a;b # note\nc") == [("a", 1, 0), ("b", 1, 2), ("c", 2, 0), ("EOF", 0, 1)]


def test_newline_in_string_does_not_advance_line() -> None:
    # The reference only counts newline tokens: everything after is a line early,
    # and the column keeps counting from the start of the string's line.
    tokens = tokenize(b'x = "a\nb" y\nz', PATH)
    assert [(t.line, t.col) for t in tokens] == [(1, 0), (1, 2), (1, 4), (1, 10), (2, 0), (0, 1)]
    assert tokens[2].text == "a\nb"
    # The true position (errors, the source map) counts it, as an editor does.
    assert [t.where[1:] for t in tokens[:5]] == [(1, 1), (1, 3), (1, 5), (2, 4), (3, 1)]


def test_eof_token_and_file_names(tmp_path: os.PathLike[str]) -> None:
    real = os.path.join(tmp_path, "real.bzz")
    link = os.path.join(tmp_path, "link.bzz")
    with open(real, "wb") as f:
        f.write(b"x")
    os.symlink(real, link)
    first, eof = tokenize(b"x", link)
    assert first.file == real  # the realpath goes into debug info
    assert first.where == (link, 1, 1)  # errors name the file as given, 1-based column
    assert (eof.kind, eof.line, eof.col, eof.file) == (Tok.EOF, 0, 1, "(null)")
    assert eof.where == (link, 1, 2)  # EOF errors point just past the last token


def test_newline_before_flags() -> None:
    flags = [t.newline_before for t in tokenize(b"return\n  x; y # c\nz", PATH)]
    assert flags == [False, True, False, True, True]


def test_string_escapes_without_the_extra_byte_bug() -> None:
    # Reference: "a\tb" gives a<TAB>b" (one extra byte per escape). Fixed here.
    assert toks(b'"a\\tb"')[0] == ("STRING", "a\tb")
    assert toks(b'"a\\tb\\tc", "|"')[0] == ("STRING", "a\tb\tc")
    assert toks(b'"q\\"q"')[0] == ("STRING", 'q"q')
    assert toks(b"'x\\ny\\\\z\\q'")[0] == ("STRING", "x\ny\\zq")


def test_string_closing_rule_is_the_reference_one() -> None:
    assert toks(b'"a\\\\" b')[:2] == [("STRING", "a\\"), ("ID", "b")]
    # A quote after \\ closes the string even when it was meant escaped.
    assert toks(b'"\\\\\\"" x"')[:2] == [("STRING", '\\"'), ("STRING", " x")]
    assert toks(b"'\\''")[0] == ("STRING", "'")
    assert toks(b"'say \"hi\"'")[0] == ("STRING", 'say "hi"')


def test_string_bytes_are_kept_one_char_per_byte() -> None:
    tok = tokenize(b'"\xff\xc3\xa9"', PATH)[0]
    assert tok.text == "\xff\xc3\xa9"


def test_unterminated_string_is_an_error() -> None:
    err = lex_error(b'x = 1\ny = "abc')
    assert (err.path, err.line, err.col) == (PATH, 2, 5)
    assert "string closing quote not found" in err.message


@pytest.mark.parametrize(
    ("src", "line", "col", "what"),
    [
        (b"x = 1\n_y = 2", 2, 1, "'_'"),
        (b"x = $", 1, 5, "'$'"),
        (b"x = \xc3\xa9", 1, 5, "byte 0xc3"),
        (b"x\v= 1", 1, 2, "byte 0x0b"),
        (b"x = `", 1, 5, "'`'"),
    ],
)
def test_unknown_characters_are_errors(src: bytes, line: int, col: int, what: str) -> None:
    err = lex_error(src)
    assert (err.line, err.col) == (line, col)
    assert err.message == f"Syntax error: unknown character {what}"
    assert err.hint


def test_lexer_error_is_raised_only_when_reached() -> None:
    # Tokens before the bad byte come out; the error is where the parser would see it.
    from bvm.lexer import Lexer, TokenStream

    stream = TokenStream(Lexer(b"a b @", PATH))
    assert stream[0].text == "a" and stream[1].text == "b"
    with pytest.raises(BuzzCompileError):
        stream[2]
    with pytest.raises(BuzzCompileError):
        stream[5]


def test_comments_and_strings_may_hold_any_bytes() -> None:
    assert toks(b"# \x00\xff _ $\nx")[0] == ("ID", "x")


def test_include_only_before_a_non_identifier_character() -> None:
    assert toks(b"included = 1")[:2] == [("ID", "included"), ("ASSIGN", "=")]
    assert toks(b"include_x")[0] == ("ID", "include_x")
    err = lex_error(b"include x")
    assert err.message == "Syntax error: expected string after include"
    err = lex_error(b'include "abc\n"')
    assert err.message == "Syntax error: expected end of string"
