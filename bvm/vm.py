"""The Buzz virtual machine: loads a program, hosts it, and runs its functions.

    vm = VM(robot_id=3)
    vm.load(bvm.compile_file("behavior.bzz"))
    vm.register("log", print)
    vm.execute()          # the global code
    vm.call("init")
    vm.call("step")

Bytecode functions run as Python functions made by the translator (bvm/translate/), falling back to
bvm/interp.py for whatever the translator declines. Both call closures the same way,
`c.fn(c, *args)`, so they mix freely.
"""

from __future__ import annotations

import inspect
import logging
import sys
from collections.abc import Callable, Iterable, Mapping
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Literal

from bvm import translate as _translate
from bvm.budget import Budget, BudgetTimeout
from bvm.errors import BuzzBudgetExceeded, BuzzError, StackEntry
from bvm.interp import TOPLEVEL, Halt, interpret, recorded_pcs
from bvm.opcodes import Op
from bvm.program import Program
from bvm.translate import DEFAULT_OPTIONS, TranslateOptions
from bvm.values import Closure, Table, to_buzz, to_python, type_name

if TYPE_CHECKING:
    from bvm.stdlib.rng import MersenneTwister

#: Where a VM is: nothing loaded, ready to run, in an entry that finished (`done`: the
#: next entry makes it ready again), or stopped by an error until `reset_error`.
VMState = Literal["no code", "ready", "done", "error"]

_log = logging.getLogger("bvm")

# Python frames allowed while a VM runs: about as many nested Buzz calls when translated,
# a quarter of that when interpreted. Deeper recursion is a clean "stack overflow" error.
_RECURSION_LIMIT = 10_000

# Translations of one function for different captured-record lengths before interpreting.
_MAX_SHAPES = 8


class _NilBuiltins(dict):
    """The builtins of translated code: a global that no one has set reads as nil."""

    __slots__ = ()

    def __missing__(self, key: Any) -> None:
        return None


def _declared_arities(program: Program, addr: int, n_actrec: int) -> tuple[list[int], bool]:
    """The argument counts to translate the function at `addr` for, likeliest first, and
    whether the first that translates is enough (else: translate every one).

    Buzz bytecode does not record a function's parameters. A call's slots are the captured
    record (`n_actrec`: `self` alone for a named function), then the arguments, then the
    locals the function declares, each with `pushnil; lstore K`, K the next slot: the first
    declaration gives the count (else, a parameter set to nil: the highest slot read). A
    function without locals reads only its parameters: the highest slot it reads, or more."""
    try:
        instrs = _translate.discover(program, addr)
    except _translate.NotStructured:
        return [], True
    highest = 0
    declared: int | None = None
    previous: Op | None = None
    for ins in instrs:
        if ins.op is Op.LLOAD or ins.op is Op.LSTORE:
            k = ins.int_arg
            if ins.op is Op.LSTORE and previous is Op.PUSHNIL and declared is None and k > highest:
                declared = max(0, k - n_actrec)
            highest = max(highest, k)
        previous = ins.op
    read = max(0, highest + 1 - n_actrec)
    if declared is not None:
        return ([declared] if declared == read else [declared, read]), True
    # Trailing parameters a function never reads leave no trace: a listener may read only
    # `value` of (topic, value, sender). Callbacks take at most three: translate those too.
    return list(range(read, max(read, 3) + 1)), False


