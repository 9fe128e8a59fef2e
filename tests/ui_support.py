"""The UI tests' shared pieces: a station with its viser app as a module fixture, and a tab opened over viser's
own WebSocket (the page's protocol, without a browser) whose panels are built on the station's side."""

from __future__ import annotations

import time
from contextlib import contextmanager
from typing import Any, Callable, Iterator

from netutil import SIM_PACED

# A tab's panels are built by the station in the background when its page says hello; on a loaded machine that
# has taken seconds. A bound, not a pause: the wait ends as soon as the tab is built.
TAB_BUILT_S = 60.0


def station_app(tmp_path_factory: Any, *, port: str = SIM_PACED, session: str | None = None, home: bool = True,
                station: dict | None = None, **ui: Any) -> Iterator[Any]:
    """A module fixture's body: ``yield from ui_support.station_app(tmp_path_factory, pendant=False)`` gives a
    homed station on the simulator (``port``; ``station``: more Station arguments; ``session``: the session it
    starts) with its StationApp on a free 127.0.0.1 port (``ui``: StationApp's options), both closed after the
    module."""
    from stations import Stations

    with Stations(lambda: tmp_path_factory.mktemp("sessions")) as built:
        yield built.app(built.station(session, home=home, port=port, **(station or {})), **ui)


@contextmanager
def unpaced(station: Any) -> Iterator[None]:
    """The simulator's clock uncapped (as fast as the CPU allows) inside the block, for a test whose moves and hits
    no wall-time action meets (no jog held): they take machine seconds, not wall seconds. The module's pace again
    after."""
    network = station.sim.network
    pace = network.pace
    network.set_pace(None)
    try:
        yield
    finally:
        network.set_pace(pace)


def _all_panels(capp: Any) -> bool:
    return "records" in capp.calibration.gui  # the calibration panel is the last one a tab builds


@contextmanager
def viser_tab(app: Any, built: Callable[[Any], bool] = _all_panels, timeout: float = TAB_BUILT_S) -> Iterator[tuple]:
    """A tab opened as a page opens it (viser's WebSocket and its first camera message); yields ``(ws, capp)``
    once the station has built the tab's panels (``built(capp)``), and keeps the socket open until the block
    ends."""
    import msgspec
    import viser
    from viser import _messages
    from websockets.sync.client import connect

    before = set(app.clients)
    # max_queue=None: the socket's reader keeps taking what the station sends (as a page does) however long the test
    # leaves it unread; with a bounded queue it stops reading, never sees the station's close frame and the close
    # waits out its 10 s time-out
    with connect(f"ws://127.0.0.1:{app.port}", subprotocols=[f"viser-v{viser.__version__}"], max_queue=None) as ws:
        camera = _messages.ViewerCameraMessage((1.0, 0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1.0, 0.01, 100.0, 600, 800,
                                               (0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
        ws.send(msgspec.msgpack.encode(camera.as_serializable_dict()))
        end = time.monotonic() + timeout
        capp = None
        while capp is None:
            assert time.monotonic() < end, f"the tab's panels were not built within {timeout:g} s"
            drain(ws, 0.1)
            new = [c for k, c in app.clients.items() if k not in before and c.client is not None]
            capp = new[0] if new and built(new[0]) else None
        yield ws, capp


def drain(ws: Any, seconds: float) -> None:
    """Read (and drop) what the station sends the tab for up to ``seconds``."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            ws.recv(timeout=max(0.0, end - time.monotonic()))
        except TimeoutError:
            return
