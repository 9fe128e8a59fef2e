"""DMIS tolerances (``T(..) = TOL/..``) evaluated on actual features: the value and INTOL / OUTOL.

Size (DIAM, RAD), distance and angle between two features (DISTB, ANGLB) report the deviation from the nominal;
the geometric tolerances are the GD&T functions' (:mod:`cmm.metrology.gdt`, ISO 1101) with the datum reference
frame of the tolerance's ``DAT(..)`` (:func:`cmm.metrology.datums.build_drf` of the DATDEF features), form,
orientation, runout and CONCEN through the station's dispatcher (:func:`cmm.metrology.gdt_eval.evaluate_one`): form
(FLAT, STRGHT, CIRLTY, CYLCTY) the minimum zone of the hits (the fit's form for other kinds); orientation
(PARLEL, PERPEND, ANGLR) the zone at the basic angle to the datum holding a plane's hits or an axis over its
length; POS the position zone's diameter, the actual in the actual datum frame against the nominal in the frame
of the datum features' nominals (the design frame: every nominal moved by the coordinate systems the program built
from the datums' nominals; without datums: against the FEAT nominal, moved with the part by the program's alignments
since, as the station's report has it); RUNOUT circular (per section) or
TOTAL, radial or axial for a face; CONCEN concentricity (a centre) or coaxiality (an axis). PROFS / PROFL: the
deviations of the hits from the FEAT nominal surface (twice the largest; with unequal lower and upper limits
twice the largest distance from the zone's middle, as an ISO 1101 UZ zone).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..metrology import gdt
from ..metrology.construct import construct
from ..metrology.datums import DRF, DatumError, build_drf, datum_from_feature
from ..metrology.features import FitError
from ..metrology.gdt_eval import MeasuredFeature, evaluate_one
from .features import Actual, Nominal

SIZE = ("DIAM", "RAD")
FORM = {"FLAT": ("plane",), "STRGHT": ("line", "cylinder", "cone"), "CIRLTY": ("circle", "sphere", "cylinder", "cone"),
        "CYLCTY": ("cylinder",)}
# DMIS word -> the GD&T characteristic (cmm.metrology.gdt); form of these kinds is the minimum zone of the hits
GDT_FORM = {("FLAT", "plane"): "flatness", ("STRGHT", "line"): "straightness", ("CIRLTY", "circle"): "circularity",
            ("CYLCTY", "cylinder"): "cylindricity"}
GDT_ORIENT = {"PARLEL": "parallelism", "PERPEND": "perpendicularity", "ANGLR": "angularity"}
ORIENT = ("PARLEL", "PERPEND", "ANGLR")
ALL = ("DIAM", "RAD", "DISTB", "ANGLB", "FLAT", "STRGHT", "CIRLTY", "CYLCTY", "PARLEL", "PERPEND", "ANGLR", "POS",
       "PROFS", "PROFL", "RUNOUT", "CONCEN")
AXIAL = ("line", "cylinder", "cone", "circle")


SIZE_KINDS = ("circle", "cylinder", "sphere")
POS_KINDS = ("point", "circle", "cylinder", "sphere", "cone")
SIZE_NEEDS = "TOL/{word} needs a circle, cylinder or sphere with a nominal diameter; FA({label}) is a {kind}"
POS_NEEDS = "TOL/POS needs a point, circle, cylinder, sphere or cone with a nominal; FA({label}) is a {kind}"


def kind_problem(word: str, kind: str, label: str) -> str | None:
    """TOL/<word> output on FA(label), a <kind>: what the run refuses for that kind, in its words (None: accepted).
    The check before a run reads the kinds from the FEAT statements and says the same."""
    if word in FORM and kind not in FORM[word]:
        return f"TOL/{word} applies to a {' or '.join(FORM[word])}, FA({label}) is a {kind}"
    if word in SIZE and kind not in SIZE_KINDS:
        return SIZE_NEEDS.format(word=word, label=label, kind=kind)
    if word == "POS" and kind not in POS_KINDS:
        return POS_NEEDS.format(label=label, kind=kind)
    return None


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
    material: str = ""  # POS: the feature's material condition, MMC / LMC ("": RFS)
    datum_material: dict[str, str] = field(default_factory=dict)  # DAT name -> MMC / LMC (its boundary)
    text: str = ""  # its TOL statement as the output file writes it (OUTPUT/F(..), T(..) prints the definition)


@dataclass
class Evaluation:
    tolerance: Tolerance
    value: float  # the deviation (sizes, distances, angles) or the zone (form, orientation, position ...)
    intol: bool
    features: list[str]
    bonus: float = 0.0  # POS at MMC / LMC: the bonus tolerance the feature's actual size gives
    note: str = ""  # how the value was taken (material condition, datum shift), for the output's comment

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


def _signed(a: Actual) -> dict[str, Any]:
    """The actual's geometry with its direction signed like its nominal (datum frames depend on the sign)."""
    g = dict(a.geometry)
    d = a.direction()
    if d is not None:
        g["normal" if "normal" in g else "direction"] = d.tolist()
    return g


