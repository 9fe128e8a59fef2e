"""Inspection report: one self-contained HTML file that prints well to PDF.

Contents: session header (part, hash, probe, alignment), a feature table
(nominal, actual, deviation, tolerance, pass/fail for size, location and
form), a deviation plot of every hit against the part mesh, and top and
front orthographic views of the part (its feature edges and outline) with
the hits as dots coloured by deviation. Inline SVG and CSS only: no
JavaScript, no external files. Tolerances come from a program's feature
definitions, else from the recorded feature, else ``DEFAULT_TOLERANCE``
(+-0.02 mm size and location, 0.02 mm form).
"""

from __future__ import annotations

import html
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .export import hit_deviations
from .model import DEFAULT_TOLERANCE, FeatureRecord, Session


@dataclass
class Row:
    feature: str
    characteristic: str
    nominal: float | None
    actual: float
    deviation: float | None
    tolerance: float
    ok: bool


def _unit(v: Any) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def feature_rows(f: FeatureRecord, tolerance: dict[str, float]) -> list[Row]:
    """Size, location and form characteristics of one feature against its nominal."""
    g, nom = f.fit, f.nominal or {}
    tol = {**DEFAULT_TOLERANCE, **(tolerance or {})}
    rows: list[Row] = []
    if "radius" in g and f.kind in ("circle", "sphere", "cylinder"):
        n = 2 * float(nom["radius"]) if "radius" in nom else None
        a = 2 * float(g["radius"])
        d = None if n is None else a - n
        rows.append(Row(f.name, "diameter", n, a, d, tol["size"], d is None or abs(d) <= tol["size"]))
    loc = None
    if nom:
        if f.kind == "plane" and "normal" in nom and "point" in g:
            n = _unit(nom["normal"])
            loc = float((np.asarray(g["point"]) - np.asarray(nom["point"])) @ n)
            rows.append(Row(f.name, "location along normal", 0.0, loc, loc, tol["location"], abs(loc) <= tol["location"]))
        elif f.kind == "sphere" and "center" in nom and "center" in g:
            loc = float(np.linalg.norm(np.asarray(g["center"]) - np.asarray(nom["center"])))
        elif f.kind in ("cylinder", "circle") and "direction" in nom:
            axis = _unit(nom["direction"])
            p = np.asarray(g.get("point", g.get("center")))
            rel = p - np.asarray(nom["point"] if "point" in nom else nom["center"])
            loc = float(np.linalg.norm(rel - (rel @ axis) * axis))
        elif f.kind == "cone" and "apex" in nom and "apex" in g:
            loc = float(np.linalg.norm(np.asarray(g["apex"]) - np.asarray(nom["apex"])))
        if loc is not None and f.kind != "plane":
            rows.append(Row(f.name, "position (distance)", 0.0, loc, loc, tol["location"], loc <= tol["location"]))
    if f.kind != "point":
        form = float(g.get("form", 0.0))
        rows.append(Row(f.name, "form", 0.0, form, form, tol["form"], form <= tol["form"]))
    return rows


# ------------------------------------------------------------------------ SVG pieces


def deviation_colour(d: float, tol: float) -> str:
    """Blue (-tol) -> green (0) -> red (+tol); beyond the band the end colours."""
    t = max(-1.0, min(1.0, d / tol)) if tol > 0 else 0.0
    green, end = (40, 160, 60), ((30, 80, 220) if t < 0 else (220, 40, 40))
    r, g, b = (int(round(c0 + abs(t) * (c1 - c0))) for c0, c1 in zip(green, end))
    return f"rgb({r},{g},{b})"


