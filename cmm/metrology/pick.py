"""Ray picks on a posed part mesh and nominal features suggested from a click.

``pick`` turns a browser click (ray origin + direction in machine coordinates)
into the hit point and outward face normal. ``suggest_feature`` grows the
surface region around the picked face and classifies it as a plane, sphere,
cylinder or cone with nominal parameters, so a click becomes a feature to
measure.

Nominal features are plain kind + params records (see NominalFeature):
    plane     point, normal (outward from the material)
    sphere    center, radius, bore (True = spherical cavity)
    cylinder  point (on the axis), direction (unit axis, sign arbitrary),
              radius, length, bore (True = hole, False = boss/shaft)
    cone      apex, direction (unit, from the apex into the cone),
              half_angle (rad), bore (True = conical hole/countersink)
    surface   point, normal: nothing simple fits (measure it against the mesh)
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from cmm.metrology.transform import apply_points, apply_vectors, as_pose, invert, unit

Array = NDArray[np.float64]

POINT_KEYS = ("point", "center", "apex")
VECTOR_KEYS = ("normal", "direction")
KINDS = ("plane", "sphere", "cylinder", "cone", "surface")


@dataclass
class NominalFeature:
    """A nominal geometric feature: kind plus parameters (see module docstring)."""

    kind: str
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"unknown feature kind '{self.kind}', expected one of {', '.join(KINDS)}")
        for key, value in self.params.items():
            if key in POINT_KEYS or key in VECTOR_KEYS:
                self.params[key] = np.asarray(value, dtype=np.float64).reshape(3)
            elif isinstance(value, (bool, np.bool_)):
                self.params[key] = bool(value)
            else:
                self.params[key] = float(value)

    def copy(self) -> "NominalFeature":
        return copy.deepcopy(self)

    def transformed(self, pose: ArrayLike) -> "NominalFeature":
        """The same feature moved by a 4x4 rigid transform."""
        T = as_pose(pose)
        params = dict(self.params)
        for key in POINT_KEYS:
            if key in params:
                params[key] = apply_points(T, params[key])
        for key in VECTOR_KEYS:
            if key in params:
                params[key] = apply_vectors(T, params[key])
        return NominalFeature(self.kind, params)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly form: {"kind": ..., **params} with lists for vectors."""
        out: dict[str, Any] = {"kind": self.kind}
        for key, value in self.params.items():
            out[key] = value.tolist() if isinstance(value, np.ndarray) else value
        return out


@dataclass(frozen=True)
class PickResult:
    """Nearest ray hit in machine coordinates."""

    point: Array  # (3,)
    normal: Array  # (3,) unit outward face normal
    face_id: int
    distance: float  # from the ray origin to the hit, mm


@dataclass(frozen=True)
class FeatureSuggestion:
    """A nominal feature proposed from a picked face, in machine coordinates."""

    feature: NominalFeature
    face_ids: NDArray[np.int64]  # faces of the region it was fitted to
    max_residual: float  # largest vertex distance to the fitted surface, mm
    rms_residual: float


def pick(mesh: trimesh.Trimesh, pose: ArrayLike | None, origin: ArrayLike, direction: ArrayLike) -> PickResult | None:
    """Nearest intersection of a ray (machine coordinates) with the posed mesh.

    ``direction`` need not be unit length. Hits behind the origin are ignored;
    returns None when the ray misses.
    """
    T = as_pose(pose)
    T_inv = invert(T)
    o = apply_points(T_inv, np.asarray(origin, dtype=np.float64).reshape(3))
    d = apply_vectors(T_inv, unit(direction, "ray direction"))
    _, _, tri = mesh.ray.intersects_location([o], [d], multiple_hits=True)
    if len(tri) == 0:
        return None
    # recompute each hit exactly from the face plane (float64, no ray-engine tolerance)
    normals = np.asarray(mesh.face_normals)[tri]
    v0 = np.asarray(mesh.triangles)[tri, 0]
    denom = normals @ d
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.einsum("ij,ij->i", v0 - o, normals) / denom
    t = np.where(np.isfinite(t) & (t >= -1e-9), t, np.inf)
    best = int(np.argmin(t))
    if not np.isfinite(t[best]):
        return None
    hit = o + t[best] * d
    tb, normal = float(t[best]), normals[best]
    exact = _exact_hit(mesh, int(tri[best]), o, d, tb)
    if exact is not None:  # a CAD part: where the ray meets the face's exact surface
        tb, normal = exact
        hit = o + tb * d
    return PickResult(
        point=apply_points(T, hit),
        normal=apply_vectors(T, normal),
        face_id=int(tri[best]),
        distance=tb,
    )


