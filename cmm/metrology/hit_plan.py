"""Auto-measure from the CAD: the hits that measure a picked surface, reachable over a clearance plane.

:func:`plan_feature` takes the nominal feature suggested for a picked face
(:func:`cmm.metrology.pick.suggest_feature`, with its face region) and
proposes what a CMM programmer would: the feature kind to fit, the number
and pattern of hits, and the approach of each hit (into the surface):

- plane: ``n`` hits (default 4) spread over the face, at least ``margin``
  from its edges (farthest-point sampling of surface samples);
- cylinder (bore or boss): two rings of ``n`` hits (default 4) at a fifth
  and four fifths of its length; a short one (< 3 mm) becomes a circle;
- sphere: the pole (along +Z) and a ring of ``n`` hits (default 4) at 45 deg,
  kept to the part of the sphere the mesh has;
- cone: two rings of ``n`` hits at a fifth and four fifths of its length.

The hits determine the feature: the two rings of a cylinder or cone are far
apart in height (``RING_LEVELS``; at least ``MIN_RING_GAP`` apart, else the
plan says the cone's angle is poorly determined) and the second ring is turned
by half the angle between hits (two rings of four hits at the same angles lie
exactly on a cylinder across the axis as well, so the fit could not tell the
probed feature from it), and there are at least as many hits as the feature
has parameters plus one to check them (``MIN_PER_RING``: cone 2 rings of 4 for
6 parameters, cylinder 2 of 3 for 5, circle 4 for 3, sphere the pole and 4 for
4). When the operator asks for fewer, the plan takes the minimum and
``HitPlan.notes`` says so (a cone of 2 rings of 3 hits has no hit to spare: its
fit can pass exactly through all six hits on a cone far from the probed one).
Planes keep the hits asked for (3 is the usual alignment plane), with a note
that 3 leave none to check the form.

Every planned hit must lie on the picked region of the mesh (a hit that would
land on another face is dropped) and face upward enough to be reached from
above (the probe comes down over a clearance plane to the first hit). The hits
after the first may hop lower: ``HitPlan.hop_z`` is the feature's local top
plus the tip radius and a margin (:func:`cmm.metrology.hops.hop_height`). The
path the probe takes to them is the control core's (``Controller.probe_paths``
previews it, from the same code the run executes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh

from .hops import hop_height
from .pick import NominalFeature
from .transform import apply_points, apply_vectors, as_pose, invert

MIN_NORMAL_Z = -0.2  # faces that look further down than this cannot be reached by a vertical stylus
ON_SURFACE = 0.05  # mm: a planned point must be this close to the picked region
# hits per ring (sphere: besides the pole) so that the hits outnumber the feature's parameters by at least one
MIN_PER_RING = {"cone": 4, "cylinder": 3, "circle": 4, "sphere": 4}
PARAMETERS = {"plane": 3, "circle": 3, "cylinder": 5, "sphere": 4, "cone": 6}
RING_LEVELS = (0.2, 0.8)  # fractions of a cylinder's or cone's length where its two rings go
SHORT_RING_LEVELS = (0.1, 0.9)  # ... of a cone so short that RING_LEVELS would put them under MIN_RING_GAP apart
MIN_RING_GAP = 2.0  # mm between the two rings of a cone: closer, its angle is poorly determined


class PlanError(ValueError):
    """A feature that cannot be measured automatically, in an operator's words."""


@dataclass
class HitPlan:
    kind: str  # the feature to fit: plane, circle, cylinder, sphere, cone
    nominal: NominalFeature  # machine coordinates
    points: np.ndarray  # n x 3 nominal surface points, machine mm
    approaches: np.ndarray  # n x 3 unit directions into the surface
    clearance_z: float  # machine Z of the clearance plane
    description: str = ""
    notes: tuple[str, ...] = ()  # what the plan changed from the request, or what the hits do not determine
    per_ring: int = 0  # hits per ring (cylinder, cone: two rings; sphere: besides the pole; others: all hits)
    hop_z: float | None = None  # machine Z of the tip centre for hops between the hits after the first

    def __len__(self) -> int:
        return len(self.points)


