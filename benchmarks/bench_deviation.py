"""Point-to-mesh signed deviation and ICP timings: the station's engine vs a plain igl.signed_distance call.

Run: python benchmarks/bench_deviation.py [--points 100000] [--huge 10000000]
Prints, for each mesh, time and points/s of the station's engine (libigl AABB tree kept
between calls, chunked) and of one ``igl.signed_distance`` call (tree built per call) on
the same points in the same run, the speed-up, the largest difference between the two
(distance and closest point) and memory (tracemalloc peak of the call).  --huge N runs N points (e.g. 1e7) through the chunked engine
and prints its working memory beyond the input and output arrays.
"""

from __future__ import annotations

import argparse
import resource
import time
import tracemalloc
from types import SimpleNamespace
from typing import Any

import igl
import numpy as np
import trimesh

from cmm.metrology.align import best_fit
from cmm.metrology.mesh import signed_deviation
from cmm.metrology.transform import apply_points, invert, make_pose, rotation_about_axis
from cmm.sim.sample_part import sample_part


def near_surface_points(mesh: trimesh.Trimesh, n: int, spread: float, seed: int) -> np.ndarray:
    """CMM-like points: on the surface, moved +-spread mm along the normal."""
    points, faces = trimesh.sample.sample_surface(mesh, n, seed=seed)
    offsets = np.random.default_rng(seed).uniform(-spread, spread, n)
    return points + offsets[:, None] * mesh.face_normals[faces]


def _igl_signed_distance(mesh: trimesh.Trimesh, points: np.ndarray, pose: np.ndarray) -> Any:
    """The reference: one igl.signed_distance call in part coordinates (pseudo-normal signs, the station's
    convention), its tree built for this call."""
    local = apply_points(invert(pose), points)
    s, _, c, _ = igl.signed_distance(local, np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64),
                                     sign_type=igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL)
    return SimpleNamespace(deviations=np.asarray(s), closest_points=apply_points(pose, np.asarray(c)))


def _timed(mesh: trimesh.Trimesh, points: np.ndarray, pose: np.ndarray, method: str) -> tuple[float, Any, float, float]:
    mesh = mesh.copy()  # cold caches: the tree build is part of the cost of a first call
    run = signed_deviation if method == "station" else _igl_signed_distance
    start = time.perf_counter()
    result = run(mesh, points, pose)
    elapsed = time.perf_counter() - start
    start = time.perf_counter()
    run(mesh, points, pose)  # again: the station's case (mesh loaded once)
    warm = time.perf_counter() - start
    tracemalloc.start()
    run(mesh, points[: min(len(points), 100_000)], pose)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return elapsed, result, peak, warm


def bench_deviation(label: str, mesh: trimesh.Trimesh, points: np.ndarray, pose: np.ndarray) -> None:
    n = len(points)
    print(f"{label}: {n:,} points, {len(mesh.faces):,} faces", flush=True)
    t_igl, r_igl, peak_igl, w_igl = _timed(mesh, points, pose, "station")
    print(f"  station : first call {t_igl:6.2f} s {n / t_igl:>9,.0f} points/s; again {w_igl:6.2f} s "
          f"{n / w_igl:>9,.0f} points/s; call peak {peak_igl / 2**20:.0f} MiB", flush=True)
    t_tm, r_tm, peak_tm, w_tm = _timed(mesh, points, pose, "igl.signed_distance")
    print(f"  igl call: first call {t_tm:6.2f} s {n / t_tm:>9,.0f} points/s; again {w_tm:6.2f} s "
          f"{n / w_tm:>9,.0f} points/s; call peak {peak_tm / 2**20:.0f} MiB")
    dd = float(np.abs(r_igl.deviations - r_tm.deviations).max())
    dc = float(np.abs(r_igl.closest_points - r_tm.closest_points).max())
    signs = int(np.count_nonzero(np.sign(r_igl.deviations) != np.sign(r_tm.deviations)))
    print(f"  speed-up {t_tm / t_igl:.1f}x first call, {w_tm / w_igl:.1f}x again; max |d distance| {dd:.1e} mm, max |d closest point| {dc:.1e} mm, "
          f"sign differences {signs}; rms {r_igl.rms:.4f} mm", flush=True)


def bench_huge(n: int, pose: np.ndarray) -> None:
    """N points through the chunked engine: working memory stays bounded (tracemalloc peak
    minus the result arrays, which are 64 bytes per point)."""
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=50.0)
    pts = apply_points(pose, near_surface_points(sphere, 100_000, 0.1, seed=4))
    pts = np.tile(pts, (n // len(pts) + 1, 1))[:n]
    last = [0.0]

    def progress(done: int, total: int) -> None:
        if time.perf_counter() - last[0] > 5 or done == total:
            last[0] = time.perf_counter()
            print(f"    {done:,}/{total:,}", flush=True)

    tracemalloc.start()
    start = time.perf_counter()
    res = signed_deviation(sphere, pts, pose, progress=progress)
    elapsed = time.perf_counter() - start
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    out = res.deviations.nbytes + res.closest_points.nbytes + res.face_ids.nbytes + res.normals.nbytes
    print(f"huge: {n:,} points, {len(sphere.faces):,} faces: {elapsed:.1f} s, {n / elapsed:,.0f} points/s; "
          f"working memory beyond the {out / 2**20:.0f} MiB result: {(peak - out) / 2**20:.0f} MiB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--points", type=int, default=100_000)
    parser.add_argument("--huge", type=float, default=0, help="also run this many points (e.g. 1e7)")
    args = parser.parse_args()
    pose = make_pose(rotation_about_axis((1.0, 1.0, 0.2), np.radians(30.0)), (1000.0, 500.0, -200.0))

    sphere = trimesh.creation.icosphere(subdivisions=6, radius=50.0)  # 81,920 faces
    pts = apply_points(pose, near_surface_points(sphere, args.points, 0.1, seed=1))
    bench_deviation("sphere R50 mesh", sphere, pts, pose)

    # the target case: 1e5 points against a 1e5-face mesh (a torus, 100,000 faces)
    torus = trimesh.creation.torus(major_radius=40.0, minor_radius=10.0, major_sections=500, minor_sections=100)
    pts = apply_points(pose, near_surface_points(torus, args.points, 0.1, seed=5))
    bench_deviation("torus 100k faces", torus, pts, pose)

    part, _ = sample_part()
    fine = part.subdivide().subdivide()  # ~200k faces incl. long slivers on the flat faces
    pts = apply_points(pose, near_surface_points(fine, args.points, 0.1, seed=2))
    bench_deviation("sample part x16", fine, pts, pose)

    points, _ = trimesh.sample.sample_surface(part, 1000, seed=3)
    small = make_pose(rotation_about_axis((1.0, 2.0, -0.5), np.radians(1.0)), (0.8, -1.0, 0.6))
    start = time.perf_counter()
    fit = best_fit(part, apply_points(small, points))
    elapsed = time.perf_counter() - start
    print(
        f"ICP: 1,000 points on the sample part ({len(part.faces):,} faces), 1 deg / 1.4 mm offset: "
        f"{elapsed:.2f} s, {fit.iterations} iterations, converged={fit.converged}, "
        f"rms {fit.rms:.2e} mm, max {fit.max_residual:.2e} mm"
    )
    if args.huge:
        bench_huge(int(args.huge), pose)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"process peak RSS: {rss:.0f} MiB")


if __name__ == "__main__":
    main()
