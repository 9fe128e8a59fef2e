"""DMIS features: ``FEAT/`` nominals, their machine-coordinate nominals for fitting, and ``FA(..)`` actual lines.

Nominals are kept in machine millimetres (the coordinate system in force when the FEAT statement ran moves them
there; an alignment of the program that finds the part elsewhere moves them with it, as the station moves its
features' nominals), actuals are the measurement model's fitted features; both are written back in the coordinate system
and units in force when they are output, in the DMIS output format (``FA(X) = FEAT/CIRCLE, INNER, CART, ...``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..metrology.pick import NominalFeature
from .frames import apply, apply_vector, inverse

# DMIS feature word -> the measurement model's kind
KINDS = {"POINT": "point", "PLANE": "plane", "LINE": "line", "CIRCLE": "circle", "CYLNDR": "cylinder",
         "CONE": "cone", "SPHERE": "sphere"}
WORDS = {v: k for k, v in KINDS.items()}
SIZED = ("CIRCLE", "CYLNDR", "CONE", "SPHERE")  # these take INNER / OUTER
# numbers after CART (without the optional ones at the end): POINT, PLANE x y z i j k; LINE ...
NUMBERS = {"POINT": (6, 6), "PLANE": (6, 6), "LINE": (6, 9), "CIRCLE": (7, 7), "CYLNDR": (7, 8), "CONE": (7, 7),
           "SPHERE": (4, 4)}


@dataclass
class Nominal:
    """A FEAT/ nominal in machine coordinates (mm, radians)."""

    word: str  # CIRCLE, CYLNDR ...
    inner: bool | None  # INNER (hole) / OUTER (boss); None for POINT, PLANE, LINE
    point: np.ndarray  # location: point, plane point, circle/sphere centre, axis point, cone apex
    vector: np.ndarray | None  # plane normal, axis, circle normal; None for a sphere
    diameter: float | None = None
    angle: float | None = None  # cone: the included angle, radians
    length: float | None = None
    design: "Nominal | None" = None  # the same nominal in the design frame (see Executor.design_frame)
    polar: bool = False  # given in POL (radius, angle, height): its actual is output the same way
    plane: np.ndarray | None = None  # LINE: the normal of the plane it lies in (its material side), if given

    @property
    def bounded(self) -> bool:
        """A FEAT/LINE, BND (two end points; ``point`` the first, ``length`` to the second)."""
        return self.word == "LINE" and self.length is not None

    @property
    def kind(self) -> str:
        return KINDS[self.word]

    def to_model(self) -> NominalFeature | None:
        """The nominal the measurement model compares the fit with (None: a point or a line)."""
        bore = bool(self.inner)
        if self.word == "PLANE":
            return NominalFeature("plane", {"point": self.point, "normal": self.vector})
        if self.word in ("CIRCLE", "CYLNDR"):
            params = {"point": self.point, "direction": self.vector, "radius": self.diameter / 2.0, "bore": bore}
            if self.length:
                params["length"] = self.length
            return NominalFeature("cylinder", params)
        if self.word == "SPHERE":
            return NominalFeature("sphere", {"center": self.point, "radius": self.diameter / 2.0, "bore": bore})
        if self.word == "CONE":
            return NominalFeature("cone", {"apex": self.point, "direction": self.vector, "half_angle": self.angle / 2.0,
                                           "bore": bore})
        return None

    def surface_normal(self, p: np.ndarray) -> np.ndarray | None:
        """The outward surface normal at a point near the nominal surface (for a PTMEAS without a vector)."""
        if self.word in ("PLANE", "POINT") and self.vector is not None:
            return self.vector / np.linalg.norm(self.vector)
        if self.word == "LINE":  # a line is probed on the face it lies in, from its plane normal's side
            return self.plane
        if self.word in ("CIRCLE", "CYLNDR", "SPHERE"):
            r = p - self.point
            if self.word != "SPHERE":
                a = self.vector / np.linalg.norm(self.vector)
                r = r - (r @ a) * a
            n = float(np.linalg.norm(r))
            if n < 1e-9:
                return None
            return -r / n if self.inner else r / n
        return None


def size_problem(word: str, numbers: list[float]) -> str | None:
    """Why a FEAT's size is no size (a diameter or a cylinder's length zero or negative), or None. ``numbers``:
    the FEAT's numbers after CART or POL (x, y, z, i, j, k, diameter[, length]; SPHERE x, y, z, diameter)."""
    where = {"SPHERE": [(3, "diameter")], "CIRCLE": [(6, "diameter")],
             "CYLNDR": [(6, "diameter"), (7, "length")]}.get(word, [])
    for k, what in where:
        if k < len(numbers) and not numbers[k] > 0.0:
            return f"its {what} {numbers[k]:g} is not a positive length"
    return None


