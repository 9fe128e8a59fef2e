"""Feature control frames: datum and tolerance definitions evaluated against measured features.

The one code path from definitions to the numbers the feature tree, the report, the JSON/CSV export and
re-evaluation show. Definitions are plain JSON-ready dicts (they are journalled as ``datum`` and ``gdt``
events, see :mod:`cmm.journal.state`):

- datum: ``{"label": "A", "feature": 3, "modifier": "" | "MMB" | "LMB", "targets": [hit ids]}`` (targets: the
  datum plane through those hits of its feature, see :func:`cmm.metrology.datums.datum_from_targets`; a target
  may also be a target area or line, ``{"area": [hit ids]}`` / ``{"line": [hit ids]}``, see
  :func:`target_points`; the boundary of a datum at
  MMB/LMB is its MMC / LMC size from the feature's nominal diameter and size tolerance; a datum's direction
  takes the sense of its feature's nominal, e.g. a plane's outward normal);
- tolerance: ``{"id", "name", "characteristic" (see :data:`cmm.metrology.gdt.CHARACTERISTICS`), "feature"
  (id), "tolerance" (mm), "datums" (["A", "B", "C"], precedence order; "A-B" is the common datum of datums A
  and B, see :func:`cmm.metrology.datums.common_datum`), "material" ("" | "MMC" | "LMC"), "angle" (degrees,
  angularity), "direction" ("radial" | "axial", runout), optionally "datum_modifiers" ({"B": "MMB"}: how this
  frame references a datum, as a feature control frame says, over the datum's own modifier), optionally
  "offset" (mm, profiles: the unequally disposed zone's offset, ISO 1101 UZ, + towards the outside of the
  material, see :func:`cmm.metrology.gdt.profile`)}``; a composite
  position frame adds ``"pattern"`` (the ids of the pattern's features, "feature" among them) and
  ``"composite": {"tolerance", "datums"}`` (the feature-relating tier; its datums repeat the first of the upper
  tier's, orientation only): it gives one row per feature for the upper tier and one for the pattern's lower tier
  (:func:`cmm.metrology.gdt.composite_position`).

A feature is a :class:`MeasuredFeature`: its name, kind, fit summary (geometry), nominal (a
``NominalFeature.to_dict()`` in the same coordinates), measured points, its size tolerance, and the fit's
``alternative`` (another solution that fits the hits better, far from the nominal), if any. The CAD
``mesh`` and ``pose`` (part -> measured coordinates) serve profiles.

:func:`evaluate` gives one :class:`~cmm.metrology.characteristics.Characteristic` per definition: nominal 0,
actual the zone, upper the tolerance plus any bonus, ``datums`` the frame ("A|B|C"); a definition that cannot
be evaluated (a datum not defined, a feature deleted, no mesh for a profile) is listed with no actual and the
reason in its note: it shows as "not evaluated", never as a pass. A row whose toleranced feature (or a
feature of its pattern) or any datum feature of its frame has an ``alternative`` is marked ``check`` (its
verdict "check"): the value stands on a fit the operator must confirm.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import gdt
from .characteristics import DEFAULT_TOLERANCE, Characteristic
from .datums import DRF, DatumError, build_drf, common_datum, datum_from_feature, datum_from_targets

MATERIAL_SYMBOL = {"MMC": "(M)", "LMC": "(L)"}


@dataclass(frozen=True)
class MeasuredFeature:
    name: str
    kind: str
    geometry: dict[str, Any]
    nominal: dict[str, Any] | None = None
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    size_tolerance: float = DEFAULT_TOLERANCE["size"]  # +- on the diameter
    hit_ids: tuple[int, ...] = ()  # the hit of each point (datum targets name hits)
    size_lower: float | None = None  # the diameter's own limits (deviations from the nominal), when not +-
    size_upper: float | None = None
    alternative: dict[str, Any] | None = None  # a clearly different fit the hits fit better (fit summary), or None
    budget: dict[str, Any] | None = None  # its uncertainty budget's summary (cmm.metrology.uncertainty), or None


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
    for label in datums:
        parts = label.split("-")
        if not all(p.isalpha() for p in parts) or len(parts) > 2:
            raise gdt.GdtError(f"{label!r} is not a datum reference: use a letter (A) or a common datum of two (A-B)")
    offset = gdt.check_offset(d.get("offset"), tol) if d.get("offset") not in (None, "") else 0.0
    if offset and not ch.startswith("profile"):
        raise gdt.GdtError("a zone offset (UZ, unequally disposed) applies to a profile tolerance only")
    out = {**d, "characteristic": ch, "tolerance": tol, "datums": datums, "material": material,
           "angle": None if angle is None else float(angle), "direction": direction}
    out.pop("offset", None)
    if offset:
        out["offset"] = offset
    out.pop("datum_modifiers", None)
    if d.get("datum_modifiers"):
        out["datum_modifiers"] = _check_modifiers(d["datum_modifiers"], datums)
    if d.get("composite") is not None or d.get("pattern") is not None:
        out.update(_check_composite(out))
    return out


def _check_modifiers(given: Any, datums: list[str]) -> dict[str, str]:
    """A frame's own datum modifiers: label -> "MMB" | "LMB" | "" (RFS), each a datum of the frame."""
    if not isinstance(given, dict):
        raise gdt.GdtError("datum modifiers are a mapping of datum label to MMB, LMB or RFS")
    out = {}
    for label, mod in given.items():
        label = str(label).strip().upper()
        m = str(mod or "").upper().replace("RFS", "").replace("RMB", "")
        if m not in ("", "MMB", "LMB"):
            raise gdt.GdtError(f"datum {label}: unknown modifier {mod!r}; use MMB, LMB or none (RFS)")
        if label not in datums:
            raise gdt.GdtError(f"datum {label} has a modifier but is not in the frame {'|'.join(datums) or '(none)'}")
        out[label] = m
    return out


