"""Base functions (docs/stdlib.md#base-functions): type, int, float, clone, size, foreach, map,
reduce, filter, is*.

Deliberate differences from the reference (see docs/compat.md):

* `int(x)` also accepts an int (returned unchanged) and `float(x)` also accepts a float;
  the reference only takes a float, resp. an int.
* `clone` copes with cyclic tables (the copy has the same cycle shape) and with arbitrarily
  deep ones; the reference overflows the C stack on a cycle.
* Tables iterate in insertion order (Python dict order), not the reference's 10-bucket order.
* `foreach`/`map`/`reduce`/`filter` iterate over a snapshot of the table taken at the call,
  so a callback that adds or removes entries cannot break the iteration.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from bvm.errors import BuzzError
from bvm.inline import inline
from bvm.values import Closure, Table, Userdata, f2i, f32, type_name

if TYPE_CHECKING:
    from bvm.host import LibraryHost


def expected(what: str, x: Any) -> BuzzError:
    """The reference's argument type error: `type mismatch: expected <what>, got <type>`."""
    return BuzzError(f"type mismatch: expected {what}, got {type_name(x)}")


# ---------------------------------------------------------------- pure natives


def b_type(_self: Any, x: Any) -> str:
    """type(x): the type name of x."""
    return type_name(x)


def b_int(_self: Any, x: Any) -> int:
    """int(x): a float truncated toward zero (x86 rule: NaN/inf/out of range -> INT_MIN).

    Unlike the reference, an int argument is accepted and returned unchanged.
    """
    cls = x.__class__
    if cls is float:
        return f2i(x)
    if cls is int:
        return x
    raise expected("float", x)


def b_float(_self: Any, x: Any) -> float:
    """float(x): an int converted to binary32. Unlike the reference, a float is accepted too."""
    cls = x.__class__
    if cls is int:
        return f32(x)
    if cls is float:
        return x
    raise expected("integer", x)


def clone(x: Any) -> Any:
    """A deep copy of x: tables copied recursively (cycles and sharing kept), order kept.

    Closures become new closure objects with the same activation record (so `self` still
    refers to the original table); everything else is returned as is (strings, numbers,
    nil and userdata are immutable or opaque). Iterative, so depth is unlimited.
    """
    cls = x.__class__
    if cls is Closure:
        return Closure(x.ref, x.native, x.actrec, x.fn)
    if cls is not Table:
        return x
    root = Table()
    copies: dict[int, Table] = {id(x): root}
    work: list[tuple[Table, Table]] = [(x, root)]
    pop = work.pop
    push = work.append
    while work:
        src, dst = pop()
        for k, v in src.items():
            vc = v.__class__
            if vc is Table:
                c = copies.get(id(v))
                if c is None:
                    c = copies[id(v)] = Table()
                    push((v, c))
                dst[k] = c
            elif vc is Closure:
                dst[k] = Closure(v.ref, v.native, v.actrec, v.fn)
            else:
                dst[k] = v
    return root


def b_clone(_self: Any, x: Any) -> Any:
    """clone(x): a deep copy (see `clone`)."""
    return clone(x)


# What the translator may emit instead of a call, for arguments of these types.
@inline("{len}({0})", "table")
def b_size(_self: Any, t: Any) -> int:
    """size(t): the number of entries of a table."""
    if t.__class__ is not Table:
        raise expected("table", t)
    return len(t)


def b_isnil(_self: Any, x: Any) -> int:
    """isnil(x): 1 if x is nil, else 0."""
    return 1 if x is None else 0


def b_isint(_self: Any, x: Any) -> int:
    """isint(x): 1 if x is an integer, else 0."""
    return 1 if x.__class__ is int else 0


def b_isfloat(_self: Any, x: Any) -> int:
    """isfloat(x): 1 if x is a float, else 0."""
    return 1 if x.__class__ is float else 0


def b_isstring(_self: Any, x: Any) -> int:
    """isstring(x): 1 if x is a string, else 0."""
    return 1 if x.__class__ is str else 0


