"""Geometric tolerances for `cmm fit`: datums from point files and ``--gdt`` characteristics on the fitted feature.

    cmm fit cylinder bore.txt --datum A=plane:top.txt --datum B=plane:front.txt --datum C=plane:left.txt \\
        --gdt "position=0.05@A|B|C" --nominal 30,40,0,0,0,1 --material MMC --size-limits 29.98,30.02 --internal
    cmm fit plane top.txt --gdt flatness=0.01 --gdt "profile of a surface=0.02" --mesh part.stl
    cmm fit cylinder mid.txt --datum A=cylinder:front_bore.txt --datum B=cylinder:rear_bore.txt --gdt "coaxiality=0.02@A-B"
    cmm fit cylinder pin.txt --datum A=plane:top.txt --datum B=cylinder:bore.txt --datum-size B=9.98,10.02,hole \\
        --gdt "position=0.05@A|B(M)" --nominal 30,0,0,0,0,1

``--datum LABEL=KIND:FILE`` fits the datum feature (least squares) from its points; a datum plane's normal
points towards the toleranced feature (into the material). The datums of a ``--gdt`` (after ``@``, in
precedence order; ``B(M)`` / ``B(L)``: referenced at MMB / LMB, its size limits from ``--datum-size``) build
the frame (:mod:`cmm.metrology.datums`): Z along the primary's normal or axis, X along the secondary's (squared
to Z), Y = Z x X. A profile's ``UZ+0.02`` after its tolerance offsets its zone (ISO 1101 UZ, see
:func:`cmm.metrology.gdt.profile`). ``--datum-targets A=1,7,13`` establishes datum plane A by those points
of its file (1 = the first line) as target points. The nominal (``--nominal x,y,z[,dx,dy,dz]``) is in that frame's coordinates
(basic dimensions from the datums); a ``--mesh`` (STL, OBJ, PLY ...) is in the points' coordinates.

The command line gives definitions (:func:`definitions`) and measured features (:func:`features`: the fitted
one is feature 0, the datum features 1, 2 ...; each datum feature's nominal is its fitted geometry, so the
nominal frame is the actual one and basic dimensions are taken in it); they are evaluated by
:func:`cmm.metrology.gdt_eval.evaluate`, as the station's tree and report are. One feature is fitted per
command, so composite (pattern) frames are not expressed here.
"""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np

from ..metrology import gdt
from ..metrology.datums import DatumError
from ..metrology.gdt_eval import MeasuredFeature, build_frames, evaluate as evaluate_definitions

from .gdt_args import add_arguments  # noqa: F401 - the options live in a light module (`cmm fit --help`)

MODIFIER_MARKS = {"(M)": "MMB", "(L)": "LMB"}


def _floats(text: str, n: tuple[int, ...], what: str) -> list[float]:
    try:
        v = [float(x) for x in text.replace(" ", "").split(",")]
    except ValueError:
        raise gdt.GdtError(f"{what} must be numbers separated by commas, got {text!r}") from None
    if len(v) not in n:
        raise gdt.GdtError(f"{what} needs {' or '.join(str(k) for k in n)} numbers, got {len(v)}")
    return v


def _labelled(specs: list[str], option: str, form: str) -> dict[str, str]:
    out = {}
    for spec in specs:
        label, _, rest = spec.partition("=")
        if not (label.strip() and rest.strip()):
            raise gdt.GdtError(f"{option} takes {form}, got {spec!r}")
        out[label.strip().upper()] = rest.strip()
    return out


def _size(f: dict[str, Any], low: float, high: float, internal: bool) -> dict[str, Any]:
    """A feature's nominal and size fields for diameter limits (low, high): the limits as deviations from its
    nominal diameter."""
    if "radius" not in f["geometry"]:
        raise gdt.GdtError(f"{f['name']} is a {f['kind']}: size limits need a feature of size (cylinder, circle, "
                           "sphere)")
    if not low < high:
        raise gdt.GdtError(f"size limits of {f['name']}: the low diameter {low:g} must be below the high {high:g}")
    d = 2.0 * float(f["geometry"]["radius"])
    return {"nominal": {**f["nominal"], "radius": d / 2.0, "bore": internal}, "size_lower": low - d,
            "size_upper": high - d}


