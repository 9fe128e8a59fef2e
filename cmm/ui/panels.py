"""One client's GUI: panels built declaratively, short callbacks, state kept outside the widgets.

:class:`ClientApp` holds one browser tab's state (picked point, speed mode,
the last move status) and exposes every action as a plain method
(``go_to``, ``jog_hold``, ``pick``, ``probe_here``, ``fit`` ...), so the tests
drive exactly what a button does without a browser. ``build()`` creates the
widgets and wires each one to a method; ``refresh()`` copies station state
into the read-outs a few times a second.

Machine commands go to the control core (``station.controller``, see
:mod:`cmm.control`) as this client (:meth:`ClientApp.who`): the core checks
the access policy (the shared :class:`~cmm.ui.access.Control`, STOP and E-stop
by its one :meth:`~cmm.ui.access.Control.may_stop` policy) and the machine
state once, and refuses with a sentence that is shown here. Measurement
changes (hits, features, sessions) ask :meth:`ClientApp.allowed` first (a
server-side check: hiding buttons is not security). The jog dead-man is the
machine loop's: held buttons re-send the jog. A busy browser sends viser's hold
events late (a WebGL frame on a slow PC blocks the page for up to ~1 s), which stopped the jog on the dead-man again
and again; so the app's hold keeper (:meth:`ClientApp.keep_hold`, 25 Hz)
re-sends a held button's jog between its hold events, for at most
``HOLD_GRACE_S`` of machine time after the newest one, then releases it.
"""

from __future__ import annotations

import math
import re
import time
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from ..control import MotionError
from ..metrology.features import FitError
from ..measurement.model import MeasurementError
from .panel_align import AlignPanel
from .ids import parse_ids  # noqa: F401 - part of this module's interface (tests, other panels)
from .panel_calibration import CalibrationPanel
from .panel_colour_map import ColourMapPanel
from .panel_features import FeaturesPanel
from .panel_measure import MeasurePanel
from .panel_sessions import SessionsPanel
from .panel_status import StatusPanel
from .scene import SCALE, draw_pick

if TYPE_CHECKING:
    from .app import StationApp

AXES = ("x", "y", "z")
SPEEDS = {"positioning": "jog_fast", "probing": "jog_slow", "fine": "jog_fine"}
STEP_SIZES = ("1 count", "0.01", "0.1", "1", "10")
JOG_KEYS_HELP = ("**Keyboard** (click the pendant below first): arrows = X/Y, PageUp/PageDown = Z at the "
                 "pendant's selected speed (Fine / Slow / Fast), hold **Shift** = fast; releasing the key stops; "
                 "**Esc** or **Space** = stop. Step jogs: the Step size above and the Step X/Y/Z buttons. "
                 "The pendant below acts for this page: it shares this page's control. A tablet opens the "
                 "pendant page alone (its own client: Take control there).")
LATE_HOLD_S = 0.2  # hold events this soon after a release are late ones (viser may run callbacks out of order)
HOLD_HZ = 20.0  # jog refresh rate while a button is held (the dead-man timeout is 0.15 s)
# machine seconds a held button's jog is kept alive after its newest hold event (a busy browser sends them late);
# a lost pointer-up or a frozen tab therefore stops within this plus the stop (a closed tab releases at once)
HOLD_GRACE_S = 1.0
OPERATOR_ERRORS = (MotionError, MeasurementError, FitError, ValueError, OSError)


def _unit(v: Any) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _angle(u: Any, v: Any) -> float:
    """Angle between two axes (sign ignored), degrees."""
    c = abs(float(np.dot(_unit(u), _unit(v))))
    return math.degrees(math.acos(min(c, 1.0)))


def _dist_to_axis(p: Any, point: Any, direction: Any) -> float:
    d = _unit(direction)
    r = np.asarray(p, float) - np.asarray(point, float)
    return float(np.linalg.norm(r - (r @ d) * d))