def _check_composite(d: dict[str, Any]) -> dict[str, Any]:
    """The pattern and lower tier of a composite position frame, checked (raises GdtError in words)."""
    if d["characteristic"] != "position":
        raise gdt.GdtError("a composite frame (pattern-locating and feature-relating tiers) is a position tolerance")
    low = d.get("composite")
    if not isinstance(low, dict):
        raise gdt.GdtError("a composite position needs its feature-relating (lower) tier: its tolerance and datums")
    try:
        pattern = [int(x) for x in d.get("pattern") or []]
    except (TypeError, ValueError):
        raise gdt.GdtError("the pattern of a composite position is a list of feature ids") from None
    if int(d["feature"]) not in pattern:
        pattern = [int(d["feature"])] + pattern
    if len(set(pattern)) < 2:
        raise gdt.GdtError("a composite position applies to a pattern: give two or more features")
    if d["material"]:
        raise gdt.GdtError("a composite position is evaluated regardless of feature size here: no MMC / LMC")
    lower_tol = gdt._check_tol(low.get("tolerance", 0), "feature-relating position")  # noqa: SLF001
    if not lower_tol < d["tolerance"]:
        raise gdt.GdtError(f"the feature-relating (lower) tolerance {lower_tol:g} must be smaller than the "
                           f"pattern-locating (upper) one {d['tolerance']:g}")
    lower = [str(x).strip().upper() for x in low.get("datums") or [] if str(x).strip()]
    if not lower:
        raise gdt.GdtError("the feature-relating (lower) tier needs the datum that orients the pattern (e.g. A); "
                           "a lower tier without datums is not evaluated here")
    if lower != d["datums"][:len(lower)] or len(lower) > 2:
        raise gdt.GdtError(f"the lower tier's datums {'|'.join(lower)} must repeat the upper tier's "
                           f"{'|'.join(d['datums']) or '(none)'} from the primary on (e.g. A, or A|B), at most two: "
                           "they orient the pattern, they do not locate it")
    return {"pattern": sorted(set(pattern), key=pattern.index),
            "composite": {"tolerance": lower_tol, "datums": lower}}


