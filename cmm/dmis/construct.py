"""DMIS constructions (``CONST/..``) from actual features: intersections, mid-points and bisectors, projections,
best-fit lines through feature locations. Distances and angles between features are DISTB / ANGLB tolerances
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
    if method == "BF":
        if kind != "line" or len(operands) < 2:
            raise ConstructError("CONST/.., BF is supported for a line through two or more feature locations")
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