def nominal_from(word: str, inner: bool | None, numbers: list[float], frame: np.ndarray, scale: float,
                 angle_scale: float) -> Nominal:
    """A Nominal from the FEAT numbers (program units, the current coordinate system ``frame``)."""
    v = list(numbers)
    if (problem := size_problem(word, v)) is not None:
        raise ValueError(problem)

    def pt(k: int) -> np.ndarray:
        return apply(frame, np.array(v[k:k + 3]) * scale)

    def vec(k: int) -> np.ndarray:
        d = np.array(v[k:k + 3], float)
        n = float(np.linalg.norm(d))
        if n < 1e-12:
            raise ValueError("a direction vector is zero")
        return apply_vector(frame, d / n)

    if word == "SPHERE":
        return Nominal(word, inner, pt(0), None, diameter=v[3] * scale)
    if word == "LINE":  # UNBND: x, y, z, i, j, k[, pi, pj, pk]
        d = vec(3)
        return Nominal(word, None, pt(0), d, plane=_line_plane(v[6:9], d, frame))
    nom = Nominal(word, inner, pt(0), vec(3))
    if word in ("CIRCLE", "CYLNDR"):
        nom.diameter = v[6] * scale
        if word == "CYLNDR" and len(v) > 7:
            nom.length = v[7] * scale
    elif word == "CONE":
        nom.angle = v[6] * angle_scale
    return nom


def _line_plane(numbers: list[float], direction: np.ndarray, frame: np.ndarray) -> np.ndarray | None:
    """A line's plane normal (pi, pj, pk in ``frame``) made square to its direction; None when not given."""
    if len(numbers) < 3:
        return None
    n = apply_vector(frame, np.array(numbers[:3], float))
    n = n - (n @ direction) * direction
    if np.linalg.norm(n) < 1e-6:
        raise ValueError("the plane normal (pi, pj, pk) is zero or along the line")
    return n / np.linalg.norm(n)


def bounded_line(numbers: list[float], frame: np.ndarray, scale: float) -> Nominal:
    """FEAT/LINE,BND,CART,x1,y1,z1,x2,y2,z2[,pi,pj,pk]: the line through two points, in the plane of that normal."""
    a = apply(frame, np.array(numbers[0:3]) * scale)
    b = apply(frame, np.array(numbers[3:6]) * scale)
    d = b - a
    if np.linalg.norm(d) < 1e-9:
        raise ValueError("the two end points of a bounded line are the same")
    u = d / np.linalg.norm(d)
    return Nominal("LINE", None, a, u, length=float(np.linalg.norm(d)), plane=_line_plane(numbers[6:9], u, frame))


