"""The viser station app against a real Station on the simulator (in-process, loopback only).

Handlers are driven directly through :class:`cmm.ui.panels.ClientApp` (what
each button calls); a raw WebSocket client stands in for a browser tab so the
per-client GUI is really built. Browser tests (Playwright) live elsewhere.
"""

from __future__ import annotations

import math
import time
import urllib.request

import numpy as np
import pytest
from control_support import wait_idle
import ui_support

pytest.importorskip("viser")

from cmm.ui.ids import parse_ids  # noqa: E402
from cmm.ui.panel_features import nominal_deviation  # noqa: E402
from cmm.ui.feature_drawing import feature_drawing  # noqa: E402
from cmm.ui.scene import SCALE, deviation_colour  # noqa: E402



@pytest.fixture(scope="module")
def app(tmp_path_factory):
    yield from ui_support.station_app(tmp_path_factory, pendant_port=0)


@pytest.fixture()
def operator(app):
    capp = app.add_client(client_id="operator", is_local=True)
    assert capp.take_control()
    yield capp
    capp.release_control()
    app.station.controller.stop(None)
    wait_idle(app.station, 10)


@pytest.fixture()
def unpaced(app):
    """The simulator's clock uncapped for a test that holds no jog: its hits take machine seconds, not wall seconds."""
    with ui_support.unpaced(app.station):
        yield


def _wait_done(status, timeout=30.0, capp=None):
    assert status is not None, capp.messages[-3:] if capp is not None else None
    status.wait(timeout)
    return status


def _above_part(station) -> np.ndarray:
    """A point 30 mm above the sample part's top, over a flat face (part X=60, Y=40)."""
    b = station.measurement.part.mesh.bounds
    local = np.array([60.0, 40.0, b[1][2] + 30.0])
    return station.measurement.part.pose[:3, :3] @ local + station.measurement.part.pose[:3, 3]


def test_page_is_served(app):
    with urllib.request.urlopen(f"http://127.0.0.1:{app.port}/", timeout=10) as r:
        assert r.status == 200
        assert b"<html" in r.read().lower()


def test_browser_tab_gets_its_own_gui(app):
    """A WebSocket client (what the page opens) makes the app build that client's panels."""
    import msgspec
    from viser import _messages

    before = len(app.clients)
    # viser counts a tab as connected once it reports its camera
    with ui_support.viser_tab(app, lambda c: "plot" in c.gui) as (ws, capp):
        assert {"machine", "trace", "plot", "take", "release"} <= set(capp.gui) and "tree" in capp.features.gui
        assert "status" in capp.status.gui and "plan" in capp.measure.gui and "result" in capp.align.gui
        assert capp.is_local  # it came from 127.0.0.1
        assert f"127.0.0.1:{app.pendant.port}/" in capp.gui["pendant"].content  # the pendant, embedded
        capp.refresh()
        assert "| X |" in capp.gui["machine"].content
        assert capp.gui["trace"].value == ""  # the byte trace changes with every poll: sent only when asked for
        capp.live_trace = True
        capp.refresh()
        assert capp.gui["trace"].value  # raw NMC bytes are shown
        assert not capp.control.can_move(capp.client_id)  # a new tab observes
        # a click in the 3D view arrives as a ray; the tab's app picks the part with it
        above = _above_part(app.station)
        click = _messages.ScenePointerMessage("click", tuple(above * SCALE), (0.0, 0.0, -1.0), ((0.5, 0.5),), None)
        ws.send(msgspec.msgpack.encode(click.as_serializable_dict()))
        end = time.monotonic() + 30  # a bound: the pick is handled in viser's thread pool
        while capp.ctx.picked is None and time.monotonic() < end:
            time.sleep(0.02)
        assert capp.ctx.picked is not None and np.allclose(capp.ctx.picked[0].normal, [0, 0, 1])
    end = time.monotonic() + 30
    while len(app.clients) > before and time.monotonic() < end:
        time.sleep(0.05)
    assert len(app.clients) == before


def test_go_to_moves_the_machine(app, operator):
    start = app.station.machine.state.position
    target = start + np.array([3.0, 2.0, -4.0])
    _wait_done(operator.go_to(*target))
    assert np.allclose(app.station.machine.state.position, target, atol=0.0021)
    _, fe = app.following_error_series()  # the shipped SC configuration reads it: the plot has data
    assert all(np.isfinite(f).any() for f in fe)


