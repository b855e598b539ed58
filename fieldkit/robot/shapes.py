"""Task graphs for graph formation: the ROSBuzz `.graph` text format, composed letter shapes,
and the Buzz table `task_allocation.bzz` reads through the `load_graph(name)` closure.

A `.graph` file holds one node per line, whitespace-separated:

    Label Pred distance bearing height

`Label` and `Pred` are integers (the root has Pred -1), `distance` is in metres from the
predecessor, `bearing` in radians from the predecessor (0 = North, +pi/2 = East, the script
frame of ROSBuzz), `height` in metres (carried, unused). Blank lines and `#` comments are
ignored. ROSBuzz's own files used centimetres; ours use metres (see the file headers).

A shape name such as "POLY" is composed from the letter files left to right (west to east):
each letter is placed `LETTER_GAP` metres east of the previous one (baselines aligned), and
its root hangs off the previous letter's root, so the whole shape is one tree whose depth
is (number of letters) + (depth of a letter): letters can form in parallel once their
roots are placed. Labels are renumbered 0..n-1 so that every predecessor comes before its
children.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

import bvm
from bvm.errors import BuzzError
from bvm.values import to_buzz
from fieldkit import resources
from fieldkit.errors import FieldkitError

#: Where the shipped letter graphs live (P, O, L, Y).
GRAPH_DIR = resources.graph_dir()

#: Metres between the easternmost node of a letter and the westernmost node of the next.
LETTER_GAP = 6.0

Point = tuple[float, float]  # (north, east) metres


class GraphError(FieldkitError, ValueError):
    """A `.graph` file or shape name that cannot be turned into a task graph."""


@dataclass(frozen=True)
class GraphNode:
    """One task: its label, its predecessor's label, and its offset from the predecessor."""

    label: int
    pred: int  # -1 for the root
    distance: float  # metres from pred
    bearing: float  # radians from pred, 0 = North, +pi/2 = East
    height: float = 0.0  # metres, carried but unused
    line: int = 0  # line in the source file (0 when composed), for error messages


