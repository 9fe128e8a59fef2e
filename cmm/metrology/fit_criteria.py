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
and bound over the cone of directions (see ``cylinder``).  Where the global
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
from scipy.optimize import linprog
from scipy.spatial import QhullError

from cmm.metrology import fit_ls
from cmm.metrology import fit_models as fm
from cmm.metrology.features import Circle, Circle2D, Cylinder, FitError, FitResult, Line, Line2D, Plane, Sphere
from cmm.metrology.fit_chebyshev import chebyshev_fit
from cmm.metrology.fit_enclosing import max_inscribed_ball, min_enclosing_ball, min_enclosing_ball_from
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
# feature: a short cylinder has smaller circumscribed cylinders tilted far from it, which are not it).
CONE_DEG = 10.0
CYLINDER_RINGS_DEG = (1.0, 3.0, 6.0, 9.5)  # minimum zone: start directions (degrees off the LS axis) ...
CYLINDER_AZIMUTHS = 6  # ... and azimuths per ring
CYLINDER_REFINE = 3
PROOF_GAP = 1e-4  # mm (0.1 um): a cylinder criterion is proven optimal in the cone when its gap to the lower bound is below
# the bound runs on every point (when the subset's leaves a gap) up to this many (MIC: a Voronoi diagram per cell)
PROOF_FULL_POINTS = {"mcc": 20000, "minzone": 20000, "mic": 2000}
# minimum zone: the axes searched pass within CENTRE_FORMS x the LS form (at most CENTRE_FRACTION x the LS radius,
# at least 1e-3 x it) of the LS axis at the data centre: zones of about the LS form lie there
CENTRE_FRACTION = 0.1
CENTRE_FORMS = 5.0
ZONE_LP_POINTS = 40  # minimum zone bound: points nearest and farthest from the axis in each cell's linear program
PROOF_CELLS = 600  # direction cells the branch and bound may evaluate away from the optimum ...
NEAR_DEG = 0.05  # ... and, besides those, within this angle of the optimum's direction,
NEAR_CELLS = 1800  # this many (first-order cell bounds close there only on cells ~ tolerance / length wide)
CRITICAL_POINTS = 150  # points per side (largest / smallest LS residuals) in the bound's subsample


def _cylinder_screen(xs: np.ndarray, u: np.ndarray, method: str) -> tuple[float, np.ndarray, float]:
    """The 2D criterion of the points projected along u: (value to minimise, axis point, radius).
    MCC and MIC exact (Welzl, Voronoi), minimum zone from the 2D least-squares circle."""
    frame = frame_with_axis(u)
    flat = xs @ frame[:, :2]
    if method == "mcc":
        c, r = min_enclosing_ball(flat)
        value = r
    elif method == "mic":
        c, r = max_inscribed_ball(flat)
        value = -r
    else:
        model = fm.BallModel(flat)
        c, r = levenberg_marquardt(model, algebraic_ball(flat), max_iter=30).state
        d = model.residuals_jacobian((c, r))[0]
        value = float(np.ptp(d))
    return value, frame[:, :2] @ c, r