def test_nan_target_is_an_error_notification_and_no_motion(app, operator):
    before = app.station.machine.state.position
    assert operator.go_to(float("nan"), 10.0, 10.0) is None
    level, title, body = operator.messages[-1]
    assert level == "error" and "not a number" in body
    time.sleep(0.1)
    assert not app.station.machine.busy
    assert np.allclose(app.station.machine.state.position, before, atol=0.0021)  # servo settling of a count is not motion
    operator.go_to(1e6, 0, 0)
    assert "outside the travel" in operator.messages[-1][2]


def test_a_target_field_without_three_finite_numbers_is_refused_with_a_sentence(app, operator):
    before = app.station.machine.state.position
    for value in ((5.0,), (1.0, 2.0), "123", None, (1.0, float("inf"), 3.0)):
        assert operator.go_to(value) is None  # the Go button passes the "Target (mm)" field's value
        level, title, body = operator.messages[-1]
        assert level == "error" and "refused" in title, value
        assert ("three numbers X, Y, Z" in body) if value != (1.0, float("inf"), 3.0) else ("each a finite number" in body), body
    assert not app.station.machine.busy
    assert np.allclose(app.station.machine.state.position, before, atol=0.0021)
    _wait_done(operator.go_to(list(before + [1.0, 0.0, 0.0])))  # three numbers go
    assert np.allclose(app.station.machine.state.position, before + [1.0, 0.0, 0.0], atol=0.0021)


def test_observer_cannot_move(app, operator):
    observer = app.add_client(client_id="observer", is_local=False)
    before = app.station.machine.state.position
    assert observer.go_to(*(before + 1.0)) is None
    observer.jog_hold(0, 1)
    observer.step(0, 1)
    assert not observer.take_control("wrong code")
    assert all(level == "error" for level, _, _ in observer.messages)
    time.sleep(0.15)
    assert not app.station.machine.busy
    assert np.allclose(app.station.machine.state.position, before)
    observer.stop()  # stopping is open to everyone
    assert operator.control.can_move("operator")


def test_jog_hold_moves_and_stops_when_refresh_stops(app, operator):
    st = app.station
    start = st.machine.state.position.copy()
    operator.speed_mode = "probing"
    # held (on_hold at 20 Hz) until X has gone 1 mm: a loaded computer runs this thread's holds late and the
    # dead-man pauses the jog in between, so how far a jog held for a time goes is not asserted
    wall_end = time.monotonic() + 30
    while st.machine.state.position[0] <= start[0] + 1.0:
        assert time.monotonic() < wall_end, "the held jog did not go 1 mm"
        operator.jog_hold(0, 1)
        time.sleep(0.05)
    released = st.machine.state.time  # no more refreshes; no release event either (lost pointer-up). Machine time:
    wall_end = time.monotonic() + 30  # a loaded test machine slows the simulated one down with it
    while st.machine.busy and time.monotonic() < wall_end:
        time.sleep(0.005)
    stopped_after = st.machine.state.time - released
    assert not st.machine.busy
    # the jog-hold pipeline's grace is the machine's dead-man: 0.15 s after the last hold event, plus the braking
    assert stopped_after < st.config.deadman_timeout + 0.15, stopped_after
    x = st.machine.state.position[0]
    time.sleep(0.1)
    assert abs(st.machine.state.position[0] - x) < 0.01  # settled (a count or two of servo settling)


def test_jog_release_event_stops_at_once(app, operator):
    st = app.station
    for _ in range(5):
        operator.jog_hold(1, 1)
        time.sleep(0.04)
    t0 = st.machine.state.time  # the simulator's clock: load on the test machine cannot make the stop look late
    operator.jog_release()
    wall_end = time.monotonic() + 30
    while st.machine.busy and time.monotonic() < wall_end:
        time.sleep(0.005)
    assert not st.machine.busy and st.machine.state.time - t0 < 0.2