def _nominal_geometry(nom: Nominal) -> tuple[str, dict[str, Any]]:
    """(kind, geometry) of a FEAT nominal as a fit would give it."""
    p, v = nom.point.tolist(), None if nom.vector is None else nom.vector.tolist()
    r = None if nom.diameter is None else nom.diameter / 2.0
    kind = nom.kind
    if kind == "circle":
        return kind, {"center": p, "normal": v, "radius": r}
    if kind == "sphere":
        return kind, {"center": p, "radius": r}
    if kind == "cone":
        return kind, {"apex": p, "direction": v, "half_angle": (nom.angle or 0.0) / 2.0}
    if kind == "plane":
        return kind, {"point": p, "normal": v}
    out = {"point": p, "direction": v}
    if r is not None:
        out["radius"] = r
    return kind, out


def _drf(names: list[str], datums: dict[str, Actual], nominal: bool = False, *,
         material: dict[str, str] | None = None, sizes: dict[str, tuple[float, float]] | None = None) -> DRF:
    """The datum reference frame of DAT(..) names: from the actual datum features, or their nominals. A datum
    at MMC / LMC (``material``) is referenced at its boundary: the MMC (LMC) size of its size limits
    (``sizes``, from the TOL/DIAM output with it), so the frame may shift by its departure from it."""
    out = []
    for name in names[:3]:
        d = datums[name]
        if nominal:
            if d.nominal is None:
                raise ToleranceError(f"DAT({name}) (FA({d.label})) has no nominal to build the nominal frame from")
            kind, g = _nominal_geometry(d.nominal.design or d.nominal)
            out.append(datum_from_feature(name, kind, g, feature=d.label))
            continue
        kind, g = d.kind, _signed(d)
        mod = (material or {}).get(name, "")
        if mod:
            limits = (sizes or {}).get(d.label)
            if limits is None or d.nominal is None or d.nominal.inner is None:
                raise ToleranceError(f"DAT({name}) at {mod} needs FA({d.label})'s size limits: output its TOL/DIAM "
                                     f"first (OUTPUT/FA({d.label}), TA(..))")
            internal = bool(d.nominal.inner)
            low, high = limits
            boundary = (low if internal else high) if mod == "MMC" else (high if internal else low)
            out.append(datum_from_feature(name, kind, g, modifier="MMB" if mod == "MMC" else "LMB",
                                          boundary=boundary, internal=internal, feature=d.label))
        else:
            out.append(datum_from_feature(name, kind, g, feature=d.label))
    return build_drf(out)


def evaluate(tol: Tolerance, features: list[Actual], datums: dict[str, Actual], frame: np.ndarray,
             sizes: dict[str, tuple[float, float]] | None = None) -> Evaluation:
    """Evaluate ``tol`` on the features an OUTPUT statement names with it. ``sizes``: feature label -> its
    (low, high) diameter limits, from the TOL/DIAM (RAD) evaluated on it (for POS at MMC / LMC)."""
    try:
        return _evaluate(tol, features, datums, frame, sizes or {})
    except (gdt.GdtError, DatumError) as exc:
        raise ToleranceError(f"T({tol.label}) (TOL/{tol.word}): {exc}") from None


