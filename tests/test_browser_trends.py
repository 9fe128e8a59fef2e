"""The Trends tab in headless chromium: a series' chart drawn inside the side panel (it never widens the panel),
every part a dot, the out-of-tolerance part in red, the statistics. Screenshot: test-artifacts/trends-tab.png."""

from __future__ import annotations

import numpy as np
import pytest

import browser_support as bs

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(600),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")

from cmm.session.trends import Measured, Trends  # noqa: E402


@pytest.fixture(scope="module")
def station(module_stations, tmp_path_factory):
    root = tmp_path_factory.mktemp("trends-browser")
    st = module_stations.station("trends", home=False, session_dir=root / "sessions")  # charts need no homing
    rng = np.random.default_rng(3)
    st.measurement.trends = Trends(root / "trends", station="cmm-1")
    for i in range(40):  # part 28 is out of tolerance
        v = 30.0 + rng.normal(0.0, 0.005) + (0.03 if i == 27 else 0.0)
        st.measurement.trends.record_part("bracket", [Measured("bore / diameter", v, 30.0, 29.98, 30.02)],
                                          serial=f"B{i + 1}", when=1e9 + i)
    yield st
    st.close()
    st.measurement.trends.close()


@pytest.fixture(scope="module")
def app(station):
    yield from bs.station_app(station, pendant=False)


def test_the_trends_tab_shows_the_chart_inside_the_panel(app, station):
    with bs.browser_context(viewport=(1280, 800)) as ctx:
        page = ctx.new_page()
        log = bs.PageLog()
        log.attach(page)
        page.goto(bs.app_url(app))
        page.get_by_role("button", name="E-STOP").wait_for()
        bs.open_tab(page, "Report", "Trends")
        chart = page.locator("svg.trend")
        chart.wait_for()
        chart.scroll_into_view_if_needed()
        panel = page.locator("#cmm-status").bounding_box()  # the status block: as wide as the panel's content
        svg = chart.bounding_box()
        assert svg["width"] <= panel["width"] + 40 and svg["x"] + svg["width"] <= 1280
        assert page.locator("svg.trend circle").count() == 40
        assert page.locator('svg.trend circle[fill="#c62828"]').count() == 1  # the part out of tolerance
        assert "Cpk" in page.locator("body").inner_text()
        bs.screenshot(page, "trends-tab")
        assert not log.problems, log.problems
