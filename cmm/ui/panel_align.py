"""The "Align" tab: the prompted hand alignment, 3-2-1 from measured features and best fit of hits to the part.

The prompted alignment (:mod:`cmm.measurement.align_wizard`, which holds all its logic): choose the kind, then the
tab names the element, marks where to touch on the part (orange: the next hit; green: taken), counts the hits as
they come (jog, pendant, or *Touch at the marker*), shows each element's fit and finally the alignment, which
*Apply this alignment* adopts. A hit or an element can be taken again.

From measured features: choose the primary plane, the secondary (plane or line) and the tertiary
(point, circle, sphere or plane) among the measured features, or the hits for
a best fit; *Compute* shows the transform and residuals, *Apply* journals the
alignment (:mod:`cmm.measurement.alignment`) and switches this tab's DRO to part
coordinates.
"""

from __future__ import annotations

import re
import threading
from typing import Any

import numpy as np

from ..metrology.align import AlignmentError
from ..measurement import alignment
from ..measurement.align_wizard import KINDS, AlignWizard, WizardError, routine_elements
from .context import PanelContext


def _fid(value: str) -> int | None:
    m = re.match(r"(\d+)", value or "")
    return int(m.group(1)) if m else None


MARKER_MM = 2.0  # the markers' radius on the part (mm)


