"""The proof of a cylinder criterion (MCC, MIC, minimum zone) in a cone of axis directions.

A branch and bound over direction cells (``_direction_bound``) gives a lower bound on the criterion of every
cylinder whose axis direction lies in the cone (for the minimum zone also passing near the least-squares axis at
the data centre); each cell is bounded from the exact 2D criterion at its centre direction (``_ball_cell_bound``)
or from the thinnest annulus by area (``_zone_cell_bound``; on small cells with the tilt a variable of its linear
program, ``_tilted_area_lower``). ``fit_criteria.cylinder`` searches, this proves.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from cmm.metrology import fit_models as fm
from cmm.metrology import lp_small
from cmm.metrology.fit_enclosing import max_inscribed_ball, min_enclosing_ball, min_enclosing_ball_from
from cmm.metrology.fit_solver import levenberg_marquardt
from cmm.metrology.geom_basics import algebraic_ball, frame_with_axis, unit

# Cylinder criteria search the axis directions within CONE_DEG of the least-squares axis (the probed
# feature: a short cylinder has smaller circumscribed cylinders tilted far from it, which are not it).
CONE_DEG = 10.0
PROOF_GAP = 1e-4  # mm (0.1 um): a cylinder criterion is proven optimal in the cone when its gap to the lower bound is below
# the bound runs on every point (when the subset's leaves a gap) up to this many (MIC: a Voronoi diagram per cell)
PROOF_FULL_POINTS = {"mcc": 20000, "minzone": 20000, "mic": 2000}
ZONE_LP_POINTS = 40  # minimum zone bound: points nearest and farthest from the axis in each cell's linear program
PROOF_CELLS = 600  # direction cells the branch and bound may evaluate away from the optimum ...
NEAR_BUDGET_DEG = 0.05  # ... and, besides those, with their centre within this angle of the optimum's direction,
NEAR_CELLS = 1800  # this many (first-order cell bounds close there only on cells ~ tolerance / length wide)
NEAR_DEG = 0.15  # the optimum's neighbourhood the proof records (near_cells: the cells evaluated there)
TILT_DELTA = 0.02  # rad: direction cells this small are bounded by the tilted annulus program (_zone_cell_bound)
TILT_START = 8  # its first rows: the points nearest and farthest from the axis (and the last cell's active ones),
TILT_ADD = 8  # then at most this many of the points its solution violates per round,
TILT_ROUNDS = 10  # for at most this many rounds (any round's weights give a bound)
CRITICAL_POINTS = 150  # points per side (largest / smallest LS residuals) in the bound's subsample
_ANNULUS_COST = np.array([0.0, 0.0, -1.0, 1.0])  # the annulus-area program: maximise A - B (see _annulus_area_lower)
_INNER_COST = np.array([0.0, 0.0, -1.0])  # the inner-radius program: maximise s (see _inner_radius_max)
_POLYGON16 = np.column_stack([np.cos(np.arange(16) * np.pi / 8), np.sin(np.arange(16) * np.pi / 8), np.zeros(16)])
_FREE4 = (np.full(4, -np.inf), np.full(4, np.inf))  # free variables


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
    rhs = np.array([1.0, 1.0, 0.0, 0.0])
    try:  # four points (the generic basis): a square system
        w = np.linalg.solve(m, rhs) if m.shape[1] == 4 else np.linalg.lstsq(m, rhs, rcond=None)[0]
    except np.linalg.LinAlgError:
        w = np.linalg.lstsq(m, rhs, rcond=None)[0]
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
    res = lp_small.solve(_ANNULUS_COST, a_ub, np.full(2 * n, -np.inf), np.concatenate([-a, a]), _FREE4[0],
                         _FREE4[1])
    if not res.ok:
        return 0.0, keep[:0], keep[:0]
    dual = np.abs(res.duals)
    lam, mu = dual[:n], dual[n:]
    if lam.sum() <= 0 or mu.sum() <= 0:
        return 0.0, keep[:0], keep[:0]
    lam, mu = lam / lam.sum(), mu / mu.sum()
    imbalance = float(np.linalg.norm(lam @ x - mu @ x))
    bound = float(lam @ a - mu @ a) - 2.0 * reach * imbalance - 1e-12 * max(1.0, float(a.max()))
    return max(bound, 0.0), keep[lam > 1e-12], keep[mu > 1e-12]


_TILT_COST = np.array([0.0, 0.0, 0.0, 0.0, -1.0, 1.0])  # the tilted annulus program: maximise A - B
_FREE6 = (np.full(6, -np.inf), np.full(6, np.inf))
_ORIGIN2 = np.zeros(2)


def _tilt_certificate(rel: np.ndarray, zs: np.ndarray, outer: np.ndarray, lam: np.ndarray, inner: np.ndarray,
                      mu: np.ndarray, reach: float, sigma: float) -> float:
    """A lower bound on max_i rho_i^2 - min_i rho_i^2 (rho_i: point i's distance to the axis) over every axis
    crossing the plane x.u = 0 within ``reach`` of the reference (rel: the points seen from it across u) along a
    direction unit(u + s), |s| <= sigma (s across u), from weights lam >= 0 on the ``outer`` points and mu >= 0
    on the ``inner`` ones, each summing to 1.

    With d the crossing and z_i = x_i.u, w_i = rel_i - d - z_i s: rho_i^2 = |w_i|^2 - (w_i.s)^2 / (1 + |s|^2)
    = L_i + |d|^2 + E_i, L_i = |rel_i|^2 - 2 rel_i.d - 2 z_i rel_i.s linear in (d, s), and
    E_i = 2 z_i d.s + z_i^2 |s|^2 - (w_i.s)^2 / (1 + |s|^2) in [-2 |z_i| reach sigma - |w_i|^2 sigma^2,
    2 |z_i| reach sigma + z_i^2 sigma^2]. The weights turn sum lam rho^2 - sum mu rho^2 (at most the range) into
    sum lam |rel|^2 - sum mu |rel|^2 less 2 reach |imbalance in d|, 2 sigma |imbalance in s| and the E terms:
    second order in the tilt but for the bilinear 2 z d.s (the first-order cell bound's 2 Z sin(delta) per unit
    width becomes 4 Z reach sigma per unit area)."""
    ro, ri = rel[outer], rel[inner]
    zo, zi = np.abs(zs[outer]), np.abs(zs[inner])
    a_o, a_i = np.einsum("ij,ij->i", ro, ro), np.einsum("ij,ij->i", ri, ri)
    imb_d = lam @ ro - mu @ ri
    imb_s = (lam * zs[outer]) @ ro - (mu * zs[inner]) @ ri
    w_o = np.sqrt(a_o) + reach + zo * sigma
    e_terms = lam @ (2.0 * zo * reach * sigma + w_o * w_o * sigma * sigma) + \
        mu @ (2.0 * zi * reach * sigma + zi * zi * sigma * sigma)
    value = (float(lam @ a_o - mu @ a_i) - 2.0 * reach * float(np.sqrt(imb_d @ imb_d))
             - 2.0 * sigma * float(np.sqrt(imb_s @ imb_s)) - float(e_terms))
    return value - 1e-12 * max(1.0, float(a_o.max()))


def _tilted_area_lower(rel: np.ndarray, zs: np.ndarray, start: np.ndarray, reach: float, sigma: float
                       ) -> tuple[float, tuple[np.ndarray, ...] | None]:
    """_tilt_certificate's bound with the weights of the linear program in (d, s, A, B): L_i in [A, B],
    |s_k| <= sigma, d free (its duals: weights whose d imbalance is zero), by constraint generation: the
    program on the points ``start``, then the points its solution violates added until none is (the program
    on every point, from a few rows). Returns the bound and the weights (outer indices, lam, inner indices, mu)
    to carry to the next cell (any weights give a bound, the last program's included)."""
    a_all = np.einsum("ij,ij->i", rel, rel)
    coef = np.hstack([-2.0 * rel, -2.0 * zs[:, None] * rel])  # L_i = a_i + coef_i.(d, s)
    tol = 1e-12 * max(1.0, float(a_all.max()))
    lb, ub = _FREE6[0].copy(), _FREE6[1].copy()
    lb[2:4], ub[2:4] = -sigma, sigma
    active = np.unique(start)
    for _ in range(TILT_ROUNDS):
        n = len(active)
        a, c = a_all[active], coef[active]
        zeros, ones = np.zeros((n, 1)), np.ones((n, 1))
        a_ub = np.vstack([np.hstack([c, zeros, -ones]), np.hstack([-c, ones, zeros])])
        res = lp_small.solve(_TILT_COST, a_ub, np.full(2 * n, -np.inf), np.concatenate([-a, a]), lb, ub)
        if not res.ok:
            return 0.0, None
        lin = a_all + coef @ res.x[:4]
        viol = np.maximum(lin - res.x[5], res.x[4] - lin)
        viol[active] = -np.inf
        out = np.flatnonzero(viol > tol)
        if not len(out):
            break
        active = np.concatenate([active, out[np.argsort(viol[out])[-TILT_ADD:]]])
    dual = np.abs(res.duals)
    lam, mu = dual[:n], dual[n:]
    if lam.sum() <= 0 or mu.sum() <= 0:
        return 0.0, None
    o, i = lam > 1e-12 * lam.sum(), mu > 1e-12 * mu.sum()
    weights = (active[o], lam[o] / lam[o].sum(), active[i], mu[i] / mu[i].sum())
    return _tilt_certificate(rel, zs, *weights, reach, sigma), weights


def _weighted_inner(radii: np.ndarray, off: np.ndarray, rho: float, idx: np.ndarray, nu: np.ndarray) -> float:
    """The bound of _inner_radius_max from weights ``nu`` (>= 0, summing to 1) on the points ``idx``; inf when
    a point weighed lies within 2 rho of the reference centre (the expansion does not hold there)."""
    r_k = radii[idx]
    if r_k.min() <= 2.0 * rho:
        return np.inf
    n_k = off[idx] / r_k[:, None]
    upper = float(nu @ r_k) + rho * float(np.linalg.norm(nu @ n_k)) + rho * rho / (2.0 * (r_k.min() - rho))
    return upper + 1e-12 * float(radii.max())


def _inner_radius_max(rel: np.ndarray, reach: float, carry: tuple[np.ndarray, np.ndarray] | None = None,
                      enough: float = -np.inf, program: bool = True, centre: np.ndarray | None = None
                      ) -> tuple[float, tuple[np.ndarray, np.ndarray] | None]:
    """An upper bound on min_i |rel_i - d| (the inner radius of an annulus centred at d) over every centre
    |d| <= reach. With a reference centre d0 (the algebraic circle's), e = d - d0 (|e| <= rho = reach + |d0|),
    R_i = |rel_i - d0| and n_i their unit vectors: |rel_i - d| <= R_i - n_i.e + rho^2 / (2 (R_i - rho)), and
    for weights nu >= 0 summing to 1, min_i (R_i - n_i.e) <= sum nu R + rho |sum nu n| (the weights: the dual of
    the linear program max s, s + n_i.e <= R_i, e in a 16-gon around the disc, on the points nearest d0; any
    weights give a valid bound, the program makes it tight). Falls back to min |rel_i| + reach.

    ``carry``: weights (point indices, nu) of a neighbouring cell's program, tried first: when their bound is
    already at most ``enough`` (what the caller needs), the program is skipped. Returns the bound and the
    weights used (to carry to the next cell). ``program`` False: the carried weights' bound only, no program."""
    plain = float(np.sqrt(np.einsum("ij,ij->i", rel, rel)).min()) + reach
    d0 = algebraic_ball(rel)[0] if centre is None else centre
    rho = reach + float(np.sqrt(d0 @ d0))
    off = rel - d0
    radii = np.sqrt(np.einsum("ij,ij->i", off, off))
    if carry is not None:
        reused = min(plain, _weighted_inner(radii, off, rho, *carry))
        if reused <= enough or not program:
            return reused, carry
    if not program:
        return plain, carry
    near = np.argsort(radii)[:ZONE_LP_POINTS]
    r_k, n_k = radii[near], off[near] / radii[near, None]
    if r_k.min() <= 2.0 * rho:
        return plain, carry
    a_ub = np.vstack([np.column_stack([n_k, np.ones(len(near))]), _POLYGON16])
    res = lp_small.solve(_INNER_COST, a_ub, np.full(len(a_ub), -np.inf), np.concatenate([r_k, np.full(16, rho)]),
                         _FREE4[0][:3], _FREE4[1][:3])
    if not res.ok:
        return plain, carry
    nu = np.abs(res.duals[:len(near)])
    if nu.sum() <= 0:
        return plain, carry
    nu = nu / nu.sum()
    upper = float(nu @ r_k) + rho * float(np.linalg.norm(nu @ n_k)) + rho * rho / (2.0 * (r_k.min() - rho))
    used = nu > 0
    return min(plain, upper + 1e-12 * float(radii.max())), (near[used], nu[used] / nu[used].sum())


def _zone_cell_bound(xs: np.ndarray, foot: np.ndarray, centre_range: float, best: float) -> Callable[..., float]:
    """Lower bound on the minimum-zone width of every cylinder whose direction lies in a direction cell and whose
    axis passes within ``centre_range`` of ``foot`` (scaled units), valid for the widths below ``best``.

    For the cell's centre direction u (cell half-angle delta) and an axis through c along u' in the cell
    (c where it crosses the plane x.u = 0; in the plane across u, q bounds how far its projection d lies from
    the foot's), with the points rel_i seen from the projected foot and a width w' < best: w' (r_out + r_in) =
    r_out^2 - r_in^2 >= F (an area bound valid over the cell), r_out + r_in = 2 r_in + w' and r_in <= r_in_max,
    so w' >= F / (2 r_in_max + best) (r_in_max from _inner_radius_max: second order in q, not first).

    Cells wider than TILT_DELTA: each point's distance rho' to the axis (c, u') and rho to (c, u) satisfy
    rho cos(delta) - Z sin(delta) <= rho' <= rho + Z sin(delta) (Z = max |x.u|), so w' >= w_u(c) - slack,
    slack = (1 - cos delta) M + 2 Z sin delta (M >= every rho), with F the annulus area bound across u (the dual
    weights of the last cell's active points when they are still feasible and prune the cell, else the linear
    program) and W = best + slack for best. Smaller cells (those around the optimum, where a slack first order in
    delta makes the cells shrink to ~ tolerance / length): F from the tilted annulus program (_tilted_area_lower,
    the tilt a variable of the program: what is left is second order in the tilt but for a term in
    q tan(delta)) and r_in_max grown by Z tan(delta)."""
    norm_foot = float(np.sqrt(foot @ foot))
    basis = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    carry: tuple[np.ndarray, np.ndarray] | None = None  # the inner-radius weights, cell to cell
    tilt_weights: tuple[np.ndarray, ...] | None = None  # the tilted program's weights, cell to cell

    def _by_inner(rel: np.ndarray, q: float, area: float, slack: float, program: bool = True, pad: float = 0.0,
                  centre: np.ndarray | None = None) -> float:
        """area / (2 (r_in_max + pad) + W): the cell is pruned when r_in_max is at most ``enough``."""
        nonlocal carry
        enough = 0.5 * (area / (best + slack) - best - slack) - pad if area > 0 else -np.inf
        r_in, carry = _inner_radius_max(rel, q, carry, enough, program, centre)
        return area / (2.0 * (r_in + pad) + best + slack)

    def tilted(rel: np.ndarray, dist: np.ndarray, zs: np.ndarray, q: float, sigma: float) -> float:
        """The bound of a small cell: the carried weights of the tilted program first, the program (from the
        points nearest and farthest from the foot and the carried ones) when they do not prune the cell."""
        nonlocal tilt_weights
        pad = float(np.abs(zs).max()) * sigma  # rho' <= |rel_i - d| + |z_i| tan(delta): see _tilt_certificate
        if tilt_weights is not None:
            area = _tilt_certificate(rel, zs, *tilt_weights, q, sigma)
            if area > 0:
                value = _by_inner(rel, q, area, 0.0, program=False, pad=pad, centre=_ORIGIN2)
                if value >= best:
                    return value
        order = np.argsort(dist)
        k = min(TILT_START, len(dist))
        start = [order[:k], order[-k:]] + ([] if tilt_weights is None else [tilt_weights[0], tilt_weights[2]])
        area, weights = _tilted_area_lower(rel, zs, np.concatenate(start), q, sigma)
        if weights is not None:
            tilt_weights = weights
        return _by_inner(rel, q, area, 0.0, pad=pad, centre=_ORIGIN2) if area > 0 else 0.0

    def bound(u: np.ndarray, delta: float) -> float:
        nonlocal basis
        f = frame_with_axis(u)[:, :2]
        q = centre_range + (centre_range + norm_foot) * np.tan(min(delta, 1.0))
        rel = xs @ f - foot @ f
        dist = np.sqrt(np.einsum("ij,ij->i", rel, rel))
        zs = xs @ u
        if delta <= TILT_DELTA:
            return tilted(rel, dist, zs, q, float(np.tan(delta)))
        z = float(np.abs(zs).max())
        slack = (1.0 - np.cos(delta)) * (float(dist.max()) + q) + 2.0 * z * np.sin(delta)
        scale = 2.0 * (float(dist.min()) + q) + best + slack
        if len(basis[0]) and len(basis[1]):
            area = _annulus_dual(rel, basis[0], basis[1], q)
            if np.isfinite(area) and area / scale - slack >= best:
                return area / scale - slack
            if np.isfinite(area) and _annulus_basis_optimal(rel, basis[0], basis[1]):
                return max(area / scale, _by_inner(rel, q, area, slack)) - slack
            if np.isfinite(area) and area > 0 and carry is not None:  # a valid bound, if not the program's best
                value = _by_inner(rel, q, area, slack, program=False) - slack
                if value >= best:
                    return value
        order = np.argsort(dist)
        k = min(ZONE_LP_POINTS, len(xs))
        keep = np.unique(np.concatenate([order[:k], order[-k:]]))  # a subset: its bound holds for all points
        area, outer, inner = _annulus_area_lower(rel, keep, q)
        if len(outer) and len(inner):
            basis = (outer, inner)
        value = area / scale - slack
        if value < best:  # not pruned: the inner radius bounded over the axis positions, not from the foot's
            value = max(value, _by_inner(rel, q, area, slack) - slack)
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
    (there the cells shrink until the bound closes). Cells whose centre lies within NEAR_BUDGET_DEG of ``u_best``
    count against NEAR_CELLS, the others against PROOF_CELLS; the search stops when either runs out. Returns
    (lowest bound left, cells evaluated, of which within NEAR_DEG of u_best)."""
    import heapq

    frame = frame_with_axis(u0)
    e1, e2 = frame[:, 0], frame[:, 1]
    t_max = np.tan(np.radians(cone))
    budget_near, near = np.radians(NEAR_BUDGET_DEG), np.radians(NEAR_DEG)
    recorded = [0]  # cells evaluated within NEAR_DEG of u_best

    def bound(p: float, q: float, h: float) -> float:
        return cell_bound(unit(u0 + p * e1 + q * e2), min(np.sqrt(2.0) * h, np.pi / 2))

    def is_near(p: float, q: float) -> bool:
        angle = np.arccos(min(1.0, abs(float(unit(u0 + p * e1 + q * e2) @ u_best))))
        recorded[0] += int(angle <= near)
        return bool(angle <= budget_near)

    n0 = 4
    h0 = t_max / n0
    heap: list[tuple[float, float, float, float]] = []
    counts = [0, 0]  # cells evaluated away from / within NEAR_BUDGET_DEG of u_best
    for i in range(n0):
        for j in range(n0):
            p, q = -t_max + (2 * i + 1) * h0, -t_max + (2 * j + 1) * h0
            counts[is_near(p, q)] += 1
            heapq.heappush(heap, (bound(p, q, h0), p, q, h0))
    while heap:
        lower, p, q, h = heap[0]
        if lower >= best or counts[0] >= PROOF_CELLS or counts[1] >= NEAR_CELLS:
            return lower, sum(counts), recorded[0]
        heapq.heappop(heap)
        for dp, dq in ((-1, -1), (-1, 1), (1, -1), (1, 1)):
            cp, cq, ch = p + dp * h / 2, q + dq * h / 2, h / 2
            if np.hypot(cp, cq) - np.sqrt(2.0) * ch > t_max:
                continue  # outside the cone
            child = bound(cp, cq, ch)
            counts[is_near(cp, cq)] += 1
            if child < best:
                heapq.heappush(heap, (child, cp, cq, ch))
    return best, sum(counts), recorded[0]


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
