"""Chebyshev-type criteria by sequential linear programming (scipy linprog/HiGHS).

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
from scipy.optimize import linprog

from cmm.metrology.features import FitError
from cmm.metrology.fit_solver import Model

CRITERIA = ("minzone", "mcc", "mic")


def _shift_radius(model: Model, state: Any, d: np.ndarray, criterion: str, n: int) -> Any:
    """Move the radius so the state is feasible (mcc/mic) or centred in its zone (minzone)."""
    shift = {"minzone": 0.5 * (d.max() + d.min()), "mcc": d.max(), "mic": d.min()}[criterion]
    step = np.zeros(n)
    step[-1] = shift
    return model.update(state, step)


def _lp_step(d: np.ndarray, jac: np.ndarray, criterion: str, delta: float) -> np.ndarray:
    m, n = jac.shape
    # the radius (last) step is left free: it keeps every LP feasible and is bounded by the constraints
    bounds = [(-delta, delta)] * (n - 1) + [(None, None)]
    if criterion == "minzone":
        c = np.zeros(n + 1)
        c[-1] = 1.0
        ones = np.ones((m, 1))
        a_ub = np.vstack([np.hstack([jac, -ones]), np.hstack([-jac, -ones])])
        b_ub = np.concatenate([-d, d])
        bounds = bounds + [(0.0, None)]
    else:
        sign = 1.0 if criterion == "mcc" else -1.0  # mcc: d + J delta <= 0; mic: -(d + J delta) <= 0
        c = np.zeros(n)
        c[-1] = sign  # mcc: minimise the radius step; mic: maximise it
        a_ub, b_ub = sign * jac, -sign * d
    res = linprog(c, A_ub=a_ub, b_ub=b_ub, bounds=bounds, method="highs")
    if res.status != 0:
        raise FitError(f"the linear program for the {criterion} criterion failed: {res.message}")
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