def b_istable(_self: Any, x: Any) -> int:
    """istable(x): 1 if x is a table, else 0."""
    return 1 if x.__class__ is Table else 0


def b_isclosure(_self: Any, x: Any) -> int:
    """isclosure(x): 1 if x is a closure, else 0."""
    return 1 if x.__class__ is Closure else 0


def b_isuserdata(_self: Any, x: Any) -> int:
    """isuserdata(x): 1 if x is userdata, else 0."""
    return 1 if x.__class__ is Userdata else 0


# ---------------------------------------------------------------- natives calling back


def _table_and_closure(t: Any, f: Any) -> None:
    """The argument checks of foreach/map/reduce/filter."""
    if t.__class__ is not Table:
        raise expected("table", t)
    if f.__class__ is not Closure:
        raise expected("closure", f)


def _make_iterators(vm: LibraryHost) -> tuple[Any, Any, Any, Any]:
    """foreach, map, reduce and filter bound to `vm` (they call back into Buzz code)."""
    # These run a Buzz closure per entry, so they call `f.fn` directly (one Python call per
    # entry) and leave wrong argument counts and the like to `vm.call_failed`.
    failed = vm.call_failed

    def b_foreach(_self: Any, t: Any, f: Any) -> None:
        """foreach(t, f): f(key, value) for every entry, in table order; returns nil."""
        _table_and_closure(t, f)
        for k, v in list(t.items()):
            try:
                f.fn(f, k, v)
            except (TypeError, AttributeError) as e:
                failed(e, f, (k, v))
        return None

    def b_map(_self: Any, t: Any, f: Any) -> Table:
        """map(t, f): a new table {k: f(k, v)}; nil results are omitted, closures not re-bound."""
        _table_and_closure(t, f)
        out = Table()
        for k, v in list(t.items()):
            try:
                r = f.fn(f, k, v)
            except (TypeError, AttributeError) as e:
                r = failed(e, f, (k, v))
            if r is not None:
                out[k] = r
        return out

    def b_reduce(_self: Any, t: Any, f: Any, acc: Any) -> Any:
        """reduce(t, f, acc): acc = f(k, v, acc) for every entry; returns acc."""
        _table_and_closure(t, f)
        for k, v in list(t.items()):
            try:
                acc = f.fn(f, k, v, acc)
            except (TypeError, AttributeError) as e:
                acc = failed(e, f, (k, v, acc))
        return acc

    def b_filter(_self: Any, t: Any, f: Any) -> Table:
        """filter(t, f): a new table with the entries for which f(k, v) is true."""
        _table_and_closure(t, f)
        out = Table()
        for k, v in list(t.items()):
            try:
                r = f.fn(f, k, v)
            except (TypeError, AttributeError) as e:
                r = failed(e, f, (k, v))
            if r is not None and (r.__class__ is not int or r != 0):
                out[k] = v
        return out

    return b_foreach, b_map, b_reduce, b_filter


def register(vm: LibraryHost) -> None:
    """Register the base globals, in the reference order (C-function ids 11-26)."""
    b_foreach, b_map, b_reduce, b_filter = _make_iterators(vm)
    g = vm.globals
    new = vm.new_native
    for name, impl, arity in (
        ("type", b_type, 1),
        ("int", b_int, 1),
        ("float", b_float, 1),
        ("clone", b_clone, 1),
        ("size", b_size, 1),
        ("foreach", b_foreach, 2),
        ("map", b_map, 2),
        ("reduce", b_reduce, 3),
        ("filter", b_filter, 2),
        ("isnil", b_isnil, 1),
        ("isint", b_isint, 1),
        ("isfloat", b_isfloat, 1),
        ("isstring", b_isstring, 1),
        ("istable", b_istable, 1),
        ("isclosure", b_isclosure, 1),
        ("isuserdata", b_isuserdata, 1),
    ):
        g[name] = new(impl, arity, name)
