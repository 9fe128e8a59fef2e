"""Known-answer test data by the null-space method (Forbes & Minh 2012).

Choose the answer, points on its surface and their unit normals.  The
Jacobian J of the orthogonal distances w.r.t. the feature's degrees of
freedom is built here *independently of the fitting code*: a rigid motion
with translation t and rotation w moves the surface at x by t + w x (x - x0),
which changes the signed distance by -n.(t + w x (x - x0)); so the columns
for the 6 rigid motions are the components of n and of (x - x0) x n, plus one
column per shape parameter.  Symmetries give zero columns, which is harmless:
the last m - n columns Q2 of a full QR of J are still orthogonal to range(J).
e = Q2 c is scaled to the wanted form error and each point is moved along
its normal by e_i; the chosen answer is then exactly the least-squares
solution and e are its residuals.

Features with two residual components per point (3D line, 3D circle) pass
normals of shape (m, 2, 3).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class KnownAnswer:
    points: np.ndarray
    answer: dict
    residuals: np.ndarray  # e, per residual component (m or 2m values)
    n_params: int
    extra: dict = field(default_factory=dict)


def _frame(u: np.ndarray) -> np.ndarray:
    u = u / np.linalg.norm(u)
    a = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(u, a)
    e1 /= np.linalg.norm(e1)
    return np.column_stack([e1, np.cross(u, e1), u])


def perturb(points, normals, shape_columns, x0, form, rng, n_params):
    """Move points along normals by a null-space vector scaled to `form` (max - min)."""
    normals = normals if normals.ndim == 3 else normals[:, None, :]
    k = normals.shape[1]
    rows_n = normals.transpose(1, 0, 2).reshape(-1, 3)  # component-major: all h, then all radial
    rows_x = np.tile(points - x0, (k, 1))
    cols = [rows_n, np.cross(rows_x, rows_n)]
    if shape_columns is not None:
        cols.append(np.asarray(shape_columns).reshape(len(rows_n), -1))
    jac = np.column_stack(cols)
    # symmetries give columns that are zero up to rounding (e.g. 1e-13 at 1000 mm): drop them
    norms = np.linalg.norm(jac, axis=0)
    jac = jac[:, norms > 1e-9 * norms.max()]
    rank = np.linalg.matrix_rank(jac, tol=1e-9 * np.linalg.norm(jac, 2))
    assert rank == n_params, f"constructed Jacobian has rank {rank}, expected {n_params}"
    if len(jac) <= 2000:
        q, _ = np.linalg.qr(jac, mode="complete")
        q2 = q[:, jac.shape[1]:]
        e = q2 @ rng.standard_normal(q2.shape[1])
    else:  # same subspace without the m x m Q: e = (I - Q1 Q1^T) c = Q2 (Q2^T c)
        q1, _ = np.linalg.qr(jac)
        c = rng.standard_normal(len(jac))
        e = c - q1 @ (q1.T @ c)
    if form > 0:
        e *= form / (e.max() - e.min())
    else:
        e[:] = 0.0
    moved = points + (e.reshape(k, -1).T[:, :, None] * normals).sum(axis=1)
    return moved, e


def _angles(m, arc_deg, rng):
    return np.radians(arc_deg) * (np.arange(m) + 0.5 * rng.random(m)) / m


def sphere(center, radius, m=60, cap_deg=360.0, form=0.01, seed=0) -> KnownAnswer:
    """Points on a full sphere or on a cap of opening angle cap_deg around +z."""
    rng = np.random.default_rng(seed)
    if cap_deg >= 360:
        n = rng.standard_normal((m, 3))
    else:
        polar = np.radians(cap_deg) / 2 * np.sqrt(rng.random(m))
        az = rng.uniform(0, 2 * np.pi, m)
        n = np.column_stack([np.sin(polar) * np.cos(az), np.sin(polar) * np.sin(az), np.cos(polar)])
    n /= np.linalg.norm(n, axis=1)[:, None]
    x = center + radius * n
    pts, e = perturb(x, n, np.ones(m), center, form, rng, 4)
    return KnownAnswer(pts, {"center": np.asarray(center, float), "radius": radius}, e, 4)


def plane(point, normal, m=40, size=50.0, form=0.01, seed=0) -> KnownAnswer:
    rng = np.random.default_rng(seed)
    f = _frame(np.asarray(normal, float))
    uv = rng.uniform(-size / 2, size / 2, (m, 2))
    x = point + uv @ f[:, :2].T
    n = np.tile(f[:, 2], (m, 1))
    pts, e = perturb(x, n, None, point, form, rng, 3)
    return KnownAnswer(pts, {"point": np.asarray(point, float), "normal": f[:, 2]}, e, 3)


def line(point, direction, m=30, length=100.0, form=0.01, seed=0) -> KnownAnswer:
    rng = np.random.default_rng(seed)
    f = _frame(np.asarray(direction, float))
    t = np.linspace(-length / 2, length / 2, m)
    x = point + np.outer(t, f[:, 2])
    normals = np.stack([np.tile(f[:, 0], (m, 1)), np.tile(f[:, 1], (m, 1))], axis=1)
    pts, e = perturb(x, normals, None, point, form, rng, 4)
    return KnownAnswer(pts, {"point": np.asarray(point, float), "direction": f[:, 2]}, e, 4)


def circle2d(center, radius, m=30, arc_deg=360.0, form=0.01, seed=0) -> KnownAnswer:
    rng = np.random.default_rng(seed)
    t = _angles(m, arc_deg, rng)
    n2 = np.column_stack([np.cos(t), np.sin(t)])
    # embed in z = 0 to reuse the 3D builder; z motions give zero rows' worth of columns
    n = np.column_stack([n2, np.zeros(m)])
    c3 = np.array([*center, 0.0])
    pts, e = perturb(c3 + radius * n, n, np.ones(m), c3, form, rng, 3)
    return KnownAnswer(pts[:, :2], {"center": np.asarray(center, float), "radius": radius}, e, 3)


def circle3d(center, normal, radius, m=30, arc_deg=360.0, form=0.01, seed=0) -> KnownAnswer:
    rng = np.random.default_rng(seed)
    f = _frame(np.asarray(normal, float))
    t = _angles(m, arc_deg, rng)
    radial = np.outer(np.cos(t), f[:, 0]) + np.outer(np.sin(t), f[:, 1])
    x = center + radius * radial
    normals = np.stack([np.tile(f[:, 2], (m, 1)), radial], axis=1)
    shape = np.concatenate([np.zeros(m), np.ones(m)])
    pts, e = perturb(x, normals, shape, center, form, rng, 6)
    return KnownAnswer(pts, {"center": np.asarray(center, float), "normal": f[:, 2], "radius": radius}, e, 6)


def circle3d_standard(center, normal, radius, m=30, arc_deg=360.0, form=0.01, plane_form=0.01, seed=0) -> KnownAnswer:
    """Known answer for the standard 3D circle (least-squares plane, then the 2D circle in it).

    The out-of-plane offsets h are a null vector of the plane's Jacobian (1, u, v) and the
    in-plane radial offsets e one of the 2D circle's (cos t, sin t, 1), so the chosen plane is
    the points' least-squares plane and the chosen circle the least-squares circle of their
    projections.  residuals = (h, e); n_params = 6.
    """
    rng = np.random.default_rng(seed)
    f = _frame(np.asarray(normal, float))
    t = _angles(m, arc_deg, rng)
    radial = np.outer(np.cos(t), f[:, 0]) + np.outer(np.sin(t), f[:, 1])
    x = center + radius * radial
    e = _null_vector(np.column_stack([np.cos(t), np.sin(t), np.ones(m)]), form, rng)
    inplane = (radius + e)[:, None] * np.column_stack([np.cos(t), np.sin(t)])  # final in-plane coordinates
    h = _null_vector(np.column_stack([np.ones(m), inplane]), plane_form, rng)
    pts = x + h[:, None] * f[:, 2] + e[:, None] * radial
    # the centroid must lie in the plane through the centre: h sums to zero by construction
    return KnownAnswer(pts, {"center": np.asarray(center, float), "normal": f[:, 2], "radius": radius},
                       np.concatenate([h, e]), 6)


def _null_vector(jac, form, rng):
    q1, _ = np.linalg.qr(jac)  # e = (I - Q1 Q1^T) c spans the null space of J^T
    c = rng.standard_normal(len(jac))
    e = c - q1 @ (q1.T @ c)
    return e * (form / (e.max() - e.min())) if form > 0 else 0.0 * e


def cylinder(point, direction, radius, m=60, length=40.0, arc_deg=360.0, form=0.01, seed=0) -> KnownAnswer:
    rng = np.random.default_rng(seed)
    f = _frame(np.asarray(direction, float))
    t = _angles(m, arc_deg, rng)
    z = rng.uniform(-length / 2, length / 2, m)
    radial = np.outer(np.cos(t), f[:, 0]) + np.outer(np.sin(t), f[:, 1])
    x = point + radius * radial + np.outer(z, f[:, 2])
    pts, e = perturb(x, radial, np.ones(m), point, form, rng, 5)
    return KnownAnswer(pts, {"point": np.asarray(point, float), "direction": f[:, 2], "radius": radius}, e, 5)


def cone(apex, direction, half_angle, m=60, z_range=(10.0, 30.0), arc_deg=360.0, form=0.01, seed=0) -> KnownAnswer:
    rng = np.random.default_rng(seed)
    f = _frame(np.asarray(direction, float))
    t = _angles(m, arc_deg, rng)
    z = rng.uniform(*z_range, m)
    radial = np.outer(np.cos(t), f[:, 0]) + np.outer(np.sin(t), f[:, 1])
    x = apex + np.tan(half_angle) * z[:, None] * radial + np.outer(z, f[:, 2])
    normal = np.cos(half_angle) * radial - np.sin(half_angle) * f[:, 2]
    slant = z / np.cos(half_angle)  # rotating a generator about the apex moves the point by slant * dpsi
    pts, e = perturb(x, normal, slant, apex, form, rng, 6)
    return KnownAnswer(pts, {"apex": np.asarray(apex, float), "direction": f[:, 2], "half_angle": half_angle}, e, 6)


def torus(center, normal, major, minor, m=80, form=0.01, seed=0) -> KnownAnswer:
    rng = np.random.default_rng(seed)
    f = _frame(np.asarray(normal, float))
    t = rng.uniform(0, 2 * np.pi, m)
    ph = rng.uniform(0, 2 * np.pi, m)
    radial = np.outer(np.cos(t), f[:, 0]) + np.outer(np.sin(t), f[:, 1])
    n = np.cos(ph)[:, None] * radial + np.outer(np.sin(ph), f[:, 2])
    x = center + major * radial + minor * n
    shape = np.column_stack([np.einsum("ij,ij->i", radial, n), np.ones(m)])
    pts, e = perturb(x, n, shape, center, form, rng, 7)
    answer = {"center": np.asarray(center, float), "normal": f[:, 2], "major_radius": major, "minor_radius": minor}
    return KnownAnswer(pts, answer, e, 7)