class Entry:
    """The way into one bytecode function for closures capturing `n_actrec` slots.

    Translations are made per argument count on first use, specialized on the argument
    types of that first call (guarded at entry). The first count seen becomes `fn`,
    which new closures call directly; other counts go through `other`.
    """

    __slots__ = (
        "vm",
        "addr",
        "n_actrec",
        "by_arity",
        "general_by_arity",
        "fn",
        "_generic",
        "interpret_only",
    )

    def __init__(self, vm: VM, addr: int, n_actrec: int, interpret_only: bool) -> None:
        self.vm = vm
        self.addr = addr
        self.n_actrec = n_actrec
        # Each captured-record length is a translation of its own; a lambda that creates
        # itself could ask for thousands, so past a few the interpreter takes over.
        self.interpret_only = interpret_only
        self.by_arity: dict[int, Callable[..., Any]] = {}
        self.general_by_arity: dict[int, Callable[..., Any]] = {}
        self._generic = self.generic
        self.fn: Callable[..., Any] = self._generic

    def generic(self, closure: Closure, *args: Any) -> Any:
        """First call through a closure: build the translation and patch the closure."""
        f = self.for_call(args)
        if self.fn is self._generic:
            self.fn = f
        if closure.fn is self._generic and f is self.fn:
            closure.fn = f
        return f(closure, *args)

    def other(self, closure: Closure, args: tuple) -> Any:
        """A call with another argument count than the closure's translation expects."""
        return self.for_call(args)(closure, *args)

    def for_call(self, args: tuple) -> Callable[..., Any]:
        """The callable for this many arguments, specialized on these arguments' types."""
        f = self.by_arity.get(len(args))
        if f is None and self.vm.prepared:  # translate nothing after `prepare`
            f = self.general_by_arity.get(len(args)) or self._interpreted()
            self.by_arity[len(args)] = f
        if f is None:
            spec = _translate.param_types(args)
            if self.interpret_only or all(t == _translate.ANY for t in spec):
                f = self.general(len(args))
            else:
                try:
                    f = _translate.translate(
                        self.vm,
                        self.addr,
                        self.n_actrec,
                        len(args),
                        speculate=spec,
                        options=self.vm.translate_options,
                    )
                except _translate.NotStructured as e:
                    _log.debug("function @%d (specialized): not translated: %s", self.addr, e)
                    f = self.general(len(args))
            self.by_arity[len(args)] = f
        return f

    def general(self, nargs: int) -> Callable[..., Any]:
        """The unspecialized callable for `nargs` arguments: translated, else interpreted."""
        f = self.general_by_arity.get(nargs)
        if f is None and (self.interpret_only or self.vm.prepared):
            f = self.general_by_arity[nargs] = self._interpreted()
        if f is None:
            try:
                f = _translate.translate(
                    self.vm, self.addr, self.n_actrec, nargs, options=self.vm.translate_options
                )
            except _translate.NotStructured as e:
                _log.info("function @%d runs on the interpreter: %s", self.addr, e)
                f = self._interpreted()
            self.general_by_arity[nargs] = f
        return f

    def call_general(self, closure: Closure, *args: Any) -> Any:
        """Where a specialized translation sends the calls its entry guard rejects."""
        return self.general(len(args))(closure, *args)

    def _interpreted(self) -> Callable[..., Any]:
        vm, addr = self.vm, self.addr

        def run(closure: Closure, *args: Any) -> Any:
            return interpret(vm, addr, [*closure.actrec, *args])

        run.interpreted = True  # type: ignore[attr-defined]  # what `prepare` asks
        return run


