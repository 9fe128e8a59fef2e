"""Small dense linear programs solved by HiGHS with prebuilt arrays (the cylinder criteria's inner loops).

``scipy.optimize.linprog`` spends most of a small program's time outside the solver (parsing and checking
its arguments, checking each option against HiGHS, building a sparse matrix). The branch and bound of the
cylinder proof and the sequential linear programming of the criteria solve hundreds of programs of a few
variables, so ``solve`` hands the dense constraint matrix straight to the HiGHS solver that scipy ships,
with its options set once, and falls back to ``linprog`` where that solver cannot be reached.

    minimise c.x  subject to  lhs <= A x <= rhs,  lb <= x <= ub

Returns ``LpResult`` (ok, x, row duals: d objective / d row bound, <= 0 on an active upper bound, >= 0 on an
active lower bound, as linprog's ``ineqlin.marginals``).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

try:  # the HiGHS bindings scipy ships (private: when they move, linprog takes over)
    import scipy.optimize._highspy._core as _h

    _OPTIONS = _h.HighsOptions()
    _OPTIONS.output_flag = False
    _OPTIONS.log_to_console = False
    _OPTIONS.presolve = "off"  # programs of a few columns: presolve costs more than it saves
    _OK = _h.HighsModelStatus.kOptimal
except Exception:  # pragma: no cover - depends on the scipy build
    _h = None

INF = np.inf
_LOCAL = threading.local()


@dataclass
class LpResult:
    ok: bool
    x: np.ndarray
    duals: np.ndarray
    message: str = ""


def _linprog(c: np.ndarray, a: np.ndarray, lhs: np.ndarray, rhs: np.ndarray, lb: np.ndarray,
             ub: np.ndarray) -> LpResult:
    from scipy.optimize import linprog

    upper, lower = np.isfinite(rhs), np.isfinite(lhs)
    a_ub = np.vstack([a[upper], -a[lower]])
    b_ub = np.concatenate([rhs[upper], -lhs[lower]])
    bounds = [(None if not np.isfinite(lo) else lo, None if not np.isfinite(hi) else hi) for lo, hi in zip(lb, ub)]
    res = linprog(c, A_ub=a_ub, b_ub=b_ub, bounds=bounds, method="highs")
    if res.status != 0:
        return LpResult(False, np.zeros(len(c)), np.zeros(len(a)), str(res.message))
    marg = res.ineqlin.marginals
    duals = np.zeros(len(a))
    duals[upper] = marg[:int(upper.sum())]
    duals[lower] -= marg[int(upper.sum()):]
    return LpResult(True, np.asarray(res.x), duals)


def solve(c: np.ndarray, a: np.ndarray, lhs: np.ndarray, rhs: np.ndarray, lb: np.ndarray,
          ub: np.ndarray) -> LpResult:
    """Solve the dense program (see the module's docstring); ``-inf`` / ``inf`` for a missing bound."""
    c = np.ascontiguousarray(c, dtype=np.float64)
    a = np.asarray(a, dtype=np.float64)
    if _h is None:  # pragma: no cover
        return _linprog(c, a, lhs, rhs, lb, ub)
    m, n = a.shape
    mask = a.T != 0.0  # column-wise, explicit zeros dropped
    # plain lists: the bindings copy a list several times faster than a numpy array
    lp = _h.HighsLp()
    lp.num_col_ = n
    lp.num_row_ = m
    lp.col_cost_ = c.tolist()
    lp.col_lower_ = np.maximum(lb, -_h.kHighsInf).tolist()
    lp.col_upper_ = np.minimum(ub, _h.kHighsInf).tolist()
    lp.row_lower_ = np.maximum(lhs, -_h.kHighsInf).tolist()
    lp.row_upper_ = np.minimum(rhs, _h.kHighsInf).tolist()
    lp.a_matrix_.num_col_ = n
    lp.a_matrix_.num_row_ = m
    lp.a_matrix_.format_ = _h.MatrixFormat.kColwise
    lp.a_matrix_.start_ = [0] + np.cumsum(mask.sum(axis=1)).tolist()
    lp.a_matrix_.index_ = np.nonzero(mask)[1].tolist()
    lp.a_matrix_.value_ = a.T[mask].tolist()
    highs = getattr(_LOCAL, "highs", None)
    if highs is None:  # one solver per thread, its options set once
        highs = _LOCAL.highs = _h._Highs()
        highs.passOptions(_OPTIONS)
    if highs.passModel(lp) == _h.HighsStatus.kError or highs.run() == _h.HighsStatus.kError:
        return _linprog(c, a, lhs, rhs, lb, ub)
    status = highs.getModelStatus()
    if status != _OK:
        return LpResult(False, np.zeros(n), np.zeros(m), highs.modelStatusToString(status))
    sol = highs.getSolution()
    return LpResult(True, np.array(sol.col_value), np.array(sol.row_dual))
