"""DMIS tolerances (``T(..) = TOL/..``) evaluated on actual features: the value and INTOL / OUTOL.

Size (DIAM, RAD), distance and angle between two features (DISTB, ANGLB) report the deviation from the nominal;
form (FLAT, STRGHT, CIRLTY, CYLCTY) the fit's form error; orientation (PARLEL, PERPEND, ANGLR) the width of the
zone, oriented to the datum, that holds the feature's surface points (a plane) or its axis over the length of
its hits (an axis); POS twice the distance of the actual location from the nominal (2D: across the nominal axis,
3D: in space) in the coordinate system in force, which the program builds from its datums with DATSET;
PROFS / PROFL the deviations of the hits from the nominal surface; RUNOUT the spread of the hits' radial
(axial, for a face) distances from a datum axis; CONCEN twice the largest distance of the feature's centre or
axis from a datum axis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..metrology.construct import construct
from ..metrology.features import FitError
from .features import Actual

SIZE = ("DIAM", "RAD")
FORM = {"FLAT": ("plane",), "STRGHT": ("line", "cylinder", "cone"), "CIRLTY": ("circle", "sphere", "cylinder", "cone"),
        "CYLCTY": ("cylinder",)}
ORIENT = ("PARLEL", "PERPEND", "ANGLR")
ALL = ("DIAM", "RAD", "DISTB", "ANGLB", "FLAT", "STRGHT", "CIRLTY", "CYLCTY", "PARLEL", "PERPEND", "ANGLR", "POS",
       "PROFS", "PROFL", "RUNOUT", "CONCEN")
AXIAL = ("line", "cylinder", "cone", "circle")


class ToleranceError(ValueError):
    """A tolerance that cannot be evaluated on the features given, in words."""


@dataclass
class Tolerance:
    label: str
    word: str  # DIAM, POS ...
    lower: float = 0.0  # mm (degrees for angles); deviation limits, or 0 .. zone
    upper: float = 0.0
    nominal: float | None = None  # DISTB / ANGLB nominal; ANGLR angle
    datums: list[str] = field(default_factory=list)
    options: list[str] = field(default_factory=list)  # 2D / 3D, CIRCLR / TOTAL, XAXIS ...


@dataclass
class Evaluation:
    tolerance: Tolerance
    value: float  # the deviation (sizes, distances, angles) or the zone (form, orientation, position ...)
    intol: bool
    features: list[str]

    @property
    def verdict(self) -> str:
        return "INTOL" if self.intol else "OUTOL"


def _unit(v: Any) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _points(a: Actual) -> np.ndarray:
    if a.hit_points is None or len(a.hit_points) == 0:
        raise ToleranceError(f"FA({a.label}) has no measured points (it was constructed)")
    return np.asarray(a.hit_points, float)


def _datum_direction(d: Actual) -> tuple[np.ndarray, bool]:
    """(direction, is an axis) of a datum feature."""
    v = d.direction()
    if v is None:
        raise ToleranceError(f"the datum FA({d.label}) ({d.kind}) has no direction: use a plane or an axis")
    return v, d.kind in AXIAL


def _axis_length(a: Actual, f: np.ndarray) -> float:
    if a.hit_points is not None and len(a.hit_points) > 1:
        s = np.asarray(a.hit_points, float) @ f
        return float(s.max() - s.min())
    if a.nominal is not None and a.nominal.length:
        return float(a.nominal.length)
    raise ToleranceError(f"FA({a.label}) has no length to evaluate its axis over")


def orientation(a: Actual, datum: Actual, angle_deg: float) -> float:
    """The orientation zone of ``a`` at ``angle_deg`` to ``datum`` (0 parallel, 90 perpendicular)."""
    f = a.direction()
    if f is None:
        raise ToleranceError(f"FA({a.label}) ({a.kind}) has no direction to orient")
    g, datum_axis = _datum_direction(datum)
    feature_axis = a.kind in AXIAL
    beta = math.radians(angle_deg if feature_axis == datum_axis else 90.0 - angle_deg)
    if a.kind == "plane":
        perp = f - (f @ g) * g
        u = perp / np.linalg.norm(perp) if np.linalg.norm(perp) > 1e-12 else np.cross(g, [1.0, 0.0, 0.0])
        m = math.cos(beta) * g + math.sin(beta) * _unit(u)
        s = _points(a) @ m
        return float(s.max() - s.min())
    if feature_axis:
        theta = math.acos(min(1.0, abs(float(f @ g))))
        return _axis_length(a, f) * abs(math.sin(theta - beta))
    raise ToleranceError(f"an orientation tolerance needs a plane or an axis, FA({a.label}) is a {a.kind}")


def _nominal_surface_deviation(a: Actual) -> np.ndarray:
    """Signed distances of the hits from the nominal surface (+ = outside the material)."""
    nom = a.nominal
    if nom is None:
        raise ToleranceError(f"FA({a.label}) has no nominal (F({a.label}) = FEAT/...) to compare its profile with")
    p = _points(a) - nom.point
    if nom.word in ("PLANE", "LINE", "POINT"):
        if nom.word == "LINE":
            raise ToleranceError("PROFL of a line needs a surface: measure a plane, circle or cylinder")
        return p @ _unit(nom.vector)
    if nom.word == "SPHERE":
        d = np.linalg.norm(p, axis=1) - nom.diameter / 2.0
    elif nom.word in ("CIRCLE", "CYLNDR"):
        ax = _unit(nom.vector)
        d = np.linalg.norm(p - np.outer(p @ ax, ax), axis=1) - nom.diameter / 2.0
    elif nom.word == "CONE":
        ax = _unit(nom.vector)
        h = p @ ax
        r = np.linalg.norm(p - np.outer(h, ax), axis=1)
        half = nom.angle / 2.0
        d = r * math.cos(half) - h * math.sin(half)
    else:
        raise ToleranceError(f"no profile for a {nom.word}")
    return -d if nom.inner else d


def _nearly_parallel(a: Actual, b: Actual, degrees: float = 1.0) -> bool:
    da, db = a.direction(), b.direction()
    return da is not None and db is not None and abs(float(da @ db)) >= math.cos(math.radians(degrees))


def _axis_distance(a: Actual, b: Actual) -> float:
    """The distance between two nominally parallel axes where they were measured: the mean of each one's
    location from the other axis (measured axes are never exactly parallel, and the shortest distance of two
    skew lines lies far away from both features)."""
    def off(p: np.ndarray, q: np.ndarray, d: np.ndarray) -> float:
        r = p - q
        return float(np.linalg.norm(r - (r @ d) * d))

    da, db = a.direction(), b.direction()
    return 0.5 * (off(a.axis_point(), b.axis_point(), db) + off(b.axis_point(), a.axis_point(), da))  # type: ignore[arg-type]


def _datum_axis(d: Actual) -> tuple[np.ndarray, np.ndarray]:
    if d.kind not in AXIAL:
        raise ToleranceError(f"the datum FA({d.label}) must be an axis (cylinder, circle, cone, line), not a {d.kind}")
    return d.location(), d.direction()  # type: ignore[return-value]


def evaluate(tol: Tolerance, features: list[Actual], datums: dict[str, Actual], frame: np.ndarray) -> Evaluation:
    """Evaluate ``tol`` on the features an OUTPUT statement names with it."""
    w = tol.word
    need = 2 if w in ("DISTB", "ANGLB") else 1
    if len(features) != need:
        raise ToleranceError(f"T({tol.label}) (TOL/{w}) applies to {need} feature{'s' if need > 1 else ''}: "
                             f"OUTPUT/{', '.join(['FA(..)'] * need)}, TA({tol.label})")
    dat = []
    for name in tol.datums:
        if name not in datums:
            raise ToleranceError(f"T({tol.label}) refers to DAT({name}), which no DATDEF has defined")
        dat.append(datums[name])
    a = features[0]
    lo, up = tol.lower, tol.upper
    if w in SIZE:
        nom = a.nominal
        if a.kind not in ("circle", "cylinder", "sphere") or nom is None or nom.diameter is None:
            raise ToleranceError(f"TOL/{w} needs a circle, cylinder or sphere with a nominal diameter; "
                                 f"FA({a.label}) is a {a.kind}")
        dev = 2.0 * float(a.geometry["radius"]) - nom.diameter
        if w == "RAD":
            dev /= 2.0
        return Evaluation(tol, dev, lo - 1e-12 <= dev <= up + 1e-12, [a.label])
    if w in ("DISTB", "ANGLB"):
        b = features[1]
        try:
            if w == "ANGLB":
                value = construct("angle", (a.kind, a.geometry), (b.kind, b.geometry)).value
            elif any(o in ("XAXIS", "YAXIS", "ZAXIS") for o in tol.options):
                axis = frame[:3, {"XAXIS": 0, "YAXIS": 1, "ZAXIS": 2}[next(o for o in tol.options if o.endswith("AXIS"))]]
                value = abs(float((b.location() - a.location()) @ axis))
            elif a.kind in AXIAL and b.kind in AXIAL and _nearly_parallel(a, b):
                value = _axis_distance(a, b)
            else:
                value = construct("distance", (a.kind, a.geometry), (b.kind, b.geometry)).value
        except (FitError, ValueError, KeyError) as exc:
            raise ToleranceError(f"TOL/{w} between FA({a.label}) and FA({b.label}): {exc}") from None
        dev = float(value) - float(tol.nominal or 0.0)
        return Evaluation(tol, dev, lo - 1e-12 <= dev <= up + 1e-12, [a.label, b.label])
    if w in FORM:
        if a.kind not in FORM[w]:
            raise ToleranceError(f"TOL/{w} applies to a {' or '.join(FORM[w])}, FA({a.label}) is a {a.kind}")
        value = float(a.geometry["form"])
    elif w in ORIENT:
        if not dat:
            raise ToleranceError(f"TOL/{w} needs a datum: TOL/{w}, zone, DAT(A)")
        angle = {"PARLEL": 0.0, "PERPEND": 90.0}.get(w, tol.nominal or 0.0)
        value = orientation(a, dat[0], angle)
    elif w == "POS":
        nom = a.nominal
        if nom is None or a.kind not in ("point", "circle", "cylinder", "sphere", "cone"):
            raise ToleranceError(f"TOL/POS needs a point, circle, cylinder, sphere or cone with a nominal; "
                                 f"FA({a.label}) is a {a.kind}")
        rel = a.axis_point() - nom.point
        if "3D" not in tol.options and nom.vector is not None and a.kind != "sphere":
            ax = _unit(nom.vector)
            rel = rel - (rel @ ax) * ax
        value = 2.0 * float(np.linalg.norm(rel))
    elif w in ("PROFS", "PROFL"):
        d = _nominal_surface_deviation(a)
        intol = bool(np.all(d >= lo - 1e-12) and np.all(d <= up + 1e-12))
        return Evaluation(tol, 2.0 * float(np.max(np.abs(d))), intol, [a.label])
    elif w == "RUNOUT":
        if not dat:
            raise ToleranceError("TOL/RUNOUT needs a datum axis: TOL/RUNOUT, CIRCLR, zone, DAT(A)")
        q, ax = _datum_axis(dat[0])
        p = _points(a) - q
        h = p @ ax
        if a.kind == "plane":
            value = float(h.max() - h.min())
        else:
            r = np.linalg.norm(p - np.outer(h, ax), axis=1)
            if "TOTAL" in tol.options:
                value = float(r.max() - r.min())
            else:  # circular: each section on its own (hits within 0.5 mm of height)
                sections: dict[int, list[float]] = {}
                for hk, rk in zip(np.round(h / 0.5), r):
                    sections.setdefault(int(hk), []).append(float(rk))
                value = max(max(v) - min(v) for v in sections.values())
    elif w == "CONCEN":
        if not dat:
            raise ToleranceError("TOL/CONCEN needs a datum axis: TOL/CONCEN, zone, DAT(A)")
        q, ax = _datum_axis(dat[0])
        centres = [a.location()]
        f = a.direction()
        if a.kind == "cylinder" and f is not None and a.hit_points is not None:
            s = (np.asarray(a.hit_points) - a.location()) @ f
            centres = [a.location() + s.min() * f, a.location() + s.max() * f]
        value = 2.0 * max(float(np.linalg.norm((c - q) - ((c - q) @ ax) * ax)) for c in centres)
    else:
        raise ToleranceError(f"TOL/{w} is not supported")
    return Evaluation(tol, value, value <= up + 1e-12, [a.label])


def model_tolerance(tol: Tolerance) -> dict[str, float]:
    """The measurement model's tolerance keys this DMIS tolerance sets (for the station's own report)."""
    w = tol.word
    width = max(abs(tol.lower), abs(tol.upper))
    if w == "DIAM" and width > 0:
        return {"size": width}
    if w == "RAD" and width > 0:
        return {"size": 2.0 * width}
    if w in FORM and tol.upper > 0:
        return {"form": tol.upper}
    if w == "POS" and tol.upper > 0:
        return {"position": tol.upper}
    return {}


def output_line(ev: Evaluation) -> str:
    t = ev.tolerance
    head = [t.word] + [o for o in t.options if o in ("2D", "3D", "CIRCLR", "TOTAL")]
    return f"TA({t.label}) = TOL/{', '.join(head)}, {ev.value + 0.0:.5f}, {ev.verdict}"