def test_step_jog_one_count(app, operator):
    st = app.station
    operator.step_size = "1 count"
    before = st.machine.state.counts[2]
    _wait_done(operator.step(2, -1), 10, operator)
    assert st.machine.state.counts[2] == before - 1


def test_pick_probe_here_and_fit(app, operator, unpaced):
    st = app.station
    above = _above_part(st)
    picked = operator.on_scene_click(above * SCALE, (0.0, 0.0, -1.0))
    assert picked is not None
    hit, nominal = picked
    assert np.allclose(hit.point[:2], above[:2], atol=1e-6)
    target = hit.point
    assert np.allclose(hit.normal, [0, 0, 1])
    assert nominal is not None and nominal.kind == "plane"
    n_before = len(st.measurement.hits)
    _wait_done(operator.probe_here(), 40)
    assert len(st.measurement.hits) == n_before + 1
    assert abs(st.measurement.last_hit.point[2] - target[2]) < 0.01
    for dx, dy in ((6, 0), (6, 6), (0, 6)):  # three more hits on the same face
        p = target + [dx, dy, 0]
        again = operator.pick(p + [0, 0, 30], [0, 0, -1])
        assert again is not None and abs(again[0].point[2] - target[2]) < 1e-9
        _wait_done(operator.probe_here(), 20)
    app.redraw()
    assert set(app.deviations()) == set(st.measurement.hits)
    feature = operator.features.fit("plane", "ls", last_n=4)
    assert feature is not None, operator.messages[-3:]
    assert feature.kind == "plane" and len(feature.hit_ids) == 4
    assert feature.result.form < 0.01
    assert abs(abs(feature.result.normal[2]) - 1) < 1e-4
    text = operator.features.feature_markdown()
    assert "form error" in text and "vs nominal plane" in text
    assert "u (1 sigma): position" in text  # standard uncertainties shown
    app.redraw()
    assert feature.id in app.view._feature_nodes
    # undo removes the last hit; a fit needs the hits it names
    last = max(st.measurement.hits)
    operator.undo()
    assert last not in st.measurement.hits
    assert operator.features.fit("sphere", "ls", ids_text=str(last)) is None
    assert operator.messages[-1][0] == "error"


def test_move_above_a_picked_point_arrives_above_it_without_contact(app, operator):
    """Move above: the tip ends the approach distance plus the tip radius out along the picked surface's normal,
    over the clearance plane, and no probe contact is recorded on the way."""
    st = app.station
    above = _above_part(st)
    hit, _ = operator.on_scene_click(above * SCALE, (0.0, 0.0, -1.0))
    n_hits, n_errors = len(st.measurement.hits), len([e for e in st.measurement.events if e[1] == "contact"])
    _wait_done(operator.move_above(), 40, operator)
    expected = hit.point + (st.config.probe.approach_distance + st.prober.settings.tip_radius) * np.asarray(hit.normal)
    assert np.allclose(st.machine.state.position, expected, atol=0.0021)
    assert len(st.measurement.hits) == n_hits
    assert len([e for e in st.measurement.events if e[1] == "contact"]) == n_errors


def test_pick_miss_and_move_above_without_pick(app):
    capp = app.add_client(client_id="viewer")
    assert capp.pick([0, 0, 200], [0, 0, 1]) is None  # pointing away from everything
    assert capp.messages == []  # no toast: a click into the view to give it the keyboard is no pick either
    assert capp.move_above() is None
    assert capp.messages[-1][0] == "error"


