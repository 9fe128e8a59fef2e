"""Relations between features: distances, angles, intersections, projections,
and GD&T basics (form, orientation, position).

Features are duck-typed: a point is an array or anything with ``.point`` /
``.center``; a line-like feature has ``.point`` (or ``.apex``) and
``.direction`` (Line, Cylinder, Cone, Axis); a plane-like one has ``.point``
and ``.normal`` (Plane).  Angles are in radians; angles between lines and
planes are folded into [0, pi/2] since their directions have no sign.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from cmm.metrology import fit_criteria
from cmm.metrology.features import FitError
from cmm.metrology.fit_enclosing import min_enclosing_ball
from cmm.metrology.fit_hull import min_width_direction
from cmm.metrology.geom_basics import axis_point_closest_to_origin, canonical_direction, frame_with_axis, unit

PARALLEL_TOL = 1e-12  # |sin| below which lines/planes are treated as parallel


@dataclass(frozen=True, eq=False)
class Axis:
    """A plain 3D line: point closest to the origin and canonical unit direction."""

    point: np.ndarray
    direction: np.ndarray

    @classmethod
    def through(cls, point: np.ndarray, direction: np.ndarray) -> "Axis":
        u = canonical_direction(direction)
        return cls(axis_point_closest_to_origin(np.asarray(point, dtype=np.float64), u), u)


def _point(x: Any) -> np.ndarray:
    """A point: an array, a feature's centre (circle, sphere) or its point."""
    for name in ("center", "point"):
        if hasattr(x, name):
            return np.asarray(getattr(x, name), dtype=np.float64)
    return np.asarray(x, dtype=np.float64)


def _line(x: Any) -> tuple[np.ndarray, np.ndarray]:
    origin = getattr(x, "point", None)
    if origin is None:
        origin = getattr(x, "apex")
    return np.asarray(origin, dtype=np.float64), unit(x.direction)


def _plane(x: Any) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(x.point, dtype=np.float64), unit(x.normal)


# ---------------------------------------------------------------- distances


def distance_point_point(a: Any, b: Any) -> float:
    return float(np.linalg.norm(_point(a) - _point(b)))


def distance_point_line(p: Any, line: Any) -> float:
    o, u = _line(line)
    return float(np.linalg.norm(np.cross(_point(p) - o, u)))


def distance_point_plane(p: Any, plane: Any) -> float:
    """Signed: positive on the side the plane normal points to."""
    o, n = _plane(plane)
    return float((_point(p) - o) @ n)


def distance_line_line(a: Any, b: Any) -> float:
    """Shortest distance between two (infinite) lines; parallel lines included."""
    oa, ua = _line(a)
    ob, ub = _line(b)
    w = np.cross(ua, ub)
    s = np.linalg.norm(w)
    if s <= PARALLEL_TOL:
        return distance_point_line(ob, a)
    return float(abs((ob - oa) @ w) / s)


def distance_line_plane(line: Any, plane: Any) -> float:
    """Distance of a line parallel to a plane; 0 if they intersect."""
    o, u = _line(line)
    _, n = _plane(plane)
    if abs(u @ n) > PARALLEL_TOL:
        return 0.0
    return abs(distance_point_plane(o, plane))


def distance_plane_plane(a: Any, b: Any) -> float:
    """Step height: the distance from b's point (a fitted plane's centroid) perpendicular to plane a.

    Measured planes are never exactly parallel; the value is taken at b's centroid whatever their angle
    (ISO 10360 / commercial practice), and the caller shows the angle (:func:`angle_plane_plane`) with it."""
    return abs(distance_point_plane(_plane(b)[0], a))


# ---------------------------------------------------------------- angles


def angle_between(u: Any, v: Any) -> float:
    """Angle between two directions in [0, pi] (robust near 0 and pi)."""
    u, v = unit(u), unit(v)
    return float(np.arctan2(np.linalg.norm(np.cross(u, v)), u @ v))


def _fold(angle: float) -> float:
    return min(angle, np.pi - angle)


def angle_line_line(a: Any, b: Any) -> float:
    return _fold(angle_between(_line(a)[1], _line(b)[1]))


def angle_line_plane(line: Any, plane: Any) -> float:
    """0 when the line lies in / parallel to the plane, pi/2 when perpendicular."""
    return np.pi / 2 - _fold(angle_between(_line(line)[1], _plane(plane)[1]))


def angle_plane_plane(a: Any, b: Any) -> float:
    return _fold(angle_between(_plane(a)[1], _plane(b)[1]))


# ---------------------------------------------------------------- intersections and projections


def intersect_line_plane(line: Any, plane: Any) -> np.ndarray:
    o, u = _line(line)
    po, n = _plane(plane)
    denom = u @ n
    if abs(denom) <= PARALLEL_TOL:
        raise FitError("the line is parallel to the plane: they do not intersect in a point")
    return o + ((po - o) @ n / denom) * u


def intersect_plane_plane(a: Any, b: Any) -> Axis:
    pa, na = _plane(a)
    pb, nb = _plane(b)
    u = np.cross(na, nb)
    if np.linalg.norm(u) <= PARALLEL_TOL:
        raise FitError("the planes are parallel: they do not intersect in a line")
    # the point on both planes closest to the origin: 3x3 system with u . x = 0
    p = np.linalg.solve(np.vstack([na, nb, u]), np.array([na @ pa, nb @ pb, 0.0]))
    return Axis.through(p, u)


def project_point(p: Any, plane: Any) -> np.ndarray:
    """Orthogonal projection of a point (or a circle/sphere centre) onto a plane."""
    po, n = _plane(plane)
    x = _point(p)
    return x - ((x - po) @ n) * n