def _evaluate(tol: Tolerance, features: list[Actual], datums: dict[str, Actual], frame: np.ndarray,
              sizes: dict[str, tuple[float, float]]) -> Evaluation:
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
        if a.kind not in SIZE_KINDS or nom is None or nom.diameter is None:
            raise ToleranceError(SIZE_NEEDS.format(word=w, label=a.label, kind=a.kind))
        dev = 2.0 * float(a.geometry["radius"]) - nom.diameter
        if w == "RAD":
            dev /= 2.0
        return Evaluation(tol, dev, lo - 1e-12 <= dev <= up + 1e-12, [a.label])
    if w in ("DISTB", "ANGLB"):
        b = features[1]
        note = ""
        try:
            if w == "ANGLB":
                value = construct("angle", (a.kind, a.geometry), (b.kind, b.geometry)).value
            elif any(o in ("XAXIS", "YAXIS", "ZAXIS") for o in tol.options):
                axis = frame[:3, {"XAXIS": 0, "YAXIS": 1, "ZAXIS": 2}[next(o for o in tol.options if o.endswith("AXIS"))]]
                value = abs(float((b.location() - a.location()) @ axis))
            elif a.kind in AXIAL and b.kind in AXIAL and _nearly_parallel(a, b):
                value = _axis_distance(a, b)
            else:
                c = construct("distance", (a.kind, a.geometry), (b.kind, b.geometry))
                value, note = c.value, c.warning
        except (FitError, ValueError, KeyError) as exc:
            raise ToleranceError(f"TOL/{w} between FA({a.label}) and FA({b.label}): {exc}") from None
        dev = float(value) - float(tol.nominal or 0.0)
        return Evaluation(tol, dev, lo - 1e-12 <= dev <= up + 1e-12, [a.label, b.label], note=note)
    if w in FORM:
        if (problem := kind_problem(w, a.kind, a.label)) is not None:
            raise ToleranceError(problem)
        characteristic = GDT_FORM.get((w, a.kind))
        if characteristic is not None and a.hit_points is not None and up > 0:
            value = _station(characteristic, up, a, [], datums).value
        else:
            value = float(a.geometry["form"])
    elif w in ORIENT:
        if not dat:
            raise ToleranceError(f"TOL/{w} needs a datum: TOL/{w}, zone, DAT(A)")
        _points(a)
        value = _station(GDT_ORIENT[w], up, a, tol.datums, datums, angle=tol.nominal if w == "ANGLR" else None).value
    elif w == "POS":
        # DMIS defines position's inputs its own way: the nominals are the design ones (moved by the coordinate
        # systems the program built from the datums' nominals, not each FEAT's own alignment), and the size
        # limits of the feature and of a datum at MMC / LMC are the program's TOL/DIAM outputs; the zone is
        # gdt.position's, as in gdt_eval
        nom = a.nominal
        if nom is None or a.kind not in POS_KINDS:
            raise ToleranceError(POS_NEEDS.format(label=a.label, kind=a.kind))
        drf = _drf(tol.datums, datums, material=tol.datum_material, sizes=sizes) if dat else None
        ndrf = _drf(tol.datums, datums, nominal=True) if dat else None
        _, nominal = _nominal_geometry((nom.design or nom) if dat else nom)
        limits = sizes.get(a.label)
        if tol.material and (limits is None or nom.inner is None):
            raise ToleranceError(f"T({tol.label}) at {tol.material} needs FA({a.label})'s size limits: output its "
                                 f"TOL/DIAM first (OUTPUT/FA({a.label}), TA(..))")
        kind, geometry, points = a.kind, _signed(a), a.hit_points
        kind, geometry, nominal, points = _dimension(tol, kind, geometry, nominal, points, frame)
        res = gdt.position(kind, geometry, nominal, up, drf=drf, nominal_drf=ndrf, points=points,
                           material=tol.material, size_limits=limits if tol.material else None,
                           internal=None if nom.inner is None else bool(nom.inner))
        return Evaluation(tol, res.value, res.value <= res.allowed + 1e-12, [a.label], bonus=res.bonus,
                          note=res.note if (tol.material or tol.datum_material) else "")
    elif w in ("PROFS", "PROFL"):
        # DMIS defines the profile against the FEAT nominal surface (not the CAD mesh), within its own lower
        # and upper limits; unequal limits are an unequally disposed zone of width up - lo whose middle is
        # offset by (lo + up) / 2, so the value is twice the largest |d - offset| (gdt.profile's UZ)
        d = _nominal_surface_deviation(a)
        intol = bool(np.all(d >= lo - 1e-12) and np.all(d <= up + 1e-12))
        return Evaluation(tol, 2.0 * float(np.max(np.abs(d - (lo + up) / 2.0))), intol, [a.label])
    elif w == "RUNOUT":
        if not dat:
            raise ToleranceError("TOL/RUNOUT needs a datum axis: TOL/RUNOUT, CIRCLR, zone, DAT(A)")
        _points(a)
        value = _station("total runout" if "TOTAL" in tol.options else "circular runout", up, a, tol.datums, datums,
                         direction="axial" if a.kind == "plane" else "radial").value
    elif w == "CONCEN":
        if not dat:
            raise ToleranceError("TOL/CONCEN needs a datum axis: TOL/CONCEN, zone, DAT(A)")
        value = _station("concentricity" if a.kind in ("circle", "sphere", "point") else "coaxiality", up, a,
                         tol.datums, datums).value
    else:
        raise ToleranceError(f"TOL/{w} is not supported")
    return Evaluation(tol, value, value <= up + 1e-12, [a.label])