@dataclass
class Actual:
    """A measured (or constructed) feature: its kind and fitted geometry in machine coordinates."""

    label: str
    kind: str  # point line plane circle cylinder cone sphere
    geometry: dict[str, Any]
    nominal: Nominal | None = None
    feature_id: int | None = None  # the measurement model's feature, if it is one
    hit_points: np.ndarray | None = None  # compensated surface points (machine), for form and profile tolerances

    def location(self) -> np.ndarray:
        g = self.geometry
        for key in ("center", "apex", "point"):
            if key in g:
                return np.asarray(g[key], float)
        raise KeyError(self.kind)

    def direction(self) -> np.ndarray | None:
        g = self.geometry
        for key in ("normal", "direction"):
            if key in g:
                d = np.asarray(g[key], float)
                d = d / np.linalg.norm(d)
                if self.nominal is not None and self.nominal.vector is not None and d @ self.nominal.vector < 0:
                    d = -d  # fits carry a canonical sign; the program's vector decides
                return d
        return None

    def axis_point(self) -> np.ndarray:
        """A cylinder's axis point nearest the nominal location (comparable with it); else the location."""
        p = self.location()
        d = self.direction()
        if self.kind in ("cylinder", "line") and d is not None and self.nominal is not None:
            return p + ((self.nominal.point - p) @ d) * d
        return p


def _f(x: float) -> str:
    return f"{round(float(x), 5) + 0.0:.5f}"  # no "-0.00000"


def _polar(p: np.ndarray, angle_scale: float) -> list[float]:
    """(radius, angle in the program's units, height) of a point in the current system."""
    return [math.hypot(p[0], p[1]), math.atan2(p[1], p[0]) / angle_scale, float(p[2])]


def actual_line(actual: Actual, frame: np.ndarray, scale: float, angle_scale: float) -> str:
    """``FA(label) = FEAT/...`` in the coordinate system ``frame`` and the program's units."""
    inv = inverse(frame)
    word = WORDS[actual.kind]
    nom = actual.nominal
    head = [word]
    if word in SIZED:
        inner = nom.inner if nom is not None and nom.inner is not None else bool(actual.geometry.get("bore", False))
        head.append("INNER" if inner else "OUTER")
    if word == "LINE":
        return _actual_line_feature(actual, inv, scale, angle_scale)
    head.append("POL" if nom is not None and nom.polar else "CART")
    p = apply(inv, actual.axis_point()) / scale
    nums = _polar(p, angle_scale) if nom is not None and nom.polar else [*p]
    d = actual.direction()
    if d is None and word == "POINT" and nom is not None and nom.vector is not None:
        d = nom.vector  # a measured point's vector is its FEAT's (DMIS writes a point as x, y, z, i, j, k)
    if word != "SPHERE" and d is not None:
        nums += list(apply_vector(inv, d))
    g = actual.geometry
    if word in ("CIRCLE", "CYLNDR", "SPHERE"):
        nums.append(2.0 * float(g["radius"]) / scale)
    if word == "CYLNDR" and nom is not None and nom.length:
        nums.append(nom.length / scale)
    if word == "CONE":
        nums.append(2.0 * float(g["half_angle"]) / angle_scale)
    return f"FA({actual.label}) = FEAT/{', '.join(head)},  $\n  " + ", ".join(_f(x) for x in nums)


def _side(d: np.ndarray, plane: np.ndarray | None) -> np.ndarray:
    """The plane normal of a line with direction ``d``: the nominal's made square to ``d``; without one (a
    constructed line), the normal square to ``d`` nearest machine Z (X for a vertical line)."""
    for n in ([plane] if plane is not None else []) + [np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])]:
        n = np.asarray(n, float) - (np.asarray(n, float) @ d) * d
        if np.linalg.norm(n) > 1e-6:
            return n / np.linalg.norm(n)
    raise ValueError("no plane normal")  # unreachable: Z and X cannot both lie along d


def _line_numbers(ends: list[np.ndarray], d: np.ndarray, plane: np.ndarray, inv: np.ndarray, scale: float,
                  angle_scale: float, polar: bool) -> tuple[list[str], list[float]]:
    """The words and numbers of a FEAT/LINE: UNBND with one point and ``d``, BND with two end points; both end
    with the plane normal. ``inv`` takes machine coordinates to the system in force."""
    nums: list[float] = []
    for e in ends:
        p = apply(inv, e) / scale
        nums += _polar(p, angle_scale) if polar else list(p)
    if len(ends) == 1:
        nums += list(apply_vector(inv, d))
    nums += list(apply_vector(inv, plane))
    return ["LINE", "BND" if len(ends) == 2 else "UNBND", "POL" if polar else "CART"], nums