def project_line(line: Any, plane: Any) -> Axis:
    o, u = _line(line)
    _, n = _plane(plane)
    v = u - (u @ n) * n
    if np.linalg.norm(v) <= PARALLEL_TOL:
        raise FitError("the line is perpendicular to the plane: its projection is a point")
    return Axis.through(project_point(o, plane), v)


def to_plane_2d(points: Any, plane: Any) -> tuple[np.ndarray, np.ndarray]:
    """Points projected into a plane as 2D coordinates, and the 3x3 frame (columns
    e1, e2, normal) so that x3 = plane.point + frame[:, :2] @ x2."""
    po, n = _plane(plane)
    frame = frame_with_axis(n)
    return (np.atleast_2d(np.asarray(points, dtype=np.float64)) - po) @ frame[:, :2], frame


# ---------------------------------------------------------------- GD&T


def straightness(points: Any, plane: Any = None) -> float:
    """Minimum-zone straightness: in a plane (points projected; exact strip width)
    if `plane` is given, else the diameter of the thinnest cylinder (SLP)."""
    if plane is not None:
        return fit_criteria.fit("line2d", to_plane_2d(points, plane)[0], "minzone").form
    return fit_criteria.fit("line", points, "minzone").form


def flatness(points: Any) -> float:
    """Minimum-zone flatness (exact, convex hull width)."""
    return fit_criteria.fit("plane", points, "minzone").form


def roundness(points: Any) -> float:
    """Minimum-zone roundness (2D points, or 3D points in their least-squares plane)."""
    pts = np.asarray(points, dtype=np.float64)
    return fit_criteria.fit("circle2d" if pts.shape[-1] == 2 else "circle", pts, "minzone").form


def cylindricity(points: Any, nominal: Any = None) -> float:
    """Minimum-zone cylindricity (SLP from the least-squares cylinder)."""
    return fit_criteria.fit("cylinder", points, "minzone", nominal=nominal).form


def sphericity(points: Any) -> float:
    return fit_criteria.fit("sphere", points, "minzone").form


def _datum(datum: Any) -> tuple[str, np.ndarray]:
    if hasattr(datum, "normal") and not hasattr(datum, "direction"):
        return "plane", unit(datum.normal)
    if hasattr(datum, "direction"):
        return "axis", unit(datum.direction)
    raise FitError("the datum must be a plane (with a normal) or an axis (with a direction)")


def _zone_along(x: np.ndarray, d: np.ndarray) -> float:
    """Two planes normal to d."""
    h = x @ d
    return float(h.max() - h.min())


def _strip_containing(x: np.ndarray, d: np.ndarray) -> float:
    """Two planes parallel to d (orientation about d free): exact 2D minimum width."""
    flat = x @ frame_with_axis(d)[:, :2]
    return min_width_direction(flat - flat.mean(axis=0))[0]


def _cylinder_along(x: np.ndarray, d: np.ndarray) -> float:
    """A cylinder with axis parallel to d: exact minimum enclosing circle diameter."""
    flat = x @ frame_with_axis(d)[:, :2]
    c = flat.mean(axis=0)
    scale = float(np.abs(flat - c).max()) or 1.0
    return 2.0 * min_enclosing_ball((flat - c) / scale)[1] * scale


def parallelism(points: Any, datum: Any, feature: str = "plane") -> float:
    """Zone width of a feature's points parallel to a datum plane or axis.

    datum plane: two planes parallel to it; datum axis: a plane feature gets two
    planes parallel to the axis, a line/axis feature a cylinder parallel to it."""
    x = np.atleast_2d(np.asarray(points, dtype=np.float64))
    kind, d = _datum(datum)
    if kind == "plane":
        return _zone_along(x, d)
    return _strip_containing(x, d) if feature == "plane" else _cylinder_along(x, d)


def perpendicularity(points: Any, datum: Any, feature: str = "plane") -> float:
    """Zone width of a feature's points perpendicular to a datum plane or axis.

    datum axis: two planes perpendicular to it; datum plane: a plane feature
    gets two planes perpendicular to it, a line/axis feature (e.g. circle
    centres at several heights) a cylinder perpendicular to it."""
    x = np.atleast_2d(np.asarray(points, dtype=np.float64))
    kind, d = _datum(datum)
    if kind == "axis":
        return _zone_along(x, d)
    return _strip_containing(x, d) if feature == "plane" else _cylinder_along(x, d)


def position(feature: Any, nominal: Any, datum_normal: Any = None) -> float:
    """True position diameter 2 sqrt(dx^2 + dy^2) of a circle centre or cylinder
    axis against a nominal point, measured in the datum plane (normal
    `datum_normal`, default the feature's own normal / axis).  A cylinder axis
    is taken where it crosses the datum-parallel plane through the nominal."""
    nominal = np.asarray(nominal, dtype=np.float64)
    if hasattr(feature, "direction"):
        o, u = _line(feature)
        d = unit(datum_normal) if datum_normal is not None else u
        if abs(u @ d) <= PARALLEL_TOL:
            raise FitError("the axis lies in the datum plane: its position in that plane is not defined")
        actual = o + ((nominal - o) @ d / (u @ d)) * u
    else:
        actual = _point(feature)
        normal = datum_normal if datum_normal is not None else getattr(feature, "normal", None)
        if normal is None:
            raise FitError("give a datum normal for the position of a feature without an axis")
        d = unit(normal)
    dev = actual - nominal
    dev = dev - (dev @ d) * d
    return float(2.0 * np.linalg.norm(dev))
