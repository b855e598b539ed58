"""Bounded Voronoi cells, centroids, hulls and random points on known geometry."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fieldkit.robot import voronoi as vor

SQUARE = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)]


def same_polygon(got: list[tuple[float, float]], want: list[tuple[float, float]]) -> bool:
    """Same vertex set (any rotation of the vertex list), to 1e-9."""
    if len(got) != len(want):
        return False
    return all(any(math.dist(g, w) < 1e-9 for g in got) for w in want)


def test_two_sites_split_a_square_in_half() -> None:
    sites = [(2.0, 5.0), (8.0, 5.0)]
    left = vor.bounded_cell(0, sites, SQUARE)
    right = vor.bounded_cell(1, sites, SQUARE)
    assert same_polygon(left, [(0, 0), (5, 0), (5, 10), (0, 10)])
    assert same_polygon(right, [(5, 0), (10, 0), (10, 10), (5, 10)])
    assert vor.centroid(left) == pytest.approx((2.5, 5.0))
    assert vor.centroid(right) == pytest.approx((7.5, 5.0))
    assert vor.area(left) > 0  # counter-clockwise


def test_corners_belong_to_boundary_cells() -> None:
    # The ROSBuzz code dropped polygon corners inside a cell; the corner cell here is the
    # triangle (0,0) (6,0) (0,6), whose centroid is (2, 2), not a point on the bisector.
    sites = [(1.0, 1.0), (5.0, 5.0)]
    cell = vor.bounded_cell(0, sites, SQUARE)
    assert same_polygon(cell, [(0, 0), (6, 0), (0, 6)])
    assert vor.centroid(cell) == pytest.approx((2.0, 2.0))


def test_a_grid_of_sites_gives_a_grid_of_cells() -> None:
    sites = [(1.0 + 2.0 * i, 1.0 + 2.0 * j) for i in range(5) for j in range(5)]
    for k, (x, y) in enumerate(sites):
        cell = vor.bounded_cell(k, sites, SQUARE)
        assert vor.area(cell) == pytest.approx(4.0)
        assert vor.centroid(cell) == pytest.approx((x, y))
    # At the centroids already: a centroidal Voronoi tessellation, distances 0.
    assert max(vor.centroid_distances(sites, SQUARE)) == pytest.approx(0.0, abs=1e-9)


def test_boundary_vertex_order_does_not_matter() -> None:
    shuffled = [SQUARE[2], SQUARE[0], SQUARE[3], SQUARE[1], (5.0, 5.0)]  # plus an inner point
    cell = vor.bounded_cell(0, [(2.0, 5.0), (8.0, 5.0)], shuffled)
    assert vor.centroid(cell) == pytest.approx((2.5, 5.0))


def test_degenerate_sites_never_raise() -> None:
    one = vor.bounded_cell(0, [(3.0, 3.0)], SQUARE)
    assert vor.area(one) == pytest.approx(100.0)
    # A duplicate of the site shares its cell.
    dup = vor.bounded_cell(0, [(3.0, 3.0), (3.0, 3.0), (7.0, 3.0)], SQUARE)
    assert vor.centroid(dup) == pytest.approx((2.5, 5.0))
    # Collinear sites: parallel strips.
    line = [(1.0, 5.0), (5.0, 5.0), (9.0, 5.0)]
    assert vor.area(vor.bounded_cell(1, line, SQUARE)) == pytest.approx(40.0)
    # A site outside the polygon owns the part of the polygon nearest to it, or nothing.
    assert vor.area(vor.bounded_cell(0, [(12.0, 5.0), (2.0, 5.0)], SQUARE)) == pytest.approx(30.0)
    assert vor.bounded_cell(0, [(30.0, 5.0), (9.0, 5.0)], SQUARE) == []
    assert vor.ideal_centroids([(30.0, 5.0), (9.0, 5.0)], SQUARE)[0] is None
    # Bad indices, non-finite sites and degenerate boundaries.
    assert vor.bounded_cell(5, line, SQUARE) == []
    assert vor.bounded_cell(0, [(math.nan, 1.0)], SQUARE) == []
    assert vor.area(vor.bounded_cell(0, [(1.0, 1.0), (math.inf, 0.0)], SQUARE)) == pytest.approx(
        100.0
    )
    assert vor.bounded_cell(0, line, [(0, 0), (1, 1), (2, 2)]) == []
    assert vor.bounded_cell(0, line, [(0, 0), (1, 0)]) == []
    assert vor.bounded_cell(0, line, []) == []


def test_centroid_of_degenerate_polygons() -> None:
    assert vor.centroid([]) is None
    assert vor.centroid([(1.0, 2.0)]) == (1.0, 2.0)
    assert vor.centroid([(0.0, 0.0), (2.0, 2.0), (4.0, 4.0)]) == pytest.approx((2.0, 2.0))
    clockwise = list(reversed(SQUARE))
    assert vor.area(clockwise) == pytest.approx(-100.0)
    assert vor.centroid(clockwise) == pytest.approx((5.0, 5.0))


def test_convex_hull_with_and_without_margin() -> None:
    pts = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0), (5.0, 5.0), (5.0, 5.0)]
    hull = vor.convex_hull(pts)
    assert same_polygon(hull, SQUARE)
    assert vor.area(hull) == pytest.approx(100.0)
    # One point inflated by a square (4 sides): a diamond of "radius" 2.
    diamond = vor.convex_hull([(1.0, 1.0)], margin=2.0, sides=4)
    assert same_polygon(diamond, [(3, 1), (1, 3), (-1, 1), (1, -1)])
    # The inflated hull contains the points with at least margin*cos(pi/sides) clearance.
    inflated = vor.convex_hull(pts, margin=20.0)
    assert all(
        vor.contains(inflated, (x + dx, y + dy))
        for x, y in SQUARE
        for dx, dy in [(18.4, 0), (0, -18.4), (-13.0, 13.0)]
    )
    assert not vor.contains(inflated, (10.0 + 20.1, 0.0))
    # Degenerate inputs.
    assert vor.convex_hull([]) == []
    assert vor.convex_hull([(1.0, 2.0), (1.0, 2.0)]) == [(1.0, 2.0)]
    assert same_polygon(vor.convex_hull([(0, 0), (2, 2), (1, 1), (3, 3)]), [(0, 0), (3, 3)])


def test_contains() -> None:
    assert vor.contains(SQUARE, (5.0, 5.0))
    assert vor.contains(SQUARE, (10.0, 3.0))  # on the edge
    assert not vor.contains(SQUARE, (10.5, 3.0))
    assert not vor.contains([(0, 0), (1, 1)], (0.5, 0.5))


@pytest.mark.parametrize("make_rng", [lambda: random.Random(7), lambda: np.random.default_rng(7)])
def test_random_points_are_inside_and_uniform(make_rng) -> None:
    rng = make_rng()
    tri = [(0.0, 0.0), (8.0, 0.0), (0.0, 4.0)]
    pts = [vor.random_point_in(tri, rng) for _ in range(1500)]
    assert all(p is not None and vor.contains(tri, p, tol=1e-9) for p in pts)
    mean = np.mean(np.array(pts), axis=0)
    assert mean == pytest.approx(vor.centroid(tri), abs=0.15)  # the mean of a uniform sample
    assert vor.random_point_in([], rng) is None
    on_segment = vor.random_point_in([(0.0, 0.0), (2.0, 0.0)], rng)
    assert on_segment is not None and 0.0 <= on_segment[0] <= 2.0 and on_segment[1] == 0.0


def test_lloyd_iterations_converge_to_the_ideal_centroids() -> None:
    rng = random.Random(3)
    boundary = vor.convex_hull([(0.0, 0.0), (40.0, 10.0), (10.0, 50.0)], margin=20.0)
    robots = [vor.random_point_in(boundary, rng) for _ in range(6)]
    for _ in range(200):
        robots = vor.ideal_centroids(robots, boundary)
    assert max(vor.centroid_distances(robots, boundary)) < 0.05


sites_strategy = st.lists(
    st.tuples(st.floats(-5.0, 25.0), st.floats(-5.0, 25.0)), min_size=1, max_size=12
)


@settings(max_examples=150, deadline=None, derandomize=True)
@given(sites=sites_strategy)
def test_cells_partition_the_polygon(sites: list[tuple[float, float]]) -> None:
    boundary = [(0.0, 0.0), (20.0, 0.0), (24.0, 12.0), (10.0, 20.0), (-2.0, 10.0)]
    # Distinct sites (closer pairs are legal, but then shares are ill-conditioned).
    distinct: list[tuple[float, float]] = []
    for s in sites:
        if all(math.dist(s, d) > 1e-3 for d in distinct):
            distinct.append(s)
    cells = [vor.bounded_cell(i, distinct, boundary) for i in range(len(distinct))]
    total = sum(abs(vor.area(c)) for c in cells)
    assert total == pytest.approx(abs(vor.area(boundary)), rel=1e-9, abs=1e-6)
    for i, cell in enumerate(cells):
        c = vor.centroid(cell)
        if c is None:
            continue
        assert vor.contains(boundary, c, tol=1e-6)
        # Every vertex of the cell is at least as close to its site as to any other.
        for v in cell:
            mine = math.dist(v, distinct[i])
            assert all(mine <= math.dist(v, s) + 1e-6 for s in distinct)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    me=st.tuples(st.floats(-40, 40), st.floats(-40, 40)),
    others=st.lists(st.tuples(st.floats(-80, 80), st.floats(-80, 80)), max_size=14),
)
def test_qhull_cell_matches_scipy_halfspace_intersection(
    me: tuple[float, float], others: list[tuple[float, float]]
) -> None:
    """The dual-hull cell has the corners scipy's HalfspaceIntersection finds, in order."""
    from scipy.spatial import HalfspaceIntersection

    region = vor.convex_hull([(-50, -50), (50, -50), (50, 50), (-50, 50)], 10.0)
    others = [o for o in others if math.dist(o, me) > 1e-3]
    cell = vor._qhull_cell(me, others, region)
    assert cell is not None
    rows = [
        (ox - me[0], oy - me[1], -0.5 * (ox * ox + oy * oy - me[0] ** 2 - me[1] ** 2))
        for ox, oy in others
    ]
    for (x0, y0), (x1, y1) in zip(region, region[1:] + region[:1], strict=True):
        rows.append((y1 - y0, x0 - x1, -((y1 - y0) * x0 + (x0 - x1) * y0)))
    want = HalfspaceIntersection(np.array(rows), np.array(me)).intersections
    # Qhull reports a corner where k half-planes meet up to k - 1 times: compare as sets.
    for corner in want:
        assert min(math.dist(corner, c) for c in cell) < 1e-6
    for c in cell:
        assert min(math.dist(c, corner) for corner in want) < 1e-6
    assert vor.area(cell) > 0  # counter-clockwise


