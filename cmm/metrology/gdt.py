"""Geometric tolerances (ISO 1101 / ASME Y14.5) of measured features, with datum reference frames.

Every function is pure (numpy, trimesh for profiles) and returns a :class:`GdtResult`: the measured
``value`` (the width or diameter of the smallest zone of the tolerance's shape and orientation that contains
the feature), the stated ``tolerance``, a material-condition ``bonus``, the datum frame used (``drf``:
"A|B|C" with modifiers) and ``ok``. Features come as fit summaries (``kind`` + ``geometry`` dict, as
:meth:`cmm.metrology.features.FitResult.summary` gives) and their measured ``points``; datums as a
:class:`~cmm.metrology.datums.DRF`. The zones:

- form (no datum): flatness (two planes), straightness (cylinder), circularity (two concentric circles in
  the feature's plane), cylindricity (two coaxial cylinders): minimum zone;
- orientation: parallelism, perpendicularity, angularity (basic angle between the toleranced feature and
  the datum: planes and axes as drawn). A plane: two parallel planes at that angle to the datum direction
  (the DRF's Z); an axis: a cylinder at that angle containing the axis over the feature's length. The
  rotation about the datum direction is free (minimised) unless a ``nominal_direction`` in DRF
  coordinates and a DRF that fixes X say where it is;
- location: position of an axis (cylinder: over its length; circle: its centre in its plane) or centre
  (sphere, point: a spherical zone) as a diameter against its nominal; with a DRF the actual feature is
  expressed in the actual DRF and the nominal in the nominal DRF (built from the datum features' nominals),
  so the part is compared as if held on its datums; translations and rotations the DRF leaves free float
  (their deviation is not counted). Material condition (MMC/LMC): bonus = the departure of the actual size
  from the MMC (LMC) size. Datum shift: a datum feature of size at MMB/LMB lets the frame move by up to
  half its shift across its axis (or around its centre);
- composite position (ASME Y14.5, :func:`composite_position`): a pattern of parallel features; the upper tier
  is each feature's position to its datums, the lower tier the smallest zone diameter when the pattern's zones
  move together (translations, and the rotation about the pattern axis unless the lower datums fix it);
- concentricity / coaxiality: the diameter of the cylinder coaxial with the datum axis containing the
  feature's centre / axis; runout: circular (per section, radial: the range of the radius about the
  datum axis; axial: of the axial position) and total (all points);
- profile of a surface / a line: twice the largest distance of the points from the CAD mesh (zone equally
  disposed), or with an ``offset`` o (an unequally disposed zone, ISO 1101 "UZ"): twice the largest
  |d - o|, d the signed distance (+ outside the material); without datums the points are first fitted to
  the mesh (least squares, then minimum zone: the profile is then form only), with datums only in the DOF
  the frame leaves free. A line profile's points lie in one section; their fit without datums stays in that
  section's plane.

Refusals are :class:`GdtError` in words ("profile tolerance needs the part mesh").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import relations
from .datums import DRF, DatumError
from .fit_enclosing import min_enclosing_ball
from .fit_hull import min_width_direction
from .geom_basics import frame_with_axis

FORM = ("flatness", "straightness", "circularity", "cylindricity")
ORIENTATION = ("parallelism", "perpendicularity", "angularity")
CHARACTERISTICS = FORM + ORIENTATION + ("position", "concentricity", "coaxiality", "circular runout",
                                        "total runout", "profile of a surface", "profile of a line")
SYMBOLS = {"flatness": "⏥", "straightness": "⏤", "circularity": "○", "cylindricity": "⌭", "parallelism": "∥",
           "perpendicularity": "⟂", "angularity": "∠", "position": "⊕", "concentricity": "◎", "coaxiality": "◎",
           "circular runout": "↗", "total runout": "⌰", "profile of a surface": "⌓", "profile of a line": "⌒"}
NEEDS_DATUMS = ORIENTATION + ("concentricity", "coaxiality", "circular runout", "total runout")
AXIS_KINDS = ("cylinder", "cone", "line")


class GdtError(DatumError):
    """A geometric tolerance that cannot be evaluated, in an operator's words."""