def _exact_hit(mesh: trimesh.Trimesh, triangle: int, o: Array, d: Array, t0: float) -> tuple[float, Array] | None:
    """Newton steps along the ray onto the exact surface of the CAD face the triangle belongs to (None: no CAD model,
    a free-form face, or the ray grazes it)."""
    from cmm.cad import cad_for_mesh
    from cmm.cad.surfaces import project

    cad = cad_for_mesh(mesh)
    if cad is None:
        return None
    face = cad.face_of(triangle)
    if not face.analytic:
        return None
    t = t0
    for _ in range(8):
        _, dist, n = project(face.kind, face.params, (o + t * d)[None, :])
        slope = float(n[0] @ d)
        if abs(slope) < 1e-3:
            return None
        step = float(dist[0]) / slope
        t -= step
        if abs(step) < 1e-13:
            break
    if abs(t - t0) > 4 * cad.deflection + 1e-6:
        return None
    _, _, n = project(face.kind, face.params, (o + t * d)[None, :])
    return t, face.sense * n[0]


def suggest_feature(
    mesh: trimesh.Trimesh,
    face_id: int,
    pose: ArrayLike | None = None,
    smooth_angle_deg: float = 20.0,
    tolerance: float | None = None,
) -> FeatureSuggestion:
    """Classify the surface around ``face_id`` and return its nominal feature.

    The region is grown over face adjacency across edges whose dihedral
    angle is below ``smooth_angle_deg`` (tessellation edges, not feature
    edges). Fits are tried from the simplest kind up (plane, cylinder, cone,
    sphere) on the region's vertices, which lie on the design surface in CAD
    exports; the first whose largest vertex residual is within ``tolerance``
    (default 1e-3 x region size, at least 1 um) wins. If the smooth region is
    a blend of several surfaces, each kind is instead grown from a small seed
    patch and the largest consistent region wins; that fallback is best
    effort (a seed patch that already straddles a tangent blend, e.g. the
    long strips of a capsule, gives a poor hypothesis) and the residuals in
    the result tell how good the suggestion is. Returned parameters are in
    machine coordinates when ``pose`` is given.
    """
    if not 0 <= face_id < len(mesh.faces):
        raise ValueError(f"face {face_id} does not exist (mesh has {len(mesh.faces)} faces)")
    exact = _cad_suggestion(mesh, face_id, pose)
    if exact is not None:
        return exact
    graph = _Adjacency(mesh)
    smooth = graph.grow([face_id], edge_ok=graph.angles < np.radians(smooth_angle_deg))
    tol = tolerance if tolerance is not None else max(1e-3 * _size(mesh, smooth), 1e-3)

    result = _classify(mesh, smooth, tol)
    if result is None:
        result = _classify_by_growth(mesh, graph, face_id, smooth, tol, np.radians(smooth_angle_deg))
    feature, faces, residuals = result
    T = as_pose(pose)
    return FeatureSuggestion(
        feature=feature.transformed(T),
        face_ids=np.sort(faces),
        max_residual=float(np.abs(residuals).max()),
        rms_residual=float(np.sqrt(np.mean(residuals**2))),
    )


def _cad_suggestion(mesh: trimesh.Trimesh, face_id: int, pose: ArrayLike | None) -> FeatureSuggestion | None:
    """A CAD part: the nominal is the picked face's exact surface (type, position, direction and size from the
    B-rep, over the faces of the same surface), not a fit to its triangles. None for a plain mesh."""
    from cmm.cad import cad_for_mesh

    cad = cad_for_mesh(mesh)
    if cad is None:
        return None
    face = cad.face_of(face_id)
    kind, params, tris = cad.nominal(face.index)
    if face.analytic:  # how far the triangulation's vertices are from the exact surface (the chords touch it)
        verts = mesh.vertices[np.unique(mesh.faces[tris])]
        residuals = cad.exact_distance(face.index, verts)
    else:
        residuals = np.zeros(1)
    return FeatureSuggestion(
        feature=NominalFeature(kind, params).transformed(as_pose(pose)),
        face_ids=np.sort(tris),
        max_residual=float(np.abs(residuals).max()),
        rms_residual=float(np.sqrt(np.mean(residuals**2))),
    )