def deviation_plot(ids: list[int], devs: list[float], tol: float, width: int = 700, height: int = 220) -> str:
    if not devs:
        return "<p class='muted'>No deviations: the part mesh is not available.</p>"
    lim = max(tol * 1.5, max(abs(d) for d in devs) * 1.1)
    left, right, top, bottom = 56, 10, 10, 28
    w, h = width - left - right, height - top - bottom
    def x(i: int) -> float:
        return left + (i + 0.5) * w / len(devs)
    def y(d: float) -> float:
        return top + h / 2 - d / lim * h / 2
    parts = [f'<svg class="plot" viewBox="0 0 {width} {height}" width="{width}" height="{height}" '
             f'xmlns="http://www.w3.org/2000/svg" role="img" aria-label="deviation of each hit">',
             f'<rect x="{left}" y="{y(tol):.1f}" width="{w}" height="{y(-tol) - y(tol):.1f}" fill="#e8f5e9"/>',
             f'<line x1="{left}" x2="{left + w}" y1="{y(0):.1f}" y2="{y(0):.1f}" stroke="#888" stroke-width="0.8"/>']
    for v in (tol, -tol):
        parts.append(f'<line x1="{left}" x2="{left + w}" y1="{y(v):.1f}" y2="{y(v):.1f}" stroke="#2e7d32" '
                     f'stroke-dasharray="4 3" stroke-width="0.8"/>')
    for v in (lim, tol, 0.0, -tol, -lim):
        parts.append(f'<text x="{left - 4}" y="{y(v) + 3:.1f}" text-anchor="end" font-size="9">{v * 1000:+.1f}</text>')
    parts.append(f'<text x="10" y="{top + h / 2:.1f}" font-size="9" transform="rotate(-90 10 {top + h / 2:.1f})" '
                 'text-anchor="middle">deviation (um)</text>')
    step = max(1, len(ids) // 20)
    for k, (i, d) in enumerate(zip(ids, devs)):
        parts.append(f'<line x1="{x(k):.1f}" x2="{x(k):.1f}" y1="{y(0):.1f}" y2="{y(d):.1f}" stroke="#bbb" stroke-width="0.6"/>')
        parts.append(f'<circle cx="{x(k):.1f}" cy="{y(d):.1f}" r="3" fill="{deviation_colour(d, tol)}">'
                     f'<title>hit {i}: {d * 1000:+.2f} um</title></circle>')
        if k % step == 0:
            parts.append(f'<text x="{x(k):.1f}" y="{height - 12}" font-size="8" text-anchor="middle">{i}</text>')
    parts.append(f'<text x="{left + w / 2:.1f}" y="{height - 1}" font-size="9" text-anchor="middle">hit id</text></svg>')
    return "".join(parts)


def view_edges(mesh: Any, view: np.ndarray, angle_deg: float = 30.0) -> np.ndarray:
    """Edges (n x 2 x 3, part coordinates) to draw: feature edges sharper than ``angle_deg``
    plus the outline seen along ``view`` (edges between a front- and a back-facing face) and open edges."""
    adj = mesh.face_adjacency
    edges = mesh.face_adjacency_edges
    sharp = mesh.face_adjacency_angles > math.radians(angle_deg)
    facing = mesh.face_normals @ view
    outline = np.sign(facing[adj[:, 0]]) != np.sign(facing[adj[:, 1]])
    keep = edges[sharp | outline]
    v = mesh.vertices
    segs = [v[keep]]
    try:  # open edges (a mesh that is not watertight)
        from trimesh.grouping import group_rows

        open_edges = mesh.edges_sorted[group_rows(mesh.edges_sorted, require_count=1)]
        if len(open_edges):
            segs.append(v[open_edges])
    except Exception:  # noqa: BLE001 - outline is help, not data
        pass
    return np.concatenate(segs, axis=0)


def part_view(mesh: Any, points: np.ndarray, devs: list[float | None], tol: float, axes: tuple[int, int],
              view: np.ndarray, title: str, size: tuple[int, int] = (340, 260)) -> str:
    """An orthographic view: mesh edges projected on ``axes`` (e.g. (0, 1) top, (0, 2) front) plus hit dots."""
    a, b = axes
    segs = view_edges(mesh, view) if mesh is not None else np.zeros((0, 2, 3))
    coords = [segs.reshape(-1, 3)] if len(segs) else []
    if len(points):
        coords.append(points)
    allp = np.concatenate(coords) if coords else np.zeros((1, 3))
    lo, hi = allp[:, [a, b]].min(axis=0), allp[:, [a, b]].max(axis=0)
    span = np.maximum(hi - lo, 1e-9)
    W, H = size
    pad = 12
    s = min((W - 2 * pad) / span[0], (H - 2 * pad - 14) / span[1])
    def px(p: np.ndarray) -> tuple[float, float]:
        return pad + (p[a] - lo[0]) * s, H - pad - (p[b] - lo[1]) * s
    out = [f'<svg class="view" viewBox="0 0 {W} {H}" width="{W}" height="{H}" xmlns="http://www.w3.org/2000/svg" '
           f'role="img" aria-label="{html.escape(title)}"><text x="{pad}" y="12" font-size="10">{html.escape(title)}</text>',
           '<path fill="none" stroke="#555" stroke-width="0.5" d="']
    d = []
    for p, q in segs:
        (x1, y1), (x2, y2) = px(p), px(q)
        d.append(f"M{x1:.1f} {y1:.1f}L{x2:.1f} {y2:.1f}")
    out.append("".join(d) + '"/>')
    order = np.argsort(points[:, 3 - a - b]) if len(points) else []  # draw nearer dots last
    for k in order:
        x, y = px(points[k])
        dv = devs[k]
        colour = "#444" if dv is None else deviation_colour(dv, tol)
        ring = ' stroke="#000" stroke-width="1"' if dv is not None and abs(dv) > tol else ""
        out.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="3.2" fill="{colour}"{ring}/>')
    out.append("</svg>")
    return "".join(out)


# ------------------------------------------------------------------------ the page

CSS = """
body { font: 11pt/1.35 system-ui, sans-serif; color: #111; margin: 24px auto; max-width: 760px; }
h1 { font-size: 18pt; margin: 0 0 4px; } h2 { font-size: 13pt; margin: 18px 0 6px; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; width: 100%; font-size: 9.5pt; }
th, td { border: 1px solid #bbb; padding: 2px 5px; text-align: right; }
th { background: #eee; } td.l, th.l { text-align: left; }
tr.fail td { background: #ffebee; } td.ok { color: #1b5e20; font-weight: 600; } td.ng { color: #b71c1c; font-weight: 700; }
.muted { color: #666; } .warn { color: #b71c1c; border: 1px solid #b71c1c; padding: 4px 8px; }
.views { display: flex; gap: 12px; flex-wrap: wrap; } svg { background: #fff; }
dl { display: grid; grid-template-columns: max-content auto; gap: 1px 12px; margin: 0; font-size: 9.5pt; }
dt { color: #555; } dd { margin: 0; word-break: break-all; }
@media print {
  @page { size: A4; margin: 12mm; }
  body { margin: 0; max-width: none; font-size: 9.5pt; }
  h2 { break-after: avoid; } table, svg, .views { break-inside: avoid; }
  thead { display: table-header-group; } tr { break-inside: avoid; }
}
"""


def _num(v: float | None, digits: int = 4) -> str:
    return "" if v is None else f"{v:.{digits}f}"


def render(session: Session, *, mesh: Any = None, program: Any = None, title: str | None = None,
           default_tolerance: float | None = None) -> str:
    """The report as an HTML string."""
    st = session.state
    tol_of: dict[str, dict[str, float]] = {}
    if program is not None:
        tol_of = {f.name: f.tolerance for f in program.features}
    base_tol = dict(DEFAULT_TOLERANCE)
    if default_tolerance is not None:
        base_tol = {k: float(default_tolerance) for k in base_tol}
    rows: list[Row] = []
    for f in st.features.values():
        rows.extend(feature_rows(f, {**base_tol, **(f.tolerance or {}), **tol_of.get(f.name, {})}))
    dev = hit_deviations(session, mesh) if mesh is not None else {}
    ids = list(st.hits)
    devs = [dev[i] for i in ids if i in dev]
    dev_ids = [i for i in ids if i in dev]
    hit_tol = base_tol["form"]
    n_fail = sum(not r.ok for r in rows)
    verdict = "PASS" if n_fail == 0 else f"FAIL ({n_fail} characteristic{'s' if n_fail != 1 else ''} out of tolerance)"
    s = session.start
    e = html.escape
    out = ["<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
           f"<title>{e(title or 'Inspection report ' + session.name)}</title><style>{CSS}</style></head><body>",
           f"<h1>{e(title or 'Inspection report')}</h1>",
           f"<p class='muted'>Session <b>{e(session.name)}</b> &middot; generated {e(time.strftime('%Y-%m-%d %H:%M'))}"
           f" &middot; result: <b>{e(verdict)}</b></p>"]
    for w in session.warnings:
        out.append(f"<p class='warn'>{e(w)}</p>")
    info = [("part", "none" if st.part is None else st.part.name),
            ("part sha256", "" if st.part is None or not st.part.sha256 else st.part.sha256),
            ("machine config", str(s.get("config", ""))),
            ("tip radius", f"{s.get('tip_radius', '')} mm"),
            ("pre-travel", ", ".join(f"{k} {v * 1000:+.2f} um" for k, v in (s.get("pretravel") or {}).items()) or "0"),
            ("alignment", "none" if st.alignment is None else
             f"{st.alignment.method}" + (f", RMS {st.alignment.info['rms'] * 1000:.2f} um" if "rms" in st.alignment.info else "")),
            ("hits", f"{len(st.hits)} (+{len(st.deleted_hits)} deleted)"), ("features", str(len(st.features)))]
    if session.derived_from:
        info.append(("derived from", f"{session.derived_from.get('session')} ({session.derived_from.get('how', '')})"))
    if program is not None:
        info.append(("program", program.name))
    out.append("<dl>" + "".join(f"<dt>{e(k)}</dt><dd>{e(str(v))}</dd>" for k, v in info) + "</dl>")
    out.append("<h2>Features</h2><table><thead><tr><th class='l'>feature</th><th class='l'>kind / method</th>"
               "<th class='l'>characteristic</th><th>nominal</th><th>actual</th><th>deviation</th><th>tolerance</th>"
               "<th>result</th></tr></thead><tbody>")
    kinds = {f.name: f"{f.kind} / {f.method} ({len(f.hit_ids)} pts)" for f in st.features.values()}
    for r in rows:
        tol_txt = f"&le; {r.tolerance:.4f}" if r.characteristic in ("form", "position (distance)") else f"&plusmn; {r.tolerance:.4f}"
        out.append(f"<tr class='{'' if r.ok else 'fail'}'><td class='l'>{e(r.feature)}</td><td class='l'>{e(kinds[r.feature])}</td>"
                   f"<td class='l'>{e(r.characteristic)}</td><td>{_num(r.nominal)}</td><td>{_num(r.actual)}</td>"
                   f"<td>{_num(r.deviation)}</td><td>{tol_txt}</td>"
                   f"<td class='{'ok' if r.ok else 'ng'}'>{'pass' if r.ok else 'FAIL'}</td></tr>")
    if not rows:
        out.append("<tr><td class='l' colspan='8'>no features were fitted in this session</td></tr>")
    out.append("</tbody></table><p class='muted'>Lengths in mm. Diameters and positions against the feature's nominal "
               "(from the part); form is the fitted feature's max - min residual.</p>")
    out.append("<h2>Deviation of each hit from the part mesh</h2>")
    out.append(deviation_plot(dev_ids, devs, hit_tol))
    if devs:
        a = np.array(devs)
        out.append(f"<p class='muted'>Signed distance of the compensated points to the mesh (+ = material outside nominal): "
                   f"min {a.min() * 1000:+.2f} um, max {a.max() * 1000:+.2f} um, RMS {np.sqrt(np.mean(a * a)) * 1000:.2f} um; "
                   f"band &plusmn;{hit_tol * 1000:.0f} um.</p>")
    out.append("<h2>Part and hits</h2>")
    if st.hits:
        pts, pdev = [], []
        for i, h in st.hits.items():
            pose = st.hit_pose.get(i) or st.part_pose
            p = np.array(h.point)
            if pose is not None:
                P = np.array(pose)
                p = P[:3, :3].T @ (p - P[:3, 3])
            pts.append(p)
            pdev.append(dev.get(i))
        pts_a = np.array(pts)
        frame = "part coordinates" if st.part_pose is not None else "machine coordinates"
        out.append("<div class='views'>")
        out.append(part_view(mesh, pts_a, pdev, hit_tol, (0, 1), np.array([0.0, 0.0, 1.0]), f"top view (X-Y, {frame})"))
        out.append(part_view(mesh, pts_a, pdev, hit_tol, (0, 2), np.array([0.0, -1.0, 0.0]), f"front view (X-Z, {frame})"))
        out.append("</div>")
        if mesh is None:
            out.append("<p class='muted'>The part mesh was not found (or its sha256 does not match): hits only.</p>")
    else:
        out.append("<p class='muted'>No hits.</p>")
    if st.notes or st.errors:
        out.append("<h2>Notes and errors</h2><ul>")
        out += [f"<li>{e(t)}</li>" for _, t in st.notes]
        out += [f"<li><b>error:</b> {e(m)}</li>" for _, m in st.errors]
        out.append("</ul>")
    out.append("</body></html>\n")
    return "".join(out)


def write_report(session: Session, path: str | Path, **kw: Any) -> Path:
    p = Path(path)
    p.write_text(render(session, **kw), encoding="utf-8")
    return p