def test_inside_hull_counts_edges_and_corners_in() -> None:
    assert vor.inside_hull(SQUARE, (5.0, 5.0))
    assert vor.inside_hull(SQUARE, (10.0, 5.0)) and vor.inside_hull(SQUARE, (0.0, 0.0))
    assert not vor.inside_hull(SQUARE, (10.001, 5.0))
    assert not vor.inside_hull(SQUARE, (-1.0, -1.0))
    rng = random.Random(2)
    hexagon = vor.convex_hull([(0, 0)], 10.0, sides=6)
    for _ in range(500):
        p = (rng.uniform(-12, 12), rng.uniform(-12, 12))
        assert vor.inside_hull(hexagon, p) == vor.contains(hexagon, p)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(
    points=st.lists(
        st.tuples(
            st.floats(-5, 5, allow_nan=False).map(lambda v: round(v, 1)),  # ties and lines
            st.floats(-5, 5, allow_nan=False).map(lambda v: round(v, 1)),
        ),
        min_size=1,
        max_size=25,
    )
)
def test_hull_vertices_are_convex_hulls(points: list[tuple[float, float]]) -> None:
    """The hot path's hull (Qhull's engine, driven directly) is ConvexHull's, errors too."""
    from scipy.spatial import ConvexHull, QhullError

    arr = np.array(points)
    try:
        expected: object = ConvexHull(arr).vertices.tolist()
    except (QhullError, ValueError) as e:
        expected = type(e)
    try:
        got: object = vor.hull_vertices(arr)
    except (QhullError, ValueError) as e:
        got = type(e)
    assert got == expected


def test_without_the_engine_convex_hull_serves(monkeypatch: pytest.MonkeyPatch) -> None:
    """A scipy whose private engine fails the import check gets the same hulls."""
    rng = np.random.default_rng(5)
    arr = rng.uniform(-1.0, 1.0, (20, 2))
    fast = vor.hull_vertices(arr)
    monkeypatch.setattr(vor, "_engine_ok", False)
    assert vor.hull_vertices(arr) == fast
    monkeypatch.setattr(vor, "_Qhull", None)
    assert not vor._engine_agrees()
