"""The "Auto-measure" tab: click a face of the part, the station proposes the feature and its hits.

A pick (click on the part) highlights the picked face in this tab's 3D view
and names it here (*Clear pick* forgets it); *Plan* shows the proposed feature (plane,
circle / bore / boss, cylinder, sphere, cone), the number and pattern of hits,
their approach directions and the clearance plane, and draws the planned path
in this tab's 3D view (up over the clearance plane, across, down, in).
*Run* measures it (needs control) through the command API's ``auto_measure``:
every hit goes over the clearance plane, then the feature is fitted against the
CAD nominal. *Cancel* (the ``cancel`` verb) stops after the current hit; STOP
stops at once.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from ..measurement.plan import plan_targets
from ..metrology.hit_plan import PlanError
from .context import PanelContext
from .path_preview import PathPreview


FACE_NAMES = {(2, 1): "top", (2, -1): "bottom", (1, -1): "front", (1, 1): "back", (0, -1): "left", (0, 1): "right"}


def face_name(normal_part: Any) -> str:
    """The part face a normal (part coordinates) belongs to, as an operator names it ("top", "front" ...): the
    axis it points along within 30 degrees, or "slanted" for any other face."""
    n = np.asarray(normal_part, float)
    axis = int(np.argmax(np.abs(n)))
    if abs(n[axis]) < np.cos(np.radians(30.0)):
        return "slanted"
    return FACE_NAMES[(axis, 1 if n[axis] > 0 else -1)]


def picked_text(part: Any, picked: Any) -> str:
    """What the last click on ``part`` picked, in the operator's words: the feature kind and the face."""
    if picked is None:
        return "*Click a face of the part, then Plan.*"
    hit, nominal = picked
    pose = getattr(part, "pose", None)
    normal = np.asarray(hit.normal, float) if pose is None else np.asarray(pose, float)[:3, :3].T @ hit.normal
    kind = nominal.kind if nominal is not None else "face"
    where = f"{face_name(normal)} face" if kind in ("plane", "face") else f"{kind} face"
    size = f" ⌀ {2 * nominal.params['radius']:.3f}" if nominal is not None and "radius" in nominal.params else ""
    return (f"Picked: **{kind}{size}**, the {where} at X {hit.point[0]:.3f} Y {hit.point[1]:.3f} "
            f"Z {hit.point[2]:.3f} (machine)")


