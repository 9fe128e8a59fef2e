"""A taught program (:mod:`cmm.session.program`, ``cmm-program/1``) written as a DMIS program that runs here.

The program's hits are in part coordinates; the DMIS program places the part with ``D(PART) = TRANS/..`` and
``ROTAT`` statements from a part pose (part -> machine: the set-up the program will run on, by default the
station's nominal set-up), then measures each feature with ``MEAS .. PTMEAS .. ENDMES``, reaching every hit as the
station's program runner does: up to the hit's clearance height, across, straight down to the pre-hit point, and
back up. Each feature gets a ``FEAT`` nominal (the taught nominal, else the ideal geometry through its nominal
hit points) and ``TOL`` statements from its tolerance (size, form, position), and is output with them.
"""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from ..metrology import fit_ls
from ..metrology.pick import NominalFeature
from .features import WORDS, from_model_nominal, nominal_line

FORM_WORDS = {"plane": "FLAT", "line": "STRGHT", "circle": "CIRLTY", "cylinder": "CYLCTY"}


def _label(name: str, used: set[str]) -> str:
    """A DMIS label name from a feature name: letters, digits and '_', unique."""
    base = re.sub(r"[^A-Za-z0-9_]", "_", name).upper().strip("_") or "F"
    if base[0].isdigit():
        base = "F_" + base
    label, k = base, 2
    while label in used:
        label, k = f"{base}_{k}", k + 1
    used.add(label)
    return label


def _euler_zyx(R: np.ndarray) -> tuple[float, float, float]:
    """(about Z, about Y, about X) in degrees with R = Rz Ry Rx."""
    b = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    if abs(math.cos(b)) > 1e-9:
        c = math.atan2(R[1, 0], R[0, 0])
        a = math.atan2(R[2, 1], R[2, 2])
    else:
        c, a = math.atan2(-R[0, 1], R[1, 1]), 0.0
    return math.degrees(c), math.degrees(b), math.degrees(a)


def _f(x: float) -> str:
    return f"{x + 0.0:.4f}"


def _ideal(kind: str, points: np.ndarray) -> NominalFeature | None:
    """The ideal feature through the nominal hit points, when the program has no nominal for it."""
    try:
        g = getattr(fit_ls, f"fit_{kind}")(points).geometry()
    except Exception:  # noqa: BLE001 - too few or degenerate points: no nominal then
        return None
    if kind == "plane":
        return NominalFeature("plane", {"point": g["point"], "normal": g["normal"]})
    if kind in ("circle", "cylinder"):
        return NominalFeature("cylinder", {"point": g.get("center", g.get("point")),
                                           "direction": g.get("normal", g.get("direction")), "radius": g["radius"]})
    if kind == "sphere":
        return NominalFeature("sphere", {"center": g["center"], "radius": g["radius"]})
    if kind == "cone":
        return NominalFeature("cone", {"apex": g["apex"], "direction": g["direction"], "half_angle": g["half_angle"]})
    return None


