"""Users on the page (a station with a user file): the start dialog's login and the admin's Users folder.

Functions of the tab's operator panel (:class:`cmm.ui.panel_operator.OperatorPanel`, passed as ``self``); every
change goes to the command API as the tab's client, and the API's role table decides (:mod:`cmm.control.roles`).
"""

from __future__ import annotations

from typing import Any

from .panel_status import run_script

# The login dialog's password field: typed characters hidden (viser's text field has no password mode)
PASSWORD_JS = """
(function () {
  // viser's label is a <label> in the field's Flex row, not linked to its input: find the row by the label
  const hide = () => {
    for (const label of document.querySelectorAll("label")) {
      if (!/^(new )?password$/i.test((label.textContent || "").trim())) continue;
      const row = label.closest(".mantine-Flex-root");
      const input = row && row.querySelector("input");
      if (input && input.type !== "password") input.type = "password";
    }
  };
  // a new field (the dialog drawn again) or a field whose type was set back (a re-render): hidden again
  let queued = false;  // at most one pass in 50 ms, however fast the page changes
  window.__cmmPasswordWatch = true;  // the page runs this watch (a test's diagnosis reads it)
  hide();
  new MutationObserver(() => {
    if (!queued) { queued = true; setTimeout(() => { queued = false; hide(); }, 50); }
  }).observe(document.body, {childList: true, subtree: true, attributes: true, attributeFilter: ["type"]});
})();
"""


def log_in(self: Any, name: str, password: str) -> bool:
    """A station with a user file: this tab acts as the user (name, role) from now on; its name is the
    operator's. Refused in one sentence that does not say which part was wrong."""
    users = getattr(self.app, "users", None)
    if users is None:
        return self.set_operator(name)
    try:
        login = users.login(str(name or "").strip(), str(password or ""))
    except PermissionError as exc:
        self.ctx.error(exc, "Log in")
        return False
    self.ctx.user, self.ctx.role = login.user, login.role
    self.set_operator(login.user)
    self.ctx.set("users", "content", users_text(self))
    self.ctx.notify("Logged in", f"{login.user} ({login.role})", "info")
    return True

def login_dialog(self: Any, gui: Any) -> None:
    """A station with users: log in with a name and password (or observe without)."""
    modal = gui.add_modal("Log in")
    with modal:
        gui.add_markdown("This station has users: log in to command it (observers see everything).")
        name = gui.add_text("User", "")
        password = gui.add_text("Password", "")

        def go(_: Any) -> None:
            if self.log_in(name.value, password.value):
                modal.close()
        gui.add_button("Log in", color="green").on_click(go)
        gui.add_button("Observe").on_click(lambda _: modal.close())
    run_script(gui, PASSWORD_JS)

def users_action(self: Any, verb: str, **params: Any) -> Any:
    """The admin's Users folder: a user verb as this tab's client (the API refuses everyone but an admin)."""
    try:
        result = self.ctx.commands.invoke(self.ctx.who(), verb, **params)
    except Exception as exc:  # noqa: BLE001 - a refusal or a bad name: said in one sentence
        self.ctx.error(exc, "Users")
        return None
    self.ctx.set("users", "content", users_text(self))
    return result

def users_text(self: Any) -> str:
    try:
        rows = self.ctx.commands.invoke(self.ctx.who(), "users")
    except Exception:  # noqa: BLE001 - not an admin: the list is theirs to see only after logging in as one
        return "Log in as an admin to manage the users."
    return "\n".join(f"- **{u['name']}** ({u['role']})" + (f", tokens: {', '.join(u['tokens'])}" if u["tokens"]
                                                            else "") for u in rows) or "no users"

def users_folder(self: Any, gui: Any) -> None:
    """Users and roles, for an admin (the command API decides; others are told so)."""
    g = self.gui
    with gui.add_folder("Users (admin)", expand_by_default=False):
        g["users"] = gui.add_markdown(users_text(self))
        name = gui.add_text("User name", "")
        role = gui.add_dropdown("Role", ("operator", "programmer", "metrologist", "admin"))
        password = gui.add_text("New password", "")
        label = gui.add_text("Token label", "")
        token = gui.add_text("New token (shown once)", "", disabled=True)
        gui.add_button("Add user").on_click(lambda _: users_action(self, 
            "add_user", name=name.value, role=role.value, password=password.value))
        gui.add_button("Set password").on_click(lambda _: users_action(self, 
            "set_password", name=name.value, password=password.value))
        gui.add_button("Remove user").on_click(lambda _: users_action(self, "remove_user", name=name.value))

        def new_token(_: Any) -> None:
            made = users_action(self, "new_token", name=name.value, label=label.value)
            if made:
                token.value = made
        gui.add_button("New API token").on_click(new_token)
        gui.add_button("Refresh").on_click(lambda _: self.ctx.set("users", "content", users_text(self)))
