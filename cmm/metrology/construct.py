"""Constructed features: intersection, distance, angle and mid-point of measured features.

Operands are (kind, geometry) pairs as fitted features record them
(``plane``: point, normal; ``circle``: center, normal, radius; ``cylinder``,
``line``: point, direction; ``cone``: apex, direction; ``sphere``: center;
``point``: point). The same construction applied to the operands' nominals
gives the constructed feature's nominal, so a distance between two bores is
toleranced against the drawing's distance.

- ``intersection``: plane x plane -> line; axis x plane -> point (an axis is a
  line, cylinder, cone or circle normal through its centre);
- ``distance``: between two point-like features (centres, points, apexes:
  3-D), a point-like feature and a plane, a point-like feature and an axis,
  two planes (a step height: from the centroid of the second plane
  perpendicular to the first, the angle between them given with it and a
  warning past ``STEP_ANGLE_WARN_DEG``), an axis and a plane (from the axis's
  location point perpendicular to the plane, the same warning when the axis
  is not parallel to the plane), two axes. Two parallel axes (cylinders, circles,
  lines, cones within ``PARALLEL_DEG``; ISO / PC-DMIS): the axis-to-axis
  distance between their location points (the foot of the data centroid on
  the axis; a circle's centre) in the plane of the alignment (perpendicular to
  its Z, when the axes run along Z within ``WORKPLANE_DEG``), else
  perpendicular to the mean axis; ``three_d`` asks for the latter always.
  Skew axes: the shortest distance between them. The projection used is named
  in the result (``projection``). The shortest distance of two nearly
  parallel axes is not their distance: it is measured along their common
  perpendicular, whose direction the axes' tiny tilts decide (43.86 mm
  between bore and boss read 41.01 that way);
- ``angle``: degrees in [0, 90]: between two planes (their normals), two
  axes, or an axis and a plane (the axis against the plane: 90 minus its
  angle to the normal), 3-D;
- ``midpoint``: the point half-way between two point-like features.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np

from . import relations as rel
from .features import FitError

OPERATIONS = ("intersection", "distance", "angle", "midpoint")
POINT_LIKE = ("point", "circle", "sphere")
AXIS_LIKE = ("line", "cylinder", "cone", "circle")


@dataclass
class Constructed:
    """A constructed feature: ``kind`` "point" / "line" (geometry) or "distance" / "angle" (``value``)."""

    kind: str
    geometry: dict[str, Any] = field(default_factory=dict)
    value: float | None = None  # mm for a distance, degrees for an angle
    projection: str = ""  # how a distance or angle was taken (the plane it was projected into, or 3-D)
    warning: str = ""  # a distance whose operands are further from parallel than STEP_ANGLE_WARN_DEG, in words
    # its expanded uncertainty from the operands' budgets ({"U", "k", "u_c", "note"}) or why it has none
    # ({"why"}): cmm.metrology.uncertainty_construct
    uncertainty: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, **self.geometry}
        if self.value is not None:
            out["value"] = self.value
        if self.projection:
            out["projection"] = self.projection
        if self.warning:
            out["warning"] = self.warning
        if self.uncertainty:
            out["uncertainty"] = dict(self.uncertainty)
        return out


PARALLEL_DEG = 5.0  # axes closer to parallel than this have an axis-to-axis distance
WORKPLANE_DEG = 10.0  # parallel axes this close to the alignment's Z are measured in its XY plane
# a step height (plane to plane, axis to plane) between features further from parallel than this is reported
# with a warning: the distance then depends on where it is taken (0.5 deg over a 20 mm face: 0.17 mm)
STEP_ANGLE_WARN_DEG = 0.5


def _step_warning(angle_deg: float, what: str) -> str:
    if angle_deg <= STEP_ANGLE_WARN_DEG:
        return ""
    return (f"{what} are {angle_deg:.3f} deg from parallel (more than {STEP_ANGLE_WARN_DEG:g} deg): the distance "
            "is taken at the centroid and varies across the face")


def _unit(v: Any) -> np.ndarray:
    v = np.asarray(v, float).reshape(3)
    return v / np.linalg.norm(v)


def _axis_distance(a: tuple[str, dict[str, Any]], b: tuple[str, dict[str, Any]], workplane: Any,
                   three_d: bool) -> tuple[float, str]:
    """Distance between two axes (see the module doc) and the projection it was taken in."""
    (ka, ga), (kb, gb) = a, b
    pa, ua = _location(ka, ga), _unit(_direction_of(ka, ga))
    pb, ub = _location(kb, gb), _unit(_direction_of(kb, gb))
    if math.degrees(rel.angle_between(ua, ub)) > PARALLEL_DEG and \
            math.degrees(rel.angle_between(ua, -ub)) > PARALLEL_DEG:
        return rel.distance_line_line(_ns(ka, ga), _ns(kb, gb)), "3-D, shortest distance between the skew axes"
    mean = _unit(ua + (ub if ua @ ub >= 0 else -ub))
    d = pb - pa
    if not three_d and workplane is not None:
        w = _unit(workplane)
        if math.degrees(min(rel.angle_between(mean, w), rel.angle_between(mean, -w))) <= WORKPLANE_DEG:
            v = d - (d @ w) * w
            return float(np.linalg.norm(v)), "axis to axis in the alignment's XY plane (perpendicular to its Z)"
    v = d - (d @ mean) * mean
    return float(np.linalg.norm(v)), "axis to axis, 3-D, perpendicular to the mean axis"


def _location(kind: str, g: dict[str, Any]) -> np.ndarray:
    """A feature's location point: circle and sphere centre, else ``point`` (cones: apex without one)."""
    if kind in ("circle", "sphere"):
        return np.asarray(g["center"], float)
    return np.asarray(g["point"] if "point" in g else g["apex"], float)


