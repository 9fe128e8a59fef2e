"""Cross-site WebSocket hijacking and DNS rebinding: only the station's own pages may drive it.

A raw WebSocket client plays the attacking page: it can set any ``Origin`` and
``Host`` a browser would send for a foreign page. The same script, sent with
the station's own origin, does take control (so the refusals are not a
broken script).
"""

from __future__ import annotations

import json
import socket
import struct
import time
import urllib.request
from typing import Any

import numpy as np
import pytest
from netutil import SIM_PACED

pytest.importorskip("viser")

import msgspec  # noqa: E402
import viser  # noqa: E402
import zstandard  # noqa: E402
from viser import _messages  # noqa: E402
from websockets.exceptions import ConnectionClosed, InvalidStatus  # noqa: E402
from websockets.sync.client import connect  # noqa: E402

from cmm.control.access import Control  # noqa: E402
from cmm.control.access import OriginPolicy, is_loopback_peer  # noqa: E402


def test_policy_rules():
    local = OriginPolicy()
    assert local.check({"Host": "127.0.0.1:8080", "Origin": "http://127.0.0.1:8080"}) is None
    assert local.check({"Host": "localhost:8080", "Origin": "http://localhost:8080"}) is None
    assert local.check({"Host": "[::1]:8080", "Origin": "http://[::1]:8080"}) is None
    assert local.check({"Host": "127.0.0.1:8080"}) is None  # a script, not a web page
    assert "another web page" in local.check({"Host": "127.0.0.1:8080", "Origin": "http://evil.example"})
    assert "another web page" in local.check({"Host": "127.0.0.1:8080", "Origin": "null"})
    assert "another web page" in local.check({"Host": "127.0.0.1:8080", "Origin": "http://127.0.0.1:9999"})
    rebinding = {"Host": "evil.example:8080", "Origin": "http://evil.example:8080"}
    assert "unknown host" in local.check(rebinding)
    assert "unknown host" in local.check({"Origin": "http://127.0.0.1:8080"})
    assert local.check({"Host": "192.168.1.20:8080", "Origin": "http://192.168.1.20:8080"}) is not None  # not on the LAN
    lan = OriginPolicy(lan=True, allow_hosts=["cmm-station.shop"])
    assert lan.check({"Host": "192.168.1.20:8080", "Origin": "http://192.168.1.20:8080"}) is None
    assert lan.check({"Host": "cmm-station.shop:8080", "Origin": "http://cmm-station.shop:8080"}) is None
    assert lan.check({"Host": f"{socket.gethostname()}:8080", "Origin": f"http://{socket.gethostname()}:8080"}) is None
    assert "unknown host" in lan.check(rebinding)
    assert is_loopback_peer(("::ffff:127.0.0.1", 5, 0, 0)) and not is_loopback_peer(("10.0.0.1", 5))


@pytest.fixture(scope="module")
def app(module_stations):
    return module_stations.app(module_stations.station(home=False, port=SIM_PACED), pendant_port=0)


def _walk(obj: Any):
    if isinstance(obj, dict):
        yield obj
        for v in obj.values():
            yield from _walk(v)
    elif isinstance(obj, (list, tuple)):
        for v in obj:
            yield from _walk(v)


def decode_frame(raw: bytes) -> Any:
    """viser's wire frame: two little-endian u64 sizes, zstd-compressed msgpack, then raw buffers."""
    size, packed = struct.unpack_from("<QQ", raw, 0)
    payload = zstandard.ZstdDecompressor().decompress(raw[16:16 + packed], max_output_size=size)
    return msgspec.msgpack.decode(payload)