def _int_field(text: str, what: str, where: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise GraphError(f"{where}: {what} must be an integer, got {text!r}") from None


def _float_field(text: str, what: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise GraphError(f"{where}: {what} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise GraphError(f"{where}: {what} must be finite, got {text!r}")
    return value


def parse_graph(text: str, path: str = "<graph>") -> list[GraphNode]:
    """Parse `.graph` text into nodes ordered predecessor-first; errors name `path:line`."""
    nodes: dict[int, GraphNode] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        fields = raw.split("#", 1)[0].split()
        if not fields:
            continue
        where = f"{path}:{number}"
        if len(fields) != 5:
            raise GraphError(
                f"{where}: expected 5 fields 'Label Pred distance bearing height', "
                f"got {len(fields)}"
            )
        label = _int_field(fields[0], "Label", where)
        pred = _int_field(fields[1], "Pred", where)
        distance = _float_field(fields[2], "distance", where)
        bearing = _float_field(fields[3], "bearing", where)
        height = _float_field(fields[4], "height", where)
        if label < 0:
            raise GraphError(f"{where}: Label must be >= 0, got {label}")
        if pred < -1:
            raise GraphError(f"{where}: Pred must be a label or -1, got {pred}")
        if distance < 0:
            raise GraphError(f"{where}: distance must be >= 0, got {distance}")
        if label in nodes:
            raise GraphError(
                f"{where}: duplicate Label {label} (first defined on line {nodes[label].line})"
            )
        nodes[label] = GraphNode(label, pred, distance, bearing, height, number)
    if not nodes:
        raise GraphError(f"{path}: no nodes")
    roots = [n for n in nodes.values() if n.pred == -1]
    if len(roots) != 1:
        lines = ", ".join(str(n.line) for n in roots) or "none"
        raise GraphError(f"{path}: expected exactly one root (Pred -1), found lines {lines}")
    for n in nodes.values():
        if n.pred != -1 and n.pred not in nodes:
            raise GraphError(f"{path}:{n.line}: Pred {n.pred} of Label {n.label} does not exist")
        if n.pred == n.label:
            raise GraphError(f"{path}:{n.line}: Label {n.label} is its own Pred")
    ordered = _tree_order(list(nodes.values()))
    if len(ordered) != len(nodes):
        placed = {n.label for n in ordered}
        cyclic = min((n for n in nodes.values() if n.label not in placed), key=lambda n: n.line)
        raise GraphError(
            f"{path}:{cyclic.line}: Label {cyclic.label} is on a cycle (not reachable from "
            "the root)"
        )
    return ordered


def _tree_order(nodes: list[GraphNode]) -> list[GraphNode]:
    """Nodes reachable from the root, predecessor first: the smallest ready label next."""
    children: dict[int, list[GraphNode]] = {}
    for n in nodes:
        children.setdefault(n.pred, []).append(n)
    out: list[GraphNode] = []
    ready = [(n.label, n) for n in children.get(-1, [])]
    heapq.heapify(ready)
    while ready:
        _, n = heapq.heappop(ready)
        out.append(n)
        for c in children.get(n.label, []):
            heapq.heappush(ready, (c.label, c))
    return out


def read_graph(path: str | Path) -> list[GraphNode]:
    """Read and parse one `.graph` file."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as e:
        raise GraphError(f"{p}: cannot read: {e.strerror or e}") from None
    return parse_graph(text, str(p))


def renumber(nodes: list[GraphNode]) -> list[GraphNode]:
    """The same tree with labels 0..n-1 in predecessor-first order."""
    ordered = _tree_order(nodes)
    new = {n.label: i for i, n in enumerate(ordered)}
    return [
        replace(n, label=new[n.label], pred=new[n.pred] if n.pred != -1 else -1) for n in ordered
    ]


def node_positions(nodes: list[GraphNode]) -> dict[int, Point]:
    """Absolute (north, east) of every node, the root at (0, 0)."""
    pos: dict[int, Point] = {}
    for n in _tree_order(nodes):
        if n.pred == -1:
            pos[n.label] = (0.0, 0.0)
        else:
            north, east = pos[n.pred]
            pos[n.label] = (
                north + n.distance * math.cos(n.bearing),
                east + n.distance * math.sin(n.bearing),
            )
    return pos


def _polar(src: Point, dst: Point) -> tuple[float, float]:
    """(distance, bearing) from `src` to `dst`, bearing 0 = North, +pi/2 = East."""
    dn, de = dst[0] - src[0], dst[1] - src[1]
    return math.hypot(dn, de), math.atan2(de, dn)


def available_letters(graph_dir: str | Path | None = None) -> list[str]:
    """The names of the `.graph` files in `graph_dir` (default: the shipped ones)."""
    return sorted(p.stem for p in Path(graph_dir or GRAPH_DIR).glob("*.graph"))


def graph_files(graph_dir: str | Path | None = None) -> dict[str, list[GraphNode] | GraphError]:
    """Every `.graph` file of `graph_dir` (default: the shipped ones), read and parsed once:
    a robot reads them at start, so `load_graph` in a tick opens no file. A file that does
    not parse keeps its error, raised when a shape uses it."""
    return _read_dir(str(Path(graph_dir or GRAPH_DIR).resolve()))


@lru_cache(maxsize=8)
def _read_dir(graph_dir: str) -> dict[str, list[GraphNode] | GraphError]:
    out: dict[str, list[GraphNode] | GraphError] = {}
    for path in sorted(Path(graph_dir).glob("*.graph")):
        try:
            out[path.stem] = renumber(read_graph(path))
        except GraphError as e:
            out[path.stem] = e
    return out


def _graph(files: dict[str, list[GraphNode] | GraphError], name: str) -> list[GraphNode]:
    got = files[name]
    if isinstance(got, GraphError):
        raise got
    return got


@lru_cache(maxsize=64)
def _compose_cached(name: str, graph_dir: str) -> tuple[GraphNode, ...]:
    directory = Path(graph_dir)
    files = graph_files(graph_dir)
    if name in files:  # a hand-made multi-letter graph takes precedence
        return tuple(_graph(files, name))
    if not name:
        raise GraphError("empty shape name")
    out: list[GraphNode] = []
    placed: dict[int, Point] = {}  # label -> absolute position, all letters so far
    previous_root = -1  # label of the previous letter's root
    for letter in name:
        if letter not in files:
            raise GraphError(
                f"shape {name!r}: no graph for letter {letter!r} in {directory} "
                f"(available: {', '.join(sorted(files)) or 'none'})"
            )
        nodes = _graph(files, letter)
        rel = node_positions(nodes)
        base = len(out)
        min_north = min(p[0] for p in rel.values())
        shift_east = 0.0
        if placed:
            east_edge = max(p[1] for p in placed.values())
            shift_east = east_edge + LETTER_GAP - min(p[1] for p in rel.values())
        absolute = {
            n.label: (rel[n.label][0] - min_north, rel[n.label][1] + shift_east) for n in nodes
        }
        for n in nodes:
            if n.pred != -1:
                out.append(replace(n, label=base + n.label, pred=base + n.pred, line=0))
                continue
            if previous_root < 0:
                out.append(replace(n, label=base, line=0))
            else:
                distance, bearing = _polar(placed[previous_root], absolute[n.label])
                out.append(GraphNode(base, previous_root, distance, bearing, n.height))
        for lbl, p in absolute.items():
            placed[base + lbl] = p
        previous_root = base
    return tuple(out)


def compose(name: str, graph_dir: str | Path | None = None) -> list[GraphNode]:
    """The task graph for a shape name ("P", "PO", "YLOPPOLY"...), labels 0..n-1."""
    return list(_compose_cached(name, str(Path(graph_dir or GRAPH_DIR).resolve())))


def positions(name: str, graph_dir: str | Path | None = None) -> dict[int, Point]:
    """Absolute (north, east) metres of every task of a shape, label 0 at (0, 0)."""
    return node_positions(compose(name, graph_dir))


def graph_table(name: str, graph_dir: str | Path | None = None) -> bvm.Table:
    """The Buzz table of a shape, as `load_graph(name)` returns it to scripts.

    Layout: `{n = count, 0 = {pred = -1, distance, bearing, height}, 1 = {...}, ...}` with
    keys 0..n-1 in predecessor-first order, `pred` an int label, distance and height floats
    in metres, bearing a float in radians (0 = North, +pi/2 = East) from `pred`.
    """
    nodes = compose(name, graph_dir)
    table: dict[object, object] = {"n": len(nodes)}
    for n in nodes:
        table[n.label] = {
            "pred": n.pred,
            "distance": float(n.distance),
            "bearing": float(n.bearing),
            "height": float(n.height),
        }
    return to_buzz(table)


def load_graph(name: object, graph_dir: str | Path | None = None) -> bvm.Table:
    """The `load_graph(name)` script closure: `graph_table`, with errors as Buzz errors."""
    if not isinstance(name, str):
        raise BuzzError(f"load_graph: expected a shape name string, got {name!r}")
    try:
        return graph_table(name, graph_dir)
    except GraphError as e:
        raise BuzzError(f"load_graph: {e}") from None
