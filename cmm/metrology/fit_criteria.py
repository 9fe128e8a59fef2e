"""Minimum zone, maximum inscribed and minimum circumscribed features.

method      line        plane      circle         sphere         cylinder
"minzone"   SLP (3D)    exact      SLP (vertex)   SLP            SLP
            exact (2D)
"mic"       -           -          exact          exact          SLP
"mcc"       -           -          exact          exact          SLP

exact: convex-hull width (fit_hull) for straightness in a plane and
flatness; Welzl minimum enclosing ball and Voronoi maximum empty ball
(fit_enclosing) for MCC / MIC circles and spheres.  SLP: sequential linear
programming from the least-squares solution (fit_chebyshev); for the
minimum-zone circle it converges to the exact optimum when, as generically,
four points are active (two on each limiting circle), and otherwise gives a
local optimum near the least-squares solution.

3D circles are evaluated in the least-squares plane of their points
(points projected into it).  Results use the feature classes of
``features``: residuals are signed distances to the returned feature (to
the mid surface of the zone for minzone, to the surface itself for
mic / mcc), form = max - min residual (the zone width for minzone; 3D line:
the diameter of the cylindrical zone), sigma as for least squares;
covariance is NaN (not defined for these criteria).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from cmm.metrology import fit_ls
from cmm.metrology import fit_models as fm
from cmm.metrology.features import Circle, Circle2D, Cylinder, FitError, FitResult, Line, Line2D, Plane, Sphere
from cmm.metrology.fit_chebyshev import chebyshev_fit
from cmm.metrology.fit_enclosing import max_inscribed_ball, min_enclosing_ball
from cmm.metrology.fit_hull import min_width_direction
from cmm.metrology.fit_solver import levenberg_marquardt
from cmm.metrology.geom_basics import (
    algebraic_ball,
    as_points,
    axis_point_closest_to_origin,
    canonical_direction,
    check_rank,
    frame_with_axis,
    ScaledPoints,
    principal_axes,
)

METHODS = ("ls", "minzone", "mic", "mcc")


def _prepare(points: Any, kind: str, rank: int, dim: int = 3) -> ScaledPoints:
    """Validated, centred and scaled points (same refusals as the least-squares fits)."""
    data = ScaledPoints(as_points(points, kind, fit_ls.MIN_POINTS[kind], dim=dim))
    check_rank(principal_axes(data.x)[0], kind, rank)
    return data


def _stats(residuals: np.ndarray, n_params: int, method: str, form: float | None = None) -> dict[str, Any]:
    dof = residuals.size - n_params
    sigma = float(np.sqrt(residuals @ residuals / dof)) if dof > 0 else float("nan")
    return {
        "residuals": residuals,
        "sigma": sigma,
        "form": float(residuals.max() - residuals.min()) if form is None else form,
        "covariance": np.full((n_params, n_params), np.nan),
        "n_points": residuals.size,
        "method": method,
    }


# ---------------------------------------------------------------- flat features (exact)


def minzone_plane(points: Any) -> Plane:
    """Flatness: the thinnest slab holding the points (exact, convex hull). Plane = mid plane."""
    ls = fit_ls.fit_plane(points)
    x = np.asarray(points, dtype=np.float64)
    xc = x - ls.point
    _, n = min_width_direction(xc)
    n = canonical_direction(n)
    h = xc @ n
    mid = 0.5 * (h.max() + h.min())
    return Plane(point=ls.point + mid * n, normal=n, **_stats(h - mid, 3, "minzone"))


def minzone_line_2d(points: Any) -> Line2D:
    """Straightness in a plane: the thinnest strip (exact, convex hull). Line = mid line."""
    data = _prepare(points, "line", 1, dim=2)
    x, c = data.to_mm(data.x), data.c
    _, n = min_width_direction(x - c)
    t = canonical_direction(np.array([n[1], -n[0]]))
    n = np.array([-t[1], t[0]])
    h = (x - c) @ n
    mid = 0.5 * (h.max() + h.min())
    p = c + mid * n
    return Line2D(point=p - (p @ t) * t, direction=t, normal=n, **_stats(h - mid, 2, "minzone"))


def minzone_line(points: Any) -> Line:
    """3D straightness: the thinnest cylinder around a line holding the points (SLP, from LS).

    Residuals are distances to the axis; form is the cylinder diameter.
    """
    ls = fit_ls.fit_line(points)
    data = _prepare(points, "line", 1)
    p = data.to_scaled(ls.point)
    p = p - (p @ ls.direction) * ls.direction
    model = fm.CylinderModel(data.x)
    p, u, r = chebyshev_fit(model, (p, ls.direction, 0.0), "mcc")
    dist = model.residuals_jacobian((p, u, 0.0))[0] * data.scale
    u = canonical_direction(u)
    return Line(point=axis_point_closest_to_origin(data.to_mm(p), u), direction=u,
                **_stats(dist, 4, "minzone", form=2.0 * float(dist.max())))


# ---------------------------------------------------------------- circles and spheres


def _criterion_ball(xs: np.ndarray, method: str) -> tuple[np.ndarray, float]:
    """Centre and radius (scaled units) of a circle (2D) / sphere (3D) by criterion."""
    if method == "mcc":
        return min_enclosing_ball(xs)
    if method == "mic":
        return max_inscribed_ball(xs)
    model = fm.BallModel(xs)
    ls_state = levenberg_marquardt(model, algebraic_ball(xs)).state
    return chebyshev_fit(model, ls_state, "minzone")


def _ball_fit(points: Any, method: str, kind: str, dim: int) -> tuple[ScaledPoints, np.ndarray, float]:
    data = _prepare(points, kind, dim, dim=dim)
    c, r = _criterion_ball(data.x, method)
    return data, data.to_mm(c), r * data.scale


def circle_2d(points: Any, method: str) -> Circle2D:
    """2D circle by criterion: mcc and mic exact, minzone SLP (see module doc)."""
    data, c, r = _ball_fit(points, method, "circle", 2)
    d = np.linalg.norm(data.to_mm(data.x) - c, axis=1) - r
    return Circle2D(center=c, radius=r, **_stats(d, 3, method))


def sphere(points: Any, method: str) -> Sphere:
    """Sphere by criterion: mcc (Welzl) and mic (Voronoi) exact, minzone SLP."""
    data, c, r = _ball_fit(points, method, "sphere", 3)
    d = np.linalg.norm(data.to_mm(data.x) - c, axis=1) - r
    return Sphere(center=c, radius=r, **_stats(d, 4, method))


def circle(points: Any, method: str) -> Circle:
    """3D circle by criterion, evaluated in the least-squares plane of the points."""
    data = _prepare(points, "circle", 2)
    plane = fit_ls.fit_plane(points)
    x = data.to_mm(data.x)
    frame = frame_with_axis(plane.normal)
    flat = (x - plane.point) @ frame[:, :2]
    c2 = circle_2d(flat, method)
    return Circle(center=plane.point + frame[:, :2] @ c2.center, normal=plane.normal, radius=c2.radius,
                  plane_residuals=plane.residuals, **_stats(c2.residuals, 6, method))


def cylinder(points: Any, method: str, nominal: Any = None) -> Cylinder:
    """Cylinder by criterion: SLP from the least-squares cylinder (local optimum)."""
    ls = fit_ls.fit_cylinder(points, nominal=nominal)
    data = _prepare(points, "cylinder", 3)
    p = data.to_scaled(ls.point)
    p = p - (p @ ls.direction) * ls.direction
    model = fm.CylinderModel(data.x)
    p, u, r = chebyshev_fit(model, (p, ls.direction, ls.radius / data.scale), method)
    d = model.residuals_jacobian((p, u, r))[0] * data.scale
    u = canonical_direction(u)
    return Cylinder(point=axis_point_closest_to_origin(data.to_mm(p), u), direction=u, radius=r * data.scale,
                    **_stats(d, 5, method))


# ---------------------------------------------------------------- dispatcher


_CLOSED_FORM = frozenset({"point", "line", "plane", "line2d"})


def _ls(kind: str) -> Callable[..., FitResult]:
    return fit_ls.LS_FITS[kind]


_CRITERIA: dict[tuple[str, str], Callable[..., FitResult]] = {
    ("line", "minzone"): lambda p, nominal=None: minzone_line(p),
    ("line2d", "minzone"): lambda p, nominal=None: minzone_line_2d(p),
    ("plane", "minzone"): lambda p, nominal=None: minzone_plane(p),
    **{("circle", m): (lambda m: lambda p, nominal=None: circle(p, m))(m) for m in ("minzone", "mic", "mcc")},
    **{("circle2d", m): (lambda m: lambda p, nominal=None: circle_2d(p, m))(m) for m in ("minzone", "mic", "mcc")},
    **{("sphere", m): (lambda m: lambda p, nominal=None: sphere(p, m))(m) for m in ("minzone", "mic", "mcc")},
    **{("cylinder", m): (lambda m: lambda p, nominal=None: cylinder(p, m, nominal))(m) for m in ("minzone", "mic", "mcc")},
}


def methods_for(kind: str) -> tuple[str, ...]:
    """The criteria available for a feature kind."""
    return ("ls",) + tuple(m for m in METHODS[1:] if (kind, m) in _CRITERIA)


def fit(kind: str, points: Any, method: str = "ls", nominal: Any = None) -> FitResult:
    """Fit feature `kind` (point, line, plane, circle, sphere, cylinder, cone, torus, line2d,
    circle2d) to points by `method` (ls, minzone, mic, mcc).

    `nominal` seeds the iterative fits; the closed-form ones (point, line, plane) do not need it."""
    if kind not in fit_ls.LS_FITS:
        raise FitError(f"unknown feature kind {kind!r}; choose one of: {', '.join(fit_ls.LS_FITS)}")
    if method == "ls":
        fn = _ls(kind)
        return fn(points, nominal=nominal) if nominal is not None and kind not in _CLOSED_FORM else fn(points)
    if (kind, method) not in _CRITERIA:
        raise FitError(f"method {method!r} is not available for a {kind}; choose one of: {', '.join(methods_for(kind))}")
    return _CRITERIA[(kind, method)](points, nominal=nominal)