def check_datum(d: dict[str, Any]) -> dict[str, Any]:
    label = str(d.get("label", "")).strip().upper()
    if not label or not label.isalpha() or len(label) > 2:
        raise DatumError(f"a datum label is a letter (A, B, C ...), got {d.get('label')!r}")
    modifier = str(d.get("modifier") or "").upper().replace("RFS", "").replace("RMB", "")
    if modifier not in ("", "MMB", "LMB"):
        raise DatumError(f"datum {label}: unknown modifier {modifier!r}; use MMB, LMB or none (RFS)")
    out = {**d, "label": label, "modifier": modifier, "feature": int(d["feature"])}
    if d.get("targets"):
        out["targets"] = [_check_target(label, t) for t in d["targets"]]
        if modifier:
            raise DatumError(f"datum {label} from target points is a plane: it cannot be referenced at {modifier}")
    else:
        out.pop("targets", None)
    return out


TARGET_SHAPES = {"area": 2, "line": 2}  # a target area or line: the hits taken in it, at least this many


def _check_target(label: str, t: Any) -> int | dict[str, list[int]]:
    """One datum target: a hit id (a target point), or {"area": [hit ids]} / {"line": [hit ids]}."""
    if isinstance(t, dict):
        shape = next((k for k in TARGET_SHAPES if k in t), None)
        if shape is None or len(t) != 1:
            raise DatumError(f"datum {label}: a target is a hit number, {{'area': [hits]}} or {{'line': [hits]}}, "
                             f"got {t!r}")
        try:
            ids = [int(h) for h in t[shape]]
        except (TypeError, ValueError):
            raise DatumError(f"datum {label}: a target {shape} is the hit numbers taken in it, got {t[shape]!r}") from None
        if len(ids) < TARGET_SHAPES[shape] or len(set(ids)) != len(ids):
            raise DatumError(f"datum {label}: a target {shape} needs {TARGET_SHAPES[shape]} or more different hits "
                             f"taken in it, got {len(set(ids))}")
        return {shape: ids}
    try:
        if isinstance(t, bool):
            raise TypeError
        return int(t)
    except (TypeError, ValueError):
        raise DatumError(f"datum {label}: the targets are hit numbers (or target areas and lines of hits), "
                         f"got {t!r}") from None


def target_points(label: str, targets: list[Any], points: dict[int, np.ndarray], normal: Any) -> np.ndarray:
    """The contact points of datum targets, as the datum simulator touches the surface (``normal``: the datum
    feature's outward normal): a target point its hit; a target area the hit of the area furthest out of the
    material (the pad meets the highest point under it); a target line two points, the line through its
    furthest-out hit along the direction its hits run (in the surface), spanning them (a line counts as two
    of the frame's targets: B1-B2 on a secondary as one line)."""
    n = np.asarray(normal, dtype=np.float64)
    n = n / np.linalg.norm(n)
    out: list[np.ndarray] = []
    for t in targets:
        if not isinstance(t, dict):
            out.append(points[int(t)])
            continue
        shape, ids = next(iter(t.items()))
        pts = np.array([points[int(h)] for h in ids], dtype=np.float64)
        contact = pts[int(np.argmax(pts @ n))]
        if shape == "area":
            out.append(contact)
            continue
        centred = pts - pts.mean(axis=0)
        u = np.linalg.svd(centred, full_matrices=False)[2][0]
        u = u - (u @ n) * n  # the line lies in the surface
        span = centred @ u if float(np.linalg.norm(u)) > 1e-12 else np.zeros(len(pts))
        if float(np.linalg.norm(u)) < 1e-12 or float(np.ptp(span)) < 1e-6:
            raise DatumError(f"datum {label}: the hits of a target line lie on one spot: a line needs hits apart "
                             "along it")
        u = u / np.linalg.norm(u)
        s = pts @ u
        out += [contact + (float(s.min()) - float(contact @ u)) * u, contact + (float(s.max()) - float(contact @ u)) * u]
    return np.array(out, dtype=np.float64).reshape(-1, 3)


