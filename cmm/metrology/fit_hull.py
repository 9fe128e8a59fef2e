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
