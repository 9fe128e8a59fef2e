"""Which web pages may open the station's WebSockets (viser page and pendant).

Two attacks are closed here, on every port the station serves:

- *Cross-site WebSocket hijacking*: any page open in a browser on the station
  PC (or on the LAN) can open a WebSocket to 127.0.0.1:8080. Browsers always
  send an ``Origin`` header with it; we accept it only when it names the very
  host the browser asked for (``Origin == http://<Host>``), i.e. the page was
  served by the station itself.
- *DNS rebinding*: a page from ``evil.example`` whose name is re-pointed at
  127.0.0.1 passes the test above (its Origin and Host both say
  ``evil.example``). So the ``Host`` itself must be one of the station's own
  names: an IP literal (a page cannot rebind an IP), ``localhost``, this
  computer's host names, or a name the operator allowed (``--allow-host``).

A client that sends no ``Origin`` at all is not a web page (scripts, tests,
the I++ client); it is judged by the access rules like any other client.
"""

from __future__ import annotations

import ipaddress
import logging
import socket
from typing import Any, Iterable, Mapping

log = logging.getLogger(__name__)


def split_host(host_header: str) -> str:
    """The host name of a ``Host`` header, lower case, without port or IPv6 brackets."""
    host = host_header.strip()
    if host.startswith("["):
        host = host[1:host.find("]")] if "]" in host else host[1:]
    elif host.count(":") == 1:
        host = host.split(":", 1)[0]
    return host.lower().rstrip(".")


def is_loopback_host(host_header: str) -> bool:
    host = split_host(host_header)
    if host == "localhost" or host.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def is_loopback_peer(address: Any) -> bool:
    """True when a socket peer address ``(ip, port, ...)`` is on the loopback interface."""
    host = address[0] if isinstance(address, (tuple, list)) and address else address
    if not isinstance(host, str):
        return False
    try:
        ip = ipaddress.ip_address(host.split("%", 1)[0])
    except ValueError:
        return host == "localhost"
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return ip.is_loopback


def own_names() -> set[str]:
    """This computer's host names as LAN browsers may type them."""
    names = set()
    for fn in (socket.gethostname, socket.getfqdn):
        try:
            name = fn().lower().rstrip(".")
        except OSError:
            continue
        if name:
            names.update({name, f"{name.split('.', 1)[0]}.local"})
    return names


class OriginPolicy:
    """Decide whether a WebSocket handshake (its headers) may come in."""

    def __init__(self, *, lan: bool = False, allow_hosts: Iterable[str] = ()) -> None:
        self.lan = lan
        self.names = {"localhost"} | {split_host(h) for h in allow_hosts if h}
        if lan:
            self.names |= own_names()
        self.refused: list[str] = []  # reasons, newest last (shown in logs and tests)

    def host_allowed(self, host_header: str) -> bool:
        host = split_host(host_header)
        if not host:
            return False
        try:
            ip = ipaddress.ip_address(host)
        except ValueError:
            return host in self.names or host.endswith(".localhost")
        return ip.is_loopback or self.lan  # an IP literal cannot be rebound by a foreign page

    def check(self, headers: Mapping[str, str]) -> str | None:
        """None when the connection may proceed, else the reason it is refused."""
        host = headers.get("Host") or ""
        if not self.host_allowed(host):
            return (f"refused a connection for unknown host {host!r}: open the station by its address "
                    "(or start it with --allow-host NAME)")
        origin = headers.get("Origin")
        if origin is not None and origin.rstrip("/").lower() not in (f"http://{host}".lower(), f"https://{host}".lower()):
            return f"refused a connection from another web page ({origin}): only the station's own pages may control it"
        return None

    def refuse(self, reason: str) -> None:
        self.refused.append(reason)
        del self.refused[:-50]
        log.warning("%s", reason)


def guard_viser(server: Any, policy: OriginPolicy) -> set[int]:
    """Close every viser WebSocket whose headers the policy refuses, before viser reads a message from it.

    viser has no public handshake hook, so this puts a connect callback first in
    its websocket server's list: those callbacks are awaited before the
    connection's message consumer starts, so a refused page never gets a
    message in or out. Returns the set of refused client ids (the app skips
    them). Raises if the viser version lacks the hook: the station must not
    serve an unguarded control port.
    """
    ws = getattr(server, "_websock_server", None)
    callbacks = getattr(ws, "_client_connect_cb", None)
    live = getattr(ws, "_live_connections", None)
    if not isinstance(callbacks, list) or not isinstance(live, dict):
        raise RuntimeError("this viser version does not expose its connection hooks: the station cannot check "
                           "the origin of browser connections; install a supported viser version")
    refused: set[int] = set()

    async def check(client: Any) -> None:
        connection = live.get(client.client_id)
        request = getattr(connection, "request", None)
        reason = "refused a connection without a handshake" if request is None else policy.check(request.headers)
        if reason is None:
            return
        refused.add(client.client_id)
        policy.refuse(reason)
        if connection is not None:
            await connection.close(1008, reason[:120])

    callbacks.insert(0, check)
    return refused
