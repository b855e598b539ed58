"""Time Buzz programs on bvm against their plain-Python twins, in one run.

    python bench/bvm_speed.py [--repeat N]

Each case is a Buzz function `run()` and a Python function doing the same work the
obvious Python way. Both are warmed up once (bvm translates bytecode on first call),
then timed best-of-N. Prints each ratio (bvm time / Python time), their geometric
mean, and the combined ratio of fib and the table loop. The goal (issue 2): at most 2x,
i.e. faster than the reference C VM, which takes about 2x CPython on fib(24) plus a
20,000-iteration table loop.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import bvm


@dataclass
class Case:
    """One benchmark: Buzz source defining run(), and its Python twin."""

    name: str
    buzz: str
    python: Callable[[], object]
    setup: Callable[[bvm.VM], None] | None = None  # host state before `run()`


FIB = """
function fib(n) {
  if (n < 2) return n
  return fib(n - 1) + fib(n - 2)
}
function run() { return fib(24) }
"""


def py_fib() -> int:
    def fib(n: int) -> int:
        if n < 2:
            return n
        return fib(n - 1) + fib(n - 2)

    return fib(24)


TABLE_LOOP = """
function run() {
  var t = {}
  var i
  for (i = 0, i < 20000, i = i + 1) {
    t[i] = i * 2
  }
  var sum = 0
  i = 0
  while (i < 20000) {
    sum = sum + t[i]
    i = i + 1
  }
  return sum
}
"""


def py_table_loop() -> int:
    t = {}
    for i in range(20000):
        t[i] = i * 2
    total = 0
    i = 0
    while i < 20000:
        total = total + t[i]
        i = i + 1
    return total


MAP_REDUCE = """
function run() {
  var t = {}
  var i = 0
  while (i < 2000) {
    t[i] = i
    i = i + 1
  }
  var total = 0
  var k = 0
  while (k < 5) {
    var doubled = map(t, function(key, value) { return value * 2 })
    var odd = filter(doubled, function(key, value) { return value % 4 == 2 })
    total = total + reduce(odd, function(key, value, acc) { return acc + value }, 0)
    k = k + 1
  }
  return total
}
"""


def _tmap(t: dict, f: Callable) -> dict:
    return {k: r for k, v in t.items() if (r := f(k, v)) is not None}


def _tfilter(t: dict, f: Callable) -> dict:
    return {k: v for k, v in t.items() if f(k, v)}


def _treduce(t: dict, f: Callable, acc: object) -> object:
    for k, v in t.items():
        acc = f(k, v, acc)
    return acc


def py_map_reduce() -> int:
    # The twin keeps the program's shape: library functions calling a closure per entry.
    t = {i: i for i in range(2000)}
    total = 0
    for _ in range(5):
        doubled = _tmap(t, lambda key, value: value * 2)
        odd = _tfilter(doubled, lambda key, value: value % 4 == 2)
        total = total + _treduce(odd, lambda key, value, acc: acc + value, 0)
    return total


STRINGS = """
function run() {
  var s = ""
  var i = 0
  while (i < 3000) {
    s = string.concat(s, string.tostring(i % 10))
    i = i + 1
  }
  var n = 0
  i = 0
  while (i < string.length(s)) {
    if (string.sub(s, i, i + 1) == "7") n = n + 1
    i = i + 1
  }
  return n
}
"""


def py_strings() -> int:
    s = ""
    i = 0
    while i < 3000:
        s = s + str(i % 10)
        i = i + 1
    n = 0
    i = 0
    while i < len(s):
        if s[i : i + 1] == "7":
            n = n + 1
        i = i + 1
    return n


VECTORS = """
function run() {
  var x = 0.0
  var y = 0.0
  var vx = 1.5
  var vy = -0.5
  var dt = 0.01
  var i = 0
  while (i < 20000) {
    var ax = -x * 0.1
    var ay = -y * 0.1
    vx = vx + ax * dt
    vy = vy + ay * dt
    x = x + vx * dt
    y = y + vy * dt
    i = i + 1
  }
  return math.sqrt(x * x + y * y)
}
"""


def py_vectors() -> float:
    x = 0.0
    y = 0.0
    vx = 1.5
    vy = -0.5
    dt = 0.01
    i = 0
    while i < 20000:
        ax = -x * 0.1
        ay = -y * 0.1
        vx = vx + ax * dt
        vy = vy + ay * dt
        x = x + vx * dt
        y = y + vy * dt
        i = i + 1
    return math.sqrt(x * x + y * y)


NEIGHBORS_STEP = """
v = stigmergy.create(1)
function run() {
  var k = 0
  var total = 0.0
  while (k < 20) {
    var close = neighbors.filter(function(rid, d) { return d.distance < 30.0 })
    var vec = close.map(function(rid, d) {
      return {.x = d.distance * math.cos(d.azimuth), .y = d.distance * math.sin(d.azimuth)}
    })
    var acc = vec.reduce(function(rid, p, a) {
      a.x = a.x + p.x
      a.y = a.y + p.y
      return a
    }, {.x = 0.0, .y = 0.0})
    v.put(id, acc.x)
    var seen = v.get(k % 50)
    total = total + acc.x + acc.y
    k = k + 1
  }
  return total
}
"""

# 50 neighbors around the robot, the host's feed of `neighbors` for the step.
FIFTY = [(i + 1, 1.0 + i, (i * 0.7) % 6.283, 0.0) for i in range(50)]


def py_neighbors_step() -> float:
    # The twin keeps the program's shape: neighbors as a dict of dicts, library functions
    # calling a closure per neighbor, and a versioned shared table whose writes and reads
    # are queued for the radio (as tuples: the twin does not serialize).
    poses = {rid: {"distance": d, "azimuth": a, "elevation": e} for rid, d, a, e in FIFTY}
    store: dict[int, list] = {}
    queue: list[tuple] = []
    total = 0.0
    for k in range(20):
        close = _tfilter(poses, lambda rid, d: d["distance"] < 30.0)
        vec = _tmap(
            close,
            lambda rid, d: {
                "x": d["distance"] * math.cos(d["azimuth"]),
                "y": d["distance"] * math.sin(d["azimuth"]),
            },
        )

        def add(rid: int, p: dict, a: dict) -> dict:
            a["x"] = a["x"] + p["x"]
            a["y"] = a["y"] + p["y"]
            return a

        acc = _treduce(vec, add, {"x": 0.0, "y": 0.0})
        entry = store.get(0)
        if entry is None:
            entry = store[0] = [acc["x"], 0, 0]
        entry[0], entry[1] = acc["x"], entry[1] + 1
        queue.append(("put", 0, tuple(entry)))
        seen = store.get(k % 50)
        queue.append(("query", k % 50, seen))
        total = total + acc["x"] + acc["y"]
    return total


CASES = [
    Case("recursion: fib(24)", FIB, py_fib),
    Case("table loop: 20,000 puts + gets", TABLE_LOOP, py_table_loop),
    Case("closures: map/filter/reduce", MAP_REDUCE, py_map_reduce),
    Case("strings: build and scan", STRINGS, py_strings),
    Case("vector math: float32 integration", VECTORS, py_vectors),
    Case(
        "neighbors step: 50 nbrs, map/reduce, vstig",
        NEIGHBORS_STEP,
        py_neighbors_step,
        lambda vm: vm.set_neighbors(FIFTY),
    ),
]


def best_of(fn: Callable[[], object], repeat: int) -> float:
    """Shortest wall time of `repeat` runs of fn."""
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def measure(case: Case, repeat: int) -> tuple[float, float]:
    """(bvm seconds, Python seconds) for one case."""
    vm = bvm.VM(robot_id=0, rng_seed=1)
    vm.load(bvm.compile_source(case.buzz, f"<bench {case.name}>"))
    if case.setup is not None:
        case.setup(vm)
    vm.execute()
    vm.call("run")  # warm-up: translation happens on the first call
    case.python()
    return best_of(lambda: vm.call("run"), repeat), best_of(case.python, repeat)


def main() -> None:
    """Run every case and print the ratios, their geometric mean and the goal's ratio."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()
    ratios = []
    goal = [0.0, 0.0]  # bvm and Python seconds of the goal's two cases
    print(f"{'case':40s} {'bvm ms':>9s} {'python ms':>10s} {'ratio':>7s}")
    for case in CASES:
        b, p = measure(case, args.repeat)
        ratios.append(b / p)
        if case.python in (py_fib, py_table_loop):
            goal = [goal[0] + b, goal[1] + p]
        print(f"{case.name:40s} {b * 1e3:9.2f} {p * 1e3:10.2f} {b / p:7.2f}")
    geo = math.exp(sum(math.log(r) for r in ratios) / len(ratios))
    print(f"{'geometric mean':40s} {'':9s} {'':10s} {geo:7.2f}")
    b, p = goal
    print(f"{'fib + table loop (the goal)':40s} {b * 1e3:9.2f} {p * 1e3:10.2f} {b / p:7.2f}")


if __name__ == "__main__":
    main()
