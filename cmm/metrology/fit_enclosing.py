"""Exact minimum circumscribed and maximum inscribed circles / spheres.

- min_enclosing_ball: Welzl's algorithm (randomised incremental, expected
  linear time) in 2D or 3D on the convex hull vertices: exact.
- max_inscribed_ball: the centre of the largest empty circle/sphere whose
  centre lies inside the convex hull is a Voronoi vertex of the points
  (scipy.spatial.Voronoi); we take the vertex inside the hull farthest from
  its nearest point: exact.  Meaningful when the points surround the
  centre (a bore probed all round).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError, Voronoi, cKDTree

from cmm.metrology.features import FitError


def _circumball(boundary: list[np.ndarray]) -> tuple[np.ndarray, float]:
    """Smallest ball with all boundary points on its surface (they are affinely independent)."""
    p0 = boundary[0]
    if len(boundary) == 1:
        return p0.copy(), 0.0
    if len(boundary) == 2:  # hot path: the midpoint (lstsq costs ~10x more)
        c = 0.5 * (p0 + boundary[1])
        return c, float(np.sqrt((c - p0) @ (c - p0)))
    a = np.array(boundary[1:]) - p0
    g, rhs = 2.0 * a @ a.T, np.einsum("ij,ij->i", a, a)
    try:
        lam = np.linalg.solve(g, rhs)
        if not np.all(np.isfinite(lam)):
            raise np.linalg.LinAlgError
    except np.linalg.LinAlgError:  # (nearly) dependent boundary points
        lam, *_ = np.linalg.lstsq(g, rhs, rcond=None)
    c = p0 + a.T @ lam
    return c, float(np.sqrt((c - p0) @ (c - p0)))


def _welzl(pts: np.ndarray, n: int, boundary: list[np.ndarray], tol: float) -> tuple[np.ndarray, float]:
    """Smallest ball holding pts[:n] with `boundary` on its surface (iterative Welzl, depth <= d+1)."""
    if boundary:
        c, r = _circumball(boundary)
    else:
        c, r = np.zeros(pts.shape[1]), -1.0
    if len(boundary) == pts.shape[1] + 1:
        return c, r
    start = 0
    while start < n:
        dist = np.linalg.norm(pts[start:n] - c, axis=1)
        outside = np.nonzero(dist > r + tol)[0]
        if outside.size == 0:
            break
        i = start + int(outside[0])
        c, r = _welzl(pts, i, boundary + [pts[i]], tol)
        start = i + 1
    return c, r


def _hull_vertices(points: np.ndarray) -> np.ndarray:
    try:
        return points[ConvexHull(points).vertices]
    except (QhullError, ValueError):
        return points


def min_enclosing_ball(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Exact minimum enclosing circle (2D) or sphere (3D) of centred, scaled points."""
    pts = _hull_vertices(points)
    pts = pts[np.random.default_rng(12345).permutation(len(pts))]  # fixed seed: reproducible results
    return _welzl(pts, len(pts), [], 1e-13)


def min_enclosing_ball_from(points: np.ndarray, support: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """The same exact ball, started from ``support`` (indices, e.g. the support of a nearby problem): the ball
    of a subset that holds every point is the ball of all of them (it can only be smaller for a subset).
    Elzinga-Hearn: the ball of the current support and the farthest point outside it, whose radius grows
    every step, until no point is outside. Returns (centre, radius, the support's indices)."""
    active = np.unique(np.asarray(support, dtype=np.int64))
    if len(active) == 0:
        active = np.array([0])
    for _ in range(4 * len(points) + 8):
        sub = points[active]
        c, r = _welzl(sub, len(sub), [], 1e-13)
        dist = np.sqrt(((points - c) ** 2).sum(axis=1))
        far = int(np.argmax(dist))
        if dist[far] <= r * (1.0 + 1e-12) + 1e-13:
            return c, r, active
        on = active[dist[active] >= r * (1.0 - 1e-9) - 1e-12]  # the support: the subset's points on its ball
        active = np.append(on, far)
    c, r = min_enclosing_ball(points)  # not converged (rounding): Welzl on every point
    return c, r, np.arange(len(points))


def max_inscribed_ball(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Exact maximum inscribed circle (2D) or sphere (3D), centre inside the hull."""
    try:
        hull = ConvexHull(points)
        vertices = Voronoi(points).vertices
    except (QhullError, ValueError) as exc:
        raise FitError(f"the points do not enclose an area or volume: {str(exc).splitlines()[0]}") from None
    inside = np.all(vertices @ hull.equations[:, :-1].T + hull.equations[:, -1] <= 1e-12, axis=1)
    if not inside.any():
        raise FitError("no inscribed circle or sphere: the points do not surround a centre")
    cand = vertices[inside]
    dist, _ = cKDTree(points).query(cand)
    k = int(np.argmax(dist))
    return cand[k], float(dist[k])
