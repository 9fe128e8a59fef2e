"""How a fitted feature is drawn in the 3-D view: thin outlines at the measured extent and faint patches.

A fitted feature must not hide the part: a plane is a translucent patch over the hull of its hits (the
measured extent) with its outline; circles, cylinders and cones are wireframes (rings where the hits are,
generator lines between them) over a faint surface that takes the clicks; a sphere is translucent with its
equator and meridian drawn. The alternative a nominal-aware fit found (a better minimum far from the nominal,
:mod:`cmm.metrology.fit_ls`) is drawn as a dashed ghost of the same kind beside it.

Everything here is machine millimetres and pure (numpy, trimesh): :mod:`cmm.ui.scene` turns a
:class:`Drawing` into viser nodes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh

RING_SECTIONS = 96  # segments of a drawn circle
GENERATORS = 8  # lines along a cylinder or cone between its end rings
PATCH_OPACITY = 0.25  # a plane's patch, a sphere
SURFACE_OPACITY = 0.12  # the faint surface under a wireframe (it takes the clicks)
DASH = 0.6  # of each dashed segment drawn (the rest is the gap)


@dataclass
class Drawing:
    """What the view draws for one feature: ``lines`` (N, 2, 3) segments and an optional translucent
    ``patch`` mesh with its opacity (machine mm)."""

    lines: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    patch: trimesh.Trimesh | None = None
    opacity: float = SURFACE_OPACITY


def _unit(v: Any) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to ``n`` and to each other."""
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = _unit(np.cross(n, a))
    return u, np.cross(n, u)


def _ring(centre: np.ndarray, normal: np.ndarray, radius: float, sections: int = RING_SECTIONS) -> np.ndarray:
    u, v = _basis(_unit(normal))
    t = np.linspace(0.0, 2 * math.pi, sections + 1)
    return centre + radius * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)


def _segments(polyline: np.ndarray) -> np.ndarray:
    return np.stack([polyline[:-1], polyline[1:]], axis=1)


def dashed(lines: np.ndarray, dash: float = DASH) -> np.ndarray:
    """Every segment cut to its first ``dash`` part: a long line becomes many short ones when drawn finely."""
    out = []
    for a, b in np.asarray(lines, float).reshape(-1, 2, 3):
        length = float(np.linalg.norm(b - a))
        pieces = max(1, int(length / 1.5))  # a dash every 1.5 mm
        ts = np.linspace(0.0, 1.0, pieces + 1)
        for t0, t1 in zip(ts[:-1], ts[1:]):
            out.append([a + (b - a) * t0, a + (b - a) * (t0 + (t1 - t0) * dash)])
    return np.array(out, float).reshape(-1, 2, 3)


def _extent(points: np.ndarray, origin: np.ndarray, direction: np.ndarray, least: float = 2.0) -> tuple[float, float]:
    """The hits' span along ``direction`` from ``origin`` (at least ``least`` mm long)."""
    if len(points) == 0:
        return -least / 2, least / 2
    t = (np.asarray(points) - origin) @ direction
    lo, hi = float(t.min()), float(t.max())
    if hi - lo < least:
        mid = (lo + hi) / 2
        lo, hi = mid - least / 2, mid + least / 2
    return lo, hi


def _hull_2d(xy: np.ndarray) -> np.ndarray:
    """Indices of the convex hull of 2-D points, counter-clockwise (Andrew's monotone chain)."""
    order = np.lexsort((xy[:, 1], xy[:, 0]))
    pts = [int(i) for i in order]

    def half(seq: list[int]) -> list[int]:
        out: list[int] = []
        for i in seq:
            while len(out) >= 2:
                o, a = xy[out[-2]], xy[out[-1]]
                if (a[0] - o[0]) * (xy[i][1] - o[1]) - (a[1] - o[1]) * (xy[i][0] - o[0]) > 1e-12:
                    break
                out.pop()
            out.append(i)
        return out
    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1], int)


def plane_drawing(point: Any, normal: Any, hits: np.ndarray, margin: float = 1.0) -> Drawing:
    """A translucent patch over the hull of the hits on the plane (``margin`` mm beyond them), outlined."""
    n = _unit(normal)
    c = np.asarray(point, float)
    u, v = _basis(n)
    rel = hits - c if len(hits) else np.zeros((1, 3))
    xy = np.c_[rel @ u, rel @ v]
    hull = _hull_2d(xy) if len(xy) >= 3 else np.array([], int)
    if len(hull) < 3:  # fewer than three hits, or all on a line: a square around them
        mid = xy.mean(axis=0)
        half = max(float(np.max(np.abs(xy - mid))) if len(xy) else 0.0, 2.0)
        poly = mid + np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    else:
        poly = xy[hull]
        centre = poly.mean(axis=0)
        out = poly - centre
        poly = poly + margin * out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-9)
    corners = c + poly[:, :1] * u + poly[:, 1:] * v
    faces = [[0, i, i + 1] for i in range(1, len(corners) - 1)]
    patch = trimesh.Trimesh(corners, faces, process=False)
    return Drawing(_segments(np.vstack([corners, corners[:1]])), patch, PATCH_OPACITY)


