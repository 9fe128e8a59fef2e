"""Deviation colour map on the part surface: the measured points' deviations spread over the nominal mesh.

What a CALYPSO / PolyWorks user expects: every piece of the part's surface
near measured points takes the colour of the deviation there, interpolated
from the hits around it; surface farther than the map's reach from every hit
(``ColourScale.reach``) stays neutral grey. Colours come from the one
:class:`~cmm.metrology.colour_scale.ColourScale` the 3D scene and the report
share, so the same deviation has the same colour everywhere.

How the deviation at a surface point ``v`` (normal ``n``) is found:

* each hit (compensated point, part coordinates) is put on the nominal surface
  (its closest point ``p_i``, normal ``n_i``, signed deviation ``d_i``);
* only hits within ``reach`` of ``v`` (cKDTree) whose normal is within
  ``NORMAL_ANGLE`` of ``n`` count: a hit on the top face does not colour the
  side face next to it, nor the far wall of a bore (an approximation of
  "distance along the surface" that needs no geodesics);
* ``d(v)`` is their inverse-distance weighted mean (power 2, at most
  ``NEIGHBOURS`` hits); hits beyond the scale's max-deviation cut-off (another
  surface, or an unaligned part) take no part.

The nominal mesh is first turned into a display mesh: vertices split where
faces meet at a sharp edge (each vertex lies on one surface and has that
surface's normal), long faces subdivided (a box's 12 triangles cannot show a
map) and meshes bigger than the face budget decimated by vertex clustering.
The scene colours its vertices; the report's views colour its faces (the
deviation at each face centre), both through ``ColourScale.colours``.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from .colour_scale import ColourScale
from .mesh import closest_points

SHARP_ANGLE = 30.0  # degrees: faces meeting at a sharper edge are separate surfaces (vertices split there)
NORMAL_ANGLE = 60.0  # degrees: a hit colours surface whose normal is within this angle of its own
NEIGHBOURS = 10  # at most this many nearest hits enter a point's weighted mean
POWER = 2.0  # inverse-distance weighting exponent
SCENE_FACES = 24_000  # display mesh budget for the 3D scene (meshes up to it are not decimated)
REPORT_FACES = 30_000  # ... and for the report's views (z-buffered images)


# ------------------------------------------------------------------ display mesh


def _decimate(mesh: trimesh.Trimesh, faces: int) -> trimesh.Trimesh:
    """Vertex-clustering decimation to roughly ``faces`` faces (a grid of cells, one vertex per cell)."""
    cell = math.sqrt(2.0 * float(mesh.area) / max(faces, 1))
    key = np.floor(np.asarray(mesh.vertices) / cell).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    # the cell's vertex: the mean of the vertices in it
    sums = np.zeros((len(first), 3))
    np.add.at(sums, inverse, mesh.vertices)
    verts = sums / np.bincount(inverse, minlength=len(first))[:, None]
    f = inverse[np.asarray(mesh.faces)]
    keep = (f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])
    f = f[keep]
    _, unique_rows = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    return trimesh.Trimesh(verts, f[np.sort(unique_rows)], process=False)


def _surface_labels(mesh: trimesh.Trimesh, angle: float) -> NDArray[np.int64]:
    """A label per face: faces joined by edges flatter than ``angle`` share one."""
    adj = mesh.face_adjacency
    smooth = adj[mesh.face_adjacency_angles <= math.radians(angle)]
    return trimesh.graph.connected_component_labels(smooth, node_count=len(mesh.faces)).astype(np.int64)


def _bisect_long_edges(v: NDArray[np.float64], f: NDArray[np.int64], labels: NDArray[np.int64], max_edge: float,
                       max_faces: int, near: Any = None) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """Split every face whose longest edge exceeds ``max_edge`` in two at that edge's midpoint, until none does
    (or ``max_faces`` is reached, longest first); ``near(centres, radii, normals)`` limits it to the faces for
    which it gives a finite gap (a face lies within ``radii`` of its centre), smallest gap first.
    Unlike 1-to-4 subdivision this shortens slivers without multiplying their neighbours."""
    for _ in range(200):
        corners = v[f]  # F x 3 x 3
        lengths = np.linalg.norm(corners[:, [1, 2, 0]] - corners, axis=2)  # edge k: corner k -> k+1
        k = lengths.argmax(axis=1)
        longest = lengths[np.arange(len(f)), k]
        wanted = longest > max_edge
        priority = -longest  # longest first ...
        if near is not None and wanted.any():
            c = corners[wanted]
            centres = c.mean(axis=1)
            radius = np.linalg.norm(c - centres[:, None, :], axis=2).max(axis=1)
            normals = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
            normals /= np.maximum(np.linalg.norm(normals, axis=1), 1e-300)[:, None]
            gap = near(centres, radius, normals)
            priority = np.full(len(f), np.inf)
            priority[wanted] = gap  # ... or the nearest first
            wanted[wanted] = np.isfinite(gap)
        split = np.nonzero(wanted)[0]
        room = max_faces - len(f)
        if len(split) == 0 or room <= 0:
            break
        if len(split) > room:
            split = split[np.argsort(priority[split], kind="stable")[:room]]
        ks = k[split]
        fs = f[split]
        a, b, c = fs[np.arange(len(fs)), ks], fs[np.arange(len(fs)), (ks + 1) % 3], fs[np.arange(len(fs)), (ks + 2) % 3]
        edge = np.sort(np.column_stack([a, b]), axis=1)
        unique_edges, which = np.unique(edge, axis=0, return_inverse=True)  # a shared edge gets one midpoint
        m = len(v) + which.ravel()
        v = np.concatenate([v, v[unique_edges].mean(axis=1)])
        keep = np.ones(len(f), bool)
        keep[split] = False
        f = np.concatenate([f[keep], np.column_stack([a, m, c]), np.column_stack([m, b, c])])
        labels = np.concatenate([labels[keep], labels[split], labels[split]])
    return v, f, labels


def display_mesh(mesh: trimesh.Trimesh, faces: int = SCENE_FACES, sharp_angle: float = SHARP_ANGLE) -> trimesh.Trimesh:
    """The mesh to paint (part coordinates): vertices split at sharp edges, decimated to about half of ``faces``
    when it has more (cached). :func:`deviation_map` refines it where the hits are."""
    key = (faces, sharp_angle)
    version, cached = _DISPLAY_CACHE.get(mesh, (None, {}))
    if version != hash(mesh):  # trimesh hashes the geometry: an edited mesh is built again
        cached = {}
        _DISPLAY_CACHE[mesh] = (hash(mesh), cached)
    if key in cached:
        return cached[key]
    src = mesh if len(mesh.faces) <= faces else _decimate(mesh, faces // 2)  # half: room to refine
    labels = _surface_labels(src, sharp_angle)
    v, f = np.asarray(src.vertices, float), np.asarray(src.faces, np.int64)
    # one vertex per (position, surface): a vertex on a sharp edge belongs to each surface meeting there
    corner_pos = np.round(v[f.ravel()] / (1e-6 * max(float(np.ptp(v, axis=0).max()), 1e-9))).astype(np.int64)
    corner_key = np.column_stack([corner_pos, np.repeat(labels, 3)])
    _, first, inverse = np.unique(corner_key, axis=0, return_index=True, return_inverse=True)
    out = trimesh.Trimesh(v[f.ravel()][first], inverse.ravel().reshape(-1, 3), process=False)
    out.metadata["surface"] = labels
    cached[key] = out
    return out


_DISPLAY_CACHE: "weakref.WeakKeyDictionary[trimesh.Trimesh, tuple[Any, dict[Any, trimesh.Trimesh]]]" = weakref.WeakKeyDictionary()


# ------------------------------------------------------------------ interpolation


def interpolate(at: ArrayLike, at_normals: ArrayLike, sources: ArrayLike, source_normals: ArrayLike,
                values: ArrayLike, reach: float, *, normal_angle: float = NORMAL_ANGLE, power: float = POWER,
                neighbours: int = NEIGHBOURS) -> NDArray[np.float64]:
    """Inverse-distance weighted ``values`` of the sources at each point of ``at``; NaN where no source
    within ``reach`` has a normal within ``normal_angle`` of the point's normal."""
    at = np.asarray(at, float).reshape(-1, 3)
    out = np.full(len(at), np.nan)
    src = np.asarray(sources, float).reshape(-1, 3)
    vals = np.asarray(values, float).ravel()
    ok = np.isfinite(vals)
    src, vals, src_n = src[ok], vals[ok], np.asarray(source_normals, float).reshape(-1, 3)[ok]
    if len(src) == 0 or len(at) == 0:
        return out
    k = min(neighbours, len(src))
    d, idx = cKDTree(src).query(at, k=k, distance_upper_bound=reach)
    d, idx = d.reshape(len(at), k), idx.reshape(len(at), k)
    valid = np.isfinite(d)
    idx = np.where(valid, idx, 0)
    cos = np.einsum("ij,ikj->ik", np.asarray(at_normals, float).reshape(-1, 3), src_n[idx])
    valid &= cos >= math.cos(math.radians(normal_angle))
    w = np.where(valid, 1.0 / np.maximum(np.where(valid, d, 1.0), 1e-6 * reach) ** power, 0.0)
    total = w.sum(axis=1)
    have = total > 0
    out[have] = (w[have] * vals[idx[have]]).sum(axis=1) / total[have]
    return out


