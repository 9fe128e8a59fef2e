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


def _vertical_width_lp_all(local: np.ndarray) -> tuple[float, np.ndarray, float]:
    """min over (a, b) of max(w - a u - b v) - min(w - a u - b v), one linear program on every point.

    Returns (width, (a, b), lo) with lo the minimum of w - a u - b v at the optimum. The LP is solved
    with u, v in units of their extent and w in units of its range, so the solver's absolute
    tolerances (1e-7) are relative to the zone, not to millimetres."""
    from scipy.optimize import linprog

    m = len(local)
    su = max(float(np.abs(local[:, :2]).max()), 1e-300)
    sw = float(np.ptp(local[:, 2]))
    sw = sw if sw > 0 else 1.0
    u, v, w = local[:, 0] / su, local[:, 1] / su, local[:, 2] / sw
    # variables (a, b, lo, hi); minimise hi - lo with lo <= w - a u - b v <= hi
    c = np.array([0.0, 0.0, -1.0, 1.0])
    ones, zeros = np.ones(m), np.zeros(m)
    a_ub = np.vstack([np.column_stack([-u, -v, zeros, -ones]),   # w - au - bv <= hi
                      np.column_stack([u, v, ones, zeros])])     # lo <= w - au - bv
    b_ub = np.concatenate([-w, w])
    res = linprog(c, A_ub=a_ub, b_ub=b_ub, bounds=[(None, None)] * 4, method="highs")
    if res.status != 0:
        raise RuntimeError(res.message)
    ab = res.x[:2] * sw / su
    r = local[:, 2] - local[:, :2] @ ab  # the zone of the solution, exactly
    return float(r.max() - r.min()), ab, float(r.min())


ACTIVE_START = 256  # points in the first linear program of the constraint generation
ACTIVE_ADD = 128  # most violating points added per side and round


def _vertical_width_lp(local: np.ndarray, active: np.ndarray | None = None) -> tuple[float, np.ndarray, np.ndarray]:
    """The same optimum as _vertical_width_lp_all by constraint generation: the LP on a small active set
    (a spread sample and the extremes), then every point is checked and the most violating ones join the
    set until none violates; the optimum of the LP over the active set is then that over all points
    (its constraints are a subset, and its solution satisfies all). Cost: a few small LPs and a few
    passes over the points, whatever the shape (a bowed plate has every point on its hull).
    ``active``: indices to start from (the set a previous, nearby frame ended with); the set this
    one ended with is returned third."""
    m = len(local)
    if m <= 4 * ACTIVE_START:
        width, ab, _ = _vertical_width_lp_all(local)
        return width, ab, np.arange(m)
    u, v, w = (np.ascontiguousarray(c) for c in local.T)
    if active is None:
        step = max(1, m // ACTIVE_START)
        active = np.unique(np.concatenate([np.arange(0, m, step), [np.argmax(w), np.argmin(w), np.argmax(u),
                                                                     np.argmin(u), np.argmax(v), np.argmin(v)]]))
    for _ in range(200):
        # the zone of the active set's optimum, evaluated exactly: active points never count as violating
        width, ab, lo = _vertical_width_lp_all(local[active])
        r = w - ab[0] * u - ab[1] * v
        hi = lo + width
        tol = 1e-13 * max(float(np.abs(w).max()), 1.0)
        above, below = np.flatnonzero(r > hi + tol), np.flatnonzero(r < lo - tol)
        if len(above) == 0 and len(below) == 0:
            return float(r.max() - r.min()), ab, active
        add = []
        for idx, key in ((above, -r), (below, r)):
            if len(idx) > ACTIVE_ADD:
                idx = idx[np.argpartition(key[idx], ACTIVE_ADD)[:ACTIVE_ADD]]
            add.append(idx)
        active = np.union1d(active, np.concatenate(add))
    width, ab, _ = _vertical_width_lp_all(local)  # not converged (never seen): the LP on every point
    return width, ab, np.arange(m)


def _hull_prefilter_2d(xy: np.ndarray, directions: int = 16) -> np.ndarray:
    """The points that may be 2D hull vertices: those not strictly inside the polygon of the extreme points
    in ``directions`` directions (Akl-Toussaint), so qhull sees a few points, not a million."""
    if len(xy) < 1000:
        return xy
    xt = np.ascontiguousarray(xy.T)  # 2 x m: every pass below runs along contiguous rows
    ang = np.linspace(0.0, np.pi, directions // 2, endpoint=False)
    proj = np.column_stack([np.cos(ang), np.sin(ang)]) @ xt
    ext = np.unique(np.concatenate([proj.argmax(axis=1), proj.argmin(axis=1)]))
    try:
        eq = ConvexHull(xt[:, ext].T).equations
    except (QhullError, ValueError):
        return xy
    tol = 1e-12 * max(float(np.abs(xt).max()), 1.0)
    maybe = np.zeros(xt.shape[1], bool)
    for a, b, c in eq:  # outside or on any edge of the polygon: possibly a hull vertex
        maybe |= a * xt[0] + b * xt[1] + c >= -tol
    return xy[maybe]


def min_width_3d(points: np.ndarray, normal: np.ndarray) -> tuple[float, np.ndarray, float]:
    """Thinnest slab holding centred 3D points, started at `normal` (e.g. the LS plane's).

    In a frame with axis n the vertical width W(a, b) of the tilted direction (-a, -b, 1)
    is convex, so a linear program finds its global minimum (by constraint generation over
    the points: a few small LPs whatever the shape); the frame is moved to the new direction
    until the step vanishes, which makes the direction stationary for the true width
    W / sqrt(1 + a^2 + b^2).
    Certificate: for every direction, width >= W* / sqrt(1 + t1^2) with
    t1 = (W* + Zr) / Wxy (Zr: height range in the final frame, Wxy: the exact minimum
    width of the points projected into the plane), because W(v) >= max(W*, |v| Wxy - Zr).
    Returns (width, unit normal, gap) where gap = width - that lower bound: the result is
    the global optimum to within gap (about W* t1^2 / 2, ~1e-11 mm for a flat plate).
    """
    verts = points
    n = normal / np.linalg.norm(normal)
    active = None  # the points that bound the zone stay nearly the same from frame to frame
    for _ in range(8):
        helper = np.eye(3)[np.argmin(np.abs(n))]
        e1 = np.cross(helper, n)
        e1 /= np.linalg.norm(e1)
        frame = np.column_stack([e1, np.cross(n, e1), n])
        _, ab, active = _vertical_width_lp(verts @ frame, active)
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
    w_star, _, _ = _vertical_width_lp(local, active)
    w_xy, _ = min_width_direction(_hull_prefilter_2d(local[:, :2]))
    z_range = float(np.ptp(local[:, 2]))
    if w_xy <= 0:
        return width, n, float("inf")
    t1 = (w_star + z_range) / w_xy
    lower = w_star / np.sqrt(1.0 + t1 * t1)
    return width, n, max(width - lower, 0.0)
