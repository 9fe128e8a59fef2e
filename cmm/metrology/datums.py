"""Datums and datum reference frames (ISO 5459 / ASME Y14.5), from measured features.

A datum is what a measured datum feature gives the frame:

- a plane (fitted plane): a direction (its normal) and a location along it;
- an axis (cylinder, circle, cone, line): a direction and a location across it (2 translations);
- a point (sphere centre, point): a location in all three translations, no direction.

:func:`build_drf` takes the datums in precedence order (primary, secondary, tertiary) and builds the frame
the way the standard's constraint order does: each datum constrains only the degrees of freedom (DOF) the
datums before it leave free, and its own orientation is taken relative to them (datum B is the plane or axis
perpendicular to A that fits B's feature: B's small squareness error to A never tilts A):

1. orientation: the first datum with a direction sets Z (and so Rx, Ry); the next datum with a direction
   that is not parallel to Z sets X, projected perpendicular to Z (Rz);
2. location: each datum's location directions (plane: its normal; axis: the two directions across it;
   point: all three) are projected onto the translations still free; what is left is constrained at the
   datum feature's location (origin = the intersection of the simulated datums; along what stays free,
   the point nearest the coordinate origin);
3. clocking: when Z is set but X is not and the translations across Z are already constrained, a later axis
   or point off the origin sets X towards it (A plane, B bore, C hole); with no Z yet and the origin
   fixed (three sphere centres) such a datum sets Z towards it.

A datum that constrains nothing the ones before it leave free is refused (:class:`DatumError`), with the
reason in words: "datum B (plane) is parallel to datum A ...". The frame reports which DOF it constrains
(``constrained``, in DRF axes: Tx Ty Tz Rx Ry Rz) and which are free: a characteristic against a partial
frame lets the free ones float (see :mod:`cmm.metrology.gdt`).

A common datum (ISO 5459 "A-B", ASME "A-B") is one datum from two datum features: two coaxial features (e.g. two
bores on one shaft) give the common axis through their centres (the location points of their axes: the
projection of each feature's points' centroid onto its axis, a circle's centre), directed as the first's axis;
two parallel faces give the common plane through their midpoint with their mean normal
(:func:`common_datum`). Features that are not both axes or both planes, axes that are not coaxial (either
axis more than COMMON_DEG from the line through the centres), centres that coincide, or planes that are not
parallel are refused in words.

Datum targets (:func:`datum_from_targets`): a datum plane established by target points on its feature (three
on the primary, two on the secondary, one on the tertiary) instead of the whole surface; other counts for the
datum's place in the frame, targets in a line or coinciding are refused in words.

Datum features of size (axis or point of a cylinder, circle or sphere) may be referenced at maximum or least
material boundary (``modifier`` "MMB" / "LMB"); the characteristic then gets a datum shift (``Datum.size``,
``Datum.boundary``, ``Datum.internal`` carry what it needs). Pure numpy; no machine, no UI.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .geom_basics import frame_with_axis

PARALLEL_DEG = 0.5  # a direction within this angle of one already constrained adds no orientation (degrees)
COINCIDENT_MM = 1e-6  # a clocking feature this close to the origin (across Z) cannot set X
DATUM_KINDS = {"plane": "plane", "cylinder": "axis", "circle": "axis", "cone": "axis", "line": "axis",
               "sphere": "point", "point": "point"}
MODIFIERS = ("", "MMB", "LMB")
COMMON_DEG = 2.0  # a common datum's features: axes within this angle of the line through their centres, planes parallel
COMMON_MIN_MM = 1.0  # ... and axis centres at least this far apart (closer, the common axis is not defined)
DOF_NAMES = ("Tx", "Ty", "Tz", "Rx", "Ry", "Rz")


class DatumError(ValueError):
    """A datum or datum reference frame that cannot be built, in an operator's words."""


