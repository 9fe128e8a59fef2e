"""The TLS-terminating proxy of `cmm serve --tls` (cmm/control/tls_proxy.py): real https and wss clients on
127.0.0.1 that verify the station's self-signed certificate reach a real websockets server (the kind viser runs:
http and its WebSocket on one port) through it; nothing is served in clear on the public port; a LAN peer naming
this PC's loopback as its host is refused (it would otherwise count as the station PC behind the proxy)."""

from __future__ import annotations

import asyncio
import http.client
import socket
import ssl
import threading

import pytest

from cmm.control import tls
from cmm.control.tls_proxy import TlsProxy
from netutil import WssClient, free_port

websockets = pytest.importorskip("websockets")


@pytest.fixture
def backend():
    """A websockets server on loopback: GET /page answers over http, / upgrades to a WebSocket that echoes."""
    from websockets.asyncio.server import serve
    from websockets.datastructures import Headers
    from websockets.http11 import Response

    port = free_port()
    seen: list[str] = []
    forwarded: list[list[str]] = []
    ready, stop = threading.Event(), {}

    def page(connection, request):
        seen.append(request.headers.get("Host", ""))
        forwarded.append(request.headers.get_all("X-Forwarded-For"))
        if request.path == "/page":
            body = b"<html>the station page</html>"
            return Response(200, "OK", Headers({"Content-Type": "text/html", "Content-Length": str(len(body))}),
                            body)
        return None

    async def echo(ws):
        async for message in ws:
            await ws.send(f"echo {message}")

    async def main():
        loop = asyncio.get_running_loop()
        stop["future"] = loop.create_future()
        stop["loop"] = loop
        async with serve(echo, "127.0.0.1", port, process_request=page, open_timeout=60):  # as patient as the page
            ready.set()
            await stop["future"]

    thread = threading.Thread(target=asyncio.run, args=(main(),), daemon=True)
    thread.start()
    assert ready.wait(30)
    yield port, seen, forwarded
    stop["loop"].call_soon_threadsafe(stop["future"].set_result, None)
    thread.join(10)


def test_https_and_wss_reach_the_page_through_the_proxy_with_the_stations_certificate(backend, tmp_path):
    port, seen, forwarded = backend
    cert = tls.certificate(tmp_path / "tls")  # self-signed, made now: 127.0.0.1 among its names
    proxy = TlsProxy(cert, "127.0.0.1", free_port(), port).start()
    try:
        trusted = ssl.create_default_context(cafile=str(cert.cert_path))  # verifies the chain and the address
        conn = http.client.HTTPSConnection("127.0.0.1", proxy.port, context=trusted, timeout=60)
        conn.request("GET", "/page", headers={"X-Forwarded-For": "10.9.9.9"})  # a client's own claim
        answer = conn.getresponse()
        assert answer.status == 200 and answer.read() == b"<html>the station page</html>"
        conn.close()
        assert forwarded[-1] == ["127.0.0.1"]  # the proxy's word for the peer only (the key of the code's rate limit)
        pem = tmp_path / "seen.pem"  # the certificate a client sees is the one whose fingerprint was printed
        pem.write_text(ssl.get_server_certificate(("127.0.0.1", proxy.port)))
        assert tls.fingerprint(pem) == cert.fingerprint

        try:  # a client whose TLS socket one thread uses (netutil.WssClient says why)
            ws = WssClient(f"wss://127.0.0.1:{proxy.port}/", ssl=trusted, open_timeout=60)
        except Exception as exc:  # what the proxy saw of it
            raise AssertionError(f"the WebSocket through the proxy failed ({exc!r}); the proxy's dropped "
                                 f"connections: {proxy.dropped}, refused: {proxy.refused}") from exc
        with ws:
            for text in ("access code 123456", "x" * 200_000):  # a frame larger than the proxy's chunk
                ws.send(text)
                assert ws.recv(timeout=60) == f"echo {text}"
        assert seen and all(h == f"127.0.0.1:{proxy.port}" for h in seen)  # the Host the browser sent, unchanged
        assert all(f == ["127.0.0.1"] for f in forwarded)  # the WebSocket's upgrade names its peer too
        assert proxy.connections >= 2

        # nothing in clear on the public port: a plain http request gets no page
        with socket.create_connection(("127.0.0.1", proxy.port), timeout=60) as raw:
            raw.sendall(f"GET /page HTTP/1.1\r\nHost: 127.0.0.1:{proxy.port}\r\n\r\n".encode())
            raw.settimeout(60)
            try:
                got = raw.recv(4096)
            except (ConnectionError, socket.timeout):
                got = b""
            assert b"the station page" not in got
    finally:
        proxy.close()


