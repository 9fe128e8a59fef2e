"""Part meshes: loading and signed deviation of measured points (float64).

Sign convention (used everywhere in the station, see SIGN_CONVENTION):
    deviation > 0  the measured point lies OUTSIDE the nominal material
                   (the real part has excess material there),
    deviation < 0  the point lies INSIDE the nominal material (material missing).
This is the opposite of ``trimesh.proximity.signed_distance`` (positive inside).

Closest points come from libigl's AABB tree (``igl.AABB``, float64; built once
per mesh and cached), the sign from the angle-weighted pseudo-normal at the
closest surface point (Baerentzen & Aanaes 2005): the face normal inside a
face, the sum of the two face normals on an edge and the angle-weighted vertex
normal at a vertex.  That is exact for any consistently wound closed mesh, needs
no ray-casting containment test, and is what ``igl.signed_distance`` with
pseudo-normal signs computes; we keep the tree between calls instead of
rebuilding it (and its normals) on every call, which matters for chunked runs
and ICP.  Points are processed in chunks of CHUNK so 1e7 points need bounded
working memory, with an optional progress callback ``progress(done, total)``.
"""

from __future__ import annotations

import atexit
import warnings
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import igl
import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from cmm.cad import cad_for_mesh
from cmm.metrology.transform import apply_points, apply_vectors, as_pose, invert

MESH_EXTENSIONS: tuple[str, ...] = (".stl", ".obj", ".ply", ".off", ".glb", ".gltf", ".3mf")
# CAD with exact surfaces (cmm.cad, OpenCASCADE): its triangulation carries the model in metadata["cad"]
SUPPORTED_EXTENSIONS: tuple[str, ...] = (".step", ".stp", ".iges", ".igs") + MESH_EXTENSIONS

SIGN_CONVENTION = (
    "deviation = signed distance to the nominal surface in mm: "
    "+ = point outside the nominal material (excess material), "
    "- = point inside the nominal material (missing material)"
)

# barycentric coordinate below which the closest point counts as on an edge/vertex
_BARY_EPS = 1e-7
# points per libigl query: bounds the working memory (~200 bytes per point) of huge runs
CHUNK = 250_000

Progress = Callable[[int, int], None]


class MeshError(ValueError):
    """A part mesh cannot be used; the message is meant for the operator."""


class MeshWarning(UserWarning):
    """The mesh loaded but results may be unreliable (e.g. not watertight)."""


def load_part(path: str | Path) -> trimesh.Trimesh:
    """Load a part mesh as one float64 triangle mesh in the file's units (mm).

    Supports STL (ascii and binary), OBJ, PLY, OFF, GLB/GLTF and 3MF; scenes
    are flattened into one mesh with their node transforms applied.
    ``mesh.metadata["watertight"]`` tells whether the mesh is closed; when it
    is not, a MeshWarning is issued because signs near holes are unreliable.
    Raises MeshError for an unsupported extension, a missing, broken or empty
    file and for NaN/infinite vertex coordinates.
    """
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in SUPPORTED_EXTENSIONS:
        raise MeshError(
            f"cannot read '{p.name}': unsupported mesh format '{ext or '(no extension)'}'; "
            f"supported formats are {', '.join(SUPPORTED_EXTENSIONS)}"
        )
    if not p.is_file():
        raise MeshError(f"mesh file '{p}' does not exist")
    if ext not in MESH_EXTENSIONS:
        return _load_cad(p)
    try:
        loaded = trimesh.load(str(p), file_type=ext[1:], force="mesh", process=False)
    except Exception as exc:  # parsers raise anything from KeyError to struct.error
        raise MeshError(f"mesh file '{p.name}' is broken or not a valid {ext[1:].upper()} file ({exc})") from exc
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise MeshError(
            f"mesh file '{p.name}' contains no triangles (empty, truncated or not a {ext[1:].upper()} file)"
        )
    vertices = np.asarray(loaded.vertices, dtype=np.float64)
    if not np.all(np.isfinite(vertices)):
        raise MeshError(f"mesh file '{p.name}' has vertices with NaN or infinite coordinates")
    mesh = trimesh.Trimesh(vertices=vertices, faces=np.asarray(loaded.faces), process=True, validate=False)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0:
        raise MeshError(f"mesh file '{p.name}' contains only degenerate (zero-area) triangles")
    mesh.metadata["file_name"] = p.name
    mesh.metadata["watertight"] = bool(mesh.is_watertight)
    if not mesh.metadata["watertight"]:
        warnings.warn(
            f"mesh '{p.name}' is not watertight (open edges): the sign of deviations "
            "near the holes may be wrong",
            MeshWarning,
            stacklevel=2,
        )
    return mesh


