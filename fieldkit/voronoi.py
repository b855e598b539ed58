"""Bounded Voronoi cells and centroids for Lloyd-style coverage (the `voronoi` closure and
the coverage metric).

Points are (x, y) pairs in metres in any planar frame (the scripts use x north, y east).
A site's cell is the set of points of the boundary polygon at least as close to it as to
any other site: the intersection of the bisector half-planes of every other site with the
polygon's own half-planes, computed by Qhull (`scipy.spatial.HalfspaceIntersection`); a
site on or outside the boundary has no interior point for Qhull, so its cell is clipped
directly. Unlike ROSBuzz's Fortune-based code, the polygon's corners that fall inside a cell
belong to it, so boundary cells are complete and their centroids unbiased.

The boundary is a convex polygon (its convex hull is taken, so vertex order does not
matter); hulls come from Qhull through `scipy.spatial.ConvexHull`. Degenerate inputs
(fewer than 3 points, collinear points, duplicate sites, a site outside the polygon) give
empty or degenerate results, never exceptions.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence

import numpy as np
from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

Point = tuple[float, float]

#: Below this many square metres a polygon is treated as having no area.
AREA_EPS = 1e-9

#: Distance under which two points are the same (clipping, duplicate sites).
EPS = 1e-9


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
    if len(cell) < 3 or abs(area(cell)) < AREA_EPS:
        return []
    pts = np.asarray(sites, dtype=float).reshape(-1, 2)
    if not 0 <= site_index < len(pts) or not np.all(np.isfinite(pts[site_index])):
        return []
    me = pts[site_index]
    others = pts[np.all(np.isfinite(pts), axis=1)]
    others = others[np.hypot(*(others - me).T) >= EPS]  # itself and sites on top of it
    if _strictly_inside(cell, me):
        qhull = _qhull_cell(me, others, cell)
        if qhull is not None:
            return qhull
    # The site on or outside the boundary: Qhull needs a point strictly inside the cell,
    # so clip the boundary by each bisector half-plane instead (Sutherland-Hodgman).
    for other in others:
        normal = (float(other[0] - me[0]), float(other[1] - me[1]))
        # |p - me|^2 <= |p - other|^2  <=>  2 (other - me) . p <= |other|^2 - |me|^2
        offset = 0.5 * (float(other @ other) - float(me @ me))
        cell = _clip(cell, normal, offset)
        if len(cell) < 3:
            return []
    cell = _tidy(cell)
    return cell if len(cell) >= 3 and abs(area(cell)) >= AREA_EPS else []


def _strictly_inside(polygon: list[Point], p: np.ndarray, margin: float = 1e-6) -> bool:
    """Whether p is inside the counter-clockwise convex polygon, off its edges."""
    px, py = float(p[0]), float(p[1])
    for (x0, y0), (x1, y1) in zip(polygon, polygon[1:] + polygon[:1], strict=True):
        edge = math.hypot(x1 - x0, y1 - y0)
        if (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0) <= margin * edge:
            return False
    return True


def _qhull_cell(me: np.ndarray, others: np.ndarray, polygon: list[Point]) -> list[Point] | None:
    """The cell as Qhull's intersection of half-planes (bisectors and the polygon's edges).

    Rows [a, b, c] mean a x + b y + c <= 0. None if Qhull declines (then the caller clips).
    """
    normals = others - me
    offsets = -0.5 * (np.einsum("ij,ij->i", others, others) - float(me @ me))
    poly = np.asarray(polygon, dtype=float)
    edge = np.roll(poly, -1, axis=0) - poly
    outward = np.column_stack([edge[:, 1], -edge[:, 0]])  # CCW polygon: interior on the left
    rows = np.vstack(
        [
            np.column_stack([normals, offsets]),
            np.column_stack([outward, -np.einsum("ij,ij->i", outward, poly)]),
        ]
    )
    try:
        vertices = HalfspaceIntersection(rows, me).intersections
    except (QhullError, ValueError):
        return None
    centre = vertices.mean(axis=0)
    order = np.argsort(np.arctan2(vertices[:, 1] - centre[1], vertices[:, 0] - centre[0]))
    cell = _tidy([(float(x), float(y)) for x, y in vertices[order]])
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
    for t, w in zip(triangles, weights, strict=True):
        if pick < w:
            tri = t
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
