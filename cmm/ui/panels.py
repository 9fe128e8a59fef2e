"""One client's GUI: panels built declaratively, short callbacks, state kept outside the widgets.

:class:`ClientApp` holds one browser tab's state (picked point, speed mode,
the last move status) and exposes every action as a plain method
(``go_to``, ``jog_hold``, ``pick``, ``probe_here``, ``fit`` ...), so the tests
drive exactly what a button does without a browser. ``build()`` creates the
widgets and wires each one to a method; ``refresh()`` copies station state
into the read-outs a few times a second.

Machine commands go to the control core (``station.controller``, see
:mod:`cmm.control`) as this client (:meth:`ClientApp.who`): the core checks
the access policy (the shared :class:`~cmm.control.access.Control`, STOP and E-stop
by its one :meth:`~cmm.control.access.Control.may_stop` policy) and the machine
state once, and refuses with a sentence that is shown here. Measurement
changes (hits, features, sessions) ask :meth:`ClientApp.allowed` first (a
server-side check: hiding buttons is not security). Jog buttons feed the core's
jog-hold pipeline (:mod:`cmm.control.jog`): each hold event refreshes the jog,
the release ends it, and the machine's dead-man stops it when the events stop.
"""

from __future__ import annotations

import asyncio
import json
import math
import re
import time
from typing import Any, Callable

import numpy as np

from ..control import Refused
from .context import OPERATOR_ERRORS, PanelContext
from .panel_align import AlignPanel
from .panel_calibration import CalibrationPanel
from .panel_colour_map import ColourMapPanel
from .panel_features import FeaturesPanel
from .panel_part import PartPanel
from .panel_measure import MeasurePanel
from .panel_routine import RoutinePanel
from .panel_sessions import SessionsPanel
from . import panel_users
from .panel_status import StatusPanel, run_script
from .panel_trends import TrendsPanel
from .frames import alignment_text, frame_label
from .scene import SCALE


def hold_worker_script(pendant_src: str, token: str) -> str:
    """web/hold_worker.js for this page (its pendant WebSocket and its refresher's grant), then web/view_keys.js
    (the keyboard jog of the 3-D view, through the same worker)."""
    from .pendant import web_dir

    ws = pendant_src.split("#", 1)[0].replace("http://", "ws://", 1).replace("https://", "wss://", 1).rstrip("/") + "/ws"
    worker = (web_dir() / "hold_worker.js").read_text().replace("__WS_URL__", ws).replace("__TOKEN__", token)
    return worker + "\n" + (web_dir() / "view_keys.js").read_text()

AXES = ("x", "y", "z")
SPEEDS = {"positioning": "jog_fast", "probing": "jog_slow", "fine": "jog_fine"}
STEP_SIZES = ("1 count", "0.01", "0.1", "1", "10")
PICK_HINT = "Click the part to pick a point."
CONTROL_FOLDS = ("who", "take")  # the name folder and Take control, hidden while this tab holds control
JOG_KEYS_HELP = ("**Keyboard**: click the 3-D view (a blue frame shows it has the keys): arrows = X/Y, "
                 "PageUp/PageDown = Z at the Speed above, hold **Shift** = fast; releasing the key stops; **Esc** or "
                 "**Space** = stop; why a key does nothing is shown on the view. In the pendant below (click it "
                 "first) the keys jog at the pendant's speed. Step jogs: the Step size above and the Step X/Y/Z buttons. "
                 "The pendant below acts for this page: it shares this page's control. A tablet opens the "
                 "pendant page alone (its own client: Take control there).")
