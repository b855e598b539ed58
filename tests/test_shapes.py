"""Task graphs: the .graph parser, its errors, composed shapes and the Buzz table."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

import bvm
from fieldkit.robot import shapes
from fieldkit.robot.shapes import GraphError, GraphNode, parse_graph


def test_parse_orders_predecessors_first_and_keeps_units() -> None:
    text = """
    # a comment line
    2 1 5.0 1.5707963 0.0   # trailing comment
    0 -1 0 0 0
    1 0 6.0 0.0 1.5
    """
    nodes = parse_graph(text, "t.graph")
    assert [n.label for n in nodes] == [0, 1, 2]
    assert nodes[1] == GraphNode(1, 0, 6.0, 0.0, 1.5, line=5)
    pos = shapes.node_positions(nodes)
    assert pos[1] == pytest.approx((6.0, 0.0))
    assert pos[2] == pytest.approx((6.0, 5.0))  # bearing pi/2 = East


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("0 -1 0 0\n", "t.graph:1: expected 5 fields"),
        ("0 -1 0 0 0\n1 0 x 0 0\n", "t.graph:2: distance must be a number, got 'x'"),
        ("0 -1 0 0 0\n1.5 0 1 0 0\n", "t.graph:2: Label must be an integer"),
        ("0 -1 0 0 0\n1 0 nan 0 0\n", "t.graph:2: distance must be finite"),
        ("0 -1 0 0 0\n1 0 -2 0 0\n", "t.graph:2: distance must be >= 0"),
        ("0 -1 0 0 0\n\n1 7 1 0 0\n", "t.graph:3: Pred 7 of Label 1 does not exist"),
        ("0 -1 0 0 0\n1 0 1 0 0\n1 0 2 0 0\n", "t.graph:3: duplicate Label 1 (first defined"),
        ("0 -1 0 0 0\n1 2 1 0 0\n2 1 1 0 0\n", "t.graph:2: Label 1 is on a cycle"),
        ("0 -1 0 0 0\n1 1 1 0 0\n", "t.graph:2: Label 1 is its own Pred"),
        (
            "0 -1 0 0 0\n1 -1 1 0 0\n",
            "t.graph: expected exactly one root (Pred -1), found lines 1, 2",
        ),
        ("# nothing\n", "t.graph: no nodes"),
    ],
)
def test_bad_graphs_name_file_and_line(text: str, message: str) -> None:
    with pytest.raises(GraphError) as err:
        parse_graph(text, "t.graph")
    assert str(err.value).startswith(message)


@pytest.mark.parametrize("letter", ["P", "O", "L", "Y"])
def test_shipped_letters_have_six_nodes_at_uav_spacing(letter: str) -> None:
    nodes = shapes.read_graph(shapes.GRAPH_DIR / f"{letter}.graph")
    assert [n.label for n in nodes] == list(range(6))
    pts = list(shapes.node_positions(nodes).values())
    closest = min(math.dist(a, b) for i, a in enumerate(pts) for b in pts[i + 1 :])
    assert closest >= 5.0 - 1e-4


@pytest.mark.parametrize(
    ("name", "count"),
    [("P", 6), ("PO", 12), ("POL", 18), ("POLY", 24), ("PPOLY", 30), ("YLOPPOLY", 48)],
)
def test_composed_shapes_are_connected_trees_in_parent_first_order(name: str, count: int) -> None:
    nodes = shapes.compose(name)
    assert [n.label for n in nodes] == list(range(count))
    assert nodes[0].pred == -1
    assert all(0 <= n.pred < n.label for n in nodes[1:])
    pos = shapes.positions(name)
    pts = [pos[i] for i in range(count)]
    closest = min(math.dist(a, b) for i, a in enumerate(pts) for b in pts[i + 1 :])
    assert closest >= 5.0 - 1e-4
    # Letters go west to east: each letter's nodes lie east of the previous letter's, and
    # its root hangs off the previous letter's root (so letters form in parallel).
    for k in range(1, len(name)):
        assert nodes[6 * k].pred == 6 * (k - 1)
        prev_east = max(p[1] for p in pts[6 * (k - 1) : 6 * k])
        here_west = min(p[1] for p in pts[6 * k : 6 * (k + 1)])
        assert here_west == pytest.approx(prev_east + shapes.LETTER_GAP)


def test_a_composed_letter_keeps_its_own_geometry() -> None:
    po = shapes.positions("PO")
    o = shapes.positions("O")
    dn, de = po[6][0] - o[0][0], po[6][1] - o[0][1]
    for k in range(6):
        assert po[6 + k] == pytest.approx((o[k][0] + dn, o[k][1] + de), abs=1e-9)
    assert po[6][0] == pytest.approx(0.0)  # baselines aligned: O's root is its southmost node


def test_unknown_letter_is_a_clear_error() -> None:
    with pytest.raises(GraphError, match=r"no graph for letter 'Q'.*available: L, O, P, Y"):
        shapes.compose("PQ")
    with pytest.raises(GraphError, match="empty shape name"):
        shapes.compose("")


def test_a_whole_name_file_takes_precedence(tmp_path: Path) -> None:
    (tmp_path / "A.graph").write_text("0 -1 0 0 0\n1 0 10 0 0\n")
    (tmp_path / "AA.graph").write_text("5 -1 0 0 0\n9 5 7 3.14159265 0\n")
    assert [(n.label, n.pred, n.distance) for n in shapes.compose("AA", tmp_path)] == [
        (0, -1, 0.0),
        (1, 0, 7.0),
    ]
    assert len(shapes.compose("AAA", tmp_path)) == 6


def test_graph_table_layout_for_buzz() -> None:
    vm = bvm.VM(robot_id=1)
    vm.load(
        bvm.compile_source(
            """
            g = load_graph("PO")
            last = g[g.n - 1]
            """
        )
    )
    vm.register("load_graph", shapes.load_graph)
    vm.execute()
    g = vm["g"]
    assert g["n"] == 12
    assert g[0] == {"pred": -1, "distance": 0.0, "bearing": 0.0, "height": 0.0}
    nodes = shapes.compose("PO")
    for n in nodes:
        assert g[n.label]["pred"] == n.pred
        assert g[n.label]["distance"] == pytest.approx(n.distance, rel=1e-6)
        assert g[n.label]["bearing"] == pytest.approx(n.bearing, rel=1e-6)
    assert vm["last"]["pred"] == 10
    assert g[6]["pred"] == 0


def test_load_graph_errors_are_buzz_errors() -> None:
    vm = bvm.VM(robot_id=1)
    vm.load(bvm.compile_source('g = load_graph("PZ")'))
    vm.register("load_graph", shapes.load_graph)
    with pytest.raises(bvm.BuzzError, match="load_graph: shape 'PZ': no graph for letter 'Z'"):
        vm.execute()
