"""The "Colour map" tab: the deviation colour map on the part, its tolerance bands, cut-offs and legend.

*Show the colour map* paints the part in the 3D view by the deviation of the
hits around each place (:mod:`cmm.metrology.colour_map`), in the bands of the
one colour scale the report uses too (:mod:`cmm.metrology.colour_scale`):
green in tolerance, amber / cyan warning, red / blue out of tolerance (excess
/ missing material); surface farther than the *reach* from every hit, and
hits beyond the *max deviation*, stay grey. The scene is shared: turning the
map on or changing the bands shows in every browser, and the report written
from the Sessions tab uses the same scale.
"""

from __future__ import annotations

import html
from typing import Any

from ..metrology.colour_scale import ColourScale
from .context import PanelContext


def legend_html(scale: ColourScale) -> str:
    """The legend: a swatch and the band limits per band (the report draws the same list)."""
    items = "".join(f"<div class='cmm-band' style='margin:1px 0'><i style='display:inline-block;width:12px;"
                    f"height:12px;background:rgb{c};border:1px solid #555;vertical-align:-2px;margin-right:5px'></i>"
                    f"{html.escape(label)}</div>" for c, label in scale.legend())
    return f"<div class='cmm-legend' style='font:11.5px system-ui'>{items}</div>"


class ColourMapPanel:
    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.gui: dict[str, Any] = {}

    @property
    def view(self) -> Any:
        return self.ctx.view

    # --- actions ---------------------------------------------------------------------------------

    def show(self, on: bool) -> Any:
        """Turn the map on or off; returns the map drawn (None when off or without a part)."""
        if on and self.ctx.query("part_frame").part is None:
            self.ctx.error("load a part first: the map is painted on its mesh", "Colour map")
        dmap = self.view.show_colour_map(on, self.ctx.deviations() or None)
        if on and self.view.map_error:
            self.ctx.error(self.view.map_error, "Colour map")
        return dmap

    def apply(self, tolerance: float, warning_percent: float, cutoff: float, reach: float) -> ColourScale | None:
        """New band limits: tolerance (mm), warning limit (% of the tolerance), max deviation and reach (mm)."""
        try:
            scale = ColourScale(float(tolerance), float(cutoff), float(warning_percent) / 100.0, float(reach))
        except (TypeError, ValueError) as exc:
            self.ctx.error(exc, "Colour map")
            return None
        self.view.set_scale(scale)
        devs = self.ctx.deviations()
        self.view.draw_hits(devs)
        if self.view.map_on:
            self.view.draw_colour_map(devs or None)
        return scale

    # --- read-outs -------------------------------------------------------------------------------------

    def summary(self) -> str:
        v = self.view
        if not v.map_on:
            return "*The map is off: the hits alone are coloured.*"
        model = self.ctx.model()
        if model.part is None:
            return "*No part loaded.*"
        if v.map_error:
            return v.map_error
        m = v.map
        if m is None:
            return "*drawing ...*"
        text = (f"{m.hits_used} hit{'s' if m.hits_used != 1 else ''} paint "
                f"{m.coverage * 100:.0f} % of the surface ({len(m.mesh.faces)} faces); the rest is grey.")
        left_out = len(model.hits) - m.hits_used
        if left_out > 0:
            text += (f" {left_out} hit{'s' if left_out != 1 else ''} deviating more than "
                     f"±{m.scale.max_distance:g} mm (another surface, or the part not aligned?) take no part.")
        return text

    # --- GUI -------------------------------------------------------------------------------------------

    def build(self, gui: Any) -> None:
        g = self.gui
        s = self.view.scale
        g["on"] = gui.add_checkbox("Show the colour map", self.view.map_on,
                                   hint="paint the part by the deviation of the hits around each place")
        g["on"].on_update(lambda e: self.show(bool(e.target.value)))
        g["legend"] = gui.add_html(legend_html(s))
        g["summary"] = gui.add_markdown(self.summary())
        tol = gui.add_number("Tolerance ± (mm)", s.tolerance, min=0.0001, step=0.001,
                             hint="red / blue beyond it: out of tolerance")
        warn = gui.add_number("Warning at (% of tol.)", round(s.warning * 100), min=1, max=100, step=5,
                              hint="amber / cyan between it and the tolerance")
        cut = gui.add_number("Max deviation (mm)", s.max_distance, min=0.001, step=0.01,
                             hint="hits deviating more belong to another surface: grey, not used")
        reach = gui.add_number("Reach (mm)", s.reach, min=0.1, step=1.0,
                               hint="surface farther than this from every hit stays grey")
        gui.add_button("Apply bands").on_click(lambda _: self.apply(tol.value, warn.value, cut.value, reach.value))
        gui.add_markdown("The report (Sessions tab) draws its colour map views with these bands.")

    def refresh(self) -> None:
        self.ctx.set("colour_map:on", "value", self.view.map_on, self.gui.get("on"))
        self.ctx.set("colour_map:legend", "content", legend_html(self.view.scale), self.gui.get("legend"))
        self.ctx.set("colour_map:summary", "content", self.summary(), self.gui.get("summary"))
