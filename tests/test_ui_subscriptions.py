"""The page follows the station through the command API's subscriptions, not by polling the queries itself: each
tab's status bar and DRO (20 Hz) and its plain read-outs (5 Hz) are subscribers of ``api.subscribe``. No browser:
a tab is opened over viser's WebSocket (``ui_support.viser_tab``)."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import ui_support

pytest.importorskip("viser")

from cmm.api import CommandAPI  # noqa: E402
from cmm.control.roles import RolePolicy  # noqa: E402
from cmm.ui.feed import Feed  # noqa: E402


def _until(condition, timeout=30.0, what="the condition"):
    """Wait for ``condition()`` (a bound, not a timing assertion: the page's threads deliver on their own)."""
    end = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < end, f"{what} did not happen within {timeout:g} s"
        time.sleep(0.02)


@pytest.fixture()
def app(stations):
    return stations.app(stations.station(), pendant=False, ask_name=False)


def test_each_tab_subscribes_and_its_dro_follows_a_move_as_an_anonymous_observer(app):
    """A tab subscribes twice (the status bar's and the read-outs') as its own client, an anonymous observer on a
    station with roles (the queries are open to observers); its DRO follows a move and the subscriptions end when
    the tab goes."""
    hub = app.api._subscriptions
    before = hub.count()
    app.api.roles = RolePolicy()  # a station with users: this tab logged nobody in
    with ui_support.viser_tab(app) as (_ws, capp):
        assert hub.count() == before + 2
        assert capp.ctx.who().user is None and not capp.control.can_move(capp.client_id)
        feed = capp.status.feed
        assert feed is not None and feed.snapshot() is not None  # the bar opened with the machine in it
        with ui_support.viser_tab(app) as (_ws2, other):
            assert hub.count() == before + 4 and other.status.feed is not feed
        _until(lambda: hub.count() == before + 2, what="the second tab's subscriptions ending")
        assert other.status.feed.closed and other.ctx.readouts.closed

        here = np.asarray(app.api.invoke(None, "position", frame="machine"), float)
        target = here + [6.25, 4.5, -3.125]
        delivered = feed.deliveries
        done = app.api.call(None, "move", {"target": target.tolist(), "frame": "machine"}, wait=True, timeout=60)
        assert done.ok, done.error
        reached = np.asarray(app.api.invoke(None, "position", frame="machine"), float)
        dro = "".join(f"<span>{n} {v:.4f}</span>" for n, v in zip("XYZ", reached))
        _until(lambda: dro in capp.status.gui["status"].content, what="the DRO showing the position reached")
        assert feed.deliveries > delivered  # it came with the subscription's deliveries
        assert np.allclose([a["mm"] for a in feed.query("state")["machine"]["axes"]], reached)
        assert "aria-label='DRO machine'" in capp.status.gui["status"].content
        capp.status.set_frame("Part")  # part coordinates: the position query of the same subscription
        part = np.asarray(feed.query("position"), float)
        assert f"X {part[0]:.4f}" in capp.status.gui["status"].content
    _until(lambda: hub.count() == before, what="the tab's subscriptions ending")
    assert feed.closed


def test_a_failing_query_is_told_once_and_the_last_good_value_stays():
    """A subscribed query that fails arrives once as its error: the tab is told (the page logs it once), its last
    good value stays and the snapshot recovers with the query."""
    api = CommandAPI()
    answer = {"value": 1, "fail": False}

    def value(client):
        if answer["fail"]:
            raise RuntimeError("the store went away")
        return answer["value"]
    api.register("value", value, {}, "a number", query=True)
    api.register("other", lambda client: "same", {}, "a constant", query=True)
    updates, errors = [], []
    heard = threading.Event()

    def update(snapshot):
        updates.append(snapshot)
        heard.set()
    feed = Feed(api, None, {"value": {}, "other": {}}, 50.0, update, lambda q, m: (errors.append((q, m)), heard.set()))
    try:
        assert feed.wait() == {"value": 1, "other": "same"}
        answer["fail"] = True
        _until(lambda: errors, what="the failure told")
        time.sleep(0.1)  # several more polls of the failing query
        assert errors == [("value", "the store went away")] and feed.snapshot() == {"value": 1, "other": "same"}
        answer.update(fail=False, value=2)
        _until(lambda: feed.snapshot() == {"value": 2, "other": "same"}, what="the recovery")
        assert updates[-1] == {"value": 2, "other": "same"}
    finally:
        feed.close()
    assert api._subscriptions.count() == 0


def test_the_pages_close_ends_its_tabs_subscriptions(app):
    hub = app.api._subscriptions
    before = hub.count()
    model = app.station.measurement
    assert app._on_model_event in model._listeners  # the page hears the model's changes
    with ui_support.viser_tab(app) as (_ws, capp):
        assert hub.count() == before + 2
        app.close()  # the page closes while the tab is open
        assert hub.count() == before and capp.status.feed.closed and capp.ctx.readouts.closed
    assert app._on_model_event not in model._listeners  # and no longer


def test_a_tab_built_before_the_first_delivery_reads_the_query_itself():
    """A tab's widgets are made from the feed at once; when the hub has not come round yet (a busy computer: the
    first snapshot was late and the tab's Probe panel failed to build, KeyError), the feed answers with the query."""
    api = CommandAPI()
    hub_may_go = threading.Event()
    api.register("slow", lambda client: hub_may_go.wait(30) and "late", {}, "held up", query=True)
    api.register("probe_data", lambda client: {"tip": 2.0}, {}, "the probe's data", query=True)
    feed = Feed(api, None, {"slow": {}, "probe_data": {}}, 50.0, lambda snapshot: None)
    try:
        assert feed.snapshot() is None  # nothing delivered: the hub waits on the first query
        assert feed.query("probe_data") == {"tip": 2.0}
        hub_may_go.set()
        _until(lambda: feed.snapshot() is not None, what="the first delivery")
        assert feed.snapshot() == {"slow": "late", "probe_data": {"tip": 2.0}}
    finally:
        hub_may_go.set()
        feed.close()
