"""Chebyshev-type criteria by sequential linear programming (HiGHS, see lp_small).

For a model of fit_models (radius = last local parameter) and a start state
(the least-squares solution) each iteration linearises d + J delta and solves

- "minzone": min h  s.t. -h <= d + J delta <= h   (zone half-width h)
- "mcc":     min delta_r  s.t. d + J delta <= 0   (every point inside)
- "mic":     max delta_r  s.t. d + J delta >= 0   (every point outside)

inside a box trust region |delta| <= Delta, accepting a step only when the
true objective (max |d|, max distance, -min distance) improves.  At a vertex
solution (n + 1 active points: the generic case) this converges
quadratically to the exact optimum of the non-linear problem; in general it
finds a local optimum near the least-squares start.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmm.metrology import lp_small
from cmm.metrology.features import FitError
from cmm.metrology.fit_solver import Model

CRITERIA = ("minzone", "mcc", "mic")


def _shift_radius(model: Model, state: Any, d: np.ndarray, criterion: str, n: int) -> Any:
    """Move the radius so the state is feasible (mcc/mic) or centred in its zone (minzone)."""
    shift = {"minzone": 0.5 * (d.max() + d.min()), "mcc": d.max(), "mic": d.min()}[criterion]
    step = np.zeros(n)
    step[-1] = shift
    return model.update(state, step)


ACTIVE_POINTS = 200  # points in each step's first linear program (the largest residuals); violators join after,
GENERATE_ABOVE = 2000  # on more points than this (fewer: the program on every point, whose optimal vertex can
# differ from the generated one's where the program is degenerate, and the search from it end elsewhere)


def _lp_rows(d: np.ndarray, jac: np.ndarray, criterion: str, delta: float) -> tuple[np.ndarray, ...]:
    """The step's program on the rows given: (c, A, lhs, rhs, lb, ub) for lhs <= A x <= rhs."""
    m, n = jac.shape
    # the radius (last) step is left free: it keeps every LP feasible and is bounded by the constraints
    lb = np.concatenate([np.full(n - 1, -delta), [-np.inf]])
    ub = np.concatenate([np.full(n - 1, delta), [np.inf]])
    if criterion == "minzone":  # -h <= d + J x <= h as two rows per point, h >= 0
        c = np.zeros(n + 1)
        c[-1] = 1.0
        ones = np.ones((m, 1))
        a = np.vstack([np.hstack([jac, -ones]), np.hstack([-jac, -ones])])
        return c, a, np.full(2 * m, -np.inf), np.concatenate([-d, d]), np.append(lb, 0.0), np.append(ub, np.inf)
    c = np.zeros(n)
    if criterion == "mcc":  # d + J x <= 0, the radius step minimised
        c[-1] = 1.0
        return c, jac, np.full(m, -np.inf), -d, lb, ub
    c[-1] = -1.0  # mic: d + J x >= 0, the radius step maximised
    return c, jac, -d, np.full(m, np.inf), lb, ub


def _violation(d: np.ndarray, jac: np.ndarray, criterion: str, x: np.ndarray) -> np.ndarray:
    """How far each point's linearised residual lies outside the step's constraints (<= 0: inside)."""
    n = jac.shape[1]
    lin = d + jac @ x[:n]
    if criterion == "minzone":
        return np.abs(lin) - x[n]
    return lin if criterion == "mcc" else -lin


def _lp_step(d: np.ndarray, jac: np.ndarray, criterion: str, delta: float) -> np.ndarray:
    """The trust-region step of the linearised criterion on all points, solved by constraint generation: the
    program on the points with the largest residuals (the others are far inside the zone), then the points the
    step violates added until it violates none (the same solution as the program on every point)."""
    m, n = jac.shape
    key = np.abs(d) if criterion == "minzone" else (d if criterion == "mcc" else -d)
    active = np.argsort(key)[-ACTIVE_POINTS:] if m > GENERATE_ABOVE else np.arange(m)
    tol = 1e-12 * max(1.0, float(np.abs(d).max()))
    for _ in range(50):
        res = lp_small.solve(*_lp_rows(d[active], jac[active], criterion, delta))
        if not res.ok:
            raise FitError(f"the linear program for the {criterion} criterion failed: {res.message}")
        if len(active) == m:
            break
        viol = _violation(d, jac, criterion, res.x)
        viol[active] = -np.inf
        out = np.flatnonzero(viol > tol)
        if not len(out):
            break
        worst = out[np.argsort(viol[out])[-ACTIVE_POINTS:]]
        active = np.concatenate([active, worst])
    return res.x[:n]


def chebyshev_fit(model: Model, state: Any, criterion: str, *, max_iter: int = 100, tol: float = 1e-14) -> Any:
    """Refine `state` (centred, scaled units) to the given criterion; returns the new state."""
    if criterion not in CRITERIA:
        raise ValueError(criterion)
    d, jac = model.residuals_jacobian(state)
    n = jac.shape[1]
    state = _shift_radius(model, state, d, criterion, n)
    d, jac = model.residuals_jacobian(state)
    f = _merit(state, d, criterion)
    delta = 0.1
    for _ in range(max_iter):
        step = _lp_step(d, jac, criterion, delta)
        trial = model.update(state, step)
        td, _ = model.residuals_jacobian(trial)
        # compare radius-independent objectives: minzone half zone; mcc/mic the feasible radius
        trial = _shift_radius(model, trial, td, criterion, n)
        td, tjac = model.residuals_jacobian(trial)
        tf = _merit(trial, td, criterion)
        step_size = float(np.max(np.abs(step)))
        if tf < f:
            state, d, jac, f = trial, td, tjac, tf
            if step_size >= 0.99 * delta:
                delta *= 2.0
        else:
            delta = 0.25 * step_size
        if step_size <= tol or delta <= tol:
            break
    return state


def _merit(state: Any, d: np.ndarray, criterion: str) -> float:
    """Value to minimise for a state whose radius was set by _shift_radius."""
    if criterion == "minzone":
        return float(np.abs(d).max())  # half the zone width
    radius = float(state[-1])  # all models used here keep the radius last
    return radius if criterion == "mcc" else -radius
