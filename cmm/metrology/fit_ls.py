"""Least-squares (Gaussian) orthogonal-distance fits.

Lines and planes: centroid + SVD (closed form, exact).  Circle, sphere,
cylinder, cone and torus: Levenberg-Marquardt (fit_solver) with analytic
Jacobians (fit_models) on points centred on their centroid and divided by
their RMS radius, so data 1000 mm from the origin fit as well as data at it.

Start values: circle/sphere from an algebraic (Kasa) fit; cylinder from a
nominal, else each principal direction in turn (long bores: first; short
rings: third; patches: second) with an algebraic circle in the projection;
cone the same plus a line fit of radius against height; torus from a
nominal, else plane normal + centroid.  With several starts each is run on
an evenly spaced subsample of at most 2000 points and the best is refined on
all points.

``nominal`` may be a mapping or any object with the feature's attribute
names (e.g. a previous result): center, normal, radius, point, direction,
apex, half_angle (rad) or half_angle_deg, major_radius, minor_radius.
"""

from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from cmm.metrology import fit_models as fm
from cmm.metrology.features import (
    Circle,
    Circle2D,
    Cone,
    Cylinder,
    FitError,
    Line,
    Line2D,
    Plane,
    Point,
    Sphere,
    Torus,
)
from cmm.metrology.fit_solver import Solution, check_conditioning, levenberg_marquardt, statistics
from cmm.metrology.geom_basics import (
    algebraic_ball,
    as_points,
    axis_point_closest_to_origin,
    canonical_direction,
    centre,
    check_rank,
    frame_with_axis,
    nominal_value,
    ScaledPoints,
    principal_axes,
    unit,
)

MIN_POINTS = {"point": 1, "line": 2, "plane": 3, "circle": 3, "sphere": 4, "cylinder": 5, "cone": 6, "torus": 7}
SUBSAMPLE = 2000


# ---------------------------------------------------------------- closed form


def fit_point(points: Any) -> Point:
    """Mean point; residuals are the distances to it, form is twice the largest."""
    x = as_points(points, "point", 1)
    c, xc = centre(x)
    dist = np.linalg.norm(xc, axis=1)
    m = len(x)
    sigma = float(np.sqrt(np.sum(xc * xc) / (3 * m - 3))) if m > 1 else float("nan")
    cov = np.eye(3) * (sigma**2 / m)
    return Point(point=c, residuals=dist, sigma=sigma, form=2.0 * float(dist.max()), covariance=cov,
                 n_points=m, method="ls", param_names=("x", "y", "z"))


def fit_line(points: Any) -> Line:
    """3D line: centroid + first principal direction (exact).

    Residuals are unsigned distances; sigma uses the 2m perpendicular
    components and n = 4; form = 2 * max distance.
    """
    x = as_points(points, "line", MIN_POINTS["line"])
    c, xc = centre(x)
    s, vt = principal_axes(xc)
    check_rank(s, "line", 1)
    u = canonical_direction(vt[0])
    loc = xc @ frame_with_axis(u)
    m = len(x)
    zeros, ones = np.zeros(m), np.ones(m)
    jac = np.vstack([np.column_stack([-ones, zeros, -loc[:, 2], zeros]),
                     np.column_stack([zeros, -ones, zeros, -loc[:, 2]])])
    dist = np.hypot(loc[:, 0], loc[:, 1])
    st = statistics(np.concatenate([loc[:, 0], loc[:, 1]]), jac, 4, form=2.0 * float(dist.max()))
    return Line(point=axis_point_closest_to_origin(c, u), direction=u, residuals=dist, n_points=m,
                method="ls", param_names=("a", "b", "alpha", "beta"), **st)


def fit_plane(points: Any) -> Plane:
    """Plane: centroid + last principal direction (exact). Point = centroid."""
    x = as_points(points, "plane", MIN_POINTS["plane"])
    c, xc = centre(x)
    s, vt = principal_axes(xc)
    check_rank(s, "plane", 2)
    n = canonical_direction(vt[2])
    loc = xc @ frame_with_axis(n)
    jac = np.column_stack([-np.ones(len(x)), loc[:, 0], loc[:, 1]])
    st = statistics(loc[:, 2], jac, 3)
    return Plane(point=c, normal=n, residuals=loc[:, 2], n_points=len(x), method="ls",
                 param_names=("offset", "alpha", "beta"), **st)