def _vec(v: Any, what: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise DatumError(f"the {what} must be three finite numbers")
    if np.abs(a).max() > 1e9:
        raise DatumError(f"the {what} coordinates are too large")
    return a


def _unit(v: Any, what: str) -> np.ndarray:
    a = _vec(v, what)
    n = float(np.linalg.norm(a))
    if n == 0.0:
        raise DatumError(f"the {what} is a zero vector")
    return a / n


@dataclass(frozen=True)
class Datum:
    """One datum: ``label`` (A, B, ...), ``kind`` plane / axis / point, ``origin`` (a point of it) and
    ``direction`` (plane normal or axis direction; None for a point); for a datum feature of size its actual
    ``size`` (diameter), the ``boundary`` it is referenced at (the MMB / LMB diameter) and ``internal``."""

    label: str
    kind: str
    origin: np.ndarray
    direction: np.ndarray | None = None
    modifier: str = ""
    size: float | None = None
    boundary: float | None = None
    internal: bool | None = None
    feature: str = ""  # the datum feature's name, for messages
    targets: np.ndarray | None = None  # datum target points (k x 3) that establish this plane, or None

    @property
    def shift(self) -> float:
        """Datum shift allowance (diameter, mm): how far the datum feature's actual size departs from the
        boundary it is referenced at, in the direction that frees it; 0 at RFS or for a plane."""
        if self.modifier not in ("MMB", "LMB") or self.size is None or self.boundary is None:
            return 0.0
        grows = self.internal if self.modifier == "MMB" else not self.internal  # a hole above its MMB is freer
        return max(0.0, (self.size - self.boundary) if grows else (self.boundary - self.size))

    @property
    def text(self) -> str:
        mod = {"MMB": "(M)", "LMB": "(L)"}.get(self.modifier, "")
        return f"{self.label}{mod}"


def datum_from_feature(label: str, kind: str, geometry: dict[str, Any], *, modifier: str = "",
                       boundary: float | None = None, internal: bool | None = None, feature: str = "") -> Datum:
    """The datum a measured feature gives (``kind`` and ``geometry`` as in a fit summary): a plane from a
    plane, an axis from a cylinder / circle / cone / line, a point from a sphere or point.

    ``modifier`` "MMB" or "LMB" needs a datum feature of size (cylinder, circle, sphere) and its
    ``boundary`` diameter (the MMB: a hole's smallest, a pin's largest allowed size; the LMB the other).
    """
    label = str(label).strip().upper()
    if not label or not label.isalpha():
        raise DatumError(f"a datum label is a letter (A, B, C ...), got {label!r}")
    dkind = DATUM_KINDS.get(kind)
    if dkind is None:
        raise DatumError(f"a {kind} cannot be a datum feature; use a plane, cylinder, circle, cone, line, "
                         "sphere or point")
    modifier = (modifier or "").upper().replace("RFS", "").replace("RMB", "")
    if modifier not in MODIFIERS:
        raise DatumError(f"datum {label}: unknown modifier {modifier!r}; use MMB, LMB or none (RFS)")
    g = geometry
    size = float(g["radius"]) * 2.0 if "radius" in g else None
    if modifier and (size is None or kind not in ("cylinder", "circle", "sphere")):
        raise DatumError(f"datum {label} ({kind}) is not a feature of size: it cannot be referenced at {modifier}")
    if modifier and (boundary is None or not math.isfinite(float(boundary)) or float(boundary) <= 0):
        raise DatumError(f"datum {label} at {modifier} needs its boundary diameter (a positive number)")
    if modifier and internal is None:
        raise DatumError(f"datum {label} at {modifier}: say whether it is a hole (internal) or a pin (external)")
    if dkind == "plane":
        return Datum(label, "plane", _vec(g["point"], f"datum {label} point"),
                     _unit(g["normal"], f"datum {label} normal"), modifier, size, boundary, internal, feature)
    if dkind == "axis":
        origin = g.get("center", g.get("point", g.get("apex")))
        direction = g.get("normal") if kind == "circle" else g.get("direction")
        return Datum(label, "axis", _vec(origin, f"datum {label} point"), _unit(direction, f"datum {label} axis"),
                     modifier, size, None if boundary is None else float(boundary), internal, feature)
    origin = g.get("center", g.get("point"))
    return Datum(label, "point", _vec(origin, f"datum {label} point"), None, modifier, size,
                 None if boundary is None else float(boundary), internal, feature)


TARGETS_NEEDED = (3, 2, 1)  # target points of a datum plane as primary, secondary, tertiary


def datum_from_targets(label: str, points: Any, normal: Any, feature: str = "") -> Datum:
    """A datum plane established by datum target points (ISO 5459 / ASME Y14.5: A1 A2 A3 on the primary, B1 B2 on
    the secondary, C1 on the tertiary) rather than by the whole surface: three points give the plane through
    them; two the plane through them square to the primary (made so in :func:`build_drf`); one the plane through
    it square to both. ``normal``: the datum feature's (outward) normal, which gives the sense and, for one or
    two points, the approximate orientation."""
    label = str(label).strip().upper()
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not 1 <= len(pts) <= 3:
        raise DatumError(f"datum {label}: datum targets are 1, 2 or 3 points ({label}1 {label}2 {label}3), got "
                         f"{len(pts)}")
    if not np.all(np.isfinite(pts)) or np.abs(pts).max() > 1e9:
        raise DatumError(f"datum {label}: the target points must be finite coordinates, not too large")
    hint = _unit(normal, f"datum {label} normal")
    n = hint
    if len(pts) == 3:
        n = np.cross(pts[1] - pts[0], pts[2] - pts[0])
        span = max(float(np.ptp(pts, axis=0).max()), 1e-300)
        if float(np.linalg.norm(n)) < 1e-6 * span * span:
            raise DatumError(f"datum {label}: target points {label}1, {label}2, {label}3 lie in a line: they do not "
                             "define a plane; choose targets spread over the face")
        n = n / np.linalg.norm(n)
    elif len(pts) == 2:
        s = pts[1] - pts[0]
        if float(np.linalg.norm(s)) < COMMON_MIN_MM:
            raise DatumError(f"datum {label}: target points {label}1 and {label}2 are {np.linalg.norm(s):.3g} mm "
                             "apart: they must be apart along the face to orient the frame")
        s = s / np.linalg.norm(s)
        n = hint - (hint @ s) * s
        n = n / np.linalg.norm(n)
    if float(n @ hint) < 0:
        n = -n
    return Datum(label, "plane", pts.mean(axis=0), n, feature=feature, targets=pts)


def common_datum(a: Datum, b: Datum) -> Datum:
    """The common datum "A-B" of two datums from two features (see the module docstring); referenced RFS."""
    label = f"{a.label}-{b.label}"
    if a.modifier or b.modifier:
        raise DatumError(f"common datum {label} is referenced regardless of size here: define {a.label} and "
                         f"{b.label} without MMB / LMB")
    if a.kind != b.kind or a.kind == "point" or a.direction is None or b.direction is None:
        raise DatumError(f"common datum {label}: {a.label} is {'an' if a.kind == 'axis' else 'a'} {a.kind} and "
                         f"{b.label} {'an' if b.kind == 'axis' else 'a'} {b.kind}; a common datum is two axes "
                         "(coaxial features such as two bores) or two planes (parallel faces)")
    feature = f"{a.feature or a.label} and {b.feature or b.label}"
    if a.kind == "axis":
        d = b.origin - a.origin
        length = float(np.linalg.norm(d))
        if length < COMMON_MIN_MM:
            raise DatumError(f"common datum {label}: the centres of {a.label} and {b.label} are {length:.3g} mm "
                             "apart; the common axis runs through them, so they must be apart along it (two "
                             "features at the two ends of the axis)")
        u = d / length
        if float(u @ a.direction) < 0:
            u = -u
        for x in (a, b):
            ang = _angle_deg(x.direction, u)
            if ang > COMMON_DEG:
                raise DatumError(f"common datum {label}: {x.label} and the line through the centres of "
                                 f"{a.label} and {b.label} are {ang:.1f} degrees apart (at most {COMMON_DEG:g}): "
                                 "the features are not coaxial")
        return Datum(label, "axis", a.origin.copy(), u, feature=feature)
    ang = _angle_deg(a.direction, b.direction)
    if ang > COMMON_DEG:
        raise DatumError(f"common datum {label}: planes {a.label} and {b.label} are {ang:.1f} degrees apart (at "
                         f"most {COMMON_DEG:g}): they do not form one plane")
    nb = b.direction if float(a.direction @ b.direction) >= 0 else -b.direction
    n = a.direction + nb
    return Datum(label, "plane", 0.5 * (a.origin + b.origin), n / np.linalg.norm(n), feature=feature)


@dataclass(frozen=True)
class DRF:
    """A datum reference frame: ``rotation`` (3x3, columns X Y Z of the DRF in the measured coordinates),
    ``origin``, the ``datums`` in precedence order, and the DOF they constrain (``constrained``: names in
    DRF axes; ``translations``: an orthonormal basis (k x 3, measured coordinates) of the constrained
    translations)."""

    rotation: np.ndarray
    origin: np.ndarray
    datums: tuple[Datum, ...]
    constrained: tuple[str, ...]
    translations: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    z_set: bool = False
    x_set: bool = False

    @property
    def labels(self) -> str:
        """"A|B|C" with modifiers ((M), (L)), as in a feature control frame."""
        return "|".join(d.text for d in self.datums)

    @property
    def free(self) -> tuple[str, ...]:
        return tuple(n for n in DOF_NAMES if n not in self.constrained)

    def to_local(self, points: Any) -> np.ndarray:
        """Measured coordinates -> DRF coordinates (points, n x 3 or 3)."""
        p = np.asarray(points, dtype=np.float64)
        return (p - self.origin) @ self.rotation

    def vector_to_local(self, v: Any) -> np.ndarray:
        return np.asarray(v, dtype=np.float64) @ self.rotation

    def summary(self) -> dict[str, Any]:
        return {"datums": self.labels, "origin": self.origin.tolist(), "rotation": self.rotation.tolist(),
                "constrained": list(self.constrained), "free": list(self.free)}


def _project_out(vectors: list[np.ndarray], basis: np.ndarray) -> list[np.ndarray]:
    """The vectors with their components in span(basis) removed."""
    return [v - basis.T @ (basis @ v) if len(basis) else v for v in vectors]


def _extend_basis(basis: np.ndarray, candidates: list[np.ndarray], tol: float = 1e-6) -> np.ndarray:
    """New orthonormal directions the candidates add to ``basis`` (Gram-Schmidt, rank-revealing)."""
    out: list[np.ndarray] = []
    for v in candidates:
        w = v.copy()
        for b in list(basis) + out:
            w = w - (w @ b) * b
        n = float(np.linalg.norm(w))
        if n > tol:
            out.append(w / n)
    return np.array(out).reshape(-1, 3)


def _location_directions(d: Datum, z: np.ndarray | None) -> list[np.ndarray]:
    """Directions a datum locates: a plane its normal; an axis the two across it (across Z when the axis is
    the one Z came from or parallel to it: the simulated datum is perpendicular to the primary); a point all."""
    if d.kind == "plane":
        return [d.direction]  # type: ignore[list-item]
    if d.kind == "axis":
        u = d.direction if z is None or _angle_deg(d.direction, z) > PARALLEL_DEG else z
        f = frame_with_axis(u)  # type: ignore[arg-type]
        return [f[:, 0], f[:, 1]]
    return [np.eye(3)[i] for i in range(3)]


def _angle_deg(u: Any, v: Any) -> float:
    c = abs(float(np.dot(u, v)))
    return math.degrees(math.acos(min(1.0, c)))


def _why_nothing(d: Datum, before: list[Datum]) -> str:
    prev = "|".join(b.label for b in before)
    for b in before:
        if d.direction is not None and b.direction is not None and _angle_deg(d.direction, b.direction) <= PARALLEL_DEG:
            if d.kind == b.kind == "plane":
                return (f"datum {d.label} (plane) is parallel to datum {b.label}: it constrains nothing {prev} "
                        f"leave free; choose a datum feature at an angle to {b.label}")
            if d.kind == "axis" and b.kind == "axis":
                return (f"datum {d.label} (axis) is coaxial with or parallel to datum {b.label} and lies on the "
                        f"origin: it constrains nothing {prev} leave free")
    return (f"datum {d.label} ({d.kind}) constrains no degree of freedom that {prev} leave free; "
            "choose a datum feature that locates or orients what is still free")


def build_drf(datums: list[Datum] | tuple[Datum, ...]) -> DRF:
    """The datum reference frame of ``datums`` in precedence order (see the module docstring)."""
    datums = list(datums)
    if not datums:
        raise DatumError("a datum reference frame needs at least one datum")
    if len(datums) > 3:
        raise DatumError(f"a datum reference frame has at most three datums, got {len(datums)}")
    labels = [d.label for d in datums]
    if len(set(labels)) != len(labels):
        raise DatumError(f"datum {next(x for x in labels if labels.count(x) > 1)} is used twice in one frame")
    z: np.ndarray | None = None
    x: np.ndarray | None = None
    trans = np.zeros((0, 3))
    rows: list[tuple[np.ndarray, float]] = []  # (direction, value): direction . origin = value
    rot_names: list[str] = []
    for i, d in enumerate(datums):
        added = False
        if d.targets is not None and len(d.targets) != TARGETS_NEEDED[i]:
            rank = ("primary", "secondary", "tertiary")[i]
            raise DatumError(f"datum {d.label} has {len(d.targets)} target point(s): as the {rank} datum a plane "
                             f"needs {TARGETS_NEEDED[i]} (primary 3, secondary 2, tertiary 1)")
        if d.targets is not None and len(d.targets) == 2 and z is not None and x is None:
            # the secondary plane through both targets, square to the primary
            w = np.cross(d.targets[1] - d.targets[0], z)
            if float(np.linalg.norm(w)) > 1e-9:
                w = w / np.linalg.norm(w)
                d = replace(d, direction=w if float(w @ d.direction) >= 0 else -w)  # type: ignore[operator]
        # 1. orientation
        if d.direction is not None:
            if z is None:
                z, added = d.direction.copy(), True
                rot_names += ["Rx", "Ry"]
            elif x is None:
                w = d.direction - (d.direction @ z) * z
                if float(np.linalg.norm(w)) > math.sin(math.radians(PARALLEL_DEG)):
                    x, added = w / np.linalg.norm(w), True
                    rot_names.append("Rz")
        # 2. location: what the datum locates, within the translations still free
        # (a direction less than PARALLEL_DEG from those already constrained locates nothing reliably)
        new = _extend_basis(trans, _project_out(_location_directions(d, z), trans),
                            math.sin(math.radians(PARALLEL_DEG)))
        for n in new:
            rows.append((n, float(n @ d.origin)))
            added = True
        trans = np.vstack([trans, new]) if len(new) else trans
        # 3. clocking by a location off the origin
        if not len(new) and d.kind in ("axis", "point") and (z is None or x is None) and len(trans):
            origin = _solve_origin(rows, np.zeros(3))
            r = d.origin - origin
            if z is not None:
                r = r - (r @ z) * z
                if float(np.linalg.norm(r)) > COINCIDENT_MM:
                    x, added = r / np.linalg.norm(r), True
                    rot_names.append("Rz")
            elif len(trans) == 3 and float(np.linalg.norm(r)) > COINCIDENT_MM:
                z, added = r / np.linalg.norm(r), True
                rot_names += ["Rx", "Ry"]
        if not added:
            raise DatumError(_why_nothing(d, datums[:i]))
    origin = _solve_origin(rows, np.zeros(3))
    if z is None:
        rotation = np.eye(3)
    else:
        if x is None:  # rotation about Z free: X from the measured X (Y when Z is near X), continuous in Z, so
            # an actual frame and its nominal built from the same datums agree but for their tilt
            ref = np.eye(3)[0] if abs(float(z[0])) < 0.9 else np.eye(3)[1]
            w = ref - (ref @ z) * z
            xx = w / np.linalg.norm(w)
        else:
            xx = x
        rotation = np.column_stack([xx, np.cross(z, xx), z])
    names = [n for k, n in enumerate(("Tx", "Ty", "Tz"))
             if len(trans) and float(np.linalg.norm(trans @ rotation[:, k])) > 1 - 1e-9]
    return DRF(rotation, origin, tuple(datums), tuple(names + sorted(set(rot_names))), trans,
               z is not None, x is not None)


def _solve_origin(rows: list[tuple[np.ndarray, float]], start: np.ndarray) -> np.ndarray:
    """The point satisfying every location constraint, nearest ``start`` along what is free. The start is the
    coordinate origin, not a datum feature's point: an actual and a nominal frame of the same datums then have
    the same origin along the translations they leave free (a fitted plane's point is its hits' centroid, the
    nominal's anywhere on the face), so a profile's best fit in those DOF starts where the part is."""
    if not rows:
        return start.copy()
    A = np.array([r[0] for r in rows])
    b = np.array([r[1] for r in rows])
    delta, *_ = np.linalg.lstsq(A, b - A @ start, rcond=None)
    return start + delta
