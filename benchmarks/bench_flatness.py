"""Flatness (minimum zone plane) timing on the shapes real plates have, beside an independent LP.

    python3 benchmarks/bench_flatness.py [--sizes 100000 1000000] [--shapes bowed saddle] [--reference-max N]

Shapes (a 100 mm square plate, tilted and 1000 mm from the origin, 0.5 um noise):

- bowed: 5 um of convexity (a dome: every point is on the convex hull, the worst case for hull methods);
- saddle: +-5 um (u^2 - v^2);
- two-level: half the plate 5 um higher (a step);
- noisy: flat with 2 um noise.

Prints the time of fit_criteria.fit("plane", points, "minzone") (constraint-generation LP with its global
certificate, fit_hull.min_width_3d) in wall and CPU seconds (the CPU figure is the one to compare on a
loaded machine; HiGHS and numpy may use more than one thread), its certified gap to the global optimum, and the width and time of an
independent reference: one scipy linprog (HiGHS) on every point, written here, re-framed until the normal
stops moving. Targets: 1e5 points < 0.5 s, 1e6 points < 5 s on every shape.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy.optimize import linprog

from cmm.metrology import fit_criteria
from cmm.metrology.fit_hull import min_width_3d

SHAPES = ("bowed", "saddle", "two-level", "noisy")


def plate(shape: str, m: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-50, 50, (m, 2))
    u, v = uv.T
    w = {"bowed": 0.005 * (1 - (u * u + v * v) / 5000.0),
         "saddle": 0.005 * (u * u - v * v) / 2500.0,
         "two-level": np.where(u > 0, 0.005, 0.0),
         "noisy": 0.0015 * rng.standard_normal(m)}[shape] + 0.0005 * rng.standard_normal(m)
    q, _ = np.linalg.qr(np.random.default_rng(99).standard_normal((3, 3)))
    return np.array([1000.0, -400.0, 300.0]) + np.column_stack([uv, w]) @ q.T


def reference_width(points: np.ndarray) -> float:
    """Minimum zone width by one LP over all points per frame: min hi - lo, lo <= w - a x - b y <= hi."""
    x = points - points.mean(axis=0)
    n = np.linalg.svd(x, full_matrices=False)[2][2]
    for _ in range(4):
        e1 = np.cross(np.eye(3)[np.argmin(np.abs(n))], n)
        e1 /= np.linalg.norm(e1)
        local = x @ np.column_stack([e1, np.cross(n, e1), n])
        m = len(local)
        a_ub = np.vstack([np.column_stack([-local[:, 0], -local[:, 1], np.zeros(m), -np.ones(m)]),
                          np.column_stack([local[:, 0], local[:, 1], np.ones(m), np.zeros(m)])])
        res = linprog([0, 0, -1, 1], A_ub=a_ub, b_ub=np.concatenate([-local[:, 2], local[:, 2]]),
                      bounds=[(None, None)] * 4, method="highs")
        a, b = res.x[:2]
        n = np.column_stack([e1, np.cross(n, e1), n]) @ np.array([-a, -b, 1.0])
        n /= np.linalg.norm(n)
    h = x @ n
    return float(h.max() - h.min())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000])
    ap.add_argument("--no-reference", action="store_true", help="skip the independent LP")
    ap.add_argument("--reference-max", type=int, default=100_000,
                    help="largest point count the independent LP runs on (at 1e6 it takes ~9 minutes)")
    ap.add_argument("--shapes", nargs="+", default=list(SHAPES), choices=SHAPES)
    args = ap.parse_args()
    print(f"{'shape':>10} {'points':>10} {'minzone':>9} {'(CPU)':>9} {'width (um)':>11} {'gap (mm)':>9} "
          f"{'reference LP':>13} {'|diff| (mm)':>12}")
    for shape in args.shapes:
        for m in args.sizes:
            pts = plate(shape, m)
            fit_criteria.fit("plane", pts[:1000], "minzone")  # warm up imports
            t, cpu = time.perf_counter(), time.process_time()
            res = fit_criteria.fit("plane", pts, "minzone")
            t_fit, cpu = time.perf_counter() - t, time.process_time() - cpu
            xc = pts - pts.mean(axis=0)
            _, _, gap = min_width_3d(xc, fit_criteria.fit_ls.fit_plane(pts).normal)
            if args.no_reference or m > args.reference_max:
                ref = diff = "-"
            else:
                t = time.perf_counter()
                w_ref = reference_width(pts)
                ref = f"{w_ref * 1000:7.4f} um {time.perf_counter() - t:5.1f} s"
                diff = f"{abs(w_ref - res.form):.1e}"
            print(f"{shape:>10} {m:>10,d} {t_fit:7.3f} s {cpu:7.3f} s {res.form * 1000:11.4f} {gap:9.1e} {ref:>13} {diff:>12}",
                  flush=True)


if __name__ == "__main__":
    main()
