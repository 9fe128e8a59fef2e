"""Exact minimum-zone width of a point set (straightness in a plane, flatness).

The minimum-width slab holding a point set is determined by its convex hull:
in 2D one side of the optimal strip is flush with a hull edge (rotating
calipers); in 3D the optimal slab touches the hull either facet-vertex or
edge-edge (Houle & Toussaint 1988).  We evaluate the width in every such
candidate direction (all facet normals and the normals of all edge pairs)
and take the smallest, so the result is exact.  Cost: O(h^2) candidates for
h hull vertices, vectorised in chunks.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

_CHUNK = 20000


def _best_direction(vertices: np.ndarray, candidates: np.ndarray) -> tuple[float, np.ndarray]:
    best_w, best_n = np.inf, candidates[0]
    for start in range(0, len(candidates), _CHUNK):
        n = candidates[start:start + _CHUNK]
        proj = vertices @ n.T
        w = proj.max(axis=0) - proj.min(axis=0)
        k = int(np.argmin(w))
        if w[k] < best_w:
            best_w, best_n = float(w[k]), n[k]
    return best_w, best_n


def _normalised(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=1)
    keep = norm > 1e-12 * max(norm.max(initial=0.0), 1e-300)
    return v[keep] / norm[keep, None]


def min_width_direction(points: np.ndarray) -> tuple[float, np.ndarray]:
    """Width and unit normal of the thinnest slab (2D strip) holding centred points.

    Falls back to the least-squares normal when the hull is degenerate
    (points exactly collinear / coplanar: width 0 in that direction).
    """
    dim = points.shape[1]
    try:
        hull = ConvexHull(points)
    except (QhullError, ValueError):
        _, _, vt = np.linalg.svd(points, full_matrices=False)
        n = vt[-1]
        proj = points @ n
        return float(proj.max() - proj.min()), n
    vertices = points[hull.vertices]
    candidates = [hull.equations[:, :dim]]
    if dim == 3:
        simplices = hull.simplices
        edges = np.sort(np.concatenate([simplices[:, [0, 1]], simplices[:, [1, 2]], simplices[:, [0, 2]]]), axis=1)
        edges = np.unique(edges, axis=0)
        vec = points[edges[:, 1]] - points[edges[:, 0]]
        i, j = np.triu_indices(len(vec), k=1)
        for start in range(0, len(i), _CHUNK * 10):
            sl = slice(start, start + _CHUNK * 10)
            candidates.append(_normalised(np.cross(vec[i[sl]], vec[j[sl]])))
    return _best_direction(vertices, np.concatenate(candidates))


# ---------------------------------------------------------------- fast flatness (LP + certificate)


def _vertical_width_lp(local: np.ndarray) -> tuple[float, np.ndarray]:
    """min over (a, b) of max(w - a u - b v) - min(w - a u - b v): a linear program (convex)."""
    from scipy.optimize import linprog

    m = len(local)
    u, v, w = local.T
    # variables (a, b, lo, hi); minimise hi - lo with lo <= w - a u - b v <= hi
    c = np.array([0.0, 0.0, -1.0, 1.0])
    ones, zeros = np.ones(m), np.zeros(m)
    a_ub = np.vstack([np.column_stack([-u, -v, zeros, -ones]),   # w - au - bv <= hi
                      np.column_stack([u, v, ones, zeros])])     # lo <= w - au - bv
    b_ub = np.concatenate([-w, w])
    res = linprog(c, A_ub=a_ub, b_ub=b_ub, bounds=[(None, None)] * 4, method="highs")
    if res.status != 0:
        raise RuntimeError(res.message)
    return float(res.fun), res.x[:2]


def min_width_3d(points: np.ndarray, normal: np.ndarray) -> tuple[float, np.ndarray, float]:
    """Thinnest slab holding centred 3D points, started at `normal` (e.g. the LS plane's).

    Works on the convex hull vertices.  In a frame with axis n the vertical width
    W(a, b) of the tilted direction (-a, -b, 1) is convex, so a linear program finds
    its global minimum; the frame is moved to the new direction until the step
    vanishes, which makes the direction stationary for the true width W / sqrt(1 + a^2 + b^2).
    Certificate: for every direction, width >= W* / sqrt(1 + t1^2) with
    t1 = (W* + Zr) / Wxy (Zr: height range in the final frame, Wxy: the exact minimum
    width of the points projected into the plane), because W(v) >= max(W*, |v| Wxy - Zr).
    Returns (width, unit normal, gap) where gap = width - that lower bound: the result is
    the global optimum to within gap (about W* t1^2 / 2, ~1e-11 mm for a flat plate).
    """
    from scipy.spatial import ConvexHull as _Hull

    try:
        verts = points[_Hull(points).vertices]
    except (QhullError, ValueError):
        verts = points
    n = normal / np.linalg.norm(normal)
    for _ in range(8):
        helper = np.eye(3)[np.argmin(np.abs(n))]
        e1 = np.cross(helper, n)
        e1 /= np.linalg.norm(e1)
        frame = np.column_stack([e1, np.cross(n, e1), n])
        _, ab = _vertical_width_lp(verts @ frame)
        step = float(np.hypot(*ab))
        n = frame @ np.array([-ab[0], -ab[1], 1.0])
        n /= np.linalg.norm(n)
        if step < 1e-15:
            break
    proj = verts @ n
    width = float(proj.max() - proj.min())
    # certificate in the final frame
    helper = np.eye(3)[np.argmin(np.abs(n))]
    e1 = np.cross(helper, n)
    e1 /= np.linalg.norm(e1)
    frame = np.column_stack([e1, np.cross(n, e1), n])
    local = verts @ frame
    w_star, _ = _vertical_width_lp(local)
    w_xy, _ = min_width_direction(local[:, :2])
    z_range = float(np.ptp(local[:, 2]))
    if w_xy <= 0:
        return width, n, float("inf")
    t1 = (w_star + z_range) / w_xy
    lower = w_star / np.sqrt(1.0 + t1 * t1)
    return width, n, max(width - lower, 0.0)