def features(args: argparse.Namespace, kind: str, summary: dict[str, Any],
             points: np.ndarray) -> tuple[dict[int, MeasuredFeature], dict[str, dict]]:
    """The measured features (0: the fitted one; 1, 2 ...: the datum features) and the datum definitions of
    the command line."""
    from ..metrology.fit_criteria import fit
    from ..metrology.pointfile import read_points_array

    towards = points.mean(axis=0)
    sizes = _labelled(args.datum_size, "--datum-size", "LABEL=LOW,HIGH,hole|pin (e.g. B=9.98,10.02,hole)")
    targets = _labelled(args.datum_targets, "--datum-targets", "LABEL=I,J,K (point numbers of its file)")
    feats: dict[int, MeasuredFeature] = {}
    datums: dict[str, dict] = {}
    for spec in args.datum:
        label, _, rest = spec.partition("=")
        dkind, _, path = rest.partition(":")
        label = label.strip().upper()
        if not (label and dkind and path):
            raise gdt.GdtError(f"--datum takes LABEL=KIND:FILE (e.g. A=plane:top.txt), got {spec!r}")
        pts = np.asarray(read_points_array(path), float)
        g = fit(dkind, pts, "ls").summary()
        if dkind == "plane" and (towards - np.asarray(g["point"])) @ np.asarray(g["normal"]) < 0:
            g["normal"] = [-x for x in g["normal"]]
        nominal = {"kind": dkind, **{k: v for k, v in g.items() if k not in ("radius", "kind", "method")}}
        f = {"name": f"datum {label}", "kind": dkind, "geometry": g, "nominal": nominal}
        if label in sizes:
            parts = [x.strip().lower() for x in sizes.pop(label).split(",")]
            if len(parts) != 3 or parts[2] not in ("hole", "pin"):
                raise gdt.GdtError(f"--datum-size {label}= takes LOW,HIGH,hole or LOW,HIGH,pin")
            lo, hi = _floats(",".join(parts[:2]), (2,), f"--datum-size {label}")
            f.update(_size(f, lo, hi, parts[2] == "hole"))
        fid = len(feats) + 1
        feats[fid] = MeasuredFeature(points=pts, hit_ids=tuple(range(1, len(pts) + 1)), **f)
        datums[label] = {"label": label, "feature": fid, "modifier": ""}
        if label in targets:
            ids = _floats(targets.pop(label), (1, 2, 3), f"--datum-targets {label}")
            if not all(x.is_integer() and 1 <= x <= len(pts) for x in ids):
                raise gdt.GdtError(f"--datum-targets {label}: the targets are point numbers of {path} (1 to "
                                   f"{len(pts)}), got {', '.join(f'{x:g}' for x in ids)}")
            datums[label]["targets"] = [int(x) for x in ids]
    left = sorted({*sizes, *targets})
    if left:
        raise gdt.GdtError(f"datum {left[0]} has a size or targets but no --datum {left[0]}=KIND:FILE")
    mine: dict[str, Any] = {"name": str(getattr(args, "file", "") or "the feature"), "kind": kind, "geometry": summary,
                            "nominal": None}
    if args.size_limits:
        mine["nominal"] = {"kind": kind}
        mine.update(_size(mine, *_floats(args.size_limits, (2,), "--size-limits"), bool(args.internal)))
    feats[0] = MeasuredFeature(points=points, hit_ids=tuple(range(1, len(points) + 1)), **mine)
    return feats, datums


def _frame(refs: str) -> tuple[list[str], dict[str, str]]:
    """The datums of a frame "A|B(M)|C" (precedence order) and its datum modifiers."""
    labels, mods = [], {}
    for x in refs.replace(",", "|").split("|"):
        x = x.strip().upper()
        if not x:
            continue
        mark = next((m for m in MODIFIER_MARKS if x.endswith(m)), None)
        if mark:
            x = x[: -len(mark)].strip()
            mods[x] = MODIFIER_MARKS[mark]
        labels.append(x)
    return labels, mods


