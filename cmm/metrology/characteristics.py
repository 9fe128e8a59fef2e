"""Toleranced characteristics of a fitted feature against its nominal: what the report and feature tree show.

Per feature kind:

- size: diameter of circles, spheres and cylinders; the half angle of cones
  (``size`` +- mm, or the limits ``size_lower`` / ``size_upper`` as deviations from the nominal diameter;
  ``angle`` +- degrees);
- location: a plane's distance from its nominal plane along the nominal
  normal (``location`` +- mm); the true position of axes and centres as a
  diameter, per ISO 1101 / ASME Y14.5: twice the distance of the actual axis
  (circle, cylinder: in the plane perpendicular to the nominal axis) or centre
  (sphere: a spherical zone; cone: its apex) from the nominal, against a
  cylindrical zone of diameter ``position`` (default 2 x ``location``);
- form: flatness, straightness, roundness, cylindricity, sphericity, cone
  form (``form``, upper limit only).

A characteristic that needs a nominal the feature does not have is listed
with ``nominal`` None and ``ok`` None ("no nominal"): it never shows a pass
or fail against a blank nominal.

A feature whose fit found a clearly different solution that fits the hits
better than the one near its nominal (``alternative`` in the fit summary)
has every characteristic marked ``check``, with the alternative's value in
``check``: the operator decides; the result is never swapped silently.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

DEFAULT_TOLERANCE = {"size": 0.02, "form": 0.02, "location": 0.02}  # mm; +- for size and location
DEFAULT_ANGLE_TOLERANCE = 0.1  # degrees, +- for a cone's half angle

FORM_NAMES = {"plane": "flatness", "line": "straightness", "circle": "roundness", "cylinder": "cylindricity",
              "sphere": "sphericity", "cone": "cone form"}
# which nominal kinds a fitted kind compares with (a circle is measured on a cylindrical bore or boss)
COMPARABLE = {"plane": ("plane", "surface"), "circle": ("cylinder", "circle"), "cylinder": ("cylinder",),
              "sphere": ("sphere",), "cone": ("cone",), "line": (), "point": ()}


@dataclass(frozen=True)
class Characteristic:
    feature: str
    name: str  # "diameter", "position ⌀", "flatness", ...
    nominal: float | None
    actual: float | None  # None: it needs a nominal to be measured (location, position)
    upper: float  # upper tolerance (deviation allowed above the nominal)
    lower: float  # lower tolerance (negative or 0)
    unit: str = "mm"
    note: str = ""
    check: str = ""  # why the operator must check this value (another solution fits better), or ""
    datums: str = ""  # a geometric tolerance's datum reference frame ("A|B|C", see cmm.metrology.gdt_eval)
    uncertainty: float | None = None  # expanded U from the feature's budget (cmm.metrology.uncertainty)
    uncertainty_k: float | None = None  # its coverage factor (2, or Student's t for few degrees of freedom)
    uncertainty_why: str = ""  # why it has none, in words (shown where the U would be)

    @property
    def deviation(self) -> float | None:
        return None if self.nominal is None or self.actual is None else self.actual - self.nominal

    @property
    def ok(self) -> bool | None:
        """True within tolerance, False outside, None when there is no nominal to compare with."""
        d = self.deviation
        if d is None:
            return None
        return bool(self.lower - 1e-12 <= d <= self.upper + 1e-12)

    @property
    def out_of_tolerance(self) -> float:
        d = self.deviation
        if d is None:
            return 0.0
        return max(d - self.upper, self.lower - d, 0.0)

    @property
    def tolerance_text(self) -> str:
        u = "°" if self.unit == "deg" else ""
        if self.lower == 0.0:
            if self.name.startswith(("position", "⊕", "◎")):
                return f"⌀ {self.upper:.4f}" + (f" | {self.datums}" if self.datums else "")
            return f"≤ {self.upper:.4f}{u}" + (f" | {self.datums}" if self.datums else "")
        if self.upper == -self.lower:
            return f"± {self.upper:.4f}{u}"
        return f"+{self.upper:.4f}/{self.lower:.4f}{u}"

    @property
    def verdict(self) -> str:
        ok = self.ok
        if self.check:
            return "check"
        return "no nominal" if ok is None else ("pass" if ok else "FAIL")


def _unit(v: Any) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    return v / np.linalg.norm(v)


def _arr(v: Any) -> np.ndarray:
    return np.asarray(v, dtype=np.float64).reshape(3)


def true_position(kind: str, geometry: dict[str, Any], nominal: dict[str, Any]) -> float | None:
    """Position deviation as a diameter (mm), or None when the geometry and nominal do not compare."""
    g, n = geometry, nominal
    if kind in ("circle", "cylinder") and "direction" in n:
        axis = _unit(n["direction"])
        origin = _arr(n["point"] if "point" in n else n["center"])
        actual = _arr(g["center"] if kind == "circle" else g["point"])
        rel = actual - origin
        return 2.0 * float(np.linalg.norm(rel - (rel @ axis) * axis))
    if kind == "circle" and "center" in n:
        return 2.0 * float(np.linalg.norm(_arr(g["center"]) - _arr(n["center"])))
    if kind == "sphere" and "center" in n:
        return 2.0 * float(np.linalg.norm(_arr(g["center"]) - _arr(n["center"])))
    if kind == "cone" and "apex" in n:
        return 2.0 * float(np.linalg.norm(_arr(g["apex"]) - _arr(n["apex"])))
    return None


def characteristics(name: str, kind: str, geometry: dict[str, Any], nominal: dict[str, Any] | None,
                    tolerance: dict[str, float] | None = None) -> list[Characteristic]:
    """The toleranced characteristics of one feature (see the module docstring)."""
    tol = {**DEFAULT_TOLERANCE, **(tolerance or {})}
    pos_tol = float(tol.get("position", 2.0 * tol["location"]))
    ang_tol = float(tol.get("angle", DEFAULT_ANGLE_TOLERANCE))
    nom = nominal or {}
    comparable = nom.get("kind") in COMPARABLE.get(kind, ())
    note = "" if comparable or not nom else f"the nominal is a {nom.get('kind')}, not comparable"
    g = geometry
    out: list[Characteristic] = []
    if kind in ("circle", "sphere", "cylinder") and "radius" in g:
        n = 2.0 * float(nom["radius"]) if comparable and "radius" in nom else None
        upper, lower = float(tol.get("size_upper", tol["size"])), float(tol.get("size_lower", -tol["size"]))
        out.append(Characteristic(name, "diameter", n, 2.0 * float(g["radius"]), upper, lower,
                                  note=note or ("" if n is not None else "no nominal diameter")))
    if kind == "cone" and "half_angle" in g:
        n = math.degrees(float(nom["half_angle"])) if comparable and "half_angle" in nom else None
        out.append(Characteristic(name, "half angle", n, math.degrees(float(g["half_angle"])), ang_tol, -ang_tol,
                                  unit="deg", note=note or ("" if n is not None else "no nominal angle")))
    if kind == "plane":
        loc = None
        if comparable and "normal" in nom and "point" in g:
            loc = float((_arr(g["point"]) - _arr(nom["point"])) @ _unit(nom["normal"]))
        out.append(Characteristic(name, "location (along the normal)", None if loc is None else 0.0,
                                  loc, tol["location"], -tol["location"],
                                  note=note or ("" if loc is not None else "no nominal plane")))
    elif kind in ("circle", "sphere", "cylinder", "cone"):
        tp = true_position(kind, g, nom) if comparable else None
        out.append(Characteristic(name, "position ⌀", None if tp is None else 0.0, tp,
                                  pos_tol, 0.0, note=note or ("" if tp is not None else "no nominal location")))
    if kind in FORM_NAMES and "form" in g:
        out.append(Characteristic(name, FORM_NAMES[kind], 0.0, float(g["form"]), tol["form"], 0.0))
    alternative = g.get("alternative")
    if alternative:
        alt = {c.name: c for c in characteristics(name, kind, alternative, nominal, tolerance)}
        out = [replace(c, check=f"another {kind} fits the hits better: {c.name} "
                                f"{_value_text(alt[c.name].actual, c.unit)} there") for c in out]
    return out


def _value_text(v: float | None, unit: str) -> str:
    return "—" if v is None else (f"{v:.4f}°" if unit == "deg" else f"{v:.4f}")


def verdict(chars: list[Characteristic]) -> tuple[str, int, int]:
    """("CHECK" | "PASS" | "FAIL" | "INCOMPLETE", failed count, not evaluated count); CHECK: a feature
    needs the operator's check (another solution fits its hits better), whatever its values."""
    failed = sum(c.ok is False for c in chars)
    missing = sum(c.ok is None for c in chars)
    if any(c.check for c in chars):
        return "CHECK", failed, missing
    if failed:
        return "FAIL", failed, missing
    return ("INCOMPLETE" if missing else "PASS"), failed, missing


