"""The pendant server against a real station on the real-time simulator, over loopback WebSockets."""

from __future__ import annotations

import json
import time
import urllib.error
import urllib.request

import pytest
from browser_moves import JogRecord
from browser_support import stop_time, wait_until
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from cmm.ui import pendant as pendant_mod
from cmm.control.access import Control
from cmm.ui.pendant import start_pendant_server

pytestmark = pytest.mark.timeout(60)

STOP_WITHIN = 0.3  # s from the last message to zero velocity (0.2 s dead-man budget + deceleration + sampling)
# Times are the simulator's (the station runs on its paced virtual clock): a loaded test machine slows the
# simulated machine down with everything else instead of making it look slow to stop.


@pytest.fixture
def station(stations):
    # homed on the uncapped clock (2 machine s), then paced (as netutil.SIM_PACED): the tests' wall-time jog
    # refreshes meet the dead-man
    return stations.station(pace=1.0)


def _serve(station, control):
    station.controller.use_policy_of(control)  # as the composition root (StationApp) wires it
    return start_pendant_server(station.controller.commands, control, "127.0.0.1", 0)


@pytest.fixture
def control(station):
    return Control(access_code="open-sesame", on_holder_lost=lambda _cid: station.controller.jog_release(None))


@pytest.fixture
def server(station, control):
    handle = _serve(station, control)
    yield handle
    handle.close()


class Client:
    """A blocking pendant client that remembers what the server said."""

    def __init__(self, url: str, clock=time.monotonic) -> None:
        self.ws = connect(url, open_timeout=30, close_timeout=2)
        self.messages: list[dict] = []
        self.clock = clock  # the station's simulated time

    def send(self, **msg) -> None:
        self.ws.send(json.dumps(msg))

    def drain(self, seconds: float = 0.0) -> list[dict]:
        end = time.monotonic() + seconds
        while True:
            try:
                self.messages.append(json.loads(self.ws.recv(timeout=max(0.0, end - time.monotonic()))))
            except TimeoutError:
                return self.messages

    def drain_until(self, done, what: str, timeout: float = 60.0) -> list[dict]:
        """Read messages until ``done()`` (about them) holds."""
        end = time.monotonic() + timeout
        while not done():
            assert time.monotonic() < end, f"{what} did not come within {timeout} s; got {self.messages[-5:]}"
            self.drain(0.05)
        return self.messages

    def wait_for(self, kind: str, timeout: float = 3.0) -> dict:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                msg = json.loads(self.ws.recv(timeout=end - time.monotonic()))
            except TimeoutError:
                break
            self.messages.append(msg)
            if msg.get("type") == kind:
                return msg
        raise AssertionError(f"no {kind!r} message within {timeout} s; got {self.messages[-5:]}")

    def errors(self) -> list[str]:
        return [m["message"] for m in self.messages if m.get("type") == "error"]

    def jog_for(self, v, seconds: float, period: float = 0.05) -> float:
        """Send a jog every ``period`` until ``seconds`` of the station's (simulated) time have passed; returns
        the simulated time of the last one. Machine time, not wall time: on a loaded computer the paced
        simulator runs slower, and a jog held for wall seconds would cover less distance."""
        first = last = self.clock()
        give_up = time.monotonic() + 30 * seconds + 5  # a station that stopped publishing fails the test, not hangs
        while last - first < seconds and time.monotonic() < give_up:
            self.send(type="jog", v=v)
            last = self.clock()
            self.drain(period)
        return last

    def jog_until(self, v, done, what: str, timeout: float = 60.0, period: float = 0.05) -> None:
        """Hold the jog (a refresh every ``period``) until ``done()`` says the machine did what was meant. A person's
        refreshes on a loaded computer come late and the dead-man pauses the jog in between: how far a jog held
        for a time goes is not the pendant's to promise, so the tests hold it until the machine has gone far enough."""
        end = time.monotonic() + timeout
        while not done():
            assert time.monotonic() < end, f"{what} did not happen within {timeout} s; got {self.messages[-5:]}"
            self.send(type="jog", v=v)
            self.drain(period)

    def close(self) -> None:
        self.ws.close()


