"""Closed-form projection of points onto analytic surfaces (plane, cylinder, cone, sphere, torus), vectorised.

Every function takes (n, 3) points and the surface's parameters (part coordinates, mm) and returns the foot
points (n, 3), the signed distances (n,) and the unit normals (n, 3) at the feet, signed along the surface's
*natural* normal:

    plane     normal ``n``
    cylinder  away from the axis
    cone      away from the axis (the side the cone's solid is not on)
    sphere    away from the centre
    torus     away from the tube's centre circle

A face's material side is this natural normal times its ``sense`` (+1 or -1, :class:`cmm.cad.model.CadFace`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
Projection = tuple[Array, Array, Array]


def _radial(p: Array, origin: Array, axis: Array) -> tuple[Array, Array, Array]:
    """Axial coordinate h, radial distance rho and unit radial direction of points about an axis."""
    d = p - origin
    h = d @ axis
    r = d - h[:, None] * axis
    rho = np.linalg.norm(r, axis=1)
    e = np.empty_like(r)
    ok = rho > 1e-300
    e[ok] = r[ok] / rho[ok, None]
    if (~ok).any():  # on the axis: any radial direction
        ref = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        x = np.cross(axis, ref)
        e[~ok] = x / np.linalg.norm(x)
    return h, rho, e


def plane(p: Array, origin: Array, normal: Array) -> Projection:
    d = (p - origin) @ normal
    return p - d[:, None] * normal, d, np.broadcast_to(normal, p.shape).copy()


def cylinder(p: Array, origin: Array, axis: Array, radius: float) -> Projection:
    h, rho, e = _radial(p, origin, axis)
    foot = origin + h[:, None] * axis + radius * e
    return foot, rho - radius, e


def sphere(p: Array, centre: Array, radius: float) -> Projection:
    d = p - centre
    rho = np.linalg.norm(d, axis=1)
    e = np.empty_like(d)
    ok = rho > 1e-300
    e[ok] = d[ok] / rho[ok, None]
    e[~ok] = (0.0, 0.0, 1.0)
    return centre + radius * e, rho - radius, e


def cone(p: Array, apex: Array, axis: Array, half_angle: float) -> Projection:
    """``axis`` points from the apex into the cone (the nappe the face lies on)."""
    h, rho, e = _radial(p, apex, axis)
    c, s = np.cos(half_angle), np.sin(half_angle)
    t = np.maximum(rho * s + h * c, 0.0)  # along the generator; behind the apex the apex is closest
    foot = apex + t[:, None] * (s * e + c * axis)
    normal = c * e - s * axis
    dist = rho * c - h * s
    behind = (rho * s + h * c) < 0
    if behind.any():  # nearest point is the apex itself
        v = p[behind] - apex
        n = np.linalg.norm(v, axis=1)
        dist[behind] = n * np.sign(dist[behind])
    return foot, dist, normal


def torus(p: Array, centre: Array, axis: Array, major: float, minor: float) -> Projection:
    h, rho, e = _radial(p, centre, axis)
    ring = centre + major * e  # nearest point of the tube's centre circle
    v = p - ring
    n = np.linalg.norm(v, axis=1)
    u = np.empty_like(v)
    ok = n > 1e-300
    u[ok] = v[ok] / n[ok, None]
    u[~ok] = axis
    return ring + minor * u, n - minor, u


def project(kind: str, params: dict, p: Array) -> Projection:
    """Foot points, signed distances and normals (natural sense) of points ``p`` on a surface of ``kind``."""
    p = np.asarray(p, dtype=np.float64).reshape(-1, 3)
    if kind == "plane":
        return plane(p, params["origin"], params["normal"])
    if kind == "cylinder":
        return cylinder(p, params["origin"], params["axis"], params["radius"])
    if kind == "sphere":
        return sphere(p, params["center"], params["radius"])
    if kind == "cone":
        return cone(p, params["apex"], params["axis"], params["half_angle"])
    if kind == "torus":
        return torus(p, params["center"], params["axis"], params["major_radius"], params["minor_radius"])
    raise ValueError(f"no closed-form projection onto a {kind} surface")


ANALYTIC = ("plane", "cylinder", "cone", "sphere", "torus")
