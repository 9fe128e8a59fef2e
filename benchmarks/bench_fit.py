"""Fit timings and accuracy on known-answer data; comparison with scikit-spatial.

    python3 benchmarks/bench_fit.py            # LS to 1e6 points, criteria to capped sizes
    python3 benchmarks/bench_fit.py --max 1e5  # smaller run
    python3 benchmarks/bench_fit.py --only-skspatial  # just the side-by-side table

The side-by-side table runs sphere, circle (standard definition: least-squares
plane, then the 2D circle; scikit-spatial's Plane.best_fit + Circle.best_fit) and
cylinder at 1e3 / 1e5 / 1e6 points.

Data: null-space known answers (tests/knownanswer.py) 1000 mm from the
origin, 0.01 mm form error.  "err" is the worst of position (mm), size (mm)
and direction (rad) error against the constructed answer.  Times are wall
clock of one fit (best of 3 below 1e5 points) on a shared machine.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import knownanswer as ka  # noqa: E402

from cmm.metrology import fit_criteria, fit_ls  # noqa: E402

FAR = np.array([1000.0, -400.0, 300.0])
AXIS = np.array([0.3, -0.5, 0.81])
SIZES = [10**3, 10**4, 10**5, 10**6]


def closest(p: np.ndarray, u: np.ndarray) -> np.ndarray:
    u = u / np.linalg.norm(u)
    return p - (p @ u) * u


def angle(u: np.ndarray, v: np.ndarray) -> float:
    return float(np.linalg.norm(np.cross(u / np.linalg.norm(u), v / np.linalg.norm(v))))


def error(kind: str, res: Any, ans: dict) -> float:
    """Worst of position / size / direction error against the known answer."""
    if kind == "line":  # axis points compared at the foot of the origin on each (NIST), not the centroid's foot
        return max(angle(res.direction, ans["direction"]),
                   float(np.linalg.norm(closest(res.point, res.direction) - closest(ans["point"], res.direction))))
    if kind == "plane":
        return max(angle(res.normal, ans["normal"]), abs(float((res.point - ans["point"]) @ res.normal)))
    if kind in ("circle", "sphere"):
        e = [float(np.linalg.norm(res.center - ans["center"])), abs(res.radius - ans["radius"])]
        return max(e + ([angle(res.normal, ans["normal"])] if kind == "circle" else []))
    if kind == "cylinder":
        return max(angle(res.direction, ans["direction"]), abs(res.radius - ans["radius"]),
                   float(np.linalg.norm(closest(res.point, res.direction) - closest(ans["point"], res.direction))))
    if kind == "cone":
        return max(angle(res.direction, ans["direction"]), abs(res.half_angle - ans["half_angle"]),
                   float(np.linalg.norm(res.apex - ans["apex"])))
    if kind == "torus":
        return max(angle(res.normal, ans["normal"]), float(np.linalg.norm(res.center - ans["center"])),
                   abs(res.major_radius - ans["major_radius"]), abs(res.minor_radius - ans["minor_radius"]))
    raise ValueError(kind)


BUILDERS: dict[str, Callable[[int], ka.KnownAnswer]] = {
    "line": lambda m: ka.line(FAR, AXIS, m=m),
    "plane": lambda m: ka.plane(FAR, AXIS, m=m),
    "circle": lambda m: ka.circle3d_standard(FAR, AXIS, 25.0, m=m),
    "sphere": lambda m: ka.sphere(FAR, 12.5, m=m),
    "cylinder": lambda m: ka.cylinder(FAR, AXIS, 8.0, m=m),
    "cone": lambda m: ka.cone(FAR, AXIS, np.radians(20.0), m=m),
    "torus": lambda m: ka.torus(FAR, AXIS, 25.0, 4.0, m=m),
}

# criteria and the largest size each is run at (LP / Voronoi / hull cost grows faster than LS)
CRITERIA_CAPS = {
    ("plane", "minzone"): 10**5,   # LP on the hull vertices with a certificate (bench_flatness.py)
    ("line", "minzone"): 10**4,    # SLP, 2m LP rows
    ("circle", "minzone"): 10**4,  # SLP
    ("circle", "mic"): 10**4,      # exact, 2D Voronoi: qhull is slow on cocircular points (22 s at 1e5)
    ("circle", "mcc"): 10**6,      # exact, Welzl on hull vertices
    ("sphere", "minzone"): 10**4,  # SLP
    ("sphere", "mic"): 10**3,      # exact, 3D Voronoi: qhull is slow on cospherical points (12 s at 1e4)
    ("sphere", "mcc"): 10**6,      # exact, Welzl on hull vertices
    ("cylinder", "minzone"): 10**4,
    ("cylinder", "mic"): 10**4,
    ("cylinder", "mcc"): 10**4,
}


def timed(fn: Callable[[], Any], m: int) -> tuple[float, Any]:
    best, out = np.inf, None
    for _ in range(3 if m < 10**5 else 1):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def cell(t: float, err: float | None = None) -> str:
    s = f"{t * 1e3:9.1f} ms" if t < 10 else f"{t:9.2f} s "
    return s + (f" {err:7.1e}" if err is not None else "")


def run_ls(sizes: list[int], data: dict) -> None:
    print("\nLeast-squares fits: time per fit and max error vs the known answer (mm / rad)")
    print(f"{'feature':10s}" + "".join(f"{m:>22,d}" for m in sizes))
    for kind in BUILDERS:
        row = f"{kind:10s}"
        for m in sizes:
            d = data[(kind, m)]
            t, res = timed(lambda: fit_ls.LS_FITS[kind](d.points), m)
            row += f"{cell(t, error(kind, res, d.answer)):>22s}"
        print(row, flush=True)


def run_criteria(sizes: list[int], data: dict) -> None:
    print("\nOther criteria: time per fit (capped sizes: '-' = not run, see CRITERIA_CAPS)")
    print(f"{'feature/method':18s}" + "".join(f"{m:>14,d}" for m in sizes))
    for (kind, method), cap in CRITERIA_CAPS.items():
        row = f"{kind + '/' + method:18s}"
        for m in sizes:
            if m > cap:
                row += f"{'-':>14s}"
                continue
            d = data[(kind, m)]
            t, _ = timed(lambda: fit_criteria.fit(kind, d.points, method), m)
            row += f"{cell(t):>14s}"
        print(row, flush=True)


def _sk_fit(kind: str, points: np.ndarray) -> dict:
    """scikit-spatial's fit, as a dict of our attribute names."""
    from skspatial.objects import Circle as SkCircle, Cylinder as SkCylinder, Plane as SkPlane, Sphere as SkSphere

    if kind == "sphere":
        sk = SkSphere.best_fit(points)
        return {"center": np.asarray(sk.point, float), "radius": float(sk.radius)}
    if kind == "circle":  # the standard definition with scikit-spatial's parts
        plane = SkPlane.best_fit(points)
        n = np.asarray(plane.normal, float)
        n /= np.linalg.norm(n)
        from cmm.metrology.geom_basics import frame_with_axis

        f = frame_with_axis(n)
        flat = (points - np.asarray(plane.point, float)) @ f[:, :2]
        c = SkCircle.best_fit(flat)
        return {"center": np.asarray(plane.point, float) + f[:, :2] @ np.asarray(c.point, float),
                "normal": n, "radius": float(c.radius)}
    sk = SkCylinder.best_fit(points)
    u = np.asarray(sk.vector, dtype=float)
    return {"point": np.asarray(sk.point, float), "direction": u / np.linalg.norm(u), "radius": float(sk.radius)}