def _actual_line_feature(actual: Actual, inv: np.ndarray, scale: float, angle_scale: float) -> str:
    """``FA(L) = FEAT/LINE, UNBND, CART, x, y, z, i, j, k, pi, pj, pk``; BND (when the FEAT was) with the first
    and last hit projected onto the fitted line as its end points."""
    nom = actual.nominal
    d = actual.direction()
    o = actual.axis_point()
    ends = [o]
    hits = actual.hit_points
    if nom is not None and nom.bounded and hits is not None and len(hits) >= 2:
        ends = [o + ((np.asarray(h, float) - o) @ d) * d for h in (hits[0], hits[-1])]
    words, nums = _line_numbers(ends, d, _side(d, nom.plane if nom is not None else None), inv, scale,
                                angle_scale, nom is not None and nom.polar)
    return f"FA({actual.label}) = FEAT/{', '.join(words)},  $\n  " + ", ".join(_f(x) for x in nums)


def nominal_line(label: str, nom: Nominal, frame: np.ndarray, scale: float, angle_scale: float) -> str:
    """``F(label) = FEAT/...`` of a nominal (for exported programs)."""
    inv = inverse(frame)
    if nom.word == "LINE":
        ends = [nom.point, nom.point + nom.length * nom.vector] if nom.bounded else [nom.point]
        words, nums = _line_numbers(ends, nom.vector, _side(nom.vector, nom.plane), inv, scale, angle_scale,
                                    nom.polar)
        return f"F({label}) = FEAT/{', '.join(words)}, " + ", ".join(_f(x) for x in nums)
    head = [nom.word] + (["INNER" if nom.inner else "OUTER"] if nom.word in SIZED else []) + \
        ["POL" if nom.polar else "CART"]
    p = apply(inv, nom.point) / scale
    nums = _polar(p, angle_scale) if nom.polar else list(p)
    if nom.vector is not None and nom.word != "SPHERE":
        nums += list(apply_vector(inv, nom.vector))
    if nom.word in ("CIRCLE", "CYLNDR", "SPHERE"):
        nums.append(nom.diameter / scale)
    if nom.word == "CYLNDR" and nom.length:
        nums.append(nom.length / scale)
    if nom.word == "CONE":
        nums.append(nom.angle / angle_scale)
    return f"F({label}) = FEAT/{', '.join(head)}, " + ", ".join(_f(x) for x in nums)


def from_model_nominal(word: str, nf: NominalFeature) -> Nominal:
    """A Nominal from a measurement-model nominal (machine or part coordinates, as given)."""
    p = nf.params
    bore = bool(p.get("bore", False))
    if nf.kind in ("plane", "surface"):
        return Nominal("PLANE", None, np.asarray(p["point"], float), np.asarray(p["normal"], float))
    if nf.kind == "cylinder":
        return Nominal(word if word in ("CIRCLE", "CYLNDR") else "CYLNDR", bore, np.asarray(p["point"], float),
                       np.asarray(p["direction"], float), diameter=2.0 * float(p["radius"]),
                       length=float(p["length"]) if "length" in p and word == "CYLNDR" else None)
    if nf.kind == "sphere":
        return Nominal("SPHERE", bore, np.asarray(p["center"], float), None, diameter=2.0 * float(p["radius"]))
    if nf.kind == "cone":
        return Nominal("CONE", bore, np.asarray(p["apex"], float), np.asarray(p["direction"], float),
                       angle=2.0 * float(p["half_angle"]))
    raise ValueError(f"no DMIS feature for a {nf.kind} nominal")


def deg(x: float) -> float:
    return math.degrees(x)
