"""Library natives with an inline fast path give exactly what the native gives.

The translated VM uses the inline templates (`@inline`, bvm/inline.py); the interpreter always calls
the native. Both run the same calls on random arguments, edge cases included.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import bvm

SRC = """
function sub3(s, n, m) { return string.sub(s, n, m) }
function sub2(s, n) { return string.sub(s, n) }
function cat(a, b) { return string.concat(a, b) }
function len(s) { return string.length(s) }
function str(x) { return string.tostring(x) }
function sz(t) { return size(t) }
"""


def _vm(translate: bool) -> bvm.VM:
    vm = bvm.VM(translate=translate)
    vm.load(bvm.compile_source(SRC))
    vm.execute()
    return vm


VMS = (_vm(True), _vm(False))
TEXT = st.text(alphabet=st.characters(max_codepoint=255), max_size=12)
SMALL = st.integers(min_value=-20, max_value=20)
ANYVAL = st.one_of(st.none(), SMALL, st.floats(width=32, allow_nan=False), TEXT)


def outcome(vm: bvm.VM, name: str, *args: object) -> object:
    try:
        return ("ok", vm.call(name, *args))
    except bvm.BuzzError as e:
        vm.reset_error()
        return ("error", e.message)


@settings(max_examples=400, deadline=None)
@given(s=TEXT, n=SMALL, m=SMALL)
def test_sub_matches_the_native(s: str, n: int, m: int) -> None:
    fast, ref = VMS
    assert outcome(fast, "sub3", s, n, m) == outcome(ref, "sub3", s, n, m)
    assert outcome(fast, "sub2", s, n) == outcome(ref, "sub2", s, n)


@settings(max_examples=300, deadline=None)
@given(a=ANYVAL, b=ANYVAL)
def test_concat_length_tostring_match_the_native(a: object, b: object) -> None:
    fast, ref = VMS
    for name, args in (("cat", (a, b)), ("len", (a,)), ("str", (a,)), ("sz", (a,))):
        assert outcome(fast, name, *args) == outcome(ref, name, *args), name


@pytest.mark.parametrize("n", [0, 1, 5])
def test_size_of_tables(n: int) -> None:
    fast, ref = VMS
    t = {str(k): k for k in range(n)}
    assert fast.call("sz", t) == ref.call("sz", t) == n
