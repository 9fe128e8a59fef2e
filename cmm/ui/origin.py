"""The viser port's handshake guard: every browser connection passes :class:`cmm.control.access.OriginPolicy`
before viser reads a message from it."""

from __future__ import annotations

from typing import Any

from ..control.access import OriginPolicy


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
