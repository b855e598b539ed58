"""Bounded Voronoi cells and centroids for Lloyd-style coverage (the `voronoi` closure and
the coverage metric).

Points are (x, y) pairs in metres in any planar frame (the scripts use x north, y east).
A site's cell is the set of points of the boundary polygon at least as close to it as to
any other site: the boundary polygon clipped by the bisector half-plane of every other
site. Unlike ROSBuzz's Fortune-based code, the polygon's corners that fall inside a cell
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
from scipy.spatial import ConvexHull, QhullError

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
    if len(polygon) < 3:
        return 0.0
    p = np.asarray(polygon, dtype=float)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def centroid(polygon: Sequence[Sequence[float]]) -> Point | None:
    """Area-weighted centroid; the vertex mean if the area is ~0; None if empty."""
    if len(polygon) == 0:
        return None
    p = np.asarray(polygon, dtype=float)
    a = area(p)
    if abs(a) < AREA_EPS:
        mean = p.mean(axis=0)
        return float(mean[0]), float(mean[1])
    x, y = p[:, 0], p[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    cx = float(np.dot(x + xn, cross)) / (6.0 * a)
    cy = float(np.dot(y + yn, cross)) / (6.0 * a)
    return cx, cy


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
    cell = convex_hull(boundary_polygon)
    if len(cell) < 3 or abs(area(cell)) < AREA_EPS:
        return []
    pts = np.asarray(sites, dtype=float).reshape(-1, 2)
    if not 0 <= site_index < len(pts) or not np.all(np.isfinite(pts[site_index])):
        return []
    me = pts[site_index]
    for j, other in enumerate(pts):
        if j == site_index or not np.all(np.isfinite(other)):
            continue
        normal = (float(other[0] - me[0]), float(other[1] - me[1]))
        if math.hypot(*normal) < EPS:
            continue
        # |p - me|^2 <= |p - other|^2  <=>  2 (other - me) . p <= |other|^2 - |me|^2
        offset = 0.5 * (float(other @ other) - float(me @ me))
        cell = _clip(cell, normal, offset)
        if len(cell) < 3:
            return []
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