@pytest.fixture
def client(server, station):
    clients: list[Client] = []

    def make() -> Client:
        c = Client(server.ws_url, clock=lambda: now(station))
        clients.append(c)
        return c

    yield make
    for c in clients:
        c.close()


def speed(station) -> float:
    return max(abs(a.velocity) for a in station.machine.state.axes)


def now(station) -> float:
    """The station's clock: simulated seconds of the last published state."""
    return station.machine.state.time


def time_to_stop(station, since: float) -> float:
    """Simulated seconds from ``since`` (simulated) until every axis stands still."""
    return stop_time(station, since, "the stop after the last message")


# --- HTTP ---------------------------------------------------------------------------


def test_serves_the_page_and_script(server):
    assert server.url.startswith("http://127.0.0.1:") and server.ws_url.endswith("/ws")
    with urllib.request.urlopen(server.url, timeout=5) as r:
        assert r.headers["Content-Type"].startswith("text/html")
        assert b"pendant.js" in r.read()
    with urllib.request.urlopen(server.url + "pendant.js", timeout=5) as r:
        assert r.headers["Content-Type"].startswith("text/javascript")
        assert b"getGamepads" in r.read()
    with pytest.raises(urllib.error.HTTPError) as e:
        urllib.request.urlopen(server.url + "../pyproject.toml", timeout=5)
    assert e.value.code == 404


def test_refuses_websocket_from_another_origin(server):
    with pytest.raises(InvalidStatus) as e:
        connect(server.ws_url, origin="http://evil.example", open_timeout=5)
    assert e.value.response.status_code == 403
    own = connect(server.ws_url, origin=server.url.rstrip("/"), open_timeout=30)
    own.close()


# --- control ----------------------------------------------------------------------------


def test_hello_reports_speeds_and_state(server, station, client):
    c = client()
    c.send(type="hello")
    hello = c.wait_for("hello")
    s = station.config.speeds
    assert hello["speeds"] == {"jog_fast": s.jog_fast, "jog_slow": s.jog_slow, "jog_fine": s.jog_fine}
    assert hello["local"] is True and hello["deadman_ms"] == round(station.config.deadman_timeout * 1000)
    state = c.wait_for("state")
    assert state["control"] is False and state["holder"] is None
    assert state["pos"] == pytest.approx(list(station.machine.state.position), abs=1e-3)


def test_observer_cannot_jog(server, station, control, client):
    c = client()
    c.send(type="hello")
    start = station.machine.state.position.copy()
    c.jog_for([20, 20, 0], 0.4)
    c.drain_until(lambda: any("not in control" in e for e in c.errors()), "the refusal")
    assert speed(station) == 0
    assert (station.machine.state.position == start).all()
    assert control.holder is None


def test_button_holds_come_only_from_a_station_pages_hold_refresher(server, station, control, client):
    """A plain pendant (no page grant with a hold refresher) cannot send a page's button holds, even in control."""
    c = client()
    c.send(type="take")
    c.wait_for("control")
    c.send(type="hold", button="hold X +")
    assert "hold refresher" in c.wait_for("error")["message"]
    time.sleep(0.2)
    assert speed(station) == 0


def test_remote_pendant_needs_the_code(server, station, control, client, monkeypatch):
    monkeypatch.setattr(pendant_mod, "is_local_connection", lambda _addr, _host=None: False)  # pretend it is on the LAN
    c = client()
    c.send(type="hello", code="guess")
    c.wait_for("error")
    assert "wrong access code" in c.errors()[-1]
    c.send(type="stop")  # an anonymous LAN observer may not stop a measurement it cannot see
    c.wait_for("error")
    assert "stop refused" in c.errors()[-1]
    start = station.machine.state.position.copy()
    c.jog_for([20, 0, 0], 0.3)
    assert (station.machine.state.position == start).all() and control.holder is None
    time.sleep(0.25)  # past the access-code rate limit (one attempt per 0.2 s)
    c.send(type="take", code="open-sesame")
    assert c.wait_for("control")["control"] is True
    assert control.holder is not None and control.holder.startswith("pendant-")