def _target_ids(targets: list[Any]) -> list[int]:
    return [h for t in targets for h in (next(iter(t.values())) if isinstance(t, dict) else [t])]


def _internal(f: MeasuredFeature) -> bool | None:
    n = f.nominal or {}
    return None if "bore" not in n else bool(n["bore"])


def _size_limits(f: MeasuredFeature) -> tuple[float, float] | None:
    n = f.nominal or {}
    if "radius" not in n:
        return None
    d = 2.0 * float(n["radius"])
    low = -f.size_tolerance if f.size_lower is None else float(f.size_lower)
    high = f.size_tolerance if f.size_upper is None else float(f.size_upper)
    return d + low, d + high


def datum_of(label: str, defs: dict[str, dict], feats: dict[int, MeasuredFeature], nominal: bool,
             modifiers: dict[str, str] | None = None) -> Any:
    """Datum ``label`` from its feature (actual, or with ``nominal`` its nominal); ``modifiers``: the frame's own
    modifier for a label (MMB, LMB, "" for RFS) over the datum definition's."""
    if "-" in label:  # a common datum: two datums from two features, one axis or plane
        first, _, second = label.partition("-")
        return common_datum(datum_of(first, defs, feats, nominal), datum_of(second, defs, feats, nominal))
    d = defs.get(label)
    if d is None:
        raise DatumError(f"datum {label} is not defined: choose its datum feature first")
    f = feats.get(int(d["feature"]))
    if f is None:
        raise DatumError(f"the datum feature of {label} (feature {d['feature']}) is not measured")
    modifier = (modifiers or {}).get(label, d.get("modifier") or "")
    boundary = internal = None
    if modifier:
        limits, internal = _size_limits(f), _internal(f)
        if limits is None or internal is None:
            raise DatumError(f"datum {label} at {modifier} needs the nominal size of {f.name} (a hole or a pin)")
        mmc = limits[0] if internal else limits[1]
        lmc = limits[1] if internal else limits[0]
        boundary = mmc if modifier == "MMB" else lmc
    targets = d.get("targets")
    if targets and modifier:
        raise DatumError(f"datum {label} from target points is a plane: it cannot be referenced at {modifier}")
    if targets and not nominal:  # the actual datum from the target hits; the nominal one is the CAD plane
        if f.kind != "plane":
            raise DatumError(f"datum {label}: datum targets here are points on a plane feature; {f.name} is a {f.kind}")
        where = {h: k for k, h in enumerate(f.hit_ids)}
        missing = [h for h in _target_ids(targets) if h not in where]
        if missing:
            raise DatumError(f"datum {label}: hit {missing[0]} is not a hit of {f.name}; its targets are hits of the "
                             "datum feature")
        g = _signed_like_nominal(f)
        pts = target_points(label, targets, {h: f.points[k] for h, k in where.items()}, g["normal"])
        return datum_from_targets(label, pts, g["normal"], feature=f.name)
    if nominal:
        n = f.nominal
        if not n or n.get("kind") in (None, "surface"):
            raise DatumError(f"datum {label} ({f.name}) has no nominal: the nominal frame cannot be built")
        return datum_from_feature(label, str(n["kind"]), n, feature=f.name)  # a circle's nominal is its cylinder
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
                 nominal: bool, modifiers: dict[str, str] | None = None) -> tuple[DRF | None, DRF | None]:
    """The actual DRF of ``labels`` and, with ``nominal``, the same frame built from the datum features'
    nominals (None, None without labels); ``modifiers``: the frame's own datum modifiers."""
    if not labels:
        return None, None
    actual = build_drf([datum_of(x, datums, feats, False, modifiers) for x in labels])
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
        for part in label.split("-"):
            dd = datums.get(part)
            if dd is not None and int(dd["feature"]) in (int(d["feature"]), *d.get("pattern", ())):
                raise gdt.GdtError(f"{f.name if int(dd['feature']) == int(d['feature']) else 'a feature of the pattern'}"
                                   f" is datum {part}: a feature is not toleranced against itself")
    tol = d["tolerance"]
    needs_nominal = ch in ("position", "profile of a surface", "profile of a line")
    drf, ndrf = build_frames(d["datums"], datums, feats, needs_nominal, d.get("datum_modifiers"))
    if ch in gdt.FORM:
        return gdt.form(ch, f.points, tol)
    if ch in gdt.ORIENTATION:
        return gdt.orientation(ch, f.kind, f.geometry, f.points, drf, tol, angle_deg=d["angle"],  # type: ignore[arg-type]
                               nominal_direction=_nominal_direction(f, d["datums"], datums, feats))
    if ch == "position" and "composite" in d:
        return evaluate_rows(d, datums, feats, mesh, pose)[0][1]
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
    return gdt.profile(ch, f.points, mesh, pose, tol, drf=drf, nominal_drf=ndrf, offset=d.get("offset", 0.0))


