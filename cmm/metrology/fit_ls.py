"""Least-squares (Gaussian) orthogonal-distance fits.

Lines and planes: centroid + SVD (closed form, exact).  Circle, sphere,
cylinder, cone and torus: Levenberg-Marquardt (fit_solver) with analytic
Jacobians (fit_models) on points centred on their centroid and divided by
their RMS radius, so data 1000 mm from the origin fit as well as data at it.

3D circles follow the standard definition (NIST algorithm testing system,
ASME B89.4.10, ISO 10360-6): the least-squares plane of the points, then the
2D least-squares circle of the points projected into it (fit_circle).  The
circle minimising full 3D distances is available as fit_circle_3d_distance.

Start values: circle/sphere from an algebraic (Kasa) fit; cylinder from a
nominal and each principal direction in turn (long bores: first; short
rings: third; patches: second) with an algebraic circle in the projection;
cone the same plus a line fit of radius against height; torus from a
nominal, else plane normal + centroid.  With several starts each is run on
an evenly spaced subsample of at most 2000 points and the best is refined on
all points.  Cylinders and cones that are sparse (<= 100 points), partial
(less than 270 degrees around the axis) or poorly determined are also started
from 64 axis directions spread over the hemisphere, so the global least-squares
optimum is found; when a clearly different solution fits almost as well (or
better than the one near a given nominal) the result carries a warning.

Every result reports standard uncertainties (from sigma^2 (J^T J)^-1) and a
warning when the data determine it poorly (see fit_solver.KAPPA_WARN).

``nominal`` may be a mapping or any object with the feature's attribute
names (e.g. a previous result): center, normal, radius, point, direction,
apex, half_angle (rad) or half_angle_deg, major_radius, minor_radius.
"""

from __future__ import annotations

from dataclasses import replace
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
from cmm.metrology.fit_solver import (
    KAPPA_WARN,
    Solution,
    amplification,
    check_conditioning,
    levenberg_marquardt,
    r_factor,
    statistics,
)
from cmm.metrology.geom_basics import (
    algebraic_ball,
    as_points,
    canonical_direction,
    centre,
    check_rank,
    frame_with_axis,
    nominal_value,
    ScaledPoints,
    angular_coverage_deg,
    hemisphere_directions,
    principal_axes,
    subsample,
    unit,
)

MIN_POINTS = {"point": 1, "line": 2, "plane": 3, "circle": 3, "sphere": 4, "cylinder": 5, "cone": 6, "torus": 7}
SUBSAMPLE = 2000
SEARCH_SUBSAMPLE = 300  # points per start in the wide axis search
SEARCH_DIRECTIONS = 400  # axis directions screened by an algebraic fit
SEARCH_STARTS = 16  # best screened directions run to convergence
REFINE = 3  # best clearly different searched solutions refined on all points
START_CUTOFF = 1e3  # starts whose cost exceeds this multiple of the best start's are not run
PARTIAL_DEG = 270.0  # cylinders/cones covering less of the circle get the wide search
SPARSE = 100

# Reported standard uncertainties: name -> (indices into param_names, factor); the value is
# factor * sqrt(sum of the variances), i.e. the root-sum-square over the components.
_L, _A = 1, 1  # readability: lengths (mm) and angles (rad) use the same rule
GROUPS: dict[str, dict[str, tuple[tuple[int, ...], float]]] = {
    "point": {"x": ((0,), _L), "y": ((1,), _L), "z": ((2,), _L)},
    "line": {"position": ((0, 1), _L), "direction": ((2, 3), _A)},
    "plane": {"position": ((0,), _L), "normal": ((1, 2), _A)},
    "line2d": {"position": ((0,), _L), "direction": ((1,), _A)},
    "circle2d": {"center": ((0, 1), _L), "radius": ((2,), _L), "diameter": ((2,), 2.0)},
    "sphere": {"center": ((0, 1, 2), _L), "radius": ((3,), _L), "diameter": ((3,), 2.0)},
    "circle": {"center": ((0, 3, 4), _L), "normal": ((1, 2), _A), "radius": ((5,), _L), "diameter": ((5,), 2.0)},
    "circle3d": {"center": ((0, 1, 2), _L), "normal": ((3, 4), _A), "radius": ((5,), _L), "diameter": ((5,), 2.0)},
    "cylinder": {"axis_position": ((0, 1), _L), "direction": ((2, 3), _A), "radius": ((4,), _L),
                 "diameter": ((4,), 2.0)},
    "cone": {"axis_position": ((0, 1), _L), "direction": ((2, 3), _A), "half_angle": ((5,), _A)},
    "torus": {"center": ((0, 1, 2), _L), "normal": ((3, 4), _A), "major_radius": ((5,), _L),
              "minor_radius": ((6,), _L)},
}


