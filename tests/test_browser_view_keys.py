"""Keyboard jog in the 3-D view, in headless chromium at 1280 x 800 on the simulator (paced virtual clock: the
keys' refreshes are wall-time and meet the machine's dead-man).

A click in the view gives it the keyboard focus, and the page shows it (a blue frame, the "Keyboard jog" badge);
a held arrow jogs the machine through the one jog pipeline and letting go stops it; when a key can do nothing the
view says why: in FAULT, with the E-STOP latched, when the page only observes, at the end of the travel. The
pendant page says why too (FAULT)."""

from __future__ import annotations

import numpy as np
import pytest

import browser_support as bs
import session_support as sup
from netutil import SIM_PACED
from ui_support import unpaced

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(600),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")

LAPTOP = (1280, 800)


@pytest.fixture(scope="module")
def station(module_stations):
    return module_stations.station("keys", port=SIM_PACED)


@pytest.fixture(scope="module")
def app(station):
    yield from bs.station_app(station, pendant_port=0)


def _velocity(station):
    return np.array([a.velocity for a in station.machine.state.axes])


def _badge(page):
    return page.locator("#cmm-view-keys")


def _press_until_told(page, key, words, what):
    """Hold ``key`` until the view's message has ``words`` (the refusal comes back from the station), let go."""
    page.keyboard.down(key)
    try:
        bs.wait_until(lambda: words in _badge(page).inner_text(), 20.0, what)
    finally:
        page.keyboard.up(key)


def test_keyboard_jog_in_the_view_with_the_focus_shown_and_every_refusal_said(app, station):
    with bs.browser_context(LAPTOP) as context:
        page = bs.open_page(context, app)
        capp = page.capp
        assert capp.take_control()
        _badge(page).wait_for()
        assert "Click the 3-D view" in _badge(page).inner_text()
        bs.focus_view(page)
        badge = _badge(page)
        bs.wait_until(lambda: "Keyboard jog" in badge.inner_text(), 10.0, "the badge saying the view has the keys")
        outline = page.evaluate("() => getComputedStyle(document.activeElement).outlineStyle")
        assert outline == "solid"  # the focus is visible on the view itself
        bs.screenshot(page, "view-keys-focused")
        # a held arrow jogs +X at the page's speed; letting go stops it
        x0 = station.machine.state.position[0]
        page.keyboard.down("ArrowRight")
        try:
            bs.wait_until(lambda: _velocity(station)[0] > 0, 20.0, "the +X jog")
            assert abs(_velocity(station)[1]) < 1e-9 and abs(_velocity(station)[2]) < 1e-9
        finally:
            page.keyboard.up("ArrowRight")
        sup.standing(station, "the jog stopping on key up")
        assert station.machine.state.position[0] > x0
        # in FAULT a key says why it does nothing, and nothing moves
        station.controller.fault("a test fault")
        bs.wait_until(lambda: station.controller.state.mode.value == "fault", 30.0, "the fault")
        sup.standing(station, "the axes standing in the fault")
        here = station.machine.state.position.copy()
        _press_until_told(page, "ArrowUp", "fault", "the view saying the machine is in fault")
        assert "Reset" in badge.inner_text()
        bs.screenshot(page, "view-keys-fault")
        assert np.allclose(station.machine.state.position, here, atol=0.002)
        capp.reset()
        bs.wait_until(lambda: station.controller.state.mode.value != "fault", 20.0, "the reset")
        # with the E-STOP latched
        capp.emergency_stop()
        bs.wait_until(lambda: station.controller.state.mode.value == "e-stopped", 10.0, "the E-STOP")
        bs.focus_view(page)
        _press_until_told(page, "ArrowLeft", "emergency stop", "the view saying the E-STOP is latched")
        capp.reset()
        bs.wait_until(lambda: station.controller.state.mode.value not in ("e-stopped", "fault"), 20.0, "the reset")
        # an observing page is told to take control
        capp.release_control()
        bs.focus_view(page)
        _press_until_told(page, "PageUp", "Take control", "the view saying this page observes")
        # at the end of the travel (homed, Z stands at its top): +Z says which axis and the way it can go
        assert capp.take_control()
        bs.focus_view(page)
        z_top = station.config.axis("z").max
        assert station.machine.state.position[2] > z_top - 0.005
        _press_until_told(page, "PageUp", "end of its travel", "the view saying Z is at the end of its travel")
        assert "-Z" in badge.inner_text()
        # Esc stops from the view
        page.keyboard.press("Escape")
        bs.wait_until(lambda: "STOP sent" in badge.inner_text(), 60.0, "the view saying STOP was sent")
        bs.wait_until(lambda: station.controller.state.mode.value == "stopped", 60.0, "the STOP from the view")
        # a page whose jog worker is not there (not loaded yet): the key's STOP goes by the STOP button's click
        capp.reset()
        bs.wait_until(lambda: station.controller.state.mode.value == "idle", 60.0, "the machine idle")
        page.evaluate("() => { window.__cmmWorkerKept = window.__cmmHoldWorker; delete window.__cmmHoldWorker; }")
        bs.focus_view(page)
        page.keyboard.press("Escape")
        bs.wait_until(lambda: station.controller.state.mode.value == "stopped", 60.0, "the STOP without the worker")
        page.evaluate("() => { window.__cmmHoldWorker = window.__cmmWorkerKept; }")
        assert page.log.page_errors == []