class VM:
    """A Buzz virtual machine for one robot.

    `globals` is the public fast global namespace: a plain dict from Buzz global name to
    Buzz value (see bvm.values), which a host may read and write directly once a step
    (one dict operation, against `vm[name]`'s conversions). Writes must be Buzz values;
    names starting with `_` belong to the translator's helpers and must not be touched.
    """

    #: `set_neighbor_columns(ids, distances, azimuths)`: the fast `set_neighbors` for a host
    #: that computes a whole swarm at once: the same neighbours as columns, every distance
    #: and azimuth already a binary32 value, every id valid (0..65535) and distinct, every
    #: elevation 0. Nothing is checked, and the lists are kept (not copied) until the next
    #: call: the host must not change them.
    set_neighbor_columns: Callable[[list[int], list[float], list[float]], None]

    #: The generator behind `math.rng`, made by the library's installation at `load`.
    rng: MersenneTwister

    def __init__(
        self,
        robot_id: int = 0,
        *,
        rng_seed: int | None = None,
        max_ticks: int | None = None,
        max_seconds: float | None = None,
        translate: bool = True,
        translate_options: TranslateOptions = DEFAULT_OPTIONS,
    ) -> None:
        """`max_ticks` bounds the loop iterations of one entry (execute or call), the same
        on every run; `max_seconds` bounds its wall time, whatever the script does.
        Exceeding either is a BuzzBudgetExceeded.
        `translate=False` runs everything on the reference interpreter (for testing);
        `translate_options` tunes the translator (its optimizations, its code cache)."""
        self.robot_id = robot_id & 0xFFFF
        self.translate = translate
        self.translate_options = translate_options
        self.rng_seed = rng_seed
        # Buzz globals and the helpers of translated code share one dict: it is the
        # generated functions' module globals. Buzz names never start with "_".
        self.globals: dict[str, Any] = {}
        self._hidden: dict[str, Any] = {}  # globals with "_" names (hand-made bytecode only)
        self.budget = Budget(self.globals)
        self.budget.max_ticks = max_ticks
        self.budget.max_seconds = max_seconds
        self.program: Program | None = None
        self.prepared = False  # see `prepare`: no translation after it
        self.state: VMState = "no code"
        self.error: BuzzError | None = None
        self.natives: list[Closure | None] = []
        # Per C-function id: (implementation, fixed arity or None); None for reserved ids.
        self._native_impls: list[tuple[Callable[..., Any], int | None] | None] = []
        self._entries: dict[tuple[int, int], Entry] = {}
        # The global code's translation (False: it runs on the interpreter), per load.
        self._toplevel: Callable[[], Any] | Literal[False] | None = None
        self._shapes: dict[int, int] = {}  # captured-record lengths seen per function
        self._global_start = 0
        self._depth = 0  # nesting of entries (host functions may call back into the VM)
        self._install_helpers()
        self._new_swarm_state()

    @property
    def max_ticks(self) -> int | None:
        """Loop iterations allowed per entry (None: unbounded)."""
        return self.budget.max_ticks

    @max_ticks.setter
    def max_ticks(self, value: int | None) -> None:
        self.budget.max_ticks = value

    @property
    def max_seconds(self) -> float | None:
        """Wall time allowed per entry (None: unbounded)."""
        return self.budget.max_seconds

    @max_seconds.setter
    def max_seconds(self, value: float | None) -> None:
        self.budget.max_seconds = value

    def _new_swarm_state(self) -> None:
        # Imported here: the library modules import bvm.vm's neighbours, not the reverse.
        from bvm.network import Network
        from bvm.stdlib.neighbors import Neighbors
        from bvm.stdlib.stigmergy import Stigmergies
        from bvm.stdlib.swarm import Swarms

        self.net = Network(self)
        self.neighbors = Neighbors(self)
        # Bound here, not wrapped in a method: every robot of a swarm calls it every tick.
        self.set_neighbor_columns = self.neighbors.set_columns
        self.stigmergies = Stigmergies(self)
        self.swarms = Swarms(self)

    def _install_helpers(self) -> None:
        g = self.globals
        g.update(_translate.helpers())
        g["__builtins__"] = _NilBuiltins()
        g["_gload"] = self.gload
        g["_gstore"] = self.gstore
        g["_native"] = self.native_closure
        g["_call_failed"] = self.call_failed
        self.budget.install(g)

    # ------------------------------------------------------------ loading

    def load(self, program: Program) -> None:
        """Load bytecode: run its function-registration prologue, then install the library."""
        from bvm import stdlib
        from bvm.stdlib.neighbors import methods_only

        self.program = program
        self.globals.clear()
        self._hidden.clear()
        self._install_helpers()
        self.natives.clear()
        self._shapes.clear()
        self._native_impls.clear()
        self._entries.clear()
        self._toplevel = None
        self.prepared = False
        self._new_swarm_state()
        self.state = "ready"
        self.error = None
        plan = program.registrations()
        if plan is not None:
            # The compiler's prologue, done directly: what interpreting its instructions
            # does, without decoding and dispatching ~190 of them per robot of a swarm.
            pairs, start = plan
            for name, addr in pairs:
                self.gstore(name, self.make_closure(addr, (None,)))
        else:
            start = self._run(
                lambda: interpret(self, program.code_start, None, toplevel=True, stop_at_nop=True)
            )
        if start is None:  # `done` before the prologue's `nop` (the reference hangs here)
            raise self._fail(BuzzError("done in the function-registration prologue"))
        self._global_start = start
        # Built-ins are stored after the prologue, so they replace same-named user
        # functions (reference behavior); later top-level assignments win again.
        stdlib.install(self)
        self.neighbors.lazy = methods_only(program)

    def execute(self) -> None:
        """Run the global code (up to `done`)."""
        self._require_program()
        if self.state == "done":
            self.state = "ready"

        def run() -> Any:
            if not self.translate:
                return interpret(self, self._global_start, None, toplevel=True)
            if self._toplevel is None:
                # Once per load: what it assumes of the globals' values is guarded, and
                # its bound names must not be bound again to other values.
                try:
                    self._toplevel = _translate.translate(
                        self,
                        self._global_start,
                        0,
                        0,
                        toplevel=True,
                        options=self.translate_options,
                    )
                except _translate.NotStructured as e:
                    _log.info("global code runs on the interpreter: %s", e)
                    self._toplevel = False
            if self._toplevel is False:
                return interpret(self, self._global_start, None, toplevel=True)
            return self._toplevel()

        self._run(run)
        if self.state == "ready":
            self.state = "done"

    def prepare(self) -> int:
        """Translate now every function the loaded program can create, and nothing later.

        A robot calls this at start (after the global code and `init()`): a function's first
        call then compiles nothing, which on a companion computer cost a 100 ms tick its
        deadline (ticks of 50-110 ms spent translating, here). Translations are general (not
        specialized on the first call's argument types) for the argument count the function
        declares; a call the translations did not foresee (another count, a closure made
        another way) runs on the interpreter, which gives the same results. Returns how many
        functions were translated; a VM that does not translate just stops translating."""
        self._require_program()
        program = self.program
        assert program is not None
        done: set[tuple[int, int]] = set()
        count = 0
        while True:  # translating a function binds the entries of the lambdas it creates
            todo = [e for key, e in list(self._entries.items()) if key not in done]
            if not todo:
                break
            for e in todo:
                done.add((e.addr, e.n_actrec))
                if e.interpret_only:
                    continue
                arities, first_only = _declared_arities(program, e.addr, e.n_actrec)
                for nargs in arities:
                    f = e.general(nargs)
                    e.by_arity.setdefault(nargs, f)
                    if not getattr(f, "interpreted", False):
                        count += 1
                        if first_only:
                            break
        self.prepared = True
        return count

    # ------------------------------------------------------------ host interface

    def call(self, name: str, *args: Any) -> Any:
        """Call the global function `name` with Python arguments; returns a Python value."""
        self._require_program()
        if self.state == "done":
            self.state = "ready"
        c = self.gload(name)
        if c is None:
            raise self._fail(BuzzError(f"type mismatch: cannot find function '{name}()'"))
        if c.__class__ is not Closure:
            raise self._fail(
                BuzzError(
                    f"type mismatch: function '{name}()': expected closure, got {type_name(c)}"
                )
            )
        bargs = tuple(to_buzz(a) for a in args) if args else ()
        return to_python(self._run(lambda: self.invoke(c, bargs)))

    def call_closure(self, c: Any, *args: Any) -> Any:
        """Call a Buzz value with Buzz arguments (for natives); returns a Buzz value."""
        return self.invoke(c, args)

    def invoke(self, c: Any, args: tuple) -> Any:
        """Call `c(*args)` with Buzz semantics for non-closures and argument counts."""
        try:
            return c.fn(c, *args)
        except (TypeError, AttributeError) as e:
            return self.call_failed(e, c, args)

    def call_failed(self, e: Exception, c: Any, args: tuple) -> Any:
        """`c.fn(c, *args)` raised TypeError or AttributeError: was it the call itself?

        Translated functions and fixed-arity natives take exactly their argument count,
        and a non-closure has no `.fn`; both fail at the call, before any callee frame.
        Anything raised inside the callee is re-raised untouched. Natives that call a
        closure in a loop use this with a plain `try` around `c.fn(c, ...)`.
        """
        tb = e.__traceback__
        if tb is not None and tb.tb_next is not None:
            raise e  # raised inside the callee, not by the call itself: not ours
        if c.__class__ is not Closure:
            raise BuzzError(f"type mismatch: expected closure, got {type_name(c)}") from None
        if isinstance(e, TypeError):
            if not c.native:
                # A translation takes exactly its argument count; go through the entry.
                return self.entry(c.ref, len(c.actrec)).other(c, args)
            arity = self.native_impl(c.ref)[1]
            if arity is not None and arity != len(args):
                raise BuzzError(
                    f"wrong number of local variables: expected {arity} parameters, got {len(args)}"
                ) from None
        raise e

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
        self.gstore(name, closure)
        return closure

    def new_native(self, impl: Callable[..., Any], arity: int | None, name: str) -> Closure:
        """A host closure with the next C-function id; `impl(self_value, *args)` runs it.

        With an `arity`, the closure's function takes exactly that many arguments, so the
        count is checked by CPython's own call (see `call_failed`) at no cost.
        """
        fid = len(self.natives)
        if arity is None:

            def fn(c: Closure, *args: Any) -> Any:
                return impl(c.actrec[0], *args)

        else:
            fn = _fixed_arity_maker(arity)(impl)
        fn.__name__ = fn.__qualname__ = f"native_{name}"
        closure = Closure(fid, True, (None,), fn)
        self.natives.append(closure)
        self._native_impls.append((impl, arity))
        return closure

    def native_impl(self, fid: int) -> tuple[Callable[..., Any] | None, int | None]:
        """The implementation and fixed arity (None: any) of host function `fid`."""
        info = self._native_impls[fid] if 0 <= fid < len(self._native_impls) else None
        if info is not None:
            return info
        return None, None

    def native_closure(self, fid: int) -> Closure:
        """The closure `pushcc fid` makes."""
        c = self.natives[fid] if 0 <= fid < len(self.natives) else None
        if c is None:
            raise BuzzError("function id out of range")
        return Closure(c.ref, True, (None,), c.fn)

    def make_closure(self, addr: int, actrec: tuple) -> Closure:
        """A bytecode closure at `addr` capturing `actrec`."""
        return Closure(addr, False, actrec, self.entry(addr, len(actrec)).fn)

    def entry(self, addr: int, n_actrec: int) -> Entry:
        """The shared entry of the bytecode function at `addr` for `n_actrec` captured slots."""
        key = (addr, n_actrec)
        e = self._entries.get(key)
        if e is None:
            neighbors = self.neighbors
            if neighbors.lazy and self.program is not None:
                # Code entered where the sweep did not look (a closure received over
                # the radio may name any offset) might read `poses` directly.
                if not self.program.global_use("neighbors").enters_cleanly(addr):
                    neighbors.stop_lazy()
            shapes = self._shapes[addr] = self._shapes.get(addr, 0) + 1
            interpret_only = not self.translate or shapes > _MAX_SHAPES
            e = self._entries[key] = Entry(self, addr, n_actrec, interpret_only)
        return e

    def gload(self, name: Any) -> Any:
        """The global `name` (a Buzz string), nil when unset."""
        if name.__class__ is not str:
            raise BuzzError(f"type mismatch: expected string, got {type_name(name)}")
        if name.startswith("_"):
            return self._hidden.get(name)
        return self.globals.get(name)

    def gstore(self, name: Any, value: Any) -> None:
        """Set the global `name` (a Buzz string)."""
        if name.__class__ is not str:
            raise BuzzError(f"type mismatch: expected string, got {type_name(name)}")
        if name.startswith("_"):
            self._hidden[name] = value
        else:
            self.globals[name] = value

    def __getitem__(self, name: str) -> Any:
        """A global as a Python value (tables become dicts)."""
        if name == "neighbors":
            self.settle()  # the host sees `poses` even while a lazy table waits for use
        return to_python(self.gload(name))

    def __setitem__(self, name: str, value: Any) -> None:
        """Set a global from a Python value."""
        self.gstore(name, to_buzz(value))

    def buzz_globals(self) -> dict[str, Any]:
        """The Buzz-visible globals (without the translator's helpers)."""
        self.settle()
        return {k: v for k, v in self.globals.items() if not k.startswith("_")}

    def namespace(self) -> dict[str, Any]:
        """The module globals of translated code (shared: it holds the Buzz globals)."""
        return self.globals

    @staticmethod
    def member(table: Table, key: Any) -> Any:
        """`table.get(key)`: what the translator reads of a global table's member (a
        translation shared between VMs reads it through a Recorder, which notes it)."""
        return table.get(key)

    @staticmethod
    def path_of(value: Any) -> None:
        """None: a VM does not note how the translator read values (a Recorder does)."""
        return None

    # ------------------------------------------------------------ swarm host interface

    @property
    def counters(self) -> Mapping[str, int]:
        """The network counters, read-only: `received`, `sent`, `decode_errors`,
        `inbox_overflow`, `outbox_overflow`, `oversize_dropped`, ... and those the host
        bumped with `count`; a name never counted reads 0. Reset by `load`."""
        return MappingProxyType(self.net.stats)

    def count(self, name: str, n: int = 1) -> None:
        """Add `n` to the counter `name`, for what the host sees of this robot's traffic
        before it reaches the VM (e.g. `bundle_errors`, a bundle that did not unpack)."""
        self.net.stats[name] += n

    @property
    def peer_count(self) -> int:
        """How many other robots this VM holds swarm memberships of (from their lists)."""
        return len(self.swarms.peers)

    def settle(self) -> None:
        """Make now what the VM keeps to be made on first use (this step's neighbour
        `poses`), so that the globals hold every value the script could read."""
        self.neighbors.poses()

    def set_neighbors(self, entries: Iterable[tuple[int, float, float, float]]) -> None:
        """Replace this step's neighbors: (robot id, distance, azimuth, elevation) each,
        distance in metres, angles in radians (azimuth from north, positive toward east)."""
        self.neighbors.set(list(entries))

    def receive(self, sender_id: int, payload: bytes) -> None:
        """Queue one Buzz message received from robot `sender_id`; see `process_inbox`."""
        self.net.receive(sender_id, payload)

    def process_inbox(self) -> None:
        """Apply the received messages (listeners run now). A payload that does not decode
        is counted in `counters` and skipped; a listener's error is a BuzzError."""
        self._require_program()
        if self.state == "done":
            self.state = "ready"
        if not self.net.inbox:
            # Nothing received: no listener can run, so no budget or error handling to
            # set up (most steps of a quiet swarm); the swarm records still age.
            self.net.age()
            return
        self._run(self.net.process_inbox)

    def drain_outbox(self, budget_bytes: int | None = None, overhead: int = 0) -> list[bytes]:
        """The serialized messages to send this step, in the reference's order.

        Call once per step, after `step()`. Each message costs its length plus `overhead`
        bytes of `budget_bytes`; what does not fit stays queued for the next step.
        """
        return self.net.drain(budget_bytes, overhead)

    # ------------------------------------------------------------ running

    def _require_program(self) -> Program:
        if self.program is None:
            raise BuzzError("no code loaded")
        if self.state == "error":
            raise BuzzError(f"VM is in error state: {self.error}")
        return self.program

    def _run(self, body: Callable[[], Any]) -> Any:
        """Run an entry within the budget; turn every failure into a located BuzzError.

        A host function that calls back into the VM (a re-entrant entry) shares the
        budget of the entry it runs in, and its errors are the outer entry's.
        """
        if self._depth:
            self._depth += 1
            try:
                return body()
            finally:
                self._depth -= 1
        # A translated Buzz call is one Python frame; allow deep recursion (docs/compat.md).
        if sys.getrecursionlimit() < _RECURSION_LIMIT:
            sys.setrecursionlimit(_RECURSION_LIMIT)
        self._depth = 1
        try:
            self.budget.start()
            result = body()
            self.budget.stop()  # from here on no timeout can be delivered
            return result
        except Halt:
            self.state = "done"
            return None
        except BudgetTimeout as e:
            err: BuzzError = BuzzBudgetExceeded(self.budget.timeout_message())
            raise self._fail(err, e) from None
        except BuzzError as e:
            raise self._fail(e, e) from None
        except RecursionError as e:
            err = BuzzError("stack overflow: function calls nested too deeply")
            raise self._fail(err, e) from None
        except MemoryError as e:
            raise self._fail(BuzzError("out of memory"), e) from None
        except Exception as e:
            raise self._fail(_unexpected(e), e) from None
        finally:
            self.budget.stop()
            self._depth = 0

    def _fail(self, err: BuzzError, cause: BaseException | None = None) -> BuzzError:
        """Enter the error state with `err`, located where `cause` was raised: the
        failing operation's position and the Buzz call stack. (Only here, once an error
        happened, are tracebacks read: locating costs the running code nothing.)"""
        program = self.program
        if err.offset is None and cause is not None:
            frames = _buzz_frames(cause)
            if frames:
                err.offset = frames[-1][1]
            # Frames still entering a function (a specialized entry forwarding to the
            # general one, or a call that overflowed the stack) are not running Buzz code.
            running = [f for f in frames if f[2] != _translate.NO_OP]
            if running:
                err.op_offset = running[-1][2]
            if program is not None:
                err.stack = _stack(program, running)
        if program is not None and (err.offset is not None or err.op_offset is not None):
            err.location = program.position(err.op_offset, err.offset)
        self.state = "error"
        self.error = err
        return err

    def reset_error(self) -> None:
        """Leave the error state (the host decides whether to keep running this program)."""
        if self.state == "error":
            self.state = "ready"
            self.error = None


