"""Levenberg-Marquardt engine for orthogonal-distance fits, and fit statistics.

A model works on centred, scaled points and exposes

    residuals_jacobian(state) -> (d, J)   # J w.r.t. a *local* minimal
                                          # parametrisation at `state` (step 0)
    update(state, step) -> state          # apply a step, re-parametrise

so each iteration linearises around the current estimate (e.g. a cylinder
axis frame is rotated to the current axis and the axis point moved back to
the plane through the centroid).  Steps are solved from the QR factor of
[J | d], which keeps memory at O(m n) and is cheap to re-damp.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from cmm.metrology.features import FitError


class Model(Protocol):
    kind: str

    def residuals_jacobian(self, state: Any) -> tuple[np.ndarray, np.ndarray]: ...

    def update(self, state: Any, step: np.ndarray) -> Any: ...


@dataclass
class Solution:
    state: Any
    residuals: np.ndarray
    jacobian: np.ndarray
    cost: float
    iterations: int


# Condition number of the reduced Jacobian beyond which the data do not fix the feature.
MAX_COND = 1e12


def _qr_reduce(jac: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r = np.linalg.qr(np.column_stack([jac, d]), mode="r")
    n = jac.shape[1]
    return r[:n, :n], r[:n, n]


def levenberg_marquardt(
    model: Model,
    state: Any,
    *,
    max_iter: int = 200,
    step_tol: float = 1e-13,
) -> Solution:
    """Minimise |d|^2. Stops when the step (in scaled units) is below step_tol,
    when the gradient vanishes, when no step reduces the cost, or when the cost
    is flat to rounding and the steps stop shrinking."""
    d, jac = model.residuals_jacobian(state)
    cost = float(d @ d)
    lam = 0.0  # start as pure Gauss-Newton: quadratic convergence on small residuals
    last_size = np.inf
    it = 0
    for it in range(1, max_iter + 1):
        r, qtd = _qr_reduce(jac, d)
        grad = r.T @ qtd
        if not np.all(np.isfinite(r)):
            raise FitError(f"the {model.kind} fit diverged (non-finite values)")
        scale_d = np.sqrt(np.sum(r * r, axis=0))  # column norms of J (Marquardt scaling)
        if np.linalg.norm(grad) <= 1e-15 * max(np.linalg.norm(scale_d) * np.sqrt(cost), 1e-300):
            break
        accepted = False
        while True:
            if lam > 0.0:
                a = np.vstack([r, np.diag(np.sqrt(lam) * np.maximum(scale_d, 1e-12))])
                rhs = np.concatenate([-qtd, np.zeros(len(qtd))])
            else:
                a, rhs = r, -qtd
            step, *_ = np.linalg.lstsq(a, rhs, rcond=None)
            new_state = model.update(state, step)
            new_d, new_jac = model.residuals_jacobian(new_state)
            new_cost = float(new_d @ new_d)
            # near the solution the cost is flat to rounding (relative 1e-12 for residuals that
            # cancel, e.g. the cone's), so tiny steps may raise it by that much and still be right
            slack = 1e-10 if lam == 0.0 and np.max(np.abs(step)) < 1e-6 else 1e-14
            if np.isfinite(new_cost) and new_cost <= cost * (1.0 + slack):
                accepted = True
                break
            lam = 1e-3 if lam == 0.0 else lam * 10.0
            if lam > 1e12:
                break
        if not accepted:
            break  # no descent possible: at the minimum to rounding
        # At the minimum the cost stops changing (rounding) before poorly determined
        # parameters (e.g. a cone apex) settle, so keep going while steps still shrink.
        stalled = new_cost >= cost
        size = float(np.max(np.abs(step)))
        state, d, jac, cost = new_state, new_d, new_jac, new_cost
        lam = 0.0 if lam <= 1e-3 else lam / 10.0
        if size <= step_tol or (stalled and size >= 0.5 * last_size):
            break
        last_size = size
    return Solution(state=state, residuals=d, jacobian=jac, cost=cost, iterations=it)


def check_conditioning(jac: np.ndarray, kind: str) -> None:
    """Refuse fits whose parameters the points do not determine."""
    s = np.linalg.svd(np.linalg.qr(jac, mode="r"), compute_uv=False)
    if s[-1] <= s[0] / MAX_COND:
        raise FitError(
            f"the points do not determine a {kind} (the fit is ill-conditioned): "
            "probe more of the surface"
        )


def statistics(
    residuals: np.ndarray,
    jac: np.ndarray,
    n_params: int,
    scale: float = 1.0,
    units: tuple[int, ...] | None = None,
    form: float | None = None,
) -> dict[str, Any]:
    """sigma, form and covariance for a solution found on points divided by `scale`.

    `residuals` are already in mm.  `jac` is the Jacobian of the scaled
    residuals w.r.t. the scaled parameters; `units[k]` is the length exponent of
    parameter k (1 length, 0 angle) used to express the covariance in mm / rad.
    """
    m = residuals.size
    dof = m - n_params
    sigma = float(np.sqrt(residuals @ residuals / dof)) if dof > 0 else float("nan")
    try:
        r = np.linalg.qr(jac, mode="r")
        rinv = np.linalg.inv(r)
        cov = rinv @ rinv.T
    except np.linalg.LinAlgError:
        cov = np.full((n_params, n_params), np.inf)
    if units is not None:
        s = np.asarray([scale ** u for u in units], dtype=np.float64)
        cov = cov * np.outer(s, s) / scale**2
    cov = cov * (sigma**2 if dof > 0 else np.nan)
    if form is None:
        form = float(residuals.max() - residuals.min())
    return {"sigma": sigma, "form": form, "covariance": cov}
