"""The "Features" tab: a feature tree as in PC-DMIS / CALYPSO, nominals and tolerances, constructions.

The tree lists every fitted and constructed feature with its method and hits,
and under it each characteristic (nominal, actual, deviation, tolerance) in
its pass / fail / no-nominal colour (:mod:`cmm.metrology.characteristics`, the
same rules as the report). Selecting a feature highlights it and its hits in
the 3D view and lists its hits with their residuals; a hit can be removed
(the feature refits) or re-taken (the next hit replaces it, then it refits).
Nominals come from the CAD (where the hits lie, or the last pick) or are
typed; tolerances are typed. Constructions: intersection, distance, angle,
mid-point of two features. Datums (A, B, C: a feature each, RFS or MMB/LMB) and geometric tolerances
(:mod:`cmm.metrology.gdt_eval`: a characteristic on a feature against datums) are defined here too and
listed under "Geometric tolerances" in the tree, evaluated as the report does. The report header (part number, drawing,
operator, temperature) is set here too; the colour map has its own tab
(:mod:`cmm.ui.panel_colour_map`).
"""

from __future__ import annotations

import html
import math
import threading
from dataclasses import replace
import re
from typing import Any

import numpy as np

from ..metrology import fit_criteria
from ..metrology.construct import OPERATIONS
from ..metrology.feature_distance import surface_distance
from ..metrology.features import proof_text
from ..metrology.gdt import CHARACTERISTICS, FORM
from ..metrology.pick import NominalFeature
from ..metrology.actuals import actuals, actuals_text, model_frame
from ..measurement.errors import FEATURE_KINDS, MeasurementError
from .context import PanelContext
from .ids import parse_ids, parse_targets
from .model_view import reader

RESULT_COLOURS = {True: "#2e7d32", False: "#c62828", None: "#8d6e00"}
RESULT_WORDS = {True: "pass", False: "FAIL", None: "no nominal"}
CHECK_COLOUR = "#e65100"  # another solution fits the hits better: the operator checks (see characteristics)


def feature_chars(f: Any) -> list[Any]:
    """A live feature's characteristics: those of its record, as the report shows them."""
    return f.record().characteristics()