class AlignPanel:
    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.gui: dict[str, Any] = {}
        self.result: alignment.AlignmentResult | None = None
        self.datums: dict[str, Any] = {}  # what the result was computed from: Apply sends it as the align verb
        self.wizard: AlignWizard | None = None
        self._markers: list[Any] = []
        self._marked: Any = None
        self._touch: threading.Thread | None = None  # the hit at the marker being taken

    # --- the prompted alignment (the logic is AlignWizard's) ------------------------------------------------

    def _verb(self, verb: str, **params: Any) -> Any:
        return self.ctx.commands.invoke(self.ctx.who(), verb, **params)

    def start_wizard(self, kind: str) -> AlignWizard | None:
        if not self.ctx.allowed("Alignment"):
            return None
        if self.wizard is not None:
            self.wizard.close()
        try:
            self.wizard = self.ctx.query("align_wizard", kind=kind, invoke=self._verb,
                                         on_change=lambda _w: self.show_wizard())
        except (WizardError, AlignmentError) as exc:
            self.wizard = None
            self.ctx.error(exc, "Alignment")
            return None
        self.wizard.listen()
        self.show_wizard()
        return self.wizard

    def routine_wizard(self, routine: Any, datums: list[str]) -> AlignWizard:
        """The wizard for a routine's manual alignment (its datums' faces marked, the hits counted; the routine
        aligns): shown in this tab while the routine waits for the hits."""
        if self.wizard is not None:
            self.wizard.close()
        self.wizard = self.ctx.query("align_wizard", kind=f"routine {routine.name}", invoke=self._verb,
                                     on_change=lambda _w: self.show_wizard(),
                                     elements=routine_elements(routine, datums))
        self.wizard.listen()
        self.show_wizard()
        self.ctx.notify("Manual alignment", f"routine {routine.name}: take the hits the Align tab marks")
        return self.wizard

    def touch_marker(self) -> Any:
        """The next hit at the marker, as a programmed hit (the wizard counts it)."""
        w = self.wizard
        if w is None:
            return self.ctx.error("start an alignment first", "Alignment")
        if not self.ctx.allowed("Touch at the marker"):
            return None
        if self._touch is not None and self._touch.is_alive():
            return None  # a second press while the hit is taken: one touch per press
        # the hit takes seconds of motion: on a thread of its own, not the page's callback (the wizard counts it)
        self._touch = threading.Thread(target=lambda: self.ctx.run("Touch at the marker", w.probe_marker,
                                                                   guarded=False), name="align-touch", daemon=True)
        self._touch.start()
        return True

    def retake_hit(self) -> Any:
        w = self.wizard
        if w is None:
            return self.ctx.error("start an alignment first", "Alignment")
        return self.ctx.run("Take the hit again", w.retake_last_hit, guarded=False)

    def retake_element(self) -> Any:
        w = self.wizard
        if w is None:
            return self.ctx.error("start an alignment first", "Alignment")
        return self.ctx.run("Take the element again", w.retake, guarded=False)

    def apply_wizard(self) -> Any:
        w = self.wizard
        if w is None:
            return self.ctx.error("start an alignment first", "Alignment")
        done = self.ctx.run("Apply this alignment", w.apply, guarded=False)
        if done is not None:
            self.ctx.show_frame("Part")
            self.ctx.notify("Aligned", f"{w.kind}: the DRO and the actuals show part coordinates")
        return done

    def wizard_text(self) -> str:
        return "*Choose the kind and Start: the page marks where to touch.*" if self.wizard is None \
            else self.wizard.text()

    def show_wizard(self) -> None:
        self.ctx.set("align:wizard", "content", self.wizard_text(), self.gui.get("wizard"))
        self._draw_markers()

    def _draw_markers(self) -> None:
        """The element in hand's markers in this tab's scene: the next hit orange and larger, taken ones green."""
        from .scene import SCALE

        w = self.wizard
        marks = [] if w is None or not w.active else w.markers()
        key = tuple((tuple(np.round(p, 3)), done) for p, _n, done in marks)
        if key == self._marked:
            return
        self._marked = key
        scene = getattr(self.ctx.client, "scene", None)
        if scene is None:
            return
        for node in self._markers:
            try:
                node.remove()
            except Exception:  # noqa: BLE001 - a node the page already dropped
                pass
        self._markers = []
        nxt = next((k for k, (_p, _n, done) in enumerate(marks) if not done), None)
        for k, (p, n, done) in enumerate(marks):
            colour = (46, 125, 50) if done else (245, 124, 0)
            r = MARKER_MM * (1.6 if k == nxt else 1.0)
            self._markers.append(scene.add_icosphere(f"/align/marker{k}", radius=r * SCALE, color=colour,
                                                     position=tuple(float(v) * SCALE for v in p)))
            seg = np.array([[p, p + 12.0 * np.asarray(n, float)]], np.float32) * SCALE
            self._markers.append(scene.add_line_segments(f"/align/approach{k}", seg, colors=colour,
                                                                 thickness=3.0, thickness_units="screen"))

    def compute_321(self, primary: int, secondary: int, tertiary: int) -> Any:
        try:
            self.result = self.ctx.query("align_preview", primary=primary, secondary=secondary, tertiary=tertiary)
            self.datums = {"primary": primary, "secondary": secondary, "tertiary": tertiary}
        except (AlignmentError, ValueError, KeyError) as exc:
            self.result = None
            return self.ctx.error(exc, "3-2-1")
        self._show()
        return self.result

    def compute_best_fit(self, ids_text: str) -> Any:
        from .ids import parse_ids

        try:
            ids = parse_ids(ids_text) if ids_text.strip() else sorted(self.ctx.model().hits)
            self.result = self.ctx.query("align_preview", hits=ids)
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
            return "*no alignment computed*"
        part = self.ctx.query("part_frame").part
        return self.result.text(None if part is None else part.pose)

    def _show(self) -> None:
        self.ctx.set("align:result", "content", self.text(), self.gui.get("result"))

    def build(self, gui: Any) -> None:
        g = self.gui
        gui.add_markdown("**Prompted alignment**: touch where the part is marked; each element is fitted and "
                         "shown before the next.")
        kind = gui.add_dropdown("Alignment kind", tuple(KINDS), initial_value="plane-line-point")
        gui.add_button("Start alignment", color="green").on_click(lambda _: self.start_wizard(kind.value))
        g["wizard"] = gui.add_markdown(self.wizard_text())
        gui.add_button("Touch at the marker").on_click(lambda _: self.touch_marker())
        gui.add_button("Take the last hit again").on_click(lambda _: self.retake_hit())
        gui.add_button("Take this element again").on_click(lambda _: self.retake_element())
        gui.add_button("Apply this alignment", color="green").on_click(lambda _: self.apply_wizard())
        gui.add_markdown("**3-2-1 from measured features**: primary plane, secondary plane or line, tertiary "
                         "point, circle, sphere or plane (a hand-hit line or point takes the CAD face it lies on).")
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
        if self.wizard is not None:
            self.show_wizard()
        feats = sorted(self.ctx.model().features.items())
        opts = tuple(f"{fid} {f.name} ({f.kind})" for fid, f in feats) or ("-",)
        for k in ("p", "s", "t"):
            self.ctx.set(f"align:{k}", "options", opts, self.gui.get(k))