def test_a_lan_peer_naming_the_loopback_as_its_host_is_refused(tmp_path):
    proxy = TlsProxy(None, "0.0.0.0", 0, 1)
    head = b"GET / HTTP/1.1\r\nHost: %s\r\nUpgrade: websocket\r\n\r\n"
    # a LAN browser asks for the station by its address or name: forwarded
    assert proxy.refusal(head % b"192.168.1.20:8080", ("192.168.1.31", 50123)) is None
    assert proxy.refusal(head % b"cmm-7:8080", ("192.168.1.31", 50123)) is None
    # a LAN peer claiming localhost would be "the station PC" behind the proxy: refused in a sentence
    why = proxy.refusal(head % b"localhost:8080", ("192.168.1.31", 50123))
    assert why == ("refused a request from 192.168.1.31 for host 'localhost:8080': open the station by its LAN "
                   "address or name")
    assert proxy.refusal(head % b"127.0.0.1:8080", ("::ffff:192.168.1.31", 50123, 0, 0)) is not None
    assert proxy.refusal(b"GET / HTTP/1.1\r\n\r\n", ("192.168.1.31", 50123)) is not None  # no Host at all
    # the station PC itself through the proxy: as it is
    assert proxy.refusal(head % b"127.0.0.1:8080", ("127.0.0.1", 50123)) is None


def test_the_proxy_names_each_peer_and_the_station_keys_the_code_limit_by_it():
    """Behind the proxy every connection comes from 127.0.0.1: the proxy forwards each LAN peer's address (a
    client's own X-Forwarded-For or Forwarded line dropped), and the station reads it only when it is behind its
    own proxy, from a loopback peer; a LAN client connecting directly cannot choose its rate-limit key."""
    from cmm.control.access import Control, forwarded_peer
    from cmm.control.tls_proxy import forwarded_head

    head = (b"GET / HTTP/1.1\r\nHost: cmm-7:8443\r\nX-Forwarded-For: 10.0.0.1\r\nforwarded: for=10.0.0.2\r\n"
            b"Upgrade: websocket\r\n\r\n")
    assert forwarded_head(head, ("192.168.1.31", 50123)) == (
        b"GET / HTTP/1.1\r\nHost: cmm-7:8443\r\nUpgrade: websocket\r\nX-Forwarded-For: 192.168.1.31\r\n\r\n")
    headers = {"X-Forwarded-For": "192.168.1.31"}
    assert forwarded_peer(("127.0.0.1", 40000), headers, True) == ("192.168.1.31", 0)
    assert forwarded_peer(("127.0.0.1", 40000), headers, False) == ("127.0.0.1", 40000)  # not behind the proxy
    assert forwarded_peer(("192.168.1.40", 40000), headers, True) == ("192.168.1.40", 40000)  # not from the proxy
    assert forwarded_peer(("127.0.0.1", 40000), {"X-Forwarded-For": "not an address"}, True) == ("127.0.0.1", 40000)
    # the rate limit per LAN client: a wrong code from one does not lock out the next one
    control = Control(access_code="open-sesame")
    one, two = (forwarded_peer(("127.0.0.1", 40000 + k), {"X-Forwarded-For": f"192.168.1.{31 + k}"}, True)[0]
                for k in range(2))
    assert control.try_take("a", "guess", peer=one) == "wrong access code: control refused"
    assert control.try_take("a", "open-sesame", peer=one).startswith("too many wrong access codes: wait")
    assert control.try_take("b", "open-sesame", peer=two) is None and control.holder == "b"


def test_cmm_serve_tls_puts_the_page_and_the_pendant_behind_the_proxy(tmp_path_factory):
    """The wiring of `cmm serve --tls` (cli/serve.py tls_proxies): the page and the pendant on loopback, each
    served over https on its public port with the station's certificate; the page addresses its embedded pendant
    (and its jog-hold socket) at the pendant's public https address."""
    import ui_support
    from cmm.cli.serve import tls_proxies
    from netutil import SIM

    cert = tls.certificate(tmp_path_factory.mktemp("tls"))
    gen = ui_support.station_app(tmp_path_factory, port=SIM, home=False)
    app = next(gen)
    try:
        page_port = free_port()
        proxies = tls_proxies(app, cert, "127.0.0.1", page_port, None)
        try:
            assert [p.port for p in proxies] == [page_port, page_port + 1]
            assert app.behind_tls_proxy and app.pendant.behind_tls_proxy  # both read the forwarded address
            assert app.pendant_src(None) == f"https://127.0.0.1:{page_port + 1}/"
            assert {page_port, page_port + 1} <= app.origins.ports
            trusted = ssl.create_default_context(cafile=str(cert.cert_path))
            for port in (page_port, page_port + 1):
                conn = http.client.HTTPSConnection("127.0.0.1", port, context=trusted, timeout=60)
                conn.request("GET", "/")
                answer = conn.getresponse()
                assert answer.status == 200 and b"<html" in answer.read().lower()
                conn.close()
        finally:
            for p in proxies:
                p.close()
    finally:
        gen.close()