def tree_html(source: Any, selected: int | None = None, hidden: Any = (), machine: bool = False) -> str:
    """The feature tree (pure: drawn from the queries of ``source``, a query function or the command API, see
    :func:`cmm.ui.model_view.reader`, so it is tested without a browser); features in ``hidden`` are marked so.
    Under each feature its actual X, Y, Z (D, axis, angle) in the alignment's frame, named at the top
    (``machine``: in machine coordinates)."""
    e = html.escape
    query = reader(source)
    view = query("model")
    frame = model_frame(view, machine)
    feats, built = sorted(view.features.items()), sorted(view.constructed.items())
    if not feats and not built:
        return "<p style='color:#777'>No features yet: take hits, then Fit (or Auto-measure a face).</p>"
    rows = [f"<div class='cmm-frame' style='font:11px system-ui;color:#444'>actuals in <b>{e(frame.label)}</b></div>"
            "<table class='cmm-tree' style='border-collapse:collapse;width:100%;font:11px system-ui'>"
            "<tr style='color:#666'><th align=left>feature</th><th align=right>nominal</th><th align=right>actual</th>"
            "<th align=right>dev</th><th align=right>tol</th><th></th></tr>"]
    items = [(fid, f.name, " · ".join(filter(None, (f.kind, f.method, f"{len(f.hit_ids)} hits",
                                                     proof_text(getattr(f.result, "proof", None), short=True)))),
              feature_chars(f)) for fid, f in feats]
    where = {fid: actuals_text(actuals(f.kind, f.result.geometry(), frame)) for fid, f in feats}
    items += [(fid, c.name, f"constructed {c.operation} of {c.operands[0]} and {c.operands[1]}",
               c.record().characteristics()) for fid, c in built]
    for fid, c in built:
        summary = c.result.summary()
        where[fid] = actuals_text(actuals(str(summary.get("kind", "")), summary, frame))
    gdt_rows = query("gdt_characteristics")
    if gdt_rows or view.datums:
        datums = ", ".join(f"{k}{ {'MMB': '(M)', 'LMB': '(L)'}.get(d.get('modifier') or '', '')} = feature {d['feature']}"
                           for k, d in sorted(view.datums.items()))
        items.append((None, "Geometric tolerances", f"datums: {datums or 'none'}",
                      [replace(c, feature=f"{d.get('id')} {c.feature}") for d, c in gdt_rows]))
    for fid, name, what, chars in items:
        oks = [c.ok for c in chars]
        worst = False if False in oks else (None if None in oks else True)
        head = CHECK_COLOUR if any(c.check for c in chars) else RESULT_COLOURS[worst]
        chosen = fid is not None and fid == selected
        mark = "▶ " if chosen else ""
        bg = "background:#fff8c4;" if chosen else ""
        off = " <i style='color:#999'>(hidden)</i>" if fid is not None and fid in hidden else ""
        rows.append(f"<tr style='{bg}border-top:1px solid #ccc'><td colspan=6 data-feature='{fid}'>"
                    f"<b style='color:{head}'>{mark}{'' if fid is None else fid} {e(name)}</b> "
                    f"<span style='color:#777'>{e(what)}</span>{off}</td></tr>")
        if where.get(fid):
            rows.append(f"<tr style='{bg}'><td colspan=6 class='cmm-actual' style='padding-left:10px;"
                        f"font-family:monospace'>{e(where[fid])}</td></tr>")
        for c in chars:
            unit = "°" if c.unit == "deg" else ""
            nominal = "—" if c.nominal is None else f"{c.nominal:.4f}{unit}"
            actual = "—" if c.actual is None else f"{c.actual:.4f}{unit}"
            if c.actual is not None and c.uncertainty is not None:  # the expanded U of the feature's budget, its k
                k = "" if c.uncertainty_k is None else f" title='U (95 %), k = {c.uncertainty_k:.2f}'"
                actual += f" <span style='color:#777'{k}>±{c.uncertainty:.4f}</span>"
            elif c.actual is not None and c.uncertainty_why:  # no U: said so, the reason in its tooltip
                actual += f" <span style='color:#777' title='{e(c.uncertainty_why)}'>(no U)</span>"
            dev = "" if c.deviation is None else f"{c.deviation:+.4f}"
            label = c.name.replace(' (along the normal)', '') if fid is not None else f"{c.feature}: {c.name}"
            rows.append(f"<tr style='{bg}'><td style='padding-left:10px' title='{e(c.note)}'>"
                        f"{e(label)}"
                        f"</td><td align=right>{nominal}</td>"
                        f"<td align=right>{actual}</td><td align=right>{dev}</td>"
                        f"<td align=right style='white-space:nowrap'>{e(c.tolerance_text)}</td>"
                        + (f"<td style='color:{CHECK_COLOUR};font-weight:600' title='{e(c.check)}'>check</td></tr>"
                           if c.check else
                           f"<td style='color:{RESULT_COLOURS[c.ok]};font-weight:600'>{RESULT_WORDS[c.ok]}</td></tr>"))
    rows.append("</table>")
    return "".join(rows)


def typed_nominal(feature: Any, centre: Any = None, diameter: float | None = None) -> NominalFeature:
    """A nominal from typed values, starting from the feature's nominal (or its fitted geometry)."""
    g = feature.result.geometry()
    if feature.nominal is not None:
        base = feature.nominal.copy()
    elif feature.kind in ("circle", "cylinder"):
        axis = g["normal"] if feature.kind == "circle" else g["direction"]
        base = NominalFeature("cylinder", {"point": g["center"] if feature.kind == "circle" else g["point"],
                                           "direction": axis, "radius": g["radius"]})
    elif feature.kind == "sphere":
        base = NominalFeature("sphere", {"center": g["center"], "radius": g["radius"]})
    elif feature.kind == "plane":
        base = NominalFeature("plane", {"point": g["point"], "normal": g["normal"]})
    else:
        raise MeasurementError(f"a {feature.kind} has no nominal to type")
    p = base.params
    if diameter is not None:
        if base.kind not in ("cylinder", "sphere"):
            raise MeasurementError(f"a {base.kind} has no diameter")
        if not (np.isfinite(diameter) and diameter > 0):
            raise MeasurementError(f"a nominal diameter must be a positive number, got {diameter}")
        p["radius"] = float(diameter) / 2
    if centre is not None:
        c = np.asarray(centre, float)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise MeasurementError("the nominal centre needs three finite coordinates")
        key = "center" if base.kind == "sphere" else "point"
        p[key] = c
    return NominalFeature(base.kind, p)