def to_dmis(program: Any, pose: Any = None, *, tip_radius: float = 1.0, approach: float = 2.0, search: float = 3.0,
            retract: float = 1.0) -> str:
    """The DMIS text of a taught ``program`` for the part at ``pose`` (part -> machine; default: none, the part
    coordinates are the machine's)."""
    P = np.eye(4) if pose is None else np.asarray(pose, float)
    hits = {h.id: h for h in program.hits}
    used: set[str] = set()
    out = [f"DMISMN/'{program.name} (exported from the station)', 05.0",
           f"FILNAM/'{program.name} output'",
           f"$$ Taught on part '{program.part_name}' (sha256 {program.part_sha256[:16]}...).",
           "$$ D(PART) places the part: edit it for another set-up.",
           "UNITS/MM, ANGDEC",
           "D(MCS) = DATSET/MCS",
           "D(PART) = TRANS/XORIG, {}, YORIG, {}, ZORIG, {}".format(*(_f(x) for x in P[:3, 3]))]
    rz, ry, rx = _euler_zyx(P[:3, :3])
    for word, angle in (("ZAXIS", rz), ("YAXIS", ry), ("XAXIS", rx)):
        if abs(angle) > 1e-9:
            out.append(f"D(PART) = ROTAT/{word}, {angle:.6f}")
    out += [f"S(TIP) = SNSDEF/PROBE, FIXED, CART, 0, 0, 0, 0, 0, -1, {2 * tip_radius:.4f}", "SNSLCT/S(TIP)",
            f"SNSET/APPRCH, {approach:g}", f"SNSET/SEARCH, {search:g}", f"SNSET/RETRCT, {retract:g}"]
    outputs: list[str] = []
    tols: list[str] = []
    for f in program.features:
        label = _label(f.name, used)
        word = WORDS[f.kind]
        pts = np.array([hits[i].point for i in f.hits], float)
        nf = None
        if f.nominal:
            nf = NominalFeature(f.nominal["kind"], {k: v for k, v in f.nominal.items() if k != "kind"})
        if nf is None or (f.kind == "cylinder" and nf.kind != "cylinder"):
            nf = _ideal(f.kind, pts)
        out.append(f"$$ --- {f.name}: {f.kind}, {len(f.hits)} hits")
        if nf is not None and f.kind not in ("point", "line"):
            nom = from_model_nominal(word, nf)
            if f.kind == "circle" and nom.vector is not None:  # the circle lies in the plane of its hits
                nom.point = nom.point + ((pts.mean(axis=0) - nom.point) @ nom.vector) * nom.vector
            if nom.word != word:
                nom.word = word
            out.append(nominal_line(label, nom, np.eye(4), 1.0, math.pi / 180.0))
        else:
            c = pts.mean(axis=0)
            n = -np.mean([hits[i].approach for i in f.hits], axis=0)
            n = n / np.linalg.norm(n)
            out.append(f"F({label}) = FEAT/{word}, CART, " + ", ".join(_f(x) for x in (*c, *n)))
        out.append(f"MEAS/{word}, F({label}), {len(f.hits)}")
        for i in f.hits:
            h = hits[i]
            p, u = np.array(h.point, float), np.array(h.approach, float)
            pre = p - (tip_radius + approach) * u
            top = max(float(h.clearance_z), float(pre[2]))
            out += [f"  GOTO/{_f(pre[0])}, {_f(pre[1])}, {_f(top)}",
                    f"  PTMEAS/CART, {_f(p[0])}, {_f(p[1])}, {_f(p[2])}, " + ", ".join(f"{-x + 0.0:.6f}" for x in u),
                    f"  GOTO/{_f(pre[0])}, {_f(pre[1])}, {_f(top)}"]
        out.append("ENDMES")
        refs = [f"FA({label})"]
        tol = f.tolerance or {}
        if "size" in tol and f.kind in ("circle", "cylinder", "sphere") and nf is not None:
            tols.append(f"T({label}_D) = TOL/DIAM, {-tol['size']:g}, {tol['size']:g}")
            refs.append(f"TA({label}_D)")
        if "form" in tol and f.kind in FORM_WORDS:
            tols.append(f"T({label}_F) = TOL/{FORM_WORDS[f.kind]}, {tol['form']:g}")
            refs.append(f"TA({label}_F)")
        if f.kind in ("circle", "cylinder", "sphere", "cone") and nf is not None and ("position" in tol or "location" in tol):
            zone = tol.get("position", 2.0 * tol.get("location", 0.0))
            tols.append(f"T({label}_P) = TOL/POS, {'3D' if f.kind in ('sphere', 'cone') else '2D'}, {zone:g}")
            refs.append(f"TA({label}_P)")
        outputs.append("OUTPUT/" + ", ".join(refs))
    out += tols + outputs + ["ENDFIL"]
    return "\n".join(out) + "\n"
