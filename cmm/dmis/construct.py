"""DMIS constructions (``CONST/..``) from actual features: intersections, mid-points and bisectors, projections,
best-fit lines, planes and circles through feature locations. Circles: INTOF a cylinder or cone with a plane
(the section: centre where the axis meets the plane, the cylinder's radius or the cone's there, normal the
axis), PROJCT of a circle or cylinder onto a plane (centre projected, normal the plane's), BF through three or
more feature locations (a bolt circle: least squares in their best-fit plane). Distances and angles between features are DISTB / ANGLB tolerances
evaluated at OUTPUT (:mod:`cmm.dmis.tolerances`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..metrology.construct import construct
from .features import Actual


class ConstructError(ValueError):
    """A construction the operands do not allow, in words."""


def _unit(v: Any) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _aligned(a: Actual, b: Actual) -> tuple[np.ndarray, np.ndarray]:
    da, db = a.direction(), b.direction()
    if da is None or db is None:
        raise ConstructError(f"FA({a.label if da is None else b.label}) has no direction")
    return da, (db if da @ db >= 0 else -db)


def construct_actual(kind: str, method: str, operands: list[Actual]) -> tuple[str, dict[str, Any]]:
    """(kind, geometry in machine coordinates) of ``CONST/<kind>, F(..), <method>, FA(..), ...``."""
    names = ", ".join(f"FA({a.label})" for a in operands)
    if kind == "circle":
        return _circle(method, operands, names)
    if method == "BF" and kind == "plane":
        if len(operands) < 3:
            raise ConstructError("CONST/PLANE, .., BF takes three or more features (their locations)")
        pts = np.array([a.location() for a in operands])
        c = pts.mean(axis=0)
        n = np.linalg.svd(pts - c)[2][2]
        first = operands[0].direction()
        if first is not None and n @ first < 0:
            n = -n
        return "plane", {"point": c.tolist(), "normal": n.tolist()}
    if method == "BF":
        if kind != "line" or len(operands) < 2:
            raise ConstructError("CONST/.., BF is supported for a line through two or more feature locations, a "
                                 "plane or circle through three or more")
        pts = np.array([a.location() for a in operands])
        c = pts.mean(axis=0)
        _, _, vt = np.linalg.svd(pts - c)
        d = vt[0] if (pts[-1] - pts[0]) @ vt[0] >= 0 else -vt[0]
        return "line", {"point": c.tolist(), "direction": d.tolist()}
    if len(operands) != 2:
        raise ConstructError(f"CONST/{kind.upper()}, .., {method} takes two features, it has {len(operands)} ({names})")
    a, b = operands
    if method in ("INTOF", "MIDPT"):
        c = construct("intersection" if method == "INTOF" else "midpoint", (a.kind, a.geometry), (b.kind, b.geometry))
        if c.kind != kind:
            raise ConstructError(f"the {method} of {names} is a {c.kind}, not a {kind}")
        return c.kind, dict(c.geometry)
    if method == "MIDPL":
        if kind != "plane" or a.kind != "plane" or b.kind != "plane":
            raise ConstructError("MIDPL constructs the mid-plane of two planes")
        na, nb = _aligned(a, b)
        return "plane", {"point": ((a.location() + b.location()) / 2).tolist(), "normal": _unit(na + nb).tolist()}
    if method == "MIDLI":
        if kind != "line":
            raise ConstructError("MIDLI constructs a line")
        da, db = _aligned(a, b)
        return "line", {"point": ((a.location() + b.location()) / 2).tolist(), "direction": _unit(da + db).tolist()}
    if method == "PROJCT":
        if b.kind != "plane":
            raise ConstructError(f"PROJCT projects onto a plane: the second feature FA({b.label}) is a {b.kind}")
        n = _unit(b.geometry["normal"])
        q = np.asarray(b.geometry["point"], float)
        p = a.location()
        foot = p - ((p - q) @ n) * n
        if kind == "point":
            return "point", {"point": foot.tolist()}
        d = a.direction()
        if kind == "line" and d is not None:
            d = d - (d @ n) * n
            if np.linalg.norm(d) < 1e-9:
                raise ConstructError(f"FA({a.label}) is perpendicular to the plane: its projection is a point")
            return "line", {"point": foot.tolist(), "direction": _unit(d).tolist()}
        raise ConstructError(f"a {kind} cannot be projected from a {a.kind}")
    raise ConstructError(f"{method} is not supported")


def _axis_meets_plane(a: Actual, plane: Actual) -> tuple[np.ndarray, np.ndarray]:
    """(point, axis direction) where the axis of a cylinder, cone or circle meets a plane."""
    d = a.direction()
    if d is None:
        raise ConstructError(f"FA({a.label}) has no axis")
    n = _unit(plane.geometry["normal"])
    q = np.asarray(plane.geometry["point"], float)
    if abs(float(d @ n)) < 1e-6:
        raise ConstructError(f"FA({a.label})'s axis is parallel to FA({plane.label}): they do not meet")
    p = a.location()
    return p + ((q - p) @ n) / float(d @ n) * d, d


def _circle(method: str, operands: list[Actual], names: str) -> tuple[str, dict[str, Any]]:
    if method == "BF":
        if len(operands) < 3:
            raise ConstructError(f"CONST/CIRCLE, .., BF takes three or more features (their locations), it has {names}")
        pts = np.array([a.location() for a in operands])
        c0 = pts.mean(axis=0)
        _, _, vt = np.linalg.svd(pts - c0)
        u, v, n = vt
        xy = np.column_stack([(pts - c0) @ u, (pts - c0) @ v])
        # the circle x^2 + y^2 + D x + E y + F = 0 through the points in least squares
        A = np.column_stack([xy, np.ones(len(xy))])
        D, E, F = np.linalg.lstsq(A, -(xy ** 2).sum(axis=1), rcond=None)[0]
        r2 = (D * D + E * E) / 4.0 - F
        if not np.isfinite(r2) or r2 <= 0:
            raise ConstructError(f"no circle passes through {names} (they lie on a line)")
        centre = c0 - D / 2.0 * u - E / 2.0 * v
        first = operands[0].direction()
        if (first is not None and n @ first < 0) or (first is None and n[np.argmax(np.abs(n))] < 0):
            n = -n
        return "circle", {"center": centre.tolist(), "normal": n.tolist(), "radius": float(np.sqrt(r2))}
    if len(operands) != 2:
        raise ConstructError(f"CONST/CIRCLE, .., {method} takes two features, it has {len(operands)} ({names})")
    a, b = operands
    if a.kind == "plane" and b.kind != "plane":
        a, b = b, a
    if b.kind != "plane":
        raise ConstructError(f"CONST/CIRCLE, .., {method} takes a cylinder, cone or circle and a plane ({names})")
    if method == "INTOF":
        if a.kind not in ("cylinder", "cone"):
            raise ConstructError(f"CONST/CIRCLE, .., INTOF cuts a cylinder or cone with a plane; FA({a.label}) is a "
                                 f"{a.kind}")
        centre, d = _axis_meets_plane(a, b)
        if a.kind == "cylinder":
            r = float(a.geometry["radius"])
        else:
            h = abs(float((centre - np.asarray(a.geometry["apex"], float)) @ d))
            r = h * float(np.tan(float(a.geometry["half_angle"])))
        return "circle", {"center": centre.tolist(), "normal": d.tolist(), "radius": r}
    if method == "PROJCT":
        if a.kind not in ("circle", "cylinder"):
            raise ConstructError(f"CONST/CIRCLE, .., PROJCT projects a circle or cylinder onto a plane; FA({a.label}) "
                                 f"is a {a.kind}")
        n = _unit(b.geometry["normal"])
        if a.kind == "cylinder":
            centre, _ = _axis_meets_plane(a, b)
        else:
            p, q = a.location(), np.asarray(b.geometry["point"], float)
            centre = p - ((p - q) @ n) * n
        return "circle", {"center": centre.tolist(), "normal": n.tolist(), "radius": float(a.geometry["radius"])}
    raise ConstructError(f"CONST/CIRCLE, .., {method} is not supported: use INTOF, PROJCT or BF")
