"""Constructed features: intersection, distance, angle and mid-point of measured features.

Operands are (kind, geometry) pairs as fitted features record them
(``plane``: point, normal; ``circle``: center, normal, radius; ``cylinder``,
``line``: point, direction; ``cone``: apex, direction; ``sphere``: center;
``point``: point). The same construction applied to the operands' nominals
gives the constructed feature's nominal, so a distance between two bores is
toleranced against the drawing's distance.

- ``intersection``: plane x plane -> line; axis x plane -> point (an axis is a
  line, cylinder, cone or circle normal through its centre);
- ``distance``: between two point-like features (centres, points, apexes),
  a point-like feature and a plane, a point-like feature and an axis, two
  parallel planes, two axes (shortest distance);
- ``angle``: between two directions (plane normals, axes), degrees in [0, 90];
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

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {"kind": self.kind, **self.geometry}
        if self.value is not None:
            out["value"] = self.value
        return out


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


def construct(operation: str, a: tuple[str, dict[str, Any]], b: tuple[str, dict[str, Any]]) -> Constructed:
    """Construct ``operation`` from two (kind, geometry) operands; FitError in words when they do not combine."""
    if operation not in OPERATIONS:
        raise FitError(f"unknown construction {operation!r}; choose one of {', '.join(OPERATIONS)}")
    (ka, ga), (kb, gb) = a, b
    if operation == "angle":
        ang = rel.angle_between(_direction_of(ka, ga), _direction_of(kb, gb))
        return Constructed("angle", value=math.degrees(min(ang, math.pi - ang)))
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
    if ka in POINT_LIKE + ("cone",) and kb in POINT_LIKE + ("cone",):
        d = float(np.linalg.norm(_point_of(ka, ga) - _point_of(kb, gb)))
    elif "plane" in (ka, kb) and (ka in POINT_LIKE or kb in POINT_LIKE):
        (pk, pg), (qk, qg) = (a, b) if kb == "plane" else (b, a)
        d = abs(rel.distance_point_plane(_point_of(pk, pg), _ns(qk, qg)))
    elif ka == "plane" and kb == "plane":
        d = rel.distance_plane_plane(_ns(ka, ga), _ns(kb, gb))
    elif ka in AXIS_LIKE and kb in AXIS_LIKE:
        d = rel.distance_line_line(_ns(ka, ga), _ns(kb, gb))
    elif (ka in POINT_LIKE and kb in AXIS_LIKE) or (kb in POINT_LIKE and ka in AXIS_LIKE):
        (pk, pg), (lk, lg) = (a, b) if kb in AXIS_LIKE else (b, a)
        d = rel.distance_point_line(_point_of(pk, pg), _ns(lk, lg))
    else:
        raise FitError(f"no distance between a {ka} and a {kb}")
    return Constructed("distance", value=float(d))


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
