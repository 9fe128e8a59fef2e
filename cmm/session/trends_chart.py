"""A characteristic's trend over a series of parts: control chart, capability, out-of-tolerance parts, and the
chart as inline SVG (the Trends tab and the report draw the same picture) or CSV.

:func:`trend` computes from a :class:`~cmm.session.trends.History` with :mod:`cmm.metrology.spc`: an
individuals (I-MR) chart for ``subgroup`` 1, an X-bar-R chart of consecutive subgroups otherwise; Cp/Cpk
against the newest part's tolerance limits with the chart's within sigma; the parts outside their own
limits. :func:`trend_svg` draws the run chart of every part (coloured by station, out-of-tolerance parts
in red) with the tolerance and control limits, and the range chart under it.
"""

from __future__ import annotations

import os
from typing import Any

import csv
import html
import io
import math
import time
from dataclasses import dataclass, field
from functools import cached_property
from typing import Callable

import numpy as np

from ..metrology import spc
from .trends import History

STATION_COLOURS = ("#1565c0", "#2e7d32", "#6a1b9a", "#ef6c00", "#00838f", "#5d4037", "#ad1457", "#455a64")
OUT_COLOUR = "#c62828"
MAX_POINTS = 400  # the run chart draws the newest parts up to this many (the statistics use every part)


@dataclass
class TrendChart:
    history: History
    subgroup: int
    chart: spc.Chart | None  # None: too few parts for it (``note`` says why)
    capability: spc.Capability | None
    nominal: float | None  # the newest part's nominal and limits
    lower: float | None
    upper: float | None
    limits_changed: bool  # the tolerance changed within the series (Cp/Cpk use the newest)
    out_of_tolerance: list[int] = field(default_factory=list)  # indices into the history
    note: str = ""

    @cached_property
    def stations(self) -> list[str]:
        return sorted(set(self.history.station))


def _last(a: np.ndarray) -> float | None:
    return None if len(a) == 0 or math.isnan(a[-1]) else float(a[-1])


def trend(history: History, subgroup: int = 1) -> TrendChart:
    """The chart statistics of one characteristic (see the module docstring)."""
    h = history
    nominal, lower, upper = _last(h.nominal), _last(h.lower), _last(h.upper)
    changed = any(len(a) and not np.all((a == a[-1]) | (np.isnan(a) & np.isnan(a[-1]))) for a in (h.lower, h.upper))
    over = np.nan_to_num(h.upper, nan=np.inf)
    under = np.nan_to_num(h.lower, nan=-np.inf)
    bad = [int(i) for i in np.flatnonzero((h.value > over + 1e-12) | (h.value < under - 1e-12))]
    chart = cap = None
    note = ""
    try:
        chart = spc.chart(h.value, subgroup)
        cap = spc.capability(h.value, lower, upper, chart.sigma)
    except spc.SpcError as exc:
        note = str(exc)
    return TrendChart(h, subgroup, chart, cap, nominal, lower, upper, changed, bad, note)


def _f(v: float | None, digits: int = 4) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}f}"


def summary(tc: TrendChart) -> list[tuple[str, str]]:
    """(label, text) rows: what the page, the report and ``cmm trends`` print."""
    h, c, cap = tc.history, tc.chart, tc.capability
    u = "°" if h.unit == "deg" else " mm"
    rows = [("parts", f"{len(h)}" + (f" from {len(tc.stations)} stations ({', '.join(tc.stations)})"
                                      if len(tc.stations) > 1 else f" ({tc.stations[0]})" if tc.stations else "")),
            ("tolerance", ("no limits" if tc.lower is None and tc.upper is None else
                           f"{_f(tc.lower)} .. {_f(tc.upper)}{u}" if tc.lower is not None else f"≤ {_f(tc.upper)}{u}")
             + (f" (nominal {_f(tc.nominal)})" if tc.nominal is not None else "")
             + ("; the tolerance changed within the series: the newest is used" if tc.limits_changed else ""))]
    if c is None:
        rows.append(("chart", tc.note))
    else:
        spread = "MR" if c.subgroup == 1 else "R"
        rows.append(("chart", f"{c.kind}" + (f", subgroups of {c.subgroup}" if c.subgroup > 1 else "")))
        rows.append(("centre line", f"{_f(c.location.centre, 5)}; control limits {_f(c.location.lower, 5)} .. "
                                    f"{_f(c.location.upper, 5)}"))
        rows.append((f"{spread}-bar", f"{_f(c.spread.centre, 5)}; UCL {_f(c.spread.upper, 5)}"
                                      + (f", LCL {_f(c.spread.lower, 5)}" if c.spread.lower else "")))
        rows.append(("sigma (within)", _f(c.sigma, 5)))
        ooc = c.out_of_control
        what = ("part" if c.subgroup == 1 else "subgroup") + ("" if len(ooc) == 1 else "s")
        rows.append(("out of control", f"{len(ooc)} {what}" + (f" (first: {ooc[0] + 1})" if ooc else "")))
    if cap is not None:
        def idx(v: float | None) -> str:
            return "-" if v is None else f"{v:.2f}"

        rows.append(("capability", f"Cp {idx(cap.cp)}, Cpk {idx(cap.cpk)}; Pp {idx(cap.pp)}, Ppk {idx(cap.ppk)}"))
    bad = tc.out_of_tolerance
    rows.append(("out of tolerance", f"{len(bad)} part{'s' if len(bad) != 1 else ''}" + (
        ": " + ", ".join(f"{h.serial[i] or h.run_id[i][:8]} ({h.station[i]}, {_f(float(h.value[i]))})"
                         for i in bad[-5:]) + (" and earlier" if len(bad) > 5 else "") if bad else "")))
    return rows


