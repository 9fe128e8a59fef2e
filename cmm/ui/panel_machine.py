"""Machine > Home, Go to and Probe: the machine's commands (Home, Zero, Reset, Reconnect, STOP, E-stop), the Go to
move in a chosen frame, the pick on the part with Move above / Probe here, and the hits list.

Machine commands go to the command API (:mod:`cmm.api`) as this tab's client: the core checks the access
policy and the machine state once, and refuses with a sentence that is shown here. What the tab shows comes from the
API's queries (``state``, ``position``, ``probe_data``, ``model`` ...).
"""

from __future__ import annotations

import threading
import time
from typing import Any, Callable

import numpy as np

from .context import OPERATOR_ERRORS, PanelContext
from .frames import alignment_text, frame_label
from .model_view import reader
from .panel_jog import AXES, JogPanel
from .scene import SCALE

PICK_HINT = "Click the part to pick a point."


def machine_markdown(source: Any) -> str:
    """Machine > Home: the axes' table, the mode and the way back from a fault (``source``: a query function or the
    command API, :func:`cmm.ui.model_view.reader`)."""
    query = reader(source)
    cs = query("state")
    st = cs.machine
    if st is None:
        return f"**{cs.mode.value.upper()}**" + (f": {cs.reason}" if cs.reason else "")
    lines = ["| axis | mm | counts | f.err | status |", "|---|---:|---:|---:|---|"]
    for name, a in zip(AXES, st.axes):
        fe = "-" if a.following_error is None else str(a.following_error)
        lines.append(f"| {name.upper()} | {a.mm:.4f} | {a.counts} | {fe} | {', '.join(a.words)} |")
    flags = [w for w, on in (("PROBE DEFLECTED", st.probe_triggered), ("LINK DOWN", not cs.link_ok)) if on]
    lines.append("")
    mode = cs.mode.value.upper() + (f" ({cs.activity})" if cs.activity else "") + (f": {cs.reason}" if cs.reason else "")
    lines.append(f"**{' · '.join([mode] + flags)}**")
    if cs.mode.value == "fault":
        lines.append("\nWay back: " + ("press **Reset** (the link answers)." if cs.link_ok else
                                        "press **Reconnect**, then **Home** (positions are lost)."))
    elif not cs.homed:
        lines.append("\nPress **Home** before measuring.")
    ippdme = query("ippdme")
    if ippdme is not None:  # cmm serve --ippdme: who drives the machine from outside
        from ..ippdme.status import ippdme_markdown

        lines.append("\n" + ippdme_markdown(ippdme))
    return "\n".join(lines)


def probe_markdown(source: Any) -> str:
    """Machine > Probe: the probe in use and the data the next hit uses (live: a qualification applied shows)."""
    d = reader(source)("probe_data")
    name = d["name"] or "probe"
    q = f"qualified {d['qualified'][:16].replace('T', ' ')}" if d["qualified"] else "**not qualified** (nominal radius)"
    q = q if d["qualified"] is not None else "qualification not known"
    return (f"**{name}**: stylus radius **{d['tip_radius']:.5f} mm** · {q} · pre-travel {d['pretravel']}")


def send_command(ctx: PanelContext, action: str, fn: Callable[..., Any], *args: Any, **kw: Any) -> Any:
    """A machine command as this tab; the control core checks access and state, a refusal is shown to the operator."""
    try:
        return fn(ctx.who(), *args, **kw)
    except OPERATOR_ERRORS as exc:
        ctx.error(exc, f"{action} refused")
        return None


def send_verb(ctx: PanelContext, action: str, method: str, /, **params: Any) -> Any:
    """A verb of the command API sent as this tab (the same checks and answers as every front end); a refusal
    is shown to the operator."""
    return send_command(ctx, action, lambda who: ctx.commands.invoke(who, method, **params))


