"""Feature control frames: datum and tolerance definitions evaluated against measured features.

The one code path from definitions to the numbers the feature tree, the report, the JSON/CSV export and
re-evaluation show. Definitions are plain JSON-ready dicts (they are journalled as ``datum`` and ``gdt``
events, see :mod:`cmm.session.model`):

- datum: ``{"label": "A", "feature": 3, "modifier": "" | "MMB" | "LMB"}`` (the boundary of a datum at
  MMB/LMB is its MMC / LMC size from the feature's nominal diameter and size tolerance; a datum's direction
  takes the sense of its feature's nominal, e.g. a plane's outward normal);
- tolerance: ``{"id", "name", "characteristic" (see :data:`cmm.metrology.gdt.CHARACTERISTICS`), "feature"
  (id), "tolerance" (mm), "datums" (["A", "B", "C"], precedence order), "material" ("" | "MMC" | "LMC"),
  "angle" (degrees, angularity), "direction" ("radial" | "axial", runout)}``.

A feature is a :class:`MeasuredFeature`: its name, kind, fit summary (geometry), nominal (a
``NominalFeature.to_dict()`` in the same coordinates), measured points, and its size tolerance. The CAD
``mesh`` and ``pose`` (part -> measured coordinates) serve profiles.

:func:`evaluate` gives one :class:`~cmm.metrology.characteristics.Characteristic` per definition: nominal 0,
actual the zone, upper the tolerance plus any bonus, ``datums`` the frame ("A|B|C"); a definition that cannot
be evaluated (a datum not defined, a feature deleted, no mesh for a profile) is listed with no actual and the
reason in its note: it shows as "not evaluated", never as a pass.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import gdt
from .characteristics import DEFAULT_TOLERANCE, Characteristic
from .datums import DRF, DatumError, build_drf, datum_from_feature

MATERIAL_SYMBOL = {"MMC": "(M)", "LMC": "(L)"}


@dataclass(frozen=True)
class MeasuredFeature:
    name: str
    kind: str
    geometry: dict[str, Any]
    nominal: dict[str, Any] | None = None
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    size_tolerance: float = DEFAULT_TOLERANCE["size"]  # +- on the diameter


def check_definition(d: dict[str, Any]) -> dict[str, Any]:
    """A tolerance definition checked and normalised (raises GdtError in words)."""
    ch = str(d.get("characteristic", "")).strip().lower()
    if ch not in gdt.CHARACTERISTICS:
        raise gdt.GdtError(f"unknown geometric tolerance {ch!r}; use one of {', '.join(gdt.CHARACTERISTICS)}")
    tol = gdt._check_tol(d.get("tolerance", 0), ch)  # noqa: SLF001 - the same check as the functions
    datums = [str(x).strip().upper() for x in d.get("datums") or [] if str(x).strip()]
    if ch in gdt.FORM and datums:
        raise gdt.GdtError(f"{ch} is a form tolerance: it takes no datums")
    if ch in gdt.NEEDS_DATUMS and not datums:
        raise gdt.GdtError(f"{ch} needs a datum (e.g. A)")
    material = str(d.get("material") or "").upper().replace("RFS", "")
    if material not in ("", "MMC", "LMC"):
        raise gdt.GdtError(f"unknown material condition {material!r}; use MMC, LMC or none (RFS)")
    if material and ch != "position":
        raise gdt.GdtError("a material condition (MMC/LMC) applies here only to position")
    angle = d.get("angle")
    if ch == "angularity":
        try:
            angle = float(angle)
        except (TypeError, ValueError):
            raise gdt.GdtError("angularity needs the basic angle in degrees") from None
    direction = str(d.get("direction") or "radial")
    if direction not in ("radial", "axial"):
        raise gdt.GdtError(f"a runout is radial or axial, got {direction!r}")
    out = {**d, "characteristic": ch, "tolerance": tol, "datums": datums, "material": material,
           "angle": None if angle is None else float(angle), "direction": direction}
    return out


def check_datum(d: dict[str, Any]) -> dict[str, Any]:
    label = str(d.get("label", "")).strip().upper()
    if not label or not label.isalpha() or len(label) > 2:
        raise DatumError(f"a datum label is a letter (A, B, C ...), got {d.get('label')!r}")
    modifier = str(d.get("modifier") or "").upper().replace("RFS", "").replace("RMB", "")
    if modifier not in ("", "MMB", "LMB"):
        raise DatumError(f"datum {label}: unknown modifier {modifier!r}; use MMB, LMB or none (RFS)")
    return {**d, "label": label, "modifier": modifier, "feature": int(d["feature"])}


def _internal(f: MeasuredFeature) -> bool | None:
    n = f.nominal or {}
    return None if "bore" not in n else bool(n["bore"])


def _size_limits(f: MeasuredFeature) -> tuple[float, float] | None:
    n = f.nominal or {}
    if "radius" not in n:
        return None
    d = 2.0 * float(n["radius"])
    return d - f.size_tolerance, d + f.size_tolerance


def datum_of(label: str, defs: dict[str, dict], feats: dict[int, MeasuredFeature], nominal: bool) -> Any:
    d = defs.get(label)
    if d is None:
        raise DatumError(f"datum {label} is not defined: choose its datum feature first")
    f = feats.get(int(d["feature"]))
    if f is None:
        raise DatumError(f"the datum feature of {label} (feature {d['feature']}) is not measured")
    modifier = d.get("modifier") or ""
    boundary = internal = None
    if modifier:
        limits, internal = _size_limits(f), _internal(f)
        if limits is None or internal is None:
            raise DatumError(f"datum {label} at {modifier} needs the nominal size of {f.name} (a hole or a pin)")
        mmc = limits[0] if internal else limits[1]
        lmc = limits[1] if internal else limits[0]
        boundary = mmc if modifier == "MMB" else lmc
    if nominal:
        n = f.nominal
        if not n or n.get("kind") in (None, "surface"):
            raise DatumError(f"datum {label} ({f.name}) has no nominal: the nominal frame cannot be built")
        kind = {"plane": "plane", "cylinder": "cylinder", "sphere": "sphere", "cone": "cone"}[n["kind"]]
        if f.kind == "circle" and kind == "cylinder":
            kind = "cylinder"
        return datum_from_feature(label, kind, n, feature=f.name)
    return datum_from_feature(label, f.kind, _signed_like_nominal(f), modifier=modifier, boundary=boundary,
                              internal=internal, feature=f.name)


def _signed_like_nominal(f: MeasuredFeature) -> dict[str, Any]:
    """The feature's geometry with its normal / axis direction turned to agree with its nominal's (a fitted
    plane's normal has no side; the nominal's points out of the material), so the actual and nominal frames
    have the same sense."""
    n = f.nominal or {}
    ref = n.get("normal", n.get("direction"))
    g = dict(f.geometry)
    key = "normal" if "normal" in g else "direction" if "direction" in g else None
    if ref is None or key is None:
        return g
    v = np.asarray(g[key], dtype=np.float64)
    if float(v @ np.asarray(ref, dtype=np.float64)) < 0:
        g[key] = (-v).tolist()
    return g


def build_frames(labels: list[str], datums: dict[str, dict], feats: dict[int, MeasuredFeature],
                 nominal: bool) -> tuple[DRF | None, DRF | None]:
    """The actual DRF of ``labels`` and, with ``nominal``, the same frame built from the datum features'
    nominals (None, None without labels)."""
    if not labels:
        return None, None
    actual = build_drf([datum_of(x, datums, feats, False) for x in labels])
    nom = build_drf([datum_of(x, datums, feats, True) for x in labels]) if nominal else None
    return actual, nom


def evaluate_one(d: dict[str, Any], datums: dict[str, dict], feats: dict[int, MeasuredFeature], mesh: Any = None,
                 pose: Any = None) -> gdt.GdtResult:
    """One tolerance definition evaluated (raises GdtError / DatumError in words)."""
    d = check_definition(d)
    ch = d["characteristic"]
    f = feats.get(int(d["feature"]))
    if f is None:
        raise gdt.GdtError(f"feature {d['feature']} is not measured (deleted?)")
    for label in d["datums"]:
        dd = datums.get(label)
        if dd is not None and int(dd["feature"]) == int(d["feature"]):
            raise gdt.GdtError(f"{f.name} is datum {label}: a feature is not toleranced against itself")
    tol = d["tolerance"]
    needs_nominal = ch in ("position", "profile of a surface", "profile of a line")
    drf, ndrf = build_frames(d["datums"], datums, feats, needs_nominal)
    if ch in gdt.FORM:
        return gdt.form(ch, f.points, tol)
    if ch in gdt.ORIENTATION:
        return gdt.orientation(ch, f.kind, f.geometry, f.points, drf, tol, angle_deg=d["angle"],  # type: ignore[arg-type]
                               nominal_direction=_nominal_direction(f, d["datums"], datums, feats))
    if ch == "position":
        if not f.nominal or f.nominal.get("kind") == "surface":
            raise gdt.GdtError(f"position of {f.name} needs its nominal location (CAD pick or typed)")
        return gdt.position(f.kind, f.geometry, f.nominal, tol, drf=drf, nominal_drf=ndrf,
                            points=f.points if len(f.points) else None, material=d["material"],
                            size_limits=_size_limits(f), internal=_internal(f))
    if ch in ("concentricity", "coaxiality"):
        return gdt.coaxiality(ch, f.kind, f.geometry, drf, tol, points=f.points if len(f.points) else None)  # type: ignore[arg-type]
    if ch in ("circular runout", "total runout"):
        return gdt.runout(ch, f.points, drf, tol, d["direction"])  # type: ignore[arg-type]
    if pose is None and mesh is not None:
        raise gdt.GdtError("profile tolerance needs the part's pose (an alignment or the nominal set-up)")
    return gdt.profile(ch, f.points, mesh, pose, tol, drf=drf, nominal_drf=ndrf)


def _nominal_direction(f: MeasuredFeature, labels: list[str], datums: dict[str, dict],
                       feats: dict[int, MeasuredFeature]) -> np.ndarray | None:
    """With a secondary datum: the feature's nominal normal / axis in the nominal DRF, which orients the
    zone about the primary; None (rotation free) without one, or when a nominal is missing."""
    n = f.nominal or {}
    v = n.get("normal", n.get("direction"))
    if len(labels) < 2 or v is None:
        return None
    try:
        _, ndrf = build_frames(labels, datums, feats, True)
    except DatumError:
        return None
    return None if ndrf is None else ndrf.vector_to_local(np.asarray(v, dtype=np.float64))


def tolerance_text(d: dict[str, Any]) -> str:
    """The feature control frame in one line: "⊕ ⌀0.0500(M) | A|B|C"."""
    ch = d.get("characteristic", "")
    dia = "⌀" if ch in ("position", "coaxiality", "concentricity") else ""
    head = f"{gdt.SYMBOLS.get(ch, '')} {dia}{float(d.get('tolerance', 0)):.4f}{MATERIAL_SYMBOL.get(d.get('material') or '', '')}"
    return head + (f" | {'|'.join(d.get('datums') or [])}" if d.get("datums") else "")


def evaluate(definitions: list[dict[str, Any]], datums: dict[str, dict], feats: dict[int, MeasuredFeature],
             mesh: Any = None, pose: Any = None) -> list[tuple[dict[str, Any], Characteristic]]:
    """Every definition as a Characteristic (see the module docstring), with its definition."""
    out = []
    for d in definitions:
        f = feats.get(int(d.get("feature", -1)))
        fname = f.name if f is not None else f"feature {d.get('feature')}"
        name = str(d.get("name") or d.get("characteristic"))
        label = f"{gdt.SYMBOLS.get(str(d.get('characteristic')), '')} {d.get('characteristic')}".strip()
        try:
            r = evaluate_one(d, datums, feats, mesh, pose)
        except (DatumError, ValueError, KeyError) as exc:
            msg = str(exc) if not isinstance(exc, KeyError) else f"missing {exc}"
            out.append((d, Characteristic(fname, label, None, None, float(d.get("tolerance") or 0.0), 0.0,
                                          note=f"{name}: not evaluated: {msg}",
                                          datums="|".join(d.get("datums") or []))))
            continue
        note = f"{name}: {r.note}"
        out.append((d, Characteristic(fname, r.label, 0.0, r.value, r.allowed, 0.0, note=note,
                                      datums=r.drf)))
    return out