def _frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def _boundary_segments(mesh: trimesh.Trimesh, faces: np.ndarray) -> np.ndarray:
    edges = np.sort(mesh.faces[faces][:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    return mesh.vertices[uniq[counts == 1]]


def _distance_to_segments(p: np.ndarray, seg: np.ndarray) -> np.ndarray:
    if len(seg) == 0:
        return np.full(len(p), np.inf)
    a, b = seg[:, 0], seg[:, 1]
    ab = b - a
    t = np.clip(np.einsum("pij,ij->pi", p[:, None, :] - a[None], ab) / np.maximum((ab * ab).sum(1), 1e-30), 0, 1)
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(p[:, None, :] - closest, axis=2).min(axis=1)


def _spread(points: np.ndarray, n: int) -> np.ndarray:
    """Farthest-point sampling: ``n`` well spread points (indices), starting far from the centroid."""
    if len(points) <= n:
        return np.arange(len(points))
    chosen = [int(np.argmax(np.linalg.norm(points - points.mean(axis=0), axis=1)))]
    d = np.linalg.norm(points - points[chosen[0]], axis=1)
    for _ in range(n - 1):
        k = int(np.argmax(d))
        chosen.append(k)
        d = np.minimum(d, np.linalg.norm(points - points[k], axis=1))
    return np.array(chosen)


def _on_region(mesh: trimesh.Trimesh, region: np.ndarray, local: np.ndarray) -> np.ndarray:
    """Which part-coordinate points lie on the region's faces (closest face in the region, on the surface)."""
    if len(local) == 0:
        return np.zeros(0, bool)
    _, dist, tri = mesh.nearest.on_surface(local)
    return (np.asarray(dist) <= ON_SURFACE) & np.isin(np.asarray(tri), region)


def plan_feature(mesh: trimesh.Trimesh, pose: Any, nominal_local: NominalFeature, region: Any, *,
                 n: int | None = None, margin: float = 3.0, clearance: float = 15.0,
                 seed: int = 0, tip_radius: float = 1.0) -> HitPlan:
    """The hits that measure ``nominal_local`` (part coordinates, on face ``region`` of ``mesh``); the hop
    height between its hits is for a tip of ``tip_radius``."""
    T = as_pose(pose)
    region = np.asarray(region, dtype=np.int64)
    nom = nominal_local
    p = nom.params
    kind = nom.kind
    pts: list[np.ndarray] = []
    app: list[np.ndarray] = []
    notes: list[str] = []
    if kind in ("plane", "surface"):
        normal = np.asarray(p["normal"], float)
        count = n or 4
        samples, _ = trimesh.sample.sample_surface(mesh.submesh([region], append=True), 400, seed=seed)
        samples = np.asarray(samples, float)
        inner = samples[_distance_to_segments(samples, _boundary_segments(mesh, region)) >= margin]
        if len(inner) < count:
            raise PlanError(f"the face is too small for {count} hits {margin:g} mm from its edges")
        for q in inner[_spread(inner, count)]:
            pts.append(q)
            app.append(-normal)
        if count <= PARAMETERS["plane"]:
            notes.append(f"{count} hits determine a plane exactly: none is left to check its form (flatness 0)")
        fit_kind, what = "plane", f"plane: {count} hits spread over the face"
    elif kind in ("cylinder", "cone"):
        axis = np.asarray(p["direction"], float)
        axis /= np.linalg.norm(axis)
        e1, e2 = _frame(axis)
        verts = mesh.vertices[np.unique(mesh.faces[region])]
        origin = np.asarray(p["point"] if kind == "cylinder" else p["apex"], float)
        h = (verts - origin) @ axis
        lo, hi = float(h.min()), float(h.max())
        length = hi - lo
        bore = bool(p.get("bore", False))
        if kind == "cylinder" and length < 3.0:
            levels, fit_kind = [lo + length / 2], "circle"
        else:
            fractions = RING_LEVELS
            if kind == "cone" and (RING_LEVELS[1] - RING_LEVELS[0]) * length < MIN_RING_GAP:
                fractions = SHORT_RING_LEVELS
            levels, fit_kind = [lo + f * length for f in fractions], kind
            gap = levels[1] - levels[0]
            if kind == "cone" and gap < MIN_RING_GAP:
                notes.append(f"the cone is {length:.1f} mm long: its rings are only {gap:.1f} mm apart "
                             f"(at least {MIN_RING_GAP:g} mm determine its angle well); its half angle and apex "
                             "are poorly determined")
        count = _enough(fit_kind, n, 4, len(levels), notes)
        for ring, level in enumerate(levels):
            # the second ring turned by half a step: rings at the same angles fit a cylinder across the axis too
            for a in np.linspace(0, 2 * math.pi, count, endpoint=False) + math.pi / count * (1 + ring):
                radial = math.cos(a) * e1 + math.sin(a) * e2
                if kind == "cylinder":
                    r = float(p["radius"])
                    surface_n = radial
                else:
                    half = float(p["half_angle"])
                    r = level * math.tan(half)
                    surface_n = math.cos(half) * radial - math.sin(half) * axis
                q = origin + level * axis + r * radial
                outward = -surface_n if bore else surface_n
                pts.append(q)
                app.append(-outward)
        rings = "one ring" if len(levels) == 1 else "two rings"
        what = f"{fit_kind} ({'bore' if bore else 'boss'}): {rings} of {count} hits"
    elif kind == "sphere":
        c = np.asarray(p["center"], float)
        r = float(p["radius"])
        bore = bool(p.get("bore", False))
        up = apply_vectors(invert(T), np.array([0.0, 0.0, 1.0]))
        e1, e2 = _frame(up)
        count = _enough("sphere", n, 4, 1, notes, extra=1)
        dirs = [up] + [math.sin(math.radians(45)) * (math.cos(a) * e1 + math.sin(a) * e2) + math.cos(math.radians(45)) * up
                       for a in np.linspace(0, 2 * math.pi, count, endpoint=False)]
        for d in dirs:
            pts.append(c + r * d)
            app.append(d if bore else -d)
        fit_kind, what = "sphere", f"sphere: the pole and {count} hits at 45°"
    else:
        raise PlanError(f"a {kind} surface cannot be measured automatically")
    local = np.array(pts, float).reshape(-1, 3)
    approach_l = np.array(app, float).reshape(-1, 3)
    keep = _on_region(mesh, region, local)
    machine_pts = apply_points(T, local)
    machine_app = apply_vectors(T, approach_l)
    keep &= (-machine_app[:, 2]) >= MIN_NORMAL_Z  # outward normal not pointing down
    minimum = {"plane": 3, "circle": 3, "cylinder": 6, "sphere": 4, "cone": 6}[fit_kind]
    if keep.sum() < minimum:
        raise PlanError(f"only {int(keep.sum())} of {len(keep)} planned hits for this {fit_kind} are on the picked "
                        f"surface and reachable from above; a {fit_kind} needs {minimum}")
    machine_pts, machine_app = machine_pts[keep], machine_app[keep]
    top = float(apply_points(T, mesh.vertices)[:, 2].max())
    clearance_z = top + clearance
    if fit_kind in ("cylinder", "cone") and (~keep).any():
        notes.append(f"{int((~keep).sum())} planned hits are not on the surface or not reachable: the rest may not "
                     f"determine the {fit_kind}")
    from .uncertainty import Sources, plan_note

    nominal_m = nom.transformed(T)
    expectation = plan_note(fit_kind, machine_pts, nominal_m.params if fit_kind in ("cylinder", "cone") else None,
                            sources=Sources(reference=tuple(T[:3, 3])))
    if expectation:  # said before Run: the plan's hits cannot hold the default tolerance to a quarter
        notes.append(expectation)
    plan = HitPlan(fit_kind, nominal_m, machine_pts, machine_app, clearance_z,
                   what + (f" ({int((~keep).sum())} dropped: not on the surface)" if (~keep).any() else ""),
                   notes=tuple(notes), per_ring=count,
                   hop_z=min(hop_height(mesh, T, machine_pts, tip_radius, region=region), clearance_z))
    return plan


def _enough(kind: str, asked: int | None, default: int, rings: int, notes: list[str], extra: int = 0) -> int:
    """Hits per ring: as asked (or ``default``), raised to MIN_PER_RING[kind] so the ``rings`` rings (and
    ``extra`` hits off them) outnumber the feature's parameters; a note says when the request was raised."""
    need = MIN_PER_RING[kind]
    if asked is None or asked >= need:
        return asked or max(default, need)
    total = need * rings + extra
    where = "per ring" if kind != "sphere" else "around the pole"
    notes.append(f"{asked} hits {where} were asked for; a {kind} has {PARAMETERS[kind]} parameters and needs "
                 f"{need} {where} ({total} hits: one at least to check the fit; with fewer the fit can pass "
                 f"exactly through the hits on another {kind}): planned {need} {where}")
    return need