def _how(result: dict[str, Any], note: str) -> str:
    """A constructed value's note: how it was measured (its projection), then what is missing."""
    return "; ".join(x for x in (str(result.get("projection") or ""), note) if x)


def constructed_characteristics(name: str, result: dict[str, Any], nominal: dict[str, Any] | None,
                                tolerance: dict[str, float] | None = None) -> list[Characteristic]:
    """Characteristics of a constructed feature (``Constructed.summary()`` dicts): a distance (+- location),
    an angle (+- angle, degrees), a point's true position (diameter); a line has none of its own."""
    tol = {**DEFAULT_TOLERANCE, **(tolerance or {})}
    kind = result.get("kind")
    nom = nominal if nominal and nominal.get("kind") == kind else None
    unc = result.get("uncertainty") or {}
    why = str(unc.get("why", "no uncertainty: constructed before the station propagated one")) if not unc.get("U") \
        else ""
    u = {"uncertainty": float(unc["U"]), "uncertainty_k": float(unc["k"])} if unc.get("U") else {"uncertainty_why": why}
    if kind == "distance":
        n = None if nom is None else float(nom["value"])
        return [Characteristic(name, "distance", n, float(result["value"]), tol["location"], -tol["location"],
                               note=_how(result, "" if n is not None else "no nominal: an operand has none"), **u)]
    if kind == "angle":
        t = float(tol.get("angle", DEFAULT_ANGLE_TOLERANCE))
        n = None if nom is None else float(nom["value"])
        return [Characteristic(name, "angle", n, float(result["value"]), t, -t, unit="deg",
                               note=_how(result, "" if n is not None else "no nominal: an operand has none"), **u)]
    if kind == "point":
        tp = None if nom is None else 2.0 * float(np.linalg.norm(_arr(result["point"]) - _arr(nom["point"])))
        return [Characteristic(name, "position ⌀", None if tp is None else 0.0, tp,
                               float(tol.get("position", 2.0 * tol["location"])), 0.0,
                               note="" if tp is not None else "no nominal: an operand has none")]
    return []
