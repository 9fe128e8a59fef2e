"""The height of a hop between two hits of one feature: over the part's local top, not the whole part's.

A feature's hits after the first may travel lower than the clearance plane: straight when the line is proven
free of the part, else over the hop height :func:`hop_height` gives (the control core's rails decide, and prove
every leg of the hop free of the part mesh before they take it; see :func:`cmm.control.rails.probe_clearance`).
The hop height is the highest point of the part over the hits' footprint (their XY bounding box grown by
``reach``, and the picked faces when given: a bore's rim, a boss's top) plus the tip radius and ``margin``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import trimesh

from .transform import apply_points, as_pose

HOP_MARGIN = 1.0  # mm between the tip and the part's local top on a hop, beyond the tip radius
HOP_REACH = 5.0  # mm the hits' footprint is grown by when looking for the part's local top


def hop_height(mesh: trimesh.Trimesh, pose: Any, points: Any, tip_radius: float, *, region: Any = None,
               reach: float = HOP_REACH, margin: float = HOP_MARGIN) -> float:
    """Machine Z of the tip centre for hops between hits at ``points`` (machine mm) on the part ``mesh`` at
    ``pose``: the highest of the hits, the mesh vertices over their footprint and the faces ``region``, plus
    ``tip_radius`` and ``margin``."""
    pts = np.asarray(points, float).reshape(-1, 3)
    verts = apply_points(as_pose(pose), np.asarray(mesh.vertices, float))
    lo, hi = pts[:, :2].min(axis=0) - reach, pts[:, :2].max(axis=0) + reach
    over = np.all((verts[:, :2] >= lo) & (verts[:, :2] <= hi), axis=1)
    tops = [float(pts[:, 2].max())]
    if over.any():
        tops.append(float(verts[over, 2].max()))
    if region is not None and len(region):
        tops.append(float(verts[np.unique(mesh.faces[np.asarray(region, np.int64)])][:, 2].max()))
    return max(tops) + float(tip_radius) + float(margin)


def with_hops(targets: Any, mesh: trimesh.Trimesh | None, pose: Any, tip_radius: float) -> list[tuple]:
    """A feature's hits (nominal point, approach, clearance Z; machine) with their hop heights: None for the first
    (it arrives over its clearance height), :func:`hop_height` over all the hits for the others (at most each
    one's clearance Z). Without a mesh, none."""
    targets = [tuple(t) for t in targets]
    if mesh is None or not targets:
        return [(*t, None) for t in targets]
    hop = hop_height(mesh, pose, [t[0] for t in targets], tip_radius)
    return [(*t, None if k == 0 else min(hop, float(t[2]))) for k, t in enumerate(targets)]