@dataclass(frozen=True)
class GdtResult:
    characteristic: str
    value: float  # mm: zone width, or diameter for position / coaxiality
    tolerance: float  # the stated tolerance
    bonus: float = 0.0  # material-condition bonus added to the tolerance
    drf: str = ""  # "A|B|C" with modifiers; "" without datums
    material: str = ""  # "MMC" / "LMC" / "" (RFS)
    note: str = ""  # how it was measured: shift used, free DOF, zone shape
    parts: tuple[float, ...] = ()  # the values the value is the largest of (a position at each axis end), or ()

    @property
    def allowed(self) -> float:
        return self.tolerance + self.bonus

    @property
    def ok(self) -> bool:
        return bool(self.value <= self.allowed + 1e-12)

    @property
    def label(self) -> str:
        return f"{SYMBOLS.get(self.characteristic, '')} {self.characteristic}".strip()

    def summary(self) -> dict[str, Any]:
        return {"characteristic": self.characteristic, "value": self.value, "tolerance": self.tolerance,
                "bonus": self.bonus, "allowed": self.allowed, "ok": self.ok, "drf": self.drf,
                "material": self.material, "note": self.note}


def _points(points: Any, what: str, n: int = 1) -> np.ndarray:
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) < n:
        raise GdtError(f"{what} needs at least {n} measured points, got {len(p)}")
    if not np.all(np.isfinite(p)):
        raise GdtError(f"{what}: the points contain NaN or infinite coordinates")
    if np.abs(p).max() > 1e9:
        raise GdtError(f"{what}: coordinates too large")
    return p


def _check_tol(tolerance: float, what: str) -> float:
    t = float(tolerance)
    if not (math.isfinite(t) and t > 0):
        raise GdtError(f"the {what} tolerance must be a positive number of mm, got {tolerance!r}")
    return t


def _drf_text(drf: DRF | None) -> str:
    return "" if drf is None else drf.labels


# ---------------------------------------------------------------- form


def form(characteristic: str, points: Any, tolerance: float) -> GdtResult:
    """Flatness, straightness (3-D line: cylinder zone), circularity (points of one section), cylindricity."""
    funcs = {"flatness": relations.flatness, "straightness": relations.straightness,
             "circularity": relations.roundness, "cylindricity": relations.cylindricity}
    if characteristic not in funcs:
        raise GdtError(f"{characteristic} is not a form tolerance; use {', '.join(FORM)}")
    p = _points(points, characteristic, {"flatness": 3, "straightness": 2, "circularity": 3}.get(characteristic, 5))
    return GdtResult(characteristic, float(funcs[characteristic](p)), _check_tol(tolerance, characteristic),
                     note="minimum zone")


# ---------------------------------------------------------------- orientation


def _datum_direction(drf: DRF | None, what: str) -> tuple[np.ndarray, bool]:
    """The DRF's Z and whether it came from a plane (True) or an axis / points (False)."""
    if drf is None or not drf.z_set:
        raise GdtError(f"{what} needs a datum that sets a direction (a plane or an axis)")
    first = next(d for d in drf.datums if d.direction is not None) if any(
        d.direction is not None for d in drf.datums) else None
    return drf.rotation[:, 2], bool(first is not None and first.kind == "plane")


def axis_ends(geometry: dict[str, Any], points: Any) -> tuple[np.ndarray, np.ndarray]:
    """The ends of a feature's axis over its length: the axis (point, direction or apex, direction)
    between the extreme projections of its measured points."""
    o = np.asarray(geometry.get("point", geometry.get("apex", geometry.get("center"))), dtype=np.float64)
    u = np.asarray(geometry.get("direction", geometry.get("normal")), dtype=np.float64)
    u = u / np.linalg.norm(u)
    t = (np.asarray(points, dtype=np.float64).reshape(-1, 3) - o) @ u
    return o + t.min() * u, o + t.max() * u


