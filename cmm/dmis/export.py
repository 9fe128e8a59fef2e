"""A taught program or routine (:mod:`cmm.program.toml_program`, ``cmm-program/1`` or ``/2``) written as a DMIS program.

The program's hits are in part coordinates; the DMIS program places the part with ``D(PART) = TRANS/..`` and
``ROTAT`` statements from a part pose (part -> machine: the set-up the program will run on, by default the
station's nominal set-up), then measures each feature with ``MEAS .. PTMEAS .. ENDMES``, reaching its hits as the
station's routine runner does: the first up at its clearance height, across and straight down to the pre-hit
point; with the part mesh the later ones straight from the last hit, else over the feature's local top, where the
rails prove that free of the part (:mod:`cmm.dmis.export_hops`: GOTO points between the PTMEAS statements), else
over the clearance height; back up after the last. Each feature gets a ``FEAT`` nominal (the taught nominal, else
the ideal geometry through its nominal hit points) and ``TOL`` statements from its tolerance (size, form,
position), and is output with them.

A routine's steps are followed in their order, skipped steps left out: a 3-2-1 alignment measures its three datum
planes and sets ``D(ALIGN) = DATSET/..`` from them (then ``TRANS``/``ROTAT`` back to the part's own origin, so
the hits that follow stay in part coordinates); a construction the interpreter has as ``CONST`` (an intersection,
a mid-point) becomes one, a distance or an angle becomes a ``TOL/DISTB`` / ``TOL/ANGLB`` between its two
features; a report step is a comment (the run's output is the report).
"""

from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from ..metrology import fit_ls
from ..metrology.construct import construct
from ..metrology.pick import NominalFeature
from .frames import datum_frame, inverse
from .export_hops import hop_gotos
from .features import WORDS, Nominal, from_model_nominal, nominal_line

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


def _goto(q: Any) -> str:
    return "  GOTO/" + ", ".join(_f(x) for x in q)


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


def _nominal(f: Any, pts: np.ndarray) -> NominalFeature | None:
    nf = None
    if f.nominal:
        nf = NominalFeature(f.nominal["kind"], {k: v for k, v in f.nominal.items() if k != "kind"})
    if nf is None or (f.kind == "cylinder" and nf.kind != "cylinder"):
        nf = _ideal(f.kind, pts)
    return nf


def _model_geometry(f: Any, nf: NominalFeature | None) -> tuple[str, dict[str, Any]] | None:
    """(kind, geometry) of a feature's nominal in part coordinates, as the constructions take them."""
    if nf is None:
        return None
    g = {k: (np.asarray(v, float) if isinstance(v, (list, tuple, np.ndarray)) else v) for k, v in nf.params.items()}
    if f.kind == "circle" and "direction" in g:
        g["normal"] = g["direction"]
    return f.kind, g


def _dir_word(v: np.ndarray, taken: set[int]) -> tuple[int, str]:
    """The part axis (not yet taken) a datum's normal lies along, and its DATSET word (ZDIR, YMINUS ...)."""
    axis = max((k for k in range(3) if k not in taken), key=lambda k: abs(v[k]))
    return axis, "XYZ"[axis] + ("DIR" if v[axis] >= 0 else "MINUS")


def _hit_line(pts: np.ndarray, face: np.ndarray) -> Nominal:
    """The line through hit points (their principal direction), bounded by the first and last hit projected
    onto it, lying in the face whose outward normal is ``face`` (the side the probe came from)."""
    c = pts.mean(axis=0)
    d = np.linalg.svd(pts - c)[2][0]
    if (pts[-1] - pts[0]) @ d < 0:
        d = -d  # from the first hit towards the last
    a, b = (c + ((p - c) @ d) * d for p in (pts[0], pts[-1]))
    plane = face - (face @ d) * d
    return Nominal("LINE", None, a, d, length=float(np.linalg.norm(b - a)), plane=plane / np.linalg.norm(plane))