def planar_position(tol: Tolerance, kind: str) -> str:
    """Why a TOL/POS cannot be the station's GD&T position (ISO 1101: a cylinder's axis over its length, a point's
    and a sphere's centre in space, a circle's centre across its axis): its 2D or 3D zone is DMIS's own here
    ("": it is the same)."""
    opts = set(tol.options)
    if "2D" in opts and kind in ("cylinder", "point", "sphere"):
        return f"TOL/POS, 2D on a {kind} is a circular zone across it (the station's GD&T takes it in space)"
    if "3D" in opts and kind == "circle":
        return "TOL/POS, 3D on a circle is a spherical zone (the station's GD&T takes it across the circle's axis)"
    return ""


PLANE_NORMAL = {"XYPLAN": 2, "YZPLAN": 0, "ZXPLAN": 1}  # WKPLAN -> the axis of the current system normal to it


def _dimension(tol: Tolerance, kind: str, geometry: dict[str, Any], nominal: dict[str, Any], points: Any,
               frame: np.ndarray) -> tuple[str, dict[str, Any], dict[str, Any], Any]:
    """TOL/POS, 2D or 3D as DMIS defines them: 2D a circular zone about the nominal in the plane across the
    feature (a cylinder's axis point, not its ends; a point or sphere in the working plane, WKPLAN), 3D a
    spherical zone about a point, sphere or circle centre and the cylindrical zone about a cylinder's nominal
    axis over its length. Without either, the feature's own (as ISO 1101)."""
    opts = set(tol.options)
    if "2D" in opts:
        if kind == "cylinder":
            return kind, geometry, nominal, None  # the axis point only: its offset across the nominal axis
        if kind in ("point", "sphere"):
            axis = next((PLANE_NORMAL[o] for o in opts if o in PLANE_NORMAL), 2)
            n = frame[:3, axis].tolist()
            centre = geometry.get("center", geometry.get("point"))
            nom = nominal.get("center", nominal.get("point"))
            g = {"center": centre, "normal": n, **({"radius": geometry["radius"]} if "radius" in geometry else {})}
            return "circle", g, {"center": nom, "normal": n}, None
    if "3D" in opts and kind == "circle":
        g = {"center": geometry["center"], **({"radius": geometry["radius"]} if "radius" in geometry else {})}
        return "sphere", g, {"center": nominal["center"]}, None
    return kind, geometry, nominal, points


def _measured(a: Actual) -> MeasuredFeature:
    """An actual as the station's geometric tolerances take it: its geometry signed like its nominal, its hits."""
    pts = np.zeros((0, 3)) if a.hit_points is None else np.asarray(a.hit_points, float).reshape(-1, 3)
    return MeasuredFeature(f"FA({a.label})", a.kind, _signed(a), None, pts)


def _station(characteristic: str, zone: float, a: Actual, names: list[str], datums: dict[str, Actual], *,
             angle: float | None = None, direction: str = "radial") -> gdt.GdtResult:
    """A tolerance DMIS defines as ISO 1101 does, evaluated by the station's dispatcher
    (:func:`cmm.metrology.gdt_eval.evaluate_one`): FA(..) is feature 0, the DAT(..) features (at most three,
    precedence order) are datums A, B, C of features 1, 2, 3."""
    letters = [chr(ord("A") + k) for k in range(len(names[:3]))]
    feats = {0: _measured(a), **{k + 1: _measured(datums[n]) for k, n in enumerate(names[:3])}}
    defs = {x: {"label": x, "feature": k + 1, "modifier": ""} for k, x in enumerate(letters)}
    return evaluate_one({"characteristic": characteristic, "feature": 0, "tolerance": zone, "datums": letters,
                         "angle": angle, "direction": direction}, defs, feats)


def model_tolerance(tol: Tolerance) -> dict[str, float]:
    """The measurement model's tolerance keys this DMIS tolerance sets (for the station's own report)."""
    w = tol.word
    width = max(abs(tol.lower), abs(tol.upper))
    if w in SIZE and width > 0 and tol.lower < tol.upper:  # the diameter's own limits, as the DMIS gives them
        k = 2.0 if w == "RAD" else 1.0
        return {"size": k * width, "size_lower": k * tol.lower, "size_upper": k * tol.upper}
    if w in FORM and tol.upper > 0:
        return {"form": tol.upper}
    if w == "POS" and tol.upper > 0 and not tol.datums and not tol.material:
        return {"position": tol.upper}  # a datum frame or a bonus: the station's GD&T (see Executor._to_model)
    return {}


def output_line(ev: Evaluation) -> str:
    t = ev.tolerance
    head = [t.word] + [o for o in t.options if o in ("2D", "3D", "CIRCLR", "TOTAL")]
    return f"TA({t.label}) = TOL/{', '.join(head)}, {round(ev.value, 5) + 0.0:.5f}, {ev.verdict}"