_INTERP_CODE = interpret.__code__


def _unexpected(e: Exception) -> BuzzError:
    """A Python exception that is not a Buzz error: a host function's, or a bvm bug's."""
    tb = e.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    code = tb.tb_frame.f_code if tb is not None else None
    if code is not None and (code in _translate.LINE_MAPS or code is _INTERP_CODE):
        # Raised by the VM's own code, not a host's: say so, rather than blame the host.
        return BuzzError(f"internal error in bvm (please report): {type(e).__name__}: {e}")
    return BuzzError(f"host function error: {type(e).__name__}: {e}")


#: A Buzz frame an error went through: (function entry or TOPLEVEL, the reference's error
#: offset, the instruction running or NO_OP).
_Frame = tuple[int, int, int]


def _buzz_frames(exc: BaseException) -> list[_Frame]:
    """The Buzz frames (interpreted or translated) `exc` was raised through, outermost
    first. A frame the exception passed twice (re-raised by `call_failed`) counts once,
    where it was last."""
    frames: dict[int, _Frame] = {}
    pcs = recorded_pcs(exc)
    tb = exc.__traceback__
    while tb is not None:
        code = tb.tb_frame.f_code
        if code is _INTERP_CODE:
            recorded = pcs.get(tb)
            if recorded is not None:
                oldpc, op, entry = recorded
                frames[id(tb.tb_frame)] = (entry, oldpc, op)
        else:
            lines = _translate.LINE_MAPS.get(code)
            n = tb.tb_lineno
            if lines is not None and n is not None and n < len(lines.offsets):
                entry = TOPLEVEL if lines.toplevel else lines.addr
                frames[id(tb.tb_frame)] = (entry, lines.offsets[n], lines.ops[n])
        tb = tb.tb_next
    return list(frames.values())