def orientation(characteristic: str, kind: str, geometry: dict[str, Any], points: Any, drf: DRF,
                tolerance: float, angle_deg: float | None = None, nominal_direction: Any = None) -> GdtResult:
    """Parallelism (angle 0), perpendicularity (90) or angularity (``angle_deg``, the basic angle between
    the toleranced feature and the datum as drawn) of a plane (its points) or an axis (cylinder, cone,
    line: over the length its points span)."""
    if characteristic not in ORIENTATION:
        raise GdtError(f"{characteristic} is not an orientation tolerance; use {', '.join(ORIENTATION)}")
    alpha = {"parallelism": 0.0, "perpendicularity": 90.0}.get(characteristic, angle_deg)
    if alpha is None or not (0.0 <= float(alpha) <= 90.0):
        raise GdtError("angularity needs the basic angle in degrees (0 to 90)")
    tol = _check_tol(tolerance, characteristic)
    z, datum_plane = _datum_direction(drf, characteristic)
    if kind == "plane":
        feature_plane = True
    elif kind in AXIS_KINDS:
        feature_plane = False
    else:
        raise GdtError(f"{characteristic} of a {kind}: measure a plane or an axis (cylinder, cone, line)")
    beta = math.radians(alpha if feature_plane == datum_plane else 90.0 - float(alpha))
    x = drf.rotation[:, 0]
    y = drf.rotation[:, 1]
    fixed = None
    if nominal_direction is not None and drf.x_set:
        nd = np.asarray(nominal_direction, dtype=np.float64)
        fixed = math.atan2(float(nd[1]), float(nd[0]))
    if feature_plane:
        p = _points(points, characteristic, 3)

        def width(phi: float) -> float:
            n = math.cos(beta) * z + math.sin(beta) * (math.cos(phi) * x + math.sin(phi) * y)
            h = p @ n
            return float(h.max() - h.min())

        if abs(beta) < 1e-12:
            value, how = width(0.0), "two planes parallel to the datum"
        elif fixed is not None:
            value, how = width(fixed), "two planes at the basic angle, oriented by the DRF"
        elif abs(beta - math.pi / 2) < 1e-12:
            flat = p @ np.column_stack([x, y])
            value, how = float(min_width_direction(flat - flat.mean(axis=0))[0]), "two planes, rotation free"
        else:
            value, how = _min_over_azimuth(width), "two planes at the basic angle, rotation free"
    else:
        e1, e2 = axis_ends(geometry, _points(points, characteristic, 2))
        seg = e2 - e1
        length = float(np.linalg.norm(seg))
        u = seg / length if length > 0 else np.asarray(geometry["direction"], float)
        theta = math.acos(min(1.0, abs(float(u @ z))))
        if fixed is not None:
            w = math.cos(beta) * z + math.sin(beta) * (math.cos(fixed) * x + math.sin(fixed) * y)
            value = float(np.linalg.norm(seg - (seg @ w) * w))
        else:
            value = length * math.sin(abs(theta - beta))
        how = f"cylinder zone over the axis length {length:.3f} mm"
    return GdtResult(characteristic, value, tol, drf=drf.labels, note=how)


def _min_over_azimuth(f: Any) -> float:
    """Minimum of a zone width over the rotation about the datum direction: a 1-degree scan, then golden
    section search in the best bracket."""
    phis = np.radians(np.arange(0.0, 360.0, 1.0))
    vals = [f(float(a)) for a in phis]
    k = int(np.argmin(vals))
    a, b = float(phis[k]) - math.radians(1.0), float(phis[k]) + math.radians(1.0)
    g = (math.sqrt(5) - 1) / 2
    for _ in range(60):
        c, d = b - g * (b - a), a + g * (b - a)
        if f(c) < f(d):
            b = d
        else:
            a = c
    return min(float(vals[k]), f((a + b) / 2))


# ---------------------------------------------------------------- location


def material_bonus(material: str, actual_size: float, size_limits: tuple[float, float], internal: bool) -> float:
    """Bonus tolerance (mm) at MMC / LMC: how far the actual size departs from that condition's size,
    within the size limits (low, high diameters)."""
    low, high = float(size_limits[0]), float(size_limits[1])
    if not (low <= high):
        raise GdtError(f"size limits must be (low, high) diameters, got {size_limits}")
    s = min(max(float(actual_size), low), high)
    if material == "MMC":
        return s - low if internal else high - s
    if material == "LMC":
        return high - s if internal else s - low
    return 0.0


