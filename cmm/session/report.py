"""Inspection report: one self-contained HTML file a quality engineer hands to a customer, and its CSV.

Contents: a header (part and part number, drawing, operator, machine,
calibration status and date, temperature, session, alignment), the verdict,
a warning when no alignment was made, the feature table (nominal, tolerances,
actual, deviation, out of tolerance, pass/fail per characteristic, see
:mod:`cmm.metrology.characteristics`), a colour-coded deviation plot of every
hit, colour map views (top, front, isometric: the part's faces painted by the
interpolated deviation of the hits, :mod:`cmm.metrology.colour_map`, with the
hits on top) in the same colour scale as the 3D scene
(:mod:`cmm.metrology.colour_scale`) and its legend, a form
plot per feature (residuals of its hits: polar for circles, cylinders and
spheres), and the machine events worded for people. Inline SVG and CSS
only: no JavaScript, no external files; the print CSS makes an A4 PDF from
any browser's *Print*. :func:`features_csv` gives the feature table as CSV.

Tolerances come from a program's feature definitions, else from the recorded
feature, else ``DEFAULT_TOLERANCE`` (+-0.02 mm size and location, 0.02 mm
form, position zone diameter 0.04 mm).
"""

from __future__ import annotations

import csv
import html
import io
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..journal.records import ConstructedRecord, FeatureRecord
from ..journal.session import Session
from ..journal.wording import error_text, grouped
from ..metrology.actuals import COLUMNS as ACTUAL_COLUMNS, actuals, cells as actual_cells, session_frame
from ..metrology.characteristics import Characteristic, verdict
from ..metrology.characteristics import DEFAULT_TOLERANCE
from ..metrology.colour_scale import ColourScale
from ..metrology.feature_distance import around_axis, surface_distance
from ..metrology.features import proof_text
from .export import hit_deviations
from .gdt_session import session_gdt
from .probe_used import probe_uses

NO_ALIGNMENT = ("No alignment was made: the part is where the station assumed it to be (nominal set-up), not "
                "where it was measured to be. Deviations from the part and positions include the set-up error.")
HEADER_FIELDS = (("part_number", "part number"), ("drawing", "drawing"), ("operator", "operator"),
                 ("machine_name", "machine"), ("temperature", "temperature"), ("remarks", "remarks"))


# ------------------------------------------------------------------------ SVG pieces


def deviation_colour(d: float, tol: float) -> str:
    """CSS colour of a deviation on the shared scale (the 3D scene uses the same bands)."""
    return ColourScale(tol).css(d)


def legend_html(scale: ColourScale) -> str:
    items = "".join(f"<span class='sw'><i style='background:rgb{c}'></i>{html.escape(label)}</span>"
                    for c, label in scale.legend())
    return f"<div class='legend' aria-label='colour scale'>{items}</div>"


