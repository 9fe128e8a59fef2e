"""The CAD model as plain data: B-rep faces with their exact surfaces, and a triangulation mapped to them.

A :class:`CadModel` is what :func:`cmm.cad.reader.read_cad` makes of a STEP or IGES file, in millimetres and the
file's own (design) frame, assemblies flattened with their placements applied:

- ``faces``: one :class:`CadFace` per B-rep face: ``kind`` (plane, cylinder, cone, sphere, torus, or free-form),
  the surface's parameters (see :mod:`cmm.cad.surfaces`), ``sense`` (+1 when the material lies on the side
  opposite the surface's natural normal, i.e. the natural normal points out of the material, else -1), the body
  it belongs to, its area and bounding box;
- ``vertices`` / ``triangles`` / ``tri_face``: the triangulation used to draw and pick the part, each triangle
  tagged with its face (wound so its normal points out of the material).

Nothing here imports OpenCASCADE: the model pickles (the simulator runs in a process of its own) and copies cheaply.
Distances to analytic faces are closed-form (:mod:`cmm.cad.surfaces`); to free-form faces OpenCASCADE projects onto
the exact surface (:mod:`cmm.cad.freeform`, the face kept as BREP text: this module itself never imports it); a
face without it is measured against its triangulation, whose chordal error is ``deflection``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import surfaces

Array = NDArray[np.float64]

FREE_FORM = "free-form"
KINDS = (*surfaces.ANALYTIC, FREE_FORM)
# a closest point found on the triangulation is refined onto its face's exact surface when the exact foot lies within
# this of it: the chordal error, plus the lateral shift a facet's tilt gives at the point's distance
ANGLE_SLACK = 0.3  # rad: half the largest angle between neighbouring facets (0.5 rad), with a margin


class CadError(ValueError):
    """A CAD file cannot be used; the message is one sentence meant for the operator."""


@dataclass
class CadFace:
    index: int
    kind: str  # plane, cylinder, cone, sphere, torus, free-form
    params: dict[str, Any]  # part coordinates, mm (see cmm.cad.surfaces)
    sense: int  # +1: the surface's natural normal points out of the material; -1: into it
    body: int  # index into CadModel.bodies
    area: float = 0.0
    bounds: Array = field(default_factory=lambda: np.zeros((2, 3)))  # (lo, hi) of its triangulation
    source: str = ""  # the surface type in the file when it was recognised as analytic (e.g. BSplineSurface)
    group: int = -1  # faces on the same exact surface and touching share a group (a cylinder split in halves)

    @property
    def analytic(self) -> bool:
        return self.kind in surfaces.ANALYTIC

    def describe(self) -> str:
        p = self.params
        if self.kind in ("cylinder", "sphere"):
            return f"{self.kind} D{2 * p['radius']:.4f}"
        if self.kind == "cone":
            return f"cone {np.degrees(p['half_angle']):.3f}° half angle"
        if self.kind == "torus":
            return f"torus R{p['major_radius']:.4f} r{p['minor_radius']:.4f}"
        return self.kind


@dataclass
class CadModel:
    source: str  # file name
    format: str  # STEP or IGES
    unit: str  # the file's length unit (mm, inch, ...); everything here is in mm
    faces: list[CadFace]
    vertices: Array  # (n, 3) mm
    triangles: NDArray[np.int64]  # (m, 3)
    tri_face: NDArray[np.int64]  # (m,) face index of every triangle
    bodies: list[str] = field(default_factory=list)
    deflection: float = 0.01  # mm, chordal error of the triangulation
    schema: str = ""  # e.g. AP203 / AP214 / AP242 for STEP

    def __deepcopy__(self, memo: dict) -> "CadModel":  # immutable by convention: meshes copy their metadata
        return self

    # --- summary ---------------------------------------------------------------

    def counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for f in self.faces:
            out[f.kind] = out.get(f.kind, 0) + 1
        return out

    def summary(self) -> str:
        kinds = ", ".join(f"{n} {k}" for k, n in sorted(self.counts().items()))
        return (f"{self.source}: {self.format}{' ' + self.schema if self.schema else ''}, {len(self.bodies)} "
                f"bod{'y' if len(self.bodies) == 1 else 'ies'}, {len(self.faces)} faces ({kinds}), file unit "
                f"{self.unit}, {len(self.triangles)} triangles")

    def mesh(self) -> Any:
        """The triangulation as a trimesh (part mm) whose ``metadata["cad"]`` is this model."""
        import trimesh

        mesh = trimesh.Trimesh(vertices=self.vertices.copy(), faces=self.triangles.copy(), process=False)
        mesh.metadata["cad"] = self
        mesh.metadata["file_name"] = self.source
        mesh.metadata["watertight"] = bool(mesh.is_watertight)
        return mesh

    # --- faces and regions ----------------------------------------------------------

    def face_of(self, triangle: int) -> CadFace:
        return self.faces[int(self.tri_face[int(triangle)])]

    def group_faces(self, face: int) -> list[int]:
        g = self.faces[face].group
        return [f.index for f in self.faces if f.group == g] if g >= 0 else [face]

    def triangles_of(self, faces: list[int]) -> NDArray[np.int64]:
        """The triangles of the given faces (the triangulation lists each face's triangles together, in face order)."""
        start = self.__dict__.get("_starts")
        if start is None or len(start) != len(self.faces) + 1:
            ordered = bool(np.all(np.diff(self.tri_face) >= 0))
            start = np.searchsorted(self.tri_face, np.arange(len(self.faces) + 1)) if ordered else np.zeros(0)
            self.__dict__["_starts"] = start
        if len(start) == 0:  # not in face order: the slow way
            return np.nonzero(np.isin(self.tri_face, np.asarray(faces, dtype=np.int64)))[0]
        return np.concatenate([np.arange(start[f], start[f + 1]) for f in faces] or [np.zeros(0, np.int64)])

    def nominal(self, face: int) -> tuple[str, dict[str, Any], NDArray[np.int64]]:
        """The nominal feature (kind, params, part coordinates) of a face's exact surface, over the faces of its
        group, and the triangles of that region. Kinds and parameters as :class:`cmm.metrology.pick.NominalFeature`."""
        f = self.faces[face]
        tris = self.triangles_of(self.group_faces(face))
        v = self.vertices[np.unique(self.triangles[tris])]
        p = f.params
        bore = f.sense < 0
        if f.kind == "plane":
            n = f.sense * np.asarray(p["normal"], float)
            c = _area_centroid(self.vertices[self.triangles[tris]])
            c = c - ((c - p["origin"]) @ n) * n
            return "plane", {"point": c, "normal": n}, tris
        if f.kind == "cylinder":
            a = _canonical(np.asarray(p["axis"], float))
            h = (v - p["origin"]) @ a
            point = np.asarray(p["origin"], float) + 0.5 * (h.min() + h.max()) * a
            return "cylinder", {"point": point, "direction": a, "radius": float(p["radius"]),
                                "length": float(h.max() - h.min()), "bore": bool(bore)}, tris
        if f.kind == "cone":
            return "cone", {"apex": np.asarray(p["apex"], float), "direction": np.asarray(p["axis"], float),
                            "half_angle": float(p["half_angle"]), "bore": bool(bore)}, tris
        if f.kind == "sphere":
            return "sphere", {"center": np.asarray(p["center"], float), "radius": float(p["radius"]),
                              "bore": bool(bore)}, tris
        corners = self.vertices[self.triangles[tris]]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        n = normals.sum(axis=0)
        n = n / (np.linalg.norm(n) or 1.0)
        return "surface", {"point": _area_centroid(corners), "normal": n}, tris

    # --- exact distances --------------------------------------------------------------

    def refine(self, points: Array, triangles: NDArray[np.int64], mesh_closest: Array, locate: Any = None
               ) -> tuple[Array, Array, Array, NDArray[np.bool_]]:
        """Closest points found on the triangulation, moved onto the exact surfaces of their faces.

        ``points`` (n, 3, part mm), the triangle each one's closest mesh point lies on and that point. Returns the
        closest points, signed distances (+ outside the material), outward unit normals and which points were
        refined: those whose face is analytic (or free-form with its exact surface) and whose exact foot lies where the mesh found the closest point
        (within the chordal error and, on a curved face, the facet tilt at that distance) and on the face itself:
        ``locate(feet)`` gives the distance of each foot to the triangulation and the triangle nearest it, which must
        be of the same face group (a point above a hole projects onto the plane around it, inside the hole: the
        rim is nearer). The others keep the mesh's values (NaN distance and normal: the caller keeps its own)."""
        points = np.asarray(points, float).reshape(-1, 3)
        faces = self.tri_face[np.asarray(triangles, dtype=np.int64)]
        foot = np.array(mesh_closest, dtype=np.float64, copy=True).reshape(-1, 3)
        dist = np.full(len(points), np.nan)
        normal = np.full((len(points), 3), np.nan)
        done = np.zeros(len(points), dtype=bool)
        order = np.argsort(faces, kind="stable")
        for sel in np.split(order, np.flatnonzero(np.diff(faces[order])) + 1) if len(order) else ():
            f = self.faces[int(faces[sel[0]])]
            if f.analytic:
                q, d, n = surfaces.project(f.kind, f.params, points[sel])
                d, n = f.sense * d, f.sense * n
            elif "brep" in f.params:  # free-form: OpenCASCADE's projection, signed by the facets' outward side
                q, d, n, projected = self._free_form(f, points[sel], np.asarray(triangles, dtype=np.int64)[sel])
                sel = sel[projected]
                q, d, n = q[projected], d[projected], n[projected]
            else:
                continue
            slack = 2.0 * self.deflection + (0.0 if f.kind == "plane" else ANGLE_SLACK) * np.abs(d) + 1e-9
            ok = np.linalg.norm(q - foot[sel], axis=1) <= slack
            if locate is not None and ok.any():
                gap, tri = locate(q[ok])
                groups = np.array([self.faces[int(k)].group for k in self.tri_face[np.asarray(tri, dtype=np.int64)]])
                ok[np.flatnonzero(ok)] = (np.asarray(gap) <= 2.0 * self.deflection + 1e-9) & (groups == f.group)
            idx = sel[ok]
            foot[idx], dist[idx], normal[idx] = q[ok], d[ok], n[ok]
            done[idx] = True
        return foot, dist, normal, done

    def _free_form(self, f: CadFace, points: Array, triangles: NDArray[np.int64]
                   ) -> tuple[Array, Array, Array, NDArray[np.bool_]]:
        """Feet, signed distances, outward normals on a free-form face's exact surface (:mod:`cmm.cad.freeform`),
        the outward side that of the triangles the points' closest mesh points lie on; which points projected."""
        from . import freeform

        corners = self.vertices[self.triangles[triangles]]
        outward = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        return freeform.project(f.params, points, outward)

    def exact_distance(self, face: int, points: Array) -> Array:
        """Signed distances (+ outside the material) of points to the exact surface of one analytic face (not
        bounded by its edges)."""
        f = self.faces[face]
        _, d, _ = surfaces.project(f.kind, f.params, np.asarray(points, float).reshape(-1, 3))
        return f.sense * d


def _canonical(direction: Array) -> Array:
    return direction if direction[np.argmax(np.abs(direction))] > 0 else -direction


def _area_centroid(corners: Array) -> Array:
    area = 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    centres = corners.mean(axis=1)
    total = area.sum()
    return centres.mean(axis=0) if total <= 0 else (centres * area[:, None]).sum(axis=0) / total


def assign_groups(model: CadModel, tol: float = 1e-6) -> None:
    """Group faces that lie on the same exact surface and share an edge of the triangulation (a cylinder exported
    as two half faces is one feature)."""
    parent = list(range(len(model.faces)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    edges = np.sort(model.triangles[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    owner = np.repeat(model.tri_face, 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    e, o = edges[order], owner[order]
    same = np.all(e[1:] == e[:-1], axis=1) & (o[1:] != o[:-1])
    pairs = {(int(min(a, b)), int(max(a, b))) for a, b in zip(o[:-1][same], o[1:][same])}
    for a, b in pairs:
        fa, fb = model.faces[a], model.faces[b]
        if fa.kind != fb.kind or not fa.analytic or fa.sense != fb.sense or find(a) == find(b):
            continue
        vb = model.vertices[np.unique(model.triangles[model.triangles_of([b])])]
        va = model.vertices[np.unique(model.triangles[model.triangles_of([a])])]
        if (np.abs(model.exact_distance(a, vb)).max() <= tol and np.abs(model.exact_distance(b, va)).max() <= tol
                and _same_size(fa, fb, tol)):
            parent[find(b)] = find(a)
    for f in model.faces:
        f.group = find(f.index)


def _same_size(a: CadFace, b: CadFace, tol: float) -> bool:
    for key in ("radius", "half_angle", "major_radius", "minor_radius"):
        if key in a.params and abs(float(a.params[key]) - float(b.params[key])) > tol:
            return False
    return True