class MeasurePanel:
    def __init__(self, ctx: PanelContext) -> None:
        self.ctx = ctx
        self.gui: dict[str, Any] = {}
        self.plan: Any = None
        self.plan_pick: Any = None  # the pick the plan was made for: a new pick makes it stale
        self.running: threading.Thread | None = None
        self.progress = ""
        self.feature: Any = None
        self.preview = PathPreview(ctx, "/plan")  # the path Run will take, drawn until Run or Clear
        self.hits_per_ring = 0  # what the operator typed for the plan (0: the feature's default)

    def make_plan(self, hits_per_ring: int | None = None) -> Any:
        if self.ctx.picked is None:
            return self.ctx.error("click the face to measure on the part first", "Auto-measure")
        try:
            self.plan = self.ctx.query("plan_at_pick", face=self.ctx.picked[0].face_id, n=hits_per_ring or None)
        except (PlanError, ValueError) as exc:
            self.plan = None
            return self.ctx.error(exc, "Auto-measure")
        self.plan_pick = self.ctx.picked
        self.progress = ""
        self.hits_per_ring = hits_per_ring or 0
        if "hits" in self.gui:  # the field shows the hits per ring the plan uses (not 0 for "the default")
            self.gui["hits"].value = self.plan_hits_per_ring()
        self.draw()
        return self.plan

    def current_plan(self) -> Any:
        """The plan, or None when another face was picked (or the pick cleared) since Plan: Run must never
        measure a face the operator no longer has picked."""
        if self.plan is not None and self.plan_pick is not self.ctx.picked:
            self.plan = self.plan_pick = None
            self.progress = ""
            self.preview.clear()
        return self.plan

    def plan_hits_per_ring(self) -> int:
        """Hits per ring of the plan (two rings on a cylinder or cone; all hits on a plane, circle, sphere)."""
        p = self.plan
        if p is None:
            return 0
        if p.per_ring:  # what the plan uses (raised above the request when the feature needs more)
            return int(p.per_ring)
        return len(p) // 2 if p.kind in ("cylinder", "cone") else len(p)

    def text(self) -> str:
        p = self.current_plan()
        picked = picked_text(self.ctx.query("part_frame").part, self.ctx.picked)
        if p is None:
            return picked + ("" if self.ctx.picked is None else "; then Plan.")
        lines = [picked, "", f"**{p.description}**", *(f"\n**check:** {note}" for note in p.notes), "",
                 f"{len(p)} hits · clearance plane Z {p.clearance_z:.1f} mm · nominal {p.nominal.kind}"
                 + (f" ⌀ {2 * p.nominal.params['radius']:.3f}" if "radius" in p.nominal.params else ""),
                 "", "Hits (machine coordinates, mm):"]
        for k, (q, u) in enumerate(zip(p.points, p.approaches), 1):
            lines.append(f"- hit {k}: X {q[0]:.3f} Y {q[1]:.3f} Z {q[2]:.3f}, approach ({u[0]:+.2f}, {u[1]:+.2f}, {u[2]:+.2f})")
        if self.preview.cycles:
            lines += ["", self.preview.text()]
        if self.progress:
            lines += ["", self.progress]
        return "\n".join(lines)

    def draw(self) -> None:
        """The plan's path preview in this tab's 3-D view, from where the tip is now (Plan and Preview path)."""
        plan = self.current_plan()
        if plan is None:
            self.preview.clear()
            return
        self.preview.show(plan_targets(plan), "Auto-measure preview")

    def clear_drawing(self) -> None:
        self.preview.clear()

    def run(self, name: str = "", wait: bool = False) -> bool:
        plan = self.current_plan()
        if plan is None:
            self.ctx.error("plan a measurement of the picked face first" if self.ctx.picked is not None
                           else "click a face of the part, then Plan", "Auto-measure")
            return False
        if self.running is not None and self.running.is_alive():
            self.ctx.error("a measurement is already running", "Auto-measure")
            return False
        if not self.ctx.allowed("Auto-measure"):
            return False
        self.preview.clear()  # the machine draws the path now
        self.ctx.pick_drawing.clear()  # and its hits: the picked face's highlight would hide them
        name = (name or "").strip()
        cycle = self.ctx.begin_cycle(f"auto-measure of {name or 'the ' + plan.kind}")

        def work() -> None:
            failure = None
            try:
                self.feature = self.ctx.commands.invoke(
                    self.ctx.who(), "auto_measure", plan=plan, name=name or None,
                    progress=lambda k, n: setattr(self, "progress", f"measured {k} of {n} hits"))
            except Exception as exc:  # noqa: BLE001 - every failure is told; the machine layer stopped itself
                failure = exc
                self.progress = f"stopped: {exc}"
                self.ctx.error(exc, "Auto-measure stopped")
                return
            finally:
                self.ctx.end_cycle(cycle, failure)  # a stop: the status bar says STOPPED with the reason
            self.progress = f"done: {self.feature.name}"
            if "name" in self.gui and self.gui["name"].value == name and name:
                self.gui["name"].value = ""  # a name is one feature's: the next gets its own
            self.ctx.selected_feature = self.feature.id
            self.ctx.notify("Auto-measure", f"{self.feature.name} measured ({len(plan)} hits)")

        self.running = threading.Thread(target=work, name="auto-measure", daemon=True)
        self.running.start()
        if wait:
            self.running.join()
        return True

    def cancel(self) -> None:
        """The command API's ``cancel``: the run ends after the hit in progress (whoever started it)."""
        self.ctx.do("Cancel", "cancel")

    def build(self, gui: Any) -> None:
        g = self.gui
        n = g["hits"] = gui.add_number("Hits (per ring)", 0, min=0, max=24, step=1,
                                       hint="0 = the default for the feature; after Plan: the plan's")
        gui.add_button("Plan").on_click(lambda _: self.make_plan(int(n.value)))
        gui.add_button_group("Path", ("Preview path", "Clear path")).on_click(
            lambda e: self.draw() if e.target.value == "Preview path" else self.clear_drawing())
        g["plan"] = gui.add_markdown(self.text())
        gui.add_button("Clear pick").on_click(lambda _: self.ctx.clear_pick())
        name = g["name"] = gui.add_text("Feature name", "", hint="optional, e.g. TOP")
        gui.add_button("Run", color="green").on_click(lambda _: self.run(name.value))
        gui.add_button("Cancel after this hit").on_click(lambda _: self.cancel())

    def refresh(self) -> None:
        self.ctx.set("measure:plan", "content", self.text(), self.gui.get("plan"))
