"""Minimum zone, maximum inscribed and minimum circumscribed features.

method      line        plane        circle           sphere           cylinder
"minzone"   SLP (3D)    LP, certified multi-start SLP  multi-start SLP  axis search + SLP
            exact (2D)
"mic"       -           -            exact            exact            axis search + SLP
"mcc"       -           -            exact            exact            axis search + SLP

exact: convex-hull width (fit_hull) for straightness in a plane; Welzl
minimum enclosing ball (a convex problem: global, also for partial features)
and Voronoi maximum empty ball (global when the points surround the centre;
refused otherwise, as it is unbounded) for MCC / MIC circles and spheres.
Flatness: linear programs on the hull vertices with a certificate of global
optimality (fit_hull.min_width_3d), the exact hull enumeration as fallback.
SLP: sequential linear programming (fit_chebyshev); minimum-zone circles and
spheres start from the least-squares, MCC and MIC solutions; cylinders search
axis directions around the least-squares axis and prove the result by a branch
and bound over the cone of directions (``cylinder_proof``).  Where the global
optimum is not proven (arcs, bounds that do not close, searches ending in
different optima) the result carries a warning saying so, with the gap.

3D circles are evaluated in the least-squares plane of their points
(points projected into it).  Results use the feature classes of
``features``: residuals are signed distances to the returned feature (to
the mid surface of the zone for minzone, to the surface itself for
mic / mcc), form = max - min residual (the zone width for minzone; 3D line:
the diameter of the cylindrical zone), sigma as for least squares;
covariance is NaN and uncertainty empty (not defined for these criteria).
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np
from scipy.spatial import QhullError

from cmm.metrology import fit_ls
from cmm.metrology import fit_models as fm
from cmm.metrology.features import Circle, Circle2D, Cylinder, FitError, FitResult, Line, Line2D, Plane, Sphere
from cmm.metrology.fit_chebyshev import chebyshev_fit
from cmm.metrology.cylinder_proof import (
    PROOF_GAP,
    _critical_subset,
    _cylinder_screen,
    _prove_cylinder,
    cone_deg,
)
from cmm.metrology.fit_enclosing import max_inscribed_ball, min_enclosing_ball
from cmm.metrology.fit_hull import min_width_3d, min_width_direction
from cmm.metrology.fit_solver import levenberg_marquardt
from cmm.metrology.geom_basics import (
    algebraic_ball,
    as_points,
    axis_foot,
    canonical_direction,
    check_rank,
    frame_with_axis,
    ScaledPoints,
    angular_coverage_deg,
    principal_axes,
    subsample,
    unit,
)

METHODS = ("ls", "minzone", "mic", "mcc")
SEARCH_POINTS = 2000  # points per start in the multi-start searches of the criteria


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


# flatness results whose certified gap to the global optimum exceeds this get the exact search
FLATNESS_GAP = 1e-9  # mm
EXACT_HULL_LIMIT = 400  # hull vertices for the O(h^2) exact search


def minzone_plane(points: Any) -> Plane:
    """Flatness: the thinnest slab holding the points. Plane = mid plane.

    LP iteration on the hull vertices from the least-squares normal with a
    certificate of global optimality (fit_hull.min_width_3d; 1e5 points in well
    under a second); when the certified gap exceeds FLATNESS_GAP (bulky point sets,
    not plates) the exact hull enumeration runs if the hull is small, else the
    result carries a warning with the gap.
    """
    ls = fit_ls.fit_plane(points)
    x = np.asarray(points, dtype=np.float64)
    xc = x - ls.point
    width, n, gap = min_width_3d(xc, ls.normal)
    warnings: tuple[str, ...] = ()
    if gap > FLATNESS_GAP:
        from scipy.spatial import ConvexHull

        if len(ConvexHull(xc).vertices) <= EXACT_HULL_LIMIT:
            w2, n2 = min_width_direction(xc)
            if w2 < width:
                n = n2
        else:
            warnings = (f"flatness: the global minimum zone is only proven to within {gap:.2g} mm "
                        "(the points are far from flat)",)
    n = canonical_direction(n)
    h = xc @ n
    mid = 0.5 * (h.max() + h.min())
    return Plane(point=ls.point + mid * n, normal=n, warnings=warnings, **_stats(h - mid, 3, "minzone"))


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
    return Line2D(point=p, direction=t, normal=n, **_stats(h - mid, 2, "minzone"))


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
    return Line(point=axis_foot(data.to_mm(p), u, data.c), direction=u,
                **_stats(dist, 4, "minzone", form=2.0 * float(dist.max())))


# ---------------------------------------------------------------- circles and spheres


def _surrounds(xs: np.ndarray, c: np.ndarray) -> bool:
    """Whether c lies inside the convex hull of the points (the feature is probed all round)."""
    from scipy.spatial import ConvexHull

    try:
        eq = ConvexHull(xs).equations
    except (QhullError, ValueError):
        return False
    return bool(np.all(eq[:, :-1] @ c + eq[:, -1] < 0.0))


def _multi_start(model: Any, starts: list[Any], method: str, merit: Callable[[Any], float]) -> tuple[Any, int, bool]:
    """SLP from every start; returns the best state, the number of runs and whether clearly
    different local optima (objective differing by more than 1e-9 relative) were found."""
    results = []
    for st in starts:
        try:
            results.append(chebyshev_fit(model, st, method))
        except FitError:
            continue
    if not results:
        raise FitError(f"the {method} fit failed from every start")
    values = np.array([merit(r) for r in results])
    best = int(np.argmin(values))
    spread = float(values.max() - values.min())
    return results[best], len(results), spread > 1e-9 * max(abs(float(values[best])), 1e-12) + 1e-12


def _unproven(kind: str, method: str, runs: int, differ: bool, partial: str | None) -> tuple[str, ...]:
    name = {"minzone": "minimum zone", "mic": "maximum inscribed", "mcc": "minimum circumscribed"}[method]
    if partial:
        return (f"{partial}: the {name} {kind} is the best of {runs} local searches; its global optimum is not proven",)
    if differ:
        return (f"the {name} {kind}: {runs} local searches found different optima; the best is reported but "
                "the global optimum is not proven",)
    return ()


def _criterion_ball(xs: np.ndarray, method: str, kind: str) -> tuple[np.ndarray, float, tuple[str, ...]]:
    """Centre and radius (scaled units) of a circle (2D) / sphere (3D) by criterion, and warnings.

    mcc: Welzl, exact and global (a convex problem), also for partial features.
    mic: Voronoi, exact and global when the points surround the centre; refused otherwise
         (a partial feature has no bounded inscribed circle / sphere).
    minzone: SLP from the least-squares, MCC and MIC solutions (the best is kept).
    """
    model = fm.BallModel(xs)
    ls_state = levenberg_marquardt(model, algebraic_ball(xs)).state
    around = _surrounds(xs, ls_state[0])
    partial = None if around else f"the points cover only part of the {kind}"
    if method == "mcc":
        c, r = min_enclosing_ball(xs)
        warn = () if around else (f"{partial}: the minimum circumscribed {kind} is the smallest one holding them "
                                  "(exact), which for a short arc or cap is smaller than the probed feature",)
        return c, r, warn
    if method == "mic":
        if not around:
            raise FitError(f"{partial}: a maximum inscribed {kind} is not defined (it could grow without bound); "
                           "probe all round or use least squares / minimum zone")
        c, r = max_inscribed_ball(xs)
        return c, r, ()
    # the search runs on a subsample (an LP per SLP step grows with the points), the best on all
    sub = subsample(xs, SEARCH_POINTS)
    starts = [ls_state, min_enclosing_ball(sub)]
    if around:
        try:
            starts.append(max_inscribed_ball(sub))
        except FitError:
            pass
    sub_model = fm.BallModel(sub)
    state, runs, differ = _multi_start(sub_model, starts, "minzone",
                                       lambda st: float(np.ptp(sub_model.residuals_jacobian(st)[0])))
    if len(sub) < len(xs):
        state = chebyshev_fit(model, state, "minzone")
    return state[0], state[1], _unproven(kind, "minzone", runs, differ, partial)


def _ball_fit(points: Any, method: str, kind: str, dim: int) -> tuple[ScaledPoints, np.ndarray, float, tuple[str, ...]]:
    data = _prepare(points, kind, dim, dim=dim)
    c, r, warn = _criterion_ball(data.x, method, kind)
    return data, data.to_mm(c), r * data.scale, warn


def circle_2d(points: Any, method: str) -> Circle2D:
    """2D circle by criterion: mcc and mic exact, minzone multi-start SLP (see _criterion_ball)."""
    data, c, r, warn = _ball_fit(points, method, "circle", 2)
    d = np.linalg.norm(data.to_mm(data.x) - c, axis=1) - r
    return Circle2D(center=c, radius=r, warnings=warn, **_stats(d, 3, method))


def sphere(points: Any, method: str) -> Sphere:
    """Sphere by criterion: mcc (Welzl) and mic (Voronoi) exact, minzone multi-start SLP."""
    data, c, r, warn = _ball_fit(points, method, "sphere", 3)
    d = np.linalg.norm(data.to_mm(data.x) - c, axis=1) - r
    return Sphere(center=c, radius=r, warnings=warn, **_stats(d, 4, method))


def circle(points: Any, method: str) -> Circle:
    """3D circle by criterion, evaluated in the least-squares plane of the points."""
    data = _prepare(points, "circle", 2)
    plane = fit_ls.fit_plane(points)
    x = data.to_mm(data.x)
    frame = frame_with_axis(plane.normal)
    flat = (x - plane.point) @ frame[:, :2]
    c2 = circle_2d(flat, method)
    return Circle(center=plane.point + frame[:, :2] @ c2.center, normal=plane.normal, radius=c2.radius,
                  plane_residuals=plane.residuals, warnings=c2.warnings, **_stats(c2.residuals, 6, method))


# Cylinder criteria search the axis directions within CONE_DEG of the least-squares axis (the probed
# feature: a short cylinder has smaller circumscribed cylinders tilted far from it, which are not it) and prove
# the result there (cylinder_proof).
CYLINDER_RINGS_DEG = (1.0, 3.0, 6.0, 9.5)  # minimum zone: start directions (degrees off the LS axis) ...
CYLINDER_AZIMUTHS = 6  # ... and azimuths per ring
CYLINDER_REFINE = 3
# minimum zone: the axes searched pass within CENTRE_FORMS x the LS form (at most CENTRE_FRACTION x the LS radius,
# at least 1e-3 x it) of the LS axis at the data centre: zones of about the LS form lie there
CENTRE_FRACTION = 0.1
CENTRE_FORMS = 5.0
# a band shorter than half its diameter: smaller circumscribed (larger inscribed, thinner zone) cylinders turned away
# from the band exist, and the search would find them. Such a band is refused when its hits know the least-squares
# axis only to more than SHORT_AXIS_DEG / 2 (3 standard uncertainties); a criterion cylinder turned more than
# SHORT_AXIS_DEG / 2 from that axis is replaced by the criterion about the least-squares axis, held: the axis
# reported is within SHORT_AXIS_DEG of the band's
SHORT_AXIS_DEG = 0.5
SHORT_RATIO = 0.5  # a band shorter than this times its diameter is short (a cone of atan(0.5) = 26.6 deg before)


def _short_axis_check(ls: Cylinder, method: str, length: float) -> float:
    """The least-squares axis's spread (deg, 3 standard uncertainties) of a short band; refused when too wide."""
    name = {"minzone": "minimum zone", "mcc": "minimum circumscribed", "mic": "maximum inscribed"}[method]
    u_dir = float(ls.uncertainty.get("direction", float("nan")))
    spread = float(np.degrees(3.0 * u_dir)) if np.isfinite(u_dir) else float("inf")
    if spread > SHORT_AXIS_DEG / 2:
        known = f"+-{spread:.2g} deg" if np.isfinite(spread) else "not at all"
        raise FitError(f"the band is {length:.3g} mm long for a {2 * ls.radius:.4g} mm cylinder: its hits know the "
                       f"axis only to {known} (more than {SHORT_AXIS_DEG / 2:g} deg), and a {name} cylinder would "
                       "turn away from the band; probe a longer band or more hits, or measure it as a circle")
    return spread


