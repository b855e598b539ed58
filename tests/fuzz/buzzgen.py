"""Random but valid Buzz source programs, from the grammar of docs/language.md#grammar.

`generate_program(chooser)` returns a `GeneratedProgram`: the source text plus the global
functions it defines (name and parameter count), which the differential oracle calls a
second time with ints, floats and strings.

Programs always terminate quickly:

* every loop has a counter that no other code assigns and a small literal trip count
  (global counters at top level, one per loop; `var` counters inside functions), and the
  counter is stepped first thing in a `while` body so no branch can skip it;
* calls are ranked: function `fN` may call only functions and lambdas of lower rank,
  top-level lambdas (method tables, callbacks) call no user function at all, and the one
  recursive function recurses on an explicit depth argument, called with a small depth.

Values cover int32 edge values, binary32 edge values (0.0, -0.0, huge, denormal), strings
that look like numbers, nil, tables (literals with identifier and number keys, nested),
closures (lambdas capturing locals, methods using `self`), and every operator.

Variables have a *kind* (int, float, num = int or float, str, table, closure) and
expressions are built to match, so most programs run to the end; a per-program `chaos`
level (zero for most programs) adds wrong-typed operands and wrong argument counts, so
runtime errors also occur, to compare their messages and offsets. Loops assign `num`
variables both ints and floats, and functions are called with ints at some call sites
and floats at others, to exercise the translator's type inference and specialization.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .choosers import Chooser

INT_LITERALS = [
    "0", "1", "2", "3", "7", "10", "-1", "-2", "100", "255", "65535", "65536",
    "2147483647", "-2147483647", "-2147483648", "2147483648", "4294967295", "4294967296",
    "1073741824", "16777217", "-16777217", "99999999999", "007", "31", "32", "33",
]  # fmt: skip
SMALL_INTS = ["0", "1", "2", "3", "-1", "5", "7"]
FLOAT_LITERALS = [
    "0.0", "1.5", "-0.0", "2.5", "-1.5", "0.5", "3.14", "1.", "1..2", "1.2.3", "100.25",
    "16777217.0", "0.1", "-0.1", "2147483648.0", "-2147483649.0", "4294967296.5",
    "340282346638528859811704183484516925440.0", "999999999999999999999999999999999999999.0",
    "0.000000000000000000000000000000000000000000001", "0.00000000000000000000000000000000000001",
    "123456.789",
]  # fmt: skip
STRING_LITERALS = [
    '""', '"a"', '"abc"', "'b'", '"c"', '"1"', '"-1"', '"1.000000"', '"0.5"', '" 12x"', '"inf"',
    '"nan"', '"x"', '"val"', '"a b"', '"99999999999"', '"0x10"', '"1e3"', '"-0.000000"', "'Z'",
    '"a\\tb"', '"q\\"q"', '"\\\\"', '"2147483647"', '"-2147483648"',
]  # fmt: skip
LONG_STRINGS = ['"abc"', '"hello"', '"1.000000"', '"a b c"', '" 12x"', '"xyzzy"']
NUMERIC_STRINGS = ['"1"', '"-1"', '" 12x"', '"99999999999"', '"0x10"', '"1e3"', '"7"']
# Globals named like Python keywords and builtins exercise the translator's name mapping.
DATA_GLOBALS = [
    "a", "b", "x", "y", "s", "w", "None", "class", "print", "len", "True", "lambda", "pass",
    "str", "is", "def", "range", "global", "sum", "self",
]  # fmt: skip
TABLE_GLOBALS = ["t", "u", "dict", "tab", "False"]
FIELDS = ["x", "y", "val", "k", "n", "in"]
NUM_KEYS = ["0", "1", "2", "3", "7", "2.5", "1.0", "10"]
# Library functions replaced by the script: the translator inlines some of them.
OVERRIDES = [
    "size = function(x) { return 42 }",
    "size = string.length",
    "string.length = size",
    "string.length = function(x) { return -1 }",
    "string.sub = string.concat",
    "string.concat = function(a, b) { return 7 }",
    "string.tostring = type",
    "string = {.length = size, .sub = math.max, .concat = math.min, .tostring = math.abs}",
    "math.abs = math.floor",
    "math = {.abs = size, .floor = string.length, .pi = 3}",
    "type = isint",
    "size = nil",
    "isnil = isint",
]
# Library calls with wrong argument types or counts (error messages and offsets).
MISUSES = [
    "string.length(5)", "string.length()", "string.length(\"a\", \"b\")", "size(\"x\")",
    "size()", "size({}, {})", "string.sub(\"abc\")", "string.sub(5, 1)", "string.sub(\"abc\", 1.5)",
    "string.sub(\"abc\", -1)", "string.sub(\"abc\", 2, -1)", "string.sub(\"abc\", 0, 2147483647)",
    "string.concat(\"a\")", "string.concat(\"a\", 5)", "string.concat(1, 2)",
    "string.tostring()", "string.tostring({})", "string.tostring(nil)", "string.tostring(-0.0)",
    "string.toint(5)", "string.tofloat(\"1e3\")", "int(\"1\")", "float(\"1\")", "math.abs(\"1\")",
    "math.min(nil, 1)", "math.max(1)", "math.sqrt(-1)", "math.log(0)", "math.floor(3000000000.0)",
    "math.round(-2.5)", "math.rng.uniform(1, 2, 3)", "math.rng.gaussian(1)", "clone()",
    "foreach({}, 5)", "map(5, size)", "reduce({.a = 1}, function(k, v, a) { return a + v }, 0)",
    "filter({.a = 1, .b = 0}, function(k, v) { return v })", "type()", "isnil(1, 2)",
]  # fmt: skip

VALUE_KINDS = ["int", "float", "num", "str", "table", "nil", "closure"]
SCALAR_KINDS = ["int", "float", "num", "str"]


@dataclass
class Var:
    """A variable the generator knows about."""

    name: str
    kind: str
    assignable: bool = True


@dataclass
class Ctx:
    """Where code is being generated: visible locals, call rank, function or top level."""

    locals: list[Var]
    rank: int  # user functions of lower rank may be called
    in_function: bool
    top_block: bool = False  # inside a block at top level (the "top-level block trap")
    method: bool = False  # `self` is a method table
    loop: bool = False  # inside a loop body

    def child(self, *, top_block: bool | None = None, loop: bool | None = None) -> Ctx:
        """A nested block: same visibility, locals added inside stay inside."""
        return Ctx(
            list(self.locals),
            self.rank,
            self.in_function,
            self.top_block if top_block is None else top_block,
            self.method,
            self.loop if loop is None else loop,
        )


@dataclass
class Function:
    """A global function the program defines (for the second round of calls)."""

    name: str
    nparams: int
    kinds: list[str] = field(default_factory=list)
    recursive: bool = False


@dataclass
class GeneratedProgram:
    """A generated Buzz program and the functions it defines."""

    source: str
    functions: list[Function] = field(default_factory=list)


class BuzzGen:
    """One program's generator state."""

    def __init__(self, ch: Chooser, *, max_statements: int = 60, max_depth: int = 3) -> None:
        self.ch = ch
        self.budget = max_statements
        self.max_depth = max_depth
        self.serial = 0
        # Most programs are type-correct; some have a few wrong-typed operands.
        self.chaos = ch.choice([0.0, 0.0, 0.0, 0.005, 0.02, 0.06])
        self.globals: list[Var] = []
        self.tables: list[Var] = []
        self.methods: list[tuple[str, str, list[str]]] = []  # (table, method, param kinds)
        self.functions: list[tuple[Function, int]] = []  # with their rank
        self.lambdas: list[Function] = []  # global variables holding top-level lambdas
        self.rec: Function | None = None
        self.rec_rank = 0

    def fresh(self, prefix: str) -> str:
        """A name used nowhere else in the program."""
        self.serial += 1
        return f"{prefix}{self.serial}"

    def wrong(self) -> bool:
        """Whether to deliberately break typing here."""
        return self.chaos > 0 and self.ch.chance(self.chaos)

    # ------------------------------------------------------------ program

    def program(self) -> GeneratedProgram:
        """Generate a whole program."""
        ch = self.ch
        lines: list[str] = []
        for name in _sample(ch, DATA_GLOBALS, ch.integer(1, 6)):
            v = Var(name, ch.choice(SCALAR_KINDS))
            lines.append(f"{name} = {self.literal(v.kind)}")
            self.globals.append(v)
        top = Ctx([], 0, False)
        self.tables = [Var(n, "table", False) for n in _sample(ch, TABLE_GLOBALS, ch.integer(1, 2))]
        for v in list(self.tables):
            lines.append(f"{v.name} = {self.table_literal(top, 1)}")
        if ch.chance(0.5):
            lines += self.method_table()
        for _ in range(ch.integer(0, 2) if ch.chance(0.4) else 0):
            lines += self.global_lambda()
        if ch.chance(0.05):  # replaced by the library at load time (docs/bytecode.md#loading)
            lines.append("function size(x) { return 99 }")
        nfun = ch.integer(0, 4)
        for rank in range(1, nfun + 1):
            lines += self.function(rank)
        if ch.chance(0.4):
            lines += self.recursive(nfun + 1)
        main = Ctx([], nfun + 2, False)
        body: list[str] = []
        while self.budget > 0 and len(body) < 30:
            body += self.statement(main, 0)
            if ch.chance(0.07):
                break
        lines += body
        funcs = [f for f, _ in self.functions] + self.lambdas
        if self.rec is not None:
            funcs.append(self.rec)
        return GeneratedProgram("\n".join(lines) + "\n", funcs)

    def method_table(self) -> list[str]:
        """`obj = {.val = n, .get = function() {...}, ...}`: methods that use `self`."""
        ch = self.ch
        name = self.fresh("obj")
        fields = [f".val = {ch.choice(SMALL_INTS)}"]
        methods: list[tuple[str, str, list[str]]] = []
        for m in _sample(ch, ["get", "add", "twice", "describe", "setx"], ch.integer(1, 4)):
            if m == "get":
                fields.append(".get = function() { return self.val }")
                methods.append((name, m, []))
            elif m == "add":
                p = self.fresh("p")
                fields.append(
                    f".add = function({p}) {{ self.val = self.val + {p} return self.val }}"
                )
                methods.append((name, m, ["num"]))
            elif m == "twice":
                fields.append(".twice = function() { return self.val * 2 }")
                methods.append((name, m, []))
            elif m == "setx":
                p = self.fresh("p")
                fields.append(f".setx = function({p}) {{ self.x = {p} return self }}")
                methods.append((name, m, ["any"]))
            else:
                p = self.fresh("p")
                ctx = Ctx([Var(p, "int")], 0, True, method=True)
                body = self.block(ctx, 2)
                fields.append(f".describe = function({p}) {{ {' '.join(body)} return self }}")
                methods.append((name, m, ["int"]))
        self.tables.append(Var(name, "table", assignable=False))
        self.methods += methods
        return [f"{name} = {{{', '.join(fields)}}}"]

    def global_lambda(self) -> list[str]:
        """`lamN = function(p...) {...}`: callable from ranked code, calls nothing itself."""
        ch = self.ch
        name = self.fresh("lam")
        kinds = [ch.choice(["int", "num", "str"]) for _ in range(ch.integer(0, 2))]
        params = [Var(self.fresh("p"), k) for k in kinds]
        ctx = Ctx(list(params), 0, True)
        body = self.block(ctx, 1)
        ret = self.cond(ctx, 1)
        self.lambdas.append(Function(name, len(params), kinds))
        head = f"{name} = function({', '.join(p.name for p in params)}) {{"
        return [head, *_indent(body + [f"return {ret}"]), "}"]

    def function(self, rank: int) -> list[str]:
        """`function fN(params) { ... return ... }`."""
        ch = self.ch
        name = f"f{rank}"
        kinds = [ch.choice(["int", "float", "num", "str", "int"]) for _ in range(ch.integer(0, 3))]
        params = [Var(self.fresh("a"), k) for k in kinds]
        ctx = Ctx(list(params), rank, True)
        body = self.block(ctx, 1)
        if ch.chance(0.85):
            ret_kind = ch.choice(["int", "float", "num", "str", "cond"])
            if ret_kind == "cond":
                body.append(f"return {self.cond(ctx, 2)}")
            else:
                body.append(f"return {self.expr(ctx, ret_kind, 2)}")
        doc = ' "docstring"' if ch.chance(0.1) else ""
        self.functions.append((Function(name, len(params), kinds), rank))
        head = f"function {name}({', '.join(p.name for p in params)}){doc} {{"
        return [head, *_indent(body), "}"]

    def recursive(self, rank: int) -> list[str]:
        """A recursive function with an explicit depth argument."""
        ch = self.ch
        n, acc = self.fresh("n"), self.fresh("acc")
        acc_kind = ch.choice(["int", "float", "num", "str"])
        ctx = Ctx([Var(n, "int", assignable=False), Var(acc, acc_kind)], rank, True)
        body = self.block(ctx, 2)
        step = self.expr(ctx, acc_kind, 2)
        self.rec = Function("rec", 2, ["int", acc_kind], recursive=True)
        self.rec_rank = rank
        return [
            f"function rec({n}, {acc}) {{",
            f"  if ({n} <= 0) {{ return {acc} }}",
            *_indent(body),
            f"  return rec({n} - 1, {step})",
            "}",
        ]

    # ------------------------------------------------------------ statements

    def block(self, ctx: Ctx, depth: int) -> list[str]:
        """A few statements."""
        out: list[str] = []
        for _ in range(self.ch.integer(1, 4)):
            if self.budget <= 0:
                break
            out += self.statement(ctx, depth)
        return out

    def assignable(self, ctx: Ctx) -> list[Var]:
        return [v for v in ctx.locals + self.globals if v.assignable]

    def statement(self, ctx: Ctx, depth: int) -> list[str]:
        """One statement (possibly compound)."""
        ch = self.ch
        self.budget -= 1
        deep = depth >= self.max_depth or self.budget <= 0
        options = ["log", "log", "assign", "assign", "assign", "tableput", "call", "library"]
        if ctx.loop:
            options += ["accumulate", "accumulate"]
        if ctx.in_function or (ctx.top_block and ch.chance(0.1)):
            options += ["var", "var"]
        if not deep:
            options += ["if", "if", "while", "for", "foreach"]
        if ctx.in_function:
            options.append("return")
        what = ch.choice(options)
        if what == "log":
            args = [self.arg(ctx) for _ in range(ch.integer(1, 3))]
            return [f"log({', '.join(args)})"]
        if what == "assign":
            targets = self.assignable(ctx)
            if not targets:
                return [f"log({self.arg(ctx)})"]
            v = ch.choice(targets)
            kind = v.kind
            if kind == "num":
                kind = ch.choice(["int", "float"])
            if self.wrong():
                kind = ch.choice(VALUE_KINDS)
            return [f"{v.name} = {self.expr(ctx, kind, 2)}"]
        if what == "accumulate":
            nums = [v for v in self.assignable(ctx) if v.kind in ("int", "num", "str")]
            if not nums:
                return [f"log({self.arg(ctx)})"]
            v = ch.choice(nums)
            if v.kind == "str":
                return [f"{v.name} = string.concat({v.name}, {self.expr(ctx, 'str', 1)})"]
            if v.kind == "num":
                op = ch.choice(["+", "-", "*"])
                return [f"{v.name} = {v.name} {op} {self.operand(ctx, 'num', 1)}"]
            op = ch.choice(["+", "-", "*", "<<", "+", "*", "%", "|", "&"])
            rhs = ch.choice(["1", "2", "3", "7", "65536", "1073741824", "2147483647", "-1"])
            if op == "%":
                rhs = ch.choice(["3", "7", "-3"])
            return [f"{v.name} = {v.name} {op} {rhs}"]
        if what == "tableput":
            t = self.table_ref(ctx)
            key = "." + ch.choice(FIELDS) if ch.chance(0.5) else f"[{self.key(ctx)}]"
            value = "nil" if ch.chance(0.1) else self.expr(ctx, ch.choice(VALUE_KINDS), 2)
            if key in (".val", '["val"]') and not self.wrong():
                value = self.expr(ctx, "int", 2)  # method tables compute with `val`
            return [f"{t}{key} = {value}"]
        if what == "library":
            if ch.chance(0.15):
                return [ch.choice(OVERRIDES)]
            if self.chaos or ch.chance(0.2):
                return [f"log({ch.choice(MISUSES)})"]
            return [f"log({self.expr(ctx, ch.choice(['int', 'str']), 2)})"]
        if what == "call":
            call = self.call(ctx, 2)
            return [call] if call else [f"log({self.arg(ctx)})"]
        if what == "var":
            name = self.fresh("v")
            kind = ch.choice(["int", "float", "num", "str", "table", "closure"])
            if kind == "closure":
                init = f" = {self.lambda_expr(ctx, ['num'], depth + 1)}"
            elif ch.chance(0.9):
                init = f" = {self.expr(ctx, 'int' if kind == 'num' else kind, 2)}"
            else:
                init, kind = "", "nil"
            ctx.locals.append(Var(name, kind, assignable=kind not in ("table", "closure")))
            return [f"var {name}{init}"]
        if what == "return":
            if ch.chance(0.2):
                return [f"if ({self.cond(ctx, 1)}) {{ return }}"]
            return [f"if ({self.cond(ctx, 1)}) {{ return {self.arg(ctx)} }}"]
        if what == "if":
            return self.if_statement(ctx, depth)
        if what == "while":
            return self.while_loop(ctx, depth)
        if what == "for":
            return self.for_loop(ctx, depth)
        return self.foreach(ctx, depth)

    def body(self, ctx: Ctx, depth: int, *, loop: bool = False) -> list[str]:
        """A block `{...}` (or, sometimes, a single braceless statement)."""
        inner = ctx.child(top_block=not ctx.in_function, loop=loop or ctx.loop)
        if self.ch.chance(0.15):
            flat = Ctx(list(ctx.locals), ctx.rank, ctx.in_function, False, ctx.method, inner.loop)
            stmt = self.statement(flat, depth + 1)
            if len(stmt) == 1 and not stmt[0].startswith("var "):
                return stmt
            return ["{", *_indent(stmt), "}"]
        return ["{", *_indent(self.block(inner, depth + 1)), "}"]

    def if_statement(self, ctx: Ctx, depth: int) -> list[str]:
        """if / if-else / else-if chains."""
        ch = self.ch
        out = [f"if ({self.cond(ctx, 2)})", *self.body(ctx, depth)]
        if ch.chance(0.5):
            if ch.chance(0.3):
                out += [f"else if ({self.cond(ctx, 2)})", *self.body(ctx, depth)]
            else:
                out += ["else", *self.body(ctx, depth)]
        return _join_heads(out)

    def loop_counter(self, ctx: Ctx, kind: str) -> tuple[list[str], str]:
        """A fresh loop counter: a `var` inside functions, a unique global at top level."""
        if ctx.in_function:
            name = self.fresh("c")
            ctx.locals.append(Var(name, kind, assignable=False))
            return [f"var {name} = 0"], name
        name = self.fresh("k")
        ctx.locals.append(Var(name, kind, assignable=False))  # readable, never assigned
        return [], name

    def while_loop(self, ctx: Ctx, depth: int) -> list[str]:
        """`while (c < K) { c = c + 1 ... }`."""
        ch = self.ch
        start = ch.choice(["0", "0", "0.5", "-1"])
        step = ch.choice(["1", "1", "1.0"])
        kind = "int" if start in ("0", "-1") and step == "1" else "float"
        pre, c = self.loop_counter(ctx, kind)
        limit = ch.integer(0, 4)
        inner = ctx.child(top_block=not ctx.in_function, loop=True)
        body = [f"{c} = {c} + {step}", *self.block(inner, depth + 1)]
        return [*pre, f"{c} = {start}", f"while ({c} < {limit}) {{", *_indent(body), "}"]

    def for_loop(self, ctx: Ctx, depth: int) -> list[str]:
        """`for (c = 0, c < K, c = c + 1) ...`."""
        ch = self.ch
        pre, c = self.loop_counter(ctx, "int")
        limit = ch.integer(0, 4)
        cond = f"{c} < {limit}"
        if ch.chance(0.2):
            cond = f"{cond} and ({self.cond(ctx, 1)})"  # never `or`: it could loop forever
        head = f"for ({c} = 0, {cond}, {c} = {c} + 1)"
        return [*pre, head, *self.body(ctx, depth, loop=True)]

    def foreach(self, ctx: Ctx, depth: int) -> list[str]:
        """foreach(t, function(k, v) {...}) as a statement."""
        t = self.table_value(ctx)
        lam = self.lambda_expr(ctx, ["any", "any"], depth + 1)
        return [f"foreach({t}, {lam})"]

    # ------------------------------------------------------------ calls

    def call(self, ctx: Ctx, d: int) -> str | None:
        """A call expression to something callable from this context, or None."""
        ch = self.ch
        options: list[tuple[str, list[str]]] = [
            (fn.name, fn.kinds) for fn, rank in self.functions if rank < ctx.rank
        ]
        if self.rec is not None and ctx.rank > self.rec_rank:
            options.append(("rec", ["depth", self.rec.kinds[1]]))
        if ctx.rank > 0:
            options += [(lam.name, lam.kinds) for lam in self.lambdas]
            options += [(f"{t}.{m}", kinds) for t, m, kinds in self.methods]
        options += [(v.name, ["num"]) for v in ctx.locals if v.kind == "closure"]
        if not options:
            return None
        name, kinds = ch.choice(options)
        kinds = list(kinds)
        if ch.chance(0.3):  # the same function called with ints here, floats elsewhere
            kinds = [{"num": ch.choice(["int", "float"]), "float": "int"}.get(k, k) for k in kinds]
        if self.wrong():
            if kinds and ch.chance(0.5):
                kinds.pop()
            else:
                kinds.append("int")
        args = []
        for k in kinds:
            if k == "depth":
                args.append(ch.choice(["0", "1", "2", "3"]))
            else:
                args.append(self.arg(ctx, d - 1) if k == "any" else self.expr(ctx, k, d - 1))
        return f"{name}({', '.join(args)})"

    def lambda_expr(self, ctx: Ctx, kinds: list[str], depth: int) -> str:
        """`function(p...) { ... return ... }` capturing the current locals."""
        params = [Var(self.fresh("p"), k) for k in kinds]
        inner = Ctx(list(ctx.locals) + params, ctx.rank, True, method=ctx.method)
        if not ctx.in_function and not ctx.top_block:
            inner.locals = list(params)
        body = self.block(inner, max(depth, self.max_depth - 1))
        if self.ch.chance(0.8):
            body.append(f"return {self.arg(inner, 1)}")
        return f"function({', '.join(p.name for p in params)}) {{ {' '.join(body)} }}"

    # ------------------------------------------------------------ expressions

    def arg(self, ctx: Ctx, d: int = 2) -> str:
        """A call argument: a condition or an expression of any kind."""
        if self.ch.chance(0.2):
            return self.cond(ctx, d)
        return self.expr(ctx, self.ch.choice(VALUE_KINDS + ["field"]), d)

    def cond(self, ctx: Ctx, d: int) -> str:
        """`[not] comparison (and|or comparison)*`."""
        ch = self.ch
        parts = [self.comparison(ctx, d)]
        for _ in range(ch.integer(1, 2) if ch.chance(0.3) else 0):
            parts.append(ch.choice(["and", "or"]))
            parts.append(self.comparison(ctx, d))
        text = " ".join(parts)
        if ch.chance(0.1):
            text = "not " + text
        return text

    def predicate(self, ctx: Ctx, d: int) -> str:
        """A condition whose value is the int 0 or 1 (comparisons joined by and/or/not)."""
        ch = self.ch
        parts = [self.comparison(ctx, d, bare=False)]
        for _ in range(ch.integer(1, 2) if ch.chance(0.3) else 0):
            parts += [ch.choice(["and", "or"]), self.comparison(ctx, d, bare=False)]
        return ("not " if ch.chance(0.1) else "") + " ".join(parts)

    def comparison(self, ctx: Ctx, d: int, *, bare: bool = True) -> str:
        """`expression [op expression]`."""
        ch = self.ch
        if bare and ch.chance(0.2):
            return self.expr(ctx, ch.choice(VALUE_KINDS), d)
        ka = ch.choice(["int", "float", "num", "str", "int", "nil", "table", "field", "closure"])
        if ka in ("int", "float", "num"):
            kb = ch.choice(["int", "float", "num"])
        elif ka == "str":
            kb = ch.choice(["str", "str", "int"])
        else:
            kb = ch.choice(VALUE_KINDS + ["field"])
        ordered = ka in SCALAR_KINDS and kb in SCALAR_KINDS
        if ordered or self.wrong():
            op = ch.choice(["==", "!=", "<", "<=", ">", ">="])
        else:
            op = ch.choice(["==", "!="])
        return f"{self.expr(ctx, ka, d)} {op} {self.expr(ctx, kb, d)}"

    def expr(self, ctx: Ctx, kind: str, d: int) -> str:
        """An `expression` (no bare comparisons) intended to have this kind."""
        ch = self.ch
        if self.wrong():
            kind = ch.choice(VALUE_KINDS)
        if kind == "any":
            kind = ch.choice(VALUE_KINDS + ["field"])
        if kind == "num":
            kind = ch.choice(["int", "float", "numvar"])
        if kind == "numvar":
            return self.atom(ctx, "num")
        if d <= 0 or ch.chance(0.3):
            return self.atom(ctx, kind)
        return getattr(self, f"expr_{kind}")(ctx, d - 1)

    def operand(self, ctx: Ctx, kind: str, d: int) -> str:
        """An expression used as an operand of a binary operator (mostly parenthesized)."""
        e = self.expr(ctx, kind, d)
        if e.startswith(("{", "function")) or (not _simple(e) and self.ch.chance(0.9)):
            return f"({e})"
        return e

    def literal(self, kind: str) -> str:
        """A literal of this kind."""
        ch = self.ch
        if kind == "int":
            return ch.choice(INT_LITERALS)
        if kind == "float":
            return ch.choice(FLOAT_LITERALS)
        if kind == "num":
            return ch.choice(INT_LITERALS + FLOAT_LITERALS)
        if kind == "str":
            return ch.choice(STRING_LITERALS)
        return "nil"

    def atom(self, ctx: Ctx, kind: str) -> str:
        """A literal or a variable of this kind."""
        ch = self.ch
        readable = {"float": ("float", "num"), "num": ("num", "int", "float")}.get(kind, (kind,))
        cands = [v.name for v in ctx.locals + self.globals if v.kind in readable]
        if kind == "table":
            cands += [v.name for v in self.tables]
        if cands and ch.chance(0.6):
            return ch.choice(cands)
        if kind in ("int", "float", "num", "str"):
            return self.literal(kind)
        if kind == "table":
            return ch.choice(self.tables).name if ch.chance(0.7) else "{}"
        if kind == "closure":
            if self.lambdas and ctx.rank > 0 and ch.chance(0.5):
                return ch.choice(self.lambdas).name
            return ch.choice(["size", "math.abs", "string.length", "type", "log"])
        if kind == "field":
            anys = [v.name for v in ctx.locals if v.kind == "any"]
            if anys and ch.chance(0.5):
                return ch.choice(anys)
            return f"{self.table_ref(ctx)}.{ch.choice(FIELDS)}"
        return "nil"

    def expr_int(self, ctx: Ctx, d: int) -> str:
        """An int-valued expression."""
        ch = self.ch
        r = ch.integer(0, 14)
        if r <= 4:
            op = ch.choice(["+", "-", "*", "+", "-", "*", "/", "%"])
            b = self.operand(ctx, "int", d)
            if op in "/%" and not self.wrong():
                b = ch.choice(["3", "-3", "7", "2", "-1", "1", "65536"])
            return f"{self.operand(ctx, 'int', d)} {op} {b}"
        if r <= 6:
            op = ch.choice(["&", "|", "<<", ">>"])
            return f"{self.operand(ctx, 'int', d)} {op} {self.operand(ctx, 'int', d)}"
        if r == 7:
            return f"{ch.choice(['-', '!', '-'])}{self.operand(ctx, 'int', d)}"
        if r == 8:
            return f"({self.predicate(ctx, d)})"
        if r == 9:
            fn = ch.choice(["math.floor", "math.ceil", "math.round", "int"])
            return f"{fn}({self.expr(ctx, 'float', d)})"
        if r == 10:
            return f"size({self.table_value(ctx)})"
        if r == 11:
            return f"string.length({self.expr(ctx, 'str', d)})"
        if r == 12:
            fn = ch.choice(["isnil", "isint", "isfloat", "isstring", "istable", "isclosure"])
            return f"{fn}({self.arg(ctx, d)})"
        if r == 13:
            return f"math.abs({self.expr(ctx, 'int', d)})"
        return ch.choice(
            [
                "math.rng.uniform(10)",
                "math.rng.uniform(1, 5)",
                "id",
                "string.toint(" + ch.choice(NUMERIC_STRINGS) + ")",
            ]
        )

    def expr_float(self, ctx: Ctx, d: int) -> str:
        """A float-valued expression."""
        ch = self.ch
        r = ch.integer(0, 9)
        if r <= 3:
            op = ch.choice(["+", "-", "*", "/", "%"])
            a, b = ch.choice(
                [("float", "float"), ("float", "int"), ("int", "float"), ("num", "float")]
            )
            return f"{self.operand(ctx, a, d)} {op} {self.operand(ctx, b, d)}"
        if r == 4:
            base = self.operand(ctx, ch.choice(["int", "float"]), d)
            return f"{base} ^ {self.operand(ctx, ch.choice(['int', 'float']), d)}"
        if r == 5:
            return f"float({self.expr(ctx, 'int', d)})"
        if r == 6:
            fn = ch.choice(
                ["sqrt", "sin", "cos", "log", "exp", "log2", "log10", "tan", "asin", "acos"]
            )
            return f"math.{fn}({self.expr(ctx, 'num', d)})"
        if r == 7:
            return ch.choice(
                ["math.pi", "math.rng.uniform(1.0)", "math.rng.uniform(0.5, 2)", "-math.pi"]
            )
        if r == 8:
            return f"math.atan({self.expr(ctx, 'float', d)}, {self.expr(ctx, 'int', d)})"
        return f"-{self.operand(ctx, 'float', d)}"

    def expr_str(self, ctx: Ctx, d: int) -> str:
        """A string-valued expression."""
        ch = self.ch
        r = ch.integer(0, 4)
        if r == 0:
            n = ch.integer(2, 3)
            return f"string.concat({', '.join(self.expr(ctx, 'str', d) for _ in range(n))})"
        if r == 1:
            s = ch.choice(LONG_STRINGS)
            if ch.chance(0.5):
                return f"string.sub({s}, {ch.choice(['0', '1', '2'])})"
            return f"string.sub({s}, {ch.choice(['0', '1'])}, {ch.choice(['2', '3', '100'])})"
        if r == 2:
            return f"string.tostring({self.expr(ctx, ch.choice(['int', 'float', 'num']), d)})"
        if r == 3:
            return f"type({self.arg(ctx, d)})"
        return self.atom(ctx, "str")

    def expr_table(self, ctx: Ctx, d: int) -> str:
        """A table-valued expression."""
        ch = self.ch
        r = ch.integer(0, 4)
        if r <= 1:
            return self.table_literal(ctx, d)
        if r == 2:
            return f"clone({self.table_value(ctx)})"
        lam = self.lambda_expr(ctx, ["any", "any"], self.max_depth)
        return f"{ch.choice(['map', 'filter'])}({self.table_value(ctx)}, {lam})"

    def expr_nil(self, ctx: Ctx, d: int) -> str:
        """nil, or something that evaluates to nil."""
        return self.ch.choice(["nil", f"{self.table_ref(ctx)}.nothere", "nil"])

    def expr_closure(self, ctx: Ctx, d: int) -> str:
        """A lambda (closures are values too)."""
        kinds = [self.ch.choice(["num", "any"]) for _ in range(self.ch.integer(0, 2))]
        return self.lambda_expr(ctx, kinds, self.max_depth)

    def expr_field(self, ctx: Ctx, d: int) -> str:
        """Table reads, method calls, min/max, reduce: values of unknown kind."""
        ch = self.ch
        r = ch.integer(0, 6)
        t = self.table_ref(ctx)
        if r <= 1:
            return f"{t}.{ch.choice(FIELDS)}"
        if r == 2:
            return f"{t}[{self.key(ctx)}]"
        if r == 3:
            fn = ch.choice(["math.min", "math.max"])
            k = ch.choice(["int", "float", "str", "num"])
            return f"{fn}({self.expr(ctx, k, d)}, {self.expr(ctx, k, d)})"
        if r == 4:
            lam = self.lambda_expr(ctx, ["any", "any", "any"], self.max_depth)
            return f"reduce({t}, {lam}, {self.expr(ctx, 'int', d)})"
        call = self.call(ctx, d)
        return call or f"{t}.{ch.choice(FIELDS)}"

    def table_ref(self, ctx: Ctx) -> str:
        """A table variable (an identifier chain: fields and indexes may follow it)."""
        ch = self.ch
        if ctx.method and ch.chance(0.3):
            return "self"
        cands = [v.name for v in ctx.locals if v.kind == "table"] + [v.name for v in self.tables]
        t = ch.choice(cands)
        if self.wrong():
            t += "." + ch.choice(FIELDS)  # nested (often nil: a type error)
        return t

    def table_value(self, ctx: Ctx) -> str:
        """A table variable or a table literal (as a call argument)."""
        if self.ch.chance(0.2):
            return self.table_literal(ctx, 1)
        return self.table_ref(ctx)

    def table_literal(self, ctx: Ctx, d: int) -> str:
        """`{.id = e, .3 = e, ...}`."""
        ch = self.ch
        keys = _sample(ch, FIELDS + NUM_KEYS, ch.integer(0, 4))
        fields = []
        for k in keys:
            kind = ch.choice(["int", "float", "str", "int", "table", "nil", "closure", "num"])
            if kind == "table" and d <= 0:
                kind = "int"
            fields.append(f".{k} = {self.expr(ctx, kind, d - 1)}")
        return "{" + ", ".join(fields) + "}"

    def key(self, ctx: Ctx) -> str:
        """A table key: int, float or string (nil now and then, a type error)."""
        ch = self.ch
        if self.wrong():
            return self.expr(ctx, ch.choice(["nil", "table", "closure"]), 1)
        r = ch.integer(0, 9)
        if r <= 3:
            return self.expr(ctx, "int", 1)
        if r <= 5:
            return ch.choice(['"x"', '"val"', '"k"', '"1"', '"in"'])
        if r <= 7:
            return self.expr(ctx, "float", 1)
        return self.expr(ctx, "str", 1)


def _sample(ch: Chooser, pool: list[str], n: int) -> list[str]:
    """n distinct elements of pool, in a chosen order."""
    rest = list(pool)
    out = []
    for _ in range(min(n, len(rest))):
        out.append(rest.pop(ch.integer(0, len(rest) - 1)))
    return out


def _simple(e: str) -> bool:
    """A token that needs no parentheses as an operand."""
    return e.replace(".", "").replace("_", "").isalnum() or e.startswith(("'", '"'))


def _indent(lines: list[str]) -> list[str]:
    return ["  " + line for line in lines]


def _join_heads(lines: list[str]) -> list[str]:
    """Put `{` on its head line (purely cosmetic)."""
    out: list[str] = []
    for line in lines:
        if line == "{" and out:
            out[-1] += " {"
        else:
            out.append(line)
    return out


def generate_program(ch: Chooser, *, max_statements: int = 60) -> GeneratedProgram:
    """A random valid Buzz program (see the module docstring)."""
    return BuzzGen(ch, max_statements=max_statements).program()
