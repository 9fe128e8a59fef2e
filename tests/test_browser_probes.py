"""In headless chromium on a tablet (820 x 1180), on a station not homed with a fresh calibration folder: the start
dialog asks who operates and the browser keeps the name (a second tab is named by itself); Home pressed in
Machine > Home homes the machine; the reference sphere's certificate entered in the Calibration tab clears the
certificate problem; the probe list shows the probe in use. Then the folder's first probe qualification, run from
the page: paused, it holds the machine (judged on the machine's clock) and says PAUSED; Resume lifts to the safe
height before the next point, and the qualified radius is shown and saved to the probe list. Every button is
pressed only where the tablet's operator can reach it (scrolled into view, on screen, not covered).

Sizes: tests/test_browser_walk.py does all of this at 1280 x 800 (name, Home, certificate, qualification), so
this file covers the tablet size.
Screenshots: test-artifacts/probes-calibration.png, probes-paused.png, probes-qualified.png."""

from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest

import browser_support as bs

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(300),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")

TABLET = (820, 1180)  # the walk does the same steps at 1280 x 800


@pytest.fixture(scope="module")
def app(module_stations, tmp_path_factory):
    folder = tmp_path_factory.mktemp("fresh-calibration")
    st = module_stations.station("probes", home=False, calibration_dir=folder)  # the operator homes it from the page
    yield from bs.station_app(st, pendant=False, ask_name=True)


@pytest.fixture
def within_reach(monkeypatch):
    """Every button press of the test (its own and browser_support's helpers') only where the operator can reach it
    at the page's size: scrolled into view, on screen and not covered (bs.press_on_screen)."""
    monkeypatch.setattr(bs, "press", bs.press_on_screen)


def home_in_page(page, station):
    """Machine > Home: the tab says to home first; Home pressed; the homing cycle runs to idle."""
    bs.open_tab(page, "Machine", "Home")
    bs.shows(page, "Press Home before measuring")
    bs.press(page, "Home")
    bs.wait_until(lambda: station.controller.state.homed and station.controller.state.mode.value == "idle",
                  180.0, "the homing cycle")
    page.get_by_text("Press Home before measuring").first.wait_for(state="hidden")


# Tablet size: the laptop size's name dialog, Home and certificate entry are in test_browser_walk.py.
def test_name_dialog_saved_name_home_and_certificate_entry(app, within_reach):
    with bs.browser_context(TABLET) as context:
        page = bs.open_page(context, app)
        assert bs.top_tab_rows(page) == [list(bs.TABS)]  # the tabs grouped in one row, as on the laptop
        bs.start_as(page, "Maria", real_click=True)  # a real click on Start: in reach
        assert page.evaluate("() => localStorage.getItem('cmm-operator')") == "Maria"
        # a second tab of the same browser names itself from the saved name
        second = bs.open_page(context, app)
        bs.wait_until(lambda: second.capp.operator == "Maria", 60.0, "the saved name in the second tab")
        second.close()
        bs.press(page, "Take control")
        bs.wait_until(lambda: app.control.holder == page.capp.client_id, 60.0, "control")
        bs.shows(page, "Maria (you) controls the machine")
        assert not app.station.controller.state.homed
        home_in_page(page, app.station)
        bs.open_tab(page, "Setup", "Calibration")
        bs.shows(page, "certificate problem")
        bs.enter_sphere_certificate(page, 25.0002, "RS-77", 0.12)
        assert page.get_by_text("certificate problem").count() == 0
        cert = app.station.calibration.certificates("probe")
        assert (cert.serial, cert.diameter, cert.uncertainty) == ("RS-77", pytest.approx(25.0002),
                                                                  pytest.approx(0.00012))
        bs.shows(page, "in use")
        assert page.get_by_text("not qualified").count() >= 1
        bs.screenshot(page, "probes-calibration")


