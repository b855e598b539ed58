"""Buzz compiler: source -> .basm text, a 1:1 port of Buzz: src/buzz/buzzparser.c.

The recursive descent keeps every emission at the same point relative to token
fetches as the reference, because each .basm line is annotated with the
lookahead token at the moment it is emitted (docs/language.md#annotation-rule). Differences from the
reference are the lead's deliberate fixes: lexer errors and a stray top-level
`}` are errors, strings with a newline are errors, and a `return` that greedily
swallowed the next line falls back to a bare `return` (see `compile_asm`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field

from bvm.errors import BuzzCompileError
from bvm.lexer import Lexer, Tok, Token, TokenStream

#: Deepest nesting of expressions/statements accepted (Python recursion stays bounded).
MAX_NESTING = 64

_BINOPS: dict[str, str] = {
    "+": "add",
    "-": "sub",
    "*": "mul",
    "/": "div",
    "%": "mod",
    "^": "pow",
    "<<": "lshift",
    ">>": "rshift",
    "&": "band",
    "|": "bor",
    "==": "eq",
    "!=": "neq",
    "<": "lt",
    "<=": "lte",
    ">": "gt",
    ">=": "gte",
}

# Tokens that can follow a statement in the reference grammar without starting one;
# a greedy `return` value followed by these is kept (the fallback could never parse).
_STATEMENT_FOLLOW = frozenset({Tok.ELSE, Tok.COMMA, Tok.PARCLOSE})
_STATEMENT_START = frozenset(
    {Tok.VAR, Tok.FUNCTION, Tok.IF, Tok.WHILE, Tok.FOR, Tok.RETURN, Tok.ID, Tok.BLOCKCLOSE, Tok.EOF}
)


@dataclass(frozen=True, slots=True)
class _Sym:
    """A symbol: a global (pos = string id of the name) or a local (pos = slot)."""

    is_global: bool
    pos: int


# What an identifier chain refers to once parsed (docs/language.md#identifier-chains).
_TABLE = "table"
_CLOSURE = "closure"
_Ref = _Sym | str


#: A true source position: (path as opened, line, 1-based column), as `Token.where`.
Pos = tuple[str, int, int]


@dataclass(slots=True)
class _Chunk:
    """The code of the global body, of a named function or of a lambda.

    Each code line comes with the true position of what it does (the operator, the
    call, the index...), or None; they become the source map (bvm/srcmap.py)."""

    label: int
    function_sid: int | None  # set for named functions: they get a prologue entry
    code: list[tuple[str, Pos | None]] = field(default_factory=list)
    name: str | None = None  # the function's name, if it has one
    where: Pos | None = None  # where the function is defined


@dataclass
class Marks:
    """What the source map needs from a compilation, keyed by .basm line number (1-based):
    the true position of each instruction line, and each function's label, name and
    definition position."""

    positions: dict[int, Pos] = field(default_factory=dict)
    functions: list[tuple[str, str | None, Pos | None]] = field(default_factory=list)


_START = Token(Tok.EOF, "", 0, 1, "(null)", ("<start>", 1, 0), False)


@dataclass(frozen=True, slots=True)
class _Snapshot:
    """Everything a greedy `return` value may change, to undo it."""

    index: int
    chunk: _Chunk
    code_len: int
    chunks_len: int
    strings_len: int
    labels: int
    tables: list[tuple[dict[str, _Sym], dict[str, _Sym]]]  # (table object, its contents)
    nesting: int
    fallbacks_len: int


class _Compiler:
    """One parse of a token stream into .basm text."""

    def __init__(self, tokens: TokenStream) -> None:
        self.tokens = tokens
        self.index = -1
        self.tok = _START
        self.strings: list[str] = []
        self.string_ids: dict[str, int] = {}
        self.labels = 0
        self.chunks: list[_Chunk] = []
        self.chunk = _Chunk(-1, None)
        self.symstack: list[dict[str, _Sym]] = []
        self.nesting = 0
        # What follows the command being parsed when it is a `for` init/update
        # (`,` / `)`), else None: it decides the reference's error after a `return`.
        self.command_follow: Tok | None = None
        # Bare-return fallbacks taken: (token index the greedy parse failed at, its error).
        self.fallbacks: list[tuple[int, BuzzCompileError]] = []
        # The position of the statement being compiled: that of its instructions that
        # have none of their own. The last link of the identifier chain parsed last
        # (what an assignment stores into), and the name a lambda being defined gets.
        self.stmt_pos: Pos | None = None
        self.last_link: Token = _START
        self.lambda_name: str | None = None
        self.marks = Marks()

    # -- tokens, errors, emission -------------------------------------------------

    def fetch(self) -> None:
        """Move to the next token."""
        self.index += 1
        self.tok = self.tokens[self.index]

    def at(self, kind: Tok) -> bool:
        """Whether the current token is `kind` (a call, so a type checker does not keep an
        earlier test of `self.tok` across the `fetch` that changed it)."""
        return self.tok.kind is kind

    def error(
        self, message: str, hint: str | None = None, tok: Token | None = None
    ) -> BuzzCompileError:
        path, line, col = (tok or self.tok).where
        return BuzzCompileError(path, line, col, message, hint)

    def expect(self, kind: Tok) -> None:
        if self.tok.kind is not kind:
            raise self.error(
                f"Syntax error: expected {kind.value}, found {self.tok.kind.value}",
                _expect_hint(kind, self.tok),
            )

    def annotate(self, text: str) -> str:
        tok = self.tok
        return f"{text}\t|{tok.line},{tok.col},{tok.file}"

    def emit(self, text: str, at: Token | None = None) -> None:
        """Append a .basm line; `at` is the token of the operation it performs."""
        self.chunk.code.append((self.annotate(text), self.stmt_pos if at is None else at.where))

    def enter(self) -> None:
        self.nesting += 1
        if self.nesting > MAX_NESTING:
            raise self.error(
                f"program nested too deeply (more than {MAX_NESTING} levels)",
                "split the expression or block into smaller functions",
            )

    def intern(self, text: str) -> int:
        sid = self.string_ids.get(text)
        if sid is None:
            sid = self.string_ids[text] = len(self.strings)
            self.strings.append(text)
        return sid

    def new_label(self) -> int:
        self.labels += 1
        return self.labels - 1

    def new_chunk(self, function_sid: int | None = None) -> _Chunk:
        chunk = _Chunk(self.new_label(), function_sid)
        self.chunks.append(chunk)
        return chunk

    # -- symbols (docs/language.md#scopes) -------------------------------------------------------

    def lookup(self, name: str) -> _Sym | None:
        for table in reversed(self.symstack):
            sym = table.get(name)
            if sym is not None:
                return sym
        return None

    def resolve(self, name: str) -> _Sym:
        """The symbol a name refers to; unknown names become globals (string id now)."""
        sym = self.lookup(name)
        if sym is None:
            sym = self.symstack[0][name] = _Sym(True, self.intern(name))
        return sym

    def add_local(self, name: str) -> _Sym:
        top = self.symstack[-1]
        sym = top[name] = _Sym(False, len(top))
        return sym

    def push_scope(self, fresh_with_self: bool) -> None:
        """A function table (`self` in slot 0), or a block or lambda table (docs/language.md)."""
        if fresh_with_self:
            self.symstack.append({"self": _Sym(False, 0)})
        elif len(self.symstack) == 1:
            self.symstack.append({})
        else:
            self.symstack.append(dict(self.symstack[-1]))

    # -- program structure -------------------------------------------------------

    def script(self) -> str:
        self.fetch()
        if self.tok.kind is Tok.EOF:
            return "!0\n\n\tnop\n"
        self.symstack.append({})
        self.chunk = self.new_chunk()
        self.statlist()
        if self.tok.kind is Tok.BLOCKCLOSE:
            raise self.error(
                "Syntax error: unexpected } at top level",
                "this closes no block; the reference silently ignores the rest of the file",
            )
        self.emit("\n@__exitpoint")
        self.emit("\tdone")
        return self.render()

    def render(self) -> str:
        out = [f"!{len(self.strings)}"]
        out += [f"'{s}" for s in self.strings]
        out.append("")
        for chunk in self.chunks:
            if chunk.function_sid is not None:
                out.append(f"\tpushs {chunk.function_sid}")
                out.append(f"\tpushcn @__label_{chunk.label}")
                out.append("\tgstore")
        out.append("\tnop")
        lineno = len(out)  # .basm lines so far (the next one is lineno + 1)
        marks = self.marks
        for k, chunk in enumerate(self.chunks):
            out.append("")
            out.append(f"@__label_{chunk.label}")
            lineno += 2
            if k:  # chunk 0 is the global code, no function
                marks.functions.append((f"@__label_{chunk.label}", chunk.name, chunk.where))
            for text, pos in chunk.code:
                out.append(text)
                lineno += text.count("\n") + 1  # "\n@__exitpoint" is two lines
                if pos is not None:
                    marks.positions[lineno] = pos
        return "\n".join(out) + "\n"

    def statlist(self) -> None:
        while self.tok.kind is not Tok.EOF and self.tok.kind is not Tok.BLOCKCLOSE:
            self.statement()

    def statement(self) -> None:
        self.enter()
        outer, self.stmt_pos = self.stmt_pos, self.tok.where
        kind = self.tok.kind
        if kind is Tok.VAR:
            self.var_decl()
        elif kind is Tok.FUNCTION:
            self.function_def()
        elif kind is Tok.IF:
            self.if_stat()
        elif kind is Tok.WHILE:
            self.while_stat()
        elif kind is Tok.FOR:
            self.for_stat()
        else:
            self.command()
        self.stmt_pos = outer
        self.nesting -= 1

    def block(self) -> None:
        self.expect(Tok.BLOCKOPEN)
        self.fetch()
        top = self.symstack[-1]
        start = len(top)
        self.statlist()
        self.expect(Tok.BLOCKCLOSE)
        self.fetch()
        dropped = [name for name, sym in top.items() if not sym.is_global and sym.pos >= start]
        for name in dropped:
            del top[name]
        if dropped:
            self.emit(f"\tlremove {len(dropped)}")

    def body(self) -> None:
        """The body of if/else/while/for: a block gets its own symbol table."""
        if self.tok.kind is Tok.BLOCKOPEN:
            self.push_scope(fresh_with_self=False)
            self.block()
            self.symstack.pop()
        else:
            self.statement()

    def idlist(self) -> None:
        """Parameters; one that already names a local aliases it (docs/language.md#scopes)."""
        if self.tok.kind is not Tok.ID:
            return
        while True:
            sym = self.lookup(self.tok.text)
            if sym is None or sym.is_global:
                self.add_local(self.tok.text)
            self.fetch()
            if not self.at(Tok.COMMA):
                return
            self.fetch()
            self.expect(Tok.ID)

    # -- statements --------------------------------------------------------------

    def var_decl(self) -> None:
        self.fetch()
        self.expect(Tok.ID)
        name = self.tok.text
        name_tok = self.tok
        if len(self.symstack) == 1:
            sym = self.resolve(name)
            self.emit(f"\tpushs {sym.pos}", name_tok)
            self.fetch()
            if self.tok.kind is Tok.ASSIGN:
                self.fetch()
                self.name_lambda(name)
                self.expression()
            else:
                self.emit("\tpushnil")
            self.emit("\tgstore", name_tok)
            return
        found = self.lookup(name)
        if found is not None and not found.is_global:
            raise self.error(
                f"Duplicated symbol '{name}'", "a local of this name is already in scope"
            )
        slot = self.add_local(name).pos
        self.fetch()
        if self.tok.kind is Tok.ASSIGN:
            self.emit("\tpushnil")
            self.emit(f"\tlstore {slot}", name_tok)
            self.fetch()
            self.name_lambda(name)
            self.expression()
        else:
            self.emit("\tpushnil")
        self.emit(f"\tlstore {slot}", name_tok)

    def name_lambda(self, name: str) -> None:
        """The value about to be parsed is `name`'s: a lambda there is named so."""
        if self.tok.kind is Tok.FUNCTION:
            self.lambda_name = name

    def function_def(self) -> None:
        keyword = self.tok
        self.fetch()
        self.expect(Tok.ID)
        name = self.tok.text
        if len(self.symstack) > 1:
            raise self.error(
                f"Syntax error: the definition of function {name}() is nested within another scope",
                f"named functions are top-level only; use a lambda: "
                f"var {name} = function(...) {{...}}",
            )
        sid = self.resolve(name).pos
        outer, self.chunk = self.chunk, self.new_chunk(function_sid=sid)
        self.chunk.name, self.chunk.where = name, keyword.where
        self.fetch()
        self.expect(Tok.PAROPEN)
        self.push_scope(fresh_with_self=True)
        self.fetch()
        self.idlist()
        self.expect(Tok.PARCLOSE)
        self.fetch()
        if self.tok.kind is Tok.STRING:  # docstring, discarded
            self.fetch()
        self.block()
        self.emit("\tret0")
        self.symstack.pop()
        self.chunk = outer

    def if_stat(self) -> None:
        l_else, l_end = self.new_label(), self.new_label()
        keyword = self.tok
        self.fetch()
        self.expect(Tok.PAROPEN)
        self.fetch()
        self.condition()
        self.expect(Tok.PARCLOSE)
        self.fetch()
        self.emit(f"\tjumpz @__label_{l_else}", keyword)
        self.body()
        if self.tok.kind is Tok.ELSE:
            self.fetch()
            self.emit(f"\tjump @__label_{l_end}")
            self.emit(f"@__label_{l_else}")
            self.body()
            self.emit(f"@__label_{l_end}")
        else:
            self.emit(f"@__label_{l_else}")

    def while_stat(self) -> None:
        l_start, l_end = self.new_label(), self.new_label()
        keyword = self.tok  # where a loop's budget error points
        self.fetch()
        self.expect(Tok.PAROPEN)
        self.fetch()
        self.emit(f"@__label_{l_start}")
        self.condition()
        self.expect(Tok.PARCLOSE)
        self.fetch()
        self.emit(f"\tjumpz @__label_{l_end}", keyword)
        self.body()
        self.emit(f"\tjump @__label_{l_start}", keyword)
        self.emit(f"@__label_{l_end}")

    def for_stat(self) -> None:
        l_cond, l_update, l_body, l_end = (self.new_label() for _ in range(4))
        keyword = self.tok  # where a loop's budget error points
        self.fetch()
        self.expect(Tok.PAROPEN)
        self.fetch()
        self.command_follow = Tok.COMMA
        self.command()
        self.expect(Tok.COMMA)
        self.fetch()
        self.emit(f"@__label_{l_cond}")
        self.condition()
        self.expect(Tok.COMMA)
        self.fetch()
        self.emit(f"\tjumpnz @__label_{l_body}", keyword)
        self.emit(f"\tjump @__label_{l_end}", keyword)
        self.emit(f"@__label_{l_update}")
        self.command_follow = Tok.PARCLOSE
        self.command()
        self.expect(Tok.PARCLOSE)
        self.fetch()
        self.emit(f"\tjump @__label_{l_cond}", keyword)
        self.emit(f"@__label_{l_body}")
        self.body()
        self.emit(f"\tjump @__label_{l_update}", keyword)
        self.emit(f"@__label_{l_end}")

    def command(self) -> None:
        follow, self.command_follow = self.command_follow, None
        if self.tok.kind is Tok.RETURN:
            self.return_stat(follow)
            return
        first = self.index
        ref = self.idref(lvalue=True)
        link = self.last_link
        if self.tok.kind is Tok.ASSIGN:
            if ref == _CLOSURE:
                raise self.error("Syntax error: can't have a function call as lvalue")
            if isinstance(ref, _Sym) and ref.is_global:
                self.emit(f"\tpushs {ref.pos}", link)
            target = "".join(self.tokens[i].text for i in range(first, self.index))
            self.fetch()
            self.name_lambda(target)
            self.expression()
            if isinstance(ref, _Sym):
                self.emit("\tgstore" if ref.is_global else f"\tlstore {ref.pos}", link)
            else:
                self.emit("\ttput", link)
        elif ref == _CLOSURE:
            self.emit("\tpop")
        else:
            raise self.error(
                "Syntax error: expected function call or assignment",
                "a statement must assign (x = ...) or call (f(...))",
            )

    def return_stat(self, follow: Tok | None) -> None:
        keyword = self.tok
        self.fetch()
        if self.tok.kind is Tok.BLOCKCLOSE:
            self.emit("\tret0", keyword)
            return
        # Deliberate fix: a value on a later line may be the next statement, which
        # the reference swallows. Parse greedily like the reference; if that fails,
        # or ends where the reference is bound to fail, undo it and return bare.
        # (Not before EOF: a top-level `return` at the end stays the reference's error.)
        if not self.tok.newline_before or self.tok.kind is Tok.EOF:
            self.condition()
            self.emit("\tret1", keyword)
            return
        snap = self.snapshot()
        try:
            self.condition()
            after = self.tok
            if after.kind not in _STATEMENT_START and after.kind not in _STATEMENT_FOLLOW:
                # The reference fails right here, with the error it would give next.
                raise self.error(
                    f"Syntax error: expected {(follow or Tok.ID).value}, found {after.kind.value}",
                    _expect_hint(follow or Tok.ID, after),
                )
        except BuzzCompileError as exc:
            reached = self.index
            self.restore(snap)
            self.fallbacks.append((reached, exc))
            self.emit("\tret0", keyword)
            return
        self.emit("\tret1", keyword)

    def snapshot(self) -> _Snapshot:
        return _Snapshot(
            self.index,
            self.chunk,
            len(self.chunk.code),
            len(self.chunks),
            len(self.strings),
            self.labels,
            [(table, dict(table)) for table in self.symstack],
            self.nesting,
            len(self.fallbacks),
        )

    def restore(self, snap: _Snapshot) -> None:
        # In place: callers up the stack hold references to the chunk and the tables.
        self.index = snap.index
        self.tok = self.tokens[snap.index]
        self.chunk = snap.chunk
        del self.chunk.code[snap.code_len :]
        del self.chunks[snap.chunks_len :]
        for text in self.strings[snap.strings_len :]:
            del self.string_ids[text]
        del self.strings[snap.strings_len :]
        self.labels = snap.labels
        self.symstack[:] = [table for table, _ in snap.tables]
        for table, contents in snap.tables:
            table.clear()
            table.update(contents)
        self.nesting = snap.nesting
        del self.fallbacks[snap.fallbacks_len :]

    # -- expressions -------------------------------------------------------------

    def condition(self) -> None:
        if self.tok.kind is Tok.LNOT:
            self.enter()
            optok = self.tok
            self.fetch()
            self.condition()
            self.emit("\tlnot", optok)
            self.nesting -= 1
            return
        self.comparison()
        while self.tok.kind is Tok.LANDOR:
            op = "land" if self.tok.text == "and" else "lor"
            optok = self.tok
            self.fetch()
            self.comparison()
            self.emit(f"\t{op}", optok)

    def comparison(self) -> None:
        self.expression()
        if self.tok.kind is Tok.CMP:
            op = _BINOPS[self.tok.text]
            optok = self.tok
            self.fetch()
            self.expression()
            self.emit(f"\t{op}", optok)

    def expression(self) -> None:
        self.enter()
        if self.tok.kind is Tok.BLOCKOPEN:
            self.table_literal()
        else:
            self.product()
            while self.tok.kind is Tok.ADDSUB:
                op = _BINOPS[self.tok.text]
                optok = self.tok
                self.fetch()
                self.product()
                self.emit(f"\t{op}", optok)
        self.nesting -= 1

    def product(self) -> None:
        self.modulo()
        while self.tok.kind is Tok.MULDIV:
            op = _BINOPS[self.tok.text]
            optok = self.tok
            self.fetch()
            self.modulo()
            self.emit(f"\t{op}", optok)

    def modulo(self) -> None:
        self.power()
        while self.tok.kind is Tok.MOD:
            optok = self.tok
            self.fetch()
            self.power()
            self.emit("\tmod", optok)

    def power(self) -> None:
        self.bitshift()
        if self.tok.kind is Tok.POW:
            self.enter()
            optok = self.tok
            self.fetch()
            self.power()
            self.emit("\tpow", optok)
            self.nesting -= 1

    def bitshift(self) -> None:
        self.bitandor()
        while self.tok.kind is Tok.LRSHIFT:
            op = _BINOPS[self.tok.text]
            optok = self.tok
            self.fetch()
            self.bitandor()
            self.emit(f"\t{op}", optok)

    def bitandor(self) -> None:
        self.bitnot()
        while self.tok.kind is Tok.BANDOR:
            op = _BINOPS[self.tok.text]
            optok = self.tok
            self.fetch()
            self.bitnot()
            self.emit(f"\t{op}", optok)

    def bitnot(self) -> None:
        if self.tok.kind is Tok.BNOT:
            self.enter()
            optok = self.tok
            self.fetch()
            self.bitnot()
            self.emit("\tbnot", optok)
            self.nesting -= 1
        else:
            self.operand()

    def operand(self) -> None:
        tok = self.tok
        kind = tok.kind
        if kind is Tok.FUNCTION:
            self.lambda_()
        elif kind is Tok.NIL:
            self.emit("\tpushnil")
            self.fetch()
        elif kind is Tok.CONST:
            self.emit(_push_const(tok.text))
            self.fetch()
        elif kind is Tok.STRING:
            self.emit(f"\tpushs {self.string_literal()}")
            self.fetch()
        elif kind is Tok.PAROPEN:
            self.fetch()
            self.condition()
            self.expect(Tok.PARCLOSE)
            self.fetch()
        elif kind is Tok.ADDSUB:
            self.enter()
            sign = tok.text
            self.fetch()
            if self.tok.kind is Tok.CONST:
                self.emit(_push_const(sign + self.tok.text))
                self.fetch()
            else:
                self.power()
                if sign == "-":
                    self.emit("\tunm", tok)
            self.nesting -= 1
        else:
            self.idref(lvalue=False)

    def string_literal(self) -> int:
        text = self.tok.text
        if "\n" in text:
            raise self.error(
                "string literal contains a newline, which Buzz assembly cannot represent",
                "the reference would produce an unassemblable .basm; build the string with "
                "string.concat or log several values instead",
            )
        if "\0" in text:
            raise self.error(
                "string literal contains a NUL byte, which .bo string tables cannot hold"
            )
        return self.intern(text)

    def lambda_(self) -> None:
        keyword = self.tok
        name, self.lambda_name = self.lambda_name, None
        self.emit(f"\tpushl @__label_{self.labels}", keyword)
        self.fetch()
        outer, self.chunk = self.chunk, self.new_chunk()
        self.chunk.name, self.chunk.where = name, keyword.where
        self.expect(Tok.PAROPEN)
        self.push_scope(fresh_with_self=len(self.symstack) == 1)
        self.fetch()
        self.idlist()
        self.expect(Tok.PARCLOSE)
        self.fetch()
        self.block()
        self.emit("\tret0")
        self.symstack.pop()
        self.chunk = outer

    def table_literal(self) -> None:
        self.fetch()
        if self.tok.kind is not Tok.DOT and self.tok.kind is not Tok.BLOCKCLOSE:
            raise self.error(
                "Syntax error: expected .id = expression or }",
                "table fields are written { .key = value, .3 = value }",
            )
        self.emit("\tpusht")
        if self.tok.kind is Tok.DOT:
            self.table_field()
            while self.at(Tok.COMMA):
                self.emit("\tdup")
                self.fetch()
                self.expect(Tok.DOT)
                self.table_field(dup=False)
        self.expect(Tok.BLOCKCLOSE)
        self.fetch()

    def table_field(self, dup: bool = True) -> None:
        if dup:
            self.emit("\tdup")
        dot = self.tok
        self.fetch()
        key = self.tok.text
        if self.tok.kind is Tok.ID:
            self.emit(f"\tpushs {self.intern(self.tok.text)}")
        elif self.tok.kind is Tok.CONST:
            self.emit(_push_const(self.tok.text))
        else:
            raise self.error(
                f"Syntax error: expected identifier or constant, found {self.tok.kind.value}",
                "table keys are .name or .number",
            )
        self.fetch()
        self.expect(Tok.ASSIGN)
        self.fetch()
        self.name_lambda(key)
        self.expression()
        self.emit("\ttput", dot)

    def call_args(self) -> int:
        count = 0
        if self.tok.kind is not Tok.PARCLOSE:
            self.condition()
            count = 1
            while self.tok.kind is Tok.COMMA:
                self.fetch()
                self.condition()
                count += 1
        self.expect(Tok.PARCLOSE)
        return count

    def idref(self, lvalue: bool) -> _Ref:
        """An identifier chain `a.b[c](d)...` (docs/language.md#identifier-chains)."""
        code = self.chunk.code
        start = len(code)  # end of O: the self slot of a chained call goes here
        self.expect(Tok.ID)
        # Where each operation points: a load at its name, an index at its `.` or `[`,
        # a call at the start of the chain (its callee, as written).
        first = link = self.tok
        ref: _Ref = self.resolve(self.tok.text)
        self.fetch()
        while self.tok.kind in (Tok.DOT, Tok.IDXOPEN, Tok.PAROPEN):
            self.load(ref, link, first)
            link = self.tok
            if self.tok.kind is Tok.DOT:
                ref = _TABLE
                self.fetch()
                self.expect(Tok.ID)
                sid = self.intern(self.tok.text)
                self.fetch()
                if self.at(Tok.PAROPEN):
                    self.emit("\tdup")
                self.emit(f"\tpushs {sid}")
            elif self.tok.kind is Tok.IDXOPEN:
                ref = _TABLE
                self.fetch()
                index_start = len(code)
                self.expression()
                self.expect(Tok.IDXCLOSE)
                self.fetch()
                if self.at(Tok.PAROPEN):
                    code.insert(index_start, (self.annotate("\tdup"), self.stmt_pos))
            else:
                ref = _CLOSURE
                self.fetch()
                count = self.call_args()
                self.fetch()
                if self.tok.kind is Tok.PAROPEN:
                    code.insert(start, (self.annotate("\tpushnil"), self.stmt_pos))
                self.emit(f"\tpushi {count}")
        self.last_link = link
        if not lvalue or ref == _CLOSURE:
            self.load(ref, link, first)
        return ref

    def load(self, ref: _Ref, link: Token, first: Token) -> None:
        """Turn the pending reference into a value (a nil self slot before a call);
        `link` is the token of the reference, `first` the start of its chain."""
        if isinstance(ref, _Sym):
            if self.tok.kind is Tok.PAROPEN:
                self.emit("\tpushnil")
            if ref.is_global:
                self.emit(f"\tpushs {ref.pos}", link)
                self.emit("\tgload", link)
            else:
                self.emit(f"\tlload {ref.pos}", link)
        elif ref == _TABLE:
            self.emit("\ttget", link)
        else:
            self.emit("\tcallc", first)


def _push_const(text: str) -> str:
    return f"\tpushf {text}" if "." in text else f"\tpushi {text}"


def _expect_hint(kind: Tok, found: Token) -> str | None:
    if kind is Tok.ID and found.kind is Tok.CMP:
        return "a comparison is not an expression here: parenthesize it, e.g. x = (a == b)"
    if kind is Tok.ID and found.kind is Tok.BLOCKOPEN:
        return "a statement cannot start with '{'; table literals go on the right of '='"
    if kind is Tok.ID and found.kind is Tok.LNOT:
        return "'not' only starts a condition: write a and (not b)"
    if found.kind is Tok.EOF:
        return "the program ends in the middle of a construct"
    return None


def compile_asm(source: bytes, path: str, include_dirs: Sequence[str] = ()) -> str:
    """Compile Buzz source to .basm text exactly as the reference `bzzparse` does
    (see `compile_marked`)."""
    return compile_marked(source, path, include_dirs)[0]


def compile_marked(source: bytes, path: str, include_dirs: Sequence[str] = ()) -> tuple[str, Marks]:
    """Compile Buzz source to .basm text exactly as the reference `bzzparse` does, with
    the marks of the source map (the true position of each instruction line).

    The text holds one character per byte (latin-1), like every Buzz string in
    this project: write it with `encoding="latin-1"` to get the reference bytes.

    Return fallback (deliberate fix): a `return` whose value starts on a later
    line is parsed greedily like the reference; when that parse fails, or ends on
    a token after which the reference must fail, it is undone and the `return`
    compiles bare (`ret0`). If the program then fails no further on than the
    greedy parse did, the greedy (reference) error is reported.
    """
    compiler = _Compiler(TokenStream(Lexer(source, path, include_dirs)))
    try:
        return compiler.script(), compiler.marks
    except BuzzCompileError as exc:
        error = exc
    except RecursionError:
        error = compiler.error("program nested too deeply", "split it into smaller functions")
    # A fallback that got no further than its greedy parse did not help: the
    # reference's (greedy) error is the one that explains the program.
    for reached, original in reversed(compiler.fallbacks):
        if compiler.index <= reached:
            raise original from None
    raise error


def compile_file(path: str, include_dirs: Sequence[str] = ()) -> str:
    """Read a .bzz file and compile it to .basm text."""
    with open(path, "rb") as f:
        return compile_asm(f.read(), path, include_dirs)


def compile_to_asm_file(src_path: str, out_path: str, include_dirs: Sequence[str] = ()) -> None:
    """Compile `src_path` and write the .basm to `out_path` byte-exactly."""
    text = compile_file(src_path, include_dirs)
    with open(out_path, "w", encoding="latin-1", newline="") as f:
        f.write(text)


def build(source: bytes, path: str, include_dirs: Sequence[str] = ()) -> tuple[bytes, bytes]:
    """Compile and assemble in one go: returns (.bo, .bdb) bytes, like `bzzc`."""
    from bvm.assembler import assemble

    return assemble(compile_asm(source, path, include_dirs), os.fspath(path))
