"""Planar polygon tests shared by the script API's geofence and the safety supervisor."""

from __future__ import annotations

from collections.abc import Sequence

Point = tuple[float, float]


def inside(p: Point, polygon: Sequence[Point]) -> bool:
    """Whether `p` lies inside (or on the edge of) a simple polygon, by ray casting."""
    x, y = p
    n = len(polygon)
    if n < 3:
        return False
    hit = False
    for i in range(n):
        (x1, y1), (x2, y2) = polygon[i], polygon[(i + 1) % n]
        if _on_segment(p, (x1, y1), (x2, y2)):
            return True
        if (y1 > y) != (y2 > y):
            xc = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
            if xc > x:
                hit = not hit
    return hit


def _on_segment(p: Point, a: Point, b: Point, eps: float = 1e-9) -> bool:
    cross = (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0])
    if abs(cross) > eps * max(1.0, abs(b[0] - a[0]) + abs(b[1] - a[1])):
        return False
    return min(a[0], b[0]) - eps <= p[0] <= max(a[0], b[0]) + eps and (
        min(a[1], b[1]) - eps <= p[1] <= max(a[1], b[1]) + eps
    )


def segment_exit(start: Point, end: Point, polygon: Sequence[Point]) -> Point | None:
    """The first point where the segment start->end crosses the polygon's boundary, or None."""
    best: tuple[float, Point] | None = None
    sx, sy = start
    dx, dy = end[0] - sx, end[1] - sy
    n = len(polygon)
    for i in range(n):
        (ax, ay), (bx, by) = polygon[i], polygon[(i + 1) % n]
        ex, ey = bx - ax, by - ay
        denom = dx * ey - dy * ex
        if denom == 0:
            continue  # parallel
        t = ((ax - sx) * ey - (ay - sy) * ex) / denom
        u = ((ax - sx) * dy - (ay - sy) * dx) / denom
        if 0.0 <= t <= 1.0 and 0.0 <= u <= 1.0 and (best is None or t < best[0]):
            best = (t, (sx + t * dx, sy + t * dy))
    return best[1] if best is not None else None