def nominal_deviation(kind: str, geometry: dict[str, Any], nominal: Any) -> dict[str, float]:
    """Deviations of a fitted feature from a nominal one (mm, degrees); empty when they do not compare."""
    if nominal is None:
        return {}
    g = {k: np.asarray(v, float) if isinstance(v, list) else v for k, v in geometry.items()}
    n, p = nominal.kind, nominal.params
    out: dict[str, float] = {}
    if kind == "plane" and n in ("plane", "surface"):
        out["distance"] = float((g["point"] - p["point"]) @ _unit(p["normal"]))
        out["angle_deg"] = _angle(g["normal"], p["normal"])
    elif kind == "sphere" and n == "sphere":
        out["centre_offset"] = float(np.linalg.norm(g["center"] - p["center"]))
        out["radius_dev"] = float(g["radius"] - p["radius"])
    elif kind == "cylinder" and n == "cylinder":
        out["radius_dev"] = float(g["radius"] - p["radius"])
        out["axis_offset"] = _dist_to_axis(g["point"], p["point"], p["direction"])
        out["axis_angle_deg"] = _angle(g["direction"], p["direction"])
    elif kind == "circle" and n == "cylinder":
        out["radius_dev"] = float(g["radius"] - p["radius"])
        out["centre_to_axis"] = _dist_to_axis(g["center"], p["point"], p["direction"])
        out["axis_angle_deg"] = _angle(g["normal"], p["direction"])
    elif kind == "cone" and n == "cone":
        out["apex_offset"] = float(np.linalg.norm(g["apex"] - p["apex"]))
        out["half_angle_dev_deg"] = math.degrees(float(g["half_angle"]) - float(p["half_angle"]))
        out["axis_angle_deg"] = _angle(g["direction"], p["direction"])
    return out


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4f}"
    if isinstance(v, list):
        return "(" + ", ".join(f"{x:.4f}" for x in v) + ")"
    return str(v)


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


