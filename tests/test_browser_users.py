"""The station page with a user file, in a real chromium over the built-in TLS proxy of `cmm serve --tls`
(https / wss with the station's self-signed certificate): the start dialog logs in (a wrong password refused in
one sentence, the right one acts as the user's role), an operator is refused an admin's action, and the Report
tab's "QIF 3 results" button gives a file that validates against the QIF 3.0.0 schemas."""

from __future__ import annotations

import pytest

import browser_support as bs
import qif_support
import session_support as sup

pytestmark = pytest.mark.skipif(bs.unavailable_reason() is not None, reason=str(bs.unavailable_reason()))

USERS = {"maria": ("correct horse", "operator"), "ada": ("admin password", "admin")}


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A homed station on the simulator with a measured session (five block features, a distance), users and roles, its page on
    loopback behind the TLS proxy; (app, the page's https address)."""
    from cmm.cli.serve import tls_proxies
    from cmm.control import tls
    from cmm.control.roles import RolePolicy
    from cmm.control.users import UserStore, register_user_verbs
    from stations import station_page
    from netutil import free_port

    store = UserStore(tmp_path_factory.mktemp("users") / "users.toml")
    for name, (password, role) in USERS.items():
        store.add(name, role, password)
    gen = sup.sim_station(tmp_path_factory.mktemp("sessions"), "block")
    station = next(gen)
    sup.teach_block(station.measurement, sup.BLOCK_FACES[:5])
    station.controller.commands.roles = RolePolicy()  # as `cmm serve --users`
    register_user_verbs(station.controller.commands, store)
    app = station_page(station, host="127.0.0.1", port=free_port(), pendant=False, users=store, shadows=False)
    cert = tls.certificate(tmp_path_factory.mktemp("tls"))
    proxies = tls_proxies(app, cert, "127.0.0.1", free_port(), None)
    try:
        yield app, f"{proxies[0].url}?fixedDpr={bs.VIEW_SCALE:g}"
    finally:
        for p in proxies:
            p.close()
        app.close()
        gen.close()


def open_over_tls(context, app, url):
    before = set(app.clients)
    page = context.new_page()
    page.log = bs.PageLog()
    page.log.attach(page)
    page.goto(url)
    assert page.url.startswith("https://")
    page.capp = app.clients[bs.new_client(page, app, before)]  # the GUI came over the wss socket through the proxy
    return page


def log_in(page, name, password):
    dialog = page.get_by_role("dialog")
    dialog.get_by_text("This station has users").wait_for(timeout=bs.PAGE_WAIT_MS)
    fields = dialog.locator("input")
    fields.nth(0).fill(name)
    fields.nth(1).fill(password)
    bs.wait_until(lambda: fields.nth(1).get_attribute("type") == "password", 30, "the password's characters hidden",
                  why=lambda: page.evaluate("() => ({watch: !!window.__cmmPasswordWatch, labels: [...document"
                                            ".querySelectorAll('label')].map(l => l.textContent), types: [...document"
                                            ".querySelectorAll('input')].map(i => i.type)})"))
    bs.wait_until(lambda: fields.nth(0).input_value() == name and fields.nth(1).input_value() == password, 30,
                  "the login typed")
    dialog.get_by_role("button", name="Log in", exact=True).click()


def test_the_page_over_https_logs_in_and_its_role_decides(served):
    app, url = served
    with bs.browser_context(ignore_https_errors=True) as context:  # the self-signed certificate
        page = open_over_tls(context, app, url)
        capp = page.capp
        assert capp.is_local  # the station PC through the proxy: a loopback peer that named the loopback
        log_in(page, "maria", "not her password")
        bs.shows(page, "wrong user name or password")
        assert capp.ctx.user is None
        log_in(page, "maria", USERS["maria"][0])
        bs.wait_until(lambda: capp.ctx.user == "maria", 60, "maria logged in")
        assert capp.ctx.role == "operator"
        page.get_by_role("dialog").wait_for(state="hidden")
        # the operator's buttons: take control (under her name) ...
        bs.press(page, "Take control")
        bs.wait_until(lambda: app.control.holder_name == "maria", 60, "maria holds control")
        # ... but not an admin's: adding a user is refused in one sentence, nothing added
        bs.open_folder(page, "Users (admin)", "Add user")
        bs.text_field(page, "User name").fill("tom")
        bs.text_field(page, "New password").fill("pass-word-3")
        bs.wait_until(lambda: bs.text_field(page, "New password").get_attribute("type") == "password", 30,
                      "the new password's characters hidden")
        bs.press(page, "Add user")
        bs.shows(page, "maria (operator) may not add user: that needs the role admin")
        assert "tom" not in {u["name"] for u in app.users.users()}
        assert not page.log.page_errors


def test_the_report_tabs_qif_button_gives_a_file_that_validates(served):
    qif_support.schema_or_skip()
    app, url = served
    with bs.browser_context(ignore_https_errors=True) as context:
        page = open_over_tls(context, app, url)
        log_in(page, "ada", USERS["ada"][0])
        bs.wait_until(lambda: page.capp.ctx.user == "ada", 60, "ada logged in")
        page.get_by_role("dialog").wait_for(state="hidden")
        bs.open_tab(page, "Report", "Sessions")
        sessions = page.capp.sessions
        sessions.refresh_list()
        name = next(n for n in sessions._names() if n.startswith("block"))
        sessions.gui["session"].value = name  # what choosing it in the Session dropdown sets
        bs.open_folder(page, "Export", "QIF 3 results")
        bs.press_until(page, "QIF 3 results", lambda: any(f.suffix == ".qif" for f in sessions.last_files),
                       "the QIF file", timeout=240.0, every=60.0)
        target = next(f for f in sessions.last_files if f.suffix == ".qif")
        bs.shows(page, target.name)  # "wrote .../block.qif", and the file offered to the browser
        root = qif_support.validate(target)
        measured = root.findall(".//q:CharacteristicMeasurements/*", qif_support.NS)
        features = root.findall(".//q:MeasuredFeatures/*", qif_support.NS)
        assert len(features) >= 5, "the five block features measured"
        assert measured, "the characteristics (the bore-boss distance, the form of the faces) with their actuals"
