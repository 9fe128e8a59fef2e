"""The "Align" tab: 3-2-1 from measured features and best fit of hits to the part, with the result shown.

Choose the primary plane, the secondary (plane or line) and the tertiary
(point, circle, sphere or plane) among the measured features, or the hits for
a best fit; *Compute* shows the transform and residuals, *Apply* journals the
alignment (:mod:`cmm.measurement.alignment`) and switches this tab's DRO to part
coordinates.
"""

from __future__ import annotations

import re
from typing import Any

from ..metrology.align import AlignmentError
from ..measurement import alignment
from .context import PanelContext


def _fid(value: str) -> int | None:
    m = re.match(r"(\d+)", value or "")
    return int(m.group(1)) if m else None


class AlignPanel:
    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.station = ctx.station
        self.gui: dict[str, Any] = {}
        self.result: alignment.AlignmentResult | None = None
        self.datums: dict[str, Any] = {}  # what the result was computed from: Apply sends it as the align verb

    def compute_321(self, primary: int, secondary: int, tertiary: int) -> Any:
        try:
            self.result = alignment.align_features(self.station.measurement, primary, secondary, tertiary)
            self.datums = {"primary": primary, "secondary": secondary, "tertiary": tertiary}
        except (AlignmentError, ValueError, KeyError) as exc:
            self.result = None
            return self.ctx.error(exc, "3-2-1")
        self._show()
        return self.result

    def compute_best_fit(self, ids_text: str) -> Any:
        from .ids import parse_ids

        try:
            ids = parse_ids(ids_text) if ids_text.strip() else sorted(self.station.measurement.hits)
            self.result = alignment.best_fit_hits(self.station.measurement, ids)
            self.datums = {"hits": ids}
        except (AlignmentError, ValueError) as exc:
            self.result = None
            return self.ctx.error(exc, "Best fit")
        self._show()
        return self.result

    def apply(self) -> bool:
        result = self.result
        if result is None:
            self.ctx.error("compute an alignment first", "Align")
            return False
        done = self.ctx.do("Align", "align", **self.datums)  # computed again from the same datums, then applied
        if done is not None:
            result = done
            self.ctx.show_frame("Part")
            self.ctx.notify("Aligned", f"{result.method}: the DRO shows part coordinates")
            self.result = None
        return done is not None

    def text(self) -> str:
        if self.result is None:
            part = self.station.measurement.part
            return "*no alignment computed*" if part is None else "*no alignment computed*"
        return self.result.text(None if self.station.measurement.part is None else self.station.measurement.part.pose)

    def _show(self) -> None:
        self.ctx.set("align:result", "content", self.text(), self.gui.get("result"))

    def build(self, gui: Any) -> None:
        g = self.gui
        gui.add_markdown("**3-2-1**: primary plane, secondary plane or line, tertiary point, circle, sphere "
                         "or plane (features with CAD nominals).")
        g["p"] = gui.add_dropdown("Primary (plane)", ("-",), initial_value="-")
        g["s"] = gui.add_dropdown("Secondary", ("-",), initial_value="-")
        g["t"] = gui.add_dropdown("Tertiary", ("-",), initial_value="-")
        gui.add_button("Compute 3-2-1").on_click(lambda _: self._compute_321())
        gui.add_markdown("**Best fit** of hits to the part mesh (at least 6, spread over several faces).")
        ids = gui.add_text("Hits for best fit", "", hint="e.g. 1-9; empty = all hits")
        gui.add_button("Compute best fit").on_click(lambda _: self.compute_best_fit(ids.value))
        g["result"] = gui.add_markdown(self.text())
        gui.add_button("Apply alignment", color="green").on_click(lambda _: self.apply())

    def _compute_321(self) -> Any:
        ids = [_fid(self.gui[k].value) for k in ("p", "s", "t")]
        if None in ids:
            return self.ctx.error("choose the three datum features", "3-2-1")
        return self.compute_321(*ids)  # type: ignore[arg-type]

    def refresh(self) -> None:
        with self.station.measurement.lock:
            feats = sorted(self.station.measurement.features.items())
        opts = tuple(f"{fid} {f.name} ({f.kind})" for fid, f in feats) or ("-",)
        for k in ("p", "s", "t"):
            self.ctx.set(f"align:{k}", "options", opts, self.gui.get(k))