def _load_cad(p: Path) -> trimesh.Trimesh:
    """A STEP or IGES part: its triangulation, with the exact B-rep model in ``metadata["cad"]``."""
    from cmm.cad import CadError, read_cad

    try:
        model = read_cad(p)
    except CadError as exc:
        raise MeshError(str(exc)) from None
    except Exception as exc:  # noqa: BLE001 - OpenCASCADE failures come as many types: one sentence
        raise MeshError(f"'{p.name}' could not be read as {p.suffix[1:].upper()} ({type(exc).__name__}: {exc})") from None
    mesh = model.mesh()
    if not mesh.metadata["watertight"]:
        warnings.warn(f"CAD part '{p.name}' is not a closed solid: the sign of deviations near its open edges may "
                      "be wrong", MeshWarning, stacklevel=3)
    return mesh


@dataclass(frozen=True)
class ClosestPoints:
    """Closest surface points in the mesh's own coordinates."""

    points: NDArray[np.float64]  # (n, 3)
    distances: NDArray[np.float64]  # (n,) unsigned
    face_ids: NDArray[np.int64]  # (n,)
    normals: NDArray[np.float64]  # (n, 3) unit outward pseudo-normal at the closest point


@dataclass(frozen=True)
class DeviationResult:
    """Signed deviation of points to a posed mesh; all arrays in machine coordinates."""

    deviations: NDArray[np.float64]  # (n,) signed, see SIGN_CONVENTION
    closest_points: NDArray[np.float64]  # (n, 3)
    face_ids: NDArray[np.int64]  # (n,)
    normals: NDArray[np.float64]  # (n, 3) outward unit normal at the closest point
    watertight: bool = True
    sign_convention: str = field(default=SIGN_CONVENTION)

    @property
    def min(self) -> float:
        return float(self.deviations.min())

    @property
    def max(self) -> float:
        return float(self.deviations.max())

    @property
    def mean(self) -> float:
        return float(self.deviations.mean())

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.deviations**2)))

    def summary(self) -> dict[str, float | int]:
        return {"n": int(self.deviations.size), "min": self.min, "max": self.max, "mean": self.mean, "rms": self.rms}


