"""Point-to-mesh signed deviation and ICP timings.

Run: python benchmarks/bench_deviation.py [--points 100000]
Prints time, points/s and memory (tracemalloc peak of the call, process peak RSS).
"""

from __future__ import annotations

import argparse
import resource
import time
import tracemalloc

import numpy as np
import trimesh

from cmm.metrology.align import best_fit
from cmm.metrology.mesh import signed_deviation
from cmm.metrology.transform import apply_points, make_pose, rotation_about_axis
from cmm.sim.sample_part import sample_part


def near_surface_points(mesh: trimesh.Trimesh, n: int, spread: float, seed: int) -> np.ndarray:
    """CMM-like points: on the surface, moved +-spread mm along the normal."""
    points, faces = trimesh.sample.sample_surface(mesh, n, seed=seed)
    offsets = np.random.default_rng(seed).uniform(-spread, spread, n)
    return points + offsets[:, None] * mesh.face_normals[faces]


def bench_deviation(label: str, mesh: trimesh.Trimesh, points: np.ndarray, pose: np.ndarray) -> None:
    signed_deviation(mesh, points[:100], pose)  # warm trimesh caches (R-tree, normals)
    start = time.perf_counter()
    result = signed_deviation(mesh, points, pose)
    elapsed = time.perf_counter() - start
    tracemalloc.start()
    signed_deviation(mesh, points, pose)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    print(
        f"{label}: {len(points):,} points, {len(mesh.faces):,} faces: {elapsed:.2f} s, "
        f"{len(points) / elapsed:,.0f} points/s, call peak {peak / 2**20:.0f} MiB, "
        f"rms {result.rms:.4f} mm"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--points", type=int, default=100_000)
    args = parser.parse_args()
    pose = make_pose(rotation_about_axis((1.0, 1.0, 0.2), np.radians(30.0)), (1000.0, 500.0, -200.0))

    sphere = trimesh.creation.icosphere(subdivisions=6, radius=50.0)  # 81,920 faces
    pts = apply_points(pose, near_surface_points(sphere, args.points, 0.1, seed=1))
    bench_deviation("sphere R50 mesh", sphere, pts, pose)

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
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"process peak RSS: {rss:.0f} MiB")


if __name__ == "__main__":
    main()