def attack(port: int, *, origin: str | None, host: str | None = None, seconds: float = 30.0,
           until: Any = lambda: False) -> dict:
    """What a page does to take control: open viser's socket, find 'Take control', click it.

    Returns how far it got: the messages it received and whether it clicked.
    """
    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
    uri = f"ws://{host or f'127.0.0.1:{port}'}/"
    out = {"messages": 0, "clicked": False, "closed": None}
    try:
        with connect(uri, sock=sock, origin=origin, subprotocols=[f"viser-v{viser.__version__}"],
                     open_timeout=30) as ws:
            camera = _messages.ViewerCameraMessage((1.0, 0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1.0, 0.01, 100.0, 600,
                                                   800, (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
            try:
                ws.send(msgspec.msgpack.encode(camera.as_serializable_dict()))
            except ConnectionClosed as exc:
                out["closed"] = exc.rcvd.code if exc.rcvd else None
                return out
            end = time.monotonic() + seconds
            button = None
            next_click = 0.0
            while time.monotonic() < end and not (out["clicked"] and until()):
                if button is not None and time.monotonic() >= next_click:
                    # the page clicks again until it works (its first click may beat the button's handler)
                    click = _messages.GuiUpdateMessage(button, {"value": True})
                    ws.send(msgspec.msgpack.encode(click.as_serializable_dict()))
                    out["clicked"] = True
                    next_click = time.monotonic() + 0.5
                try:
                    raw = ws.recv(timeout=0.1)
                except TimeoutError:
                    continue
                except ConnectionClosed as exc:
                    out["closed"] = exc.rcvd.code if exc.rcvd else None
                    return out
                out["messages"] += 1
                for d in _walk(decode_frame(raw)):
                    props = d.get("props")
                    if isinstance(props, dict) and props.get("label") == "Take control" and "uuid" in d:
                        button = d["uuid"]
            time.sleep(0.5)
    except InvalidStatus as exc:
        out["closed"] = exc.response.status_code
    return out


def _wait_released(app, timeout: float = 10.0) -> None:
    end = time.monotonic() + timeout
    while app.control.holder is not None and time.monotonic() < end:
        time.sleep(0.05)
    assert app.control.holder is None  # a closed tab gives control back


def test_the_stations_own_page_can_take_control(app):
    """The control case: the attack script works when the Origin is the station's own."""
    holders = []  # the tab releases control when its socket closes: look while it is open
    result = attack(app.port, origin=f"http://127.0.0.1:{app.port}",
                    until=lambda: holders.append(app.control.holder) or holders[-1] is not None)
    assert result["clicked"], result
    assert any(h is not None and h.startswith("viser-") for h in holders), (result, holders[-3:])
    _wait_released(app)


@pytest.mark.parametrize("origin,host", [
    ("http://evil.example", None),                      # another page open in the operator's browser
    ("null", None),                                     # a sandboxed iframe or a file:// page
    ("http://evil.example:{port}", "evil.example:{port}"),  # DNS rebinding: the page's name points at us
])
def test_a_foreign_page_is_refused_before_any_message(app, origin, host):
    before = len(app.clients)
    position = app.station.machine.state.position.copy()
    origin = origin.format(port=app.port)
    result = attack(app.port, origin=origin, host=host.format(port=app.port) if host else None, seconds=3.0)
    assert result["closed"] == 1008 and result["messages"] == 0 and not result["clicked"], result
    assert app.control.holder is None
    assert len(app.clients) <= before and not set(app.clients) & app._refused  # no panels were built for it
    assert any(origin in r or "unknown host" in r for r in app.origins.refused)
    assert np.allclose(app.station.machine.state.position, position, atol=0.0021)


def test_the_pendant_port_refuses_foreign_pages_too(app):
    from websockets.sync.client import connect as ws_connect

    url = app.pendant.ws_url
    with pytest.raises(InvalidStatus) as info:
        ws_connect(url, origin="http://evil.example", open_timeout=5)
    assert info.value.response.status_code == 403
    port = app.pendant.port
    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
    with pytest.raises(InvalidStatus) as info:
        ws_connect(f"ws://evil.example:{port}/ws", sock=sock, origin=f"http://evil.example:{port}", open_timeout=5)
    assert info.value.response.status_code == 403
    with ws_connect(url, origin=f"http://127.0.0.1:{port}", open_timeout=30) as ws:  # its own page is welcome
        ws.send('{"type": "hello"}')
        kinds = [json.loads(ws.recv(timeout=5))["type"] for _ in range(5)]
        assert "hello" in kinds


def test_page_still_served(app):
    with urllib.request.urlopen(f"http://127.0.0.1:{app.port}/", timeout=10) as r:
        assert r.status == 200