def test_colour_map_and_helpers():
    assert deviation_colour(0.0, 0.01) == deviation_colour(0.004, 0.01)  # within the warning limit: green
    red, blue = deviation_colour(0.05, 0.01), deviation_colour(-0.05, 0.01)
    assert red[0] > 200 and red[2] < 60 and blue[2] > 200 and blue[0] < 60
    assert deviation_colour(math.nan) == (150, 150, 150)
    assert parse_ids("1-3, 7 9") == [1, 2, 3, 7, 9]
    with pytest.raises(ValueError):
        parse_ids("a")
    pts = np.array([[0, 0, 0], [0, 0, 10.0]])
    for kind, geom in (("plane", {"point": [0, 0, 0], "normal": [0, 0, 1]}),
                       ("circle", {"center": [0, 0, 0], "normal": [1, 0, 0], "radius": 5.0}),
                       ("sphere", {"center": [1, 2, 3], "radius": 4.0}),
                       ("cylinder", {"point": [0, 0, 0], "direction": [0, 1, 0], "radius": 3.0}),
                       ("cone", {"apex": [0, 0, 0], "direction": [0, 0, 1], "half_angle": 0.3})):
        drawing = feature_drawing(kind, geom, pts)
        assert drawing is not None and len(drawing.lines) > 0 and len(drawing.patch.faces) > 0, kind
    cone = feature_drawing("cone", {"apex": [0, 0, 0], "direction": [0, 0, 1], "half_angle": 0.3}, pts)
    assert np.allclose(cone.lines.reshape(-1, 3).min(axis=0)[2], 0.0, atol=1e-9)  # from the apex, opening along +z

    from cmm.metrology.pick import NominalFeature
    dev = nominal_deviation("sphere", {"center": [0, 0, 1.0], "radius": 5.002},
                            NominalFeature("sphere", {"center": [0, 0, 0], "radius": 5.0}))
    assert dev["centre_offset"] == pytest.approx(1.0) and dev["radius_dev"] == pytest.approx(0.002)


def test_probe_node_follows_micrometre_moves(app, operator):
    """A 1-count move reaches the scene's probe node unquantised (node positions are float64)."""
    st = app.station
    operator.step_size = "1 count"
    _wait_done(operator.step(0, 1), 10)
    at_machine = lambda: np.allclose(np.asarray(app.view.probe.position) / SCALE, st.machine.state.position,  # noqa: E731
                                     atol=1e-9)
    end = time.monotonic() + 10.0  # a few updater ticks (the scene's probe moves at most 25 times a second)
    while not at_machine() and time.monotonic() < end:
        time.sleep(0.01)
    assert at_machine()
    assert app.updater.pushes > 0


def test_status_bar_auto_measure_and_feature_tree(app, operator, unpaced):
    """The status bar's read-out, a face measured from a pick (plan, run), and the tree's verdicts."""
    from cmm.ui.panel_features import tree_html, typed_nominal
    from cmm.ui.panel_status import status_html

    st = app.station
    text = status_html(st.controller.commands, operator.ctx.control_text(), frame="Machine", link_rate=100.0)
    x, y, z = st.machine.state.position
    mode = str(st.controller.state.mode.value).upper()  # idle, or stopped after the previous test's STOP
    assert f">{mode}</span>" in text and f"X {x:.4f}" in text and "link <span class=''>ok" in text
    assert "SILENT" in status_html(st.controller.commands, "", link_rate=0.0)
    assert "probe Probe1 <span" in text  # no calibration folder given: the list's first probe, named
    part = status_html(st.controller.commands, "", frame="Part")
    assert "no alignment made" in part
    above = _above_part(st)
    assert operator.pick(above, [0, 0, -1]) is not None
    plan = operator.measure.make_plan(3)
    assert plan is not None and plan.kind == "plane" and len(plan) == 3
    assert "3 hits · clearance plane" in operator.measure.text()
    assert operator.measure.run(name="top face", wait=True), operator.messages[-2:]
    feature = operator.measure.feature
    assert feature.name == "top face" and len(feature.hit_ids) == 3 and feature.nominal.kind == "plane"
    tree = tree_html(st.controller.commands, feature.id)
    assert "▶" in tree and "top face" in tree and "flatness" in tree and ">pass<" in tree
    with pytest.raises(Exception, match="no diameter"):
        typed_nominal(feature, diameter=10.0)
    # an observer cannot run a measurement
    viewer = app.add_client(client_id="viewer-2")
    viewer.ctx.picked = operator.ctx.picked
    viewer.measure.make_plan()
    assert viewer.measure.run() is False and viewer.messages[-1][1] == "Not in control"
    assert "only observes" in viewer.messages[-1][2]  # the core's refusal, in its words
    # the page sends the verb without judging access itself: the core refuses and the tab shows why
    before = len(st.measurement.features)
    viewer.features.construct("distance", feature.id, feature.id)
    assert viewer.messages[-1][1] == "Construct refused" and "only observes" in viewer.messages[-1][2]
    assert len(st.measurement.features) == before