def circle_drawing(center: Any, normal: Any, radius: float) -> Drawing:
    ring = _ring(np.asarray(center, float), normal, float(radius))
    disc = trimesh.creation.annulus(r_min=max(radius - 0.3, 0.0), r_max=radius + 0.3, height=0.05, sections=64)
    T = trimesh.geometry.align_vectors([0.0, 0.0, 1.0], _unit(normal))
    T[:3, 3] = center
    disc.apply_transform(T)
    return Drawing(_segments(ring), disc)


def cylinder_drawing(point: Any, direction: Any, radius: float, hits: np.ndarray) -> Drawing:
    """Rings at both ends of the hits' span along the axis, generator lines between them, the axis line."""
    d = _unit(direction)
    p = np.asarray(point, float)
    lo, hi = _extent(hits, p, d)
    a, b = p + lo * d, p + hi * d
    ra, rb = _ring(a, d, radius), _ring(b, d, radius)
    step = RING_SECTIONS // GENERATORS
    gens = np.stack([ra[:-1:step], rb[:-1:step]], axis=1)
    lines = np.concatenate([_segments(ra), _segments(rb), gens, dashed([[a, b]])])
    surface = trimesh.creation.cylinder(radius=float(radius), segment=[a, b], sections=48)
    return Drawing(lines, surface)


def cone_drawing(apex: Any, direction: Any, half_angle: float, hits: np.ndarray) -> Drawing:
    """Rings where the hits' span along the axis starts and ends, generator lines between them."""
    d = _unit(direction)
    q = np.asarray(apex, float)
    lo, hi = _extent(hits, q, d)
    lo = max(lo, 0.0)
    hi = max(hi, lo + 2.0)
    tan = math.tan(float(half_angle))
    ra, rb = _ring(q + lo * d, d, lo * tan), _ring(q + hi * d, d, hi * tan)
    step = RING_SECTIONS // GENERATORS
    gens = np.stack([ra[:-1:step], rb[:-1:step]], axis=1)
    lines = np.concatenate([_segments(rb), gens] + ([_segments(ra)] if lo * tan > 1e-6 else []))
    # the frustum surface: rings joined by quads (two triangles each)
    n = RING_SECTIONS
    verts = np.vstack([ra[:-1], rb[:-1]])
    faces = [[i, (i + 1) % n, n + i] for i in range(n)] + [[(i + 1) % n, n + (i + 1) % n, n + i] for i in range(n)]
    return Drawing(lines, trimesh.Trimesh(verts, faces, process=False))


def sphere_drawing(center: Any, radius: float) -> Drawing:
    c = np.asarray(center, float)
    rings = [_ring(c, axis, float(radius)) for axis in ((0, 0, 1), (1, 0, 0), (0, 1, 0))]
    m = trimesh.creation.icosphere(subdivisions=3, radius=float(radius))
    m.apply_translation(c)
    return Drawing(np.concatenate([_segments(r) for r in rings]), m, PATCH_OPACITY)


def feature_drawing(kind: str, geometry: dict[str, Any], hits: Any) -> Drawing | None:
    """The drawing of a fitted ``kind`` with ``geometry`` (a fit's ``geometry()``) measured by ``hits`` (its
    points, machine mm: they give the measured extent); None for a kind that is not drawn."""
    g = {k: np.asarray(v, float) if isinstance(v, list) else v for k, v in geometry.items()}
    pts = np.asarray(hits, float).reshape(-1, 3)
    if kind == "plane":
        return plane_drawing(g["point"], g["normal"], pts)
    if kind == "circle":
        return circle_drawing(g["center"], g["normal"], float(g["radius"]))
    if kind == "cylinder":
        return cylinder_drawing(g["point"], g["direction"], float(g["radius"]), pts)
    if kind == "cone":
        return cone_drawing(g["apex"], g["direction"], float(g["half_angle"]), pts)
    if kind == "sphere":
        return sphere_drawing(g["center"], float(g["radius"]))
    if kind == "line":
        d = _unit(g["direction"])
        lo, hi = _extent(pts, g["point"], d)
        return Drawing(np.array([[g["point"] + lo * d, g["point"] + hi * d]]))
    if kind == "point":
        m = trimesh.creation.icosphere(subdivisions=2, radius=0.5)
        m.apply_translation(g["point"])
        return Drawing(patch=m, opacity=0.8)
    return None


def ghost_drawing(kind: str, alternative: dict[str, Any], hits: Any) -> np.ndarray:
    """The dashed outline of a fit's alternative (the better minimum far from the nominal): segments, mm."""
    drawing = feature_drawing(kind, alternative, hits)
    return np.zeros((0, 2, 3)) if drawing is None else dashed(drawing.lines)