def test_loopback_only_server_refuses_remote_pendants(station, monkeypatch):
    monkeypatch.setattr(pendant_mod, "is_local_connection", lambda _addr, _host=None: False)
    control = Control()  # no --lan: no code at all
    with _serve(station, control) as srv:
        c = Client(srv.ws_url)
        c.send(type="take", code="anything")
        c.wait_for("error")
        assert "--lan" in c.errors()[-1]
        c.close()
    assert control.holder is None


def test_holder_jogs_and_release_stops(server, station, client):
    c = client()
    c.send(type="hello", code=None)  # local: no code needed
    assert c.wait_for("control")["control"] is True
    start = station.machine.state.position.copy()
    with JogRecord(station) as rec:
        c.jog_until([20, 10, 0], lambda: (station.machine.state.position - start)[0] > 4, "4 mm of +X")
        c.drain_until(lambda: any(m["type"] == "state" for m in c.messages), "a state")
        moved = station.machine.state.position - start
        assert moved[1] > 1 and abs(moved[2]) < 1e-6, moved  # X and Y together, Z still
        assert abs(moved[0] / moved[1] - 2) < 0.1, moved  # on the line the jog asked for
        state = [m for m in c.messages if m["type"] == "state"][-1]
        assert state["control"] is True and state["holder"] == "you"
        let_go = now(station)
        c.send(type="release")
        released, t, _rest = rec.stop_after_release(let_go, "the release")
    assert t < STOP_WITHIN


def test_silence_stops_the_jog(server, station, client):
    c = client()
    c.send(type="take")
    c.wait_for("control")
    x0 = station.machine.state.position[0]
    with JogRecord(station) as rec:
        c.jog_until([20, 0, 0], lambda: station.machine.state.position[0] > x0 + 2, "2 mm of +X")
        # no release, no message: the dead-man stops it, counted from when the station heard the last refresh
        last = max(rec.heard)
        assert rec.standstill_after(last, "the silence") < STOP_WITHIN
        wait_until(lambda: rec.deadman, 60.0, "the dead-man's event")  # told through the dispatcher thread
    assert not rec.releases


def test_closing_the_socket_stops_the_jog_and_releases_control(server, station, control, client):
    c = client()
    c.send(type="take")
    c.wait_for("control")
    with JogRecord(station) as rec:
        c.jog_until([20, 0, 0], lambda: speed(station) > 1.0, "the jog")
        c.ws.close()
        # the closed socket releases the jog; at the latest the dead-man stops it after the last refresh heard
        assert rec.standstill_after(max(rec.heard), "the closed socket") < STOP_WITHIN
    end = time.monotonic() + 2
    while control.holder is not None and time.monotonic() < end:
        time.sleep(0.01)
    assert control.holder is None


def test_stop_message(server, station, client):
    c = client()
    c.send(type="take")
    c.wait_for("control")
    with JogRecord(station) as rec:
        c.jog_until([20, 0, 0], lambda: speed(station) > 1.0, "the jog")
        c.send(type="stop")
        wait_until(lambda: rec.stops, 60.0, "the STOP reaching the station")
        assert rec.standstill_after(rec.stops[0], "the STOP") < STOP_WITHIN
    observer = client()  # a local pendant that does not hold control may still press stop
    observer.send(type="stop")
    observer.drain(0.2)
    assert observer.errors() == []


