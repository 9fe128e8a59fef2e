"""A plain local optimiser for the minimum-zone cylinder: the reference the solver is compared with.

Nelder-Mead (scipy) over the axis (two direction tilts and two offsets in the least-squares frame at the data
centre) minimising the zone width max - min of the points' distances to the axis, from the least-squares axis,
restarted from its own result until a restart gains less than 1 nm. ``cone_deg``: axes turned further from the
least-squares axis count as infinitely wide (the solver searches only that cone). Used by the tests (its value)
and by benchmarks/bench_cylinder_proof.py (its time).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize

from cmm.metrology import fit_ls
from cmm.metrology.geom_basics import frame_with_axis, unit


def nelder_mead_zone(points: np.ndarray, cone_deg: float = 90.0) -> float:
    """The minimum-zone width (mm) a plain Nelder-Mead over the axis reaches."""
    x = np.asarray(points, dtype=np.float64)
    ls = fit_ls.fit_cylinder(x)
    centre = x.mean(axis=0)
    xc = x - centre
    frame = frame_with_axis(ls.direction)
    p0 = ls.point - centre
    cos_cone = np.cos(np.radians(cone_deg))

    def width(v: np.ndarray) -> float:
        u = unit(frame[:, 2] + v[0] * frame[:, 0] + v[1] * frame[:, 1])
        if u @ frame[:, 2] < cos_cone:
            return np.inf
        r = xc - (p0 + v[2] * frame[:, 0] + v[3] * frame[:, 1])
        r = r - np.outer(r @ u, u)
        return float(np.ptp(np.sqrt(np.einsum("ij,ij->i", r, r))))

    v, best = np.zeros(4), np.inf
    while True:
        res = minimize(width, v, method="Nelder-Mead",
                       options={"xatol": 1e-10, "fatol": 1e-12, "maxiter": 20000, "maxfev": 20000})
        if res.fun > best - 1e-6:
            return float(min(best, res.fun))
        v, best = res.x, float(res.fun)