def summary_markdown(tc: TrendChart) -> str:
    return "\n\n".join(f"**{k}**: {html.escape(v, quote=False)}" for k, v in summary(tc))


def summary_html(tc: TrendChart) -> str:
    return "<dl>" + "".join(f"<dt>{html.escape(k)}</dt><dd>{html.escape(v)}</dd>" for k, v in summary(tc)) + "</dl>"


def history_csv(h: History) -> str:
    """Every part of the characteristic: time, station, run id, serial, value, nominal, limits, result."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["time", "station", "run_id", "serial", "series", "characteristic", "unit", "value", "nominal",
                "lower_limit", "upper_limit", "result"])
    for i in range(len(h)):
        lo, up = h.lower[i], h.upper[i]
        v = float(h.value[i])
        res = "" if math.isnan(lo) and math.isnan(up) else (
            "FAIL" if (not math.isnan(up) and v > up + 1e-12) or (not math.isnan(lo) and v < lo - 1e-12) else "pass")
        w.writerow([time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(float(h.time[i]))), h.station[i], h.run_id[i],
                    h.serial[i], h.series, h.characteristic, h.unit, f"{v:.6f}",
                    *("" if math.isnan(x) else f"{x:.6f}" for x in (h.nominal[i], lo, up)), res])
    return buf.getvalue()


def local_minutes(times: np.ndarray) -> list[str]:
    """"YYYY-MM-DD HH:MM" local time of each epoch second, formatted at once: the local offset is looked up
    once per hour of the series (summer time changes on the hour)."""
    t = np.asarray(times, dtype=np.float64)
    if not len(t):
        return []
    hours = np.floor(t / 3600.0).astype(np.int64)
    uniq, inverse = np.unique(hours, return_inverse=True)
    offsets = np.array([time.localtime(int(u) * 3600).tm_gmtoff or 0 for u in uniq], dtype=np.int64)
    local = (np.floor(t).astype(np.int64) + offsets[inverse]).astype("datetime64[s]").astype("datetime64[m]")
    return [x.replace("T", " ") for x in np.datetime_as_string(local, unit="m").tolist()]


def trend_svg(tc: TrendChart, width: int = 680, height: int = 340, max_points: int = MAX_POINTS,
              fluid: bool = False) -> str:
    """The run chart (values, tolerance and control limits) over the range chart, as one inline SVG;
    ``fluid``: as wide as its container (the page's side panel), ``width`` x ``height`` only setting its shape."""
    h, c = tc.history, tc.chart
    e = html.escape
    label = f"{h.series}: {h.characteristic}"
    size = ('width="100%" style="height:auto;display:block"' if fluid else f'width="{width}" height="{height}"')
    if len(h) == 0:
        return (f'<svg class="trend" viewBox="0 0 {width} 40" '
                + ('width="100%" style="height:auto;display:block"' if fluid else f'width="{width}" height="40"')
                + f' xmlns="http://www.w3.org/2000/svg" role="img" aria-label="{e(label)}"><text x="8" y="24" '
                f'font-size="11">{e(label)}: no parts yet</text></svg>')
    start = max(0, len(h) - max_points)
    idx = np.arange(start, len(h))
    vals = h.value[idx]
    left, right, top = 92, 12, 20
    h_run, gap, h_rng, bottom = int((height - top - 40) * 0.68), 22, int((height - top - 40) * 0.32), 18
    w = width - left - right
    colour = {s: STATION_COLOURS[k % len(STATION_COLOURS)] for k, s in enumerate(tc.stations)}
    # y range: the values, the tolerance and control limits
    ys = [float(vals.min()), float(vals.max())]
    for v in (tc.lower, tc.upper, tc.nominal):
        if v is not None:
            ys.append(v)
    if c is not None:
        ys += [c.location.lower, c.location.upper]
    lo, hi = min(ys), max(ys)
    pad = (hi - lo) * 0.08 or max(abs(hi) * 1e-3, 1e-6)
    lo, hi = lo - pad, hi + pad

    def x(i: float) -> float:
        return left + (i - start + 0.5) * w / max(len(idx), 1)

    def y(v: float) -> float:
        return top + h_run - (v - lo) / (hi - lo) * h_run

    out = [f'<svg class="trend" viewBox="0 0 {width} {height}" {size} '
           f'xmlns="http://www.w3.org/2000/svg" role="img" aria-label="{e(label)}">',
           f'<text x="{left}" y="12" font-size="11" font-weight="600">{e(label)}</text>',
           f'<rect x="{left}" y="{top}" width="{w}" height="{h_run}" fill="none" stroke="#bbb" stroke-width="0.6"/>']

    def hline(v: float, stroke: str, dash: str, name: str, yf: Callable[[float], float] | None = None,
              inside: bool = False) -> None:
        """A limit line labelled left of the plot (tolerances) or ``inside`` at its right end (control limits,
        so a control limit next to a tolerance limit does not print over it)."""
        yy = (yf or y)(v)
        out.append(f'<line x1="{left}" x2="{left + w}" y1="{yy:.1f}" y2="{yy:.1f}" stroke="{stroke}" '
                   f'stroke-width="0.9"{dash}/>')
        if name and inside:
            out.append(f'<text x="{left + w - 3}" y="{yy - 2:.1f}" font-size="8.5" text-anchor="end" fill="{stroke}">'
                       f'{e(name)} {v:.4f}</text>')
        elif name:
            out.append(f'<text x="{left - 3}" y="{yy + 3:.1f}" font-size="8.5" text-anchor="end" fill="{stroke}">'
                       f'{e(name)} {v:.4f}</text>')

    for v, name in ((tc.upper, "USL"), (tc.lower, "LSL")):
        if v is not None:
            hline(v, OUT_COLOUR, "", name)
    if tc.nominal is not None:
        hline(tc.nominal, "#888", ' stroke-dasharray="2 3"', "")
    if c is not None:
        for v, name in ((c.location.upper, "UCL"), (c.location.centre, "CL"), (c.location.lower, "LCL")):
            hline(v, "#1565c0", ' stroke-dasharray="6 3"' if name != "CL" else "",
                  name if c.subgroup == 1 else f"X̄ {name}", inside=True)
        if c.subgroup > 1:  # the subgroup means over the individuals
            n = c.subgroup
            pts = [(x(k * n + (n - 1) / 2), y(m)) for k, m in enumerate(c.points) if (k + 1) * n > start]
            out.append('<polyline fill="none" stroke="#1565c0" stroke-width="1.2" points="'
                       + " ".join(f"{a:.1f},{b:.1f}" for a, b in pts) + '"/>')
    bad = set(tc.out_of_tolerance)
    ooc = set(c.out_of_control) if c is not None and c.subgroup == 1 else set()
    # every point's position at once (a chart holds up to max_points of them)
    xs = (left + (idx - start + 0.5) * w / max(len(idx), 1)).tolist()
    ys = (top + h_run - (vals - lo) / (hi - lo) * h_run).tolist()
    if len(idx) > 1:
        out.append('<polyline fill="none" stroke="#9e9e9e" stroke-width="0.6" points="'
                   + " ".join([f"{a:.1f},{b:.1f}" for a, b in zip(xs, ys)]) + '"/>')
    r = 2.6 if len(idx) <= 100 else 1.8
    stamps = local_minutes(h.time[idx])
    for k, i in enumerate(idx.tolist()):
        v = float(vals[k])
        fill = OUT_COLOUR if i in bad else colour[h.station[i]]
        ring = ' stroke="#000" stroke-width="1"' if i in ooc or i in bad else ""
        stamp = stamps[k]
        out.append(f'<circle cx="{xs[k]:.1f}" cy="{ys[k]:.1f}" r="{r}" fill="{fill}"{ring}><title>'
                   f'{e(h.serial[i] or h.run_id[i][:8])} ({e(h.station[i])}, {stamp}): {v:.5f}'
                   f'{" OUT OF TOLERANCE" if i in bad else ""}</title></circle>')
    # the range chart (moving ranges or subgroup ranges)
    y0 = top + h_run + gap
    if c is not None:
        sp = c.spread_points
        first = 1 if c.subgroup == 1 else 0
        s_hi = max(float(sp.max()) if len(sp) else 0.0, c.spread.upper) * 1.1 or 1e-6

        def yr(v: float) -> float:
            return y0 + h_rng - v / s_hi * h_rng

        out.append(f'<rect x="{left}" y="{y0}" width="{w}" height="{h_rng}" fill="none" stroke="#bbb" '
                   'stroke-width="0.6"/>')
        name = "MR" if c.subgroup == 1 else "R"
        hline(c.spread.upper, "#1565c0", ' stroke-dasharray="6 3"', f"{name} UCL", yf=yr)
        hline(c.spread.centre, "#1565c0", "", f"{name}̄", yf=yr)
        if c.spread.lower > 0:
            hline(c.spread.lower, "#1565c0", ' stroke-dasharray="6 3"', f"{name} LCL", yf=yr)
        if c.subgroup == 1:
            keep = idx >= first
            pts = list(zip(np.asarray(xs)[keep].tolist(),
                           (y0 + h_rng - np.asarray(sp, float)[idx[keep] - 1] / s_hi * h_rng).tolist()))
        else:
            n = c.subgroup
            pts = [(x(k * n + (n - 1) / 2), yr(float(v))) for k, v in enumerate(sp) if (k + 1) * n > start]
        if pts:
            out.append('<polyline fill="none" stroke="#455a64" stroke-width="0.9" points="'
                       + " ".join(f"{a:.1f},{b:.1f}" for a, b in pts) + '"/>')
    # x axis: part numbers, and the station legend
    for k in np.linspace(start, len(h) - 1, num=min(6, len(idx))).round().astype(int):
        out.append(f'<text x="{x(k):.1f}" y="{height - bottom + 2}" font-size="8.5" text-anchor="middle">{k + 1}</text>')
    shown = f"part (newest {len(idx)} of {len(h)})" if start else "part"
    out.append(f'<text x="{left + w / 2:.1f}" y="{height - 4}" font-size="9" text-anchor="middle">{e(shown)}</text>')
    lx = left + w
    for s in reversed(tc.stations):
        text = f"● {s}"
        lx -= 8 + 6.2 * len(text)
        out.append(f'<text x="{lx:.1f}" y="12" font-size="9" fill="{colour[s]}">{e(text)}</text>')
    out.append("</svg>")
    return "".join(out)



def trends_section(charts: list[TrendChart], title: str = "Trends across parts") -> str:
    """The report's section: per characteristic its chart and statistics (plain HTML and SVG)."""
    if not charts:
        return ""
    h0 = charts[0].history
    where = ("every station's parts (shared database)" if h0.source == "database"
             else "this station's parts (local journal)")
    out = [f"<h2>{html.escape(title)}</h2><p class='muted'>Series <b>{html.escape(h0.series)}</b>: {where}. "
           "Run chart coloured by station (red: out of tolerance; ringed: beyond a control limit), tolerance "
           "limits in red, control limits dashed blue; the range chart below.</p>"]
    for tc in charts:
        out.append(f"<div class='trend'>{trend_svg(tc)}{summary_html(tc)}</div>")
    return "".join(out)


def open_trends(directory: str, db: str | None) -> Any:
    from .trends import Trends

    return Trends(directory, database=db or os.environ.get("CMM_TRENDS_DB") or None)


def charts_for(trends: Any, series: str, characteristic: str | None = None, *, subgroup: int = 1,
               station: str | None = None) -> list[Any]:
    """The charts of one characteristic or of every characteristic of a series (what the report includes)."""
    from .trends import TrendError

    names = [c for c, _unit in trends.characteristics(series)]
    if not names:
        known = ", ".join(trends.series()) or "none"
        raise TrendError(f"there is no series {series!r} (recorded series: {known})")
    if characteristic is not None:
        if characteristic not in names:
            raise TrendError(f"the series {series!r} has no characteristic {characteristic!r}; it has: "
                             + ", ".join(names))
        names = [characteristic]
    return [trend(trends.history(series, n, station), subgroup) for n in names]