# --- region growing -----------------------------------------------------------


class _Adjacency:
    """Face adjacency as CSR arrays with the dihedral angle per edge."""

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        pairs = np.asarray(mesh.face_adjacency, dtype=np.int64)
        angles = np.asarray(mesh.face_adjacency_angles, dtype=np.float64)
        both = np.concatenate([pairs, pairs[:, ::-1]])
        order = np.argsort(both[:, 0], kind="stable")
        self.src, self.dst = both[order, 0], both[order, 1]
        self.angles = np.concatenate([angles, angles])[order]
        self.start = np.searchsorted(self.src, np.arange(len(mesh.faces) + 1))
        self.n_faces = len(mesh.faces)

    def grow(
        self,
        seeds: list[int] | NDArray[np.int64],
        edge_ok: NDArray[np.bool_],
        face_ok: Callable[[NDArray[np.int64]], NDArray[np.bool_]] | None = None,
        max_faces: int | None = None,
    ) -> NDArray[np.int64]:
        """Breadth-first growth over allowed edges (and faces); returns face ids."""
        visited = np.zeros(self.n_faces, dtype=bool)
        frontier = np.unique(np.asarray(seeds, dtype=np.int64))
        visited[frontier] = True
        count = len(frontier)
        while len(frontier) and (max_faces is None or count < max_faces):
            lo, hi = self.start[frontier], self.start[frontier + 1]
            idx = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi)]) if len(lo) else np.empty(0, np.int64)
            idx = idx[edge_ok[idx]]
            cand = np.unique(self.dst[idx])
            cand = cand[~visited[cand]]
            if face_ok is not None and len(cand):
                cand = cand[face_ok(cand)]
            visited[cand] = True
            count += len(cand)
            frontier = cand
        return np.nonzero(visited)[0]


def _size(mesh: trimesh.Trimesh, faces: NDArray[np.int64]) -> float:
    v = mesh.vertices[np.unique(mesh.faces[faces])]
    return float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))


# --- surface fits on a face region ---------------------------------------------

_Fit = tuple[NominalFeature, Callable[[Array], Array]]  # feature, signed distance of points


def _classify(
    mesh: trimesh.Trimesh, faces: NDArray[np.int64], tol: float
) -> tuple[NominalFeature, NDArray[np.int64], Array] | None:
    """The simplest fitting kind for the whole region, or None."""
    for fitter in _FITTERS:
        fit = fitter(mesh, faces)
        if fit is None:
            continue
        residuals = fit[1](mesh.vertices[np.unique(mesh.faces[faces])])
        if np.abs(residuals).max() <= tol and _normals_agree(mesh, faces, fit[1], tol):
            return fit[0], faces, residuals
    return None


def _normals_agree(mesh: trimesh.Trimesh, faces, distance: Callable[[Array], Array], tol: float) -> bool:
    """Facet normals must match the fitted surface's normal (gradient of its distance).

    Vertices alone are ambiguous: the two rim circles of a cylinder or cone
    also lie on a sphere.
    """
    centres = np.asarray(mesh.triangles_center[faces], dtype=np.float64)
    h = max(tol, 1e-6)
    grad = np.stack(
        [distance(centres + h * e) - distance(centres - h * e) for e in np.eye(3)], axis=1
    ) / (2 * h)
    grad /= np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-300)
    cos = np.abs(np.einsum("ij,ij->i", grad, mesh.face_normals[faces]))
    return bool(cos.min() >= np.cos(_NORMAL_TOL))


