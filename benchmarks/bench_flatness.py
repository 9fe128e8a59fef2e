"""Flatness (minimum zone plane) timing: LP + certificate vs the exact O(h^2) hull search.

    python3 benchmarks/bench_flatness.py

Data: a 100 mm square plate with 5 um of convexity (a dome: every point is a hull
vertex on one side, the worst case for hull methods) plus 0.5 um noise, tilted and
1000 mm from the origin.  Prints the time of fit_criteria.minzone_plane, the
certified gap to the global optimum and, where it is affordable, the time and the
width of the exact enumeration of all hull facet and edge-pair directions.
"""

from __future__ import annotations

import time

import numpy as np

from cmm.metrology import fit_criteria
from cmm.metrology.fit_hull import min_width_3d, min_width_direction


def plate(m: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-50, 50, (m, 2))
    w = 0.005 * (1 - (uv**2).sum(axis=1) / 5000.0) + 0.0005 * rng.standard_normal(m)
    q, _ = np.linalg.qr(np.random.default_rng(99).standard_normal((3, 3)))
    return np.array([1000.0, -400.0, 300.0]) + np.column_stack([uv, w]) @ q.T


def main() -> None:
    print(f"{'points':>9} {'minzone_plane':>14} {'gap (mm)':>10} {'exact search':>13} {'|width diff|':>13}")
    for m in (250, 500, 1000, 10_000, 100_000):
        pts = plate(m)
        t = time.perf_counter()
        res = fit_criteria.fit("plane", pts, "minzone")
        t_lp = time.perf_counter() - t
        xc = pts - pts.mean(axis=0)
        _, _, gap = min_width_3d(xc, fit_criteria.fit_ls.fit_plane(pts).normal)
        if m <= 500:
            t = time.perf_counter()
            w_exact, _ = min_width_direction(xc)
            t_ex = time.perf_counter() - t
            exact, diff = f"{t_ex:10.2f} s ", f"{abs(w_exact - res.form):13.1e}"
        else:
            exact, diff = f"{'-':>13}", f"{'-':>13}"
        print(f"{m:>9,d} {t_lp:12.3f} s {gap:10.1e} {exact} {diff}", flush=True)


if __name__ == "__main__":
    main()
