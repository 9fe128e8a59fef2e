"""Grants that let the station page's embedded pendant act as that page's client (one operator, one control).

The station page embeds the pendant in an iframe. Without a grant the pendant
is a client of its own and shows "observer" although the page holds control.
So the page asks for a grant bound to its viser client and puts the token into
the iframe URL's fragment (``#as=TOKEN``: never sent in an HTTP request, so it
is in no log or Referer). The pendant sends it in its ``hello``; the pendant
server then runs that connection as the page's client: the page's control,
its local / access-code standing, its STOP rights.

What keeps another tab out:

- the WebSocket handshake passes the same Origin / Host checks as before
  (:class:`cmm.control.access.OriginPolicy`): a page from another origin never gets to send a token;
- the token is 144 random bits, compared in constant time;
- it is bound to the network address the page connected from;
- one pendant connection at a time may use it (a second is refused while the
  first is open; the embedded pendant's own reconnect works after a close);
- it dies with the page's viser connection (:meth:`Grants.revoke`), and the
  pendant connections that used it are closed then.

Taking control itself is unchanged: :class:`~cmm.control.access.Control` decides,
with the access code rules of :mod:`cmm.control.access`.
"""

from __future__ import annotations

import hmac
import secrets
import threading
from dataclasses import dataclass
from typing import Any, Callable


@dataclass(eq=False)
class Grant:
    owner: Callable[[], Any]  # the page's client now (cmm.control.Client: id, local, authenticated)
    peer: str | None  # the page's network address; the pendant must come from the same one
    claimed: bool = False
    hold: Callable[[str], Any] | None = None  # a held page button's label -> (velocity, armed): its hold refresher


class Grants:
    """Thread-safe registry of the embedded pendants' grants."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._grants: dict[str, Grant] = {}

    def issue(self, owner: Callable[[], Any], peer: str | None, hold: Callable[[str], Any] | None = None) -> str:
        token = secrets.token_urlsafe(18)
        with self._lock:
            self._grants[token] = Grant(owner, peer, hold=hold)
        return token

    def revoke(self, token: str | None) -> Grant | None:
        with self._lock:
            return self._grants.pop(token, None) if token else None

    def claim(self, token: Any, peer: str | None) -> Grant | str:
        """The grant for ``token`` presented from ``peer``, now in use; else the reason it is refused."""
        if not isinstance(token, str) or not token:
            return "the embedded pendant's grant is missing"
        with self._lock:
            found = None
            for known, grant in self._grants.items():  # constant time per comparison
                if hmac.compare_digest(known.encode(), token.encode()):
                    found = grant
            if found is None:
                return "the embedded pendant's grant is not valid (reload the station page)"
            if found.peer is not None and peer != found.peer:
                return "the embedded pendant's grant belongs to another computer"
            if found.claimed:
                return "the station page's pendant is already open in another frame"
            found.claimed = True
        return found

    def unclaim(self, grant: Grant) -> None:
        with self._lock:
            grant.claimed = False
