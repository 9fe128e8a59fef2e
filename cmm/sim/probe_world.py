"""The simulated CMM's world: machine geometry, the part, the reference sphere and the probe.

Given the three axis readings it answers where the stylus tip really is and
whether the touch-trigger probe has fired. The trigger fires when the tip
ball has penetrated the material by the pre-travel delta of the contact
direction (3-lobed in XY, another value along Z) plus trigger noise.

Distance queries against a mesh are expensive, so they use conservative
advancement: after a query at distance d the tip cannot touch anything until
it has moved by d - r - delta_max, and no query is made before that.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import trimesh

from ..machine.geometry import geometry_matrix


@dataclass(frozen=True)
class ProbeModel:
    """The simulated probe (mm). delta(n) = xy + lobe * cos(3 phi + phase) horizontally, z vertically."""

    tip_radius: float = 1.0
    pretravel_xy: float = 0.004
    pretravel_lobe: float = 0.0015
    pretravel_phase: float = 0.0
    pretravel_z: float = 0.002
    noise_sigma: float = 0.00025

    def pretravel(self, n: np.ndarray) -> float:
        """Pre-travel for a contact whose surface normal (out of the material) is ``n``."""
        s2 = n[0] * n[0] + n[1] * n[1]
        phi = math.atan2(-n[1], -n[0])  # azimuth of the stylus deflection direction (into the surface)
        horizontal = self.pretravel_xy + self.pretravel_lobe * math.cos(3 * phi + self.pretravel_phase)
        return s2 * horizontal + (1 - s2) * self.pretravel_z

    @property
    def min_pretravel(self) -> float:
        """A lower bound of the trigger depth (noise drawn beyond 6 sigma is clipped)."""
        return max(0.0, min(self.pretravel_xy - abs(self.pretravel_lobe), self.pretravel_z) - 6 * self.noise_sigma)


RESEAT = 0.0005  # mm clear of the surface before the probe's switch closes again


@dataclass(frozen=True)
class GeometryErrors:
    """First-order machine geometry: per-axis scale (ppm) and squareness (urad), default off."""

    scale_ppm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    squareness_urad: tuple[float, float, float] = (0.0, 0.0, 0.0)  # xy, xz, yz

    def matrix(self) -> np.ndarray:
        """Columns: where a unit move of the X, Y and Z carriage really takes the tip."""
        return geometry_matrix(self.scale_ppm, self.squareness_urad)


class Obstacle:
    """Something the tip can touch: distance from a point to its surface and the outward normal there."""

    def query(self, p: np.ndarray) -> tuple[float, np.ndarray]:  # pragma: no cover - interface
        raise NotImplementedError


class SphereObstacle(Obstacle):
    def __init__(self, centre: np.ndarray, radius: float) -> None:
        self.centre = np.asarray(centre, dtype=np.float64)
        self.radius = float(radius)

    def query(self, p: np.ndarray) -> tuple[float, np.ndarray]:
        d = p - self.centre
        n = float(np.linalg.norm(d))
        return n - self.radius, d / n if n > 0 else np.array([0.0, 0.0, 1.0])


class PlaneObstacle(Obstacle):
    """A half-space below z = height (the table)."""

    def __init__(self, height: float = 0.0) -> None:
        self.height = height

    def query(self, p: np.ndarray) -> tuple[float, np.ndarray]:
        return float(p[2] - self.height), np.array([0.0, 0.0, 1.0])


class MeshObstacle(Obstacle):
    """A watertight part mesh at a pose (4x4, part -> machine).

    A full closest-point query costs milliseconds, too much for a servo
    tick, so the triangles near the last full query are kept: while the tip
    stays within LOCAL_REACH of that point, the closest point is among them.
    """

    LOCAL_REACH = 0.5  # mm
    BOUND_REACH = 5.0  # mm: within this of the last exact distance, that distance bounds the next one
    # beyond this distance from the bounding box (mm) a query answers the box's distance, a lower bound: it must
    # exceed the mounted tip's radius (SimulatedCMM.mount_stylus keeps it so), or a bound would read as a contact
    box_reach = 1.0

    def __init__(self, mesh, pose: np.ndarray) -> None:
        from ..cad import cad_of

        # a CAD part: the contact found on the triangulation is moved onto its face's exact surface
        self.cad = cad_of(mesh)
        pose = np.asarray(pose, dtype=np.float64)
        self._rot, self._shift = pose[:3, :3].copy(), pose[:3, 3].copy()
        self.mesh = mesh.copy()
        self.mesh.apply_transform(np.asarray(pose, dtype=np.float64))
        self.lo, self.hi = self.mesh.bounds
        self._tree = self.mesh.triangles_tree
        self._local_at: np.ndarray | None = None
        self._local_faces = np.zeros(0, dtype=np.int64)
        self._known_at: np.ndarray | None = None  # where the last exact distance to the triangles was taken
        self._known_dist = 0.0
        self.full_queries = 0

    def _gather(self, p: np.ndarray) -> None:
        """Faces that can hold the closest point for any tip within LOCAL_REACH of ``p``."""
        if self._known_at is not None and float(np.linalg.norm(p - self._known_at)) <= self.BOUND_REACH:
            # the last exact distance bounds this one (the surface is at most that far plus the step): the faces
            # in reach come from the tree's boxes alone, without the full query's search
            dist = self._known_dist + float(np.linalg.norm(p - self._known_at))
        else:
            dist = float(self.mesh.nearest.on_surface(p[None, :])[1][0])
            self.full_queries += 1
        reach = dist + 2 * self.LOCAL_REACH
        box = np.concatenate([p - reach, p + reach])
        self._local_faces = np.fromiter(self._tree.intersection(box), dtype=np.int64)
        self._local_at = p.copy()

    def query(self, p: np.ndarray) -> tuple[float, np.ndarray]:
        # a cheap lower bound first: the distance to the bounding box
        gap = np.maximum(np.maximum(self.lo - p, p - self.hi), 0.0)
        box = float(np.linalg.norm(gap))
        if box > self.box_reach:  # farther than any contact of the mounted tip: the bound is enough
            return box, np.array([0.0, 0.0, 1.0])
        if self._local_at is None or float(np.linalg.norm(p - self._local_at)) > self.LOCAL_REACH:
            self._gather(p)
        faces = self._local_faces
        tris = self.mesh.triangles[faces]
        cps = trimesh.triangles.closest_point(tris, np.repeat(p[None, :], len(faces), axis=0))
        d2 = np.einsum("ij,ij->i", cps - p, cps - p)
        k = int(np.argmin(d2))
        c = cps[k]
        n = self.mesh.face_normals[faces[k]]
        v = p - c
        dv = float(np.sqrt(d2[k]))
        self._known_at, self._known_dist = p.copy(), dv
        if self.cad is not None:
            local = self._rot.T @ (np.stack([p, c]) - self._shift).T

            def locate(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # among the triangles near the tip
                world = q @ self._rot.T + self._shift
                near = trimesh.triangles.closest_point(tris, np.repeat(world, len(faces), axis=0))
                j = int(np.argmin(np.einsum("ij,ij->i", near - world, near - world)))
                return np.array([float(np.linalg.norm(near[j] - world[0]))]), faces[j:j + 1]

            _, signed, normal, exact = self.cad.refine(local[:, :1].T, faces[k:k + 1], local[:, 1:].T, locate)
            if exact[0]:
                return float(signed[0]), self._rot @ normal[0]
        inside = float(np.dot(v, n)) < 0 if dv > 1e-12 else False
        normal = (v / dv if dv > 1e-9 else n) * (-1 if inside else 1)
        return (-dv if inside else dv), normal


@dataclass
class ProbeWorld:
    """Axis readings -> tip position -> probe state."""

    obstacles: list[Obstacle]
    probe: ProbeModel = field(default_factory=ProbeModel)
    errors: GeometryErrors = field(default_factory=GeometryErrors)
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))  # tip position at zero axis travel
    seed: int = 0

    def __post_init__(self) -> None:
        self._m = self.errors.matrix()
        m, o = self._m, self.origin  # as plain floats for update (every servo tick); the matrix is upper triangular
        self._k = tuple(float(v) for v in (o[0], o[1], o[2], m[0, 0], m[0, 1], m[0, 2], m[1, 1], m[1, 2], m[2, 2]))
        self._rng = np.random.default_rng(self.seed)
        self._safe_from: np.ndarray | None = None  # tip position of the last distance query
        self._safe_dist = 0.0  # how far the tip may move from there before it could touch
        self.triggered = False
        self._threshold = self._draw_threshold()
        self.contact_normal: np.ndarray | None = None
        self.queries = 0

    def _draw_threshold(self) -> float:
        sigma = self.probe.noise_sigma
        return float(np.clip(self._rng.normal(0.0, sigma), -6 * sigma, 6 * sigma))

    def tip(self, axes_mm: np.ndarray) -> np.ndarray:
        """Where the tip centre really is for the given axis readings (mm)."""
        return self.origin + self._m @ np.asarray(axes_mm, dtype=np.float64)

    def update(self, x: float, y: float, z: float) -> bool:
        """New axis readings (mm of carriage travel); returns whether the probe is triggered.

        Runs every servo tick, so the no-contact-possible case is plain floats.
        """
        ox, oy, oz, m00, m01, m02, m11, m12, m22 = self._k
        px = ox + m00 * x + m01 * y + m02 * z
        py = oy + m11 * y + m12 * z
        pz = oz + m22 * z
        if self._safe_from is not None:
            sx, sy, sz = self._safe_from
            if (px - sx) ** 2 + (py - sy) ** 2 + (pz - sz) ** 2 < self._safe_dist ** 2:
                return self.triggered
        p = np.array([px, py, pz])
        r = self.probe.tip_radius
        best, normal = math.inf, None
        for ob in self.obstacles:
            d, n = ob.query(p)
            if d < best:
                best, normal = d, n
        self.queries += 1
        penetration = r - best
        if self.triggered:
            # the switch re-seats once the tip is clear of the surface again
            if penetration < -RESEAT:
                self.triggered = False
                self._threshold = self._draw_threshold()
                self.contact_normal = None
                self._safe_from = None
            else:  # it cannot re-seat before the tip has moved this far
                self._safe_from = (px, py, pz)
                self._safe_dist = penetration + RESEAT
            return self.triggered
        assert normal is not None
        if penetration >= self.probe.pretravel(normal) + self._threshold:
            self.triggered = True
            self.contact_normal = normal
            self._safe_from = None
            return True
        self._safe_from = (px, py, pz)
        self._safe_dist = max(0.0, best - r + self.probe.min_pretravel)
        return False
