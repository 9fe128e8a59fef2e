"""Who may send which command: one pluggable policy, asked once per command by the control core.

A policy is any object with ``refusal(client, command) -> str | None`` (None =
allowed). ``client`` is a :class:`Client` (or a plain id string) naming the
person or program behind a front end (a viser tab, a pendant, an I++ DME
connection), with what the front end knows about its connection (local to the
station PC, authenticated with the access code); ``None`` is the station
itself (scripts, the CLI, the homing cycle). :class:`HolderPolicy` adapts the
UI's single-holder :class:`cmm.ui.access.Control`: only the holder moves the
machine; STOP, E-STOP, cancel and jog release follow its ``may_stop`` policy
(everyone, when the control object has none).
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from typing import Any, Protocol

from .modes import SAFETY_COMMANDS


@dataclass(frozen=True)
class Client:
    id: str
    local: bool = False  # connects from the station PC itself
    authenticated: bool = False  # gave the access code on this connection (or is local)


def client_of(client: Any) -> Client | None:
    if client is None or isinstance(client, Client):
        return client
    return Client(str(client))


class AccessPolicy(Protocol):
    def refusal(self, client: Client | None, command: str) -> str | None: ...


class OpenPolicy:
    """Everything allowed: a station driven by one script or the CLI."""

    def refusal(self, client: Client | None, command: str) -> str | None:
        return None


class HolderPolicy:
    """Only the control holder moves the machine; STOP and E-STOP per ``may_stop`` (default: everyone)."""

    def __init__(self, control: Any) -> None:
        self.control = control
        may_stop = getattr(control, "may_stop", None)
        self._stop_kw = may_stop is not None and "is_local" in inspect.signature(may_stop).parameters

    def refusal(self, client: Client | None, command: str) -> str | None:
        client = client_of(client)
        if client is None:
            return None
        if command in SAFETY_COMMANDS:
            may_stop = getattr(self.control, "may_stop", None)
            if may_stop is None:
                return None
            ok = (may_stop(client.id, is_local=client.local, authenticated=client.authenticated) if self._stop_kw
                  else may_stop(client.id))
            if ok or (command == "jog_release" and self.control.can_move(client.id)):
                return None
            words = getattr(self.control, "stop_refusal", None)
            return words() if words is not None else "this client may not stop the machine (enter the access code)"
        if self.control.can_move(client.id):
            return None
        return "this client only observes: take control first"