def _ns(kind: str, g: dict[str, Any]) -> SimpleNamespace:
    ns = SimpleNamespace(**{k: np.asarray(v, float) if isinstance(v, (list, tuple, np.ndarray)) else v
                            for k, v in g.items()})
    if kind == "circle" and not hasattr(ns, "direction"):
        ns.direction, ns.point = ns.normal, ns.center  # a circle's axis
    if kind == "cone" and not hasattr(ns, "point"):
        ns.point = ns.apex
    return ns


def _point_of(kind: str, g: dict[str, Any]) -> np.ndarray:
    if kind in ("circle", "sphere"):
        return np.asarray(g["center"], float)
    if kind == "cone":
        return np.asarray(g["apex"], float)
    return np.asarray(g["point"], float)


def _direction_of(kind: str, g: dict[str, Any]) -> np.ndarray:
    if kind == "plane" or (kind == "circle" and "direction" not in g):
        return np.asarray(g["normal"], float)
    if "direction" in g:
        return np.asarray(g["direction"], float)
    raise FitError(f"a {kind} has no direction for an angle")


def construct(operation: str, a: tuple[str, dict[str, Any]], b: tuple[str, dict[str, Any]], *,
              workplane: Any = None, three_d: bool = False) -> Constructed:
    """Construct ``operation`` from two (kind, geometry) operands; FitError in words when they do not combine.

    ``workplane``: the alignment's Z (machine coordinates), whose XY plane a distance between parallel axes
    along it is measured in; ``three_d``: measure such distances in 3-D instead (see the module doc)."""
    if operation not in OPERATIONS:
        raise FitError(f"unknown construction {operation!r}; choose one of {', '.join(OPERATIONS)}")
    (ka, ga), (kb, gb) = a, b
    if operation == "angle":
        ang = rel.angle_between(_direction_of(ka, ga), _direction_of(kb, gb))
        ang = math.degrees(min(ang, math.pi - ang))
        if (ka == "plane") != (kb == "plane"):  # an axis and a plane: the axis against the plane, not its normal
            axis_kind = kb if ka == "plane" else ka
            return Constructed("angle", value=90.0 - ang,
                               projection=f"3-D, between the axis of the {axis_kind} and the plane, 0 to 90 degrees")
        what = {"plane": "normal", "circle": "normal"}
        return Constructed("angle", value=ang,
                           projection=f"3-D, between the {what.get(ka, 'axis')} of the {ka} and the "
                                      f"{what.get(kb, 'axis')} of the {kb}, 0 to 90 degrees")
    if operation == "midpoint":
        if ka not in POINT_LIKE + ("cone",) or kb not in POINT_LIKE + ("cone",):
            raise FitError("a mid-point needs two points, circles or spheres (their centres)")
        return Constructed("point", {"point": ((_point_of(ka, ga) + _point_of(kb, gb)) / 2).tolist()})
    if operation == "intersection":
        if ka == "plane" and kb == "plane":
            axis = rel.intersect_plane_plane(_ns(ka, ga), _ns(kb, gb))
            return Constructed("line", {"point": axis.point.tolist(), "direction": axis.direction.tolist()})
        if {ka, kb} & {"plane"} and ({ka, kb} - {"plane"}) <= set(AXIS_LIKE):
            (lk, lg), (pk, pg) = (a, b) if kb == "plane" else (b, a)
            p = rel.intersect_line_plane(_ns(lk, lg), _ns(pk, pg))
            return Constructed("point", {"point": np.asarray(p).tolist()})
        raise FitError(f"a {ka} and a {kb} do not intersect in a point or a line here; "
                       "use two planes, or an axis and a plane")
    # distance
    projection = "3-D"
    if ka in AXIS_LIKE and kb in AXIS_LIKE and not (ka == "cone" and kb == "cone"):
        d, projection = _axis_distance(a, b, workplane, three_d)
    elif ka in POINT_LIKE + ("cone",) and kb in POINT_LIKE + ("cone",):
        d = float(np.linalg.norm(_point_of(ka, ga) - _point_of(kb, gb)))
        projection = "3-D, between the centres (cone: apex)"
    elif "plane" in (ka, kb) and (ka in POINT_LIKE or kb in POINT_LIKE):
        (pk, pg), (qk, qg) = (a, b) if kb == "plane" else (b, a)
        d = abs(rel.distance_point_plane(_point_of(pk, pg), _ns(qk, qg)))
        projection = "3-D, from the centre perpendicular to the plane"
    elif ka == "plane" and kb == "plane":
        d = rel.distance_plane_plane(_ns(ka, ga), _ns(kb, gb))
        ang = math.degrees(rel.angle_plane_plane(_ns(ka, ga), _ns(kb, gb)))
        return Constructed("distance", value=float(d), projection=(
            f"step height: from the centroid of the second plane perpendicular to the first; the planes are "
            f"{ang:.4f} deg apart"), warning=_step_warning(ang, "the planes"))
    elif "plane" in (ka, kb) and ({ka, kb} - {"plane"}) <= set(AXIS_LIKE):
        (lk, lg), (qk, qg) = (a, b) if kb == "plane" else (b, a)
        d = abs(rel.distance_point_plane(_location(lk, lg), _ns(qk, qg)))
        ang = math.degrees(rel.angle_line_plane(_ns(lk, lg), _ns(qk, qg)))
        return Constructed("distance", value=float(d), projection=(
            f"from the {lk}'s location point perpendicular to the plane; the axis is {ang:.4f} deg from parallel "
            "to the plane"), warning=_step_warning(ang, f"the {lk}'s axis and the plane"))
    elif (ka in POINT_LIKE and kb in AXIS_LIKE) or (kb in POINT_LIKE and ka in AXIS_LIKE):
        (pk, pg), (lk, lg) = (a, b) if kb in AXIS_LIKE else (b, a)
        d = rel.distance_point_line(_point_of(pk, pg), _ns(lk, lg))
        projection = "3-D, from the centre perpendicular to the axis"
    else:
        raise FitError(f"no distance between a {ka} and a {kb}")
    return Constructed("distance", value=float(d), projection=projection)


def nominal_geometry(kind: str, nominal: dict[str, Any] | None) -> tuple[str, dict[str, Any]] | None:
    """A recorded nominal (pick kinds: plane, cylinder, sphere, cone) as an operand of the fitted ``kind``."""
    if not nominal:
        return None
    n = {k: v for k, v in nominal.items() if k != "kind"}
    nk = nominal.get("kind")
    if kind == "circle" and nk == "cylinder":
        return "circle", {"center": n["point"], "normal": n["direction"], "radius": n.get("radius", 0.0)}
    if nk in ("plane", "surface") and kind == "plane":
        return "plane", n
    if nk == kind:
        return kind, n
    return None