def definitions(args: argparse.Namespace) -> list[dict[str, Any]]:
    """The ``--gdt`` tolerances as definitions on feature 0 (see :mod:`cmm.metrology.gdt_eval`)."""
    out = []
    for k, spec in enumerate(args.gdt):
        head, _, refs = spec.partition("@")
        name, _, tol_text = head.partition("=")
        tol_text, uz, offset_text = tol_text.upper().partition("UZ")
        try:
            tol = float(tol_text)
            offset = float(offset_text) if uz else 0.0
        except ValueError:
            raise gdt.GdtError(f"--gdt takes CHARACTERISTIC=TOLERANCE[UZ+OFFSET][@A|B|C], got {spec!r}") from None
        labels, mods = _frame(refs)
        d = {"id": k + 1, "name": name.strip().lower(), "characteristic": name.strip().lower(), "feature": 0,
             "tolerance": tol, "datums": labels, "material": (args.material or "") if name.strip().lower() == "position"
             else "", "angle": args.angle, "direction": args.direction}
        if mods:
            d["datum_modifiers"] = mods
        if uz:
            d["offset"] = offset
        out.append(d)
    return out


def _nominal(args: argparse.Namespace, kind: str, feat: MeasuredFeature, labels: list[str],
             datums: dict[str, dict], feats: dict[int, MeasuredFeature]) -> dict[str, Any] | None:
    """``--nominal`` (in the datums' frame, or the points' coordinates without datums) in the points'
    coordinates, as the feature's nominal."""
    if not args.nominal:
        return feat.nominal
    v = np.array(_floats(args.nominal, (3, 6), "--nominal"), float)
    p, u = v[:3], (v[3:] if len(v) == 6 else None)
    if labels:
        drf, _ = build_frames(labels, datums, feats, False)
        p = drf.origin + drf.rotation @ p
        u = None if u is None else drf.rotation @ u
    key = {"sphere": "center", "point": "point", "cone": "apex"}.get(kind, "point")
    return {**(feat.nominal or {}), "kind": kind, key: p.tolist(), **({} if u is None else {"direction": u.tolist()})}


def evaluate(args: argparse.Namespace, kind: str, summary: dict[str, Any], points: np.ndarray) -> list[dict]:
    """Each ``--gdt`` of the command line evaluated on the fitted feature (raises GdtError / DatumError)."""
    defs = definitions(args)
    if not defs:
        return []
    feats, datums = features(args, kind, summary, points)
    mesh = None
    if args.mesh and any(d["characteristic"].startswith("profile") for d in defs):
        from ..metrology.mesh import load_part

        mesh = load_part(args.mesh)
    out = []
    for d in defs:
        missing = [p for x in d["datums"] for p in x.split("-") if p not in datums]
        if missing:
            raise DatumError(f"datum {missing[0]} is not given: add --datum {missing[0]}=KIND:FILE")
        if any(len(x.split("-")) > 2 for x in d["datums"]):
            raise DatumError("a common datum is two datums, e.g. A-B")
        if d["characteristic"] == "position" and not args.nominal:
            raise gdt.GdtError("position needs --nominal x,y,z[,dx,dy,dz] (in the datum frame)")
        f = feats[0]
        own = {**feats, 0: MeasuredFeature(f.name, f.kind, f.geometry, _nominal(args, kind, f, d["datums"], datums,
                                                                               feats), f.points, f.size_tolerance,
                                           f.hit_ids, f.size_lower, f.size_upper)}
        for d_, c in evaluate_definitions([d], datums, own, mesh, np.eye(4)):
            if c.actual is None:
                raise gdt.GdtError(c.note.partition(": not evaluated: ")[2] or c.note)
            out.append({"characteristic": d_["characteristic"], "value": c.actual, "tolerance": float(d_["tolerance"]),
                        "bonus": max(c.upper - float(d_["tolerance"]), 0.0), "allowed": c.upper, "ok": bool(c.ok),
                        "drf": c.datums, "material": d_.get("material") or "",
                        "note": c.note.partition(": ")[2], **({"offset": d_["offset"]} if "offset" in d_ else {})})
    return out