LATE_HOLD_S = 0.2  # hold events this soon after a release are late ones (viser may run callbacks out of order)
# hold events a second while a button is held: 3-4 within the machine's 0.15 s dead-man, so a browser that is
# late by up to ~0.1 s keeps the jog, and one that goes silent (a lost pointer-up, a frozen or closed tab)
# stops 0.15 s after its last event plus the braking
HOLD_HZ = 25.0
# The tab strips a little tighter than viser's (0.9em a side) so the six top tabs fit one row of the wide panel;
# dock tabs (laptop) and Mantine tabs (viser's narrow-screen layout) alike.
TABS_CSS = """<style>
[role=tablist] > [data-dock-tab] { padding: 0 0.6em !important; }
.mantine-Tabs-tab { padding-left: 0.6em !important; padding-right: 0.6em !important; }
</style>"""
OPERATOR_KEY = "cmm-operator"  # where the browser keeps the operator's name (localStorage)
# The start dialog's name field filled from the browser's saved name, then its Start pressed, as the operator
# would: the value goes through the field's own input event (React's onChange), so the station hears it.
OPERATOR_JS = """
(() => {
  const name = localStorage.getItem("cmm-operator");
  if (!name) return;
  let tries = 0;
  const fill = () => {
    const modal = document.querySelector(".mantine-Modal-content") || document;
    const label = [...modal.querySelectorAll("*")].find(e => e.childElementCount === 0
                                                        && e.textContent.trim() === "Your name");
    if (!label) return false;
    let box = label.parentElement;
    while (box && !box.querySelector("input")) box = box.parentElement;
    const input = box && box.querySelector("input");
    const start = [...modal.querySelectorAll("button")].find(b => b.textContent.trim() === "Start");
    if (!input || !start) return false;
    Object.getOwnPropertyDescriptor(HTMLInputElement.prototype, "value").set.call(input, name);
    input.dispatchEvent(new Event("input", { bubbles: true }));
    setTimeout(() => start.click(), 150);
    return true;
  };
  // tried for up to a minute: on a loaded machine the dialog may take that long to appear
  const again = () => { if (!fill() && ++tries < 300) setTimeout(again, 200); };
  again();
})();
"""


def machine_markdown(station: Any) -> str:
    cs = station.controller.state
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
    if getattr(station, "ippdme", None) is not None:  # cmm serve --ippdme: who drives the machine from outside
        from ..ippdme.status import ippdme_markdown

        lines.append("\n" + ippdme_markdown(station.ippdme))
    return "\n".join(lines)


def probe_markdown(station: Any) -> str:
    """Machine > Probe: the probe in use and the data the next hit uses (live: a qualification applied shows)."""
    d = station.measurement.probe_data()
    name = station.measurement.probe_name or "probe"
    q = f"qualified {d['qualified'][:16].replace('T', ' ')}" if d["qualified"] else "**not qualified** (nominal radius)"
    q = q if d["qualified"] is not None else "qualification not known"
    return (f"**{name}**: stylus radius **{d['tip_radius']:.5f} mm** · {q} · pre-travel {d['pretravel']}")