def nominal_fields(feature: Any) -> tuple[tuple[float, float, float], float] | None:
    """What the typed-nominal fields show for a feature: its nominal's centre (axis point, sphere centre) and
    diameter, or None when it has no nominal with a centre (the fields are left as the operator typed them)."""
    if feature is None or feature.nominal is None:
        return None
    p = feature.nominal.params
    centre = p.get("center", p.get("point"))
    if centre is None:
        return None
    radius = p.get("radius")
    return (tuple(round(float(v), 4) for v in np.asarray(centre, float).reshape(3)),
            0.0 if radius is None else round(2.0 * float(radius), 4))


def _unit(v: Any) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _angle(u: Any, v: Any) -> float:
    """Angle between two axes (sign ignored), degrees."""
    c = abs(float(np.dot(_unit(u), _unit(v))))
    return math.degrees(math.acos(min(c, 1.0)))


def _dist_to_axis(p: Any, point: Any, direction: Any) -> float:
    d = _unit(direction)
    r = np.asarray(p, float) - np.asarray(point, float)
    return float(np.linalg.norm(r - (r @ d) * d))


def nominal_deviation(kind: str, geometry: dict[str, Any], nominal: Any) -> dict[str, float]:
    """Deviations of a fitted feature from a nominal one (mm, degrees); empty when they do not compare."""
    if nominal is None:
        return {}
    g = {k: np.asarray(v, float) if isinstance(v, list) else v for k, v in geometry.items()}
    n, p = nominal.kind, nominal.params
    out: dict[str, float] = {}
    if kind == "plane" and n in ("plane", "surface"):
        out["distance"] = float((g["point"] - p["point"]) @ _unit(p["normal"]))
        out["angle_deg"] = _angle(g["normal"], p["normal"])
    elif kind == "sphere" and n == "sphere":
        out["centre_offset"] = float(np.linalg.norm(g["center"] - p["center"]))
        out["radius_dev"] = float(g["radius"] - p["radius"])
    elif kind == "cylinder" and n == "cylinder":
        out["radius_dev"] = float(g["radius"] - p["radius"])
        out["axis_offset"] = _dist_to_axis(g["point"], p["point"], p["direction"])
        out["axis_angle_deg"] = _angle(g["direction"], p["direction"])
    elif kind == "circle" and n == "cylinder":
        out["radius_dev"] = float(g["radius"] - p["radius"])
        out["centre_to_axis"] = _dist_to_axis(g["center"], p["point"], p["direction"])
        out["axis_angle_deg"] = _angle(g["normal"], p["direction"])
    elif kind == "cone" and n == "cone":
        out["apex_offset"] = float(np.linalg.norm(g["apex"] - p["apex"]))
        out["half_angle_dev_deg"] = math.degrees(float(g["half_angle"]) - float(p["half_angle"]))
        out["axis_angle_deg"] = _angle(g["direction"], p["direction"])
    return out


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4f}"
    if isinstance(v, list):
        return "(" + ", ".join(f"{x:.4f}" for x in v) + ")"
    return str(v)


