"""In headless chromium at 1280 x 800: the start dialog asks who operates and the browser keeps the name (a
second tab is named by itself); the reference sphere's certificate entered in the Calibration tab of a fresh
calibration folder clears the certificate problem; the probe list shows the probe in use.
Screenshot: test-artifacts/probes-calibration.png."""

from __future__ import annotations

import pytest

import browser_support as bs

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(300),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")

LAPTOP = (1280, 800)


@pytest.fixture(scope="module")
def app(tmp_path_factory):
    from cmm.station import Station

    folder = tmp_path_factory.mktemp("fresh-calibration")
    st = Station(port=bs.SIM, session_dir=tmp_path_factory.mktemp("sessions"), calibration_dir=folder).start(
        "probes", home=True)
    try:
        yield from bs.station_app(st, pendant=False, ask_name=True)
    finally:
        st.close()


def test_name_dialog_saved_name_and_certificate_entry(app):
    with bs.browser_context(LAPTOP) as context:
        page = bs.open_page(context, app)
        page.get_by_text("Who is operating?").wait_for()
        field = page.locator(".mantine-Modal-content input").first  # the dialog's one field, "Your name"
        field.wait_for(state="visible")
        page.wait_for_timeout(1000)  # the dialog's opening transition
        field.fill("Maria")
        page.get_by_role("dialog").get_by_role("button", name="Start", exact=True).click()
        bs.wait_until(lambda: page.capp.operator == "Maria", 10.0, "the operator's name")
        page.get_by_text("Who is operating?").wait_for(state="hidden")
        assert page.evaluate("() => localStorage.getItem('cmm-operator')") == "Maria"
        # a second tab of the same browser names itself from the saved name
        second = bs.open_page(context, app)
        bs.wait_until(lambda: second.capp.operator == "Maria", 60.0, "the saved name in the second tab")
        second.close()
        page.get_by_role("button", name="Take control").click()
        bs.wait_until(lambda: app.control.holder == page.capp.client_id, 10.0, "control")
        page.get_by_text("Maria (you) controls the machine").first.wait_for()
        bs.open_tab(page, "Setup", "Calibration")
        page.get_by_text("certificate problem").first.wait_for()
        bs.enter_sphere_certificate(page, 25.0002, "RS-77", 0.12)
        assert page.get_by_text("certificate problem").count() == 0
        cert = app.station.calibration.certificates("probe")
        assert (cert.serial, cert.diameter, cert.uncertainty) == ("RS-77", pytest.approx(25.0002),
                                                                  pytest.approx(0.00012))
        page.get_by_text("in use").first.wait_for()
        assert page.get_by_text("not qualified").count() >= 1
        bs.screenshot(page, "probes-calibration")
