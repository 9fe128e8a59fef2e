"""Who calls the API: every call is made as a client (a front end's connection), or as ``None``, the station itself.

A :class:`Client` is what a front end knows of its connection: its id, whether it sits at the station PC, whether
it gave the access code, the listener it came through and who logged in on it. The API hands it to the role check
and to every verb; the control core's access rules (:mod:`cmm.control.access`) decide with it who holds control and
who may stop. A plain string is a client id with nothing else known.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Client:
    id: str
    local: bool = False  # connects from the station PC itself
    authenticated: bool = False  # gave the access code on this connection (or is local)
    # came through a listener the operator opened for programs that command the machine (the I++ DME port, its
    # address chosen at start-up): that decision stands in for the access code when it takes control
    listener_grants_control: bool = False
    # who logged in on this connection (a station with a user file, cmm.control.users): the name every message and
    # record carries, and the role cmm.control.roles checks; None: nobody logged in
    user: str | None = None
    role: str | None = None


def client_of(client: Any) -> Client | None:
    if client is None or isinstance(client, Client):
        return client
    return Client(str(client))


class AccessRefused(PermissionError):
    """Control (or a stop, or a verb for the client's role) refused, with the reason an operator reads."""