def test_jog_is_validated_and_clamped(server, station, client):
    c = client()
    c.send(type="take")
    c.wait_for("control")
    for bad in ([1, 2], ["1", 0, 0], [float("nan"), 0, 0], None, [True, 0, 0]):
        c.send(type="jog", v=bad)
        c.wait_for("error")
        assert "three finite velocities" in c.errors()[-1]
        c.messages.clear()
        time.sleep(ERROR_GAP)
    assert speed(station) == 0
    fast = station.config.speeds.jog_fast
    with JogRecord(station) as rec:
        c.jog_until([1000, 0, 0], lambda: speed(station) > fast * 0.9, "the clamped jog at speed")
        c.drain(0.2)  # and on at it
        _t, _pos, speeds = rec.arrays()
    one_count_per_tick = 1953.125 / station.config.axes[0].counts_per_mm  # the module reports whole counts a tick
    assert speeds.max() <= fast + one_count_per_tick + 1e-6  # never faster than the fastest jog speed
    assert not [e for e in c.errors() if "jog" in e and "finite" not in e]
    notices = [m["message"] for m in c.messages if m.get("type") == "notice"]
    assert len(notices) == 1 and "1000 mm/s limited" in notices[0]  # clamped, said once, not 20 times a second
    c.send(type="release")
    time_to_stop(station, now(station))
    c.ws.send("not json")
    c.wait_for("error")
    c.send(type="dance")
    assert "unknown" in c.wait_for("error")["message"]


ERROR_GAP = pendant_mod.ERROR_INTERVAL + 0.05


def _notices(c) -> list[str]:
    return [m["message"] for m in c.messages if m.get("type") == "notice"]


def test_a_jog_at_the_end_of_the_travel_says_why_it_does_not_start_or_stops(server, station, client):
    """Homed, X and Y stand at their minimum (0 mm) and Z at its maximum: a jog there says so, never nothing."""
    c = client()
    c.send(type="take")
    c.wait_for("control")
    start = station.machine.state.position.copy()
    c.send(type="jog", v=[-20, 0, 0])
    assert c.wait_for("error")["message"] == "X is at the end of its travel (0 mm): it can only jog +X"
    c.drain(0.2)
    assert speed(station) == 0
    time.sleep(ERROR_GAP)
    c.messages.clear()
    # +X runs; -Y would leave the travel: left out, and said once
    c.jog_until([20, -10, 0], lambda: station.machine.state.position[0] > start[0] + 0.5, "0.5 mm of +X")
    c.drain_until(lambda: _notices(c), "the notice")
    c.drain(0.1)
    notices = _notices(c)
    assert notices == ["Y is at the end of its travel (0 mm): it can only jog +Y. The jog runs on the other axes."]
    moved = station.machine.state.position - start
    assert moved[0] > 0.5 and moved[1] == pytest.approx(0.0, abs=0.002), moved
    c.send(type="release")
    time_to_stop(station, now(station))
    c.messages.clear()
    c.jog_for([1e308, 0, 0], 0.2)  # an absurd speed runs at the fastest jog speed, and says so
    c.drain_until(lambda: [n for n in _notices(c) if "1e+308 mm/s limited to the fastest jog speed" in n], "the clamp")
    c.send(type="release")
    time_to_stop(station, now(station))
    time.sleep(ERROR_GAP)
    c.messages.clear()
    end = time.monotonic() + 60  # back to X = 0: the travel clips the jog, and then refuses it
    while not c.errors() and time.monotonic() < end:
        c.jog_for([-40, 0, 0], 0.1)
    assert "X reached the end of its travel: the jog stops there" in _notices(c)
    assert c.errors() and c.errors()[0] == "X is at the end of its travel (0 mm): it can only jog +X"
    assert station.machine.state.position[0] == pytest.approx(0.0, abs=0.006)