# Tablet size: the laptop size's qualification (not paused) is in test_browser_walk.py.
def test_qualification_paused_and_resumed_from_the_page(app, within_reach):
    st = app.station
    safe_z = st.config.axis("z").max - 5.0  # the qualification's safe height
    with bs.browser_context(TABLET) as context:
        page = bs.open_page(context, app)
        bs.start_as(page, "Quinn")
        bs.press(page, "Take control")
        bs.wait_until(lambda: app.control.holder == page.capp.client_id, 30.0, "control")
        if not st.controller.state.homed:  # run alone
            home_in_page(page, st)
        bs.open_tab(page, "Setup", "Calibration")
        if st.calibration.certificate_problem("probe") is not None:  # run alone: the fresh folder's certificate
            bs.enter_sphere_certificate(page, 25.0002, "RS-77", 0.12)
        calib = page.capp.calibration
        bs.open_folder(page, "Probe options", "Points per ring")
        for label, value in (("Points per ring", 3), ("Hits per point", 1)):  # a short pattern: 3 per ring, 1 hit each
            page.get_by_label(label, exact=True).fill(str(value))
            page.get_by_label(label, exact=True).press("Enter")
        bs.wait_until(lambda: (calib.gui["per_ring"].value, calib.gui["repeats"].value) == (3, 1), 30.0,
                      "the qualification options at the station")

        def pattern() -> int | None:
            """The pattern's number of points while it runs (the progress says "point 2 of 10")."""
            m = re.search(r"point \d+ of (\d+)", calib.job.message or "") if calib.job is not None else None
            return int(m.group(1)) if m else None

        # every state the machine loop reads: machine time, X, Y, Z, largest axis speed, probe deflected
        trace: list[tuple[float, float, float, float, float, bool]] = []
        touched = threading.Event()

        def watch(s) -> None:
            trace.append((s.time, *s.position, max(abs(a.velocity) for a in s.axes), bool(s.probe_triggered)))
            if s.probe_triggered and pattern() is not None and not touched.is_set():
                # The operator presses Pause while the probe touches the sphere. On the simulator's clock the
                # whole pattern takes about a wall second, less than a press takes to reach the station, so the
                # machine loop (and with it the machine's clock) waits here until the station has the Pause.
                touched.set()
                end = time.monotonic() + 120.0
                while not st.calibration.paused and time.monotonic() < end:
                    time.sleep(0.01)

        unsubscribe = st.machine.subscribe(watch)
        try:
            bs.press(page, "Run")
            bs.wait_until(touched.is_set, 300.0, "a touch of the qualification's pattern",
                          why=lambda: calib.job and calib.job.message)
            points = pattern()
            bs.press(page, "Pause")
            bs.wait_until(lambda: st.calibration.holding, 300.0, "the hold between two points",
                          why=lambda: f"{calib.job.message}; done: {calib.job.done}")
            status = calib.progress_view.status  # the station's status line, then the page's
            bs.wait_until(lambda: re.search(r"PAUSED.*holding", status.content) is not None, 60.0,
                          "PAUSED ... holding in the station's status line", why=lambda: status.content)
            try:
                bs.shows(page, re.compile(r"PAUSED.*holding"))  # the page says so ...
            except Exception:  # once beside CPU hogs the page never did: say what it showed instead
                bs.screenshot(page, "probes-paused-missing")
                raise AssertionError(f"the page never said PAUSED ... holding (the station's line: {status.content!r}); "
                                     f"the page's Calibration tab: {page.inner_text('body')[:3000]!r}") from None
            page.locator("#cmm-status").get_by_text("PAUSED", exact=True).filter(visible=True).first.wait_for()  # ... and its status bar
            bs.screenshot(page, "probes-paused")
            # the machine stands: one machine second (the simulator's clock) without a move
            held = st.machine.state.time
            bs.wait_until(lambda: st.machine.state.time > held + 1.0, 120.0, "a machine second of the hold")
            during = [row for row in trace if row[0] >= held]
            assert during and max(row[4] for row in during) < 1e-9, "the machine moved while paused"
            assert np.ptp(np.array([row[1:4] for row in during]), axis=0).max() < 1e-6
            assert st.calibration.holding and not calib.job.done
            z_held = during[-1][3]
            assert z_held < safe_z - 5.0  # paused beside the sphere, below the safe height
            bs.press(page, "Resume")
            bs.wait_until(lambda: not st.calibration.paused, 60.0, "the resume at the station")
            resumed = st.machine.state.time
            bs.wait_until(lambda: calib.job.done, 600.0, "the qualification's end",
                          why=lambda: calib.job.message)
        finally:
            unsubscribe()
        assert calib.job.error is None, calib.job.error
        # Resume lifted to the safe height before the probe touched the sphere again
        next_touch = next(row[0] for row in trace if row[0] > resumed and row[5])
        assert max(row[3] for row in trace if resumed <= row[0] <= next_touch) >= safe_z - 0.01
        result = calib.result[1]
        assert result.record.n_points == points >= 7 and result.skipped == []
        radius = f"{result.record.tip_radius:.5f} mm"
        bs.shows(page, radius)  # the results: the effective tip radius
        bs.press_until(page, "Save record", lambda: st.calibration.status.get("probe"), "the qualification saved")
        rows = {r["name"]: r for r in calib.probes()}
        assert rows["Probe1"]["tip_radius"] == pytest.approx(result.record.tip_radius)
        bs.wait_until(lambda: radius in calib.gui["probes"].content, 30.0, "the probe list's qualified radius")
        page.get_by_text(re.compile(r"Probe1.*\(in use\)")).filter(visible=True).first.wait_for()
        bs.screenshot(page, "probes-qualified")
        assert not page.log.page_errors, page.log.page_errors