def evaluate_rows(d: dict[str, Any], datums: dict[str, dict], feats: dict[int, MeasuredFeature], mesh: Any = None,
                  pose: Any = None) -> list[tuple[str, gdt.GdtResult]]:
    """(feature name, result) rows of one definition: one row, or for a composite position one per feature of
    the pattern (upper tier) and one for the pattern (lower tier). Raises GdtError / DatumError in words."""
    d = check_definition(d)
    if "composite" not in d:
        f = feats.get(int(d["feature"]))
        return [(f.name if f is not None else f"feature {d['feature']}", evaluate_one(d, datums, feats, mesh, pose))]
    items, names = [], []
    for fid in d["pattern"]:
        f = feats.get(int(fid))
        if f is None:
            raise gdt.GdtError(f"feature {fid} of the pattern is not measured (deleted?)")
        if not f.nominal or f.nominal.get("kind") == "surface":
            raise gdt.GdtError(f"position of {f.name} needs its nominal location (CAD pick or typed)")
        items.append((f.kind, f.geometry, f.nominal, f.points if len(f.points) else None))
        names.append(f.name)
    for label in d["datums"]:
        for part in label.split("-"):
            dd = datums.get(part)
            if dd is not None and int(dd["feature"]) in d["pattern"]:
                raise gdt.GdtError(f"{feats[int(dd['feature'])].name} is datum {part}: a feature of the pattern is "
                                   "not toleranced against itself")
    drf, ndrf = build_frames(d["datums"], datums, feats, True)
    low = d["composite"]
    ldrf, lndrf = build_frames(low["datums"], datums, feats, True)
    if drf is None or ldrf is None:
        raise gdt.GdtError("a composite position needs datums in both tiers (e.g. A|B|C above, A below)")
    upper, lower = gdt.composite_position(items, d["tolerance"], low["tolerance"], drf, ndrf, ldrf, lndrf, names)
    return [*zip(names, upper), (f"pattern of {len(names)}", lower)]


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
    if d.get("offset"):  # an unequally disposed profile zone, as ISO 1101 writes it: "UZ+0.0050"
        head += f" UZ{float(d['offset']):+.4f}"
    mods = {k: {"MMB": "(M)", "LMB": "(L)"}.get(v, "") for k, v in (d.get("datum_modifiers") or {}).items()}
    text = head + (f" | {'|'.join(x + mods.get(x, '') for x in d.get('datums') or [])}" if d.get("datums") else "")
    low = d.get("composite")
    if isinstance(low, dict):  # the lower tier on a second line of the frame: "/ ⌀0.0200 | A"
        text += f" / ⌀{float(low.get('tolerance', 0)):.4f}" + (f" | {'|'.join(low.get('datums') or [])}"
                                                              if low.get("datums") else "")
    return text


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
            rows = evaluate_rows(d, datums, feats, mesh, pose)
        except (DatumError, ValueError, KeyError) as exc:
            msg = str(exc) if not isinstance(exc, KeyError) else f"missing {exc}"
            out.append((d, Characteristic(fname, label, None, None, float(d.get("tolerance") or 0.0), 0.0,
                                          note=f"{name}: not evaluated: {msg}",
                                          datums="|".join(d.get("datums") or []))))
            continue
        check = check_text(d, datums, feats)
        uncs = _uncertainty(d, datums, feats, rows, mesh, pose)
        for (feature_name, r), unc in zip(rows, uncs):
            out.append((d, Characteristic(feature_name, r.label, 0.0, r.value, r.allowed, 0.0,
                                          note=f"{name}: {r.note}", check=check, datums=r.drf, **unc)))
    return out