def _classify_by_growth(mesh, graph: _Adjacency, seed: int, smooth, tol: float, smooth_angle: float):
    """Region made of several smooth surfaces: grow each kind from a seed patch."""
    edge_ok = graph.angles < smooth_angle
    in_smooth = np.zeros(len(mesh.faces), dtype=bool)
    in_smooth[smooth] = True
    patch = graph.grow([seed], edge_ok, face_ok=lambda f: in_smooth[f], max_faces=24)
    best = None
    for fitter in _FITTERS:
        fit = fitter(mesh, patch)
        if fit is None:
            continue
        region = patch
        for _ in range(2):  # grow, refit on the larger region, grow again
            distance = fit[1]
            face_ok = lambda f, distance=distance: (  # noqa: E731
                np.abs(distance(mesh.triangles[f].reshape(-1, 3))).reshape(-1, 3).max(axis=1) <= tol
            )
            region = graph.grow([seed], edge_ok, face_ok=face_ok)
            refit = fitter(mesh, region)
            if refit is None:
                break
            fit = refit
        residuals = fit[1](mesh.vertices[np.unique(mesh.faces[region])])
        if np.abs(residuals).max() > tol or not _normals_agree(mesh, region, fit[1], tol):
            continue
        area = float(mesh.area_faces[region].sum())
        if best is None or area > 1.05 * best[0]:  # simpler kinds win near-ties
            best = (area, fit[0], region, residuals)
    if best is None:
        n = _area_normal(mesh, smooth)
        centroid = np.average(mesh.triangles_center[smooth], axis=0, weights=mesh.area_faces[smooth])
        return NominalFeature("surface", {"point": centroid, "normal": n}), smooth, np.zeros(1)
    return best[1], best[2], best[3]


def _area_normal(mesh: trimesh.Trimesh, faces) -> Array:
    n = (mesh.face_normals[faces] * mesh.area_faces[faces, None]).sum(axis=0)
    length = np.linalg.norm(n)
    return n / length if length > 0 else np.asarray(mesh.face_normals[faces[0]], dtype=np.float64)


def _region(mesh: trimesh.Trimesh, faces):
    """Region vertices, face normals, face areas and face centres."""
    return (
        np.asarray(mesh.vertices[np.unique(mesh.faces[faces])], dtype=np.float64),
        np.asarray(mesh.face_normals[faces], dtype=np.float64),
        np.asarray(mesh.area_faces[faces], dtype=np.float64),
        np.asarray(mesh.triangles_center[faces], dtype=np.float64),
    )


def _canonical(direction: Array) -> Array:
    """Axis directions have no natural sign: make the largest component positive."""
    return direction if direction[np.argmax(np.abs(direction))] > 0 else -direction


def _normal_spread(normals: Array, areas: Array) -> tuple[Array, Array]:
    """Eigen-decomposition of the area-weighted normal scatter (ascending)."""
    w, v = np.linalg.eigh((normals * areas[:, None]).T @ normals / areas.sum())
    return w, v


def _fit_plane(mesh, faces) -> _Fit | None:
    v, normals, areas, _ = _region(mesh, faces)
    c = v.mean(axis=0)
    n = np.linalg.svd(v - c, full_matrices=False)[2][-1]
    if n @ (normals * areas[:, None]).sum(axis=0) < 0:
        n = -n
    return NominalFeature("plane", {"point": c, "normal": n}), lambda x: (x - c) @ n


def _fit_sphere(mesh, faces) -> _Fit | None:
    v, normals, areas, centres = _region(mesh, faces)
    if len(v) < 4 or _normal_spread(normals, areas)[0][1] < 1e-6:
        return None  # flat or cylindrical normals: not a sphere
    m = v.mean(axis=0)
    q = v - m
    # algebraic start |q|^2 = 2 c.q + k on centred data, then Gauss-Newton on |q - c| - r
    sol, *_ = np.linalg.lstsq(np.c_[2 * q, np.ones(len(q))], (q**2).sum(axis=1), rcond=None)
    c, r = sol[:3], np.sqrt(max(sol[3] + sol[:3] @ sol[:3], 0.0))
    for _ in range(5):
        d = q - c
        rho = np.linalg.norm(d, axis=1)
        J = np.c_[-d / rho[:, None], -np.ones(len(q))]
        step, *_ = np.linalg.lstsq(J, -(rho - r), rcond=None)
        c, r = c + step[:3], r + step[3]
    center = c + m
    bore = bool(np.sum(np.einsum("ij,ij->i", normals, centres - center) * areas) < 0)
    feature = NominalFeature("sphere", {"center": center, "radius": abs(r), "bore": bore})
    return feature, lambda x: np.linalg.norm(x - center, axis=1) - abs(r)


