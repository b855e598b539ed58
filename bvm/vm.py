"""The Buzz virtual machine: loads a program, hosts it, and runs its functions.

    vm = VM(robot_id=3)
    vm.load(bvm.compile_file("behavior.bzz"))
    vm.register("log", print)
    vm.execute()          # the global code
    vm.call("init")
    vm.call("step")

Bytecode functions run as Python functions made by bvm/translate.py, falling back to
bvm/interp.py for whatever the translator declines. Both call closures the same way,
`c.fn(c, *args)`, so they mix freely.
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable
from typing import Any

from bvm import translate as _translate
from bvm.errors import BuzzBudgetExceeded, BuzzError
from bvm.interp import Halt, interpret
from bvm.program import Program
from bvm.values import Closure, to_buzz, to_python, type_name

# How many loop iterations and calls run between two checks of the step budget.
_TICK_CHUNK = 1000


class Globals(dict):
    """Global variables by name; an absent name reads as nil."""

    __slots__ = ()

    def __missing__(self, key: Any) -> None:
        return None


class Entry:
    """The way into one bytecode function for closures capturing `n_actrec` slots.

    Translations are made per argument count, on first use. The first count seen
    becomes `fn`, which new closures call directly; other counts go through `other`.
    """

    __slots__ = ("vm", "addr", "n_actrec", "by_arity", "fn", "_generic")

    def __init__(self, vm: VM, addr: int, n_actrec: int) -> None:
        self.vm = vm
        self.addr = addr
        self.n_actrec = n_actrec
        self.by_arity: dict[int, Callable[..., Any]] = {}
        self._generic = self.generic
        self.fn: Callable[..., Any] = self._generic

    def generic(self, closure: Closure, *args: Any) -> Any:
        """First call through a closure: build the translation and patch the closure."""
        f = self.for_arity(len(args))
        if self.fn is self._generic:
            self.fn = f
        if closure.fn is self._generic and f is self.fn:
            closure.fn = f
        return f(closure, *args)

    def other(self, closure: Closure, args: tuple) -> Any:
        """A call with a different argument count than the translation expected."""
        return self.for_arity(len(args))(closure, *args)

    def for_arity(self, nargs: int) -> Callable[..., Any]:
        """The callable for `nargs` arguments: translated, or interpreted as a fallback."""
        f = self.by_arity.get(nargs)
        if f is None:
            try:
                f = _translate.translate(self.vm, self.addr, self.n_actrec, nargs)
            except _translate.NotStructured:
                f = self._interpreted()
            self.by_arity[nargs] = f
        return f

    def _interpreted(self) -> Callable[..., Any]:
        vm, addr = self.vm, self.addr

        def run(closure: Closure, *args: Any) -> Any:
            budget = vm.budget_cell
            budget[0] -= 1
            if budget[0] <= 0:
                vm.tick()
            return interpret(vm, addr, [*closure.actrec, *args])

        return run


class VM:
    """A Buzz virtual machine for one robot."""

    def __init__(
        self,
        robot_id: int = 0,
        *,
        rng_seed: int | None = None,
        max_ticks: int | None = None,
        max_seconds: float | None = None,
    ) -> None:
        """`max_ticks` bounds the loop iterations plus calls of one entry (execute/call);
        `max_seconds` bounds its wall time. Exceeding either is a BuzzBudgetExceeded."""
        self.robot_id = robot_id & 0xFFFF
        self.rng_seed = rng_seed
        self.max_ticks = max_ticks
        self.max_seconds = max_seconds
        self.globals: Globals = Globals()
        self.program: Program | None = None
        self.state = "no code"
        self.error: BuzzError | None = None
        self.natives: list[Closure | None] = []
        self.budget_cell = [_TICK_CHUNK]
        self._ticks_left: int | None = None
        self._deadline: float | None = None
        self._entries: dict[tuple[int, int], Entry] = {}
        self._global_start = 0
        self._namespace: dict[str, Any] | None = None

    # ------------------------------------------------------------ loading

    def load(self, program: Program) -> None:
        """Load bytecode: run its function-registration prologue, then install the library."""
        from bvm import stdlib

        self.program = program
        self.globals.clear()
        self.natives.clear()
        self._entries.clear()
        self._namespace = None
        self.state = "ready"
        self.error = None
        self._global_start = self._run(
            lambda: interpret(self, program.code_start, None, toplevel=True, stop_at_nop=True)
        )
        # Built-ins are stored after the prologue, so they replace same-named user
        # functions (reference behavior); later top-level assignments win again.
        stdlib.install(self)

    def execute(self) -> None:
        """Run the global code (up to `done`)."""
        program = self._require_program()
        if self.state == "done":
            self.state = "ready"

        def run() -> Any:
            try:
                f = _translate.translate(self, self._global_start, 0, 0, toplevel=True)
            except _translate.NotStructured:
                return interpret(self, self._global_start, None, toplevel=True)
            return f()

        del program
        self._run(run)
        if self.state == "ready":
            self.state = "done"

    # ------------------------------------------------------------ host interface

    def call(self, name: str, *args: Any) -> Any:
        """Call the global function `name` with Python arguments; returns a Python value."""
        self._require_program()
        if self.state == "done":
            self.state = "ready"
        c = self.globals.get(name)
        if c is None:
            raise self._fail(BuzzError(f"type mismatch: cannot find function '{name}()'"))
        if c.__class__ is not Closure:
            raise self._fail(
                BuzzError(
                    f"type mismatch: function '{name}()': expected closure, got {type_name(c)}"
                )
            )
        bargs = [to_buzz(a) for a in args]
        return to_python(self._run(lambda: c.fn(c, *bargs)))

    def call_closure(self, c: Any, *args: Any) -> Any:
        """Call a Buzz value with Buzz arguments (for natives); returns a Buzz value."""
        if c.__class__ is not Closure:
            raise BuzzError(f"type mismatch: expected closure, got {type_name(c)}")
        budget = self.budget_cell
        budget[0] -= 1
        if budget[0] <= 0:
            self.tick()
        return c.fn(c, *args)

    def register(self, name: str, func: Callable[..., Any]) -> Closure:
        """Expose a Python callable to Buzz as the global `name`.

        It receives Buzz values (None, int, float, str, Table, Closure, Userdata) and its
        result is converted with `to_buzz`. A wrong argument count is a Buzz error.
        """
        lo, hi = _arity_range(func)

        def impl(_self: Any, *args: Any) -> Any:
            if not lo <= len(args) <= (hi if hi is not None else len(args)):
                raise BuzzError(
                    f"wrong number of local variables: {name}() expected "
                    f"{_arity_text(lo, hi)} parameters, got {len(args)}"
                )
            return to_buzz(func(*args))

        closure = self.new_native(impl, None, name)
        self.globals[name] = closure
        return closure

    def new_native(self, impl: Callable[..., Any], arity: int | None, name: str) -> Closure:
        """A host closure with the next C-function id; `impl(self_value, *args)` runs it."""
        fid = len(self.natives)
        if arity is None:

            def fn(c: Closure, *args: Any) -> Any:
                return impl(c.actrec[0], *args)

        else:

            def fn(c: Closure, *args: Any) -> Any:
                if len(args) != arity:
                    raise BuzzError(
                        f"wrong number of local variables: expected {arity} parameters, "
                        f"got {len(args)}"
                    )
                return impl(c.actrec[0], *args)

        fn.__name__ = fn.__qualname__ = f"native_{name}"
        closure = Closure(fid, True, (None,), fn)
        self.natives.append(closure)
        return closure

    def reserve_native_ids(self, count: int) -> None:
        """Skip `count` C-function ids, for library parts registered elsewhere."""
        self.natives.extend([None] * count)

    def native_closure(self, fid: int) -> Closure:
        """The closure `pushcc fid` makes."""
        if fid >= len(self.natives) or self.natives[fid] is None:
            raise BuzzError("function id out of range")
        c = self.natives[fid]
        assert c is not None
        return Closure(c.ref, True, (None,), c.fn)

    def make_closure(self, addr: int, actrec: tuple) -> Closure:
        """A bytecode closure at `addr` capturing `actrec`."""
        return Closure(addr, False, actrec, self.entry(addr, len(actrec)).fn)

    def entry(self, addr: int, n_actrec: int) -> Entry:
        """The shared entry of the bytecode function at `addr` for `n_actrec` captured slots."""
        key = (addr, n_actrec)
        e = self._entries.get(key)
        if e is None:
            e = self._entries[key] = Entry(self, addr, n_actrec)
        return e

    def __getitem__(self, name: str) -> Any:
        """A global as a Python value (tables become dicts)."""
        return to_python(self.globals.get(name))

    def __setitem__(self, name: str, value: Any) -> None:
        """Set a global from a Python value."""
        self.globals[name] = to_buzz(value)

    # ------------------------------------------------------------ budget

    def tick(self) -> None:
        """Called every `_TICK_CHUNK` loop iterations and calls: enforce the budget."""
        if self._ticks_left is not None:
            self._ticks_left -= _TICK_CHUNK - self.budget_cell[0]
            if self._ticks_left <= 0:
                self.budget_cell[0] = _TICK_CHUNK
                raise BuzzBudgetExceeded(
                    f"budget exceeded: more than {self.max_ticks} loop iterations and calls"
                )
        if self._deadline is not None and time.monotonic() > self._deadline:
            self.budget_cell[0] = _TICK_CHUNK
            raise BuzzBudgetExceeded(f"budget exceeded: ran longer than {self.max_seconds} s")
        chunk = _TICK_CHUNK
        if self._ticks_left is not None:
            chunk = max(1, min(chunk, self._ticks_left))
        self.budget_cell[0] = chunk

    def namespace(self) -> dict[str, Any]:
        """The names translated code uses (a fresh copy each time: constants get added)."""
        if self._namespace is None:
            ns = _translate.base_namespace()
            ns.update(
                _G=self.globals,
                _B=self.budget_cell,
                _tick=self.tick,
                _gload=self._gload,
                _gstore=self._gstore,
                _native=self.native_closure,
            )
            self._namespace = ns
        return dict(self._namespace)

    def _gload(self, name: Any) -> Any:
        if name.__class__ is not str:
            raise BuzzError(f"type mismatch: expected string, got {type_name(name)}")
        return self.globals[name]

    def _gstore(self, name: Any, value: Any) -> None:
        if name.__class__ is not str:
            raise BuzzError(f"type mismatch: expected string, got {type_name(name)}")
        self.globals[name] = value

    # ------------------------------------------------------------ running

    def _require_program(self) -> Program:
        if self.program is None:
            raise BuzzError("no code loaded")
        if self.state == "error":
            raise BuzzError(f"VM is in error state: {self.error}")
        return self.program

    def _run(self, body: Callable[[], Any]) -> Any:
        """Run an entry with a fresh budget; turn every failure into a located BuzzError."""
        self._ticks_left = self.max_ticks
        self._deadline = time.monotonic() + self.max_seconds if self.max_seconds else None
        self.budget_cell[0] = min(_TICK_CHUNK, self.max_ticks or _TICK_CHUNK)
        try:
            return body()
        except Halt:
            self.state = "done"
            return None
        except BuzzError as e:
            raise self._fail(e, e.__traceback__) from None
        except RecursionError as e:
            err = BuzzError("stack overflow: function calls nested too deeply")
            raise self._fail(err, e.__traceback__) from None
        except MemoryError as e:
            raise self._fail(BuzzError("out of memory"), e.__traceback__) from None
        except Exception as e:  # a host function failed: report it as a Buzz error
            err = BuzzError(f"host function error: {type(e).__name__}: {e}")
            raise self._fail(err, e.__traceback__) from None

    def _fail(self, err: BuzzError, tb: Any = None) -> BuzzError:
        if err.offset is None and tb is not None:
            err.offset = _locate(tb)
        if err.offset is not None and self.program is not None:
            err.location = self.program.location(err.offset)
        self.state = "error"
        self.error = err
        return err

    def reset_error(self) -> None:
        """Leave the error state (the host decides whether to keep running this program)."""
        if self.state == "error":
            self.state = "ready"
            self.error = None


_INTERP_CODE = interpret.__code__


def _locate(tb: Any) -> int | None:
    """Bytecode offset of the innermost Buzz frame (interpreted or translated) in a traceback."""
    offset = None
    while tb is not None:
        code = tb.tb_frame.f_code
        if code is _INTERP_CODE:
            offset = tb.tb_frame.f_locals.get("oldpc", offset)
        else:
            lines = _translate.LINE_MAPS.get(code.co_filename)
            if lines is not None and tb.tb_lineno < len(lines):
                offset = lines[tb.tb_lineno]
        tb = tb.tb_next
    return offset


def _arity_range(func: Callable[..., Any]) -> tuple[int, int | None]:
    try:
        sig = inspect.signature(func)
    except (TypeError, ValueError):
        return 0, None
    lo, hi = 0, 0
    for p in sig.parameters.values():
        if p.kind in (p.VAR_POSITIONAL,):
            return lo, None
        if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD):
            hi += 1
            if p.default is p.empty:
                lo += 1
    return lo, hi


def _arity_text(lo: int, hi: int | None) -> str:
    if hi is None:
        return f"at least {lo}"
    return str(lo) if lo == hi else f"{lo} to {hi}"