def _location(kind: str, g: dict[str, Any]) -> tuple[np.ndarray, np.ndarray | None]:
    if kind in ("cylinder", "line"):
        return np.asarray(g["point"], float), np.asarray(g["direction"], float)
    if kind == "cone":
        return np.asarray(g["apex"], float), np.asarray(g["direction"], float)
    if kind == "circle":
        return np.asarray(g["center"], float), np.asarray(g["normal"], float)
    if kind in ("sphere", "point"):
        return np.asarray(g.get("center", g.get("point")), float), None
    raise GdtError(f"position of a {kind}: measure a cylinder, circle, cone, sphere or point")


def _float_free(drf: DRF, act: np.ndarray, nom_ref: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Actual points (DRF coordinates) with the DRF's free rotation (about Z, or any with no Z) and free
    translations used to bring them onto the nominal reference point (their deviation does not count)."""
    notes = []
    ref = act.mean(axis=0)
    if "Rz" not in drf.constrained and drf.z_set:
        a0, a1 = math.atan2(ref[1], ref[0]), math.atan2(nom_ref[1], nom_ref[0])
        if math.hypot(ref[0], ref[1]) > 1e-9 and math.hypot(nom_ref[0], nom_ref[1]) > 1e-9:
            c, s = math.cos(a1 - a0), math.sin(a1 - a0)
            act = act @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        notes.append("rotation about the datum axis free")
    for k, t in enumerate(("Tx", "Ty", "Tz")):
        if t not in drf.constrained:
            act = act.copy()
            act[:, k] += nom_ref[k] - act.mean(axis=0)[k]
            notes.append(f"{t} free")
    return act, notes


def position(kind: str, geometry: dict[str, Any], nominal: dict[str, Any], tolerance: float, *,
             drf: DRF | None = None, nominal_drf: DRF | None = None, points: Any = None,
             material: str = "", size_limits: tuple[float, float] | None = None,
             internal: bool | None = None) -> GdtResult:
    """True position (diameter) of an axis or centre against its nominal (see the module docstring).

    ``nominal`` holds the nominal location (``point``/``center``/``apex`` and ``direction``/``normal``) in
    the coordinates of ``nominal_drf``'s datum features; with a ``drf`` and no ``nominal_drf`` the nominal is
    in DRF coordinates (basic dimensions). ``points``: the feature's measured points (a cylinder's position is
    checked at both ends of its length). ``material`` "MMC" / "LMC" with ``size_limits`` (low, high
    diameter) and ``internal`` (hole True, pin False) gives a bonus."""
    tol = _check_tol(tolerance, "position")
    act_o, act_u = _location(kind, geometry)
    nom_o = np.asarray(nominal.get("point", nominal.get("center", nominal.get("apex"))), dtype=np.float64)
    nom_u = nominal.get("direction", nominal.get("normal"))
    if nom_o.shape != (3,) or not np.all(np.isfinite(nom_o)):
        raise GdtError("position needs the nominal location (three finite coordinates)")
    ends = np.array([act_o])
    if act_u is not None and kind != "circle" and points is not None:
        ends = np.array(axis_ends(geometry, _points(points, "position", 2)))
    notes: list[str] = []
    if drf is not None:
        ends = drf.to_local(ends)
        if nominal_drf is not None:
            nom_o = nominal_drf.to_local(nom_o)
            nom_u = None if nom_u is None else nominal_drf.vector_to_local(np.asarray(nom_u, float))
        ends, notes = _float_free(drf, ends, nom_o)
    if nom_u is None and act_u is not None and kind != "circle":
        raise GdtError("position of an axis needs the nominal axis direction")
    dev = ends - nom_o
    if nom_u is not None and kind not in ("sphere", "point"):
        n = np.asarray(nom_u, float) / np.linalg.norm(nom_u)
        dev = dev - np.outer(dev @ n, n)  # the zone is a cylinder about the nominal axis
    shift = 0.0
    if drf is not None:
        dev, shift = _datum_shift(drf, dev)
        if shift:
            notes.append(f"datum shift up to ⌀{shift:.4f} used")
    ends_value = 2.0 * np.linalg.norm(dev, axis=1)
    value = float(ends_value.max())
    bonus = 0.0
    if material:
        if material not in ("MMC", "LMC"):
            raise GdtError(f"unknown material condition {material!r}; use MMC, LMC or none (RFS)")
        if size_limits is None or internal is None or "radius" not in geometry:
            raise GdtError(f"position at {material} needs a feature of size, its size limits and whether it is "
                           "a hole or a pin")
        bonus = material_bonus(material, 2.0 * float(geometry["radius"]), size_limits, internal)
        notes.append(f"actual size ⌀{2.0 * float(geometry['radius']):.4f}, bonus {bonus:.4f}")
    zone = "spherical zone" if kind in ("sphere", "point") else "cylindrical zone"
    return GdtResult("position", value, tol, bonus, _drf_text(drf), material, "; ".join([zone] + notes),
                     parts=tuple(float(v) for v in ends_value) if len(ends_value) > 1 else ())


def _datum_shift(drf: DRF, dev: np.ndarray) -> tuple[np.ndarray, float]:
    """Deviations (DRF coordinates) after the frame moves within the datum features' shift: each datum of
    size at MMB/LMB may move up to half its shift across its axis (all ways for a point)."""
    total = 0.0
    for d in drf.datums:
        s = d.shift
        if s <= 0 or d.kind == "plane":
            continue
        total += s
        if d.kind == "axis":
            u = drf.vector_to_local(d.direction)
            basis = frame_with_axis(u)[:, :2].T
        else:
            basis = np.eye(3)
        mean = dev.mean(axis=0)
        move = basis.T @ (basis @ mean)
        norm = float(np.linalg.norm(move))
        if norm > s / 2:
            move = move * (s / 2 / norm)
        dev = dev - move
    return dev, total


def _pattern_points(items: list[tuple[str, dict[str, Any], dict[str, Any], Any]], drf: DRF, ndrf: DRF | None,
                    what: str) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """Per feature of a pattern: its actual axis ends (or centre) in ``drf`` coordinates and its nominal location
    in ``ndrf`` coordinates (``drf``'s when None), and the pattern's common nominal axis direction (DRF)."""
    acts, noms, dirs = [], [], []
    for kind, g, nominal, pts in items:
        o, u = _location(kind, g)
        ends = np.array([o])
        if u is not None and kind != "circle" and pts is not None and len(pts):
            ends = np.array(axis_ends(g, _points(pts, what, 2)))
        n_o = np.asarray(nominal.get("point", nominal.get("center", nominal.get("apex"))), dtype=np.float64)
        n_u = nominal.get("direction", nominal.get("normal"))
        if n_u is None:
            raise GdtError(f"{what}: every feature of the pattern needs its nominal axis direction")
        frame = ndrf or drf
        acts.append(drf.to_local(ends))
        noms.append(frame.to_local(n_o))
        v = frame.vector_to_local(np.asarray(n_u, dtype=np.float64))
        dirs.append(v / np.linalg.norm(v))
    axis = dirs[0]
    for v in dirs[1:]:
        if math.degrees(math.acos(min(1.0, abs(float(v @ axis))))) > 0.5:
            raise GdtError(f"{what}: the features of the pattern are not parallel (their nominal axes differ by "
                           "more than 0.5 degrees); a composite position frame here needs a pattern of parallel "
                           "holes or pins")
    return acts, noms, axis


def composite_position(items: list[tuple[str, dict[str, Any], dict[str, Any], Any]], upper: float, lower: float,
                       drf: DRF, ndrf: DRF | None, lower_drf: DRF, lower_ndrf: DRF | None,
                       names: list[str]) -> tuple[list[GdtResult], GdtResult]:
    """A composite position frame (ASME Y14.5) on a pattern of parallel features ``items`` (kind, geometry,
    nominal, points): the upper tier (pattern-locating zone, PLTZF) is each feature's position against ``drf``
    (``upper``, as :func:`position`); the lower tier (feature-relating zone, FRTZF) lets the pattern's zones
    move together: every translation is free and the rotation about the pattern's axis too unless the lower
    tier's datums (``lower_drf``, orientation only) fix it. Its value is the smallest diameter such that one
    pattern of zones, so moved, holds every feature's axis ends: the minimum enclosing circle (exact) of the
    ends' deviations across the axis, minimised over the free rotation. Returns (upper per feature, lower)."""
    what = "composite position"
    if len(items) < 2:
        raise GdtError(f"{what} is a tolerance on a pattern: give two or more features")
    if not lower < upper:
        raise GdtError(f"{what}: the feature-relating (lower) tolerance {lower:g} must be smaller than the "
                       f"pattern-locating (upper) one {upper:g}")
    upper_rows = [position(kind, g, nominal, upper, drf=drf, nominal_drf=ndrf, points=pts)
                  for kind, g, nominal, pts in items]
    upper_rows = [GdtResult(r.characteristic, r.value, r.tolerance, r.bonus, r.drf, r.material,
                            f"pattern-locating tier (PLTZF); {r.note}", r.parts) for r in upper_rows]
    acts, noms, axis = _pattern_points(items, lower_drf, lower_ndrf, what)
    f = frame_with_axis(axis)
    e = f[:, :2]
    a2 = [x @ e for x in acts]  # across the pattern's axis
    n2 = [x @ e for x in noms]
    centre = np.mean(n2, axis=0)
    rz_free = "Rz" not in lower_drf.constrained

    def spread(phi: float) -> float:
        c, s = math.cos(phi), math.sin(phi)
        rot = np.array([[c, -s], [s, c]])
        dev = np.vstack([(a - centre) @ rot.T + centre - n for a, n in zip(a2, n2)])
        return float(min_enclosing_ball(dev)[1])

    if rz_free:
        from scipy.optimize import minimize_scalar

        reach = max(float(np.linalg.norm(np.vstack(a2) - np.vstack([np.repeat(n[None], len(a), 0)
                                                                    for a, n in zip(a2, n2)]), axis=1).max()), 1e-9)
        size = max(float(np.linalg.norm(np.vstack(n2) - centre, axis=1).max()), 1e-9)
        bound = min(0.5, 4.0 * reach / size)  # rotations beyond this move some feature more than it deviates
        grid = np.linspace(-bound, bound, 41)
        k = int(np.argmin([spread(float(p)) for p in grid]))
        lo, hi = float(grid[max(k - 1, 0)]), float(grid[min(k + 1, len(grid) - 1)])
        res = minimize_scalar(spread, bounds=(lo, hi), method="bounded", options={"xatol": 1e-12})
        radius = min(float(res.fun), spread(float(grid[k])))
        how = "translations and the rotation about the pattern axis free"
    else:
        radius = spread(0.0)
        how = "translations free, orientation by the datums"
    lower_row = GdtResult("position", 2.0 * radius, lower, drf=lower_drf.labels,
                          note=f"feature-relating tier (FRTZF) of {', '.join(names)}: {how}")
    return upper_rows, lower_row


def coaxiality(characteristic: str, kind: str, geometry: dict[str, Any], drf: DRF, tolerance: float,
               points: Any = None) -> GdtResult:
    """Concentricity (a circle's or sphere's centre) or coaxiality (an axis over its length): the diameter
    of the zone coaxial with the datum axis (the DRF's Z through its origin) containing it."""
    tol = _check_tol(tolerance, characteristic)
    _datum_axis(drf, characteristic)
    o, u = _location(kind, geometry)
    if u is not None and kind not in ("circle",) and points is not None:
        ends = np.array(axis_ends(geometry, _points(points, characteristic, 2)))
    else:
        ends = o[None, :]
    local = drf.to_local(ends)
    ends_value = 2.0 * np.hypot(local[:, 0], local[:, 1])
    return GdtResult(characteristic, float(ends_value.max()), tol, drf=drf.labels,
                     note="zone coaxial with the datum axis",
                     parts=tuple(float(v) for v in ends_value) if len(ends_value) > 1 else ())


def _datum_axis(drf: DRF, what: str) -> None:
    if drf is None or not drf.z_set or not {"Tx", "Ty"} <= set(drf.constrained):
        raise GdtError(f"{what} needs a datum axis: the frame {_drf_text(drf) or '(none)'} does not locate one")


def runout(characteristic: str, points: Any, drf: DRF, tolerance: float, direction: str = "radial") -> GdtResult:
    """Circular runout (per section) or total runout of surface points about the datum axis; ``direction``
    "radial" (a surface around the axis) or "axial" (a face across it)."""
    if characteristic not in ("circular runout", "total runout"):
        raise GdtError(f"{characteristic} is not a runout; use circular runout or total runout")
    if direction not in ("radial", "axial"):
        raise GdtError(f"runout direction is radial or axial, got {direction!r}")
    tol = _check_tol(tolerance, characteristic)
    _datum_axis(drf, characteristic)
    local = drf.to_local(_points(points, characteristic, 3))
    r = np.hypot(local[:, 0], local[:, 1])
    z = local[:, 2]
    measured, across = (r, z) if direction == "radial" else (z, r)
    if characteristic == "total runout":
        value = float(np.ptp(measured))
        how = f"total {direction} runout over {len(measured)} points"
    else:
        groups = _sections(across)
        value = max(float(np.ptp(measured[g])) for g in groups)
        how = f"circular {direction} runout, worst of {len(groups)} section(s)"
    return GdtResult(characteristic, value, tol, drf=drf.labels, note=how)


def _sections(t: np.ndarray) -> list[np.ndarray]:
    """Indices of points grouped into sections along t (a gap wider than 0.2 mm or 2 % of the span)."""
    order = np.argsort(t)
    gap = max(0.2, 0.02 * float(np.ptp(t)))
    cuts = np.nonzero(np.diff(t[order]) > gap)[0] + 1
    return [g for g in np.split(order, cuts) if len(g)]


# ---------------------------------------------------------------- profile


def profile(characteristic: str, points: Any, mesh: Any, pose: Any, tolerance: float, *, drf: DRF | None = None,
            nominal_drf: DRF | None = None, iterations: int = 30, offset: float = 0.0) -> GdtResult:
    """Profile of a surface or of a line against the CAD ``mesh`` (part coordinates) at ``pose`` (part ->
    measured coordinates): twice the largest |distance| of the points from the surface after the fit the
    datums allow (none: a best fit in all DOF, a line's in its section plane).

    ``offset`` o (mm) makes the zone unequally disposed, as ISO 1101's "UZ": the zone's mid surface is the
    nominal surface moved by o along its outward normal (+ towards the outside of the material, - into it);
    the value is twice the largest |d - o| of the signed distances d (+ outside), so the points lie within
    [o - t/2, o + t/2] of the surface when the value is at most the tolerance t. ASME Y14.5's "U u" (u of the
    zone t outside the material) is o = u - t/2; o = +-t/2 puts the whole zone outside (inside)."""
    if characteristic not in ("profile of a surface", "profile of a line"):
        raise GdtError(f"{characteristic} is not a profile; use profile of a surface or profile of a line")
    if mesh is None:
        raise GdtError("profile tolerance needs the part mesh: load the part (CAD) the points were measured on")
    tol = _check_tol(tolerance, characteristic)
    o = check_offset(offset, tol)
    from .mesh import closest_points, surface_index
    from .transform import as_pose, invert, rotation_from_rotvec

    p = _points(points, characteristic, 3)
    T = as_pose(pose)
    to_part = invert(T)
    # the points in a working frame W whose axes are the DRF's (or the measured ones), and W -> part
    if drf is not None:
        local = drf.to_local(p)
        ndrf = nominal_drf or drf
        w_to_meas = np.eye(4)
        w_to_meas[:3, :3], w_to_meas[:3, 3] = ndrf.rotation, ndrf.origin
        free = [k for k, n in enumerate(("Tx", "Ty", "Tz", "Rx", "Ry", "Rz")) if n not in drf.constrained]
    else:
        local, w_to_meas = p.copy(), np.eye(4)
        free = list(range(6))
        if characteristic == "profile of a line":
            n = relations.fit_criteria.fit("plane", p, "ls").normal if len(p) >= 3 else np.array([0, 0, 1.0])
            f = frame_with_axis(np.asarray(n, float))
            w_to_meas[:3, :3] = f
            local = p @ f
            free = [0, 1, 5]  # in the section plane: two translations and the rotation about its normal
    M = to_part @ w_to_meas
    index = surface_index(mesh)
    def linearised(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Signed distances of the points (working frame), d(distance)/d(free DOF), and the turning centre."""
        qp = q @ M[:3, :3].T + M[:3, 3]
        cp = closest_points(mesh, qp, index)
        nrm = cp.normals @ M[:3, :3]  # part -> working frame
        c = q.mean(axis=0) if drf is None else np.zeros(3)  # a DRF's free rotations turn about its origin
        signed = np.einsum("ij,ij->i", qp - cp.points, cp.normals)
        return np.sign(signed) * cp.distances - o, np.c_[nrm, np.cross(q - c, nrm)][:, free], c

    def moved(q: np.ndarray, step: np.ndarray, c: np.ndarray) -> np.ndarray:
        full = np.zeros(6)
        full[free] = step
        return (q - c) @ rotation_from_rotvec(full[3:]).T + c + full[:3]

    q = local.copy()
    lever = max(1.0, float(np.linalg.norm(q - q.mean(axis=0), axis=1).max()))  # mm per rad of a free turn
    for _ in range(iterations if free else 0):  # least squares (point to plane ICP) in the free DOF
        d, A, c = linearised(q)
        B = _live_dof(A, free, lever)
        if not B.shape[1]:
            break
        z, *_ = np.linalg.lstsq(A @ B, -d, rcond=None)
        step = B @ z
        q2 = moved(q, step, c)
        if np.linalg.norm(linearised(q2)[0]) > np.linalg.norm(d) + 1e-12:
            break
        q = q2
        if np.abs(z).max() < 1e-10:
            break
    d, A, c = linearised(q)
    for _ in range(iterations if free else 0):  # then minimum zone: the largest |distance| as small as it goes
        B = _live_dof(A, free, lever)
        z = _minimax_step(d, A @ B)
        if z is None:
            break
        step = B @ z
        q2 = moved(q, step, c)
        d2, A2, c2 = linearised(q2)
        if np.abs(d2).max() >= np.abs(d).max() - 1e-12:
            break
        q, d, A, c = q2, d2, A2, c2
    value = 2.0 * float(np.abs(d).max())
    how = ("best fit to the CAD, minimum zone (form only)" if drf is None else
           "located by the datums" + (f"; {', '.join(n for n in ('Tx', 'Ty', 'Tz', 'Rx', 'Ry', 'Rz') if n not in drf.constrained)} free"
                                      if len(free) else ""))
    how += f"; deviations {d.min() + o:+.4f} .. {d.max() + o:+.4f} mm"
    if o:
        how += f"; zone offset {o:+.4f} mm (UZ), {o - tol / 2:+.4f} .. {o + tol / 2:+.4f} mm"
    return GdtResult(characteristic, value, tol, drf=_drf_text(drf), note=how)


def check_offset(offset: Any, tolerance: float) -> float:
    """A profile zone's offset (mm, ISO 1101 UZ), checked: a finite number; 0 is the equally disposed zone."""
    try:
        o = float(offset or 0.0)
    except (TypeError, ValueError):
        raise GdtError(f"a profile zone offset (UZ) is a number in mm, got {offset!r}") from None
    if not math.isfinite(o):
        raise GdtError(f"a profile zone offset (UZ) is a finite number in mm, got {offset!r}")
    if abs(o) > tolerance / 2.0 + 1e-12:
        raise GdtError(f"the zone offset {o:+g} moves the profile zone of {tolerance:g} off the nominal surface: "
                       f"use an offset within +-{tolerance / 2.0:g} (+ towards the outside of the material)")
    return o


def _live_dof(A: np.ndarray, free: list[int], lever: float) -> np.ndarray:
    """The combinations of the free DOF the distances respond to (geom_basics.live_dof): a datum tilted by
    0.01 deg made a translation along the face a DOF with a 1e-4 effect, and the fit slid the points thousands
    of mm along it (2.1e12 mm profiles)."""
    from .geom_basics import live_dof

    return live_dof(A, np.array([1.0 if k < 3 else lever for k in free]))


def _minimax_step(d: np.ndarray, A: np.ndarray, reach: float = 1.0) -> np.ndarray | None:
    """The step x (within +-reach, the columns of A scaled to mm) minimising max |d + A x| (a linear program),
    or None."""
    from scipy.optimize import linprog

    n, k = A.shape
    if k == 0:
        return None
    cost = np.r_[np.zeros(k), 1.0]
    a_ub = np.block([[A, -np.ones((n, 1))], [-A, -np.ones((n, 1))]])
    res = linprog(cost, A_ub=a_ub, b_ub=np.r_[-d, d], bounds=[(-reach, reach)] * k + [(0, None)], method="highs")
    return res.x[:k] if res.status == 0 else None
