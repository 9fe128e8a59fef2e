"""The tab's operator and control: who operates (the start dialog, the name folder, a user's log-in) and the
machine's control (Take control, Release, the LAN-stop choice, the toast when another client took it).

Every change goes to the control core as this tab's client (:meth:`~cmm.ui.context.PanelContext.who`); the core
refuses in the operator's words and the refusal is shown here.
"""

from __future__ import annotations

import json
from typing import Any, Callable

from ..control import Refused
from .context import PanelContext
from . import panel_users
from .panel_status import run_script

CONTROL_FOLDS = ("who", "take")  # the name folder and Take control, hidden while this tab holds control
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


class OperatorPanel:
    """The operator's name, the user log-in and the machine's control of one tab."""

    def __init__(self, ctx: PanelContext, app: Any, client: Any, *, is_local: bool,
                 jog_release: Callable[[], None]) -> None:
        self.ctx = ctx
        self.app = app
        self.control = app.control
        self.client = client
        self.client_id = ctx.client_id
        self.is_local = is_local
        self.gui = ctx.gui
        self._jog_release = jog_release  # releasing control ends this tab's jog first
        self._had_control = False

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

    def start_dialog(self, gui: Any) -> None:
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
        if name is None or self.ctx.commands.invoke(self.ctx.who(), "report_info").get("operator") == name:
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
        self._jog_release()
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

    def control_buttons(self, gui: Any) -> None:
        """Take control, or Release once this tab holds control (one button's room in the status block)."""
        g = self.gui
        g["take"] = take = gui.add_button("Take control", color="green")
        take.on_click(lambda _: self.take_control(g["code"].value if "code" in g else None))
        g["release"] = gui.add_button("Release", visible=False)
        g["release"].on_click(lambda _: self.release_control())

    def build(self, gui: Any) -> None:
        """The operator's name (and, for a LAN tab, the access code) folded under one header: the room is the tabs';
        the admin's Users folder and the station's LAN-stop choice on a station with a user file."""
        g = self.gui
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

    def refresh(self) -> None:
        """Once this tab holds control its name folder and Take control leave, Release takes the button's place."""
        holding = self.control.holder == self.client_id
        for key in CONTROL_FOLDS:
            self.ctx.set(f"control:{key}", "visible", not holding, self.gui.get(key))
        self.ctx.set("control:release", "visible", holding, self.gui.get("release"))