class SurfaceIndex:
    """libigl AABB tree of one mesh for repeated closest-point queries (deviation, ICP).

    ``surface_index(mesh)`` returns a cached one; the mesh must not be edited
    while an index is in use (the cache notices edits through the mesh's hash).
    """

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        self.vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
        self.faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
        self.tree = igl.AABB()
        self.tree.init(self.vertices, self.faces)
        self._edge_sums: NDArray[np.float64] | None = None
        self._vertex_sums: NDArray[np.float64] | None = None

    # The pseudo-normals' sums over a mesh's edges and vertices, made once per mesh: summing them over the whole
    # mesh for every query was most of a rails check's time (np.add.at over every face).
    def edge_normal_sums(self, mesh: trimesh.Trimesh) -> NDArray[np.float64]:
        if self._edge_sums is None:
            edge_sum = np.zeros((len(mesh.edges_unique), 3))
            np.add.at(edge_sum, mesh.edges_unique_inverse, np.repeat(np.asarray(mesh.face_normals, float), 3, axis=0))
            self._edge_sums = edge_sum
        return self._edge_sums

    def vertex_normal_sums(self, mesh: trimesh.Trimesh) -> NDArray[np.float64]:
        if self._vertex_sums is None:
            vertex_sum = np.zeros((len(mesh.vertices), 3))
            angles = np.nan_to_num(np.asarray(mesh.face_angles))
            np.add.at(vertex_sum, mesh.faces, np.asarray(mesh.face_normals, float)[:, None, :] * angles[:, :, None])
            self._vertex_sums = vertex_sum
        return self._vertex_sums

    def query(self, points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
        """Squared distances, face ids and closest points of (n, 3) points.

        The points are queried in Morton (Z-curve) order: neighbours in the list are then
        neighbours in space, so tree nodes stay in cache (2-4x faster on scattered input)."""
        order = _morton_order(points)
        d2, faces, closest = self.tree.squared_distance(self.vertices, self.faces, np.ascontiguousarray(points[order]))
        out_d2, out_f, out_c = np.empty(len(points)), np.empty(len(points), dtype=np.int64), np.empty((len(points), 3))
        out_d2[order], out_f[order], out_c[order] = d2, faces, closest
        return out_d2, out_f, out_c


def _morton_order(points: NDArray[np.float64], bits: int = 10) -> NDArray[np.int64]:
    """Indices sorting points along a Z-order curve of their bounding box (bits per axis)."""
    if len(points) < 2:
        return np.arange(len(points))
    lo = points.min(axis=0)
    span = float(np.ptp(points, axis=0).max()) or 1.0
    q = ((points - lo) * ((2**bits - 1) / span)).astype(np.uint64)
    code = np.zeros(len(points), dtype=np.uint64)
    for b in range(bits):
        for k in range(3):
            code |= ((q[:, k] >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b + k)
    return np.argsort(code, kind="stable")


_INDEX_CACHE: "weakref.WeakKeyDictionary[trimesh.Trimesh, tuple[int, SurfaceIndex]]" = weakref.WeakKeyDictionary()
# the cached meshes (the sample part's) live until the interpreter ends, and libigl's bindings report every AABB
# tree still alive then as a leak on stderr: drop the trees at exit
atexit.register(_INDEX_CACHE.clear)


def surface_index(mesh: trimesh.Trimesh) -> SurfaceIndex:
    """The (cached) SurfaceIndex of a mesh; rebuilt when the mesh's geometry changed."""
    key = hash(mesh)  # trimesh hashes the vertex and face data (cached until they change)
    hit = _INDEX_CACHE.get(mesh)
    if hit is not None and hit[0] == key:
        return hit[1]
    index = SurfaceIndex(mesh)
    _INDEX_CACHE[mesh] = (key, index)
    return index


def closest_points(mesh: trimesh.Trimesh, points: ArrayLike, index: SurfaceIndex | None = None,
                   progress: Progress | None = None) -> ClosestPoints:
    """Exact closest points on the mesh for (n, 3) points in mesh coordinates (libigl AABB),
    with outward unit pseudo-normals; chunked (CHUNK points at a time)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(pts)
    index = index or surface_index(mesh)
    cad = cad_for_mesh(mesh)
    best_pt = np.empty((n, 3))
    dist = np.empty(n)
    face = np.empty(n, dtype=np.int64)
    normals = np.empty((n, 3))
    for start in range(0, n, CHUNK):
        sl = slice(start, min(start + CHUNK, n))
        d2, f, c = index.query(pts[sl])
        best_pt[sl], dist[sl], face[sl] = c, np.sqrt(np.maximum(d2, 0.0)), f
        normals[sl] = pseudo_normals(mesh, f, c)
        if cad is not None:  # analytic faces: the closest point on the exact surface
            def locate(q, index=index):
                d2q, fq, _ = index.query(np.ascontiguousarray(q))
                return np.sqrt(np.maximum(d2q, 0.0)), fq

            foot, signed, normal, exact = cad.refine(pts[sl], f, c, locate)
            idx = np.arange(sl.start, sl.stop)[exact]
            best_pt[idx], dist[idx], normals[idx] = foot[exact], np.abs(signed[exact]), normal[exact]
        if progress is not None:
            progress(sl.stop, n)
    if not np.all(np.isfinite(dist)):  # cannot happen for finite input; guard the invariant
        raise MeshError("closest-point search failed (non-finite points?)")
    return ClosestPoints(best_pt, dist, face, normals)


def pseudo_normals(mesh: trimesh.Trimesh, face_ids: NDArray[np.int64], points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Unit angle-weighted pseudo-normals at surface points lying on the given faces."""
    face_normals = np.asarray(mesh.face_normals, dtype=np.float64)
    normals = face_normals[face_ids].copy()
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[face_ids], points)
    small = bary < _BARY_EPS
    n_small = small.sum(axis=1)

    on_edge = np.nonzero(n_small == 1)[0]
    if len(on_edge):
        # edge k of a face joins vertices k and k+1, so it is opposite vertex k+2
        zero = np.argmax(small[on_edge], axis=1)
        k = (zero + 1) % 3
        edge_sum = surface_index(mesh).edge_normal_sums(mesh)
        normals[on_edge] = edge_sum[mesh.edges_unique_inverse[3 * face_ids[on_edge] + k]]

    on_vertex = np.nonzero(n_small >= 2)[0]
    if len(on_vertex):
        vertex_sum = surface_index(mesh).vertex_normal_sums(mesh)
        corner = np.argmax(bary[on_vertex], axis=1)
        normals[on_vertex] = vertex_sum[mesh.faces[face_ids[on_vertex], corner]]

    length = np.linalg.norm(normals, axis=1)
    ok = length > 1e-12  # a knife edge can cancel; fall back to the face normal
    normals[ok] /= length[ok, None]
    normals[~ok] = face_normals[face_ids[~ok]]
    return normals


def signed_deviation(mesh: trimesh.Trimesh, points: ArrayLike, pose: ArrayLike | None = None,
                     progress: Progress | None = None) -> DeviationResult:
    """Signed deviation of measured points (machine coordinates) to a posed part mesh.

    ``pose`` is the 4x4 part-to-machine transform of the mesh (None = identity).
    Sign: + = point outside the nominal material (excess), - = inside (missing);
    the opposite of trimesh.proximity.signed_distance, the same as libigl's.
    Works in chunks of CHUNK points; ``progress(done, total)`` is called after
    each.
    """
    T = as_pose(pose)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(pts) == 0:
        raise MeshError("no measured points were given")
    if not np.all(np.isfinite(pts)):
        raise MeshError("measured points contain NaN or infinite coordinates")
    n = len(pts)
    inv = invert(T)
    deviations = np.empty(n)
    closest = np.empty((n, 3))
    faces = np.empty(n, dtype=np.int64)
    normals = np.empty((n, 3))
    index = surface_index(mesh)
    for start in range(0, n, CHUNK):
        sl = slice(start, min(start + CHUNK, n))
        local = apply_points(inv, pts[sl])
        cp = closest_points(mesh, local, index)
        sign = np.sign(np.einsum("ij,ij->i", local - cp.points, cp.normals))
        deviations[sl] = sign * cp.distances
        closest[sl] = apply_points(T, cp.points)
        faces[sl] = cp.face_ids
        normals[sl] = apply_vectors(T, cp.normals)
        if progress is not None:
            progress(sl.stop, n)
    return DeviationResult(
        deviations=deviations,
        closest_points=closest,
        face_ids=faces,
        normals=normals,
        watertight=bool(mesh.metadata.get("watertight", mesh.is_watertight)),
    )
