"""Probe-radius compensation for fitted features and for single points.

A touch-trigger probe latches the centre T of its tip sphere.  With the
effective radius r_eff (= stylus radius - pre-travel, from qualification)
the surface point is M = T + r_eff * n, n the unit normal from the tip
centre towards the contact (into the material).

For closed offset features the exact method is to fit the feature to the
tip centres and then offset its size by r_eff; the side comes from the
approach directions u (the direction of motion at contact, into the surface):

- u points away from the centre/axis (probe inside a bore, ring or hollow
  sphere): the surface lies outside the tip-centre feature: radius + r_eff;
- u points towards the centre/axis (boss, shaft, ball): radius - r_eff;
- plane: shifted by r_eff along its normal, towards the side u points to;
- cone: surfaces offset normal by r_eff, apex moved along the axis by
  r_eff / sin(half angle); torus: minor radius +- r_eff.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from cmm.metrology.features import (
    Circle,
    Circle2D,
    Cone,
    Cylinder,
    FitError,
    FitResult,
    Plane,
    Sphere,
    Torus,
)

BORE, BOSS = 1, -1


def _unit_rows(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=1)
    if np.any(norm == 0.0):
        raise FitError("a point lies on the feature's centre or axis: its surface normal is not defined")
    return v / norm[:, None]


def _radial(points: np.ndarray, origin: np.ndarray, axis: np.ndarray | None) -> np.ndarray:
    rel = points - origin
    if axis is not None:
        rel = rel - np.outer(rel @ axis, axis)
    return _unit_rows(rel)


def surface_normals(feature: FitResult, points: Any) -> np.ndarray:
    """Unit outward normals of the feature at (near) the given points: away from
    the centre / axis / tube circle; for a plane, its normal."""
    x = np.atleast_2d(np.asarray(points, dtype=np.float64))
    if isinstance(feature, Plane):
        return np.tile(feature.normal, (len(x), 1))
    if isinstance(feature, (Sphere, Circle2D)):
        return _radial(x, feature.center, None)
    if isinstance(feature, Circle):
        return _radial(x, feature.center, feature.normal)
    if isinstance(feature, Cylinder):
        return _radial(x, feature.point, feature.direction)
    if isinstance(feature, Cone):
        e = _radial(x, feature.apex, feature.direction)
        return np.cos(feature.half_angle) * e - np.sin(feature.half_angle) * feature.direction
    if isinstance(feature, Torus):
        tube = feature.center + feature.major_radius * _radial(x, feature.center, feature.normal)
        return _unit_rows(x - tube)
    raise FitError(f"probe compensation is not defined for a {feature.kind}")


def probing_side(feature: FitResult, tips: Any, approach: Any) -> int:
    """BORE (+1) if the approach directions point outward along the feature's
    normals (probe inside), BOSS (-1) if inward; refuses mixed or tangential ones."""
    normals = surface_normals(feature, tips)
    u = np.atleast_2d(np.asarray(approach, dtype=np.float64))
    if u.shape[0] == 1:
        u = np.tile(u, (len(normals), 1))
    if u.shape != normals.shape:
        raise FitError(f"got {len(u)} approach directions for {len(normals)} points")
    dots = np.einsum("ij,ij->i", _unit_rows(u), normals)
    if np.all(dots > 1e-3):
        return BORE
    if np.all(dots < -1e-3):
        return BOSS
    raise FitError(
        "the approach directions do not show one side of the surface "
        "(some point inward, some outward or along it): check the probing directions"
    )


def offset_feature(feature: FitResult, tips: Any, approach: Any, r_eff: float) -> FitResult:
    """The surface feature from a feature fitted to tip centres (see module doc).

    Residuals and form are unchanged (offset surfaces are parallel). A better-fitting alternative
    solution (see FitResult.alternative) is offset the same way, so both read as surfaces."""
    result = _offset(feature, tips, approach, r_eff)
    if feature.alternative is None:
        return result
    try:
        alt = _offset(feature.alternative, tips, approach, r_eff)
    except FitError:
        alt = feature.alternative  # the far solution has no valid surface offset: kept as fitted
    return replace(result, alternative=alt)


def _offset(feature: FitResult, tips: Any, approach: Any, r_eff: float) -> FitResult:
    side = probing_side(feature, tips, approach)
    delta = side * float(r_eff)  # outward offset of the surface
    if isinstance(feature, Plane):
        return replace(feature, point=feature.point + delta * feature.normal)
    if isinstance(feature, (Sphere, Circle, Circle2D, Cylinder)):
        radius = feature.radius + delta
        if radius <= 0.0:
            raise FitError(f"the compensated radius {radius:.6g} mm is not positive: check r_eff and the side")
        return replace(feature, radius=radius)
    if isinstance(feature, Cone):
        # the contact points lie delta along the outward normal from the tips, whose axial part is -sin(psi) u:
        # their centroid's foot on the axis (the location point) moves by -delta sin(psi) u
        u = feature.direction
        return replace(feature, apex=feature.apex - delta / np.sin(feature.half_angle) * u,
                       point=feature.point - delta * np.sin(feature.half_angle) * u)
    if isinstance(feature, Torus):
        return replace(feature, minor_radius=feature.minor_radius + delta)
    raise FitError(f"probe compensation is not defined for a {feature.kind}")


def compensate_points(tips: Any, r_eff: float, normals: Any) -> np.ndarray:
    """M = T + r_eff * n for each tip centre T; n (normalised here) points from
    the tip centre to the contact, e.g. the approach direction or
    contact_normals(...)."""
    t = np.atleast_2d(np.asarray(tips, dtype=np.float64))
    n = np.atleast_2d(np.asarray(normals, dtype=np.float64))
    if n.shape[0] == 1:
        n = np.tile(n, (len(t), 1))
    return t + float(r_eff) * _unit_rows(n)


def contact_normals(feature: FitResult, tips: Any, approach: Any) -> np.ndarray:
    """Feature normals at the tips, signed to point the way the probe approached
    (a better normal than the approach direction itself)."""
    return surface_normals(feature, tips) * probing_side(feature, tips, approach)