class FeaturesPanel:
    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.gui: dict[str, Any] = {}
        self.retake: tuple[int, int, int] | None = None  # (feature, hit to replace, newest hit id when armed)
        self._nominal_shown: Any = None  # the feature (and its nominal) the nominal fields were filled from
        self.rows: dict[int, Any] = {}  # feature id -> its Show checkbox (Show > Each feature), one per tree row
        self._row_view: dict[int, bool] = {}  # feature id -> shown in the view when its box was last synced
        self._rows_lock = threading.Lock()  # refresh runs in the refresher and after a selection
        self._gui_api: Any = None
        self.machine = False  # actuals in machine coordinates (on demand) instead of the alignment's frame

    # --- actions (each checks control through ctx.run) -------------------------------------

    def hit_ids_for(self, ids_text: str, last_n: int) -> list[int]:
        if ids_text.strip():
            return parse_ids(ids_text)
        ids = sorted(self.ctx.model().hits)
        return ids[-int(last_n):] if last_n > 0 else ids

    def fit(self, kind: str, method: str = "ls", ids_text: str = "", last_n: int = 0) -> Any:
        def do() -> Any:
            ids = self.hit_ids_for(ids_text, last_n)
            # the nominal is the CAD surface the hits lie on (the station finds it), not the last click:
            # "Nominal from the last CAD pick" in the Features tab applies a pick on purpose
            feature = self.ctx.commands.invoke(self.ctx.who(), "measure_feature", kind=kind, hits=ids, method=method)
            self.ctx.selected_feature = feature.id
            self.ctx.view.select_feature(feature.id)
            self.ctx.notify("Fitted", f"{feature.name}: form {feature.result.form * 1000:.2f} um "
                                      f"from {len(ids)} hits")
            return feature
        return self.ctx.run("Fit", do, guarded=False)  # the measure_feature verb decides who may

    def feature_markdown(self) -> str:
        fid = self.ctx.selected_feature
        model = self.ctx.model()
        feature = model.features.get(fid) if fid is not None else None
        if feature is None:
            return "*no feature selected*"
        s = feature.result.summary()
        lines = [f"**{feature.name}** ({feature.kind}, {feature.method}, hits {feature.hit_ids})", "",
                 f"form error: **{s['form'] * 1000:.2f} um**"
                 + (f" · sigma {s['sigma'] * 1000:.2f} um" if s.get("sigma") is not None else "")]
        if s.get("uncertainty"):  # standard uncertainties: angles (rad) in urad, lengths (mm) in um
            lines.append("u (1 sigma): " + " · ".join(
                f"{k} {v * 1e6:.1f} urad" if k in ("normal", "direction", "half_angle") else f"{k} {v * 1000:.2f} um"
                for k, v in s["uncertainty"].items()))
        if s.get("proof"):
            lines.append(f"\n{proof_text(s['proof'])}")
        lines.extend(f"\n**warning:** {w}" for w in s.get("warnings", []))
        frame = model_frame(model, self.machine)
        lines.append(f"\nactual in {frame.label}: **{actuals_text(actuals(feature.kind, feature.result.geometry(), frame))}**")
        if self.machine:
            lines.append("\ngeometry (machine coordinates, mm):")
            for k, v in feature.result.geometry().items():
                lines.append(f"- {k}: {_fmt(v)}")
        dev = nominal_deviation(feature.kind, feature.result.geometry(), feature.nominal)
        if dev:
            lines.append(f"\nvs nominal {feature.nominal.kind}:")
            lines.extend(f"- {k}: {v:+.4f}" for k, v in dev.items())
        return "\n".join(lines)


    def selected(self) -> Any:
        fid = self.ctx.selected_feature
        return None if fid is None else self.ctx.model().features.get(fid)

    def remove_hit(self, hid: int) -> Any:
        f = self.selected()
        if f is None:
            return self.ctx.error("select a feature first", "Remove hit")
        if hid not in f.hit_ids:
            return self.ctx.error(f"hit {hid} is not in {f.name} (hits {f.hit_ids})", "Remove hit")
        return self.ctx.do("Remove hit", "refit_feature", feature=f.id, hits=[h for h in f.hit_ids if h != hid])

    def retake_hit(self, hid: int) -> None:
        f = self.selected()
        if f is None or hid not in f.hit_ids:
            return self.ctx.error(f"pick a hit of the selected feature to re-take", "Re-take")
        if not self.ctx.allowed("Re-take"):
            return
        self.retake = (f.id, hid, max(self.ctx.model().hits, default=0))
        self.ctx.notify("Re-take", f"take the new hit for hit {hid} of {f.name} (Probe here, jog or auto)")

    def _check_retake(self) -> None:
        if self.retake is None:
            return
        fid, old, newest = self.retake
        view = self.ctx.model()
        fresh, f = sorted(h for h in view.hits if h > newest), view.features.get(fid)
        if not fresh or f is None:
            return
        self.retake = None
        ids = [fresh[0] if h == old else h for h in f.hit_ids]
        feature = self.ctx.do("Re-take", "refit_feature", feature=fid, hits=ids)
        if feature is not None:
            self.ctx.do("Re-take", "delete_hit", hit=old)
            self.ctx.notify("Re-take", f"hit {old} replaced by hit {fresh[0]}; {f.name} refitted")

    def nominal_from_pick(self) -> Any:
        f = self.selected()
        nominal = self.ctx.picked[1] if self.ctx.picked is not None else None
        if f is None or nominal is None:
            return self.ctx.error("select a feature and click its surface on the part first", "Nominal")
        return self.ctx.do("Nominal", "set_nominal", feature=f.id, nominal=nominal)

    def type_nominal(self, centre: Any = None, diameter: float | None = None) -> Any:
        f = self.selected()
        if f is None:
            return self.ctx.error("select a feature first", "Nominal")
        return self.ctx.run("Nominal", lambda: self.ctx.commands.invoke(
            self.ctx.who(), "set_nominal", feature=f.id, nominal=typed_nominal(f, centre, diameter)), guarded=False)

    def set_tolerance(self, **tol: float) -> Any:
        fid = self.ctx.selected_feature
        if fid is None:
            return self.ctx.error("select a feature first", "Tolerance")
        return self.ctx.do("Tolerance", "set_nominal", feature=fid, tolerance=tol)

    def construct(self, operation: str, a: int, b: int, name: str = "", three_d: bool = False) -> Any:
        c = self.ctx.do("Construct", "construct", operation=operation, a=a, b=b, name=name or None, three_d=three_d)
        if c is not None:
            self.ctx.selected_feature = c.id
            if "construct_name" in self.gui:
                self.gui["construct_name"].value = ""  # a name is one construction's: the next gets its own
        return c

    def define_datum(self, label: str, feature: int, modifier: str = "", targets: str = "") -> Any:
        """Datum ``label`` from a feature, or from its targets (``targets`` as typed: hit ids "12 14 17", target
        areas and lines of hits "area(12-14) line(15 16) 17")."""
        return self.ctx.run("Datum", lambda: self.ctx.commands.invoke(
            self.ctx.who(), "define_datum", label=label, feature=feature, modifier=modifier,
            targets=parse_targets(targets) if targets.strip() else None), guarded=False)

    def define_gdt(self, characteristic: str, feature: int, tolerance: float, datums: str = "",
                   material: str = "", angle: float | None = None, direction: str = "radial",
                   pattern: str = "", lower: float = 0.0, lower_datums: str = "", offset: float = 0.0) -> Any:
        """A geometric tolerance on a feature against datums "A|B|C" or a common datum "A-B" (refused in words
        when it cannot be evaluated); the tree lists it under "Geometric tolerances". A composite position: the
        ``pattern``'s feature ids as typed ("3 5 8") and the feature-relating tier's tolerance ``lower`` and
        datums ``lower_datums`` ("A"). ``offset``: a profile's unequally disposed zone (mm, UZ)."""
        def do() -> Any:
            extra: dict[str, Any] = {}
            if lower:
                extra = {"pattern": parse_ids(pattern), "composite": {"tolerance": lower, "datums": lower_datums}}
            if offset:
                extra["offset"] = offset
            d, c = self.ctx.commands.invoke(self.ctx.who(), "define_gdt", characteristic=characteristic,
                                            feature=feature, tolerance=tolerance, datums=datums, material=material,
                                            angle=angle, direction=direction, **extra)
            self.ctx.notify("GD&T", f"{d['name']}: {c.actual:.4f} ({c.verdict})")
            return d, c
        return self.ctx.run("GD&T", do, guarded=False)  # the define_gdt verb decides who may

    def delete_gdt(self, gid: int) -> Any:
        return self.ctx.do("GD&T", "delete_gdt", gdt=gid)

    def delete_feature(self) -> None:
        fid = self.ctx.selected_feature
        if fid is not None:
            self.ctx.do("Delete feature", "delete_feature", feature=fid)
            self.ctx.selected_feature = None

    def save_info(self, **fields: Any) -> Any:
        return self.ctx.do("Report header", "set_info", **fields)

    # --- what the 3-D view shows ----------------------------------------------------------------

    def show_selected(self, shown: bool) -> None:
        """Show or hide the selected feature in the 3-D view (anyone may: it changes no record)."""
        fid = self.ctx.selected_feature
        if fid is None:
            if not shown:
                self.ctx.error("select a feature first", "Show")
            return
        self.ctx.view.show_feature(fid, bool(shown))

    def show_feature(self, fid: int, shown: bool) -> None:
        """Show or hide one feature in the 3-D view (its row's checkbox)."""
        self.ctx.view.show_feature(fid, bool(shown))

    def show_kind(self, kind: str, shown: bool) -> None:
        self.ctx.view.show_kind(kind, bool(shown))

    def show_all(self) -> None:
        self.ctx.view.show_all()
        self._sync_show()
        self._sync_rows()

    def hidden(self) -> set[int]:
        """The features the 3-D view does not draw now (hidden themselves or by their kind)."""
        kinds = {fid: f.kind for fid, f in self.ctx.model().features.items()}
        return {fid for fid, kind in kinds.items() if not self.ctx.view.feature_shown(fid, kind)}

    def _sync_show(self) -> None:
        """The Show checkboxes say what the view does (another tab may have changed it)."""
        view = self.ctx.view
        fid = self.ctx.selected_feature
        for kind in FEATURE_KINDS:
            self.ctx.set(f"features:show_{kind}", "value", kind not in view.hidden_kinds, self.gui.get(f"show_{kind}"))
        self.ctx.set("features:show_feature", "value", fid is None or fid not in view.hidden_features,
                     self.gui.get("show_feature"))

    def _sync_rows(self) -> None:
        """One Show checkbox per fitted feature, labelled as its tree row (id and name), added and removed with the
        features and ticked as the view draws it (another tab may have changed that)."""
        folder = self.gui.get("show_rows")
        if folder is None or self._gui_api is None:
            return
        feats = {fid: (f.name, f.kind) for fid, f in self.ctx.model().features.items()}
        hidden = self.ctx.view.hidden_features
        with self._rows_lock:
            for fid in [f for f in self.rows if f not in feats]:
                self.rows.pop(fid).remove()
                self._row_view.pop(fid, None)
            for fid in sorted(feats):
                name, kind = feats[fid]
                label, shown = f"{fid} {name}", fid not in hidden
                box = self.rows.get(fid)
                if box is None:
                    with folder:
                        box = self._gui_api.add_checkbox(label, shown, hint=f"draw {name} ({kind}) in the 3-D view")
                    box.on_update(lambda e, fid=fid: self.show_feature(fid, e.target.value))
                    self.rows[fid] = box
                    self._row_view[fid] = shown
                    continue
                if box.label != label:
                    box.label = label  # renamed
                # the box follows the view only when the view changed (another tab, Show all): a click whose
                # callback has not run yet is not overridden by the view's state from before it
                if self._row_view.get(fid) != shown:
                    self._row_view[fid] = shown
                    if box.value != shown:
                        box.value = shown

    # --- read-outs -------------------------------------------------------------------------

    def hits_html(self) -> str:
        f = self.selected()
        if f is None:
            return ""
        hits = self.ctx.model().hit_or_deleted()
        pts = np.array([hits[h].point for h in f.hit_ids if h in hits], float).reshape(-1, 3)
        try:
            res = surface_distance(f.kind, f.result.summary(), pts)
        except (KeyError, ValueError):
            res = np.full(len(pts), np.nan)
        cells = " · ".join(f"{h}: {r * 1000:+.1f} µm" for h, r in zip(f.hit_ids, res))
        return f"<div style='font:11.5px system-ui'><b>{html.escape(f.name)}</b> hits (residual): {cells}</div>"

    def detail_markdown(self) -> str:
        fid = self.ctx.selected_feature
        c = self.ctx.model().constructed.get(fid) if fid is not None else None
        if c is None:
            return self.feature_markdown()
        r = c.result.summary()
        value = f"{r['value']:.4f}{'°' if r['kind'] == 'angle' else ' mm'}" if "value" in r else ", ".join(
            f"{k} ({', '.join(f'{x:.4f}' for x in v)})" for k, v in r.items() if isinstance(v, list))
        return f"**{c.name}**: constructed {c.operation} of features {c.operands[0]} and {c.operands[1]}: {value}"

    def options(self) -> tuple[str, ...]:
        return tuple(f"{fid} {name}" for fid, name in self.ctx.model().named()) or ("-",)

    # --- GUI ---------------------------------------------------------------------------------

    def build(self, gui: Any) -> None:
        g = self.gui
        g["machine"] = gui.add_checkbox("Machine coordinates", False,
                                        hint="actuals in machine coordinates instead of the alignment's frame")
        g["machine"].on_update(lambda e: setattr(self, "machine", bool(e.target.value)))
        g["tree"] = gui.add_html(tree_html(self.ctx.query))
        g["features"] = gui.add_dropdown("Feature", ("-",), initial_value="-")
        g["features"].on_update(lambda e: self._chosen(e.target.value))
        g["hits"] = gui.add_html("")
        g["detail"] = gui.add_markdown(self.feature_markdown())  # fit details: geometry, uncertainties, warnings
        with gui.add_folder("Show", expand_by_default=False):
            g["show_feature"] = gui.add_checkbox("Selected feature", True,
                                                 hint="draw the selected feature in the 3-D view")
            g["show_feature"].on_update(lambda e: self.show_selected(e.target.value))
            self._gui_api = gui
            g["show_rows"] = gui.add_folder("Each feature", expand_by_default=True)  # filled by _sync_rows
            for kind in FEATURE_KINDS:
                g[f"show_{kind}"] = box = gui.add_checkbox(f"{kind.capitalize()}s", True,
                                                           hint=f"draw every {kind} in the 3-D view")
                box.on_update(lambda e, kind=kind: self.show_kind(kind, e.target.value))
            gui.add_button("Show all").on_click(lambda _: self.show_all())
        with gui.add_folder("Fit hits"):
            kind = gui.add_dropdown("Kind", FEATURE_KINDS, initial_value="plane")
            method = gui.add_dropdown("Method", fit_criteria.methods_for("plane"), initial_value="ls")
            kind.on_update(lambda e: setattr(method, "options", fit_criteria.methods_for(e.target.value)))
            ids = gui.add_text("Hit ids", "", hint="e.g. 1-4, 7; empty = the last N hits")
            last_n = gui.add_number("Last N hits", 4, min=0, step=1)
            gui.add_button("Fit").on_click(lambda _: self.fit(kind.value, method.value, ids.value, int(last_n.value)))
        with gui.add_folder("Hits of the feature", expand_by_default=False):
            hit = gui.add_number("Hit", 1, min=1, step=1)
            gui.add_button("Remove hit and refit").on_click(lambda _: self.remove_hit(int(hit.value)))
            gui.add_button("Re-take hit").on_click(lambda _: self.retake_hit(int(hit.value)))
            gui.add_button("Delete feature").on_click(lambda _: self.delete_feature())
        with gui.add_folder("Nominal and tolerance", expand_by_default=False):
            gui.add_button("Nominal from the last CAD pick").on_click(lambda _: self.nominal_from_pick())
            centre = g["nominal_centre"] = gui.add_vector3("Nominal centre, machine (mm)", (0.0, 0.0, 0.0), step=0.001)
            diameter = g["nominal_diameter"] = gui.add_number("Nominal diameter", 0.0, min=0.0, step=0.001)
            gui.add_button("Apply typed nominal").on_click(lambda _: self.type_nominal(
                centre.value if any(centre.value) else None, diameter.value or None))
            size = gui.add_number("Size ± (mm)", 0.02, min=0.0001, step=0.001)
            form = gui.add_number("Form (mm)", 0.02, min=0.0001, step=0.001)
            pos = gui.add_number("Position ⌀ (mm)", 0.04, min=0.0001, step=0.001)
            gui.add_button("Apply tolerances").on_click(lambda _: self.set_tolerance(
                size=size.value, form=form.value, position=pos.value))
        with gui.add_folder("Construct", expand_by_default=False):
            op = gui.add_dropdown("Operation", OPERATIONS, initial_value="distance")
            g["a"] = gui.add_dropdown("Feature A", ("-",), initial_value="-")
            g["b"] = gui.add_dropdown("Feature B", ("-",), initial_value="-")
            name = g["construct_name"] = gui.add_text("Name", "", hint="optional")
            three_d = gui.add_checkbox("3-D distance", False,
                                       hint="parallel axes: perpendicular to the axes, not in the alignment's XY plane")
            gui.add_button("Construct").on_click(lambda _: self._construct(op.value, g["a"].value, g["b"].value,
                                                                          name.value, three_d.value))
        with gui.add_folder("Datums and GD&T", expand_by_default=False):
            label = gui.add_dropdown("Datum", ("A", "B", "C", "D", "E", "F"), initial_value="A")
            g["datum_feature"] = gui.add_dropdown("Datum feature", ("-",), initial_value="-")
            dmod = gui.add_dropdown("Datum modifier", ("RFS", "MMB", "LMB"), initial_value="RFS")
            targets = gui.add_text("Datum targets", "", hint="hit ids on a datum plane: 3 for A, 2 for B, 1 for C; "
                                                             "area(12-14), line(15 16) for target areas and lines; "
                                                             "empty: the whole feature")
            gui.add_button("Set datum").on_click(lambda _: self._datum(label.value, g["datum_feature"].value,
                                                                       dmod.value, targets.value))
            ch = gui.add_dropdown("Tolerance", CHARACTERISTICS, initial_value="position")
            g["gdt_feature"] = gui.add_dropdown("Toleranced feature", ("-",), initial_value="-")
            tol = gui.add_number("Tolerance (mm)", 0.05, min=0.0001, step=0.001)
            refs = gui.add_text("Datums", "A|B|C", hint="precedence order, e.g. A|B|C; empty for form")
            mat = gui.add_dropdown("Material", ("RFS", "MMC", "LMC"), initial_value="RFS")
            ang = gui.add_number("Basic angle (°)", 0.0, min=0.0, max=90.0, step=0.1)
            rdir = gui.add_dropdown("Runout", ("radial", "axial"), initial_value="radial")
            pattern = gui.add_text("Pattern", "", hint="composite position: the pattern's feature ids, e.g. 5 6 7 8")
            lower = gui.add_number("Lower tier ⌀ (mm)", 0.0, min=0.0, step=0.001,
                                   hint="composite position: the feature-relating tolerance; 0: not composite")
            lower_refs = gui.add_text("Lower tier datums", "A", hint="composite: orientation datums, e.g. A")
            uz = gui.add_number("Profile zone offset (mm)", 0.0, step=0.001,
                                hint="profile: unequally disposed zone (ISO UZ), its middle this far outside the "
                                     "material (- inside); 0: equally disposed")
            gui.add_button("Add tolerance").on_click(lambda _: self._gdt(
                ch.value, g["gdt_feature"].value, tol.value, refs.value, mat.value, ang.value, rdir.value,
                pattern.value, lower.value, lower_refs.value, uz.value))
            gid = gui.add_number("Tolerance id", 1, min=1, step=1)
            gui.add_button("Delete tolerance").on_click(lambda _: self.delete_gdt(int(gid.value)))
        with gui.add_folder("Report header"):
            info = self.ctx.model().info
            fields = {k: gui.add_text(label, str(info.get(k, "") or ""))
                      for k, label in (("part_number", "Part number"), ("drawing", "Drawing"), ("operator", "Operator"),
                                       ("temperature", "Temperature (°C)"))}
            gui.add_button("Save header").on_click(lambda _: self.save_info(**{k: w.value for k, w in fields.items()}))

    def _construct(self, op: str, a: str, b: str, name: str, three_d: bool = False) -> Any:
        ma, mb = re.match(r"(\d+)", a), re.match(r"(\d+)", b)
        if not (ma and mb):
            return self.ctx.error("choose two features", "Construct")
        return self.construct(op, int(ma.group(1)), int(mb.group(1)), name, three_d)

    def _datum(self, label: str, feature: str, modifier: str, targets: str = "") -> Any:
        m = re.match(r"(\d+)", feature)
        if not m:
            return self.ctx.error("choose the datum feature", "Datum")
        return self.define_datum(label, int(m.group(1)), "" if modifier == "RFS" else modifier, targets)

    def _gdt(self, ch: str, feature: str, tol: float, refs: str, material: str, angle: float, direction: str,
             pattern: str = "", lower: float = 0.0, lower_refs: str = "", offset: float = 0.0) -> Any:
        m = re.match(r"(\d+)", feature)
        if not m:
            return self.ctx.error("choose the toleranced feature", "GD&T")
        return self.define_gdt(ch, int(m.group(1)), tol, "" if ch in FORM else refs,
                               "" if material == "RFS" else material, angle if ch == "angularity" else None, direction,
                               pattern, lower if ch == "position" else 0.0, lower_refs,
                               offset if ch.startswith("profile") else 0.0)

    def _chosen(self, value: str) -> None:
        m = re.match(r"(\d+)", value)
        if m:
            self.ctx.select_feature(int(m.group(1)))

    def _fill_nominal_fields(self) -> None:
        """The nominal fields show the selected feature's nominal (a D30 bore reads 30, not 0) when it changes."""
        fid = self.ctx.selected_feature
        f = self.ctx.model().features.get(fid) if fid is not None else None
        key = (fid, None if f is None or f.nominal is None else repr(f.nominal.to_dict()))
        if key == self._nominal_shown:
            return
        self._nominal_shown = key
        shown = nominal_fields(f)
        if shown is not None and "nominal_centre" in self.gui:
            self.gui["nominal_centre"].value, self.gui["nominal_diameter"].value = shown

    def refresh(self) -> None:
        self._check_retake()
        self._fill_nominal_fields()
        options = self.options()
        for key in ("features", "a", "b", "datum_feature", "gdt_feature"):
            self.ctx.set(f"features:{key}", "options", options, self.gui.get(key))
        self._sync_show()
        self._sync_rows()
        self.ctx.set("features:tree", "content", tree_html(self.ctx.query, self.ctx.selected_feature, self.hidden(),
                                                       self.machine),
                     self.gui.get("tree"))
        self.ctx.set("features:hits", "content", self.hits_html(), self.gui.get("hits"))
        self.ctx.set("features:detail", "content", self.detail_markdown(), self.gui.get("detail"))
