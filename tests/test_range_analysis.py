"""The translator's int ranges must be sound: where it drops an int32 wrap check, no value
can leave int32. Counted loops and guarded recursion near the int32 limits, translated vs
the interpreter (which always wraps)."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

import bvm

EDGE = st.one_of(
    st.integers(min_value=-(2**31), max_value=-(2**31) + 40),
    st.integers(min_value=2**31 - 40, max_value=2**31 - 1),
    st.integers(min_value=-40, max_value=40),
    st.integers(min_value=2**30 - 20, max_value=2**30 + 20),
)
STEP = st.sampled_from([-3, -1, 1, 2, 7, 1000, 2**30, -(2**30)])
CMP = st.sampled_from(["<", "<=", ">", ">=", "!="])


def run(src: str, translate: bool) -> object:
    vm = bvm.VM(translate=translate, max_ticks=200)
    vm.load(bvm.compile_source(src))
    vm.execute()
    try:
        return ("ok", vm.call("f"))
    except bvm.BuzzError as e:
        return ("error", e.message)


@st.composite
def near_the_limit(draw: st.DrawFn) -> tuple[int, int, int]:
    """(start, bound, step) where bound + step lands within a few of an int32 limit, the
    places an unsound range would let a value escape unwrapped."""
    step = draw(STEP)
    limit = 2**31 - 1 if step > 0 else -(2**31)
    bound = limit - step + draw(st.integers(min_value=-3, max_value=3))
    bound = max(-(2**31), min(2**31 - 1, bound))
    start = bound - step * draw(st.integers(min_value=0, max_value=4))
    return max(-(2**31), min(2**31 - 1, start)), bound, step


def wrap(x: int) -> int:
    return ((x + 2**31) % 2**32) - 2**31


@settings(max_examples=300, deadline=None)
@given(case=near_the_limit(), cmp=CMP)
def test_counted_loops_at_the_limits(case: tuple[int, int, int], cmp: str) -> None:
    start, bound, step = case
    src = f"""
    function f() {{
      var acc = {{}}
      var n = 0
      var i
      for (i = {start}, i {cmp} {bound}, i = i + {step}) {{
        acc[n] = i + {step}
        n = n + 1
        if (n > 8) return acc
      }}
      acc[n] = i
      return acc
    }}
    """
    assert run(src, True) == run(src, False)


@settings(max_examples=300, deadline=None)
@given(case=near_the_limit(), cmp=CMP)
def test_guards_at_the_limits(case: tuple[int, int, int], cmp: str) -> None:
    _, bound, step = case
    src = f"""
    function g(x) {{
      if (x {cmp} {bound}) return 0
      return x + {step}
    }}
    function f() {{
      return {{ .a = g({bound}), .b = g({wrap(bound + 1)}), .c = g({wrap(bound - 1)}) }}
    }}
    """
    assert run(src, True) == run(src, False)


@settings(max_examples=300, deadline=None)
@given(start=EDGE, bound=EDGE, step=STEP, cmp=CMP, scale=STEP)
def test_counted_loops(start: int, bound: int, step: int, cmp: str, scale: int) -> None:
    src = f"""
    function f() {{
      var acc = {{}}
      var n = 0
      var i
      for (i = {start}, i {cmp} {bound}, i = i + {step}) {{
        acc[n] = i * {scale} - {step}
        n = n + 1
        if (n > 50) return acc
      }}
      acc[n] = i + {step}
      return acc
    }}
    """
    assert run(src, True) == run(src, False)


@settings(max_examples=200, deadline=None)
@given(limit=EDGE, step=STEP, cmp=CMP)
def test_guarded_recursion(limit: int, step: int, cmp: str) -> None:
    src = f"""
    function g(x, depth) {{
      if (x {cmp} {limit}) return x - {step}
      if (depth > 20) return x * {step}
      return g(x + {step}, depth + 1) + x
    }}
    function f() {{ return g({limit} - {step}, 0) }}
    """
    assert run(src, True) == run(src, False)


@settings(max_examples=150, deadline=None)
@given(start=EDGE, step=STEP, scale=STEP, cmp=CMP)
def test_recursion_typed_by_its_own_results(start: int, step: int, scale: int, cmp: str) -> None:
    # The direct self-calls' results are typed int (every return is), so the sums below
    # keep only the int32 wrap: it must still happen at each level.
    src = f"""
    function g(x, depth) {{
      if (depth > 4) return x
      if (x {cmp} {start}) return g(x * {scale}, depth + 2) - x
      return g(x + {step}, depth + 1) + g(x - {step}, depth + 2) + x
    }}
    function f() {{ return g({start}, 0) }}
    """
    assert run(src, True) == run(src, False)