@dataclass
class DeviationMap:
    """The colour map of one set of hits on one part: display mesh (part mm) and deviations per vertex and face."""

    mesh: trimesh.Trimesh
    scale: ColourScale
    sources: NDArray[np.float64]  # the hits used, on the nominal surface (part mm)
    source_normals: NDArray[np.float64]  # the surface's outward normal there
    values: NDArray[np.float64]  # their deviations (mm)

    @property
    def hits_used(self) -> int:
        return len(self.values)

    @cached_property
    def vertex_deviations(self) -> NDArray[np.float64]:
        return self.deviation_at(self.mesh.vertices, self.mesh.vertex_normals)

    @cached_property
    def face_deviations(self) -> NDArray[np.float64]:
        """The deviation at each face's centre."""
        return self.deviation_at(self.mesh.triangles_center, self.mesh.face_normals)

    def deviation_at(self, points: ArrayLike, normals: ArrayLike) -> NDArray[np.float64]:
        """The map's deviation at any surface points (part mm) with their normals (NaN: grey)."""
        return interpolate(points, normals, self.sources, self.source_normals, self.values, self.scale.reach)

    @property
    def vertex_colours(self) -> NDArray[np.uint8]:
        return self.scale.colours(self.vertex_deviations)

    @property
    def face_colours(self) -> NDArray[np.uint8]:
        return self.scale.colours(self.face_deviations)

    @property
    def coverage(self) -> float:
        """Fraction of the surface area that is coloured (not grey)."""
        area = self.mesh.area_faces
        coloured = self.scale.bands(self.face_deviations) != 3
        return float(area[coloured].sum() / max(area.sum(), 1e-300))

    def coloured_mesh(self) -> trimesh.Trimesh:
        """The display mesh with RGBA vertex colours for a glTF (GLB) viewer: the scale's sRGB colours stored
        as the linear values glTF's COLOR_0 holds, so the viewer shows the scale's colours (see ``to_srgb``)."""
        m = trimesh.Trimesh(self.mesh.vertices, self.mesh.faces, process=False)
        rgba = np.column_stack([to_linear(self.vertex_colours), np.full(len(m.vertices), 255, np.uint8)])
        m.visual = trimesh.visual.ColorVisuals(m, vertex_colors=rgba)
        return m


