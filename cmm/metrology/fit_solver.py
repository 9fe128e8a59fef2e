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
    r: np.ndarray | None = None  # R factor of the final Jacobian (set once the fit is accepted)


# Condition number of the reduced Jacobian beyond which the data do not fix the feature.
MAX_COND = 1e12


# Above this many rows the triangular factor comes from a Cholesky factor of the Gram matrix
# (one BLAS pass, 10-50x faster than Householder QR on 1e6 x 6); below it, and whenever the
# Gram matrix is too ill-conditioned to factor, from QR.  Both give the same R up to signs;
# the fixed point J^T d = 0 and hence the solution do not depend on which is used.
GRAM_ROWS = 20_000


def _triangular(a: np.ndarray) -> np.ndarray:
    """Upper triangular R with R^T R = A^T A (rows of R with a non-negative diagonal)."""
    if a.shape[0] > GRAM_ROWS:
        g = a.T @ a
        try:
            r = np.linalg.cholesky(g).T
            if np.all(np.isfinite(r)) and np.min(np.abs(np.diag(r))) > 1e-7 * np.max(np.abs(np.diag(r))):
                return r
        except np.linalg.LinAlgError:
            pass
    return np.linalg.qr(a, mode="r")


def _qr_reduce(jac: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    n = jac.shape[1]
    if jac.shape[0] > GRAM_ROWS:
        r = _triangular(jac)
        if r.shape == (n, n) and not np.allclose(r, 0):
            return r, np.linalg.solve(r.T, jac.T @ d)  # Q^T d = R^-T J^T d
    r = np.linalg.qr(np.column_stack([jac, d]), mode="r")
    return r[:n, :n], r[:n, n]


def levenberg_marquardt(
    model: Model,
    state: Any,
    *,
    max_iter: int = 300,
    step_tol: float = 1e-14,
) -> Solution:
    """Minimise |d|^2 (Gauss-Newton, damped only when a step does not descend).

    Convergence is judged on the step and the gradient, never on the cost: near
    the minimum the cost is flat to rounding (relative 1e-15) long before poorly
    determined parameters (short arcs, cone apex) have settled, and large-residual
    problems converge linearly with slowly shrinking steps.  Stops when
    - the step (scaled units) is below step_tol, or
    - the residual vector is orthogonal to the Jacobian's range to rounding, or
    - the steps are small (< 1e-7) and stop shrinking twice in a row (rounding floor), or
    - no damped step can reduce the cost (at the minimum to rounding).
    """
    d, jac = model.residuals_jacobian(state)
    cost = float(d @ d)
    lam = 0.0  # start as pure Gauss-Newton: quadratic convergence on small residuals
    nu = 2.0
    last_size = np.inf
    stuck = 0
    it = 0
    for it in range(1, max_iter + 1):
        r, qtd = _qr_reduce(jac, d)
        if not np.all(np.isfinite(r)) or not np.all(np.isfinite(qtd)):
            raise FitError(f"the {model.kind} fit diverged (non-finite values)")
        scale_d = np.maximum(np.sqrt(np.sum(r * r, axis=0)), 1e-12)  # column norms of J (Marquardt scaling)
        if np.linalg.norm(qtd) <= 1e-15 * np.sqrt(max(cost, 1e-300)):
            break  # gradient J^T d vanishes relative to |d|
        # Gauss-Newton's predicted reduction |Q^T d|^2: when it is below rounding of the cost,
        # comparing costs says nothing and the (tiny-gradient) GN step is trusted
        flat = float(qtd @ qtd) <= 1e-10 * cost
        accepted = False
        while True:
            if lam > 0.0:
                a = np.vstack([r, np.diag(np.sqrt(lam) * scale_d)])
                rhs = np.concatenate([-qtd, np.zeros(len(qtd))])
            else:
                a, rhs = r, -qtd
            step, *_ = np.linalg.lstsq(a, rhs, rcond=None)
            new_state = model.update(state, step)
            new_d, new_jac = model.residuals_jacobian(new_state)
            new_cost = float(new_d @ new_d)
            # tiny Gauss-Newton steps are trusted even if rounding raises the flat cost a little
            slack = 1e-10 if lam == 0.0 and (flat or np.max(np.abs(step)) < 1e-6) else 1e-14
            if np.isfinite(new_cost) and new_cost <= cost * (1.0 + slack):
                accepted = True
                break
            # Nielsen's damping update: grow faster after repeated failures
            lam = 1e-3 if lam == 0.0 else lam * nu
            nu *= 2.0
            if lam > 1e12:
                break
        if not accepted:
            break  # no descent possible: at the minimum to rounding
        size = float(np.max(np.abs(step)))
        # predicted vs actual reduction sets how much damping to keep (Nielsen 1999)
        if lam > 0.0:
            pred = float(qtd @ qtd - np.sum((r @ step + qtd) ** 2))
            rho = (cost - new_cost) / pred if pred > 0 else 0.0
            lam = lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            if lam < 1e-6:
                lam = 0.0
        nu = 2.0
        state, d, jac, cost = new_state, new_d, new_jac, new_cost
        if size <= step_tol:
            break
        stuck = stuck + 1 if (size < 1e-7 and size >= last_size) else 0
        if stuck >= 2:
            break
        last_size = size
    return Solution(state=state, residuals=d, jacobian=jac, cost=cost, iterations=it)


def r_factor(jac: np.ndarray) -> np.ndarray:
    """The n x n R of J = QR: R^T R = J^T J, so it stands in for J in the statistics (one QR of
    the tall Jacobian per fit instead of one per use)."""
    return _triangular(jac)


def check_conditioning(jac: np.ndarray, kind: str) -> None:
    """Refuse fits whose parameters the points do not determine (jac: J or its R factor)."""
    s = np.linalg.svd(_triangular(jac), compute_uv=False)
    if s[-1] <= s[0] / MAX_COND:
        raise FitError(
            f"the points do not determine a {kind} (the fit is ill-conditioned): "
            "probe more of the surface"
        )


# Noise amplification (parameter change per unit of point scatter, dimensionless) above
# which a fit warns that the data determine that parameter poorly.  A full circle or
# sphere gives about 1.4-1.7; a 30 degree arc about 60 in the radius; a 10 degree arc 500.
KAPPA_WARN = 100.0


def amplification(jac: np.ndarray, m: int | None = None) -> np.ndarray:
    """sqrt(m * diag((J^T J)^-1)) per parameter on centred, scaled data: how many units a
    parameter moves for one unit of independent scatter on every point (1 ~ averaging).
    `jac` may be the n x n R factor of J (same J^T J) when m, the number of rows of J, is given."""
    m = jac.shape[0] if m is None else m
    try:
        rinv = np.linalg.inv(_triangular(jac))
    except np.linalg.LinAlgError:
        return np.full(jac.shape[1], np.inf)
    return np.sqrt(m * np.sum(rinv * rinv, axis=1))


def statistics(
    residuals: np.ndarray,
    jac: np.ndarray,
    n_params: int,
    scale: float = 1.0,
    units: tuple[int, ...] | None = None,
    form: float | None = None,
    groups: dict[str, tuple[tuple[int, ...], float]] | None = None,
) -> dict[str, Any]:
    """sigma, form, covariance and standard uncertainties for a solution found on points
    divided by `scale`.

    `residuals` are already in mm.  `jac` is the Jacobian of the scaled
    residuals w.r.t. the scaled parameters; `units[k]` is the length exponent of
    parameter k (1 length, 0 angle) used to express the covariance in mm / rad.
    `groups` maps a reported name to (parameter indices, factor): its standard
    uncertainty is factor * sqrt(sum of their variances) (e.g. a centre's three
    coordinates, a diameter = 2 x radius).
    """
    m = residuals.size
    dof = m - n_params
    sigma = float(np.sqrt(residuals @ residuals / dof)) if dof > 0 else float("nan")
    try:
        r = _triangular(jac)
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
    out: dict[str, Any] = {"sigma": sigma, "form": form, "covariance": cov}
    if groups is not None:
        var = np.diag(cov)
        out["uncertainty"] = {name: float(f * np.sqrt(np.sum(var[list(idx)]))) for name, (idx, f) in groups.items()}
    return out