def _align_lines(datums: list[str], labels: dict[str, str], planes: dict[str, NominalFeature | None]) -> list[str]:
    """``DATSET`` from the three datum planes (primary direction and origin, secondary direction and origin,
    tertiary origin), then ``TRANS`` and ``ROTAT`` to the part's own origin and axes (their nominal 3-2-1 frame
    taken out), so the program's coordinates after it are part coordinates on the part where it lies."""
    noms = [planes[d] for d in datums]
    if any(n is None or n.kind != "plane" for n in noms):
        return [f"$$ the alignment on {', '.join(datums)} is not exported: a datum has no nominal plane"]
    pts = [np.asarray(n.params["point"], float) for n in noms]  # type: ignore[union-attr]
    nrm = [np.asarray(n.params["normal"], float) for n in noms]  # type: ignore[union-attr]
    a1, w1 = _dir_word(nrm[0], set())
    a2, w2 = _dir_word(nrm[1], {a1})
    a3 = 3 - a1 - a2
    entries = [(datums[0], w1, pts[0], nrm[0]), (datums[0], "XYZ"[a1] + "ORIG", pts[0], nrm[0]),
               (datums[1], w2, pts[1], nrm[1]), (datums[1], "XYZ"[a2] + "ORIG", pts[1], nrm[1]),
               (datums[2], "XYZ"[a3] + "ORIG", pts[2], nrm[2])]
    back = inverse(datum_frame(entries))  # the part's frame in the nominal datum frame
    first, second, third = (f"FA({labels[d]})" for d in datums)
    out = [f"$$ --- 3-2-1 alignment: {' | '.join(datums)}",
           f"D(ALIGN) = DATSET/{first}, {w1}, {'XYZ'[a1]}ORIG, {second}, {w2}, {'XYZ'[a2]}ORIG, {third}, "
           f"{'XYZ'[a3]}ORIG",
           "D(ALIGN) = TRANS/XORIG, {}, YORIG, {}, ZORIG, {}".format(*(_f(x) for x in back[:3, 3]))]
    rz, ry, rx = _euler_zyx(back[:3, :3])
    for word, angle in (("ZAXIS", rz), ("YAXIS", ry), ("XAXIS", rx)):
        if abs(angle) > 1e-9:
            out.append(f"D(ALIGN) = ROTAT/{word}, {angle:.6f}")
    return out


