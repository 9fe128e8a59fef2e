"""The CAD nominal of a measured feature, found from where its hits lie on the part mesh.

An operator measures a boss with eight hits and never clicks it: its nominal
is the mesh surface those hits touched. :func:`nominal_for_points` finds the
face nearest to each hit (part coordinates), takes the face most hits are
nearest to, grows and classifies its surface (:func:`pick.suggest_feature`)
and returns the nominal in machine coordinates when its kind suits the
fitted kind (a circle or cylinder on a cylinder, a plane on a plane ...).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .characteristics import COMPARABLE
from .pick import NominalFeature, suggest_feature
from .transform import apply_points, as_pose, invert

MAX_DISTANCE = 2.0  # mm: hits farther than this from the mesh are not on it (set-up error up to ~1 mm)


def nominal_for_points(mesh: Any, pose: Any, points: Any, kind: str, max_distance: float = MAX_DISTANCE
                       ) -> NominalFeature | None:
    """The nominal feature (machine coordinates) the points were taken on, or None."""
    wanted = COMPARABLE.get(kind, ())
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not wanted or len(pts) == 0 or mesh is None:
        return None
    T = as_pose(pose)
    local = apply_points(invert(T), pts)
    closest, distance, faces = mesh.nearest.on_surface(local)
    near = np.asarray(distance) <= max_distance
    if near.sum() < max(1, (len(pts) + 1) // 2):
        return None
    ids, counts = np.unique(np.asarray(faces)[near], return_counts=True)
    for face in ids[np.argsort(-counts)][:3]:  # the most-touched face first; a tessellation seam may split them
        try:
            suggestion = suggest_feature(mesh, int(face), T)
        except ValueError:
            continue
        if suggestion.feature.kind in wanted and suggestion.feature.kind != "surface":
            return suggestion.feature
        if kind == "plane" and suggestion.feature.kind == "surface":
            return NominalFeature("plane", dict(suggestion.feature.params))
    return None