def raised_at(exc: BaseException, program: Program) -> tuple[str, int, int] | None:
    """(file, line, col) of the Buzz operation `exc` was raised in (a KeyboardInterrupt
    in a script, say), if it went through Buzz code."""
    frames = _buzz_frames(exc)
    if not frames:
        return None
    _, offset, op = frames[-1]
    return program.position(op, offset)


def _stack(program: Program, frames: list[_Frame]) -> list[StackEntry]:
    """The call stack of running Buzz frames (outermost first), innermost first: each
    function with where its caller called it (None: from the host)."""
    stack = []
    # Deep recursion repeats a few (function, call site) pairs thousands of times.
    made: dict[tuple[int, int, int], StackEntry] = {}
    for k, (entry, _, _) in enumerate(frames):
        if entry == TOPLEVEL:
            continue
        _, offset, op = frames[k - 1] if k else (entry, -1, -1)
        found = made.get((entry, offset, op))
        if found is None:
            called_at = None
            if k:
                where = program.position(op, offset)
                called_at = (
                    f"{where[0]}:{where[1]}:{where[2]}" if where else f"bytecode offset {op}"
                )
            found = made[entry, offset, op] = StackEntry(program.function_name(entry), called_at)
        stack.append(found)
    stack.reverse()
    return stack