def test_the_pendant_page_says_why_a_key_does_nothing(app, station):
    with bs.browser_context(LAPTOP) as context:
        pendant = context.new_page()
        pendant.goto(app.pendant.url)
        pendant.get_by_role("button", name="Take control").click()
        bs.shows(pendant, "you have control")
        station.controller.fault("a test fault")
        try:
            bs.wait_until(lambda: "FAULT" in pendant.locator("#motion").inner_text(), 10.0, "the pendant's FAULT")
            pendant.locator("body").click(position={"x": 5, "y": 5})
            pendant.keyboard.down("ArrowRight")
            try:
                bs.wait_until(lambda: "fault" in pendant.locator("#message").inner_text(), 20.0,
                              "the pendant saying the machine is in fault")
            finally:
                pendant.keyboard.up("ArrowRight")
            assert pendant.locator("#message").is_visible()
        finally:
            station.controller.reset(None)
            app.control.release(app.control.holder)


def _click_button(page, name):
    page.get_by_role("button", name=name, exact=True).first.evaluate("b => { b.scrollIntoView({block: 'nearest'}); "
                                                                     "b.click(); }")


def test_the_path_preview_and_the_show_checkboxes_in_the_page(app, station):
    """Plan draws the path the run will take in this tab's 3-D view, Clear path removes it, Run clears it; the
    Features tab's Show checkboxes hide and show the measured feature (the selected one, and by its own row) and its
    kind in the 3-D view."""
    with bs.browser_context(LAPTOP) as context:
        page = bs.open_page(context, app)
        capp = page.capp
        assert capp.take_control()
        pose = station.measurement.part.pose
        top = (pose @ np.array([20.0, 10.0, 100.0, 1.0]))[:3]
        assert capp.pick(top, pose[:3, :3] @ np.array([0.0, 0.0, -1.0])) is not None  # what a click on the top sends
        bs.open_tab(page, "Measure", "Auto-measure")
        _click_button(page, "Plan")
        bs.wait_until(lambda: capp.measure.preview.nodes, 30.0, "the path preview drawn")
        nodes = capp.measure.preview.nodes
        assert set(nodes) == {"rapid", "approach", "retract", "hits"}
        assert len(nodes["hits"].points) == len(capp.measure.plan)
        bs.shows(page, "Path preview:")
        bs.screenshot(page, "path-preview")
        _click_button(page, "Clear path")
        bs.wait_until(lambda: not capp.measure.preview.nodes, 30.0, "the path preview cleared")
        _click_button(page, "Preview path")
        bs.wait_until(lambda: capp.measure.preview.nodes, 30.0, "the path preview drawn again")
        before = set(station.measurement.features)
        with unpaced(station):  # no key is held while the face is measured: its hits in machine seconds, not wall
            _click_button(page, "Run")
            bs.wait_until(lambda: not capp.measure.preview.nodes, 30.0, "Run clearing the preview")
            bs.wait_until(lambda: set(station.measurement.features) - before, 300.0, "the top face measured")
        (fid,) = set(station.measurement.features) - before
        bs.wait_until(lambda: fid in app.view._feature_nodes, 30.0, "the plane drawn")
        node = app.view._feature_nodes[fid]
        assert node.visible and node.patch.opacity <= 0.6
        capp.select_feature(fid)
        bs.open_tab(page, "Measure", "Features")
        page.get_by_text("Show", exact=True).first.evaluate("e => e.click()")  # the Show folder opens
        bs.checkbox(page, "Planes").wait_for(state="attached")
        bs.checkbox(page, "Planes").evaluate("e => e.click()")
        bs.wait_until(lambda: not app.view._feature_nodes[fid].visible, 30.0, "the planes hidden")
        bs.shows(page, "(hidden)")  # the tree says so
        _click_button(page, "Show all")
        bs.wait_until(lambda: app.view._feature_nodes[fid].visible, 30.0, "the planes shown again")
        bs.checkbox(page, "Selected feature").evaluate("e => e.click()")
        bs.wait_until(lambda: not app.view._feature_nodes[fid].visible, 30.0, "the selected feature hidden")
        app.view.show_all()
        # the feature's own row (Show > Each feature), whichever feature is selected
        capp.select_feature(None)
        row = bs.checkbox(page, f"{fid} {station.measurement.features[fid].name}")
        # ticked on both sides: the station's copy of the box too (a click on a page still showing the tick from
        # before the hide, while the station's box already said unticked, changes nothing the station can see)
        bs.wait_until(lambda: capp.features.rows[fid].value and row.count() and row.is_checked(), 30.0,
                      "the feature's row ticked (shown)")
        row.evaluate("e => e.click()")
        bs.wait_until(lambda: not app.view._feature_nodes[fid].visible, 30.0, "the feature hidden by its row")
        bs.shows(page, "(hidden)")  # the tree says so
        app.view.show_all()