def _fit_cylinder(mesh, faces) -> _Fit | None:
    v, normals, areas, centres = _region(mesh, faces)
    w, vecs = _normal_spread(normals, areas)
    if len(v) < 5 or w[1] < 1e-6:
        return None  # all normals parallel: a plane
    axis = _canonical(vecs[:, 0])  # the direction all normals are perpendicular to
    # circle fit in the plane perpendicular to the axis
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    m = v.mean(axis=0)
    uv = np.c_[(v - m) @ e1, (v - m) @ e2]
    sol, *_ = np.linalg.lstsq(np.c_[2 * uv, np.ones(len(uv))], (uv**2).sum(axis=1), rcond=None)
    c2, r = sol[:2], np.sqrt(max(sol[2] + sol[:2] @ sol[:2], 0.0))
    for _ in range(5):
        d = uv - c2
        rho = np.linalg.norm(d, axis=1)
        J = np.c_[-d / rho[:, None], -np.ones(len(uv))]
        step, *_ = np.linalg.lstsq(J, -(rho - r), rcond=None)
        c2, r = c2 + step[:2], r + step[2]
    point = m + c2[0] * e1 + c2[1] * e2
    h = (v - point) @ axis
    point = point + 0.5 * (h.min() + h.max()) * axis  # middle of the region along the axis
    radial = centres - point - np.outer((centres - point) @ axis, axis)
    bore = bool(np.sum(np.einsum("ij,ij->i", normals, radial) * areas) < 0)
    feature = NominalFeature(
        "cylinder",
        {"point": point, "direction": axis, "radius": abs(r), "length": float(h.max() - h.min()), "bore": bore},
    )

    def distance(x: Array) -> Array:
        d = x - point
        return np.linalg.norm(d - np.outer(d @ axis, axis), axis=1) - abs(r)

    return feature, distance


def _fit_cone(mesh, faces) -> _Fit | None:
    v, normals, areas, centres = _region(mesh, faces)
    if len(v) < 6 or _normal_spread(normals, areas)[0][1] < 1e-6:
        return None
    # cone normals keep a constant angle to the axis: n.a = s for all faces
    sw = np.sqrt(areas)[:, None]
    a_s = np.linalg.svd(np.c_[normals, -np.ones(len(normals))] * sw, full_matrices=False)[2][-1]
    if np.linalg.norm(a_s[:3]) < 1e-9:
        return None
    axis, s = a_s[:3] / np.linalg.norm(a_s[:3]), a_s[3] / np.linalg.norm(a_s[:3])
    if abs(s) < 1e-6 or abs(s) >= 1.0:
        return None  # cylinder or plane
    # every facet plane passes through the apex: least-squares intersection of the planes
    A = (normals * areas[:, None]).T @ normals
    b = (normals * areas[:, None]).T @ np.einsum("ij,ij->i", normals, centres)
    if np.linalg.cond(A) > 1e10:
        return None
    apex = np.linalg.solve(A, b)
    if (centres - apex).mean(axis=0) @ axis < 0:
        axis, s = -axis, -s  # point from the apex into the cone
    # the facets form a pyramid (flatter than the cone by cos(pi/n)); the vertices lie on
    # the cone itself, so take the half angle from them
    d = v - apex
    h = d @ axis
    rho = np.linalg.norm(d - np.outer(h, axis), axis=1)
    far = h > 1e-6 * max(h.max(), 1e-300)
    half = float(np.mean(np.arctan2(rho[far], h[far]))) if far.any() else float(np.arcsin(abs(s)))
    radial = centres - apex - np.outer((centres - apex) @ axis, axis)
    bore = bool(np.sum(np.einsum("ij,ij->i", normals, radial) * areas) < 0)
    feature = NominalFeature("cone", {"apex": apex, "direction": axis, "half_angle": half, "bore": bore})

    def distance(x: Array) -> Array:
        d = x - apex
        h = d @ axis
        rho = np.linalg.norm(d - np.outer(h, axis), axis=1)
        return rho * np.cos(half) - h * np.sin(half)

    return feature, distance


# simplest first; sphere last because rim-only vertex sets of cylinders and cones fit a sphere too
_FITTERS = (_fit_plane, _fit_cylinder, _fit_cone, _fit_sphere)
# largest angle between a facet normal and the fitted surface normal at the facet centre
_NORMAL_TOL = np.radians(10.0)