def test_takeover_stops_the_previous_holders_jog(server, station, control, client):
    a, b = client(), client()
    a.send(type="take")
    a.wait_for("control")
    a.jog_until([20, 0, 0], lambda: speed(station) > 1.0, "the jog")
    b.send(type="take")  # the person at the machine takes over
    b.wait_for("control")
    a.jog_for([20, 0, 0], 0.3)  # a keeps pushing: refused
    a.drain_until(lambda: any("not in control" in e for e in a.errors()), "the refusal")
    assert speed(station) == 0
    assert control.holder is not None and b.wait_for("state")["holder"] == "you"


def test_observe_gives_control_back(server, station, control, client):
    c = client()
    c.send(type="take")
    c.wait_for("control")
    c.send(type="observe")
    assert c.wait_for("control")["control"] is False
    assert control.holder is None


def test_close_with_connected_clients(station, control):
    srv = _serve(station, control)
    c = Client(srv.ws_url)
    c.send(type="take")
    c.wait_for("control")
    c.jog_for([20, 0, 0], 0.2)
    srv.close()
    assert time_to_stop(station, now(station)) < 1.0
    assert control.holder is None


def test_a_grant_makes_the_pendant_act_as_the_page_and_only_from_its_computer(server, client, control):
    """A station page's grant: the pendant that presents it acts as the page's client (shares its control, does
    not release it when it closes); a grant issued to another computer's page is refused from this one."""
    from cmm.control import Client as Who

    page = Who("viser-7", local=True, authenticated=True)
    assert control.take(page.id, is_local=True)
    token = server.grants.issue(lambda: page, "127.0.0.1")
    embedded = client()
    embedded.send(type="hello", **{"as": token})
    hello = embedded.wait_for("hello")
    assert hello["shared"] is True and hello["client"] == "viser-7"
    state = embedded.wait_for("state")
    assert state["control"] is True and state["holder"] == "you"
    second = client()  # the same grant in another connection while the first uses it
    second.send(type="hello", **{"as": token})
    assert second.wait_for("hello")["shared"] is False
    assert any("already open" in e for e in second.errors())  # the refusal comes before the hello answer
    embedded.close()
    time.sleep(0.3)
    assert control.holder == "viser-7"  # the page keeps its control when its pendant frame goes
    remote = server.grants.issue(lambda: Who("viser-8"), "192.0.2.10")
    thief = client()
    thief.send(type="hello", **{"as": remote})
    assert "another computer" in thief.wait_for("error")["message"]
    server.revoke(token)
    late = client()
    late.send(type="hello", **{"as": token})
    assert "not valid" in late.wait_for("error")["message"]


def test_observer_is_told_the_holders_name(server, station, control, client):
    """A holder who gave their name (the browser's start dialog) is named in the pendant's state."""
    assert control.take("viser-named", is_local=True)
    try:
        c = client()
        c.send(type="hello")
        state = c.wait_for("state")
        assert state["holder"] == "other" and state["holder_name"] is None  # no name given: the pendant says "another client"
        control.set_name("viser-named", "Maria")
        end = time.monotonic() + 10
        while state.get("holder_name") != "Maria" and time.monotonic() < end:
            state = c.wait_for("state")
        assert state["holder_name"] == "Maria"
    finally:
        control.release("viser-named")


def test_a_stop_whose_thread_fails_hands_the_error_to_the_waiting_page():
    """The pendant runs a stop on a thread of its own and awaits it; when that thread fails, the awaiting
    coroutine gets the error. (The callback binds the error when it is scheduled: an except clause's name is
    deleted when its block ends, so a callback the loop ran after that found nothing and the page's STOP would
    wait forever; a race the loop usually won.)"""
    import asyncio
    import types

    def boom():
        raise RuntimeError("the modules did not answer")

    async def page_waits():
        server = types.SimpleNamespace(_loop=asyncio.get_running_loop())
        await asyncio.wait_for(pendant_mod.PendantServer._own_thread(server, boom), timeout=30)

    with pytest.raises(RuntimeError, match="did not answer"):
        asyncio.run(page_waits())
