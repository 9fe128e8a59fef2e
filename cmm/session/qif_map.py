"""How the station's features and characteristics map onto QIF 3 (ISO 23952) types, and the expanded
uncertainty each characteristic carries.

The writer (:mod:`cmm.session.qif`) asks this module three things per characteristic: the QIF characteristic
type (``Diameter``, ``Position``, ``Flatness`` ...), which family its definition belongs to (a ``Tolerance`` with
limits around a target, or a ``ToleranceValue`` zone), and its expanded uncertainty U (k = 2, or its budget's own k).

**Expanded uncertainty (the hook).** :func:`expanded_uncertainty` first takes the characteristic's own U when
it carries one (an attribute ``expanded_uncertainty``, ``U`` or ``uncertainty`` on the
:class:`~cmm.metrology.characteristics.Characteristic`: the station's uncertainty budget, when it has one, goes
there). Without it, it gives what the station has today: twice the least-squares scatter-based standard
uncertainty of the fitted quantity (``uncertainty`` in the fit summary: diameter, centre / axis position, cone
half angle), scaled to the characteristic (a position is a diameter: 2 x the centre's). Form, orientation and
other zone values have no scatter-based value: their U is not written (None).
"""

from __future__ import annotations

import math
from typing import Any

QIF_NS = "http://qifstandards.org/xsd/qif3"
COVERAGE_FACTOR = 2.0

# station feature kind -> QIF feature type prefix
FEATURE_TYPES = {"plane": "Plane", "circle": "Circle", "cylinder": "Cylinder", "sphere": "Sphere", "cone": "Cone",
                 "line": "Line", "point": "Point"}

# characteristic name (Characteristic.name, lower case, without symbols) -> (QIF type, family)
# families: "limits" (Tolerance MaxValue / MinValue around a TargetValue, the value is the size itself),
#           "zone" (ToleranceValue, the value is the zone width), "user" (user-defined linear)
_TYPES = {
    "diameter": ("Diameter", "limits"),
    "half angle": ("Angle", "angular"),
    "distance": ("DistanceBetween", "limits"),
    "angle": ("AngleBetween", "angular"),
    "location (along the normal)": ("UserDefinedLinear", "user"),
    "position": ("Position", "zone"),
    "flatness": ("Flatness", "zone"),
    "straightness": ("Straightness", "zone"),
    "roundness": ("Circularity", "zone"),
    "circularity": ("Circularity", "zone"),
    "cylindricity": ("Cylindricity", "zone"),
    "cone form": ("Conicity", "zone"),
    "sphericity": ("OtherForm", "zone"),  # QIF's Sphericity measurement needs the zone's radii and point
    "parallelism": ("Parallelism", "zone"),
    "perpendicularity": ("Perpendicularity", "zone"),
    "angularity": ("Angularity", "zone"),
    "concentricity": ("Concentricity", "zone"),
    "coaxiality": ("Coaxiality", "zone"),
    "circular runout": ("CircularRunout", "zone"),
    "total runout": ("TotalRunout", "zone"),
    "profile of a surface": ("SurfaceProfile", "zone"),
    "profile of a line": ("LineProfile", "zone"),
}
ORIENTATION = ("Parallelism", "Perpendicularity", "Angularity")
WITH_ZONE_SHAPE = ORIENTATION + ("Straightness", "Concentricity", "Coaxiality")


def plain_name(name: str) -> str:
    """A characteristic's name without its symbols ("position ⌀" -> "position", "⟂ perpendicularity" ...)."""
    words = [w for w in name.replace("⌀", " ").split() if any(ch.isalpha() for ch in w)]
    return " ".join(words).strip().lower()


def qif_type(name: str, feature_kind: str = "") -> tuple[str, str]:
    """(QIF characteristic type, family) of a characteristic's name; a sphere's diameter is spherical."""
    key = plain_name(name)
    t = _TYPES.get(key)
    if t is None:
        for k, v in _TYPES.items():
            if key.startswith(k) or k in key:
                t = v
                break
    if t is None:
        t = ("UserDefinedLinear", "user")
    if t[0] == "Diameter" and feature_kind == "sphere":
        return "SphericalDiameter", "limits"
    return t


def status(c: Any) -> str:
    """The QIF characteristic status of a station verdict: pass / FAIL / check / no nominal."""
    if c.check:
        return "INDETERMINATE"
    ok = c.ok
    return "NOT_ANALYZED" if ok is None else ("PASS" if ok else "FAIL")


def _u(fit: dict, *keys: str) -> float | None:
    unc = (fit or {}).get("uncertainty") or {}
    for k in keys:
        v = unc.get(k)
        if isinstance(v, (int, float)) and math.isfinite(v):
            return float(v)
    return None


def coverage_factor(c: Any) -> float:
    """The coverage factor of ``expanded_uncertainty``: the characteristic's own (its budget's: 2, or Student's t
    for few degrees of freedom), else COVERAGE_FACTOR (the fit's scatter-based U)."""
    k = getattr(c, "uncertainty_k", None)
    if isinstance(k, (int, float)) and math.isfinite(k) and k > 0 and isinstance(getattr(c, "uncertainty", None),
                                                                               (int, float)):
        return float(k)
    return COVERAGE_FACTOR


def expanded_uncertainty(c: Any, fit: dict | None = None) -> float | None:
    """U (k: ``coverage_factor``) of a characteristic in its unit (mm, degrees), or None when the station has none for it.
    See the module docstring: the characteristic's own U first, else the fit's scatter-based one."""
    for attr in ("expanded_uncertainty", "U", "uncertainty"):
        v = getattr(c, attr, None)
        if isinstance(v, (int, float)) and math.isfinite(v) and v >= 0:
            return float(v)
    if c.actual is None or not fit:
        return None
    key = plain_name(c.name)
    k = COVERAGE_FACTOR
    if key == "diameter":
        u = _u(fit, "diameter")
        if u is None:
            u2 = _u(fit, "radius")
            u = None if u2 is None else 2.0 * u2
        return None if u is None else k * u
    if key == "position":
        u = _u(fit, "center", "apex", "axis_position", "position")
        return None if u is None else k * 2.0 * u  # the position is a diameter: twice the centre's offset
    if key.startswith("location"):
        u = _u(fit, "position")
        return None if u is None else k * u
    if key == "half angle":
        u = _u(fit, "half_angle")
        return None if u is None else k * math.degrees(u)
    return None
