"""Signed distances of points to a fitted feature given as its recorded geometry.

Recorded features (journal ``feature`` events) keep the geometry, not the
residuals; reports and the feature tree recompute the residuals of the
compensated hits from the geometry: + = outside the feature (away from the
axis/centre, along a plane's normal), in mm. ``around_axis`` gives each
point's angle about a feature's axis, for polar form plots.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def _unit(v: Any) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(v))
    if not n > 0:
        raise ValueError("a feature direction has zero length")
    return v / n


def axis_of(kind: str, geometry: dict[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """(point on the axis, unit axis) of an axial feature; None for planes, spheres, points."""
    if kind == "circle":
        return np.asarray(geometry["center"], float), _unit(geometry["normal"])
    if kind in ("cylinder", "line"):
        return np.asarray(geometry["point"], float), _unit(geometry["direction"])
    if kind == "cone":
        return np.asarray(geometry["apex"], float), _unit(geometry["direction"])
    return None


def surface_distance(kind: str, geometry: dict[str, Any], points: Any) -> np.ndarray:
    """Signed distance (mm) of each point (n x 3) to the feature surface."""
    g = geometry
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if kind == "plane":
        return (p - np.asarray(g["point"], float)) @ _unit(g["normal"])
    if kind == "sphere":
        return np.linalg.norm(p - np.asarray(g["center"], float), axis=1) - float(g["radius"])
    if kind == "point":
        return np.linalg.norm(p - np.asarray(g["point"], float), axis=1)
    if kind in ("circle", "cylinder", "line"):
        origin, axis = axis_of(kind, g)  # type: ignore[misc]
        rel = p - origin
        radial = np.linalg.norm(rel - np.outer(rel @ axis, axis), axis=1)
        return radial - (float(g["radius"]) if kind != "line" else 0.0)
    if kind == "cone":
        apex, axis = axis_of(kind, g)  # type: ignore[misc]
        rel = p - apex
        h = rel @ axis
        rho = np.linalg.norm(rel - np.outer(h, axis), axis=1)
        half = float(g["half_angle"])
        return rho * math.cos(half) - h * math.sin(half)
    raise ValueError(f"no distance for a {kind!r} feature")


def around_axis(kind: str, geometry: dict[str, Any], points: Any) -> np.ndarray | None:
    """Angle (rad, 0..2pi) of each point about the axis of a circle, cylinder or cone; about Z for a sphere."""
    g = geometry
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if kind == "sphere":
        origin, axis = np.asarray(g["center"], float), np.array([0.0, 0.0, 1.0])
    else:
        ax = axis_of(kind, g)
        if ax is None or kind == "line":
            return None
        origin, axis = ax
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    rel = p - origin
    return np.mod(np.arctan2(rel @ e2, rel @ e1), 2 * math.pi)