def _short_cylinder(ls: Cylinder, points: Any, method: str, length: float, spread: float) -> Cylinder:
    """The criterion of a short band about the held least-squares axis."""
    name = {"minzone": "minimum zone", "mcc": "minimum circumscribed", "mic": "maximum inscribed"}[method]
    x = np.asarray(points, dtype=np.float64)
    frame = frame_with_axis(ls.direction)
    c2 = circle_2d((x - ls.point) @ frame[:, :2], method)
    centre = ls.point + frame[:, :2] @ c2.center
    note = (f"a short band ({length:.3g} mm long for a {2 * c2.radius:.4g} mm cylinder): the axis is the "
            f"least-squares axis, held (+-{spread:.2g} deg at 3 standard uncertainties), and the {name} criterion is "
            "that of the hits projected along it")
    return Cylinder(point=axis_foot(centre, ls.direction, x.mean(axis=0)), direction=ls.direction,
                    radius=c2.radius, warnings=(note,) + tuple(c2.warnings), proof=None,
                    **_stats(c2.residuals, 5, method))


def cylinder(points: Any, method: str, nominal: Any = None) -> Cylinder:
    """Cylinder by criterion, the axis within ``cone_deg`` of the least-squares axis (the probed feature).

    MIC is refused when the points do not surround the axis (an arc: it could grow without bound), as
    for circles. Search: the least-squares start and the best of rings of directions (screened by the exact 2D
    MCC / MIC of the projected points, or their 2D least-squares circle for the minimum zone) refined by SLP on
    the full 5-parameter problem. Proof: a branch and bound over the directions in the cone
    (``_direction_bound``; for the minimum zone over the axes passing near the LS axis at the data centre, see
    CENTRE_FORMS) gives a lower bound on every other cylinder's value there; when the
    reported value is within PROOF_GAP of it, no warning, else a warning with the gap. The result's ``proof``
    records the domain and the outcome (``proven``, ``cone_deg``, ``gap_um``, ``cells``, ``near_cells``; minimum
    zone ``centre_mm``). An arc (< 300 degrees covered) is not searched for a proof (``proof`` None) and always
    carries the warning.
    """
    ls = fit_ls.fit_cylinder(points, nominal=nominal)
    data = _prepare(points, "cylinder", 3)
    length = float(np.ptp(data.x @ ls.direction)) * data.scale
    short = length < SHORT_RATIO * 2.0 * ls.radius
    spread = _short_axis_check(ls, method, length) if short else 0.0
    p = data.to_scaled(ls.point)
    p = p - (p @ ls.direction) * ls.direction
    model = fm.CylinderModel(data.x)
    u0 = ls.direction
    coverage = angular_coverage_deg(data.x, p, u0)
    frame = frame_with_axis(u0)
    cone = cone_deg(float(np.ptp(data.x @ u0)), 2.0 * ls.radius / data.scale)
    if short:
        cone = min(cone, SHORT_AXIS_DEG / 2)
    if method == "mic" and not _surrounds((data.x - p) @ frame[:, :2], np.zeros(2)):
        raise FitError(f"the points cover only {coverage:.0f} degrees around the axis: a maximum inscribed cylinder "
                       "is not defined (it could grow without bound); probe all round or use least squares / "
                       "minimum zone")
    dirs = [frame @ unit(np.array([np.tan(np.radians(a)) * np.cos(b), np.tan(np.radians(a)) * np.sin(b), 1.0]))
            for a in CYLINDER_RINGS_DEG if a <= cone
            for b in np.linspace(0, 2 * np.pi, CYLINDER_AZIMUTHS, endpoint=False) + np.radians(a)]
    sub = subsample(data.x, SEARCH_POINTS)
    screened = []
    for u in dirs:
        try:
            value, c, r = _cylinder_screen(sub, u, method)
        except (FitError, np.linalg.LinAlgError):
            continue
        screened.append((value, (c, u, r)))
    screened.sort(key=lambda vs: vs[0])
    starts = [(p, u0, ls.radius / data.scale)] + [st for _, st in screened[:CYLINDER_REFINE]]

    sub_model = fm.CylinderModel(sub)

    turn = np.radians(cone)

    def merit(st: Any) -> float:
        if abs(float(unit(st[1]) @ u0)) < np.cos(turn):
            return float("inf")  # turned away from the probed feature: another cylinder
        d = sub_model.residuals_jacobian(st)[0]
        return {"minzone": float(np.ptp(d)), "mcc": float(st[2] + d.max()), "mic": float(-(st[2] + d.min()))}[method]

    state, runs, _ = _multi_start(sub_model, starts, method, merit)
    if len(sub) < len(data.x):
        state = chebyshev_fit(model, state, method)  # the best search result, on all points
    if short and abs(float(unit(state[1]) @ u0)) < np.cos(turn):
        return _short_cylinder(ls, points, method, length, spread)
    pu, uu, ru = state
    d = model.residuals_jacobian(state)[0] * data.scale
    u = canonical_direction(uu)
    name = {"minzone": "minimum zone", "mcc": "minimum circumscribed", "mic": "maximum inscribed"}[method]
    proof = None
    if coverage < 300.0:  # an arc: the bound would not close (the search is not worth its time)
        smaller = ("" if method == "minzone" else ": the smallest cylinder holding them, which for an arc is smaller "
                   "than the probed feature")
        warnings = (f"the points cover only {coverage:.0f} degrees around the axis{smaller}; the {name} cylinder is "
                    f"the best of {runs} local searches and its global optimum is not proven",)
    else:
        value = {"minzone": float(np.ptp(d)), "mcc": float(ru * data.scale + d.max()),
                 "mic": float(-(ru * data.scale + d.min()))}[method] / data.scale
        crit = _critical_subset(data.x, model.residuals_jacobian((p, u0, ls.radius / data.scale))[0], method)
        centre_range = min(CENTRE_FRACTION * ls.radius, max(CENTRE_FORMS * ls.form, 1e-3 * ls.radius)) / data.scale
        gap, cells, near = _prove_cylinder(data.x, crit, method, u0, value, unit(uu), cone, p, centre_range,
                                           PROOF_GAP / data.scale)
        gap *= data.scale
        proof = {"proven": bool(gap <= PROOF_GAP), "cone_deg": cone, "gap_um": float(gap) * 1000.0, "cells": cells,
                 "near_cells": near}
        if method == "minzone":
            proof["centre_mm"] = centre_range * data.scale
        where = (f"among axes within {cone:.3g} degrees of the least-squares axis" if method != "minzone" else
                 f"among axes within {cone:.3g} degrees of the least-squares axis and "
                 f"{centre_range * data.scale:.3g} mm of it at the data centre")
        warnings = () if gap <= PROOF_GAP else (
            f"the {name} cylinder is proven optimal {where} only to within {gap:.2g} mm ({cells} direction cells "
            "searched); its global optimum is not proven",)
    return Cylinder(point=axis_foot(data.to_mm(pu), u, data.c), direction=u, radius=ru * data.scale,
                    warnings=warnings, proof=proof, **_stats(d, 5, method))


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
