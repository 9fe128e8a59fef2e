"""`cmm serve --ippdme [ADDR:PORT]`: the I++ DME server beside the browser station, on the same station."""

from __future__ import annotations

from typing import Any

from ..control.access import is_loopback_host
from .backend import StationBackend
from .server import IppServer, parse_address


def start(api: Any, address: str, *, user: tuple[str, str] | None = None) -> IppServer:
    """Start the I++ DME server on the station's command API ``api``; raises ValueError/OSError with an operator's
    message. The caller hands the server's :class:`~cmm.ippdme.status.IppStatus` (connected client, current
    command, measured points) to the station for the browser (``station.serving_ippdme(server.status)``).
    """
    host, port = parse_address(address)
    try:
        # the operator chose this address at start-up: its clients take control without an access code
        server = IppServer(StationBackend(api, grants_control=True, user=user), host, port).start()
    except OSError as exc:
        raise OSError(f"cannot listen for I++ DME clients on {host}:{port}: {exc}") from None
    print(f"I++ DME server on {server.address}: point PC-DMIS, CALYPSO, ... at this address (one client at a time)")
    if not is_loopback_host(host):
        print("I++ DME: listening beyond this PC; anyone on the network can connect and move the machine")
    return server