_PROPAGATED: dict[tuple, list[dict[str, Any]]] = {}  # the propagation of a tolerance on given hits (see _uncertainty)


def _row_values(d: dict[str, Any], datums: dict[str, dict], feats: dict[int, MeasuredFeature], mesh: Any = None,
                pose: Any = None) -> list[gdt.GdtResult]:
    return [r for _, r in evaluate_rows(d, datums, feats, mesh, pose)]


def _uncertainty(d: dict[str, Any], datums: dict[str, dict], feats: dict[int, MeasuredFeature],
                 rows: list[tuple[str, gdt.GdtResult]], mesh: Any, pose: Any) -> list[dict[str, Any]]:
    """The Characteristic's uncertainty fields of each of a definition's rows (cmm.metrology.uncertainty_gdt;
    a composite position's tiers each their own)."""
    from .uncertainty_gdt import involved, row_uncertainties

    # the tree, the report, the CSV and QIF evaluate the same tolerances on the same hits: propagate once
    parts = [(fid, None if feats.get(fid) is None else (feats[fid].kind, repr(feats[fid].geometry),
                                                        np.asarray(feats[fid].points).tobytes(),
                                                        repr((feats[fid].budget or {}).get("inputs"))))
             for fid in involved(d, datums)]
    values = [float(r.value) for _, r in rows]
    key = (repr(sorted(d.items())), repr(sorted(datums.items())), repr(parts), tuple(values))
    us = _PROPAGATED.get(key)
    if us is None:
        us = row_uncertainties(d, datums, feats, values, _row_values, mesh, pose)
        if len(_PROPAGATED) > 512:
            _PROPAGATED.clear()
        _PROPAGATED[key] = us
    return [{"uncertainty": float(u["U"]), "uncertainty_k": float(u["k"])} if "U" in u
            else {"uncertainty_why": str(u.get("why", "no uncertainty"))} for u in us]


def check_text(d: dict[str, Any], datums: dict[str, dict], feats: dict[int, MeasuredFeature]) -> str:
    """Why a definition's value needs the operator's check: the features it stands on (the toleranced
    feature, the pattern's, the datum features of both tiers) whose fit has an alternative; "" when none."""
    ids = [int(d.get("feature", -1)), *(int(x) for x in d.get("pattern") or [])]
    labels = [*(d.get("datums") or []), *((d.get("composite") or {}).get("datums") or [])]
    for label in labels:
        for part in str(label).upper().split("-"):
            dd = datums.get(part.strip())
            if dd is not None:
                ids.append(int(dd["feature"]))
    names = []
    for fid in dict.fromkeys(ids):
        f = feats.get(fid)
        if f is not None and f.alternative and f.name not in names:
            names.append(f.name)
    if not names:
        return ""
    return (f"another fit of {', '.join(names)} fits the hits better: the value stands on the "
            f"{'fits' if len(names) > 1 else 'fit'} near the nominal")