class ClientApp:
    """One browser client (or a test standing in for one)."""

    def __init__(self, app: "StationApp", client: Any = None, *, client_id: str | None = None,
                 is_local: bool = False) -> None:
        self.app = app
        self.station = app.station
        self.control = app.control
        self.client = client
        self.client_id = client_id or (f"viser-{client.client_id}" if client is not None else "test")
        self.is_local = is_local
        self.authenticated = is_local  # local, or gave the right access code on this connection
        self.messages: list[tuple[str, str, str]] = []  # (level, title, body): what the operator was told
        self.speed_mode = "probing"
        self.step_size = "1"
        self.manual_probe = False
        self.picked: Any = None  # (PickResult, NominalFeature | None)
        self.move_status: Any = None
        self.selected_feature: int | None = None
        self.pendant_token: str | None = None  # the embedded pendant's grant (acts as this client)
        self._jogging = False
        self._last_hold = 0.0
        self._hold: tuple[np.ndarray, bool, int, float] | None = None  # (v, probe, release seq, machine time)
        self._last_error = ("", 0.0)
        self._zero_armed = 0.0
        self._released_at = 0.0
        self.gui: dict[str, Any] = {}
        self._shown: dict[str, Any] = {}
        self.live_trace = False
        self._had_control = False
        self._plot_key: bytes | None = None
        self.sessions = SessionsPanel(self)
        self.calibration = CalibrationPanel(self)
        self.status = StatusPanel(self)
        self.features = FeaturesPanel(self)
        self.align = AlignPanel(self)
        self.measure = MeasurePanel(self)
        self.colour_map = ColourMapPanel(self)

    # --- messages -------------------------------------------------------------

    def notify(self, title: str, body: str = "", level: str = "info") -> None:
        self.messages.append((level, title, body))
        del self.messages[:-50]
        if self.client is not None:
            try:
                self.client.add_notification(title, body, auto_close_seconds=6.0 if level != "error" else 10.0,
                                             color="red" if level == "error" else None)
            except Exception:  # noqa: BLE001 - the tab may have closed
                pass

    def error(self, exc: BaseException | str, title: str = "Refused") -> None:
        self.notify(title, str(exc), "error")

    def allowed(self, action: str) -> bool:
        """The server-side control check every machine- or measurement-changing action makes first."""
        if self.control.can_move(self.client_id):
            return True
        self.error(f"{action}: this browser only observes. Take control first.", "Not in control")
        return False

    def _run(self, action: str, fn: Callable[[], Any], *, guarded: bool = True) -> Any:
        if guarded and not self.allowed(action):
            return None
        try:
            return fn()
        except OPERATOR_ERRORS as exc:
            self.error(exc, f"{action} refused")
            return None

    @property
    def api(self) -> Any:
        """The control core: every machine command goes there with this client's id."""
        return self.station.controller

    def who(self) -> Any:
        """This browser as the control core's access policy sees it."""
        from ..control import Client

        return Client(self.client_id, local=self.is_local, authenticated=bool(getattr(self, "authenticated", False)))

    def _cmd(self, action: str, fn: Callable[..., Any], *args: Any, **kw: Any) -> Any:
        """A machine command; the control core checks access and state, a refusal is shown to the operator."""
        try:
            return fn(self.who(), *args, **kw)
        except OPERATOR_ERRORS as exc:
            self.error(exc, f"{action} refused")
            return None

    # --- machine ------------------------------------------------------------------

    def stop(self) -> Any:
        self._hold = None
        self._jogging = False
        report = self._cmd("Stop", self.api.stop)
        if report is not None and not report.ok:
            self.notify("STOP not confirmed", report.message, "error")
        return report

    def emergency_stop(self) -> Any:
        self._hold = None
        self._jogging = False
        report = self._cmd("E-stop", self.api.emergency_stop)
        if report is not None:
            self.notify("Emergency stop" if report.ok else "E-STOP NOT CONFIRMED", report.message, "error")
        return report

    def reset(self) -> None:
        self._cmd("Reset", self.api.reset)

    def reconnect(self) -> None:
        self._cmd("Reconnect", self.api.reconnect)

    def home(self) -> None:
        """The homing cycle, in a worker thread (it takes seconds); STOP aborts it."""
        import threading

        def run() -> None:
            if self._cmd("Home", self.api.home) is None and self.api.state.homed:
                self.notify("Homed", "the machine is homed")
        threading.Thread(target=run, name="ui-home", daemon=True).start()

    def zero(self, confirm: bool = False) -> None:
        """Zero needs a second press within 5 s (or ``confirm``): it redefines the machine origin."""
        now = time.monotonic()
        if not confirm and now - self._zero_armed > 5.0:
            self._zero_armed = now
            self.notify("Zero: press again to confirm",
                        "Zero makes the present position the home coordinates (the machine origin). "
                        "Press Zero again within 5 s to confirm.", "error")
            return
        self._zero_armed = 0.0
        self._cmd("Zero", self.api.zero, confirm=True)

    # --- go to -------------------------------------------------------------------

    def go_to(self, x: float, y: float, z: float) -> Any:
        status = self._cmd("Go to", self.api.move_to, [float(x), float(y), float(z)])
        if status is not None:
            self.move_status = status
            status.add_callback(self._move_done)
        return status

    def _move_done(self, status: Any) -> None:
        err = getattr(status, "error", None)
        if err is not None and "stopped by the operator" not in str(err):
            self.error(err, "Move ended")

    def cancel(self) -> None:
        status = self.move_status
        if status is not None and not getattr(status, "done", True):
            self._cmd("Cancel", self.api.cancel, status)
        else:
            self.stop()

    # --- jog -------------------------------------------------------------------------

    def jog_velocity(self, axis: int, sign: int) -> np.ndarray:
        v = np.zeros(3)
        v[axis] = math.copysign(getattr(self.station.config.speeds, SPEEDS[self.speed_mode]), sign)
        return v

    def jog_hold(self, axis: int, sign: int) -> None:
        """Called repeatedly while a jog button is held: refreshes the machine loop's dead-man jog."""
        if time.monotonic() - self._released_at < LATE_HOLD_S:
            return  # a hold event that arrived after the button's release must not start the jog again
        v = self.jog_velocity(axis, sign)
        v = self.station.manual_probe_velocity(v) if self.manual_probe else v
        who = self.who()
        seq = self.api.release_seq(who)  # a release after this point drops this jog and the keeper's re-sends
        try:
            self.api.jog(who, v, probe=self.manual_probe, after=seq)
        except OPERATOR_ERRORS as exc:
            self._hold = None
            self._throttled_error("Jog", str(exc))
            return
        self._jogging = True
        self._last_hold = time.monotonic()
        self._hold = (v, self.manual_probe, seq, self._machine_time())

    def keep_hold(self) -> None:
        """The hold keeper (app thread, 25 Hz): re-send a held button's jog between its (late) hold events; release
        it once none came for ``HOLD_GRACE_S`` of machine time (lost pointer-up, frozen tab)."""
        hold = self._hold
        if hold is None:
            return
        v, probe, seq, since = hold
        if self._machine_time() - since > HOLD_GRACE_S:
            if self._hold is hold:
                self._hold = None
                self.jog_release()
            return
        try:
            self.api.jog(self.who(), v, probe=probe, after=seq)
        except OPERATOR_ERRORS:
            pass  # refused (control taken, fault, contact back-off): the next hold event tells the operator

    def _machine_time(self) -> float:
        st = self.station.machine.state
        return float(st.time) if st is not None and getattr(st, "time", None) is not None else time.monotonic()

    def jog_release(self) -> None:
        """The button was released (viser's click event fires on release) or the holds stopped coming."""
        self._hold = None
        self._released_at = time.monotonic()
        if self._jogging:
            self._jogging = False
            try:
                self.api.jog_release(self.who())
            except OPERATOR_ERRORS as exc:
                self.error(exc, "Jog release")

    def _throttled_error(self, title: str, body: str) -> None:
        last, when = self._last_error
        if body != last or time.monotonic() - when > 2.0:
            self._last_error = (body, time.monotonic())
            self.error(body, title)

    def step(self, axis: int, sign: int) -> Any:
        size = self.step_size
        mm = 1.0 / self.station.config.axes[axis].counts_per_mm if size == "1 count" else float(size)
        return self._cmd("Step", lambda cid: self.station.controller.step(cid, AXES[axis], math.copysign(mm, sign)))

    def set_manual_probe(self, on: bool) -> None:
        self.jog_release()
        self.manual_probe = bool(on)

    # --- pick ------------------------------------------------------------------------

    def pick(self, origin_mm: Any, direction: Any) -> Any:
        """Ray pick on the part (machine mm). Anyone may pick: it moves nothing."""
        try:
            result = self.station.measurement.pick(origin_mm, direction)
        except OPERATOR_ERRORS as exc:
            self.error(exc, "Pick")
            return None
        if result is None:
            self.notify("Pick", "the ray missed the part")
            return None
        self.picked = result
        hit, nominal = result
        if self.client is not None:
            draw_pick(self.client.scene, hit.point, hit.normal)
        self.notify("Picked", "X={:.3f} Y={:.3f} Z={:.3f}".format(*hit.point)
                    + (f" · {nominal.kind}" if nominal is not None else ""))
        return result

    def on_scene_click(self, origin_scene: Any, direction: Any) -> Any:
        return self.pick(np.asarray(origin_scene, float) / SCALE, direction)

    def move_above(self) -> Any:
        if self.picked is None:
            self.error("click a point on the part first", "Move above")
            return None
        hit = self.picked[0]
        status = self._cmd("Move above", lambda cid: self.station.move_above(hit.point, hit.normal, client=cid))
        return None if status is None else self._track(status)

    def probe_here(self) -> Any:
        if self.picked is None:
            self.error("click a point on the part first", "Probe here")
            return None
        hit = self.picked[0]
        status = self._cmd("Probe here", lambda cid: self.station.measurement.probe_here(hit.point, hit.normal, client=cid))
        return None if status is None else self._track(status)

    def _track(self, status: Any) -> Any:
        self.move_status = status
        status.add_callback(self._move_done)
        return status

    # --- hits ---------------------------------------------------------------------------

    def delete_hit(self, hid: int) -> None:
        self._run("Delete hit", lambda: self.station.measurement.delete_hit(int(hid)))

    def undo(self) -> None:
        message = self._run("Undo", self.station.measurement.undo)
        if message:
            self.notify("Undo", message)

    # --- features --------------------------------------------------------------------------

    def hit_ids_for(self, ids_text: str, last_n: int) -> list[int]:
        if ids_text.strip():
            return parse_ids(ids_text)
        with self.station.measurement.lock:
            ids = sorted(self.station.measurement.hits)
        return ids[-int(last_n):] if last_n > 0 else ids

    def fit(self, kind: str, method: str = "ls", ids_text: str = "", last_n: int = 0) -> Any:
        def do() -> Any:
            ids = self.hit_ids_for(ids_text, last_n)
            # the nominal is the CAD surface the hits lie on (the station finds it), not the last click:
            # "Nominal from the last CAD pick" in the Features tab applies a pick on purpose
            feature = self.station.measurement.fit_feature(kind, ids, method)
            self.selected_feature = feature.id
            self.app.view.select_feature(feature.id)
            self.notify("Fitted", f"{feature.name}: form {feature.result.form * 1000:.2f} um "
                                  f"from {len(ids)} hits")
            return feature
        return self._run("Fit", do)

    def select_feature(self, fid: int) -> None:
        self.selected_feature = fid
        self.app.view.select_feature(fid)
        self.refresh()

    def feature_markdown(self) -> str:
        fid = self.selected_feature
        feature = self.station.measurement.features.get(fid) if fid is not None else None
        if feature is None:
            return "*no feature selected*"
        s = feature.result.summary()
        lines = [f"**{feature.name}** ({feature.kind}, {feature.method}, hits {feature.hit_ids})", "",
                 f"form error: **{s['form'] * 1000:.2f} um**"
                 + (f" · sigma {s['sigma'] * 1000:.2f} um" if s.get("sigma") is not None else "")]
        if s.get("uncertainty"):  # standard uncertainties: angles (rad) in urad, lengths (mm) in um
            lines.append("u (1 sigma): " + " · ".join(
                f"{k} {v * 1e6:.1f} urad" if k in ("normal", "direction", "half_angle") else f"{k} {v * 1000:.2f} um"
                for k, v in s["uncertainty"].items()))
        lines.extend(f"\n**warning:** {w}" for w in s.get("warnings", []))
        for k, v in feature.result.geometry().items():
            lines.append(f"- {k}: {_fmt(v)}")
        dev = nominal_deviation(feature.kind, feature.result.geometry(), feature.nominal)
        if dev:
            lines.append(f"\nvs nominal {feature.nominal.kind}:")
            lines.extend(f"- {k}: {v:+.4f}" for k, v in dev.items())
        return "\n".join(lines)

    # --- control ------------------------------------------------------------------------------

    def peer(self) -> str | None:
        """This tab's network address: the key of the access-code rate limit (new tabs share it)."""
        if self.client is None:
            return None
        address = self.app.client_address(self.client.client_id)
        return address[0] if isinstance(address, (tuple, list)) and address else None

    def take_control(self, code: str | None = None) -> bool:
        refusal = self.control.try_take(self.client_id, code or None, self.is_local, peer=self.peer())
        if refusal is None:
            self.authenticated = True
            self.notify("Control", "you control the machine")
        else:
            self.error(refusal, "Take control")
        return refusal is None

    def set_lan_stop(self, allowed: bool) -> None:
        try:
            self.control.set_lan_stop(allowed, is_local=self.is_local)
        except PermissionError as exc:
            self.error(exc, "LAN stops")

    def release_control(self) -> None:
        self.jog_release()
        self._had_control = False
        self.control.release(self.client_id)

    def watch_control(self) -> None:
        """Tell this tab when another client took control from it (it may have been about to jog)."""
        holder = self.control.holder
        if self._had_control and holder != self.client_id:
            self.notify("Control taken", f"{holder or 'nobody'} now controls the machine; this tab observes.",
                        "error")
        self._had_control = holder == self.client_id

    def control_text(self) -> str:
        holder = self.control.holder
        if holder == self.client_id:
            return "**You control the machine.**"
        if holder is None:
            return "Nobody controls the machine. You observe."
        return f"Observing; control is held by `{holder}`."

    # --- GUI ---------------------------------------------------------------------------------------

    def build(self) -> None:
        """Create this client's widgets. Callbacks only call the methods above."""
        gui = self.client.gui
        g = self.gui
        self.status.build(gui)  # first, and sticky: state, DRO, probe, STOP / E-STOP always on screen
        with gui.add_folder("Control"):
            g["control"] = gui.add_markdown(self.control_text())
            g["code"] = gui.add_text("Access code", "", hint="local clients may leave it empty")
            take = gui.add_button("Take control", color="green")
            take.on_click(lambda _: self.take_control(g["code"].value))
            gui.add_button("Release").on_click(lambda _: self.release_control())
            if self.is_local and self.control.access_code is not None:  # only the person at the station decides
                lan_stop = gui.add_checkbox("LAN observers may stop", self.control.lan_stop)
                lan_stop.on_update(lambda e: self.set_lan_stop(e.target.value))
        tabs = gui.add_tab_group()
        with tabs.add_tab("Machine"):
            info = self.app.link_info()
            gui.add_markdown(info)
            g["machine"] = gui.add_markdown(machine_markdown(self.station))
            gui.add_button("Home").on_click(lambda _: self.home())
            gui.add_button("Zero (press twice)").on_click(lambda _: self.zero())
            gui.add_button("Reset").on_click(lambda _: self.reset())
            gui.add_button("Reconnect").on_click(lambda _: self.reconnect())
        with tabs.add_tab("Jog"):
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
                    b.on_hold(lambda _e, i=i, s=sign: self.jog_hold(i, s), callback_hz=HOLD_HZ)
                    b.on_click(lambda _e: self.jog_release())
            size = gui.add_dropdown("Step (mm)", STEP_SIZES, initial_value=self.step_size)
            size.on_update(lambda e: setattr(self, "step_size", e.target.value))
            for i, name in enumerate(AXES):
                gui.add_button_group(f"Step {name.upper()}", ("−", "+")).on_click(
                    lambda e, i=i: self.step(i, -1 if e.target.value == "−" else 1))
            src = self.app.pendant_src(self.client.client_id)
            self.pendant_token = self.app.pendant_grant(self) if src else None
            if src:
                if self.pendant_token:
                    src += f"#as={self.pendant_token}"
                gui.add_markdown(JOG_KEYS_HELP)
                g["pendant"] = gui.add_html(f'<iframe src="{src}" style="width:100%;height:300px;border:0" '
                                            'title="pendant" allow="gamepad"></iframe>')
        with tabs.add_tab("Go to"):
            pos = self.station.machine.state.position if self.station.machine.state is not None else np.zeros(3)
            g["target"] = gui.add_vector3("Target (mm)", tuple(float(v) for v in pos), step=0.001)
            gui.add_button("Go").on_click(lambda _: self.go_to(*g["target"].value))
            gui.add_button("Cancel").on_click(lambda _: self.cancel())
            g["pick"] = gui.add_markdown("Click the part to pick a point.")
            gui.add_button("Move above").on_click(lambda _: self.move_above())
            gui.add_button("Probe here").on_click(lambda _: self.probe_here())
        with tabs.add_tab("Probe"):
            settings = self.station.prober.settings
            gui.add_markdown(f"stylus radius **{settings.tip_radius:.4f} mm** · pre-travel "
                             f"{settings.pretravel.describe()}")
            g["contact"] = gui.add_markdown("*no hit yet*")
            g["hits"] = gui.add_markdown("")
            g["hit_id"] = gui.add_number("Hit", 1, min=1, step=1)
            gui.add_button("Delete hit").on_click(lambda _: self.delete_hit(int(g["hit_id"].value)))
            gui.add_button("Undo").on_click(lambda _: self.undo())
        with tabs.add_tab("Features"):
            self.features.build(gui)
        with tabs.add_tab("Align"):
            self.align.build(gui)
        with tabs.add_tab("Colour map"):
            self.colour_map.build(gui)
        with tabs.add_tab("Auto-measure"):
            self.measure.build(gui)
        with tabs.add_tab("Diagnostics"):
            # the trace changes with every poll: sent only while asked for (an idle page stays quiet)
            live = gui.add_checkbox("Live byte trace", False)
            live.on_update(lambda e: setattr(self, "live_trace", bool(e.target.value)))
            g["trace"] = gui.add_text("NMC bytes (Tx/Rx)", "", multiline=True, disabled=True)
            gui.add_button("Snapshot of the bytes").on_click(lambda _: self._show_trace())
            t, fe = self.app.following_error_series()
            g["plot"] = gui.add_uplot(
                (t, *fe), ({"label": "t (s)"}, {"label": "X", "stroke": "red"}, {"label": "Y", "stroke": "green"},
                           {"label": "Z", "stroke": "blue"}),
                title="following error (counts)", aspect=1.6)
        with tabs.add_tab("Sessions"):
            self.sessions.build(gui)
        with tabs.add_tab("Calibration"):
            self.calibration.build(gui)

    def refresh(self) -> None:
        """Copy station state into this client's read-outs (only what changed)."""
        self.watch_control()
        st_now = self.station.machine.state
        if self._jogging and st_now is not None and not st_now.jogging:
            self._jogging = False  # the machine loop ended the jog (dead-man, limit, contact, stop)
        if not self.gui:
            return
        st = self.station
        self._set("control", "content", self.control_text())
        self.status.refresh()
        self._set("machine", "content", machine_markdown(st))
        hit = st.measurement.last_hit
        if hit is not None:
            self._set("contact", "content",
                      "last trigger (tip centre): X={:.4f} Y={:.4f} Z={:.4f}\n\n".format(*hit.machine)
                      + "contact point: X={:.4f} Y={:.4f} Z={:.4f}".format(*hit.point))
        with st.measurement.lock:
            hits = sorted(st.measurement.hits.items())
        devs = self.app.deviations()
        rows = [f"{hid}: ({h.point[0]:.3f}, {h.point[1]:.3f}, {h.point[2]:.3f}) "
                f"{devs.get(hid, float('nan')) * 1000:+.1f} um {h.mode}" for hid, h in hits[-12:]]
        self._set("hits", "content", "hits (last 12):\n\n" + ("\n\n".join(rows) if rows else "*none*"))
        self.features.refresh()
        self.align.refresh()
        self.colour_map.refresh()
        self.measure.refresh()
        if self.picked is not None:
            p, nominal = self.picked
            self._set("pick", "content", "picked X={:.3f} Y={:.3f} Z={:.3f}, normal ({:.3f}, {:.3f}, {:.3f})".format(
                *p.point, *p.normal) + (f"; nominal {nominal.kind}" if nominal is not None else ""))
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
        self.calibration.refresh()

    def _show_trace(self) -> None:
        self._set("trace", "value", self.station.link_trace(30))

    def fast_refresh(self) -> None:
        """The status bar (DRO) at the refresher's full rate while the machine moves; idle it changes nothing."""
        if self.gui:
            self.status.refresh()

    def aligned(self) -> bool:
        return bool(self.station.measurement.aligned)

    def station_probing_speed(self) -> float:
        return float(getattr(self.station, "qualified_probing_speed", self.station.config.speeds.probing))

    def _set(self, key: str, attr: str, value: Any, handle: Any = None) -> None:
        """Set a widget attribute only when the value changed (``handle`` for widgets of the sub-panels)."""
        widget = handle if handle is not None else self.gui.get(key)
        if widget is not None and self._shown.get(key) != value:
            self._shown[key] = value
            setattr(widget, attr, value)