def fit_line_2d(points: Any) -> Line2D:
    """2D line (points already in a plane's coordinates): centroid + SVD (exact)."""
    x = as_points(points, "2D line", 2, dim=2)
    c, xc = centre(x)
    s, vt = principal_axes(xc)
    check_rank(s, "line", 1)
    t = canonical_direction(vt[0])
    n = np.array([-t[1], t[0]])
    d = xc @ n
    jac = np.column_stack([-np.ones(len(x)), xc @ t])
    st = statistics(d, jac, 2)
    return Line2D(point=c - (c @ t) * t, direction=t, normal=n, residuals=d, n_points=len(x), method="ls",
                  param_names=("offset", "angle"), **st)


# ---------------------------------------------------------------- iterative


def _solve(model_cls: Callable[[np.ndarray], Any], xs: np.ndarray, starts: Sequence[Any], kind: str) -> Solution:
    """Run LM from each start (on a subsample when there are several) and refine the best."""
    if not starts:
        raise FitError(f"no usable starting values for the {kind} fit")
    if len(starts) > 1:
        sub = xs if len(xs) <= SUBSAMPLE else xs[np.linspace(0, len(xs) - 1, SUBSAMPLE).astype(int)]
        best, best_cost = None, np.inf
        for st in starts:
            try:
                trial = levenberg_marquardt(model_cls(sub), st, max_iter=60)
            except (FitError, np.linalg.LinAlgError, FloatingPointError):
                continue
            if np.isfinite(trial.cost) and trial.cost < best_cost:
                best, best_cost = trial.state, trial.cost
        if best is None:
            raise FitError(f"the {kind} fit did not converge from any starting value")
        starts = [best]
    sol = levenberg_marquardt(model_cls(xs), starts[0])
    if not np.isfinite(sol.cost):
        raise FitError(f"the {kind} fit diverged")
    check_conditioning(sol.jacobian, kind)
    return sol


def _finish(sol: Solution, model: Any, data: ScaledPoints, residuals_mm: np.ndarray, **extra: Any) -> dict[str, Any]:
    st = statistics(residuals_mm, sol.jacobian, sol.jacobian.shape[1], data.scale, model.units, **extra)
    return {"n_points": len(data.x), "method": "ls", **st}


def fit_circle_2d(points: Any, nominal: Any = None) -> Circle2D:
    """2D circle: algebraic start, then LM on d = |x - c| - r."""
    x = as_points(points, "circle", MIN_POINTS["circle"], dim=2)
    data = ScaledPoints(x)
    check_rank(principal_axes(data.x)[0], "circle", 2)
    sol = _solve(fm.BallModel, data.x, [_ball_start(data, nominal)], "circle")
    c, r = sol.state
    out = _finish(sol, fm.BallModel(data.x), data, sol.residuals * data.scale)
    return Circle2D(center=data.to_mm(c), radius=r * data.scale, residuals=sol.residuals * data.scale,
                    param_names=("x", "y", "r"), **out)


def fit_sphere(points: Any, nominal: Any = None) -> Sphere:
    """Sphere: algebraic start, then LM on d = |x - c| - r."""
    x = as_points(points, "sphere", MIN_POINTS["sphere"])
    data = ScaledPoints(x)
    check_rank(principal_axes(data.x)[0], "sphere", 3)
    sol = _solve(fm.BallModel, data.x, [_ball_start(data, nominal)], "sphere")
    c, r = sol.state
    out = _finish(sol, fm.BallModel(data.x), data, sol.residuals * data.scale)
    return Sphere(center=data.to_mm(c), radius=r * data.scale, residuals=sol.residuals * data.scale,
                  param_names=("x", "y", "z", "r"), **out)


def _ball_start(data: ScaledPoints, nominal: Any) -> tuple[np.ndarray, float]:
    c, r = nominal_value(nominal, "center"), nominal_value(nominal, "radius")
    if c is not None:
        cs = data.to_scaled(c)
        return cs, (float(r) / data.scale if r is not None else float(np.mean(np.linalg.norm(data.x - cs, axis=1))))
    return algebraic_ball(data.x)


