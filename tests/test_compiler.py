"""Compiler: exact .basm text for the language's constructs and the deliberate fixes.

Facts: docs/language.md#grammar, #scopes, #code-generation; fixes: docs/compat.md.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from bvm.compiler import MAX_NESTING, build, compile_asm
from bvm.errors import BuzzCompileError

P = "/nonexistent/dir/prog.bzz"  # realpath of a missing file is itself


def basm(src: str | bytes, path: str = P, include_dirs: tuple[str, ...] = ()) -> str:
    data = src.encode() if isinstance(src, str) else src
    return compile_asm(data, path, include_dirs)


def chunks(text: str) -> dict[int, list[str]]:
    """Code lines per chunk label, annotations stripped."""
    out: dict[int, list[str]] = {}
    current: list[str] | None = None
    for line in text.split("\n"):
        m = re.fullmatch(r"@__label_(\d+)", line)  # chunk labels carry no annotation
        if m:
            current = out.setdefault(int(m.group(1)), [])
            continue
        if current is not None and line:
            current.append(line.split("\t|")[0].strip())
    return out


def code(src: str, chunk: int = 0) -> list[str]:
    """The instructions of one chunk, without the global exit point."""
    lines = chunks(basm(src))[chunk]
    if chunk == 0:
        assert lines[-2:] == ["@__exitpoint", "done"]
        lines = lines[:-2]
    return lines


def error(src: str | bytes, path: str = P, **kw: object) -> BuzzCompileError:
    with pytest.raises(BuzzCompileError) as info:
        basm(src, path, **kw)  # type: ignore[arg-type]
    return info.value


def ann(text: str) -> str:
    """Expected .basm written with `|l,c` shorthands for `\\t|l,c,<path>`."""
    return re.sub(r" \|(\d+),(\d+)(?=\n)", lambda m: f"\t|{m[1]},{m[2]},{P}", text).replace(
        " |EOF", "\t|0,1,(null)"
    )


# -- whole files ---------------------------------------------------------------------


def test_worked_example_full_text() -> None:
    expected = ann(
        "!3\n'x\n'y\n'z\n\n\tnop\n\n@__label_0\n"
        "\tpushs 0 |1,2\n\tpushf 3.14 |1,4\n\tgstore |2,0\n"
        "\tpushs 1 |2,2\n\tpushf -0.5 |2,5\n\tgstore |3,0\n"
        "\tpushs 2 |3,2\n\tpushf 1. |3,4\n\tgstore |EOF\n"
        "\n@__exitpoint |EOF\n\tdone |EOF\n"
    )
    assert basm("x = 3.14\ny = -0.5\nz = 1.") == expected


def test_empty_program() -> None:
    assert basm("") == "!0\n\n\tnop\n"
    assert basm("# only a comment\n;;\n\n") == "!0\n\n\tnop\n"


def test_function_prologue_and_chunk_order() -> None:
    text = basm("function f() {return self}\ng = function() {}\nfunction h(a) {}")
    head = text.split("\n@__label_0\n")[0]
    assert head == (
        "!3\n'f\n'g\n'h\n\n"
        "\tpushs 0\n\tpushcn @__label_1\n\tgstore\n"
        "\tpushs 2\n\tpushcn @__label_3\n\tgstore\n\tnop\n"
    )
    labels = re.findall(r"^@__label_(\d+)$", text, re.M)
    assert labels == ["0", "1", "2", "3"]  # chunks in creation order, lambda included
    assert chunks(text)[1] == ["lload 0", "ret1", "ret0"]
    assert chunks(text)[2] == ["ret0"]


# -- annotations and control flow (docs/language.md#annotation-rule, #emission-order) -----


def test_if_else_layout_and_annotations() -> None:
    expected = ann(
        "!2\n'x\n'y\n\n\tnop\n\n@__label_0\n"
        "\tpushs 0 |1,5\n\tgload |1,5\n\tjumpz @__label_1 |1,7\n"
        "\tpushs 1 |1,9\n\tpushi 1 |1,11\n\tgstore |1,13\n"
        "\tjump @__label_2 |1,18\n@__label_1 |1,18\n"
        "\tpushs 1 |1,20\n\tpushi 2 |1,22\n\tgstore |EOF\n@__label_2 |EOF\n"
        "\n@__exitpoint |EOF\n\tdone |EOF\n"
    )
    assert basm("if (x) y = 1 else y = 2") == expected


def test_if_without_else() -> None:
    assert code("if (x) y = 1") == [
        "pushs 0", "gload", "jumpz @__label_1", "pushs 1", "pushi 1", "gstore", "@__label_1",
    ]  # fmt: skip


def test_while_layout_and_annotations() -> None:
    text = basm("while (i < 3) i = i + 1")
    assert text.split("@__label_0\n")[1] == ann(
        "@__label_1 |1,7\n\tpushs 0 |1,9\n\tgload |1,9\n\tpushi 3 |1,11\n\tlt |1,12\n"
        "\tjumpz @__label_2 |1,14\n\tpushs 0 |1,16\n\tpushs 0 |1,20\n\tgload |1,20\n"
        "\tpushi 1 |1,22\n\tadd |EOF\n\tgstore |EOF\n\tjump @__label_1 |EOF\n@__label_2 |EOF\n"
        "\n@__exitpoint |EOF\n\tdone |EOF\n"
    )


def test_for_layout_and_annotations() -> None:
    text = basm("for (i = 0, i < 3, i = i + 1) f(i)")
    assert text.split("@__label_0\n")[1] == ann(
        "\tpushs 0 |1,7\n\tpushi 0 |1,9\n\tgstore |1,10\n"
        "@__label_1 |1,12\n\tpushs 0 |1,14\n\tgload |1,14\n\tpushi 3 |1,16\n\tlt |1,17\n"
        "\tjumpnz @__label_3 |1,19\n\tjump @__label_4 |1,19\n@__label_2 |1,19\n"
        "\tpushs 0 |1,21\n\tpushs 0 |1,25\n\tgload |1,25\n\tpushi 1 |1,27\n\tadd |1,28\n"
        "\tgstore |1,28\n\tjump @__label_1 |1,30\n@__label_3 |1,30\n"
        "\tpushnil |1,31\n\tpushs 1 |1,31\n\tgload |1,31\n\tpushs 0 |1,33\n\tgload |1,33\n"
        "\tpushi 1 |EOF\n\tcallc |EOF\n\tpop |EOF\n\tjump @__label_2 |EOF\n@__label_4 |EOF\n"
        "\n@__exitpoint |EOF\n\tdone |EOF\n"
    )


def test_labels_are_reserved_at_construct_entry() -> None:
    # The lambda inside the condition is created after if reserved labels 1 and 2.
    text = basm("if (f(function() {})) x = 1")
    assert "pushl @__label_3" in text and "jumpz @__label_1" in text


def test_call_statement_annotations() -> None:
    # `log(i)`: the argument count and callc carry the token after `)`.
    text = basm("log(i)\nx = 1")
    assert "\tpushi 1\t|2,0," in text and "\tcallc\t|2,0," in text


# -- identifier chains (docs/language.md#identifier-chains) -------------------------------


@pytest.mark.parametrize(
    ("src", "expected"),
    [
        ("f(a)", "pushnil|pushs 0|gload|pushs 1|gload|pushi 1|callc|pop"),
        ("t.m(a)", "pushs 0|gload|dup|pushs 1|tget|pushs 2|gload|pushi 1|callc|pop"),
        ("t[k](a)", "pushs 0|gload|dup|pushs 1|gload|tget|pushs 2|gload|pushi 1|callc|pop"),
        ("f()()", "pushnil|pushnil|pushs 0|gload|pushi 0|callc|pushi 0|callc|pop"),
        ("a.b.c = 1", "pushs 0|gload|pushs 1|tget|pushs 2|pushi 1|tput"),
        ("t[k] = v", "pushs 0|gload|pushs 1|gload|pushs 2|gload|tput"),
        ("x = t.a[1]", "pushs 0|pushs 1|gload|pushs 2|tget|pushi 1|tget|gstore"),
        ("t.m()()", "pushnil|pushs 0|gload|dup|pushs 1|tget|pushi 0|callc|pushi 0|callc|pop"),
        (
            "x = f(1)(2)",
            "pushs 0|pushnil|pushnil|pushs 1|gload|pushi 1|pushi 1|callc|pushi 2"
            "|pushi 1|callc|gstore",
        ),
    ],
)
def test_identifier_chain_shapes(src: str, expected: str) -> None:
    assert "|".join(code(src)) == expected


def test_self_member_assignment_in_function() -> None:
    assert code("function g(p, q) { self.k = q }", chunk=1) == [
        "lload 0", "pushs 1", "lload 2", "tput", "ret0",
    ]  # fmt: skip


def test_out_of_order_lines_carry_the_token_of_their_insertion() -> None:
    text = basm("f()(\n)")
    body = text.split("@__label_0\n")[1].split("\n")
    # The second pushnil is inserted at the front when the second `(` is seen.
    assert body[0] == f"\tpushnil\t|1,3,{P}"
    assert body[1] == f"\tpushnil\t|1,1,{P}"


def test_local_call_gets_nil_self_slot() -> None:
    assert code("function f(g) { g(1) }", chunk=1) == [
        "pushnil", "lload 1", "pushi 1", "pushi 1", "callc", "pop", "ret0",
    ]  # fmt: skip


# -- expressions ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("src", "expected"),
    [
        ("x = -2^2", "pushi -2|pushi 2|pow"),
        ("x = -y^2", "pushs 1|gload|pushi 2|pow|unm"),
        ("x = +5", "pushi +5"),
        ("x = -1.5", "pushf -1.5"),
        ("x = 2*3%2", "pushi 2|pushi 3|pushi 2|mod|mul"),
        ("x = 1<<2^2", "pushi 1|pushi 2|lshift|pushi 2|pow"),
        ("x = 2+1<<1", "pushi 2|pushi 1|pushi 1|lshift|add"),
        ("x = !1", "pushi 1|bnot"),
        ("x = a^b^c", "pushs 1|gload|pushs 2|gload|pushs 3|gload|pow|pow"),
        ("x = -a & b", "pushs 1|gload|pushs 2|gload|band|unm"),
        ("x = (1 == 1)", "pushi 1|pushi 1|eq"),
        ("x = (a and b or c)", "pushs 1|gload|pushs 2|gload|land|pushs 3|gload|lor"),
        ("x = (not a == b and c)", "pushs 1|gload|pushs 2|gload|eq|pushs 3|gload|land|lnot"),
        ("x = nil", "pushnil"),
        ("x = 1.2.3", "pushf 1.2.3"),
        ('x = "s"', "pushs 1"),
    ],
)
def test_expressions(src: str, expected: str) -> None:
    lines = code(src)
    assert lines[0] == "pushs 0" and lines[-1] == "gstore"
    assert "|".join(lines[1:-1]) == expected


@pytest.mark.parametrize(
    ("src", "expected"),
    [
        ("x = {}", "pusht"),
        ("x = {.a = 1}", "pusht|dup|pushs 1|pushi 1|tput"),
        (
            "x = {.a = 1, .7 = 2, .3.5 = 3}",
            "pusht|dup|pushs 1|pushi 1|tput|dup|pushi 7|pushi 2|tput|dup|pushf 3.5|pushi 3|tput",
        ),
        ("x = {.t = {.u = nil}}", "pusht|dup|pushs 1|pusht|dup|pushs 2|pushnil|tput|tput"),
    ],
)
def test_table_literals(src: str, expected: str) -> None:
    assert "|".join(code(src)[1:-1]) == expected


def test_table_literal_annotations() -> None:
    text = basm("x = {.a = 1,\n.b = 2}")
    assert f"\tdup\t|1,11,{P}" in text  # the second dup sits on the comma


def test_table_literal_errors() -> None:
    assert error("x = {a = 1}").message == "Syntax error: expected .id = expression or }"
    assert error("x = {.if = 1}").message.startswith("Syntax error: expected identifier or")
    assert error("x = 1 + {}").message == "Syntax error: expected identifier, found {"


def test_logic_has_no_short_circuit() -> None:
    assert code("if (a and f()) x = 1")[:8] == [
        "pushs 0", "gload", "pushnil", "pushs 1", "gload", "pushi 0", "callc", "land",
    ]  # fmt: skip


# -- scopes and symbols (docs/language.md#scopes) -----------------------------------------


def test_var_global_and_local() -> None:
    assert code("var a = 1\nvar b") == [
        "pushs 0",
        "pushi 1",
        "gstore",
        "pushs 1",
        "pushnil",
        "gstore",
    ]
    assert code("function g(a) { var b = a var c }", chunk=1) == [
        "pushnil", "lstore 2", "lload 1", "lstore 2", "pushnil", "lstore 3", "lremove 2", "ret0",
    ]  # fmt: skip


def test_local_var_annotations_sit_on_the_equals() -> None:
    text = basm("function g() {\nvar b = 5\n}")
    assert f"\tpushnil\t|2,6,{P}\n\tlstore 1\t|2,6,{P}\n\tpushi 5\t|2,8,{P}" in text


def test_duplicated_local_is_an_error_but_global_redeclaration_is_fine() -> None:
    err = error("function g(a) { var a = 1 }")
    assert (err.message, err.line, err.col) == ("Duplicated symbol 'a'", 1, 21)
    assert code("var a\nvar a") == ["pushs 0", "pushnil", "gstore"] * 2


def test_block_scopes_drop_their_locals() -> None:
    assert code("function g() { if (1) { var x = 1 } var y }", chunk=1) == [
        "pushi 1", "jumpz @__label_2", "pushnil", "lstore 1", "pushi 1", "lstore 1",
        "lremove 1", "@__label_2", "pushnil", "lstore 1", "lremove 1", "ret0",
    ]  # fmt: skip


def test_top_level_block_traps() -> None:
    # `var` in a top-level block is local slot 0; a lambda there has no self slot.
    assert code("if (c) { var v = 1 }")[3:7] == ["pushnil", "lstore 0", "pushi 1", "lstore 0"]
    assert code("if (c) { f = function(a) { return a } }", chunk=3) == ["lload 0", "ret1", "ret0"]
    assert code("f = function(a) { return a }", chunk=1) == ["lload 1", "ret1", "ret0"]
    # A braceless body pushes no table: the var is global.
    assert code("if (c) var v = 1")[3:6] == ["pushs 1", "pushi 1", "gstore"]


def test_parameter_aliasing() -> None:
    text = basm("function f(x){ var g=function(x){return x} return g(5) }")
    assert chunks(text)[2] == ["lload 1", "ret1", "ret0"]  # x aliases f's slot 1


def test_lambda_in_function_clones_the_locals() -> None:
    text = basm("function f(a) { var b = function(c) { return b } }")
    assert chunks(text)[2] == ["lload 2", "ret1", "ret0"]


def test_self_is_a_global_at_top_level() -> None:
    assert code("x = self") == ["pushs 0", "pushs 1", "gload", "gstore"]


def test_nested_named_function_is_rejected() -> None:
    err = error("function f() { function g() {} }")
    assert err.message.startswith("Syntax error: the definition of function g() is nested")
    assert err.hint


def test_docstring_is_discarded() -> None:
    text = basm('function f(a) "Does things,\nacross lines." { return a }')
    assert text.startswith("!1\n'f\n")


# -- string ids (docs/language.md#string-ids) ---------------------------------------------


def test_string_id_order_and_sharing() -> None:
    text = basm('x = "hello"\nfunction hello() {}\nt.k = t["x"]\na = b(c.d, "e")')
    assert text.startswith("!9\n'x\n'hello\n't\n'k\n'a\n'b\n'c\n'd\n'e\n\n\tpushs 1\n")


def test_string_literal_bytes_reach_the_basm() -> None:
    text = basm(b'x = "\xff\xc3\xa9 \\t|,"')
    raw = text.encode("latin-1")
    assert b"\n'\xff\xc3\xa9 \t|,\n" in raw


# -- syntax errors (reference texts) --------------------------------------------------


@pytest.mark.parametrize(
    ("src", "message", "line", "col"),
    [
        ("x = 1 == 1", "Syntax error: expected identifier, found == != < <= > >=", 1, 7),
        ("{ x = 1 }", "Syntax error: expected identifier, found {", 1, 1),
        ("x.y", "Syntax error: expected function call or assignment", 0, 1),
        ("f() = 1", "Syntax error: can't have a function call as lvalue", 1, 5),
        ("5", "Syntax error: expected identifier, found constant", 1, 1),
        ("x = a and not b", "Syntax error: expected identifier, found and or", 1, 7),
        ("if (a < b < c) x = 1", "Syntax error: expected ), found == != < <= > >=", 1, 11),
        ("x = t.3", "Syntax error: expected identifier, found constant", 1, 7),
        ("x = (f)()", "Syntax error: expected identifier, found (", 1, 8),
        ("x = (1", "Syntax error: expected ), found end of file", 1, 7),
        (
            "for (var i = 0, i < 1, i = i + 1) x = 1",
            "Syntax error: expected identifier, found var",
            1,
            6,
        ),
        ("return", "Syntax error: expected identifier, found end of file", 1, 7),
    ],
)
def test_syntax_errors(src: str, message: str, line: int, col: int) -> None:
    err = error(src)
    assert err.message == message
    if line:
        assert (err.path, err.line, err.col) == (P, line, col)
    assert str(err).startswith(f"{P}:")


def test_error_message_format() -> None:
    err = error("x = 1 == 1")
    assert str(err) == (
        f"{P}:1:7: Syntax error: expected identifier, found == != < <= > >=\n"
        "  hint: a comparison is not an expression here: parenthesize it, e.g. x = (a == b)"
    )


# -- deliberate decision 1: return fallback --------------------------------------------


def test_return_fallback_to_bare_return() -> None:
    src = "function f(x) { if(x) return\n y = 2\n return 3 }"
    assert code(src, chunk=1) == [
        "lload 1", "jumpz @__label_2", "ret0", "@__label_2",
        "pushs 1", "pushi 2", "gstore", "pushi 3", "ret1", "ret0",
    ]  # fmt: skip


def test_greedy_return_is_kept_when_the_reference_accepts_it() -> None:
    src = 'function f(x) { if(x) return\n log("after") }'
    assert code(src, chunk=1)[2:9] == [
        "pushnil", "pushs 1", "gload", "pushs 2", "pushi 1", "callc", "ret1",
    ]  # fmt: skip
    # `else` after the swallowed value: the reference accepts, so do we.
    src = "function f(x) { if(x) return\n x\n else return 2 }"
    assert code(src, chunk=1)[:4] == ["lload 1", "jumpz @__label_2", "lload 1", "ret1"]


def test_return_fallback_in_braceless_while_and_several_sites() -> None:
    src = "function f(x) {\n while (x) return\n x = 1\n if (x) return\n y.z = 2\n}"
    body = code(src, chunk=1)
    assert body.count("ret0") == 3 and "ret1" not in body


def test_return_fallback_undoes_strings_labels_and_chunks() -> None:
    # The greedy parse starts a lambda at `function` (label 3, a chunk, pushl) and
    # fails at `g`; after the undo the named function gets label 3 and no orphan.
    text = basm("if (x) return\nfunction g() {}\nz = 1")
    assert text.startswith("!3\n'x\n'g\n'z\n\n\tpushs 1\n\tpushcn @__label_3\n\tgstore\n")
    assert re.findall(r"^@__label_(\d+)$", text, re.M) == ["0", "3"]
    assert "pushl" not in text
    assert chunks(text)[0][:4] == ["pushs 0", "gload", "jumpz @__label_1", "ret0"]
    assert chunks(text)[3] == ["ret0"]


def test_return_fallback_inside_a_block_keeps_its_locals() -> None:
    # Undo happens in place: the enclosing block still drops its own locals.
    src = "function f() { var a = 1\n if (a) { var b = 2\n if (b) return\n b = 3 } a = 4 }"
    assert code(src, chunk=1)[-10:] == [
        "ret0", "@__label_4", "pushi 3", "lstore 2", "lremove 1", "@__label_2",
        "pushi 4", "lstore 1", "lremove 1", "ret0",
    ]  # fmt: skip


def test_return_fallback_that_also_fails_reports_the_greedy_error() -> None:
    err = error("function f() { return\n 1 + }")
    assert (err.message, err.line, err.col) == ("Syntax error: expected identifier, found }", 2, 6)


def test_return_at_end_of_file_stays_an_error() -> None:
    assert error("if (x) return\n").message.endswith("found end of file")


def test_return_on_the_same_line_is_never_a_fallback() -> None:
    err = error("function f(x) { if(x) return y = 2 }")
    assert (err.message, err.col) == ("Syntax error: expected identifier, found =", 32)


# -- deliberate decision 2: strings ----------------------------------------------------


def test_escapes_have_no_extra_byte() -> None:
    assert basm('log("a\\tb", \'q\\"q\')').startswith("!3\n'log\n'a\tb\n'q\"q\n")


@pytest.mark.parametrize("src", [b'x = "a\\nb"', b'x = 1\ny = "a\nb"', b"log('\\n')"])
def test_newline_in_string_value_is_an_error(src: bytes) -> None:
    err = error(src)
    assert "newline" in err.message and err.hint
    where = src.rfind(b"=") + 2 if b"=" in src else 4
    assert err.col == where - src.rfind(b"\n", 0, where)  # 1-based


def test_newline_in_string_keeps_line_numbers_reference_like() -> None:
    text = basm('function f() "a\nb" {\n}\nx = 1')
    assert f"\tpushs 1\t|3,2,{P}" in text  # really line 4: the docstring hid a newline


# -- deliberate decision 3: lexer errors and stray braces --------------------------------


def test_lexer_error_does_not_truncate() -> None:
    err = error("x = 1\n_y = 2")
    assert (err.line, err.col) == (2, 1) and "unknown character '_'" in err.message
    assert error("x = 1\ny = 'abc").message == "Syntax error: string closing quote not found"


def test_stray_closing_brace_is_an_error() -> None:
    err = error("x = 1\n}\ny = 2")
    assert (err.line, err.col) == (2, 1) and "}" in err.message and err.hint


# -- deliberate decision 4: include ----------------------------------------------------


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_include_search_order(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    main = write(tmp_path / "src" / "main.bzz", 'include "lib.bzz"\n')
    write(tmp_path / "src" / "lib.bzz", "from_own_dir = 1")
    write(tmp_path / "idir" / "lib.bzz", "from_include_dirs = 1")
    write(tmp_path / "env" / "lib.bzz", "from_env = 1")
    write(tmp_path / "cwd" / "lib.bzz", "from_cwd = 1")
    monkeypatch.chdir(tmp_path / "cwd")
    monkeypatch.setenv("BUZZ_INCLUDE_PATH", f":{tmp_path / 'nowhere'}::{tmp_path / 'env'}")
    dirs = (str(tmp_path / "idir"),)

    def first_global() -> str:
        return basm(main.read_bytes(), str(main), dirs).split("\n")[1]

    assert first_global() == "'from_cwd"
    (tmp_path / "cwd" / "lib.bzz").unlink()
    assert first_global() == "'from_env"
    monkeypatch.delenv("BUZZ_INCLUDE_PATH")
    assert first_global() == "'from_include_dirs"
    assert basm(main.read_bytes(), str(main)).split("\n")[1] == "'from_own_dir"


def test_include_annotations_use_the_included_realpath(tmp_path: Path) -> None:
    lib = write(tmp_path / "lib.bzz", "a = 1\n")
    main = write(tmp_path / "main.bzz", 'include "lib.bzz"\nb = 2\n')
    text = basm(main.read_bytes(), str(main))
    assert f"\tpushs 0\t|1,2,{lib}" in text and f"\tpushs 1\t|2,2,{main}" in text


def test_include_once(tmp_path: Path) -> None:
    write(tmp_path / "lib.bzz", "x = x + 1\n")
    write(tmp_path / "sub" / "other.bzz", 'include "../lib.bzz"\n')
    main = write(
        tmp_path / "main.bzz", 'include "lib.bzz"\ninclude "sub/other.bzz"\ninclude "lib.bzz"\n'
    )
    body = code_of(main)
    assert body.count("add") == 1  # the reference would compile lib.bzz three times


def test_include_recursion_is_skipped(tmp_path: Path) -> None:
    write(tmp_path / "one.bzz", 'include "two.bzz"\nfunction f() { log("f()") }\n')
    two = write(tmp_path / "two.bzz", 'include "one.bzz"\nf()\n')
    text = basm(two.read_bytes(), str(two))
    assert text.startswith("!3\n'f\n'log\n'f()\n")
    assert chunks(text)[0][:5] == ["pushnil", "pushs 0", "gload", "pushi 0", "callc"]


def test_include_mid_expression_and_without_space(tmp_path: Path) -> None:
    write(tmp_path / "val.bzz", "42")
    main = write(tmp_path / "main.bzz", "x = include'val.bzz' + 1")
    assert "|".join(code_of(main)) == "pushs 0|pushi 42|pushi 1|add|gstore"


def test_include_not_found(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("BUZZ_INCLUDE_PATH", "/nonexistent/a")
    main = write(tmp_path / "main.bzz", 'x = 1\n  include "nope.bzz"\n')
    err = error(main.read_bytes(), str(main), include_dirs=("/nonexistent/b",))
    assert str(err).startswith(f"{main}:2:3: Can't find file 'nope.bzz'")
    assert err.hint is not None
    assert "/nonexistent/a" in err.hint and "/nonexistent/b" in err.hint
    assert "Can't read 'nope.bzz'" in err.hint  # the reference's own wording
    assert str(tmp_path) in err.hint


def code_of(path: Path) -> list[str]:
    lines = chunks(basm(path.read_bytes(), str(path)))[0]
    return lines[:-2]


# -- bad input -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "src",
    [
        "x = " + "(" * 10_000 + "1" + ")" * 10_000,
        "x = " + "-" * 10_000 + "1",
        "x = " + "!" * 10_000 + "1",
        "x = " + "a^" * 10_000 + "1",
        "if (" + "not " * 10_000 + "1) x = 1",
        "if (1) {" * 10_000 + "}" * 10_000,
        "x = " + "{.a = " * 10_000 + "1" + "}" * 10_000,
        "x = " + "a[" * 10_000 + "1" + "]" * 10_000,
        "x = " + "f(" * 10_000 + ")" * 10_000,
        "x = function() {" * 3_000 + "}" * 3_000,
    ],
)
def test_deep_nesting_is_a_clean_error(src: str) -> None:
    err = error(src)
    assert "nested too deeply" in err.message


def test_reasonable_nesting_compiles() -> None:
    depth = MAX_NESTING // 2
    basm("x = " + "(" * depth + "1" + ")" * depth)
    basm("if (1) {" * depth + "}" * depth)


def test_build_gives_bo_and_bdb() -> None:
    bo, bdb = build(b"x = 3.14\ny = -0.5\nz = 1.", P)
    assert bo.hex().startswith("030078007900") and len(bdb) > 0


def test_non_ascii_paths_reach_debug_info_as_file_system_bytes(tmp_path: Path) -> None:
    main = write(tmp_path / "d\u00e9j\u00e0" / "m.bzz", 'include "\u00e9t\u00e9.bzz"\n')
    write(main.parent / "\u00e9t\u00e9.bzz", "x = 1")
    bo, bdb = build(main.read_bytes(), str(main))
    assert str(main.parent / "\u00e9t\u00e9.bzz").encode() in bdb


def test_compile_to_asm_file_is_byte_exact(tmp_path: Path) -> None:
    from bvm.compiler import compile_to_asm_file

    src = write(tmp_path / "s.bzz", "")
    src.write_bytes(b'x = "\xff\xfe"\n')
    out = tmp_path / "s.basm"
    compile_to_asm_file(str(src), str(out))
    assert b"\n'\xff\xfe\n" in out.read_bytes()
    assert os.path.getsize(out) > 0