#: Arity -> a function making the native wrapper of that arity for an impl. Compiled once:
#: every robot of a swarm makes about a hundred natives, and an exec each was a third of
#: starting a swarm.
_MAKERS: dict[int, Callable[[Callable[..., Any]], Callable[..., Any]]] = {}


def _fixed_arity_maker(arity: int) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """`make(impl)` -> `fn(c, a0, .., a{arity-1})` calling `impl(c.actrec[0], a0, ..)`."""
    make = _MAKERS.get(arity)
    if make is None:
        params = "".join(f", a{k}" for k in range(arity))
        namespace: dict[str, Any] = {}
        exec(
            f"def make(impl):\n def fn(c{params}): return impl(c.actrec[0]{params})\n return fn",
            namespace,
        )
        make = _MAKERS[arity] = namespace["make"]
    return make


#: (code object, defaults given, bound) -> arity range. Every robot of a swarm registers its
#: own closures and bound methods of the same few functions: inspect.signature for each was
#: 15% of starting a thousand robots.
_ARITY: dict[tuple[object, int, bool], tuple[int, int | None]] = {}


def _arity_range(func: Callable[..., Any]) -> tuple[int, int | None]:
    """How many positional arguments `func` takes: (at least, at most or None)."""
    bound = inspect.ismethod(func)
    plain = getattr(func, "__func__", func) if bound else func
    code = getattr(plain, "__code__", None)
    if (
        code is None
        or type(plain).__name__ != "function"
        # A decorator's wrapper shares its code across the functions it wraps.
        or hasattr(plain, "__wrapped__")
        or hasattr(plain, "__signature__")
    ):
        return _arity_of_signature(func)
    key = (code, len(getattr(plain, "__defaults__", None) or ()), bound)
    found = _ARITY.get(key)
    if found is None:
        found = _ARITY[key] = _arity_of_signature(func)
    return found


def _arity_of_signature(func: Callable[..., Any]) -> tuple[int, int | None]:
    try:
        sig = inspect.signature(func)
    except (TypeError, ValueError):
        return 0, None
    lo, hi = 0, 0
    for p in sig.parameters.values():
        if p.kind is p.VAR_POSITIONAL:
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