def fit_circle(points: Any, nominal: Any = None) -> Circle:
    """3D circle: plane by SVD, 2D circle in it, then the full 3D fit.

    Minimises sum(h^2 + (rho - r)^2), the squared 3D distances; residuals are
    rho - r (roundness), plane_residuals are h; sigma uses 2m values, n = 6.
    """
    x = as_points(points, "circle", MIN_POINTS["circle"])
    data = ScaledPoints(x)
    s, vt = principal_axes(data.x)
    check_rank(s, "circle", 2)
    n0 = nominal_value(nominal, "normal")
    n0 = unit(n0) if n0 is not None else vt[2]
    frame = frame_with_axis(n0)
    c_nom = nominal_value(nominal, "center")
    if c_nom is not None:
        c0 = data.to_scaled(c_nom)
        c0 = c0 - (c0 @ n0) * n0  # into the plane through the centroid
        r_nom = nominal_value(nominal, "radius")
        r0 = float(r_nom) / data.scale if r_nom is not None else float(np.mean(np.linalg.norm(data.x - c0, axis=1)))
    else:
        flat = data.x @ frame[:, :2]
        c2, r2 = levenberg_marquardt(fm.BallModel(flat), algebraic_ball(flat)).state
        c0, r0 = frame[:, :2] @ c2, r2
    sol = _solve(fm.Circle3Model, data.x, [(c0, n0, r0)], "circle")
    c, n, r = sol.state
    m = len(x)
    radial, height = sol.residuals[m:] * data.scale, sol.residuals[:m] * data.scale
    st = statistics(sol.residuals * data.scale, sol.jacobian, 6, data.scale, fm.Circle3Model.units,
                    form=float(radial.max() - radial.min()))
    return Circle(center=data.to_mm(c), normal=canonical_direction(n), radius=r * data.scale, residuals=radial,
                  plane_residuals=height, n_points=m, method="ls",
                  param_names=("a", "b", "c_n", "alpha", "beta", "r"), **st)


def _axis_candidates(data: ScaledPoints, nominal: Any) -> list[np.ndarray]:
    u = nominal_value(nominal, "direction", "normal")
    if u is not None:
        return [unit(u)]
    return list(principal_axes(data.x)[1])


def _axis_start(data: ScaledPoints, u: np.ndarray, nominal: Any) -> tuple[np.ndarray, float]:
    """Axis point (in the centroid plane) and radius for axis direction u."""
    p = nominal_value(nominal, "point", "center")
    if p is not None:
        ps = data.to_scaled(p)
        ps = ps - (ps @ u) * u
        r = nominal_value(nominal, "radius")
        if r is not None:
            return ps, float(r) / data.scale
        flat = data.x - ps
        return ps, float(np.mean(np.linalg.norm(flat - np.outer(flat @ u, u), axis=1)))
    frame = frame_with_axis(u)
    c2, r = algebraic_ball(data.x @ frame[:, :2])
    return frame[:, :2] @ c2, r


def fit_cylinder(points: Any, nominal: Any = None) -> Cylinder:
    """Cylinder: LM with axis point in the centroid plane, two tilt angles, radius."""
    x = as_points(points, "cylinder", MIN_POINTS["cylinder"])
    data = ScaledPoints(x)
    check_rank(principal_axes(data.x)[0], "cylinder", 3)
    starts = []
    for u in _axis_candidates(data, nominal):
        p, r = _axis_start(data, u, nominal)
        starts.append((p, u, r))
    sol = _solve(fm.CylinderModel, data.x, starts, "cylinder")
    p, u, r = sol.state
    u = canonical_direction(u)
    out = _finish(sol, fm.CylinderModel(data.x), data, sol.residuals * data.scale)
    return Cylinder(point=axis_point_closest_to_origin(data.to_mm(p), u), direction=u, radius=r * data.scale,
                    residuals=sol.residuals * data.scale, param_names=("a", "b", "alpha", "beta", "r"), **out)


