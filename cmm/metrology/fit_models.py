"""Orthogonal-distance models with analytic Jacobians (for fit_solver).

All models work on centred (and scaled) points X.  Each Jacobian is taken
w.r.t. a minimal local parametrisation at the current state, with the axis
frame R (third column = current axis) so the linearisation is always at
"zero tilt":

- ball (circle 2D / sphere): centre c, radius r; d = |x - c| - r.
- circle 3D: centre c, normal n, radius r; two residuals per point:
  h = (x - c).n (out of plane) and rho - r (in plane), whose squares sum to
  the squared 3D distance to the circle.  Local params (a, b, c_n, alpha,
  beta, dr): centre + R(a, b, c_n), normal R(alpha, beta, 1)/|.|.
- cylinder: axis point p in the plane through the centroid, direction u,
  radius r; local (a, b, alpha, beta, dr); d = rho - r.
- cone: p, u as the cylinder, s = radius at p, psi = half angle;
  d = (rho - s) cos psi - z sin psi; local (a, b, alpha, beta, ds, dpsi).
- torus: centre c, axis u, radii R, r; d = sqrt((rho - R)^2 + z^2) - r;
  local (a, b, c_n, alpha, beta, dR, dr).

(x, y, z) below are the point coordinates in the frame R at the axis point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmm.metrology.geom_basics import frame_with_axis, tilt


def _local(points: np.ndarray, origin: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    frame = frame_with_axis(axis)
    return frame, (points - origin) @ frame


def _safe_rho(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    rho = np.hypot(x, y)
    return np.where(rho > 0.0, rho, np.finfo(float).tiny)


@dataclass
class BallModel:
    """Circle in 2D or sphere in 3D. State: (centre, radius)."""

    points: np.ndarray
    kind: str = "sphere"
    units: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        self.units = (1,) * (self.points.shape[1] + 1)

    def residuals_jacobian(self, state):
        c, r = state
        diff = self.points - c
        dist = np.linalg.norm(diff, axis=1)
        dist = np.where(dist > 0.0, dist, np.finfo(float).tiny)
        jac = np.column_stack([-diff / dist[:, None], -np.ones(len(dist))])
        return dist - r, jac

    def update(self, state, step):
        c, r = state
        return c + step[:-1], r + step[-1]


@dataclass
class Circle3Model:
    points: np.ndarray
    kind: str = "circle"
    units: tuple[int, ...] = (1, 1, 1, 0, 0, 1)

    def residuals_jacobian(self, state):
        c, n, r = state
        _, loc = _local(self.points, c, n)
        x, y, h = loc.T
        rho = _safe_rho(x, y)
        zeros, ones = np.zeros_like(x), np.ones_like(x)
        jac_h = np.column_stack([zeros, zeros, -ones, x, y, zeros])
        jac_r = np.column_stack([-x / rho, -y / rho, zeros, -h * x / rho, -h * y / rho, -ones])
        return np.concatenate([h, rho - r]), np.vstack([jac_h, jac_r])

    def update(self, state, step):
        c, n, r = state
        frame = frame_with_axis(n)
        return c + frame @ step[:3], tilt(frame, step[3], step[4]), r + step[5]


def _recentre_axis(p: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, float]:
    """Move p along u into the plane through the origin (the centroid); return p and the shift."""
    t = -float(p @ u)
    return p + t * u, t


@dataclass
class CylinderModel:
    points: np.ndarray
    kind: str = "cylinder"
    units: tuple[int, ...] = (1, 1, 0, 0, 1)

    def residuals_jacobian(self, state):
        p, u, r = state
        _, loc = _local(self.points, p, u)
        x, y, z = loc.T
        rho = _safe_rho(x, y)
        jac = np.column_stack([-x / rho, -y / rho, -x * z / rho, -y * z / rho, -np.ones_like(x)])
        return rho - r, jac

    def update(self, state, step):
        p, u, r = state
        frame = frame_with_axis(u)
        p = p + frame @ np.array([step[0], step[1], 0.0])
        u = tilt(frame, step[2], step[3])
        p, _ = _recentre_axis(p, u)
        return p, u, r + step[4]


@dataclass
class ConeModel:
    points: np.ndarray
    kind: str = "cone"
    units: tuple[int, ...] = (1, 1, 0, 0, 1, 0)

    def residuals_jacobian(self, state):
        p, u, s, psi = state
        _, loc = _local(self.points, p, u)
        x, y, z = loc.T
        rho = _safe_rho(x, y)
        cp, sp = np.cos(psi), np.sin(psi)
        d = (rho - s) * cp - z * sp
        jac = np.column_stack(
            [
                -cp * x / rho,
                -cp * y / rho,
                -cp * x * z / rho - sp * x,
                -cp * y * z / rho - sp * y,
                -cp * np.ones_like(x),
                -(rho - s) * sp - z * cp,
            ]
        )
        return d, jac

    def update(self, state, step):
        p, u, s, psi = state
        frame = frame_with_axis(u)
        p = p + frame @ np.array([step[0], step[1], 0.0])
        u = tilt(frame, step[2], step[3])
        s, psi = s + step[4], psi + step[5]
        p, t = _recentre_axis(p, u)
        return p, u, s + t * np.tan(psi), psi


@dataclass
class TorusModel:
    points: np.ndarray
    kind: str = "torus"
    units: tuple[int, ...] = (1, 1, 1, 0, 0, 1, 1)

    def residuals_jacobian(self, state):
        c, u, big_r, r = state
        _, loc = _local(self.points, c, u)
        x, y, z = loc.T
        rho = _safe_rho(x, y)
        q = np.hypot(rho - big_r, z)
        q = np.where(q > 0.0, q, np.finfo(float).tiny)
        w = (rho - big_r) / q
        jac = np.column_stack(
            [
                -w * x / rho,
                -w * y / rho,
                -z / q,
                z * x * big_r / (rho * q),
                z * y * big_r / (rho * q),
                -w,
                -np.ones_like(x),
            ]
        )
        return q - r, jac

    def update(self, state, step):
        c, u, big_r, r = state
        frame = frame_with_axis(u)
        return c + frame @ step[:3], tilt(frame, step[3], step[4]), big_r + step[5], r + step[6]