class MachinePanel:
    """One tab's machine commands, Go to frame and move, and pick."""

    def __init__(self, ctx: PanelContext, app: Any, client: Any, jog: JogPanel) -> None:
        self.ctx = ctx
        self.app = app
        self.client = client
        self.gui = ctx.gui
        self.jog = jog  # STOP and E-stop end this tab's jog
        self.goto_frame = "Machine"  # the Go to fields' frame: follows the DRO's unless chosen here
        self.move_status: Any = None
        self._zero_armed = 0.0

    def _verb(self, action: str, method: str, /, **params: Any) -> Any:
        return send_verb(self.ctx, action, method, **params)

    # --- machine ------------------------------------------------------------------

    def stop(self) -> Any:
        self.jog._jogging = False
        # a STOP not confirmed by every module is told by the machine's "stop" event (one toast per event)
        return self._verb("Stop", "stop")

    def emergency_stop(self) -> Any:
        self.jog._jogging = False
        # the machine's "estop" event tells every tab (confirmed or not): one toast per event
        return self._verb("E-stop", "estop")

    def reset(self) -> None:
        self._verb("Reset", "reset")

    def reconnect(self) -> None:
        self._verb("Reconnect", "reconnect")

    def home(self) -> None:
        """The homing cycle, in a worker thread (it takes seconds); STOP aborts it."""
        def run() -> None:
            self._verb("Home", "home")  # done: the machine's "homed" event toasts in every tab
        threading.Thread(target=run, name="ui-home", daemon=True).start()

    def zero(self, confirm: bool = False) -> None:
        """Zero needs a second press within 5 s (or ``confirm``): it redefines the machine origin."""
        now = time.monotonic()
        if not confirm and now - self._zero_armed > 5.0:
            self._zero_armed = now
            self.ctx.notify("Zero: press again to confirm",
                        "Zero makes the present position the home coordinates (the machine origin). "
                        "Press Zero again within 5 s to confirm.", "error")
            return
        self._zero_armed = 0.0
        self._verb("Zero", "zero", confirm=True)

    # --- go to -------------------------------------------------------------------

    def go_to(self, *target: Any, frame: str | None = None) -> Any:
        """Go to a point in ``frame`` ('machine' or 'part'; default: the Go to tab's frame, which follows the
        DRO's), over the clearance plane. ``target`` is X, Y, Z or one sequence of them."""
        if len(target) == 1 and isinstance(target[0], (list, tuple, np.ndarray)):
            target = tuple(target[0])
        try:
            xyz = [float(v) for v in target]
        except (TypeError, ValueError):
            xyz = []
        if len(xyz) != 3:
            self.ctx.error(f"the target needs three numbers X, Y, Z in mm (got {len(target)})", "Go to refused")
            return None
        status = self._verb("Go to", "move", target=xyz, frame=(frame or self.goto_frame).lower())
        if status is not None:
            self.move_status = status
            status.add_callback(self._move_done)
        return status

    def set_goto_frame(self, frame: str) -> None:
        """The frame of the Go to fields; the fields show the present position in it."""
        if frame not in ("Machine", "Part"):
            return
        self.goto_frame = frame
        if "goto_frame" in self.gui and self.gui["goto_frame"].value != frame:
            self.gui["goto_frame"].value = frame
        here = self.ctx.query("position", frame=frame.lower())
        if "target" in self.gui and here is not None:
            self.gui["target"].value = tuple(round(float(v), 4) for v in here)
        self.ctx.set("goto_frame_text", "content", self.goto_frame_text())
        self.ctx.set("target:label", "label", self.target_label(), self.gui.get("target"))

    def target_label(self) -> str:
        """The Go to field's label names its frame (and the alignment part coordinates go through)."""
        return f"Target, {frame_label(self.ctx.query('part_frame'), self.goto_frame)} (mm)"

    def goto_frame_text(self) -> str:
        if self.goto_frame == "Part":
            return (f"Target in **part** coordinates ({alignment_text(self.ctx.query('part_frame'))}); the move goes over the "
                    "clearance plane.")
        return "Target in **machine** coordinates; the move goes over the clearance plane."

    def _move_done(self, status: Any) -> None:
        err = getattr(status, "error", None)
        if err is not None and "stopped by the operator" not in str(err):
            self.ctx.error(err, "Move ended")

    def cancel(self) -> None:
        status = self.move_status
        if status is not None and not getattr(status, "done", True):
            self._verb("Cancel", "cancel_move", status=status)
        else:
            self.stop()

    # --- pick ------------------------------------------------------------------------

    def pick(self, origin_mm: Any, direction: Any) -> Any:
        """Ray pick on the part (machine mm). Anyone may pick: it moves nothing."""
        try:
            picked = self.ctx.query("pick", origin=origin_mm, direction=direction)
        except OPERATOR_ERRORS as exc:
            self.ctx.error(exc, "Pick")
            return None
        if picked is None:  # no toast: a click into the view to give it the keyboard is no pick either
            if self.ctx.picked is None:
                self.ctx.set("pick", "content", "The click missed the part. " + PICK_HINT)
            return None
        hit, suggestion = picked
        nominal = suggestion.feature if suggestion is not None else None
        result = self.ctx.picked = (hit, nominal)
        if self.client is not None:  # the marker and the picked face, replacing the last pick's
            faces = None if suggestion is None else suggestion.face_ids
            m = self.ctx.query("part_frame")
            self.ctx.pick_drawing.show(self.client.scene, hit, m.part, faces, m.state)
        self.ctx.notify("Picked", "X={:.3f} Y={:.3f} Z={:.3f} (machine)".format(*hit.point)
                    + (f" · {nominal.kind}" if nominal is not None else ""))
        return result

    def clear_pick(self) -> None:
        """Forget the last pick and remove its marker and face highlight from this tab's 3-D view."""
        self.ctx.picked = None
        self.ctx.pick_drawing.clear()
        self.ctx.set("pick", "content", PICK_HINT)

    def forget_stale_pick(self) -> None:
        """A new part (another CAD part or the next part of a series) removes the drawing of a pick made on the one
        before; another CAD part forgets the pick too (its faces are not the new part's)."""
        m = self.ctx.query("part_frame")
        if self.ctx.pick_drawing.drop_stale(m.part, m.state):
            self.clear_pick()

    def on_scene_click(self, origin_scene: Any, direction: Any) -> Any:
        return self.pick(np.asarray(origin_scene, float) / SCALE, direction)

    def move_above(self) -> Any:
        if self.ctx.picked is None:
            self.ctx.error("click a point on the part first", "Move above")
            return None
        hit = self.ctx.picked[0]
        above = self.ctx.query("above_point", point=hit.point, normal=hit.normal)  # approach distance + tip radius out
        status = self._verb("Move above", "move", target=above, frame="machine")  # over the clearance plane
        return None if status is None else self._track(status)

    def probe_here(self) -> Any:
        if self.ctx.picked is None:
            self.ctx.error("click a point on the part first", "Probe here")
            return None
        hit = self.ctx.picked[0]
        # along the picked (outward) normal, the rapid over the part's clearance plane
        clearance_z = None if self.ctx.query("part_frame").part is None else self.ctx.query("clearance_z")
        status = send_command(self.ctx, "Probe here", lambda cid: self.ctx.commands.invoke(
            cid, "probe", target=hit.point, approach=-np.asarray(hit.normal, float), frame="machine",
            clearance_z=clearance_z))
        return None if status is None else self._track(status)

    def _track(self, status: Any) -> Any:
        self.move_status = status
        status.add_callback(self._move_done)
        return status

    # --- hits ---------------------------------------------------------------------------

    def delete_hit(self, hid: int) -> None:
        self.ctx.do("Delete hit", "delete_hit", hit=int(hid))

    def undo(self) -> None:
        message = self.ctx.do("Undo", "undo")
        if message:
            self.ctx.notify("Undo", message)

    # --- GUI ---------------------------------------------------------------------------------------

    def build_home(self, gui: Any) -> None:
        """Machine > Home: the link, the axes' table and the machine's commands."""
        gui.add_markdown(self.app.link_info())
        self.gui["machine"] = gui.add_markdown(machine_markdown(self.ctx.query))
        gui.add_button("Home").on_click(lambda _: self.home())
        gui.add_button("Zero (press twice)").on_click(lambda _: self.zero())
        gui.add_button("Reset").on_click(lambda _: self.reset())
        gui.add_button("Reconnect").on_click(lambda _: self.reconnect())

    def build_goto(self, gui: Any) -> None:
        """Machine > Go to: the target in its frame, and the pick's Move above / Probe here."""
        g = self.gui
        here = self.ctx.query("state").position  # the control core's last sample
        pos = here if here is not None else np.zeros(3)
        g["goto_frame"] = gui.add_button_group("Frame", ("Machine", "Part"))
        g["goto_frame"].on_click(lambda e: self.set_goto_frame(e.target.value))
        g["goto_frame_text"] = gui.add_markdown(self.goto_frame_text())
        g["target"] = gui.add_vector3(self.target_label(), tuple(float(v) for v in pos), step=0.001)
        gui.add_button("Go").on_click(lambda _: self.go_to(g["target"].value))
        gui.add_button("Cancel").on_click(lambda _: self.cancel())
        g["pick"] = gui.add_markdown(PICK_HINT)
        gui.add_button("Move above").on_click(lambda _: self.move_above())
        gui.add_button("Probe here").on_click(lambda _: self.probe_here())

    def build_probe(self, gui: Any) -> None:
        """Machine > Probe: the probe's data, the last contact and the hits (delete, undo)."""
        g = self.gui
        feed = self.ctx.readouts
        g["probe_data"] = gui.add_markdown(probe_markdown(self.ctx.query if feed is None else feed.query))
        if feed is not None:  # a delivery that came while the widget was made
            self.show_probe(feed.snapshot())
        g["contact"] = gui.add_markdown("*no hit yet*")
        g["hits"] = gui.add_markdown("")
        g["hit_id"] = gui.add_number("Hit", 1, min=1, step=1)
        gui.add_button("Delete hit").on_click(lambda _: self.delete_hit(int(g["hit_id"].value)))
        gui.add_button("Undo").on_click(lambda _: self.undo())

    def refresh(self) -> None:
        """The axes' table, the Go to label (the alignment may change), the probe's data, the contact and the hits."""
        query = self.ctx.query
        # the axes' status words are the machine's (AxisState.words), which the state query's JSON does not carry,
        # and the I++ DME line an in-process object: read here at the read-outs' rate, not subscribed to
        self.ctx.set("machine", "content", machine_markdown(query))
        self.ctx.set("target:label", "label", self.target_label(), self.gui.get("target"))  # the alignment may change
        if self.ctx.readouts is None:  # a tab with a page has the probe's data from its subscription (show_probe)
            self.ctx.set("probe_data", "content", probe_markdown(query))
        model = self.ctx.model()
        hit = model.last_hit
        if hit is not None:
            self.ctx.set("contact", "content",
                      "last trigger (tip centre, machine): X={:.4f} Y={:.4f} Z={:.4f}\n\n".format(*hit.machine)
                      + "contact point (machine): X={:.4f} Y={:.4f} Z={:.4f}".format(*hit.point))
        hits = sorted(model.hits.items())
        devs = self.app.deviations()
        rows = [f"{hid}: ({h.point[0]:.3f}, {h.point[1]:.3f}, {h.point[2]:.3f}) "
                f"{devs.get(hid, float('nan')) * 1000:+.1f} um {h.mode}" for hid, h in hits[-12:]]
        self.ctx.set("hits", "content", "hits (last 12, machine coordinates):\n\n" + ("\n\n".join(rows) if rows else "*none*"))

    def show_probe(self, snapshot: dict[str, Any] | None) -> None:
        """Machine > Probe's data from the read-outs' subscription (a qualification applied shows at once)."""
        if snapshot is not None:
            self.ctx.set("probe_data", "content", probe_markdown(lambda name: snapshot[name]))

    def refresh_pick(self) -> None:
        if self.ctx.picked is not None:
            p, nominal = self.ctx.picked
            self.ctx.set("pick", "content", "picked X={:.3f} Y={:.3f} Z={:.3f}, normal ({:.3f}, {:.3f}, {:.3f})".format(
                *p.point, *p.normal) + (f"; nominal {nominal.kind}" if nominal is not None else "") + " (machine coordinates)")
