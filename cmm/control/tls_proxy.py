"""A TLS-terminating proxy for the station's web pages: https / wss on the LAN, plain http / ws on loopback.

The viser page has no TLS of its own (viser 1.x serves http and its WebSocket on one port, without an SSL
option), so ``cmm serve --tls`` runs the page on a loopback port and this proxy on the public address: it
accepts TLS with the station's certificate (:mod:`cmm.control.tls`), reads the first request's head, and then
forwards the bytes both ways unchanged (an HTTP request, or a WebSocket upgrade and its frames). The access
code and the users' passwords therefore never cross the LAN in clear.

Behind the proxy every connection comes from 127.0.0.1, and the page tells "at the station PC" from "on the
LAN" by a loopback peer that asked for a loopback host name; the proxy names each client's own address in an
``X-Forwarded-For`` header (any the client sent is dropped), which the page and the pendant, knowing they are
behind it, read for the access-code rate limit and the local test. The proxy also refuses (421) a request from a LAN
peer whose ``Host`` names this PC's loopback (``localhost``, ``127.0.0.1``): a LAN browser never sends one, and
letting it through would make that browser local. A request from a loopback peer passes as it is.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from typing import Any

from .access import FORWARDED_FOR, is_loopback_host, is_loopback_peer

log = logging.getLogger(__name__)
HEAD_LIMIT = 64 * 1024  # bytes of a request head
HEAD_TIMEOUT = 30.0  # s a client has to send its request head
CHUNK = 64 * 1024


class TlsProxy:
    """``TlsProxy(certificate, host, port, backend_port).start()``; ``close()`` stops it; ``url`` is its address."""

    def __init__(self, certificate: Any, host: str, port: int, backend_port: int, *,
                 backend_host: str = "127.0.0.1", name: str = "page") -> None:
        self.certificate = certificate
        self.host, self.port = host, int(port)
        self.backend = (backend_host, int(backend_port))
        self.name = name
        self.connections = 0  # accepted and forwarded
        self.refused: list[str] = []  # why requests were refused (the last 50)
        self.dropped: list[str] = []  # connections that ended before a request head came (the last 50), and why
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: asyncio.AbstractServer | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._failure: BaseException | None = None

    @property
    def url(self) -> str:
        shown = "127.0.0.1" if self.host in ("0.0.0.0", "", "::") else self.host
        return f"https://{shown}:{self.port}/"

    def start(self, timeout: float = 30.0) -> "TlsProxy":
        self._thread = threading.Thread(target=self._run, name=f"tls-proxy-{self.name}", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout):
            raise OSError(f"the TLS proxy for the {self.name} did not start within {timeout:.0f} s")
        if self._failure is not None:
            raise OSError(f"cannot serve the {self.name} over TLS on {self.host}:{self.port}: {self._failure}")
        return self

    def close(self, timeout: float = 5.0) -> None:
        loop = self._loop
        if loop is not None and not loop.is_closed():
            loop.call_soon_threadsafe(loop.stop)
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        try:
            self._server = loop.run_until_complete(asyncio.start_server(
                self._serve, self.host, self.port, ssl=self.certificate.ssl_context(), reuse_address=True,
                ssl_handshake_timeout=HEAD_TIMEOUT))
            if self.port == 0:
                self.port = self._server.sockets[0].getsockname()[1]
        except BaseException as exc:  # noqa: BLE001 - told to start()
            self._failure = exc
            self._ready.set()
            loop.close()
            return
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            self._server.close()
            for task in asyncio.all_tasks(loop):
                task.cancel()
            loop.run_until_complete(asyncio.sleep(0))
            loop.close()

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        try:
            try:
                head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), HEAD_TIMEOUT)
            except (asyncio.IncompleteReadError, asyncio.LimitOverrunError, asyncio.TimeoutError,
                    ConnectionError) as exc:
                why = {asyncio.TimeoutError: f"no request head within {HEAD_TIMEOUT:g} s",
                       asyncio.IncompleteReadError: "closed before its request head"}.get(type(exc), repr(exc))
                self.dropped.append(f"{peer}: {why}")  # a certificate check or a port scan closes before it
                del self.dropped[:-50]
                log.debug("TLS connection from %s ended: %s", peer, why)
                return
            why = self.refusal(head, peer)
            if why is not None:
                self.refused.append(why)
                del self.refused[:-50]
                log.warning("%s", why)
                body = (why + "\n").encode()
                writer.write(b"HTTP/1.1 421 Misdirected Request\r\nContent-Type: text/plain; charset=utf-8\r\n"
                             + f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n".encode() + body)
                await writer.drain()
                return
            try:
                back_reader, back_writer = await asyncio.open_connection(*self.backend)
            except OSError as exc:
                log.warning("the %s behind the TLS proxy does not answer: %s", self.name, exc)
                writer.write(b"HTTP/1.1 502 Bad Gateway\r\nContent-Length: 0\r\nConnection: close\r\n\r\n")
                await writer.drain()
                return
            self.connections += 1
            back_writer.write(forwarded_head(head, peer))
            await asyncio.gather(_pipe(reader, back_writer), _pipe(back_reader, writer))
        except (ConnectionError, OSError, asyncio.CancelledError):
            pass
        finally:
            writer.close()

    def refusal(self, head: bytes, peer: Any) -> str | None:
        """Why a request head from ``peer`` is refused: a LAN peer naming this PC's loopback as its host."""
        if is_loopback_peer(peer):
            return None
        host = ""
        for line in head.split(b"\r\n")[1:]:
            key, sep, value = line.partition(b":")
            if sep and key.strip().lower() == b"host":
                host = value.strip().decode("latin-1")
                break
        if not host or is_loopback_host(host):
            where = peer[0] if isinstance(peer, (tuple, list)) and peer else peer
            return (f"refused a request from {where} for host {host or '(none)'!r}: open the station by its LAN "
                    "address or name")
        return None


def forwarded_head(head: bytes, peer: Any) -> bytes:
    """The request head as the page receives it: the client's own X-Forwarded-For / Forwarded lines dropped and
    the proxy's X-Forwarded-For with the peer's address added, so the station keys the access-code rate limit
    (and tells local from LAN) by each LAN client, not by the proxy's 127.0.0.1 that all of them share."""
    lines = head[:-4].split(b"\r\n") if head.endswith(b"\r\n\r\n") else head.split(b"\r\n")
    dropped = {FORWARDED_FOR.lower().encode(), b"forwarded"}
    kept = [lines[0]] + [ln for ln in lines[1:] if ln.partition(b":")[0].strip().lower() not in dropped]
    address = peer[0] if isinstance(peer, (tuple, list)) and peer else str(peer or "")
    kept.append(f"{FORWARDED_FOR}: {address}".encode("latin-1"))
    return b"\r\n".join(kept) + b"\r\n\r\n"


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while True:
            data = await reader.read(CHUNK)
            if not data:
                break
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError):
        pass
    finally:
        try:
            if writer.can_write_eof():
                writer.write_eof()
            else:
                writer.close()
        except (OSError, RuntimeError):
            writer.close()
