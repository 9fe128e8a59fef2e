"""Deviation colour map timings: what turning the map on (or a new hit) costs the 3D view, and the report's views.

Run: python benchmarks/bench_colour_map.py [--hits 10 100 1000]
For the sample part (and a 80 000-face sphere, decimated for display), per number of hits spread over the
surface: the display mesh build (once per part), the map (closest points, refinement near the hits, vertex
deviations), the GLB the scene sends (size, export time), and the report's three z-buffered map views.
Compare the figures within one run: the machine is shared.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import trimesh

from cmm.metrology.colour_map import REPORT_FACES, SCENE_FACES, deviation_map, display_mesh, hits_on_surface
from cmm.metrology.colour_scale import ColourScale
from cmm.session.report import VIEWS, part_view
from cmm.sim.sample_part import sample_part


def hits_on(mesh: trimesh.Trimesh, n: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """n points on the surface with deviations of +-30 um (a smooth wave over the part)."""
    points, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    dev = 0.03 * np.sin(points[:, 0] / 20.0) * np.cos(points[:, 1] / 25.0)
    return points, dev


def run(name: str, mesh: trimesh.Trimesh, counts: list[int]) -> None:
    scale = ColourScale()
    t = time.perf_counter()
    disp = display_mesh(mesh, SCENE_FACES)
    print(f"{name}: {len(mesh.faces)} faces; display mesh {len(disp.faces)} faces in "
          f"{(time.perf_counter() - t) * 1000:.0f} ms (once per part)")
    for n in counts:
        pts, dev = hits_on(mesh, n)
        t = time.perf_counter()
        dmap = deviation_map(mesh, pts, dev, scale)
        colours = dmap.vertex_colours
        t_map = time.perf_counter() - t
        t = time.perf_counter()
        glb = dmap.coloured_mesh().export(file_type="glb")
        t_glb = time.perf_counter() - t
        t = time.perf_counter()
        rmap = deviation_map(mesh, pts, dev, scale, faces=REPORT_FACES)
        normals = hits_on_surface(mesh, pts)[1]  # once for the three views, as the report does
        svgs = [part_view(mesh, pts, list(dev), scale, np.array(v), title, dmap=rmap, hit_normals=normals)
                for title, v in VIEWS]
        t_report = time.perf_counter() - t
        print(f"  {n:5d} hits: map {t_map * 1000:6.0f} ms ({len(dmap.mesh.faces)} faces, "
              f"{len(colours)} vertex colours, {dmap.coverage * 100:3.0f} % coloured) · GLB {len(glb) / 1e6:.2f} MB "
              f"in {t_glb * 1000:.0f} ms · report views {t_report * 1000:6.0f} ms "
              f"({sum(len(s) for s in svgs) / 1e3:.0f} kB)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hits", type=int, nargs="+", default=[10, 100, 1000])
    args = parser.parse_args()
    run("sample part", sample_part()[0], args.hits)
    run("sphere r=40", trimesh.creation.icosphere(subdivisions=6, radius=40.0), args.hits)


if __name__ == "__main__":
    main()
