"""`cmm serve --opcua [ADDR:PORT]`: the OPC UA server (OPC 40210 GMS) beside the browser station."""

from __future__ import annotations

from typing import Any

from ..control.access import is_loopback_host

DEFAULT = "127.0.0.1:4840"


def parse_address(address: str) -> tuple[str, int]:
    """"ADDR:PORT", ":PORT" or "ADDR" (port 4840) -> (host, port); ValueError in the operator's words."""
    text = (address or DEFAULT).strip()
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = text, "4840"
    host = host.strip("[]") or "127.0.0.1"
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"--opcua wants ADDR:PORT (e.g. 127.0.0.1:4840), got {address!r}") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"--opcua: port {number} is not between 0 and 65535")
    return host, number


def start(api: Any, address: str, *, name: str = "CMM", authenticate: Any = None, client_factory: Any = None,
          certificate: Any = None, rate: float = 10.0) -> Any:
    """Start the OPC UA server on the command API ``api``; raises ValueError/OSError with an operator's message."""
    from .server import OpcUaServer

    host, port = parse_address(address)
    server = OpcUaServer(api, host, port, name=name, authenticate=authenticate, client_factory=client_factory,
                         certificate=certificate, rate=rate).start()
    print(f"OPC UA server (OPC 40210 GMS) on {server.url}: Objects/Machines/{name}; anonymous clients read, "
          "users log in to write and call methods")
    if not is_loopback_host(host) and certificate is None:
        print("OPC UA: listening beyond this PC without encryption (start with --tls for Basic256Sha256)")
    return server