def _critical_subset(xs: np.ndarray, residuals: np.ndarray, method: str) -> np.ndarray:
    """The points that decide the criterion (largest LS residuals for MCC, smallest for MIC, both for the
    minimum zone) and a spread sample. A bound computed on a subset holds for every point: a subset's MCC and
    minimum zone are never larger, its MIC never smaller, than all points'."""
    order = np.argsort(residuals)
    k = min(CRITICAL_POINTS, len(xs))
    pick = {"mcc": [order[-k:]], "mic": [order[:k]]}.get(method, [order[-k:], order[:k]])
    pick.append(np.arange(0, len(xs), max(1, len(xs) // CRITICAL_POINTS)))
    return xs[np.unique(np.concatenate(pick))]


def cone_deg(length: float, diameter: float) -> float:
    """The cone of axis directions a cylinder criterion searches around the least-squares axis: CONE_DEG, and
    atan(length / diameter) for a cylinder shorter than its diameter (tilted further, a smaller cylinder
    passes through the same short band of points: another feature, not the probed one)."""
    return float(min(CONE_DEG, np.degrees(np.arctan2(length, diameter))))


def _annulus_dual(rel: np.ndarray, outer: np.ndarray, inner: np.ndarray, reach: float) -> float:
    """A lower bound on min over centres d (|d| <= reach) of [max_i |rel_i - d|^2 - min_i |rel_i - d|^2] from
    weights lam >= 0 on the ``outer`` points and mu >= 0 on the ``inner`` ones, each summing to 1, with
    sum lam rel = sum mu rel (LP duality: for every d the difference is at least sum lam |rel|^2 - sum mu |rel|^2,
    less 2 reach |imbalance|). The weights solve the balance equations; -inf when they are not all >= 0."""
    m = np.zeros((4, len(outer) + len(inner)))
    m[0, :len(outer)] = 1.0
    m[1, len(outer):] = 1.0
    m[2:, :len(outer)] = rel[outer].T
    m[2:, len(outer):] = -rel[inner].T
    w = np.linalg.lstsq(m, np.array([1.0, 1.0, 0.0, 0.0]), rcond=None)[0]
    if np.any(w < -1e-12):
        return -np.inf
    w = np.maximum(w, 0.0)
    lam, mu = w[:len(outer)], w[len(outer):]
    if abs(lam.sum() - 1.0) > 1e-9 or abs(mu.sum() - 1.0) > 1e-9:
        return -np.inf
    lam, mu = lam / lam.sum(), mu / mu.sum()
    imbalance = float(np.linalg.norm(lam @ rel[outer] - mu @ rel[inner]))
    a = np.einsum("ij,ij->i", rel, rel)
    return float(lam @ a[outer] - mu @ a[inner]) - 2.0 * reach * imbalance - 1e-12 * max(1.0, float(a.max()))


def _annulus_basis_optimal(rel: np.ndarray, outer: np.ndarray, inner: np.ndarray) -> bool:
    """Whether the annulus through the ``outer`` and ``inner`` points (four in all) holds every point: then their
    dual weights' bound (_annulus_dual) is the optimum itself and no linear program can raise it."""
    if len(outer) + len(inner) != 4:
        return False
    a = np.einsum("ij,ij->i", rel, rel)
    m = np.zeros((4, 4))  # unknowns d (2), A, B: |rel|^2 - 2 rel.d = B on the outer points, = A on the inner
    m[:, :2] = -2.0 * np.vstack([rel[outer], rel[inner]])
    m[:len(outer), 3] = -1.0
    m[len(outer):, 2] = -1.0
    try:
        sol = np.linalg.solve(m, -np.concatenate([a[outer], a[inner]]))
    except np.linalg.LinAlgError:
        return False
    g = a - 2.0 * rel @ sol[:2]
    tol = 1e-12 * max(1.0, float(a.max()))
    return bool(g.max() <= sol[3] + tol and g.min() >= sol[2] - tol)


def _annulus_area_lower(rel: np.ndarray, keep: np.ndarray, reach: float) -> tuple[float, np.ndarray, np.ndarray]:
    """A lower bound on min over centres d (|d| <= reach) of [max_i |rel_i - d|^2 - min_i |rel_i - d|^2] over the
    points ``keep`` (= r_out^2 - r_in^2 of the thinnest annulus by area: a subset's is never larger), from the
    linear program in (d, A, B): |rel_i|^2 - 2 rel_i.d lies in [A, B]. The bound is its dual weights' value
    (sum lam |rel|^2 - sum mu |rel|^2 less 2 reach |sum lam rel - sum mu rel|, see _annulus_dual): it holds
    whatever the solver's tolerances. Also returns the points active on the outer and inner circles."""
    x = rel[keep]
    a = np.einsum("ij,ij->i", x, x)
    n = len(x)
    zeros, ones = np.zeros((n, 1)), np.ones((n, 1))
    a_ub = np.vstack([np.hstack([-2.0 * x, zeros, -ones]), np.hstack([2.0 * x, ones, zeros])])
    res = linprog([0.0, 0.0, -1.0, 1.0], A_ub=a_ub, b_ub=np.concatenate([-a, a]), bounds=[(None, None)] * 4,
                  method="highs")
    if res.status != 0:
        return 0.0, keep[:0], keep[:0]
    dual = np.abs(res.ineqlin.marginals)
    lam, mu = dual[:n], dual[n:]
    if lam.sum() <= 0 or mu.sum() <= 0:
        return 0.0, keep[:0], keep[:0]
    lam, mu = lam / lam.sum(), mu / mu.sum()
    imbalance = float(np.linalg.norm(lam @ x - mu @ x))
    bound = float(lam @ a - mu @ a) - 2.0 * reach * imbalance - 1e-12 * max(1.0, float(a.max()))
    return max(bound, 0.0), keep[lam > 1e-12], keep[mu > 1e-12]


def _inner_radius_max(rel: np.ndarray, reach: float) -> float:
    """An upper bound on min_i |rel_i - d| (the inner radius of an annulus centred at d) over every centre
    |d| <= reach. With a reference centre d0 (the algebraic circle's), e = d - d0 (|e| <= rho = reach + |d0|),
    R_i = |rel_i - d0| and n_i their unit vectors: |rel_i - d| <= R_i - n_i.e + rho^2 / (2 (R_i - rho)), and
    for weights nu >= 0 summing to 1, min_i (R_i - n_i.e) <= sum nu R + rho |sum nu n| (the weights: the dual of
    the linear program max s, s + n_i.e <= R_i, e in a 16-gon around the disc, on the points nearest d0; any
    weights give a valid bound, the program makes it tight). Falls back to min |rel_i| + reach."""
    plain = float(np.sqrt(np.einsum("ij,ij->i", rel, rel)).min()) + reach
    d0 = algebraic_ball(rel)[0]
    rho = reach + float(np.sqrt(d0 @ d0))
    off = rel - d0
    radii = np.sqrt(np.einsum("ij,ij->i", off, off))
    near = np.argsort(radii)[:ZONE_LP_POINTS]
    r_k, n_k = radii[near], off[near] / radii[near, None]
    if r_k.min() <= 2.0 * rho:
        return plain
    ang = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
    a_ub = np.vstack([np.column_stack([n_k, np.ones(len(near))]),
                      np.column_stack([np.cos(ang), np.sin(ang), np.zeros(16)])])
    res = linprog([0.0, 0.0, -1.0], A_ub=a_ub, b_ub=np.concatenate([r_k, np.full(16, rho)]),
                  bounds=[(None, None)] * 3, method="highs")
    if res.status != 0:
        return plain
    nu = np.abs(res.ineqlin.marginals[:len(near)])
    if nu.sum() <= 0:
        return plain
    nu = nu / nu.sum()
    upper = float(nu @ r_k) + rho * float(np.linalg.norm(nu @ n_k)) + rho * rho / (2.0 * (r_k.min() - rho))
    return min(plain, upper + 1e-12 * float(radii.max()))


def _zone_cell_bound(xs: np.ndarray, foot: np.ndarray, centre_range: float, best: float) -> Callable[..., float]:
    """Lower bound on the minimum-zone width of every cylinder whose direction lies in a direction cell and whose
    axis passes within ``centre_range`` of ``foot`` (scaled units), valid for the widths below ``best``.

    For the cell's centre direction u (cell half-angle delta) and an axis through c along u' in the cell
    (c where it crosses the plane x.u = 0), each point's distance rho' to it and rho to the axis (c, u) satisfy
    rho cos(delta) - Z sin(delta) <= rho' <= rho + Z sin(delta) (Z = max |x.u|), so the width
    w' >= w_u(c) - (1 - cos delta) M - 2 Z sin delta (M >= every rho). In the plane across u, with the points
    rel_i seen from the projected foot: w_u(c) (r_out + r_in) = r_out^2 - r_in^2 >= F (the annulus area bound:
    the dual weights of the last cell's active points when they are still feasible and prune the cell, else
    the linear program), r_in <= min |rel_i| + q (q: how far c's projection can be from the foot's), so a
    cylinder with w' < best has w_u < W = best + slack and w_u >= F / (2 r_in_max + W): the returned bound is
    F / (2 r_in_max + W) - slack. A cell this does not prune gets r_in_max from _inner_radius_max (second order
    in q instead of first), so the bound closes on cells around the optimum once they are small enough."""
    norm_foot = float(np.sqrt(foot @ foot))
    basis = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))

    def bound(u: np.ndarray, delta: float) -> float:
        nonlocal basis
        f = frame_with_axis(u)[:, :2]
        q = centre_range + (centre_range + norm_foot) * np.tan(min(delta, 1.0))
        rel = xs @ f - foot @ f
        dist = np.sqrt(np.einsum("ij,ij->i", rel, rel))
        z = float(np.abs(xs @ u).max())
        slack = (1.0 - np.cos(delta)) * (float(dist.max()) + q) + 2.0 * z * np.sin(delta)
        scale = 2.0 * (float(dist.min()) + q) + best + slack
        if len(basis[0]) and len(basis[1]):
            area = _annulus_dual(rel, basis[0], basis[1], q)
            if np.isfinite(area) and area / scale - slack >= best:
                return area / scale - slack
            if np.isfinite(area) and _annulus_basis_optimal(rel, basis[0], basis[1]):
                return max(area / scale, area / (2.0 * _inner_radius_max(rel, q) + best + slack)) - slack
        order = np.argsort(dist)
        k = min(ZONE_LP_POINTS, len(xs))
        keep = np.unique(np.concatenate([order[:k], order[-k:]]))  # a subset: its bound holds for all points
        area, outer, inner = _annulus_area_lower(rel, keep, q)
        if len(outer) and len(inner):
            basis = (outer, inner)
        value = area / scale - slack
        if value < best:  # not pruned: the inner radius bounded over the axis positions, not from the foot's
            value = max(value, area / (2.0 * _inner_radius_max(rel, q) + best + slack) - slack)
        return value

    return bound


def _ball_cell_bound(xs: np.ndarray, method: str) -> Callable[..., float]:
    """Lower bound on the MCC radius (mcc) or on minus the MIC radius (mic) of every cylinder whose direction
    lies in a cell (centre u, half-angle delta). A point at height z along u and distance rho from an axis moves
    to a distance within [rho cos(delta) - |z| sin(delta), rho + |z| sin(delta)] from the axis through the same
    point along any direction of the cell, so mcc(u') >= mcc(u) cos(delta) - Z sin(delta) and
    mic(u') <= mic(u) + Z sin(delta), Z = max |z| (the axis point taken where it crosses x.u = 0)."""
    support = np.arange(min(3, len(xs)))  # MCC: the enclosing circle's points, carried from cell to cell

    def bound(u: np.ndarray, delta: float) -> float:
        nonlocal support
        if method == "mcc":
            f = frame_with_axis(u)
            _, value, support = min_enclosing_ball_from(xs @ f[:, :2], support)
        else:
            value = _cylinder_screen(xs, u, method)[0]
        z = float(np.abs(xs @ u).max())
        return value * np.cos(delta) - z * np.sin(delta) if method == "mcc" else value - z * np.sin(delta)

    return bound


def _direction_bound(cell_bound: Callable[..., float], u0: np.ndarray, best: float, u_best: np.ndarray,
                     cone: float) -> tuple[float, int, int]:
    """Branch and bound over every axis direction within ``cone`` degrees of u0: the lowest bound on the criterion
    value (mcc: radius; mic: -radius; minzone: width; scaled units) of any direction there.

    Directions u = unit(u0 + p e1 + q e2) on square cells in (p, q); every direction of a cell lies within
    delta = sqrt(2) h of its centre's (h: half the cell side); ``cell_bound(u, delta)`` bounds the criterion
    over the cell. Cells whose bound cannot beat ``best`` are dropped, the others split in four; a cell is
    only dropped on its bound, so the result bounds the whole cone, the optimum's own neighbourhood included
    (there the cells shrink until the first-order bound closes). Cells whose centre lies within NEAR_DEG of
    ``u_best`` count against NEAR_CELLS, the others against PROOF_CELLS; the search stops when either runs out.
    Returns (lowest bound left, cells evaluated, of which near u_best)."""
    import heapq

    frame = frame_with_axis(u0)
    e1, e2 = frame[:, 0], frame[:, 1]
    t_max = np.tan(np.radians(cone))
    near = np.radians(NEAR_DEG)

    def bound(p: float, q: float, h: float) -> float:
        return cell_bound(unit(u0 + p * e1 + q * e2), min(np.sqrt(2.0) * h, np.pi / 2))

    def is_near(p: float, q: float) -> bool:
        return bool(np.arccos(min(1.0, abs(float(unit(u0 + p * e1 + q * e2) @ u_best)))) <= near)

    n0 = 4
    h0 = t_max / n0
    heap: list[tuple[float, float, float, float]] = []
    counts = [0, 0]  # cells evaluated away from / near u_best
    for i in range(n0):
        for j in range(n0):
            p, q = -t_max + (2 * i + 1) * h0, -t_max + (2 * j + 1) * h0
            counts[is_near(p, q)] += 1
            heapq.heappush(heap, (bound(p, q, h0), p, q, h0))
    while heap:
        lower, p, q, h = heap[0]
        if lower >= best or counts[0] >= PROOF_CELLS or counts[1] >= NEAR_CELLS:
            return lower, sum(counts), counts[1]
        heapq.heappop(heap)
        for dp, dq in ((-1, -1), (-1, 1), (1, -1), (1, 1)):
            cp, cq, ch = p + dp * h / 2, q + dq * h / 2, h / 2
            if np.hypot(cp, cq) - np.sqrt(2.0) * ch > t_max:
                continue  # outside the cone
            child = bound(cp, cq, ch)
            counts[is_near(cp, cq)] += 1
            if child < best:
                heapq.heappush(heap, (child, cp, cq, ch))
    return best, sum(counts), counts[1]


def _prove_cylinder(xs: np.ndarray, crit: np.ndarray, method: str, u0: np.ndarray, value: float,
                    u_best: np.ndarray, cone: float, foot: np.ndarray, centre_range: float,
                    tol: float) -> tuple[float, int, int]:
    """The gap (scaled units) between ``value`` (the criterion of the reported cylinder, all points) and the
    lowest bound over the cone, the cells searched and how many of them lay within NEAR_DEG of the optimum. The
    bound runs on ``crit`` (a subset: valid for all points, and fast) and, when that leaves a gap above ``tol``,
    on every point (when the subset is less than half of them, up to PROOF_FULL_POINTS)."""
    target = value - 0.5 * tol
    gap, cells, near = np.inf, 0, 0
    for pts in (crit, xs) if 2 * len(crit) < len(xs) <= PROOF_FULL_POINTS[method] else (crit,):
        cb = (_zone_cell_bound(pts, foot, centre_range, target) if method == "minzone"
              else _ball_cell_bound(pts, method))
        lower, n, n_near = _direction_bound(cb, u0, target, u_best, cone)
        cells, near = cells + n, near + n_near
        gap = min(gap, max(value - lower, 0.0))
        if gap <= tol:
            break
    return gap, cells, near


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
    p = data.to_scaled(ls.point)
    p = p - (p @ ls.direction) * ls.direction
    model = fm.CylinderModel(data.x)
    u0 = ls.direction
    coverage = angular_coverage_deg(data.x, p, u0)
    frame = frame_with_axis(u0)
    cone = cone_deg(float(np.ptp(data.x @ u0)), 2.0 * ls.radius / data.scale)
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

    def merit(st: Any) -> float:
        d = sub_model.residuals_jacobian(st)[0]
        return {"minzone": float(np.ptp(d)), "mcc": float(st[2] + d.max()), "mic": float(-(st[2] + d.min()))}[method]

    state, runs, _ = _multi_start(sub_model, starts, method, merit)
    if len(sub) < len(data.x):
        state = chebyshev_fit(model, state, method)  # the best search result, on all points
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