class ClientApp:
    """One browser client (or a test standing in for one)."""

    def __init__(self, app: Any, client: Any = None, *, client_id: str | None = None,
                 is_local: bool = False) -> None:
        self.app = app
        self.station = app.station
        self.control = app.control
        self.client = client
        self.client_id = client_id or (f"viser-{client.client_id}" if client is not None else "test")
        self.is_local = is_local
        # what this tab's panels share (selection, messages, widgets, the control check); they get it, not the tab
        self.ctx = PanelContext(app.station, app.control, app.view, client, client_id=self.client_id,
                                is_local=is_local, deviations=app.deviations, shared=app.shared)
        self.ctx.stop, self.ctx.emergency_stop = self.stop, self.emergency_stop
        self.ctx.select_feature = self.select_feature
        self.ctx.clear_pick = self.clear_pick
        self.messages = self.ctx.messages  # (level, title, body): what the operator was told
        self.gui = self.ctx.gui
        self.speed_mode = "probing"
        self.goto_frame = "Machine"  # the Go to fields' frame: follows the DRO's unless chosen here
        self.step_size = "1"
        self.move_status: Any = None
        self.pendant_token: str | None = None  # the embedded pendant's grant (acts as this client)
        self.hold_token: str | None = None  # the jog buttons' hold refresher's grant (web/hold_worker.js)
        self._jogging = False
        self._last_error = ("", 0.0)
        self._zero_armed = 0.0
        self.live_trace = False
        self._had_control = False
        self._plot_key: bytes | None = None
        self.sessions = SessionsPanel(self.ctx)
        self.calibration = CalibrationPanel(self.ctx)
        self.status = StatusPanel(self.ctx)
        self.features = FeaturesPanel(self.ctx)
        self.align = AlignPanel(self.ctx)
        self.measure = MeasurePanel(self.ctx)
        self.part = PartPanel(self.ctx)
        self.routine = RoutinePanel(self.ctx)
        self.routine.align = self.align  # a routine's manual alignment is prompted by the Align tab's wizard
        self.colour_map = ColourMapPanel(self.ctx)
        self.trends = TrendsPanel(self.ctx)
        self.ctx.show_frame = self.status.set_frame
        self.ctx.frame_shown = self.set_goto_frame

    @property
    def api(self) -> Any:
        """The control core: every machine command goes there with this client's id."""
        return self.station.controller

    def _verb(self, action: str, method: str, /, **params: Any) -> Any:
        """A verb of the command API sent as this tab (the same checks and answers as every front end); a refusal
        is shown to the operator."""
        return self._cmd(action, lambda who: self.ctx.commands.invoke(who, method, **params))

    def _cmd(self, action: str, fn: Callable[..., Any], *args: Any, **kw: Any) -> Any:
        """A machine command; the control core checks access and state, a refusal is shown to the operator."""
        try:
            return fn(self.ctx.who(), *args, **kw)
        except OPERATOR_ERRORS as exc:
            self.ctx.error(exc, f"{action} refused")
            return None

    # --- machine ------------------------------------------------------------------

    def stop(self) -> Any:
        self._jogging = False
        # a STOP not confirmed by every module is told by the station's "stop" event (one toast per event)
        return self._verb("Stop", "stop")

    def emergency_stop(self) -> Any:
        self._jogging = False
        # the station's "estop" event tells every tab (confirmed or not): one toast per event
        return self._verb("E-stop", "estop")

    def reset(self) -> None:
        self._verb("Reset", "reset")

    def reconnect(self) -> None:
        self._verb("Reconnect", "reconnect")

    def home(self) -> None:
        """The homing cycle, in a worker thread (it takes seconds); STOP aborts it."""
        import threading

        def run() -> None:
            self._verb("Home", "home")  # done: the station's "homed" event toasts in every tab
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
        here = self.api.frame_position(frame.lower())
        if "target" in self.gui and here is not None:
            self.gui["target"].value = tuple(round(float(v), 4) for v in here)
        self.ctx.set("goto_frame_text", "content", self.goto_frame_text())
        self.ctx.set("target:label", "label", self.target_label(), self.gui.get("target"))

    def target_label(self) -> str:
        """The Go to field's label names its frame (and the alignment part coordinates go through)."""
        return f"Target, {frame_label(self.station, self.goto_frame)} (mm)"

    def goto_frame_text(self) -> str:
        if self.goto_frame == "Part":
            return (f"Target in **part** coordinates ({alignment_text(self.station)}); the move goes over the "
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

    # --- jog -------------------------------------------------------------------------

    def jog_velocity(self, axis: int, sign: int) -> np.ndarray:
        v = np.zeros(3)
        v[axis] = math.copysign(getattr(self.station.config.speeds, SPEEDS[self.speed_mode]), sign)
        return v

    def _hold_handler(self, axis: int, sign: int) -> Callable[[Any], Any]:
        """The jog button's hold callback: a coroutine, so viser runs it in its event loop as the event arrives;
        it notes that moment (the dead-man runs from it) and hands the hold to a thread (a late thread pool
        then cannot keep the jog going)."""
        async def held(_event: Any) -> None:
            heard = self.api.clock.now()
            asyncio.get_running_loop().run_in_executor(None, self.jog_hold, axis, sign, heard)
        return held

    def jog_hold(self, axis: int, sign: int, heard: float | None = None) -> None:
        """A hold event of a jog button (viser sends them at ``HOLD_HZ`` while it is held; received at
        ``heard``, default now): fed to the core's jog-hold pipeline, which clamps (an armed jog to the qualified
        probing speed), drops events that ran after the release, and stops the jog when they stop coming (the
        machine's dead-man, counted from when each was heard)."""
        try:
            self.ctx.commands.invoke(self.ctx.who(), "jog_hold", velocity=self.jog_velocity(axis, sign),
                                     probe=self.ctx.manual_probe, settle=LATE_HOLD_S, heard=heard,
                                     on_error=lambda text: self._throttled_error("Jog", text))
        except OPERATOR_ERRORS as exc:
            self._throttled_error("Jog", str(exc))
            return
        self._jogging = True

    def hold_velocity(self, label: Any) -> tuple[np.ndarray, bool]:
        """What a held jog button means now ("hold X +" ...) or held keys of the 3-D view ("keys +x -y", "fast"
        with Shift): the velocity at this tab's speed, and whether the jog is armed (the page's hold refresher
        sends the label, see web/hold_worker.js and web/view_keys.js)."""
        if isinstance(label, str) and label.startswith("keys "):
            return self.keys_velocity(label), bool(self.ctx.manual_probe)
        for i, name in enumerate(AXES):
            for sign, text in ((-1, f"hold {name.upper()} −"), (1, f"hold {name.upper()} +")):
                if label == text:
                    return self.jog_velocity(i, sign), bool(self.ctx.manual_probe)
        raise ValueError(f"no jog button is called {label!r}")

    def keys_velocity(self, label: str) -> np.ndarray:
        """The jog of held keys: "keys +x -y" at this tab's speed, "... fast" at the fast jog speed."""
        words = label.split()[1:]
        fast = "fast" in words
        speed = getattr(self.station.config.speeds, "jog_fast" if fast else SPEEDS[self.speed_mode])
        v = np.zeros(3)
        for w in words:
            if w == "fast":
                continue
            if len(w) != 2 or w[0] not in "+-" or w[1] not in AXES:
                raise ValueError(f"no key jog is called {label!r}")
            v[AXES.index(w[1])] = math.copysign(speed, 1 if w[0] == "+" else -1)
        if not np.any(v):
            raise ValueError(f"no key jog is called {label!r}")
        return v

    def jog_release(self) -> None:
        """The button was released (viser's click event fires on release)."""
        # also marks the release for late holds; with no jog of this tab known to run it is a let-go, which the
        # core sends on only for the control holder (an observer's release never ends the holder's jog)
        jogging, self._jogging = self._jogging, False
        try:
            self.ctx.commands.invoke(self.ctx.who(), "jog_release", let_go=not jogging)
        except OPERATOR_ERRORS as exc:
            self.ctx.error(exc, "Jog release")

    def _throttled_error(self, title: str, body: str) -> None:
        last, when = self._last_error
        if body != last or time.monotonic() - when > 2.0:
            self._last_error = (body, time.monotonic())
            self.ctx.error(body, title)

    def step(self, axis: int, sign: int) -> Any:
        size = self.step_size
        mm = 1.0 / self.station.config.axes[axis].counts_per_mm if size == "1 count" else float(size)
        return self._verb("Step", "step", axis=AXES[axis], mm=math.copysign(mm, sign))

    def set_manual_probe(self, on: bool) -> None:
        self.jog_release()
        self.ctx.manual_probe = bool(on)

    # --- pick ------------------------------------------------------------------------

    def pick(self, origin_mm: Any, direction: Any) -> Any:
        """Ray pick on the part (machine mm). Anyone may pick: it moves nothing."""
        m = self.station.measurement
        try:
            picked = m.pick_region(origin_mm, direction)
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
            self.ctx.pick_drawing.show(self.client.scene, hit, m.part, faces, m.state)
        self.ctx.notify("Picked", "X={:.3f} Y={:.3f} Z={:.3f} (machine)".format(*hit.point)
                    + (f" · {nominal.kind}" if nominal is not None else ""))
        return result

    def clear_pick(self) -> None:
        """Forget the last pick and remove its marker and face highlight from this tab's 3-D view."""
        self.ctx.picked = None
        self.ctx.pick_drawing.clear()
        self.ctx.set("pick", "content", PICK_HINT)

    def _forget_stale_pick(self) -> None:
        """A new part (another CAD part or the next part of a series) removes the drawing of a pick made on the one
        before; another CAD part forgets the pick too (its faces are not the new part's)."""
        m = self.station.measurement
        if self.ctx.pick_drawing.drop_stale(m.part, m.state):
            self.clear_pick()

    def on_scene_click(self, origin_scene: Any, direction: Any) -> Any:
        return self.pick(np.asarray(origin_scene, float) / SCALE, direction)

    def move_above(self) -> Any:
        if self.ctx.picked is None:
            self.ctx.error("click a point on the part first", "Move above")
            return None
        hit = self.ctx.picked[0]
        above = self.station.measurement.above_point(hit.point, hit.normal)  # approach distance + tip radius out
        status = self._verb("Move above", "move", target=above, frame="machine")  # over the clearance plane
        return None if status is None else self._track(status)

    def probe_here(self) -> Any:
        if self.ctx.picked is None:
            self.ctx.error("click a point on the part first", "Probe here")
            return None
        hit = self.ctx.picked[0]
        m = self.station.measurement  # along the picked (outward) normal, the rapid over the part's clearance plane
        status = self._cmd("Probe here", lambda cid: self.ctx.commands.invoke(
            cid, "probe", target=hit.point, approach=-np.asarray(hit.normal, float), frame="machine",
            clearance_z=None if m.part is None else m.clearance_z()))
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

    # --- features --------------------------------------------------------------------------

    def select_feature(self, fid: int) -> None:
        """Select a feature in every panel of this tab and in the 3-D view."""
        self.ctx.selected_feature = fid
        self.app.view.select_feature(fid)
        self.refresh()

    # --- control ------------------------------------------------------------------------------

    def peer(self) -> str | None:
        """This tab's network address: the key of the access-code rate limit (new tabs share it)."""
        if self.client is None:
            return None
        address = self.app.client_address(self.client.client_id)
        return address[0] if isinstance(address, (tuple, list)) and address else None

    def take_control(self, code: str | None = None) -> bool:
        try:
            self.ctx.commands.invoke(self.ctx.who(), "take_control", code=code or None, peer=self.peer())
            refusal = None
        except PermissionError as exc:  # the core's refusal, in the operator's words
            refusal = str(exc)
        if refusal is None:
            self.ctx.authenticated = True
            self.ctx.notify("Control", "you control the machine")
            self._operator_to_report()
        else:
            self.ctx.error(refusal, "Take control")
        return refusal is None

    @property
    def operator(self) -> str | None:
        """This tab's operator as they gave their name (None: not given)."""
        name = self.control.name(self.client_id)
        return None if name == self.client_id else name

    def set_operator(self, name: str) -> bool:
        """The operator of this tab (the start dialog, or the name the browser saved): the status bar and the control
        messages name them, the browser keeps it (localStorage) and, while they control the machine, the report
        header shows them as the operator."""
        try:
            name = self.control.set_name(self.client_id, name)
        except ValueError as exc:
            self.ctx.error(exc, "Your name")
            return False
        if self.client is not None:
            run_script(self.client.gui, f"localStorage.setItem({OPERATOR_KEY!r}, {json.dumps(name)});")
        self._operator_to_report()
        self.ctx.set("operator", "value", name)
        return True

    def log_in(self, name: str, password: str) -> bool:
        """A station with a user file: this tab acts as the user from now on (:mod:`.panel_users`)."""
        return panel_users.log_in(self, name, password)

    def users_action(self, verb: str, **params: Any) -> Any:
        """The admin's Users folder: a user verb as this tab's client (the API refuses all but an admin)."""
        return panel_users.users_action(self, verb, **params)

    def _start_dialog(self, gui: Any) -> None:
        """Ask who operates (the browser's saved name fills it in by itself); Skip leaves the tab unnamed."""
        if getattr(self.app, "users", None) is not None:
            panel_users.login_dialog(self, gui)
            return
        if self.operator is not None:
            return
        modal = gui.add_modal("Who is operating?")
        with modal:
            gui.add_markdown("Your name goes in the status bar, the control messages and the report header.")
            name = gui.add_text("Your name", "")

            def start(_: Any) -> None:
                if self.set_operator(name.value):
                    modal.close()
            gui.add_button("Start", color="green").on_click(start)
            gui.add_button("Skip").on_click(lambda _: modal.close())
        run_script(gui, OPERATOR_JS)

    def _operator_to_report(self) -> None:
        """The named holder is the session's operator (journalled, so the report header shows them)."""
        name = self.operator
        if name is None or self.station.measurement.info.get("operator") == name:
            return
        try:
            self.ctx.commands.invoke(self.ctx.who(), "set_info", operator=name)
        except Refused:  # an observer's name is not the session's operator: the core refused, nothing to tell
            pass
        except Exception as exc:  # noqa: BLE001 - a closed session or a full disk: said, nothing else changes
            self.ctx.error(f"the operator could not be recorded: {exc}", "Your name")

    def set_lan_stop(self, allowed: bool) -> None:
        try:
            self.control.set_lan_stop(allowed, is_local=self.is_local)
        except PermissionError as exc:
            self.ctx.error(exc, "LAN stops")

    def release_control(self) -> None:
        self.jog_release()
        self._had_control = False
        self.ctx.commands.invoke(self.ctx.who(), "release_control")

    def watch_control(self) -> None:
        """Tell this tab when another client took control from it (it may have been about to jog)."""
        holder = self.control.holder
        if self._had_control and holder != self.client_id:
            self.ctx.notify("Control taken", f"{self.control.name(holder)} now controls the machine; this tab observes.",
                        "error")
        self._had_control = holder == self.client_id

    # --- GUI ---------------------------------------------------------------------------------------

    def _control_buttons(self, gui: Any) -> None:
        """Take control, or Release once this tab holds control (one button's room in the status block)."""
        g = self.gui
        g["take"] = take = gui.add_button("Take control", color="green")
        take.on_click(lambda _: self.take_control(g["code"].value if "code" in g else None))
        g["release"] = gui.add_button("Release", visible=False)
        g["release"].on_click(lambda _: self.release_control())

    def build(self) -> None:
        """Create this client's widgets. Callbacks only call the methods above."""
        gui = self.client.gui
        g = self.gui
        # first, and sticky: state, holder, DRO, link, probe, STOP / E-STOP, Take control / Release always on screen
        self.status.build(gui, controls=self._control_buttons)
        if getattr(self.app, "ask_name", False):
            self._start_dialog(gui)
        # the operator's name (and, for a LAN tab, the access code) folded under one header: the room is the tabs'
        needs_code = not self.is_local and self.control.access_code is not None
        with gui.add_folder("Operator name, access code" if needs_code else "Operator name",
                            expand_by_default=False) as who:
            g["who"] = who
            g["operator"] = gui.add_text("Operator", self.operator or "", hint="your name, for the messages and the report")
            g["set_name"] = gui.add_button("Set name")
            g["set_name"].on_click(lambda _: self.set_operator(g["operator"].value))
            if needs_code:
                g["code"] = gui.add_text("Access code", "", hint="shown on the station's own screen")
        if getattr(self.app, "users", None) is not None:
            panel_users.users_folder(self, gui)
            if self.is_local and self.control.access_code is not None:  # only the person at the station decides
                lan_stop = gui.add_checkbox("LAN observers may stop", self.control.lan_stop)
                lan_stop.on_update(lambda e: self.set_lan_stop(e.target.value))
        # Tabs named for the operator's day, in its order: the machine (home, jog, go to, probe), the part alignment,
        # measuring, the routine, the report, and the set-up done once in a while (probes, diagnostics). Each group's
        # sub-tabs hold what the flat list of 13 tabs held; tests reach them with browser_support.open_tab.
        gui.add_html(TABS_CSS)
        tabs = gui.add_tab_group()
        with tabs.add_tab("Machine"):
            machine = gui.add_tab_group()
            with machine.add_tab("Home"):
                info = self.app.link_info()
                gui.add_markdown(info)
                g["machine"] = gui.add_markdown(machine_markdown(self.station))
                gui.add_button("Home").on_click(lambda _: self.home())
                gui.add_button("Zero (press twice)").on_click(lambda _: self.zero())
                gui.add_button("Reset").on_click(lambda _: self.reset())
                gui.add_button("Reconnect").on_click(lambda _: self.reconnect())
            with machine.add_tab("Jog"):
                speed = gui.add_button_group("Speed", tuple(SPEEDS))
                speed.value = self.speed_mode
                speed.on_click(lambda e: setattr(self, "speed_mode", e.target.value))
                manual = gui.add_checkbox("Manual probing (armed jog)", False)
                manual.on_update(lambda e: self.set_manual_probe(e.target.value))
                gui.add_markdown(f"Manual hits are taken at the qualified probing speed "
                                 f"({self.station_probing_speed():g} mm/s), whatever the speed selected.")
                for i, name in enumerate(AXES):
                    for sign, label in ((-1, f"{name.upper()} −"), (1, f"{name.upper()} +")):
                        b = gui.add_button(f"hold {label}")
                        b.on_hold(self._hold_handler(i, sign), callback_hz=HOLD_HZ)
                        b.on_click(lambda _e: self.jog_release())
                size = gui.add_dropdown("Step (mm)", STEP_SIZES, initial_value=self.step_size)
                size.on_update(lambda e: setattr(self, "step_size", e.target.value))
                for i, name in enumerate(AXES):
                    gui.add_button_group(f"Step {name.upper()}", ("−", "+")).on_click(
                        lambda e, i=i: self.step(i, -1 if e.target.value == "−" else 1))
                src = self.app.pendant_src(self.client.client_id)
                self.pendant_token = self.app.pendant_grant(self) if src else None
                self.hold_token = self.app.pendant_grant(self, hold=self.hold_velocity) if src else None
                if src and self.hold_token:
                    run_script(gui, hold_worker_script(src, self.hold_token))
                if src:
                    if self.pendant_token:
                        src += f"#as={self.pendant_token}"
                    gui.add_markdown(JOG_KEYS_HELP)
                    g["pendant"] = gui.add_html(f'<iframe src="{src}" style="width:100%;height:300px;border:0" '
                                                'title="pendant" allow="gamepad"></iframe>')
            with machine.add_tab("Go to"):
                here = self.station.controller.state.position  # the control core's last sample
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
            with machine.add_tab("Probe"):
                g["probe_data"] = gui.add_markdown(probe_markdown(self.station))
                g["contact"] = gui.add_markdown("*no hit yet*")
                g["hits"] = gui.add_markdown("")
                g["hit_id"] = gui.add_number("Hit", 1, min=1, step=1)
                gui.add_button("Delete hit").on_click(lambda _: self.delete_hit(int(g["hit_id"].value)))
                gui.add_button("Undo").on_click(lambda _: self.undo())
        with tabs.add_tab("Align"):
            self.align.build(gui)
        with tabs.add_tab("Measure"):
            measure = gui.add_tab_group()
            with measure.add_tab("Auto-measure"):
                self.measure.build(gui)
            with measure.add_tab("Features"):
                self.features.build(gui)
            with measure.add_tab("Colour map"):
                self.colour_map.build(gui)
        with tabs.add_tab("Routine"):
            self.routine.build(gui)
        with tabs.add_tab("Report"):
            report = gui.add_tab_group()
            with report.add_tab("Sessions"):
                self.sessions.build(gui)
            with report.add_tab("Trends"):
                self.trends.build(gui)
        with tabs.add_tab("Setup"):
            setup = gui.add_tab_group()
            with setup.add_tab("Part"):  # the part file, where it sits, the next part (on the simulator)
                self.part.build(gui)
            with setup.add_tab("Calibration"):
                self.calibration.build(gui)
            with setup.add_tab("Diagnostics"):
                # the trace changes with every poll: sent only while asked for (an idle page stays quiet)
                live = gui.add_checkbox("Live byte trace", False)
                live.on_update(lambda e: setattr(self, "live_trace", bool(e.target.value)))
                g["trace"] = gui.add_text("NMC bytes (Tx/Rx)", "", multiline=True, disabled=True)
                gui.add_button("Snapshot of the bytes").on_click(lambda _: self._show_trace())
                # late replies a retry recovered: counted here, not shouted in the status bar (docs/reliability.md)
                g["link_health"] = gui.add_markdown(self._link_health())
                t, fe = self.app.following_error_series()
                g["plot"] = gui.add_uplot(
                    (t, *fe), ({"label": "t (s)"}, {"label": "X", "stroke": "red"}, {"label": "Y", "stroke": "green"},
                               {"label": "Z", "stroke": "blue"}),
                    title="following error (counts)", aspect=1.6)

    def refresh(self) -> None:
        """Copy station state into this client's read-outs (only what changed)."""
        self.watch_control()
        self._forget_stale_pick()
        st_now = self.station.controller.state.machine
        if self._jogging and st_now is not None and not st_now.jogging:
            self._jogging = False  # the machine loop ended the jog (dead-man, limit, contact, stop)
        if not self.gui:
            return
        st = self.station
        # once this tab holds control its name folder and Take control leave, Release takes the button's place
        holding = self.control.holder == self.client_id
        for key in CONTROL_FOLDS:
            self.ctx.set(f"control:{key}", "visible", not holding, self.gui.get(key))
        self.ctx.set("control:release", "visible", holding, self.gui.get("release"))
        self.status.refresh()
        self.ctx.set("machine", "content", machine_markdown(st))
        self.ctx.set("target:label", "label", self.target_label(), self.gui.get("target"))  # the alignment may change
        self.ctx.set("probe_data", "content", probe_markdown(st))  # a qualification applied shows at once
        hit = st.measurement.last_hit
        if hit is not None:
            self.ctx.set("contact", "content",
                      "last trigger (tip centre, machine): X={:.4f} Y={:.4f} Z={:.4f}\n\n".format(*hit.machine)
                      + "contact point (machine): X={:.4f} Y={:.4f} Z={:.4f}".format(*hit.point))
        hits = sorted(self.ctx.model().hits.items())
        devs = self.app.deviations()
        rows = [f"{hid}: ({h.point[0]:.3f}, {h.point[1]:.3f}, {h.point[2]:.3f}) "
                f"{devs.get(hid, float('nan')) * 1000:+.1f} um {h.mode}" for hid, h in hits[-12:]]
        self.ctx.set("hits", "content", "hits (last 12, machine coordinates):\n\n" + ("\n\n".join(rows) if rows else "*none*"))
        self.features.refresh()
        self.align.refresh()
        self.part.refresh()
        self.colour_map.refresh()
        self.measure.refresh()
        self.routine.refresh()
        if self.ctx.picked is not None:
            p, nominal = self.ctx.picked
            self.ctx.set("pick", "content", "picked X={:.3f} Y={:.3f} Z={:.3f}, normal ({:.3f}, {:.3f}, {:.3f})".format(
                *p.point, *p.normal) + (f"; nominal {nominal.kind}" if nominal is not None else "") + " (machine coordinates)")
        if self.live_trace:
            self._show_trace()
        t, fe = self.app.following_error_series()
        # the plot is re-sent only when a following error changed: 500 samples x 4 float64 (16 kB) five times a
        # second was most of an idle page's 50-80 kB/s
        values = np.nan_to_num(np.stack(fe))
        key = values.tobytes() if np.ptp(values) > 0 else values.flat[0].tobytes()  # flat: however long
        if "plot" in self.gui and len(t) > 1 and key != self._plot_key:
            self._plot_key = key
            self.gui["plot"].data = (t, *fe)
        self.sessions.refresh()
        self.trends.refresh()
        self.calibration.refresh()

    def _show_trace(self) -> None:
        self.ctx.set("trace", "value", self.station.controller.trace_text(last=30))  # the link process's on a real port
        self.ctx.set("link_health", "content", self._link_health())

    def _link_health(self) -> str:
        return self.ctx.commands.invoke(self.ctx.who(), "link_health")["text"]

    def fast_refresh(self) -> None:
        """The status bar (DRO) at the refresher's full rate while the machine moves; idle it changes nothing."""
        if self.gui:
            self.status.refresh()

    def station_probing_speed(self) -> float:
        return float(self.station.calibration.qualified_probing_speed)