def conditioning_warnings(jac: np.ndarray, kind: str, groups: dict[str, tuple[tuple[int, ...], float]],
                          what: str | None = None, m: int | None = None) -> list[str]:
    """A warning naming the poorly determined quantities when the data amplify scatter > KAPPA_WARN.
    `jac` may be the R factor of the Jacobian with m its number of rows."""
    kappa = amplification(jac, m)
    bad = [(name, float(kappa[list(idx)].max())) for name, (idx, f) in groups.items()
           if f == 1 and kappa[list(idx)].max() > KAPPA_WARN]
    if not bad:
        return []
    names = " and ".join(n.replace("_", " ") for n, _ in bad)
    worst = max(k for _, k in bad)
    return [f"the points determine the {what or kind}'s {names} poorly: probing scatter is amplified about "
            f"{worst:.0f}x (typical of a short arc, small cap or narrow patch); the uncertainties show by how "
            "much; probe a larger part of the feature"]


# ---------------------------------------------------------------- closed form


def fit_point(points: Any) -> Point:
    """Mean point; residuals are the distances to it, form is twice the largest."""
    x = as_points(points, "point", 1)
    c, xc = centre(x)
    dist = np.linalg.norm(xc, axis=1)
    m = len(x)
    sigma = float(np.sqrt(np.sum(xc * xc) / (3 * m - 3))) if m > 1 else float("nan")
    cov = np.eye(3) * (sigma**2 / m)
    unc = {k: float(np.sqrt(sigma**2 / m)) for k in "xyz"} if m > 1 else {}
    return Point(point=c, residuals=dist, sigma=sigma, form=2.0 * float(dist.max()), covariance=cov,
                 n_points=m, method="ls", param_names=("x", "y", "z"), uncertainty=unc)


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
    st = statistics(np.concatenate([loc[:, 0], loc[:, 1]]), jac, 4, form=2.0 * float(dist.max()),
                    groups=GROUPS["line"])
    return Line(point=c, direction=u, residuals=dist, n_points=m,
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
    st = statistics(loc[:, 2], jac, 3, groups=GROUPS["plane"])
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
    st = statistics(d, jac, 2, groups=GROUPS["line2d"])
    return Line2D(point=c, direction=t, normal=n, residuals=d, n_points=len(x), method="ls",
                  param_names=("offset", "angle"), **st)


# ---------------------------------------------------------------- iterative


def _run(model_cls: Callable[[np.ndarray], Any], xs: np.ndarray, start: Any, max_iter: int,
         step_tol: float = 1e-14) -> Solution | None:
    try:
        sol = levenberg_marquardt(model_cls(xs), start, max_iter=max_iter, step_tol=step_tol)
    except (FitError, np.linalg.LinAlgError, FloatingPointError):
        return None
    return sol if np.isfinite(sol.cost) else None


def _distinct(a: np.ndarray, b: np.ndarray) -> bool:
    """Two solutions differ when their residuals on the same points differ by more than a
    tenth of the residual scatter (converged runs of the same minimum agree far closer)."""
    rms = max(float(np.sqrt(np.mean(a * a))), float(np.sqrt(np.mean(b * b))), 1e-12)
    return float(np.max(np.abs(a - b))) > 0.1 * rms


def _solve(model_cls: Callable[[np.ndarray], Any], xs: np.ndarray, starts: Sequence[Any], kind: str,
           *, search_points: int = SUBSAMPLE) -> tuple[Solution, list[str]]:
    """Run LM from each start (on a subsample when there are several), refine the best on all
    points; warn when a clearly different solution fits almost as well."""
    if not starts:
        raise FitError(f"no usable starting values for the {kind} fit")
    warnings: list[str] = []
    if len(starts) > 1:
        sub = subsample(xs, search_points)
        # starts far worse than the best start (e.g. a long bore started across its axis) are skipped
        start_cost = []
        for st in starts:
            try:
                d0, _ = model_cls(sub).residuals_jacobian(st)
                start_cost.append(float(d0 @ d0))
            except (FitError, np.linalg.LinAlgError, FloatingPointError, ValueError):
                start_cost.append(np.inf)
        cutoff = START_CUTOFF * min(start_cost) if np.isfinite(min(start_cost)) else np.inf
        # searching: a coarse convergence is enough to rank the starts
        trials = [(i, t) for i, st in enumerate(starts)
                  if start_cost[i] <= cutoff and (t := _run(model_cls, sub, st, 40, 1e-9)) is not None]
        if not trials:
            raise FitError(f"the {kind} fit did not converge from any starting value")
        trials.sort(key=lambda it: it[1].cost)
        # the searches ran coarsely: refine the best few clearly different ones on all points
        picked: list[tuple[int, Solution]] = []
        for i, t in trials:
            if len(picked) == (REFINE if len(xs) <= 20_000 else 1) or t.cost > 10.0 * trials[0][1].cost:
                break  # enough, or the rest fit far worse (a rival must fit almost as well)
            if all(_distinct(t.residuals, o.residuals) for _, o in picked):
                picked.append((i, t))
        refined = [(i, r) for i, t in picked if (r := _run(model_cls, xs, t.state, 300)) is not None]
        if not refined:
            raise FitError(f"the {kind} fit diverged")
        refined.sort(key=lambda it: it[1].cost)
        sol = refined[0][1]
        # a clearly different competitor that fits almost as well makes the result ambiguous
        rival = next((o for _, o in refined[1:] if _distinct(o.residuals, sol.residuals)), None)
        if rival is not None and rival.cost <= 1.25 * sol.cost:
            warnings.append(
                f"the points fit two clearly different {kind}s almost equally well (rms "
                f"{np.sqrt(sol.cost / sol.residuals.size):.3g} vs {np.sqrt(rival.cost / rival.residuals.size):.3g} "
                "in scaled units); the better one is reported: probe more of the surface or give a nominal")
    else:
        sol = _run(model_cls, xs, starts[0], 300)
        if sol is None:
            raise FitError(f"the {kind} fit diverged")
    sol.r = r_factor(sol.jacobian)
    check_conditioning(sol.r, kind)
    return sol, warnings


def _near_nominal(model_cls: Callable[[np.ndarray], Any], xs: np.ndarray, start: Any, kind: str,
                  search: Callable[[], tuple[Solution, list[str]]]) -> tuple[Solution, list[str], Solution | None]:
    """The minimum reached from the nominal's start values, and (third) a clearly different solution
    found by the global ``search`` that fits the points better, or None.

    The nominal decides which of several minima is the measured feature: with few hits a cone or a
    short cylinder has other minima far from it (two rings of four hits at the same angles lie exactly
    on a cylinder across the axis), and the best-fitting one is not the probed feature. The better
    far solution is returned for the operator to check, never swapped in."""
    near = _run(model_cls, xs, start, 300)
    found, warn = search()
    if near is not None:
        near.r = r_factor(near.jacobian)
        try:
            check_conditioning(near.r, kind)
        except FitError:
            near = None
    if near is None:
        return found, [f"the {kind} fit did not converge from the nominal; the best-fitting {kind} is reported: "
                       "check the nominal"] + warn, None
    if not _distinct(found.residuals, near.residuals):  # the same minimum: keep the better-converged run
        return (found if found.cost < near.cost else near), [], None
    return near, [], (found if found.cost < near.cost else None)


def _finish(sol: Solution, model: Any, data: ScaledPoints, residuals_mm: np.ndarray, group: str,
            warnings: Sequence[str] = (), **extra: Any) -> dict[str, Any]:
    r = r_factor(sol.jacobian) if sol.r is None else sol.r
    st = statistics(residuals_mm, r, r.shape[1], data.scale, model.units, groups=GROUPS[group], **extra)
    warn = list(warnings) + conditioning_warnings(r, model.kind, GROUPS[group], m=sol.jacobian.shape[0])
    return {"n_points": len(data.x), "method": "ls", "warnings": tuple(warn), **st}


def fit_circle_2d(points: Any, nominal: Any = None) -> Circle2D:
    """2D circle: algebraic start, then LM on d = |x - c| - r."""
    x = as_points(points, "circle", MIN_POINTS["circle"], dim=2)
    data = ScaledPoints(x)
    check_rank(principal_axes(data.x)[0], "circle", 2)
    sol, warn = _solve(_circle_model, data.x, [_ball_start(data, nominal)], "circle")
    c, r = sol.state
    out = _finish(sol, _circle_model(data.x), data, sol.residuals * data.scale, "circle2d", warn)
    return Circle2D(center=data.to_mm(c), radius=r * data.scale, residuals=sol.residuals * data.scale,
                    param_names=("x", "y", "r"), **out)


def _circle_model(x: np.ndarray) -> fm.BallModel:
    return fm.BallModel(x, kind="circle")


def fit_sphere(points: Any, nominal: Any = None) -> Sphere:
    """Sphere: algebraic start, then LM on d = |x - c| - r."""
    x = as_points(points, "sphere", MIN_POINTS["sphere"])
    data = ScaledPoints(x)
    check_rank(principal_axes(data.x)[0], "sphere", 3)
    sol, warn = _solve(fm.BallModel, data.x, [_ball_start(data, nominal)], "sphere")
    c, r = sol.state
    out = _finish(sol, fm.BallModel(data.x), data, sol.residuals * data.scale, "sphere", warn)
    return Sphere(center=data.to_mm(c), radius=r * data.scale, residuals=sol.residuals * data.scale,
                  param_names=("x", "y", "z", "r"), **out)


def _ball_start(data: ScaledPoints, nominal: Any) -> tuple[np.ndarray, float]:
    c, r = nominal_value(nominal, "center"), nominal_value(nominal, "radius")
    if c is not None:
        cs = data.to_scaled(c)
        return cs, (float(r) / data.scale if r is not None else float(np.mean(np.linalg.norm(data.x - cs, axis=1))))
    return algebraic_ball(data.x)


def fit_circle(points: Any, nominal: Any = None) -> Circle:
    """3D circle, standard definition: least-squares plane of the points, then the 2D
    least-squares circle of the points projected into it (NIST / ASME B89.4.10 / ISO 10360-6).

    residuals are in-plane radial deviations (roundness), plane_residuals the
    distances to the plane; sigma over both (2m values, n = 6).  Parameters:
    plane offset and two tilts, then the in-plane centre (x, y) and r; the
    covariance is block diagonal (plane and circle estimated in turn).
    ``nominal`` (center, radius) only seeds the in-plane circle.
    """
    x = as_points(points, "circle", MIN_POINTS["circle"])
    data = ScaledPoints(x)
    s, vt = principal_axes(data.x)
    check_rank(s, "circle", 2)
    n = canonical_direction(vt[2])
    frame = frame_with_axis(n)
    loc = data.x @ frame
    h = loc[:, 2]
    flat = loc[:, :2]
    c_nom = nominal_value(nominal, "center")
    if c_nom is not None:
        c0 = (data.to_scaled(c_nom) @ frame)[:2]
        r_nom = nominal_value(nominal, "radius")
        r0 = float(r_nom) / data.scale if r_nom is not None else float(np.mean(np.linalg.norm(flat - c0, axis=1)))
        start = (c0, r0)
    else:
        start = algebraic_ball(flat)
    sol, warn = _solve(_circle_model, flat, [start], "circle")
    c2, r = sol.state
    m = len(x)
    jac_plane = np.column_stack([-np.ones(m), loc[:, 0], loc[:, 1]])
    rf = np.zeros((6, 6))  # R factor of the block-diagonal Jacobian [plane 0; 0 circle]
    rf[:3, :3] = r_factor(jac_plane)
    rf[3:, 3:] = sol.r
    radial, height = sol.residuals * data.scale, h * data.scale
    st = statistics(np.concatenate([height, radial]), rf, 6, data.scale, (1, 0, 0, 1, 1, 1),
                    form=float(radial.max() - radial.min()), groups=GROUPS["circle"])
    warn += conditioning_warnings(rf, "circle", GROUPS["circle"], m=m)
    return Circle(center=data.to_mm(frame[:, :2] @ c2), normal=n, radius=r * data.scale, residuals=radial,
                  plane_residuals=height, n_points=m, method="ls", warnings=tuple(warn),
                  param_names=("offset", "alpha", "beta", "x", "y", "r"), **st)


def fit_circle_3d_distance(points: Any, nominal: Any = None) -> Circle:
    """3D circle minimising the full 3D distances sum(h^2 + (rho - r)^2) (not the standard
    definition; see fit_circle).  Starts from the standard circle.

    residuals are rho - r (roundness), plane_residuals are h; sigma uses 2m values, n = 6.
    """
    std = fit_circle(points, nominal)
    x = as_points(points, "circle", MIN_POINTS["circle"])
    data = ScaledPoints(x)
    sol, warn = _solve(fm.Circle3Model, data.x, [(data.to_scaled(std.center), std.normal, std.radius / data.scale)],
                       "circle")
    c, n, r = sol.state
    m = len(x)
    radial, height = sol.residuals[m:] * data.scale, sol.residuals[:m] * data.scale
    st = statistics(sol.residuals * data.scale, sol.r, 6, data.scale, fm.Circle3Model.units,
                    form=float(radial.max() - radial.min()), groups=GROUPS["circle3d"])
    warn += conditioning_warnings(sol.r, "circle", GROUPS["circle3d"], m=2 * m)
    return Circle(center=data.to_mm(c), normal=canonical_direction(n), radius=r * data.scale, residuals=radial,
                  plane_residuals=height, n_points=m, method="ls", warnings=tuple(warn),
                  param_names=("a", "b", "c_n", "alpha", "beta", "r"), **st)


def _axis_candidates(data: ScaledPoints, nominal: Any) -> list[np.ndarray]:
    """The nominal axis (first, if given) and the three principal directions."""
    out = list(principal_axes(data.x)[1])
    u = nominal_value(nominal, "direction", "normal")
    return ([unit(u)] if u is not None else []) + out


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


def _needs_search(data: ScaledPoints, sol: Solution, p: np.ndarray, u: np.ndarray) -> bool:
    """Partial or poorly determined axis features get the wide multi-start search."""
    if angular_coverage_deg(data.x, p, u) < PARTIAL_DEG:
        return True
    return bool(amplification(sol.r, len(sol.residuals)).max() > KAPPA_WARN)


def _cylinder_algebraic(x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Cylinder with axis direction u from an algebraic circle in the projection."""
    frame = frame_with_axis(u)
    c2, r = algebraic_ball(x @ frame[:, :2])
    return frame[:, :2] @ c2, u, r


def _cone_algebraic(x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """Cone with axis direction u, linear in the unknowns: with in-plane coordinates q and
    height z, |q - p|^2 = (s + z tan psi)^2 gives |q|^2 = 2 q.p + (s^2 - |p|^2) + 2 s t z + t^2 z^2."""
    frame = frame_with_axis(u)
    loc = x @ frame
    q, z = loc[:, :2], loc[:, 2]
    a = np.column_stack([2.0 * q, np.ones(len(x)), z, z * z])
    sol, *_ = np.linalg.lstsq(a, np.einsum("ij,ij->i", q, q), rcond=None)
    t = float(np.sqrt(max(sol[4], 1e-6)))
    s = sol[3] / (2.0 * t)
    p = frame[:, :2] @ sol[:2]  # axis point in the centroid plane
    if s < 0:  # rho = |s + z t| grows along -u: same cone with the axis reversed
        u, s = -u, -s
    return p, u, float(s), float(np.arctan(t))


def _screen(model_cls: Callable[[np.ndarray], Any], x: np.ndarray, builder: Callable[[np.ndarray, np.ndarray], Any],
            directions: np.ndarray, k: int) -> list[Any]:
    """Build a start per direction, rank them by their true orthogonal-distance cost, keep the best k."""
    scored = []
    for u in directions:
        try:
            st = builder(x, u)
            d, _ = model_cls(x).residuals_jacobian(st)
        except (FitError, np.linalg.LinAlgError, FloatingPointError, ValueError):
            continue
        c = float(d @ d)
        if np.isfinite(c):
            scored.append((c, st))
    scored.sort(key=lambda cs: cs[0])
    return [st for _, st in scored[:k]]


def _wide_solve(model_cls: Callable[[np.ndarray], Any], data: ScaledPoints, first: Solution | None,
                first_warn: list[str], starts: list[Any], kind: str,
                builder: Callable[[np.ndarray, np.ndarray], Any]) -> tuple[Solution, list[str]]:
    """Re-solve from the first solution, the given starts and the best of SEARCH_DIRECTIONS
    axis directions screened with an algebraic start each."""
    sub = subsample(data.x, SEARCH_SUBSAMPLE)
    screened = _screen(model_cls, sub, builder, hemisphere_directions(SEARCH_DIRECTIONS), SEARCH_STARTS)
    lead = [] if first is None else [first.state]
    sol, warn = _solve(model_cls, data.x, lead + starts + screened, kind, search_points=SEARCH_SUBSAMPLE)
    if first is not None and sol.cost > first.cost * (1.0 + 1e-12):
        return first, first_warn  # the search did not beat the first solution
    return sol, warn


def _axis_solve(model_cls: Callable[[np.ndarray], Any], data: ScaledPoints, starts: list[Any], kind: str,
                has_nominal: bool, builder: Callable[[np.ndarray, np.ndarray], Any]
                ) -> tuple[Solution, list[str], Solution | None]:
    """Cylinder / cone solve: multi-start, widened for sparse, partial or poorly determined data; with a
    nominal (its start first in ``starts``) the minimum near the nominal and any better far one."""
    def search() -> tuple[Solution, list[str]]:
        sol, warn = (None, []) if len(data.x) <= SPARSE else _solve(model_cls, data.x, starts, kind)
        if sol is None or _needs_search(data, sol, sol.state[0], sol.state[1]):
            sol, warn = _wide_solve(model_cls, data, sol, warn, starts, kind, builder)
        return sol, warn

    if has_nominal:
        return _near_nominal(model_cls, data.x, starts[0], kind, search)
    return (*search(), None)


def _check_warning(kind: str, reported: Any, alternative: Any, detail: str) -> str:
    """The operator's sentence for a better-fitting solution far from the nominal (both described)."""
    rms = lambda f: float(np.sqrt(np.mean(np.square(f.residuals))))  # noqa: E731 - one-line helper
    tilt = np.degrees(np.arccos(min(1.0, abs(float(reported.direction @ alternative.direction)))))
    return (f"check: a different {kind} fits the hits better ({detail(alternative)}, axis {tilt:.3g} deg from the "
            f"reported one, rms {rms(alternative) * 1000:.3g} um) than the one near the nominal, which is reported "
            f"({detail(reported)}, rms {rms(reported) * 1000:.3g} um): check the nominal, or probe more of the surface")


def fit_cylinder(points: Any, nominal: Any = None) -> Cylinder:
    """Cylinder: LM with axis point in the centroid plane, two tilt angles, radius.

    The reported axis point is the projection of the data centroid onto the axis; its
    ``axis_position`` uncertainty holds there."""
    x = as_points(points, "cylinder", MIN_POINTS["cylinder"])
    data = ScaledPoints(x)
    check_rank(principal_axes(data.x)[0], "cylinder", 3)
    has_nominal = nominal_value(nominal, "direction", "normal") is not None
    starts = [(*_axis_start(data, u, nominal if (i == 0 and has_nominal) else None), u)
              for i, u in enumerate(_axis_candidates(data, nominal))]
    starts = [(p, u, r) for p, r, u in starts]
    sol, warn, far = _axis_solve(fm.CylinderModel, data, starts, "cylinder", has_nominal, _cylinder_algebraic)
    result = _cylinder_result(sol, data, warn)
    if far is None:
        return result
    far.r = r_factor(far.jacobian)
    alt = _cylinder_result(far, data, [])
    detail = lambda f: f"diameter {f.diameter:.4f} mm"  # noqa: E731
    return replace(result, alternative=alt,
                   warnings=(_check_warning("cylinder", result, alt, detail),) + result.warnings)


def _cylinder_result(sol: Solution, data: ScaledPoints, warn: list[str]) -> Cylinder:
    p, u, r = sol.state
    u = canonical_direction(u)
    out = _finish(sol, fm.CylinderModel(data.x), data, sol.residuals * data.scale, "cylinder", warn)
    return Cylinder(point=data.to_mm(p), direction=u, radius=r * data.scale,
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
    """Cone: LM on d = (rho - s) cos(psi) - z sin(psi), s = radius in the centroid plane.

    ``point`` is the projection of the data centroid onto the axis (its ``axis_position``
    uncertainty holds there); the apex is reported with its own uncertainty."""
    x = as_points(points, "cone", MIN_POINTS["cone"])
    data = ScaledPoints(x)
    check_rank(principal_axes(data.x)[0], "cone", 3)
    has_nominal = nominal_value(nominal, "direction", "normal") is not None
    starts = [_cone_start(data, u, nominal if (i == 0 and has_nominal) else None)
              for i, u in enumerate(_axis_candidates(data, nominal))]
    sol, warn, far = _axis_solve(fm.ConeModel, data, starts, "cone", has_nominal, _cone_algebraic)
    result = _cone_result(sol, data, warn)
    if far is None:
        return result
    far.r = r_factor(far.jacobian)
    try:
        alt = _cone_result(far, data, [])
    except FitError:
        return result  # the far solution is no valid cone (half angle out of range): nothing to check
    detail = lambda f: f"half angle {f.half_angle_deg:.4g} deg"  # noqa: E731
    return replace(result, alternative=alt, warnings=(_check_warning("cone", result, alt, detail),) + result.warnings)


def _cone_result(sol: Solution, data: ScaledPoints, warn: list[str]) -> Cone:
    p, u, s, psi = sol.state
    psi = float(psi)
    if psi < 0:
        u, psi = -u, -psi
    if not 0.0 < psi < np.pi / 2:
        raise FitError("the cone fit gave no valid half angle: the points do not look like a cone")
    t = -s / np.tan(psi)  # apex along the axis from p (scaled)
    apex = data.to_mm(p + t * u)
    out = _finish(sol, fm.ConeModel(data.x), data, sol.residuals * data.scale, "cone", warn)
    cov = out["covariance"]
    # apex = p + t u: d apex = frame @ (da + t dalpha, db + t dbeta, dt), dt = -cot(psi) ds + s/sin^2(psi) dpsi
    t_mm, s_mm = t * data.scale, s * data.scale
    g = np.array([[1.0, 0.0, t_mm, 0.0, 0.0, 0.0],
                  [0.0, 1.0, 0.0, t_mm, 0.0, 0.0],
                  [0.0, 0.0, 0.0, 0.0, -1.0 / np.tan(psi), s_mm / np.sin(psi) ** 2]])
    out["uncertainty"]["apex"] = float(np.sqrt(max(np.trace(g @ cov @ g.T), 0.0))) \
        if np.all(np.isfinite(cov)) else float("nan")
    u_psi = out["uncertainty"].get("half_angle", float("nan"))
    # nearly a cylinder: the apex is far away, or a small half angle is not significantly above 0
    if abs(t) > 100.0 or (np.isfinite(u_psi) and psi < 3.0 * u_psi and psi < np.radians(5.0)):
        out["warnings"] += (
            f"the cone is nearly a cylinder (half angle {np.degrees(psi):.4g} deg, apex {abs(t_mm):.4g} mm from the "
            "points): its apex and half angle are poorly determined; fit a cylinder instead",)
    return Cone(apex=apex, point=data.to_mm(p), direction=unit(u), half_angle=psi,
                residuals=sol.residuals * data.scale, param_names=("a", "b", "alpha", "beta", "s", "psi"), **out)


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
    sol, warn = _solve(fm.TorusModel, data.x, starts, "torus")
    c, u, big_r, r = sol.state
    out = _finish(sol, fm.TorusModel(data.x), data, sol.residuals * data.scale, "torus", warn)
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
