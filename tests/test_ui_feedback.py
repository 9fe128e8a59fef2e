"""The operator's feedback in the station page: names kept, fields that show what they mean, one toast
per event, RUNNING for a whole auto-measure cycle, what was picked said in the Auto-measure tab.

A raw WebSocket client stands in for the browser tab so the tab's widgets really exist; the panels are driven
through what their buttons call, on the simulator.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

import numpy as np
import pytest
from control_support import wait_idle
from netutil import SIM
import ui_support

pytest.importorskip("viser")

from cmm.ui.panel_features import nominal_fields  # noqa: E402
from cmm.ui.panel_measure import face_name  # noqa: E402
from cmm.ui.panel_status import status_html  # noqa: E402


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    # the simulator's clock uncapped: no test here holds a jog, so no wall-time action meets the machine's clock
    # and its auto-measure cycles and homing take machine seconds, not wall seconds
    yield from ui_support.station_app(tmp_path_factory, port=SIM, pendant_port=0)


def _until(predicate, timeout, what):
    end = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.05)


@contextmanager
def browser_tab(app):
    """A tab with its widgets built (the page's WebSocket), in control of the machine."""
    with ui_support.viser_tab(app, lambda c: "plot" in c.gui and "hits" in c.measure.gui) as (_ws, capp):
        assert capp.take_control()
        try:
            yield capp
        finally:
            capp.release_control()
            app.station.controller.stop(None)
            wait_idle(app.station, 10)


def _pick(capp, station, local, outward):
    pose = station.measurement.part.pose
    target = pose[:3, :3] @ np.asarray(local, float) + pose[:3, 3]
    n = pose[:3, :3] @ np.asarray(outward, float)
    assert capp.pick(target + 40 * n, -n) is not None


def test_face_names_and_running_status_between_moves(app):
    assert face_name([0, 0, 1]) == "top" and face_name([0, -1, 0]) == "front" and face_name([-1, 0, 0]) == "left"
    assert face_name([0.7, 0, 0.7]) == "slanted"
    st = app.station
    wait_idle(st, 10)
    assert st.controller.state.mode.value == "idle"
    # between two hits of a cycle the machine is idle: the bar still says the cycle runs
    running = status_html(st.controller.commands, "", cycle="auto-measure of TOP")
    assert ">RUNNING</span>" in running and "auto-measure of TOP" in running
    assert ">IDLE</span>" in status_html(st.controller.commands, "")
    paused = status_html(st.controller.commands, "", cycle="routine block on part 2", cycle_paused=True)  # a routine paused between hits
    assert ">PAUSED</span>" in paused and "routine block on part 2: Resume goes on" in paused
    # the reason has a line of its own in every state (a blank one when idle), kept to one line while the machine
    # runs: the block's height does not change as a move starts or ends
    assert "<div class='reason' title=''>&nbsp;</div>" in status_html(st.controller.commands, "")
    assert "<div class='reason warn one' title='auto-measure of TOP'>auto-measure of TOP</div>" in running
    assert "class='reason warn' " in paused  # standing: wrapped, read in full


def test_a_paused_run_is_not_called_silent(app):
    """'link SILENT: no samples' in red while a routine stood paused (the paused run holds the machine
    loop, so no samples come). Paused: the link is ok, not sampling; a link without samples otherwise is SILENT."""
    st = app.station
    wait_idle(st, 10)
    paused = status_html(st.controller.commands, "", link_rate=0.0, cycle="routine block on part 2", cycle_paused=True)
    assert ">PAUSED</span>" in paused and "SILENT" not in paused and "ok (paused: not sampling)" in paused, paused
    assert "SILENT: no samples" in status_html(st.controller.commands, "", link_rate=0.0)  # idle and no samples: that is silent
    assert "SILENT" not in status_html(st.controller.commands, "", link_rate=100.0)


def test_auto_measure_names_the_pick_keeps_the_typed_name_and_runs_as_one_cycle(app):
    st = app.station
    with browser_tab(app) as capp:
        m = capp.measure
        assert "Click a face of the part" in m.text()
        _pick(capp, st, (20.0, 60.0, 40.0), (0, 0, 1))
        assert "Picked: **plane**, the top face" in m.text()
        assert capp.ctx.pick_drawing.face is not None  # the picked face highlighted in the tab's view
        plan = m.make_plan(0)
        assert plan is not None and plan.kind == "plane"
        assert m.gui["hits"].value == len(plan) > 0  # the field shows the plan's hits, not 0
        assert "Picked: **plane**, the top face" in m.text() and f"{len(plan)} hits · clearance plane" in m.text()
        m.gui["name"].value = "TOP"
        assert m.run(m.gui["name"].value)
        assert not capp.ctx.pick_drawing.nodes  # the run's hits are drawn now, not the pick
        # the whole cycle is RUNNING in every tab's status bar, also between its moves (set before the first hit)
        assert app.shared.cycle == "auto-measure of TOP" and ">RUNNING</span>" in capp.status.html()
        m.running.join(120)
        assert m.feature.name == "TOP", capp.messages[-3:]
        assert app.shared.cycle is None and ">RUNNING</span>" not in capp.status.html()
        assert m.gui["name"].value == ""  # the next feature gets its own name
        # a boss: its nominal diameter (20) and centre fill the typed-nominal fields when it is selected
        _pick(capp, st, (80.0, 22.0, 47.0), (1, 0, 0))
        assert "Picked: **cylinder ⌀ 20.000**" in m.text()
        assert m.make_plan(3) is not None and m.gui["hits"].value == 3
        assert m.run("", wait=True), capp.messages[-3:]
        boss = m.feature
        assert boss.name != "TOP" and boss.kind == "cylinder", capp.messages[-3:]
        capp.select_feature(boss.id)
        capp.features.refresh()
        centre, diameter = nominal_fields(boss)
        assert diameter == pytest.approx(20.0)
        assert capp.features.gui["nominal_diameter"].value == pytest.approx(20.0)
        assert np.allclose(capp.features.gui["nominal_centre"].value, centre)
        assert np.allclose(centre, boss.nominal.params["point"], atol=1e-4)
        # a construction's name is cleared once used: the next one is not named the same
        top = next(f for f in st.measurement.features.values() if f.name == "TOP")
        capp.features.gui["construct_name"].value = "top-boss"
        c = capp.features.construct("angle", top.id, boss.id, capp.features.gui["construct_name"].value)
        assert c is not None and c.name == "top-boss", capp.messages[-3:]
        assert capp.features.gui["construct_name"].value == ""


def test_one_toast_per_event(app):
    st = app.station
    with browser_tab(app) as capp:
        other = app.add_client(client_id="observer-toasts")
        n0 = len(capp.messages)
        capp.emergency_stop()
        _until(lambda: any(t == "Emergency stop" for _l, t, _b in capp.messages[n0:]), 20.0, "the E-STOP toast")
        _until(lambda: any(t == "Emergency stop" for _l, t, _b in other.messages), 20.0, "the other tab's toast")
        capp.reset()
        _until(lambda: st.controller.state.mode.value != "e-stopped", 20.0, "the reset")
        n1 = len(capp.messages)
        capp.home()
        _until(lambda: any(t == "Homed" for _l, t, _b in capp.messages[n1:]), 120.0, "the Homed toast")
        wait_idle(st, 10)
        titles = [t for _l, t, _b in capp.messages[n0:]]
        assert titles.count("Emergency stop") == 1 and titles.count("Homed") == 1, titles


def test_diagnostics_shows_the_link_counters_and_retry_rate(app):
    """a retry that succeeded is counted where the operator can see it (Setup > Diagnostics), with the
    rate and the threshold above which the status bar warns."""
    with browser_tab(app) as capp:
        capp._show_trace()
        text = capp.gui["link_health"].content
        stats = app.station.machine.bus.stats
        assert "transactions" in text and "late replies" in text and "the status bar warns above 1%" in text, text
        assert stats["transactions"] > 0 and "window_retries" in stats