def _cone_start(data: ScaledPoints, u: np.ndarray, nominal: Any) -> tuple[np.ndarray, np.ndarray, float, float]:
    apex = nominal_value(nominal, "apex")
    psi = nominal_value(nominal, "half_angle")
    if psi is None and nominal_value(nominal, "half_angle_deg") is not None:
        psi = np.radians(float(nominal_value(nominal, "half_angle_deg")))
    if apex is not None and psi is not None:
        a = data.to_scaled(apex)
        p = a - (a @ u) * u  # axis point in the centroid plane
        return p, u, float(-(a @ u) * np.tan(psi)), float(psi)
    p, _ = _axis_start(data, u, None)
    rel = data.x - p
    z = rel @ u
    rho = np.linalg.norm(rel - np.outer(z, u), axis=1)
    slope, s = np.polyfit(z, rho, 1)
    if slope < 0:  # radius must grow along u
        u, slope = -u, -slope
    return p, u, float(s), float(np.arctan(max(slope, 1e-3)))


def fit_cone(points: Any, nominal: Any = None) -> Cone:
    """Cone: LM on d = (rho - s) cos(psi) - z sin(psi), s = radius in the centroid plane."""
    x = as_points(points, "cone", MIN_POINTS["cone"])
    data = ScaledPoints(x)
    check_rank(principal_axes(data.x)[0], "cone", 3)
    starts = [_cone_start(data, u, nominal) for u in _axis_candidates(data, nominal)]
    sol = _solve(fm.ConeModel, data.x, starts, "cone")
    p, u, s, psi = sol.state
    if psi < 0:
        u, psi = -u, -psi
    if not 0.0 < psi < np.pi / 2:
        raise FitError("the cone fit gave no valid half angle: the points do not look like a cone")
    apex = data.to_mm(p - (s / np.tan(psi)) * u)
    out = _finish(sol, fm.ConeModel(data.x), data, sol.residuals * data.scale)
    return Cone(apex=apex, direction=unit(u), half_angle=float(psi), residuals=sol.residuals * data.scale,
                param_names=("a", "b", "alpha", "beta", "s", "psi"), **out)


def fit_torus(points: Any, nominal: Any = None) -> Torus:
    """Torus: LM on d = sqrt((rho - R)^2 + z^2) - r; start from a nominal or plane normal + centroid."""
    x = as_points(points, "torus", MIN_POINTS["torus"])
    data = ScaledPoints(x)
    s, vt = principal_axes(data.x)
    check_rank(s, "torus", 3)
    u = nominal_value(nominal, "normal", "direction")
    u = unit(u) if u is not None else vt[2]
    centres = [data.to_scaled(nominal_value(nominal, "center"))] if nominal_value(nominal, "center") is not None \
        else [np.zeros(3), _axis_start(data, u, None)[0]]
    starts = []
    for c in centres:
        rel = data.x - c
        z = rel @ u
        rho = np.linalg.norm(rel - np.outer(z, u), axis=1)
        big_r = nominal_value(nominal, "major_radius")
        big_r = float(big_r) / data.scale if big_r is not None else float(rho.mean())
        r = nominal_value(nominal, "minor_radius")
        r = float(r) / data.scale if r is not None else float(np.mean(np.hypot(rho - big_r, z)))
        starts.append((c, u, big_r, r))
    sol = _solve(fm.TorusModel, data.x, starts, "torus")
    c, u, big_r, r = sol.state
    out = _finish(sol, fm.TorusModel(data.x), data, sol.residuals * data.scale)
    return Torus(center=data.to_mm(c), normal=canonical_direction(u), major_radius=big_r * data.scale,
                 minor_radius=r * data.scale, residuals=sol.residuals * data.scale,
                 param_names=("a", "b", "c_n", "alpha", "beta", "R", "r"), **out)


LS_FITS: dict[str, Callable[..., Any]] = {
    "point": fit_point,
    "line": fit_line,
    "plane": fit_plane,
    "circle": fit_circle,
    "sphere": fit_sphere,
    "cylinder": fit_cylinder,
    "cone": fit_cone,
    "torus": fit_torus,
    "line2d": fit_line_2d,
    "circle2d": fit_circle_2d,
}
