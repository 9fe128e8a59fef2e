"""The "Trends" tab: a characteristic over the parts of a series (every run of a routine or program), across
stations.

Choose the series, the characteristic, a station (or all of them) and the chart: individuals (I-MR) for
subgroup 1, X-bar-R for subgroups of 2 to 25. The tab shows the run chart coloured by station with the
tolerance and control limits and the range chart under it (:func:`cmm.session.trends_chart.trend_svg`, the
picture the report includes), the chart statistics, Cp/Cpk and the out-of-tolerance parts, and where the
data come from: the shared database (every station) or, while it is unreachable, this station's journal.
A part recorded here redraws the chart; *Refresh* fetches other stations' new parts. *Export CSV* writes
the characteristic's parts next to the trends journal.

The tab reads the trends through the command API's queries (``trends``, ``trend_series``, ``trend_options``,
``trend_history``:
:mod:`cmm.session.verbs`), open to observers: reading charts changes nothing.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from ..session.trends import TrendError
from ..session.trends_chart import TrendChart, history_csv, summary_markdown, trend, trend_svg
from .context import PanelContext

ALL = "all stations"
NOT_CONFIGURED = ("Trends are not recorded on this station: start it with `cmm serve --trends DIR` "
                  "(and `--trends-db postgresql://...` to share them).")


class TrendsPanel:
    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.gui: dict[str, Any] = {}
        self.series: str | None = None
        self.characteristic: str | None = None
        self.station_filter: str | None = None  # None: every station
        self.subgroup = 1
        self.chart: TrendChart | None = None
        self._version = -1

    def _query(self, name: str, **params: Any) -> Any:
        return self.ctx.commands.invoke(self.ctx.who(), name, **params)

    @property
    def trends(self) -> dict[str, Any] | None:
        """The ``trends`` query: None when none are recorded here; else the parts' version, shared, directory."""
        return self._query("trends")

    # --- actions ---------------------------------------------------------------------------------

    def series_options(self) -> list[str]:
        return [] if self.trends is None else self._query("trend_series")["series"]

    def _options_of_series(self) -> dict[str, Any] | None:
        if self.series is None or self.trends is None:
            return None
        return self._query("trend_options", series=self.series)

    def characteristic_options(self) -> list[str]:
        o = self._options_of_series()
        return [] if o is None else [name for name, _unit in o["characteristics"]]

    def station_options(self) -> list[str]:
        o = self._options_of_series()
        return [ALL] if o is None else [ALL, *o["stations"]]

    def choose_series(self, name: str | None) -> None:
        names = self.series_options()
        self.series = name if name in names else (names[0] if names else None)
        chars = self.characteristic_options()
        if self.characteristic not in chars:
            self.characteristic = chars[0] if chars else None
        if self.station_filter not in self.station_options():
            self.station_filter = None
        self.update()

    def choose_characteristic(self, name: str) -> None:
        self.characteristic = name
        self.update()

    def choose_station(self, name: str) -> None:
        self.station_filter = None if name in (ALL, "", None) else name
        self.update()

    def set_subgroup(self, n: Any) -> None:
        try:
            k = int(n)
        except (TypeError, ValueError):
            self.ctx.error(f"the subgroup size must be a whole number, got {n!r}", "Trends")
            return
        if not 1 <= k <= 25:
            self.ctx.error(f"subgroups of {k} parts: choose 1 (individuals chart) to 25", "Trends")
            return
        self.subgroup = k
        self.update()

    def update(self) -> TrendChart | None:
        """Fetch the chosen characteristic and redraw the chart, the statistics and the options."""
        t = self.trends
        if t is None:
            self._show(NOT_CONFIGURED, "", "")
            return None
        if self.series is None or self.series not in self.series_options():
            names = self.series_options()
            self.series = names[0] if names else None
            chars = self.characteristic_options()
            self.characteristic = chars[0] if chars else None
        if self.series is None or self.characteristic is None:
            self.chart = None
            self._show(self._query("trend_series")["status"], "", "No parts recorded yet: run a program or routine.")
            return None
        h = self._query("trend_history", series=self.series, characteristic=self.characteristic,
                        station=self.station_filter)
        self.chart = trend(h, self.subgroup)
        self._version = t["version"]
        where = "" if h.source == "database" or not t["shared"] else " (from this station's journal)"
        self._show(self._query("trend_series")["status"], trend_svg(self.chart, width=400, height=320, fluid=True),
                   summary_markdown(self.chart) + where)
        return self.chart

    def export_csv(self, path: str | Path | None = None) -> Path | None:
        """The characteristic's parts as CSV (by default ``<trends dir>/<series>-<characteristic>.csv``)."""
        if self.chart is None:
            self.ctx.error("choose a series and a characteristic first", "Export CSV")
            return None
        h = self.chart.history
        if path is None:
            slug = re.sub(r"[^A-Za-z0-9._-]+", "_", f"{h.series}-{h.characteristic}").strip("_")
            path = Path(self.trends["directory"]) / f"{slug}.csv"
        try:
            p = Path(path)
            p.write_text(history_csv(h), encoding="utf-8")
        except OSError as exc:
            self.ctx.error(f"cannot write {path}: {exc.strerror or exc}", "Export CSV")
            return None
        self.ctx.notify("Export CSV", f"{len(h)} parts written to {p}")
        return p

    # --- GUI -------------------------------------------------------------------------------------

    def build(self, gui: Any) -> None:
        g = self.gui
        g["status"] = gui.add_markdown("")
        g["series"] = gui.add_dropdown("Series", ("-",))
        g["series"].on_update(lambda e: self._guard(self.choose_series, e.target.value))
        g["characteristic"] = gui.add_dropdown("Characteristic", ("-",))
        g["characteristic"].on_update(lambda e: self._guard(self.choose_characteristic, e.target.value))
        g["station"] = gui.add_dropdown("Station", (ALL,))
        g["station"].on_update(lambda e: self._guard(self.choose_station, e.target.value))
        g["subgroup"] = gui.add_number("Subgroup (1 = I-MR)", 1, min=1, max=25, step=1)
        g["subgroup"].on_update(lambda e: self._guard(self.set_subgroup, e.target.value))
        gui.add_button("Refresh").on_click(lambda _: self._guard(self.update))
        g["chart"] = gui.add_html("")
        g["summary"] = gui.add_markdown("")
        gui.add_button("Export CSV").on_click(lambda _: self._guard(self.export_csv))
        self._guard(self.update)

    def _guard(self, fn: Any, *args: Any) -> Any:
        """Reading charts changes nothing: no control needed; a refusal is shown, not raised."""
        try:
            return fn(*args)
        except (TrendError, ValueError, OSError) as exc:
            self.ctx.error(exc, "Trends")
            return None

    def _show(self, status: str, svg: str, text: str) -> None:
        self.ctx.set("trends_status", "content", status, self.gui.get("status"))
        self.ctx.set("trends_chart", "content", svg, self.gui.get("chart"))
        self.ctx.set("trends_summary", "content", text, self.gui.get("summary"))
        if not self.gui:
            return
        self._options("series", self.series_options() or ["-"], self.series or "-")
        self._options("characteristic", self.characteristic_options() or ["-"], self.characteristic or "-")
        self._options("station", self.station_options(), self.station_filter or ALL)

    def _options(self, key: str, options: list[str], value: str) -> None:
        w = self.gui.get(key)
        if w is None:
            return
        if tuple(w.options) != tuple(options):
            w.options = tuple(options)
        if w.value != value:
            w.value = value

    def _parts_version(self) -> int:
        t = self.trends
        return -1 if t is None else t["version"]

    def refresh(self) -> None:
        """Called by the tab's refresh (5 Hz): redraw when a part was recorded here."""
        version = self._parts_version()
        if version != -1 and version != self._version:
            self._guard(self.update)