def deviation_plot(ids: list[int], devs: list[float], scale: ColourScale, width: int = 700, height: int = 220) -> str:
    if not devs:
        return "<p class='muted'>No deviations: the part mesh is not available.</p>"
    tol = scale.tolerance
    shown = [d for d in devs if abs(d) <= scale.max_distance] or [tol]
    lim = max(tol * 2.5, max(abs(d) for d in shown) * 1.1)
    left, right, top, bottom = 56, 10, 10, 30
    w, h = width - left - right, height - top - bottom

    def x(i: int) -> float:
        return left + (i + 0.5) * w / len(devs)

    def y(d: float) -> float:
        return top + h / 2 - max(-lim, min(lim, d)) / lim * h / 2

    parts = [f'<svg class="plot" viewBox="0 0 {width} {height}" width="{width}" height="{height}" '
             f'xmlns="http://www.w3.org/2000/svg" role="img" aria-label="deviation of each hit">',
             f'<rect x="{left}" y="{y(tol):.1f}" width="{w}" height="{y(-tol) - y(tol):.1f}" fill="#e8f5e9"/>',
             f'<line x1="{left}" x2="{left + w}" y1="{y(0):.1f}" y2="{y(0):.1f}" stroke="#888" stroke-width="0.8"/>']
    for v in (tol, -tol):
        parts.append(f'<line x1="{left}" x2="{left + w}" y1="{y(v):.1f}" y2="{y(v):.1f}" stroke="#2e7d32" '
                     f'stroke-dasharray="4 3" stroke-width="0.8"/>')
    # axis labels far enough apart not to overlap (at least 11 px)
    labels: list[float] = []
    for v in (lim, tol, 0.0, -tol, -lim):
        if all(abs(y(v) - y(u)) >= 11 for u in labels):
            labels.append(v)
            parts.append(f'<text x="{left - 4}" y="{y(v) + 3:.1f}" text-anchor="end" font-size="9">{v * 1000:+.1f}</text>')
    parts.append(f'<text x="10" y="{top + h / 2:.1f}" font-size="9" transform="rotate(-90 10 {top + h / 2:.1f})" '
                 'text-anchor="middle">deviation (µm)</text>')
    step = max(1, math.ceil(len(ids) / max(1, w // 22)))  # hit numbers at least ~22 px apart
    for k, (i, d) in enumerate(zip(ids, devs)):
        ring = ' stroke="#000"' if abs(d) > lim else ""
        parts.append(f'<line x1="{x(k):.1f}" x2="{x(k):.1f}" y1="{y(0):.1f}" y2="{y(d):.1f}" stroke="#bbb" stroke-width="0.6"/>')
        parts.append(f'<circle cx="{x(k):.1f}" cy="{y(d):.1f}" r="3" fill="{scale.css(d)}"'
                     f'{ring}>'
                     f'<title>hit {i}: {d * 1000:+.2f} µm</title></circle>')
        if k % step == 0:
            parts.append(f'<text x="{x(k):.1f}" y="{height - 14}" font-size="8" text-anchor="middle">{i}</text>')
    parts.append(f'<text x="{left + w / 2:.1f}" y="{height - 2}" font-size="9" text-anchor="middle">hit number</text></svg>')
    return "".join(parts)


def view_edges(mesh: Any, view: np.ndarray, angle_deg: float = 30.0, front_only: bool = False) -> np.ndarray:
    """Edges (n x 2 x 3, part coordinates) to draw: feature edges sharper than ``angle_deg``
    plus the outline seen along ``view`` (edges between a front- and a back-facing face) and open edges.
    ``front_only``: only edges of a face turned to the viewer (the painted views hide the back edges)."""
    adj = mesh.face_adjacency
    edges = mesh.face_adjacency_edges
    sharp = mesh.face_adjacency_angles > math.radians(angle_deg)
    facing = mesh.face_normals @ view
    outline = np.sign(facing[adj[:, 0]]) != np.sign(facing[adj[:, 1]])
    keep_mask = sharp | outline
    if front_only:
        keep_mask &= (facing[adj[:, 0]] > 1e-9) | (facing[adj[:, 1]] > 1e-9)
    keep = edges[keep_mask]
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


RASTER = 1.5  # colour map image pixels per SVG unit (sharp enough in print)
# orthographic views of the colour map: (title, direction towards the viewer)
VIEWS = (("top view (X-Y)", (0.0, 0.0, 1.0)), ("front view (X-Z)", (0.0, -1.0, 0.0)),
         ("isometric view", (1.0, -1.0, 1.0)))


def view_basis(view: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, towards the viewer) of an orthographic view; +Z is up unless looking along Z (then +Y)."""
    v = np.asarray(view, float)
    v = v / np.linalg.norm(v)
    up = np.array([0.0, 1.0, 0.0]) if abs(v[2]) > 0.99 else np.array([0.0, 0.0, 1.0])
    up = up - (up @ v) * v
    up /= np.linalg.norm(up)
    return np.cross(up, v), up, v


def part_view(mesh: Any, points: np.ndarray, devs: list[float | None], scale: ColourScale, view: Any, title: str,
              dmap: Any = None, size: tuple[int, int] = (264, 230), hit_normals: np.ndarray | None = None) -> str:
    """An orthographic view along ``view`` (towards the viewer): the colour map (``dmap``, a
    :class:`~cmm.metrology.colour_map.DeviationMap`) as a z-buffered image when given, the mesh's feature
    edges and outline, and the hits as dots in the same colour scale. ``hit_normals``: the hits' surface
    normals (``hits_on_surface``) when the caller draws several views of them (found here otherwise)."""
    right, up, towards = view_basis(view)
    P = np.stack([right, up])  # 2 x 3: part mm -> view mm
    segs = view_edges(mesh, towards, front_only=dmap is not None) if mesh is not None else np.zeros((0, 2, 3))
    pts = np.asarray(points, float).reshape(-1, 3)
    devs = list(devs)
    if dmap is not None and len(pts):  # hits on the far side of the part are hidden by it
        if hit_normals is None:
            from ..metrology.colour_map import hits_on_surface

            _, hit_normals = hits_on_surface(mesh, pts)
        front = hit_normals @ towards > -1e-6
        pts, devs = pts[front], [d for d, f in zip(devs, front) if f]
    coords = [np.asarray(mesh.vertices)] if mesh is not None else []
    if len(pts):
        coords.append(pts)
    allp = np.concatenate(coords) @ P.T if coords else np.zeros((1, 2))
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    span = np.maximum(hi - lo, 1e-9)
    W, H = size
    pad = 12
    s = min((W - 2 * pad) / span[0], (H - 2 * pad - 14) / span[1])

    def px(q: np.ndarray) -> np.ndarray:  # n x 3 -> n x 2 pixels
        uv = np.asarray(q, float).reshape(-1, 3) @ P.T
        return np.column_stack([pad + (uv[:, 0] - lo[0]) * s, H - pad - (uv[:, 1] - lo[1]) * s])

    out = [f'<svg class="view" viewBox="0 0 {W} {H}" width="{W}" height="{H}" xmlns="http://www.w3.org/2000/svg" '
           f'role="img" aria-label="{html.escape(title)}"><text x="{pad}" y="12" font-size="10">{html.escape(title)}</text>']
    if dmap is not None:  # the map as an image under the vector edges and dots (exact band colours per pixel)
        import base64

        from ..metrology.colour_map import png, view_image

        def from_pixels(xy: np.ndarray, depth: np.ndarray) -> np.ndarray:
            u = (xy[:, 0] / RASTER - pad) / s + lo[0]
            v = (H - pad - xy[:, 1] / RASTER) / s + lo[1]
            return u[:, None] * right + v[:, None] * up + depth[:, None] * towards

        img = view_image(dmap, lambda q: px(q) * RASTER, from_pixels, towards, round(W * RASTER), round(H * RASTER))
        out.append(f'<image class="map" x="0" y="0" width="{W}" height="{H}" '
                   f'href="data:image/png;base64,{base64.b64encode(png(img)).decode()}"/>')
    d = []
    for a, b in zip(px(segs[:, 0]) if len(segs) else [], px(segs[:, 1]) if len(segs) else []):
        d.append(f"M{a[0]:.1f} {a[1]:.1f}L{b[0]:.1f} {b[1]:.1f}")
    out.append(f'<path fill="none" stroke="{"#333" if dmap is not None else "#555"}" stroke-width="0.5" d="'
               + "".join(d) + '"/>')
    if len(pts):
        xy = px(pts)
        for k in np.argsort(pts @ towards):  # nearer dots last
            dv = devs[k]
            ring = ' stroke="#000" stroke-width="1"' if dv is not None and scale.band(dv) != 0 else ' stroke="#fff" stroke-width="0.6"'
            out.append(f'<circle cx="{xy[k, 0]:.1f}" cy="{xy[k, 1]:.1f}" r="3.2" fill="{scale.css(dv)}"{ring}/>')
    out.append("</svg>")
    return "".join(out)


def form_plot(f: FeatureRecord, points: np.ndarray, form_tol: float, size: int = 170) -> str:
    """Residuals of a feature's hits to its fitted geometry: polar (circle, cylinder, sphere, cone) or per hit."""
    try:
        res = surface_distance(f.kind, f.fit, points) if len(points) else np.zeros(0)
        ang = around_axis(f.kind, f.fit, points) if len(points) else None
    except (KeyError, ValueError, TypeError):
        return ""
    if f.kind == "point" or len(res) == 0:
        return ""
    title = html.escape(f"{f.name}: form {float(f.fit.get('form', 0.0)) * 1000:.1f} µm")
    span = max(float(np.max(np.abs(res))), form_tol / 2, 1e-6)
    W = H = size
    out = [f'<svg class="form" viewBox="0 0 {W} {H + 14}" width="{W}" height="{H + 14}" '
           f'xmlns="http://www.w3.org/2000/svg" role="img" aria-label="form plot {html.escape(f.name)}">',
           f'<text x="2" y="10" font-size="9">{title}</text>']
    if ang is not None:
        cx, cy, r0, gain = W / 2, H / 2 + 12, W * 0.28, W * 0.16 / span
        out.append(f'<circle cx="{cx}" cy="{cy}" r="{r0:.1f}" fill="none" stroke="#888" stroke-width="0.7"/>')
        for t in (form_tol / 2, -form_tol / 2):
            out.append(f'<circle cx="{cx}" cy="{cy}" r="{r0 + t * gain:.1f}" fill="none" stroke="#2e7d32" '
                       'stroke-dasharray="3 2" stroke-width="0.6"/>')
        order = np.argsort(ang)
        pts = [(cx + (r0 + res[k] * gain) * math.cos(ang[k]), cy - (r0 + res[k] * gain) * math.sin(ang[k])) for k in order]
        if len(pts) > 2 and f.kind in ("circle",):
            out.append('<polygon fill="none" stroke="#1565c0" stroke-width="0.9" points="'
                       + " ".join(f"{x:.1f},{y:.1f}" for x, y in pts) + '"/>')
        for (x, y), k in zip(pts, order):
            out.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="2.2" fill="#1565c0"><title>hit {f.hit_ids[k] if k < len(f.hit_ids) else k}: '
                       f'{res[k] * 1000:+.2f} µm</title></circle>')
        out.append(f'<text x="{W - 2}" y="{H + 12}" font-size="8" text-anchor="end">scale: ring = {span * 1000:.1f} µm</text>')
    else:
        left, top, w, h = 8, 16, W - 16, H - 12
        mid = top + h / 2
        out.append(f'<line x1="{left}" x2="{left + w}" y1="{mid}" y2="{mid}" stroke="#888" stroke-width="0.7"/>')
        for t in (form_tol / 2, -form_tol / 2):
            yy = mid - t / span * h / 2 * 0.9
            out.append(f'<line x1="{left}" x2="{left + w}" y1="{yy:.1f}" y2="{yy:.1f}" stroke="#2e7d32" '
                       'stroke-dasharray="3 2" stroke-width="0.6"/>')
        for k, r in enumerate(res):
            xx = left + (k + 0.5) * w / len(res)
            yy = mid - r / span * h / 2 * 0.9
            out.append(f'<line x1="{xx:.1f}" x2="{xx:.1f}" y1="{mid}" y2="{yy:.1f}" stroke="#1565c0" stroke-width="2">'
                       f'<title>{r * 1000:+.2f} µm</title></line>')
        out.append(f'<text x="{W - 2}" y="{H + 12}" font-size="8" text-anchor="end">full height = ±{span * 1000:.1f} µm</text>')
    out.append("</svg>")
    return "".join(out)


# ------------------------------------------------------------------------ header helpers


def _date(t: Any) -> str:
    try:
        return time.strftime("%Y-%m-%d %H:%M", time.localtime(float(t)))
    except (TypeError, ValueError, OverflowError):
        return "-"


def calibration_text(start: dict, used: list[Any] | None = None) -> str:
    """Calibration status and date from the session's start snapshot; the probe's from the hits (``used``:
    :func:`cmm.session.probe_used.probe_uses`) when they recorded it: a requalification during the session counts."""
    cal = start.get("calibration")
    if not isinstance(cal, dict):
        return "not recorded in this session"
    parts = []
    probe, machine = cal.get("probe"), cal.get("machine")
    dates = sorted({u.qualified[:10] for u in used or () if u.qualified})
    if used:
        parts.append(f"probe qualified {', '.join(dates)}" if dates else
                     "probe not qualified (nominal tip radius)")
    elif probe:
        parts.append(f"probe qualified {str(probe.get('date', '?'))[:10]}")
    else:
        parts.append("probe not qualified (nominal tip radius)")
    if machine:
        parts.append(f"geometry calibrated {str(machine.get('date', '?'))[:10]}")
    else:
        parts.append("geometry not calibrated")
    if cal.get("problems"):
        parts.append(f"{len(cal['problems'])} record(s) refused")
    return "; ".join(parts)


def _tip_radius(start: dict) -> str:
    r = start.get("tip_radius")
    try:
        return f"{float(r):.4f} mm"
    except (TypeError, ValueError):
        return "not recorded"


def _pretravel(start: dict) -> str:
    coef = start.get("pretravel") or {}
    items = [f"{k} {float(v) * 1000:+.2f} µm" for k, v in coef.items() if isinstance(v, (int, float))]
    return ", ".join(items) or "none"


def _temperature(info: dict) -> str:
    t = info.get("temperature")
    if t is None or t == "":
        return "not recorded"
    try:
        return f"{float(t):.1f} °C"
    except (TypeError, ValueError):
        return str(t)


# ------------------------------------------------------------------------ the page

CSS = """
body { font: 10.5pt/1.35 system-ui, sans-serif; color: #111; margin: 24px auto; max-width: 820px; }
h1 { font-size: 17pt; margin: 0 0 4px; } h2 { font-size: 12.5pt; margin: 16px 0 6px; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; width: 100%; font-size: 9pt; }
th, td { border: 1px solid #bbb; padding: 2px 4px; text-align: right; white-space: nowrap; }
th { background: #eee; } td.l, th.l { text-align: left; white-space: normal; }
tr.fail td { background: #ffebee; } tr.none td { color: #666; }
td.ok { color: #1b5e20; font-weight: 600; } td.ng { color: #b71c1c; font-weight: 700; }
tr.feat td { border-top: 2px solid #777; }
.muted { color: #666; } .warn { color: #b71c1c; border: 1px solid #b71c1c; padding: 4px 8px; }
.verdict { font-size: 13pt; font-weight: 700; padding: 4px 10px; display: inline-block; border: 2px solid; }
.verdict.PASS { color: #1b5e20; } .verdict.FAIL { color: #b71c1c; } .verdict.INCOMPLETE { color: #8a6d00; }
.verdict.CHECK { color: #e65100; } td.chk { color: #e65100; font-weight: 700; } .checknote { color: #e65100; }
.views, .forms { display: flex; gap: 10px; flex-wrap: wrap; } svg { background: #fff; }
.head { display: grid; grid-template-columns: 1fr 1fr; gap: 0 24px; }
dl { display: grid; grid-template-columns: max-content auto; gap: 1px 10px; margin: 0; font-size: 9.5pt;
  align-content: start; }
dt { color: #555; } dd { margin: 0; word-break: break-word; }
.legend { display: flex; flex-wrap: wrap; gap: 4px 12px; font-size: 8.5pt; margin: 4px 0; }
.legend i { display: inline-block; width: 12px; height: 12px; margin-right: 4px; vertical-align: -2px;
  border: 1px solid #555; -webkit-print-color-adjust: exact; print-color-adjust: exact; }
* { -webkit-print-color-adjust: exact; print-color-adjust: exact; }
@media print {
  @page { size: A4; margin: 12mm; }
  body { margin: 0; max-width: none; font-size: 9pt; }
  h2 { break-after: avoid; } table, svg, .views, .legend, .head { break-inside: avoid; }
  thead { display: table-header-group; } tr { break-inside: avoid; }
  .forms svg { break-inside: avoid; }
}
"""


def _num(v: float | None, digits: int = 4) -> str:
    return "&mdash;" if v is None else f"{v:.{digits}f}"


def _tolerances(session: Session, program: Any, default_tolerance: float | None) -> dict[int, dict[str, float]]:
    tol_of: dict[str, dict[str, float]] = {}
    if program is not None:
        tol_of = {f.name: f.tolerance for f in program.features}
    base = dict(DEFAULT_TOLERANCE)
    if default_tolerance is not None:
        base = {k: float(default_tolerance) for k in base}
    return {fid: {**base, **(f.tolerance or {}), **tol_of.get(f.name, {})} for fid, f in session.state.features.items()}


def _constructed_rows(session: Session, default_tolerance: float | None) -> list[tuple[ConstructedRecord,
                                                                                      list[Characteristic]]]:
    base = dict(DEFAULT_TOLERANCE) if default_tolerance is None else {k: float(default_tolerance) for k in DEFAULT_TOLERANCE}
    return [(c, c.characteristics({**base, **(c.tolerance or {})})) for c in session.state.constructed.values()]




def gdt_table(rows: list[tuple[dict, Characteristic]], session: Session) -> str:
    """The geometric tolerances: feature control frame, datums and their features, value, allowed, result."""
    from ..metrology.gdt_eval import tolerance_text

    e = html.escape
    st = session.state
    out = ["<h2>Geometric tolerances</h2><table><thead><tr><th class='l'>feature</th><th class='l'>tolerance</th>"
           "<th class='l'>datums</th><th>tolerance</th><th>bonus</th><th>actual</th><th>U (95 %)</th><th>out of tol</th>"
           "<th>result</th>"
           "</tr></thead><tbody>"]
    for d, c in rows:
        frame = []
        for ref in d.get("datums") or []:
            for label in ref.split("-"):  # a common datum A-B: both of its features
                df = st.datums.get(label)
                f = None if df is None else st.features.get(int(df["feature"]))
                own = (d.get("datum_modifiers") or {}).get(label)  # the frame's own modifier, else the datum's
                mod = {"MMB": "(M)", "LMB": "(L)"}.get(((df or {}).get("modifier") or "") if own is None else own, "")
                frame.append(f"{label}{mod} = {f.name if f is not None else 'not defined'}")
        bonus = c.upper - float(d.get("tolerance") or 0.0)
        result = "<td class='chk'>check</td>" if c.check else {
            True: "<td class='ok'>pass</td>", False: "<td class='ng'>FAIL</td>",
            None: "<td class='l muted'>not evaluated</td>"}[c.ok]
        cls = "fail" if c.ok is False else "none" if c.ok is None else ""
        check = f"<br><span class='checknote'>check: {e(c.check)}</span>" if c.check else ""
        if c.uncertainty is None and c.uncertainty_why and c.actual is not None:  # no U: the reason under the frame
            check += f"<br><span class='muted'>{e(c.uncertainty_why)}</span>"
        k = "" if c.uncertainty_k is None else f" title='k = {c.uncertainty_k:.2f}'"
        out.append(f"<tr class='{cls}'><td class='l'><b>{e(c.feature)}</b></td><td class='l'>{e(tolerance_text(d))}"
                   f"<br><span class='muted'>{e(c.note)}</span>{check}</td><td class='l'>{e('; '.join(frame)) or '&mdash;'}</td>"
                   f"<td>{float(d.get('tolerance') or 0):.4f}</td><td>{'' if bonus < 1e-12 else f'{bonus:.4f}'}</td>"
                   f"<td>{_num(c.actual)}</td><td class='muted'{k}>"
                   f"{'none' if c.uncertainty is None and c.actual is not None else _num(c.uncertainty)}</td>"
                   f"<td>{'' if not c.out_of_tolerance else f'{c.out_of_tolerance:.4f}'}</td>{result}</tr>")
    out.append("</tbody></table><p class='muted'>ISO 1101 / ASME Y14.5: the actual is the width (diameter for "
               "⌀ zones) of the smallest zone of the tolerance's shape containing the feature, in the datum "
               "reference frame built from the datum features in precedence order; the tolerance allowed is the "
               "stated one plus the bonus at MMC/LMC. U (95 %): the expanded uncertainty of the value, its budget's "
               "sources (probe, machine, temperature, scatter, sampling) moved through the feature's and the datum "
               "features' fits and the zone's evaluation (a source of the set-up in all of them at once); "
               "&ldquo;none&rdquo;: none could be propagated, the reason under the frame.</p>")
    return "".join(out)


def features_csv(session: Session, *, program: Any = None, default_tolerance: float | None = None,
                 mesh: Any = None) -> str:
    """The feature table as CSV: one row per characteristic, mm (degrees for angles); geometric tolerances
    as kind ``gdt`` with their datum frame in the method column (``mesh``: for profiles)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    # the feature's actual location, diameter, axis and angle in the frame of the alignment in force (named in
    # the last column; machine coordinates when nothing was aligned): the same on every row of the feature
    frame = session_frame(session.state)
    w.writerow(["feature", "kind", "method", "hits", "characteristic", "unit", "nominal", "upper_tol", "lower_tol",
                "actual", "deviation", "out_of_tolerance", "result", "probe", "U", "k",
                *[f"actual_{k.lower()}" for k in ACTUAL_COLUMNS], "frame"])
    tols = _tolerances(session, program, default_tolerance)
    for fid, f in session.state.features.items():
        where = [*actual_cells(actuals(f.kind, f.fit, frame)), frame.label]
        for c in f.characteristics(tols[fid]):
            u = c.uncertainty
            w.writerow([f.name, f.kind, f.method, len(f.hit_ids), c.name, c.unit,
                        "" if c.nominal is None else f"{c.nominal:.6f}", f"{c.upper:.6f}", f"{c.lower:.6f}",
                        "" if c.actual is None else f"{c.actual:.6f}",
                        "" if c.deviation is None else f"{c.deviation:.6f}", f"{c.out_of_tolerance:.6f}", c.verdict,
                        f.probe or "", "" if u is None else f"{u:.6f}",
                        "" if u is None or c.uncertainty_k is None else f"{c.uncertainty_k:.2f}", *where])
    for rec, cs in _constructed_rows(session, default_tolerance):
        where = [*actual_cells(actuals(str(rec.result.get("kind", "")), rec.result, frame)), frame.label]
        for c in cs:
            w.writerow([c.feature, "constructed", rec.operation, "", c.name, c.unit,
                        "" if c.nominal is None else f"{c.nominal:.6f}", f"{c.upper:.6f}", f"{c.lower:.6f}",
                        "" if c.actual is None else f"{c.actual:.6f}",
                        "" if c.deviation is None else f"{c.deviation:.6f}", f"{c.out_of_tolerance:.6f}", c.verdict, "",
                        "" if c.uncertainty is None else f"{c.uncertainty:.6f}",
                        "" if c.uncertainty_k is None else f"{c.uncertainty_k:.2f}", *where])
    # geometric tolerances: kind "gdt", method the datum reference frame ("A|B|C"), upper_tol with any bonus
    for d, c in session_gdt(session, mesh, tols):
        w.writerow([c.feature, "gdt", c.datums, "", c.name, c.unit, "" if c.nominal is None else f"{c.nominal:.6f}",
                    f"{c.upper:.6f}", f"{c.lower:.6f}", "" if c.actual is None else f"{c.actual:.6f}",
                    "" if c.deviation is None else f"{c.deviation:.6f}", f"{c.out_of_tolerance:.6f}", c.verdict, "",
                    "" if c.uncertainty is None else f"{c.uncertainty:.6f}",
                    "" if c.uncertainty_k is None else f"{c.uncertainty_k:.2f}"])
    return buf.getvalue()


def actuals_table(session: Session) -> str:
    """Every feature's actual X, Y, Z, D, axis and angle in the frame of the alignment in force, the frame named."""
    st = session.state
    frame = session_frame(st)
    rows = [(f.name, f.kind, actuals(f.kind, f.fit, frame)) for f in st.features.values()]
    rows += [(c.name, f"constructed {c.operation}", actuals(str(c.result.get("kind", "")), c.result, frame))
             for c in st.constructed.values()]
    rows = [r for r in rows if r[2]]
    if not rows:
        return ""
    e = html.escape
    out = [f"<h2>Actuals in {e(frame.label)}</h2><table><thead><tr><th class='l'>feature</th>"
           + "".join(f"<th>{'angle °' if k == 'angle' else k}</th>" for k in ACTUAL_COLUMNS) + "</tr></thead><tbody>"]
    for name, kind, v in rows:
        out.append(f"<tr><td class='l'><b>{e(name)}</b> <span class='muted'>{e(kind)}</span></td>" + "".join(
            "<td></td>" if k not in v else f"<td>{v[k]:.6f}</td>" if k in "IJK" else f"<td>{v[k]:.4f}</td>"
            for k in ACTUAL_COLUMNS) + "</tr>")
    out.append("</tbody></table><p class='muted'>Where each feature is: its centre (a circle, sphere), a point of its "
               "axis (a cylinder, line) or plane, or its apex (a cone), its diameter D, its axis or normal (I, J, K) "
               "and a cone's included angle, in the coordinates named above.</p>")
    return "".join(out)


def render(session: Session, *, mesh: Any = None, program: Any = None, title: str | None = None,
           default_tolerance: float | None = None, colour_scale: ColourScale | None = None,
           trends: list[Any] | None = None) -> str:
    """The report as an HTML string. ``colour_scale`` (e.g. the 3D scene's) sets the colour map's bands, cut-off
    and reach; by default the form tolerance's bands. ``trends``: charts
    (:func:`cmm.session.trends_chart.trend`) shown in a section "Trends across parts"."""
    from ..journal.bulk import gc_paused

    with gc_paused():  # see cmm.journal.bulk: no collector passes over a big session while it is drawn
        return _render(session, mesh=mesh, program=program, title=title, default_tolerance=default_tolerance,
                       colour_scale=colour_scale, trends=trends)


def colour_map_of(session: Session, mesh: Any, scale: ColourScale, dev: dict[int, float]) -> tuple[
        np.ndarray, list[float | None], Any]:
    """The active hits in part coordinates (each at the alignment in force for it), their deviations (``dev``:
    :func:`~cmm.session.export.hit_deviations`), and the colour map
    (:func:`cmm.metrology.colour_map.deviation_map`, report-sized mesh; None without a mesh)."""
    from ..metrology.colour_map import REPORT_FACES, deviation_map

    st = session.state
    pts, pdev = [], []
    for i, h in st.hits.items():
        pose = st.hit_pose.get(i) or st.part_pose
        p = np.array(h.point, float)
        if pose is not None:
            T = np.array(pose, float)
            p = T[:3, :3].T @ (p - T[:3, 3])
        pts.append(p)
        pdev.append(dev.get(i))
    pts_a = np.array(pts, float).reshape(-1, 3)
    dmap = None
    if mesh is not None and st.part_pose is not None:
        dmap = deviation_map(mesh, pts_a, [math.nan if d is None else d for d in pdev], scale, faces=REPORT_FACES)
    return pts_a, pdev, dmap


def _render(session: Session, *, mesh: Any = None, program: Any = None, title: str | None = None,
            default_tolerance: float | None = None, colour_scale: ColourScale | None = None,
            trends: list[Any] | None = None) -> str:
    st = session.state
    tols = _tolerances(session, program, default_tolerance)
    base_tol = dict(DEFAULT_TOLERANCE) if default_tolerance is None else {k: float(default_tolerance) for k in DEFAULT_TOLERANCE}
    scale = colour_scale or ColourScale(base_tol["form"])
    per_feature: list[tuple[Any, list[Characteristic]]] = [(f, f.characteristics(tols[fid]))
                                                          for fid, f in st.features.items()]
    per_feature += _constructed_rows(session, default_tolerance)
    gdt_rows = session_gdt(session, mesh, tols)
    rows = [c for _, cs in per_feature for c in cs] + [c for _, c in gdt_rows]
    word, n_fail, n_missing = verdict(rows)
    if word == "CHECK":
        n_check = sum(bool(c.check) for c in rows)
        word_long = (f"CHECK ({n_check} characteristic{'s' if n_check != 1 else ''} of features another solution "
                     "fits better: see the warnings)")
    elif word == "FAIL":
        word_long = f"FAIL ({n_fail} characteristic{'s' if n_fail != 1 else ''} out of tolerance)"
    elif word == "INCOMPLETE":
        word_long = f"INCOMPLETE ({n_missing} characteristic{'s' if n_missing != 1 else ''} without a nominal)"
    else:
        word_long = "PASS" if rows else "PASS (no features)"
    dev = hit_deviations(session, mesh) if mesh is not None else {}
    ids = list(st.hits)
    dev_ids = [i for i in ids if i in dev]
    devs = [dev[i] for i in dev_ids]
    s, info = session.start, st.info
    e = html.escape
    heading = title or "Inspection report"
    out = ["<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>",
           f"<title>{e(heading + ' ' + session.name)}</title><style>{CSS}</style></head><body>",
           f"<h1>{e(heading)}</h1>",
           f"<p class='muted'>Session <b>{e(session.name)}</b> &middot; measured {_date(s.get('time'))} &middot; "
           f"report generated {e(time.strftime('%Y-%m-%d %H:%M'))}</p>",
           f"<p>result: <span class='verdict {word}'>{e(word_long)}</span></p>"]
    warnings = list(session.warnings)
    if st.part is not None and st.hits and not st.alignments:
        warnings.insert(0, NO_ALIGNMENT)
    for w in warnings:
        out.append(f"<p class='warn'>{e(w)}</p>")
    part = "none" if st.part is None else st.part.name
    left = [("part", part)] + [(label, str(info.get(k) or "—")) for k, label in HEADER_FIELDS[:3]]
    left += [("temperature", _temperature(info))]
    if info.get("remarks"):
        left.append(("remarks", str(info["remarks"])))
    machine = str(info.get("machine_name") or "")
    config = Path(str(s.get("config", ""))).name
    used = probe_uses(session)  # the probe data the hits were taken with, not the start's snapshot
    right = [("machine", ", ".join(x for x in (machine, config) if x) or "-"),
             ("calibration", calibration_text(s, used)),
             ("tip radius", ", ".join(dict.fromkeys(f"{u.tip_radius:.4f} mm" for u in used if u.tip_radius is not None))
              or _tip_radius(s)),
             ("pre-travel", "; ".join(dict.fromkeys(u.pretravel for u in used if u.pretravel)) or _pretravel(s)),
             *([("probe data of the hits", "; ".join(u.text() for u in used))] if used else []),
             ("alignment", "none" if st.alignment is None else
              st.alignment.method.replace("_", " ")
              + "".join(f" {'/'.join(str(n) for n in names)}" for names in [st.alignment.info.get("names")] if names)
              + (f", RMS {st.alignment.info['rms'] * 1000:.2f} µm" if isinstance(st.alignment.info.get("rms"), (int, float)) else "")),
             ("actuals in", session_frame(st).label),
             ("hits", f"{len(st.hits)}" + (f" (+{len(st.deleted_hits)} deleted)" if st.deleted_hits else "")),
             ("part sha256", "" if st.part is None or not st.part.sha256 else st.part.sha256[:16] + "…")]
    if session.derived_from:
        right.append(("derived from", f"{session.derived_from.get('session')} ({session.derived_from.get('how', '')})"))
    if program is not None:
        right.append(("program", program.name))

    def dl(items: list[tuple[str, str]]) -> str:
        return "<dl>" + "".join(f"<dt>{e(k)}</dt><dd>{e(v)}</dd>" for k, v in items) + "</dl>"

    out.append(f"<div class='head'>{dl(left)}{dl(right)}</div>")
    out.append("<h2>Features</h2><table><thead><tr><th class='l'>feature</th><th class='l'>probe</th>"
               "<th class='l'>characteristic</th>"
               "<th>nominal</th><th>+tol</th><th>&minus;tol</th><th>actual</th><th>U (95 %)</th><th>deviation</th>"
               "<th>out of tol</th><th>result</th></tr></thead><tbody>")
    for f, cs in per_feature:
        for k, c in enumerate(cs):
            cls = ("fail" if c.ok is False else "none" if c.ok is None else "") + (" feat" if k == 0 else "")
            built = isinstance(f, ConstructedRecord)
            if built:
                what = f"constructed: {f.operation} of features {', '.join(str(i) for i in f.operands)}"
                probe = ""
            else:
                what = f"{f.kind}, {f.method}, {len(f.hit_ids)} hits"
                proof = proof_text(f.fit.get("proof"))
                what += f"; {proof}" if proof else ""
                probe = f.probe or ""  # "": recorded before features named their probe
            fname = f.name
            name_cell = (f"<td class='l' rowspan='{len(cs)}'><b>{e(fname)}</b><br><span class='muted'>{e(what)}"
                         f"</span></td><td class='l' rowspan='{len(cs)}'>{e(probe) or '&mdash;'}</td>") if k == 0 else ""
            unit = "°" if c.unit == "deg" else ""
            lower = "" if c.lower == 0.0 else f"{c.lower:.4f}"
            # notes: why a value is missing; for a constructed value also how it was measured (its projection)
            note = f"<br><span class='muted'>{e(c.note)}</span>" if c.note and (c.ok is None or built) \
                else ""
            if c.check:
                note += f"<br><span class='checknote'>check: {e(c.check)}</span>"
            if c.uncertainty is None and c.uncertainty_why and c.actual is not None:
                note += f"<br><span class='muted'>{e(c.uncertainty_why)}</span>"
            result = "<td class='chk'>check</td>" if c.check else {
                True: "<td class='ok'>pass</td>", False: "<td class='ng'>FAIL</td>",
                None: "<td class='l muted'>not evaluated</td>"}[c.ok]
            out.append(f"<tr class='{cls.strip()}'>{name_cell}<td class='l'>{e(c.name)}{note}</td>"
                       f"<td>{_num(c.nominal)}{unit if c.nominal is not None else ''}</td><td>{c.upper:.4f}</td>"
                       f"<td>{lower}</td><td>{_num(c.actual)}{unit if c.actual is not None else ''}</td>"
                       f"<td class='muted'>{'none' if c.uncertainty_why and c.actual is not None else _num(c.uncertainty)}</td><td>{_num(c.deviation)}</td><td>{'' if not c.out_of_tolerance else f'{c.out_of_tolerance:.4f}'}</td>"
                       f"{result}</tr>")
    if not per_feature:
        out.append("<tr><td class='l' colspan='11'>no features were fitted in this session</td></tr>")
    out.append("</tbody></table><p class='muted'>Lengths in mm, angles in degrees. Sizes and locations against the "
               "feature's nominal from the part (CAD); position is the diameter of the zone the actual axis or centre "
               "lies in (ISO 1101), relative to the alignment; form is the fitted feature's max &minus; min residual. "
               "&ldquo;Not evaluated&rdquo;: the feature has no nominal for this characteristic. U (95 %): the expanded "
               "uncertainty from the feature's budget (probe, machine, temperature, sampling, scatter), where it has "
               "one: U = k u_c with k = 2, or Student's t for the budget's effective degrees of freedom where a few "
               "hits' residuals carry most of it (k up to about 2.3; the features CSV gives k); &ldquo;none&rdquo;: the value has no uncertainty, the "
               "reason under its name.</p>")
    out.append(actuals_table(session))
    if gdt_rows:
        out.append(gdt_table(gdt_rows, session))
    out.append("<h2>Deviation of each hit from the part</h2>")
    out.append(legend_html(scale))
    out.append(deviation_plot(dev_ids, devs, scale))
    if devs:
        a = np.array([d for d in devs if abs(d) <= scale.max_distance])
        cut = len(devs) - len(a)
        if len(a):
            out.append(f"<p class='muted'>Signed distance of the compensated points to the part surface (+ = material "
                       f"outside nominal): min {a.min() * 1000:+.2f} µm, max {a.max() * 1000:+.2f} µm, RMS "
                       f"{np.sqrt(np.mean(a * a)) * 1000:.2f} µm"
                       + (f"; {cut} hit{'s' if cut != 1 else ''} beyond the {scale.max_distance:g} mm cut-off not counted"
                          if cut else "") + ".</p>")
        else:
            out.append(f"<p class='warn'>Every hit is more than {scale.max_distance:g} mm from the part surface.</p>")
    out.append("<h2>Colour map</h2>")
    if st.hits:
        pts_a, pdev, dmap = colour_map_of(session, mesh, scale, dev)
        frame = "part coordinates" if st.part_pose is not None else "machine coordinates"
        out.append(legend_html(scale))
        out.append("<div class='views'>")
        normals = None
        if dmap is not None:  # the hits' surface normals, found once for the three views (which hide hits)
            from ..metrology.colour_map import hits_on_surface

            normals = hits_on_surface(mesh, pts_a)[1]
        for name, view in (VIEWS if mesh is not None else VIEWS[:2]):
            out.append(part_view(mesh, pts_a, pdev, scale, np.array(view), f"{name}, {frame}", dmap=dmap,
                                 hit_normals=normals))
        out.append("</div>")
        if dmap is not None:
            out.append(f"<p class='muted'>The part's surface in the colour of the deviation of the hits around it "
                       f"(inverse-distance weighted, hits on the same surface within {scale.reach:g} mm); grey: "
                       f"no hit within {scale.reach:g} mm. {dmap.hits_used} hit{'s' if dmap.hits_used != 1 else ''} "
                       f"colour {dmap.coverage * 100:.0f} % of the surface. Dots: the hits.</p>")
        elif mesh is None:
            out.append("<p class='muted'>The part mesh was not found (or its sha256 does not match): hits only.</p>")
    else:
        out.append("<p class='muted'>No hits.</p>")
    forms = []
    all_hits = {**st.deleted_hits, **st.hits}
    for fid, f in st.features.items():
        pts = np.array([all_hits[h].point for h in f.hit_ids if h in all_hits], float).reshape(-1, 3)
        forms.append(form_plot(f, pts, tols[fid]["form"]))
    forms = [x for x in forms if x]
    if forms:
        out.append("<h2>Form plots</h2><p class='muted'>Residual of each hit to its fitted feature, magnified; "
                   "dashed: the form tolerance band.</p><div class='forms'>" + "".join(forms) + "</div>")
    if trends:
        from .trends_chart import trends_section

        out.append(trends_section(trends))
    texts = [error_text(str(ev.get("source", "")), str(ev.get("message", "")))
             for ev in session.events if ev.get("kind") == "error"]
    if st.notes or texts:
        out.append("<h2>Notes and machine events</h2><ul>")
        out += [f"<li>{e(t)}</li>" for _, t in st.notes]
        out += [f"<li>{e(t)}" + (f" <span class='muted'>(&times;{n})</span>" if n > 1 else "") + "</li>"
                for t, n in grouped(texts)]
        out.append("</ul>")
    out.append("</body></html>\n")
    return "".join(out)


def write_report(session: Session, path: str | Path, **kw: Any) -> Path:
    p = Path(path)
    p.write_text(render(session, **kw), encoding="utf-8")
    return p


def write_part_report(journal: Path, *, mesh: Any = None, title: str = "") -> Path:
    """The report of the session journalled at ``journal`` (a file), written beside it as HTML: what a routine's
    report step makes (the measurement model's ``reporter``)."""
    from ..journal.store import open_session

    return write_report(open_session(journal), journal.with_suffix(".html"), mesh=mesh, title=title)


def write_features_csv(session: Session, path: str | Path, **kw: Any) -> Path:
    p = Path(path)
    p.write_text(features_csv(session, **kw), encoding="utf-8")
    return p