class _Result:
    def __init__(self, values: dict):
        self.__dict__.update(values)


def run_skspatial(sizes: list[int], data: dict) -> None:
    print("\nSide by side with scikit-spatial (same known-answer data, 1000 mm from the origin)")
    try:
        import skspatial
    except ImportError:
        print("  skipped: scikit-spatial is not installed (pip install scikit-spatial).\n"
              "  It is only a point of comparison, not a dependency of this project.")
        return
    print(f"  scikit-spatial {skspatial.__version__}; err = worst of position (mm), size (mm), direction (rad)")
    print(f"  {'feature':9s}{'points':>11s} {'cmm time':>12s} {'cmm err':>9s} {'skspatial time':>15s} {'sk err':>9s}")
    for kind in ("sphere", "circle", "cylinder"):
        for m in sizes:
            d = data[(kind, m)]
            t_ours, ours = timed(lambda: fit_ls.LS_FITS[kind](d.points), m)
            try:
                t_sk, sk = timed(lambda: _sk_fit(kind, d.points), m)
                sk_err = f"{error(kind, _Result(sk), d.answer):9.1e}"
                sk_time = cell(t_sk)
            except Exception as exc:  # report, do not stop the table
                sk_err, sk_time = "failed", type(exc).__name__
            print(f"  {kind:9s}{m:>11,d} {cell(t_ours):>12s} {error(kind, ours, d.answer):9.1e} "
                  f"{sk_time:>15s} {sk_err:>9s}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max", type=float, default=1e6, help="largest point count (default 1e6)")
    parser.add_argument("--only-skspatial", action="store_true", help="only the comparison with scikit-spatial")
    args = parser.parse_args()
    sizes = [m for m in SIZES if m <= args.max]
    sk_sizes = [m for m in (10**3, 10**5, 10**6) if m <= args.max]
    print("generating known-answer data ...", flush=True)
    kinds = ("sphere", "circle", "cylinder") if args.only_skspatial else tuple(BUILDERS)
    need = sorted(set(sk_sizes) | (set() if args.only_skspatial else set(sizes)))
    data = {(kind, m): BUILDERS[kind](m) for kind in kinds for m in need}
    if not args.only_skspatial:
        run_ls(sizes, data)
        run_criteria(sizes, data)
    run_skspatial(sk_sizes, data)


if __name__ == "__main__":
    main()