def test_a_new_pick_drops_the_plan_of_the_face_picked_before(app, operator):
    """Plan on the top, then a click on the front face: the page must not show the top's plan under the front's
    name, and Run must not measure the top (the face no longer picked); Plan again plans the front."""
    st = app.station
    assert operator.pick(_above_part(st), [0, 0, -1]) is not None
    top = operator.measure.make_plan(3)
    assert top is not None and "top face" in operator.measure.text() and "3 hits · clearance" in operator.measure.text()
    part = st.measurement.part
    lo, hi = part.mesh.bounds
    front = part.pose[:3, :3] @ [60.0, lo[1] - 40.0, lo[2] + 0.3 * (hi[2] - lo[2])] + part.pose[:3, 3]
    assert operator.pick(front, part.pose[:3, :3] @ [0, 1, 0]) is not None
    text = operator.measure.text()
    assert "front face" in text and "then Plan" in text and "clearance plane" not in text, text
    hits_before = len(st.measurement.hits)
    assert operator.measure.run() is False
    assert operator.messages[-1][1] == "Auto-measure" and "plan a measurement of the picked face" in operator.messages[-1][2]
    assert len(st.measurement.hits) == hits_before
    plan = operator.measure.make_plan(3)
    assert plan is not None and plan is not top
    towards = part.pose[:3, :3] @ [0, 1, 0]  # onto the front face: along the part's +Y
    assert all(np.dot(u, towards) > 0.999 for u in plan.approaches), plan.approaches
    operator.ctx.clear_pick()
    assert operator.measure.run() is False and "click a face of the part" in operator.messages[-1][2]


def test_a_tab_is_told_when_control_is_taken_from_it_and_a_hit_is_retaken(app, operator, unpaced):
    """Another local client takes over: the previous holder gets an alert. Re-take: the next hit replaces
    the chosen one in the selected feature, which refits."""
    st = app.station
    assert operator.pick(_above_part(st), [0, 0, -1]) is not None
    plan = operator.measure.make_plan(3)
    assert operator.measure.run(wait=True), operator.messages[-2:]
    feature = operator.measure.feature
    operator.select_feature(feature.id)
    old = feature.hit_ids[1]
    operator.features.retake_hit(old)
    assert operator.features.retake is not None
    p, u = plan.points[1], plan.approaches[1]
    _wait_done(st.measurement.probe(p, u, client=operator.ctx.who()), 40)
    operator.features.refresh()
    refit = st.measurement.features[feature.id]
    assert old not in refit.hit_ids and len(refit.hit_ids) == 3 and old not in st.measurement.hits
    assert refit.hit_ids[1] == max(st.measurement.hits)
    operator.refresh()
    other = app.add_client(client_id="second-operator", is_local=True)
    assert other.take_control()
    operator.refresh()
    assert operator.messages[-1][:2] == ("error", "Control taken"), operator.messages[-2:]
    other.release_control()


def test_a_failing_tab_refresh_is_logged_and_the_refresher_keeps_the_other_tabs_alive(app, caplog):
    """One tab whose refresh raises: the failure is logged once (not swallowed, not a log line 20 times a second)
    and the refresher goes on refreshing the other tabs."""
    broken = app.add_client(client_id="broken")
    fine = app.add_client(client_id="fine")
    calls = []

    def fail():
        raise RuntimeError("a widget went away")
    broken.fast_refresh = fail
    fine.fast_refresh = lambda: calls.append(1)
    before = app.refresh_errors
    try:
        with caplog.at_level("ERROR", logger="cmm.ui.app"):
            end = time.monotonic() + 30
            while (app.refresh_errors < before + 5 or len(calls) < 5) and time.monotonic() < end:
                time.sleep(0.05)
        assert app.refresh_errors >= before + 5 and len(calls) >= 5 and app._refresher.is_alive()
        logged = [r for r in caplog.records if "a widget went away" in (r.exc_text or "")
                  or (r.exc_info and "a widget went away" in str(r.exc_info[1]))]
        assert len(logged) == 1 and "status bar" in logged[0].getMessage()
    finally:
        with app._clients_lock:
            for key in [k for k, c in app.clients.items() if c in (broken, fine)]:
                del app.clients[key]
