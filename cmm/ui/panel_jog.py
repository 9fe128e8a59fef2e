"""Machine > Jog: the hold-to-jog buttons, the step jogs, the speed, manual probing, and the embedded pendant.

The jog buttons feed the core's jog-hold pipeline (:mod:`cmm.control.jog`): each hold event refreshes the jog,
the release ends it, and the machine's dead-man stops it when the events stop. The page's hold refresher
(web/hold_worker.js) and the 3-D view's keys (web/view_keys.js) ask :meth:`JogPanel.hold_velocity` what a held
button or key means.
"""

from __future__ import annotations

import asyncio
import math
import time
from typing import Any, Callable

import numpy as np

from .context import OPERATOR_ERRORS, PanelContext
from .panel_status import run_script

AXES = ("x", "y", "z")
SPEEDS = {"positioning": "jog_fast", "probing": "jog_slow", "fine": "jog_fine"}
STEP_SIZES = ("1 count", "0.01", "0.1", "1", "10")
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


def hold_worker_script(pendant_src: str, token: str) -> str:
    """web/hold_worker.js for this page (its pendant WebSocket and its refresher's grant), then web/view_keys.js
    (the keyboard jog of the 3-D view, through the same worker)."""
    from .pendant import web_dir

    ws = pendant_src.split("#", 1)[0].replace("http://", "ws://", 1).replace("https://", "wss://", 1).rstrip("/") + "/ws"
    worker = (web_dir() / "hold_worker.js").read_text().replace("__WS_URL__", ws).replace("__TOKEN__", token)
    return worker + "\n" + (web_dir() / "view_keys.js").read_text()


class JogPanel:
    """One tab's jog: its speed and step size, and whether a jog of this tab is known to run."""

    def __init__(self, ctx: PanelContext, app: Any, client: Any, verb: Callable[..., Any]) -> None:
        self.ctx = ctx
        self.app = app
        self.client = client
        self.gui = ctx.gui
        self._verb = verb  # a verb of the command API sent as this tab, a refusal shown
        self.speed_mode = "probing"
        self.step_size = "1"
        self.pendant_token: str | None = None  # the embedded pendant's grant (acts as this client)
        self.hold_token: str | None = None  # the jog buttons' hold refresher's grant (web/hold_worker.js)
        self._jogging = False
        self._last_error = ("", 0.0)
        self._clock: Any = None  # the machine's clock (the clock query), taken once: a hold notes when it was heard

    @property
    def config(self) -> Any:
        """The machine's configuration (the ``config`` query): the jog speeds and the counts per mm."""
        return self.ctx.query("machine_config")

    def jog_velocity(self, axis: int, sign: int) -> np.ndarray:
        v = np.zeros(3)
        v[axis] = math.copysign(getattr(self.config.speeds, SPEEDS[self.speed_mode]), sign)
        return v

    def _hold_handler(self, axis: int, sign: int) -> Callable[[Any], Any]:
        """The jog button's hold callback: a coroutine, so viser runs it in its event loop as the event arrives;
        it notes that moment (the dead-man runs from it) and hands the hold to a thread (a late thread pool
        then cannot keep the jog going)."""
        if self._clock is None:
            self._clock = self.ctx.query("clock")

        async def held(_event: Any) -> None:
            heard = self._clock.now()
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
        speed = getattr(self.config.speeds, "jog_fast" if fast else SPEEDS[self.speed_mode])
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
        mm = 1.0 / self.config.axes[axis].counts_per_mm if size == "1 count" else float(size)
        return self._verb("Step", "step", axis=AXES[axis], mm=math.copysign(mm, sign))

    def set_manual_probe(self, on: bool) -> None:
        self.jog_release()
        self.ctx.manual_probe = bool(on)

    def station_probing_speed(self) -> float:
        return float(self.ctx.query("calibration_state")["probing_speed"])

    def build(self, gui: Any, grant: Callable[..., str | None]) -> None:
        """The Jog tab; ``grant`` issues a pendant grant acting as this tab (``hold=``: the hold refresher's)."""
        g = self.gui
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
        self.pendant_token = grant() if src else None
        self.hold_token = grant(hold=self.hold_velocity) if src else None
        if src and self.hold_token:
            run_script(gui, hold_worker_script(src, self.hold_token))
        if src:
            if self.pendant_token:
                src += f"#as={self.pendant_token}"
            gui.add_markdown(JOG_KEYS_HELP)
            g["pendant"] = gui.add_html(f'<iframe src="{src}" style="width:100%;height:300px;border:0" '
                                        'title="pendant" allow="gamepad"></iframe>')

    def refresh(self) -> None:
        st_now = self.ctx.query("state").machine
        if self._jogging and st_now is not None and not st_now.jogging:
            self._jogging = False  # the machine loop ended the jog (dead-man, limit, contact, stop)