def to_dmis(program: Any, pose: Any = None, *, tip_radius: float = 1.0, approach: float = 2.0, search: float = 3.0,
            retract: float = 1.0, mesh: Any = None) -> str:
    """The DMIS text of a taught ``program`` for the part at ``pose`` (part -> machine; default: none, the part
    coordinates are the machine's), its routine steps in their order. With the part's ``mesh`` (part
    coordinates) a feature's later hits hop as the routine runner's (:mod:`cmm.dmis.export_hops`); without it
    every hit goes over its clearance height."""
    P = np.eye(4) if pose is None else np.asarray(pose, float)
    hits = {h.id: h for h in program.hits}
    used: set[str] = set()
    out = [f"DMISMN/'{program.name} (exported from the station)', 05.0",
           f"FILNAM/'{program.name} output'",
           f"$$ Taught on part '{program.part_name}' (sha256 {program.part_sha256[:16]}...).",
           "$$ D(PART) places the part (within 0.5 mm: the moves before an alignment are checked against it): edit it",
           "$$ for another set-up. Start with the probe above the part's clearance height: the first move goes",
           "$$ straight across to the first hit.",
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
    labels: dict[str, str] = {}
    nominals: dict[str, NominalFeature | None] = {}
    geometry: dict[str, tuple[str, dict[str, Any]] | None] = {}

    def measure(name: str) -> None:
        if name in labels:
            return
        f = program.feature(name)
        labels[name] = label = _label(f.name, used)
        word = WORDS[f.kind]
        pts = np.array([hits[i].point for i in f.hits], float)
        nominals[name] = nf = _nominal(f, pts)
        geometry[name] = _model_geometry(f, nf)
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
            if f.kind == "line":  # BND through the first and last hit on the ideal line, in the probed face
                out.append(nominal_line(label, _hit_line(pts, n), np.eye(4), 1.0, math.pi / 180.0))
            else:
                out.append(f"F({label}) = FEAT/{word}, CART, " + ", ".join(_f(x) for x in (*c, *n)))
        out.append(f"MEAS/{word}, F({label}), {len(f.hits)}")
        before, after = hop_gotos([hits[i] for i in f.hits], mesh, tip_radius=tip_radius, approach=approach,
                                  retract=retract)
        for i, gotos in zip(f.hits, before):
            p, u = np.array(hits[i].point, float), np.array(hits[i].approach, float)
            out.extend([_goto(q) for q in gotos] + [f"  PTMEAS/CART, {_f(p[0])}, {_f(p[1])}, {_f(p[2])}, "
                                                    + ", ".join(f"{-x + 0.0:.6f}" for x in u)])
        out.extend([_goto(after), "ENDMES"])
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

    def construction(step: dict[str, Any]) -> None:
        name, op, (a, b) = step["name"], step["operation"], step["of"]
        if a not in labels or b not in labels:
            out.append(f"$$ {name} ({op} of {a} and {b}) is not exported: {a if a not in labels else b} "
                       "is not measured (its step is skipped)")
            return
        label = _label(name, used)
        fa, fb = f"FA({labels[a]})", f"FA({labels[b]})"
        ga, gb = geometry[a], geometry[b]
        try:
            nominal = None if ga is None or gb is None else construct(op, ga, gb, workplane=np.array([0, 0, 1.0]))
        except Exception:  # noqa: BLE001 - operands whose nominals do not combine: said below
            nominal = None
        if op in ("distance", "angle"):
            if nominal is None or nominal.value is None:
                out.append(f"$$ {name} ({op} of {a} and {b}) is not exported: its features have no nominal")
                return
            word, unit = ("DISTB", "mm") if op == "distance" else ("ANGLB", "degrees")
            zone = 0.1 if op == "distance" else 0.5
            out.append(f"$$ --- {name}: the {op} of {a} and {b}, nominal {float(nominal.value):.4f} {unit}; the "
                       f"routine gives it no tolerance: +/-{zone:g} {unit} here, edit it")
            tols.append(f"T({label}) = TOL/{word}, NOMINL, {float(nominal.value):.4f}, {-zone:g}, {zone:g}")
            outputs.append(f"OUTPUT/{fa}, {fb}, TA({label})")
            return
        kind = nominal.kind if nominal is not None else ("point" if op == "midpoint" else None)
        if kind not in ("point", "line", "plane", "circle"):
            out.append(f"$$ {name} ({op} of {a} and {b}) is not exported: DMIS CONST here has no such "
                       "construction")
            return
        out.append(f"$$ --- {name}: the {op} of {a} and {b}")
        out.append(f"CONST/{kind.upper()}, F({label}), {'INTOF' if op == 'intersection' else 'MIDPT'}, {fa}, {fb}")
        outputs.append(f"OUTPUT/FA({label})")

    for step in program.steps or [{"kind": "feature", "name": f.name} for f in program.features]:
        if step.get("skip"):
            out.append(f"$$ step {step['name']} is skipped in the routine")
            continue
        kind = step["kind"]
        if kind == "align":
            if step.get("manual"):
                out.append("$$ the routine takes 3-2-1 hits by hand first: here the datums are measured at D(PART)")
            for d in step["datums"]:
                measure(d)
            out.extend(_align_lines(list(step["datums"]), labels, nominals))
        elif kind == "feature":
            measure(step["name"])
        elif kind == "construct":
            construction(step)
        else:
            out.append(f"$$ {step['name']}: the station's report is written beside this program's output")
    out += tols + outputs + ["ENDFIL"]
    return "\n".join(out) + "\n"