def to_linear(srgb: ArrayLike) -> NDArray[np.uint8]:
    """sRGB 8-bit colours -> linear 8-bit (glTF vertex colours are linear; three.js turns them back to sRGB)."""
    c = np.asarray(srgb, float) / 255.0
    lin = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return np.round(lin * 255.0).astype(np.uint8)


def to_srgb(linear: ArrayLike) -> NDArray[np.uint8]:
    """Linear 8-bit colours -> sRGB 8-bit (what a glTF viewer shows for a vertex colour)."""
    c = np.asarray(linear, float) / 255.0
    s = np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055)
    return np.round(s * 255.0).astype(np.uint8)


def hits_on_surface(mesh: trimesh.Trimesh, points_part: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Closest nominal surface points and outward normals (part coordinates) of measured points."""
    cp = closest_points(mesh, np.asarray(points_part, float).reshape(-1, 3))
    return cp.points, cp.normals


def deviation_map(mesh: trimesh.Trimesh, points_part: ArrayLike, deviations: ArrayLike, scale: ColourScale, *,
                  faces: int = SCENE_FACES) -> DeviationMap:
    """The colour map of hits (``points_part``: compensated points in part coordinates, ``deviations``: their
    signed deviations in mm, NaN = unknown) on the part ``mesh``."""
    disp = display_mesh(mesh, faces)
    pts = np.asarray(points_part, float).reshape(-1, 3)
    dev = np.asarray(deviations, float).ravel()
    if len(pts) != len(dev):
        raise ValueError(f"{len(pts)} points but {len(dev)} deviations")
    keep = np.isfinite(dev) & (np.abs(np.nan_to_num(dev, nan=np.inf)) <= scale.max_distance)
    if not keep.any():
        return DeviationMap(disp, scale, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    src, src_n = hits_on_surface(mesh, pts[keep])
    return DeviationMap(refine_near(disp, src, src_n, scale.reach, faces), scale, src, src_n, dev[keep])


def refine_near(disp: trimesh.Trimesh, sources: NDArray[np.float64], source_normals: NDArray[np.float64],
                reach: float, faces: int) -> trimesh.Trimesh:
    """The display mesh with its faces within ``reach`` of a hit bisected to edges of about reach / 3 (at most
    ``faces`` faces in all): vertex colours need vertices near every hit, whatever the CAD triangulation
    (a fan of 100 mm slivers around a bore has none), while surface far from the hits stays coarse and grey."""
    edge = max(reach / 3.0, math.sqrt(2.0 * float(disp.area) / max(faces, 1)))
    tree = cKDTree(sources)
    k = min(NEIGHBOURS, len(sources))
    cos_min = math.cos(math.radians(NORMAL_ANGLE))

    def near(centres: NDArray[np.float64], radii: NDArray[np.float64], normals: NDArray[np.float64]) -> NDArray[np.float64]:
        # a face some hit can colour (a hit within reach of it, on a surface facing the same way): how far the
        # face may be from that hit (nearest first when the budget runs out); inf for the others
        d, i = tree.query(centres, k=k)
        d, i = d.reshape(len(centres), k), i.reshape(len(centres), k)
        facing = np.einsum("ij,ikj->ik", normals, source_normals[i]) >= cos_min
        gap = np.where(facing, d - radii[:, None], np.inf).min(axis=1)
        return np.where(gap < reach, np.maximum(gap, 0.0), np.inf)

    v, f, labels = _bisect_long_edges(np.asarray(disp.vertices, float), np.asarray(disp.faces, np.int64),
                                      np.asarray(disp.metadata["surface"]), edge, faces, near)
    if len(f) == len(disp.faces):
        return disp
    out = trimesh.Trimesh(v, f, process=False)
    out.metadata["surface"] = labels
    return out


# ------------------------------------------------------------------ raster views (the report)


def rasterize(mesh: trimesh.Trimesh, to_pixels: Any, towards: ArrayLike, width: int, height: int,
              max_candidates: int = 2_000_000) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """Z-buffer of the faces turned to the viewer: (pixel index y * width + x, face, depth) of each covered
    pixel. ``to_pixels`` maps n x 3 part mm to n x 2 pixel coordinates (x right, y down) of an orthographic
    view along ``towards`` (unit vector to the viewer). Vectorised scanlines: every (face, pixel row) pair
    gets the span of pixel centres inside the triangle, then every pixel of the spans its depth (in chunks of
    about ``max_candidates`` pixels); long thin faces cost their pixels, not their bounding box."""
    towards = np.asarray(towards, float)
    shown = np.nonzero(mesh.face_normals @ towards > 1e-9)[0]
    xy = np.asarray(to_pixels(mesh.vertices), float)
    depth_v = np.asarray(mesh.vertices) @ towards
    tri = xy[np.asarray(mesh.faces)[shown]]  # n x 3 x 2
    tri_d = depth_v[np.asarray(mesh.faces)[shown]]
    a, b, c3 = tri[:, 0], tri[:, 1], tri[:, 2]
    area = (b[:, 0] - a[:, 0]) * (c3[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c3[:, 0] - a[:, 0])
    ok = np.abs(area) > 1e-9  # faces seen edge-on cover no pixel centre
    shown, tri, tri_d, area = shown[ok], tri[ok], tri_d[ok], area[ok]
    a, b, c3 = tri[:, 0], tri[:, 1], tri[:, 2]
    # the depth as a linear function of the pixel position, per face: depth = A x + B y + C
    l1x, l1y = (c3[:, 1] - a[:, 1]) / area, -(c3[:, 0] - a[:, 0]) / area
    l2x, l2y = -(b[:, 1] - a[:, 1]) / area, (b[:, 0] - a[:, 0]) / area
    d0, d1, d2 = tri_d[:, 0], tri_d[:, 1] - tri_d[:, 0], tri_d[:, 2] - tri_d[:, 0]
    dA, dB = d1 * l1x + d2 * l2x, d1 * l1y + d2 * l2y
    dC = d0 - dA * a[:, 0] - dB * a[:, 1]
    # rows whose centre (y + 0.5) lies within each face
    y0 = np.clip(np.ceil(tri[:, :, 1].min(axis=1) - 0.5), 0, height).astype(np.int64)
    y1 = np.clip(np.floor(tri[:, :, 1].max(axis=1) - 0.5), -1, height - 1).astype(np.int64)
    rows = np.maximum(y1 - y0 + 1, 0)
    f_of = np.repeat(np.arange(len(shown)), rows)
    py = y0[f_of] + np.arange(int(rows.sum())) - np.repeat(np.cumsum(rows) - rows, rows)
    cy = py + 0.5
    xl, xr = np.full(len(py), np.inf), np.full(len(py), -np.inf)
    for i, j in ((0, 1), (1, 2), (2, 0)):  # where the row crosses each edge
        p, q = tri[f_of, i], tri[f_of, j]
        dy = q[:, 1] - p[:, 1]
        t = (cy - p[:, 1]) / np.where(dy == 0, np.inf, dy)
        cross = (dy != 0) & (t >= -1e-9) & (t <= 1 + 1e-9)
        x = p[:, 0] + t * (q[:, 0] - p[:, 0])
        xl = np.where(cross, np.minimum(xl, x), xl)
        xr = np.where(cross, np.maximum(xr, x), xr)
    x0 = np.clip(np.ceil(xl - 0.5), 0, width).astype(np.int64)
    x1 = np.clip(np.floor(xr - 0.5), -1, width - 1).astype(np.int64)
    counts = np.maximum(x1 - x0 + 1, 0)
    pid_all, face_all, depth_all = [], [], []
    cum = np.cumsum(counts)
    start = 0
    while start < len(counts):
        done = int(cum[start - 1]) if start else 0
        stop = max(int(np.searchsorted(cum, done + max_candidates, side="right")), start + 1)
        sl = slice(start, stop)
        start = stop
        c = counts[sl]
        if not c.sum():
            continue
        span = np.repeat(np.arange(sl.start, sl.stop), c)
        px = x0[span] + np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        f = f_of[span]
        pid_all.append(py[span] * width + px)
        face_all.append(shown[f])
        depth_all.append(dA[f] * (px + 0.5) + dB[f] * cy[span] + dC[f])
    if not pid_all:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    pid, face, depth = np.concatenate(pid_all), np.concatenate(face_all), np.concatenate(depth_all)
    zbuf = np.full(width * height, -np.inf)
    np.maximum.at(zbuf, pid, depth)  # the nearest depth per pixel
    front = depth >= zbuf[pid]
    pid, face, depth = pid[front], face[front], depth[front]
    first = np.unique(pid, return_index=True)[1]  # one face per pixel where two touch at the same depth
    return pid[first], face[first], depth[first]


def png(rgba: NDArray[np.uint8]) -> bytes:
    """A PNG file of an h x w x 4 RGBA image (zlib from the standard library; no imaging dependency)."""
    import struct
    import zlib

    h, w = rgba.shape[:2]
    raw = np.concatenate([np.zeros((h, 1), np.uint8), np.ascontiguousarray(rgba, np.uint8).reshape(h, w * 4)], axis=1)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw.tobytes(), 9)) + chunk(b"IEND", b""))


def view_image(dmap: DeviationMap, to_pixels: Any, from_pixels: Any, towards: ArrayLike, width: int,
               height: int) -> NDArray[np.uint8]:
    """The colour map seen along ``towards`` as an RGBA image (transparent off the part): each pixel in the
    scale's colour of the deviation interpolated at the surface point it shows (crisp band borders whatever
    the triangulation). ``from_pixels(xy, depth)`` maps pixel coordinates and depth back to part mm."""
    pid, face, depth = rasterize(dmap.mesh, to_pixels, towards, width, height)
    img = np.zeros((height * width, 4), np.uint8)
    if len(pid):
        xy = np.column_stack([pid % width + 0.5, pid // width + 0.5])
        points = from_pixels(xy, depth)
        dev = dmap.deviation_at(points, dmap.mesh.face_normals[face])
        img[pid, :3] = dmap.scale.colours(dev)
        img[pid, 3] = 255
    return img.reshape(height, width, 4)
