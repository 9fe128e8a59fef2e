"""The path preview: the probe path a plan or a routine will run, drawn in one tab's 3-D view before Run.

The path comes from the control core (its ``probe_paths`` query, :meth:`cmm.control.core.Controller.probe_paths`): the rails' clearance
height and the prober's cycle, the very functions the run executes, from where the tip stands now. It shows the
clearance moves (orange), each approach and search into the surface (magenta, to the hit point), each retract
(cyan) and the hit points; Run or Clear removes it. A preview the rails refuse (a hit outside the travel) says
why in the tab.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .context import OPERATOR_ERRORS, PanelContext
from .scene import draw_cycles


class PathPreview:
    """One tab's preview under ``root`` in the tab's own scene (other tabs do not see it)."""

    def __init__(self, ctx: PanelContext, root: str = "/preview") -> None:
        self.ctx = ctx
        self.root = root
        self.cycles: list[Any] = []
        self.nodes: dict[str, Any] = {}

    def show(self, targets: Any, what: str = "Preview") -> list[Any] | None:
        """Draw the path of ``targets`` ((point, approach, clearance Z), machine mm) as the core will run it."""
        return self.show_cycles(lambda: self.ctx.query("probe_paths", targets=list(targets)), what)

    def show_cycles(self, paths: Any, what: str = "Preview") -> list[Any] | None:
        """Draw the cycles ``paths()`` returns (the control core's, e.g. a routine's); its refusal is told."""
        self.clear()
        try:
            cycles = list(paths())
        except OPERATOR_ERRORS as exc:
            self.ctx.error(exc, what)
            return None
        self.cycles = cycles
        if self.ctx.client is not None and cycles:
            self.nodes = draw_cycles(self.ctx.client.scene, cycles, self.root)
        return cycles

    def clear(self) -> None:
        for node in self.nodes.values():
            try:
                node.remove()
            except Exception:  # noqa: BLE001 - the tab may have closed
                pass
        self.nodes = {}
        self.cycles = []

    def text(self) -> str:
        """The preview in one line: hits, travel, the clearance heights crossed."""
        if not self.cycles:
            return ""
        line = np.concatenate([self.cycles[0].polyline()[:1]] + [c.polyline()[1:] for c in self.cycles])
        travel = float(np.sum(np.linalg.norm(np.diff(line, axis=0), axis=1)))
        top = max(float(q[2]) for c in self.cycles for q in c.rapid)
        return (f"Path preview: {len(self.cycles)} hits, {travel:.0f} mm of travel from where the tip is, highest "
                f"Z {top:.1f} mm (machine). Orange: clearance moves; magenta: approach and search to each hit; "
                "cyan: retract.")
