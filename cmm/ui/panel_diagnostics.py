"""Setup > Diagnostics: the NMC byte trace (live or a snapshot), the link's health, and the following-error plot."""

from __future__ import annotations

from typing import Any

import numpy as np

from .context import PanelContext


class DiagnosticsPanel:
    """One tab's Diagnostics: the trace is sent only while asked for (an idle page stays quiet)."""

    def __init__(self, ctx: PanelContext, app: Any) -> None:
        self.ctx = ctx
        self.app = app
        self.gui = ctx.gui
        self.live_trace = False
        self._plot_key: bytes | None = None

    def show_trace(self) -> None:
        self.ctx.set("trace", "value", self.ctx.commands.invoke(self.ctx.who(), "trace", last=30))  # the link process's on a real port
        self.ctx.set("link_health", "content", self.link_health())

    def link_health(self) -> str:
        return self.ctx.commands.invoke(self.ctx.who(), "link_health")["text"]

    def build(self, gui: Any) -> None:
        g = self.gui
        # the trace changes with every poll: sent only while asked for (an idle page stays quiet)
        live = gui.add_checkbox("Live byte trace", False)
        live.on_update(lambda e: setattr(self, "live_trace", bool(e.target.value)))
        g["trace"] = gui.add_text("NMC bytes (Tx/Rx)", "", multiline=True, disabled=True)
        gui.add_button("Snapshot of the bytes").on_click(lambda _: self.show_trace())
        # late replies a retry recovered: counted here, not shouted in the status bar (docs/reliability.md)
        g["link_health"] = gui.add_markdown(self.link_health())
        t, fe = self.app.following_error_series()
        g["plot"] = gui.add_uplot(
            (t, *fe), ({"label": "t (s)"}, {"label": "X", "stroke": "red"}, {"label": "Y", "stroke": "green"},
                       {"label": "Z", "stroke": "blue"}),
            title="following error (counts)", aspect=1.6)

    def refresh(self) -> None:
        if self.live_trace:
            self.show_trace()
        t, fe = self.app.following_error_series()
        # the plot is re-sent only when a following error changed: 500 samples x 4 float64 (16 kB) five times a
        # second was most of an idle page's 50-80 kB/s
        values = np.nan_to_num(np.stack(fe))
        key = values.tobytes() if np.ptp(values) > 0 else values.flat[0].tobytes()  # flat: however long
        if "plot" in self.gui and len(t) > 1 and key != self._plot_key:
            self._plot_key = key
            self.gui["plot"].data = (t, *fe)
