"""Bounded Voronoi cells and centroids for Lloyd-style coverage (the `voronoi` closure and
the coverage metric).

Points are (x, y) pairs in metres in any planar frame (the scripts use x north, y east).
A site's cell is the set of points of the boundary polygon at least as close to it as to
any other site: the intersection of the bisector half-planes of every other site with the
polygon's own half-planes, computed by Qhull (the convex hull of their polar duals, as
`scipy.spatial.HalfspaceIntersection` does it); a site on or outside the boundary has no
interior point for Qhull, so its cell is clipped directly. Unlike ROSBuzz's Fortune-based
code, the polygon's corners that fall inside a cell belong to it, so boundary cells are
complete and their centroids unbiased.

The boundary is a convex polygon (its convex hull is taken, so vertex order does not
matter); hulls come from Qhull through `scipy.spatial.ConvexHull` (on the closure's hot
path, from the engine ConvexHull drives: `hull_vertices`). Degenerate inputs
(fewer than 3 points, collinear points, duplicate sites, a site outside the polygon) give
empty or degenerate results, never exceptions.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence

import numpy as np
from scipy.spatial import ConvexHull, QhullError

try:  # ConvexHull's own engine, for the hot path; see `hull_vertices`
    from scipy.spatial._qhull import _Qhull
except ImportError:  # pragma: no cover - a scipy that moved it: ConvexHull does the job
    _Qhull = None

Point = tuple[float, float]

#: Below this many square metres a polygon is treated as having no area.
AREA_EPS = 1e-9

#: Distance under which two points are the same (clipping, duplicate sites).
EPS = 1e-9


def hull_vertices(points: np.ndarray) -> list[int]:
    """The indices of the 2-D convex hull's vertices, counter-clockwise, by Qhull: what
    `ConvexHull(points).vertices` gives, raising QhullError or ValueError as it does.

    The voronoi closure asks this of ten to twenty points for every robot of a swarm;
    ConvexHull then spends more time filling attributes nobody reads (simplices, facet
    neighbours, equations, area) than Qhull spends on the hull. So this goes to the engine
    ConvexHull itself drives, `scipy.spatial._qhull._Qhull`, with ConvexHull's options; a
    scipy where that does not work as checked at import gets ConvexHull.
    """
    if _engine_ok:
        return _engine_hull(points)
    return ConvexHull(points).vertices.tolist()


def _engine_hull(points: np.ndarray) -> list[int]:
    """`hull_vertices` by `_Qhull`, as ConvexHull drives it (its mode and options)."""
    qhull = _Qhull(b"i", points, b"", required_options=b"Qt")
    try:
        return qhull.get_extremes_2d().tolist()
    finally:
        qhull.close()


def _engine_agrees() -> bool:
    """Whether `_Qhull` is there and answers as ConvexHull does (a private class)."""
    if _Qhull is None:
        return False
    square = np.array([(0.0, 0.0), (2.0, 0.0), (1.0, 1.0), (2.0, 2.0), (0.0, 2.0), (1.0, 3.0)])
    try:
        got = _engine_hull(square)
    except Exception:  # noqa: BLE001 - any change of the private API means: don't use it
        return False
    return got == ConvexHull(square).vertices.tolist()


_engine_ok = _engine_agrees()


def _unique(points: Sequence[Sequence[float]]) -> np.ndarray:
    """The finite points, duplicates removed, first occurrence order kept."""
    arr = np.asarray(points, dtype=float).reshape(-1, 2)
    arr = arr[np.all(np.isfinite(arr), axis=1)]
    if len(arr) == 0:
        return arr
    _, first = np.unique(np.round(arr / EPS), axis=0, return_index=True)
    return arr[np.sort(first)]


def _hull(arr: np.ndarray) -> list[Point]:
    """Convex hull of an array of points, counter-clockwise; degenerate cases handled."""
    if len(arr) >= 3:
        try:
            hull = ConvexHull(arr)
            return [(float(x), float(y)) for x, y in arr[hull.vertices]]  # CCW in 2-D
        except QhullError:
            pass  # all points collinear (or coincident): fall through
    if len(arr) <= 1:
        return [(float(x), float(y)) for x, y in arr]
    # Collinear: the two extreme points along the direction of largest spread.
    direction = arr[np.argmax(np.linalg.norm(arr - arr[0], axis=1))] - arr[0]
    t = (arr - arr[0]) @ direction
    a, b = arr[np.argmin(t)], arr[np.argmax(t)]
    return [(float(a[0]), float(a[1])), (float(b[0]), float(b[1]))]


def convex_hull(
    points: Sequence[Sequence[float]], margin: float = 0.0, sides: int = 8
) -> list[Point]:
    """Convex hull (counter-clockwise) of `points` inflated by `margin` metres.

    Inflation replaces each point with a regular `sides`-gon of circumradius `margin`
    whose first corner is due +x (north), as coverage.bzz does, then takes the hull.
    Fewer than 3 distinct points with no margin give those points (a degenerate hull).
    """
    arr = _unique(points)
    if margin > 0 and len(arr):
        angles = 2.0 * math.pi * np.arange(sides) / sides
        ring = margin * np.column_stack([np.cos(angles), np.sin(angles)])
        arr = (arr[:, None, :] + ring[None, :, :]).reshape(-1, 2)
    return _hull(arr)


def area(polygon: Sequence[Sequence[float]]) -> float:
    """Signed area (shoelace): positive when the vertices run counter-clockwise."""
    n = len(polygon)
    if n < 3:
        return 0.0
    # Plain floats: cells have a handful of vertices, where numpy's call costs dominate.
    total = 0.0
    x0, y0 = polygon[-1]
    for x1, y1 in polygon:
        total += x0 * y1 - x1 * y0
        x0, y0 = x1, y1
    return 0.5 * float(total)


def centroid(polygon: Sequence[Sequence[float]]) -> Point | None:
    """Area-weighted centroid; the vertex mean if the area is ~0; None if empty."""
    n = len(polygon)
    if n == 0:
        return None
    a = area(polygon)
    if abs(a) < AREA_EPS:
        return (
            float(sum(p[0] for p in polygon)) / n,
            float(sum(p[1] for p in polygon)) / n,
        )
    cx = cy = 0.0
    x0, y0 = polygon[-1]
    for x1, y1 in polygon:
        cross = x0 * y1 - x1 * y0
        cx += (x0 + x1) * cross
        cy += (y0 + y1) * cross
        x0, y0 = x1, y1
    return float(cx) / (6.0 * a), float(cy) / (6.0 * a)


def is_convex_ccw(polygon: Sequence[Sequence[float]]) -> bool:
    """Whether the polygon is already strictly convex and counter-clockwise (a hull)."""
    n = len(polygon)
    if n < 3:
        return False
    for k in range(n):
        (x0, y0), (x1, y1), (x2, y2) = polygon[k - 2], polygon[k - 1], polygon[k]
        if not all(map(math.isfinite, (x2, y2))):
            return False
        if (x1 - x0) * (y2 - y1) - (y1 - y0) * (x2 - x1) <= EPS:
            return False
    return True


def contains(polygon: Sequence[Sequence[float]], point: Sequence[float], tol: float = 1e-9) -> bool:
    """Whether `point` lies in the convex polygon (boundary included, any vertex order)."""
    hull = convex_hull(polygon)
    if len(hull) < 3:
        return False
    px, py = float(point[0]), float(point[1])
    for (x0, y0), (x1, y1) in zip(hull, hull[1:] + hull[:1], strict=True):
        if (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0) < -tol:
            return False
    return True


def _clip(poly: list[Point], normal: tuple[float, float], offset: float) -> list[Point]:
    """Sutherland-Hodgman: the part of a convex polygon where normal . p <= offset."""
    out: list[Point] = []
    n = len(poly)
    for k in range(n):
        cur, nxt = poly[k], poly[(k + 1) % n]
        dc = normal[0] * cur[0] + normal[1] * cur[1] - offset
        dn = normal[0] * nxt[0] + normal[1] * nxt[1] - offset
        if dc <= 0:
            out.append(cur)
        if (dc < 0 < dn) or (dn < 0 < dc):
            t = dc / (dc - dn)
            out.append((cur[0] + t * (nxt[0] - cur[0]), cur[1] + t * (nxt[1] - cur[1])))
    return out


def _tidy(poly: list[Point]) -> list[Point]:
    """Drop consecutive near-duplicate vertices left by clipping."""
    out: list[Point] = []
    for p in poly:
        if not out or math.dist(p, out[-1]) > 1e-7:
            out.append(p)
    while len(out) > 1 and math.dist(out[0], out[-1]) <= 1e-7:
        out.pop()
    return out


def bounded_cell(
    site_index: int, sites: Sequence[Sequence[float]], boundary_polygon: Sequence[Sequence[float]]
) -> list[Point]:
    """The Voronoi cell of `sites[site_index]` intersected with the convex boundary.

    Counter-clockwise vertices, the polygon's corners included; [] when the cell misses
    the polygon (a site outside it can still own a part) or the polygon has no area.
    Other sites at the same position as this one are ignored: they share its cell.
    """
    if is_convex_ccw(boundary_polygon):
        cell = [(float(x), float(y)) for x, y in boundary_polygon]  # a hull already
    else:
        cell = convex_hull(boundary_polygon)
    return hull_cell(site_index, sites, cell)


def hull_cell(site_index: int, sites: Sequence[Sequence[float]], hull: list[Point]) -> list[Point]:
    """`bounded_cell` for a boundary known to be strictly convex and counter-clockwise
    (`is_convex_ccw`), such as a hull: the voronoi closure checks that once per call."""
    cell = hull
    if len(cell) < 3 or abs(area(cell)) < AREA_EPS:
        return []
    # Plain floats, not numpy: a robot has about ten neighbours, and numpy's per-call
    # costs would outweigh Qhull itself (the voronoi closure runs on every robot).
    pts = [(float(x), float(y)) for x, y in sites]
    if not 0 <= site_index < len(pts):
        return []
    mx, my = me = pts[site_index]
    if not (math.isfinite(mx) and math.isfinite(my)):
        return []
    isfinite, hypot = math.isfinite, math.hypot
    others = [
        (x, y)
        for x, y in pts
        if isfinite(x) and isfinite(y) and hypot(x - mx, y - my) >= EPS  # not on top of me
    ]
    if _strictly_inside(cell, me):
        qhull = _qhull_cell(me, others, cell)
        if qhull is not None:
            return qhull
    # The site on or outside the boundary: Qhull needs a point strictly inside the cell,
    # so clip the boundary by each bisector half-plane instead (Sutherland-Hodgman).
    for ox, oy in others:
        # |p - me|^2 <= |p - other|^2  <=>  2 (other - me) . p <= |other|^2 - |me|^2
        offset = 0.5 * (ox * ox + oy * oy - mx * mx - my * my)
        cell = _clip(cell, (ox - mx, oy - my), offset)
        if len(cell) < 3:
            return []
    cell = _tidy(cell)
    return cell if len(cell) >= 3 and abs(area(cell)) >= AREA_EPS else []


def inside_hull(hull: Sequence[Point], p: Point, tol: float = 1e-9) -> bool:
    """Whether p is in the strictly convex counter-clockwise polygon, its edges included."""
    px, py = p
    x0, y0 = hull[-1]
    for x1, y1 in hull:
        ex, ey = x1 - x0, y1 - y0
        if ex * (py - y0) - ey * (px - x0) < -tol * max(1.0, abs(ex) + abs(ey)):
            return False
        x0, y0 = x1, y1
    return True


def _strictly_inside(polygon: list[Point], p: Point, margin: float = 1e-6) -> bool:
    """Whether p is inside the counter-clockwise convex polygon, off its edges."""
    px, py = p
    for (x0, y0), (x1, y1) in zip(polygon, polygon[1:] + polygon[:1], strict=True):
        edge = math.hypot(x1 - x0, y1 - y0)
        if (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0) <= margin * edge:
            return False
    return True


def _qhull_cell(me: Point, others: list[Point], polygon: list[Point]) -> list[Point] | None:
    """The cell as the intersection of half-planes (bisectors and the polygon's edges), by
    Qhull's convex hull of their polar duals: what `HalfspaceIntersection` does, without
    its per-call array checks, which cost three times Qhull's own work on ten neighbours.

    With `me` moved to the origin, a half-plane a . p <= d (d > 0: `me` strictly inside)
    has the dual point a / d; the hull's vertices, counter-clockwise, are the half-planes
    that bound the cell in the order of its edges, and each two consecutive ones meet at
    a corner. None if Qhull declines (then the caller clips).
    """
    mx, my = me
    duals = []
    for ox, oy in others:
        ax, ay = ox - mx, oy - my
        d = 0.5 * (ax * ax + ay * ay)  # bisector: a . p <= |a|^2 / 2
        duals.append((ax / d, ay / d))
    x0, y0 = polygon[-1]
    x0, y0 = x0 - mx, y0 - my
    for x1, y1 in polygon:
        x1, y1 = x1 - mx, y1 - my
        ax, ay = y1 - y0, x0 - x1  # outward normal of a counter-clockwise edge
        d = ax * x0 + ay * y0
        duals.append((ax / d, ay / d))
        x0, y0 = x1, y1
    try:
        order = hull_vertices(np.array(duals))  # counter-clockwise in 2-D
    except (QhullError, ValueError):
        return None
    cell = []
    ax, ay = duals[order[-1]]
    for k in order:
        bx, by = duals[k]
        det = ax * by - ay * bx  # > 0: consecutive counter-clockwise hull vertices
        if det <= 0.0:
            return None
        cell.append((mx + (by - ay) / det, my + (ax - bx) / det))
        ax, ay = bx, by
    cell = _tidy(cell)
    return cell if len(cell) >= 3 and abs(area(cell)) >= AREA_EPS else []


def random_point_in(
    polygon: Sequence[Sequence[float]], rng: random.Random | np.random.Generator
) -> Point | None:
    """A uniformly random point of the convex polygon (None if it has no vertices).

    `rng` is a `random.Random` or a numpy `Generator` (only `.random()` is used). Exact:
    a fan triangle picked by area, then a uniform point in it, so no rejection loop.
    """
    hull = convex_hull(polygon)
    if not hull:
        return None
    if len(hull) < 3:
        a, b = hull[0], hull[-1]
        t = float(rng.random())
        return a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])
    o = hull[0]
    triangles = [(o, hull[k], hull[k + 1]) for k in range(1, len(hull) - 1)]
    weights = [abs(area(t)) for t in triangles]
    pick = float(rng.random()) * sum(weights)
    tri = triangles[-1]
    for candidate, w in zip(triangles, weights, strict=True):
        if pick < w:
            tri = candidate
            break
        pick -= w
    u, v = float(rng.random()), float(rng.random())
    if u + v > 1.0:  # fold the far half of the parallelogram back into the triangle
        u, v = 1.0 - u, 1.0 - v
    (x0, y0), (x1, y1), (x2, y2) = tri
    return x0 + u * (x1 - x0) + v * (x2 - x0), y0 + u * (y1 - y0) + v * (y2 - y0)


def ideal_centroids(
    positions: Sequence[Sequence[float]], boundary: Sequence[Sequence[float]]
) -> list[Point | None]:
    """The centroid of every robot's bounded cell (None where the cell is empty)."""
    return [centroid(bounded_cell(i, positions, boundary)) for i in range(len(positions))]


def centroid_distances(
    positions: Sequence[Sequence[float]], boundary: Sequence[Sequence[float]]
) -> list[float]:
    """Each robot's distance to its ideal centroid (inf where its cell is empty)."""
    out = []
    for p, c in zip(positions, ideal_centroids(positions, boundary), strict=True):
        out.append(math.inf if c is None else math.dist((p[0], p[1]), c))
    return out
