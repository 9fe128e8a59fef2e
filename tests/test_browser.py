"""The pendant page (and the viser app, once it exists) in headless chromium, driving the simulated station.

Needs the Python package ``playwright`` and Debian's ``chromium``; skipped with the reason otherwise.
Screenshots go to test-artifacts/ (git-ignored).
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import time
import urllib.request

import numpy as np
import pytest

import browser_support as bs
import browser_moves as bm
from cmm.ui import pendant as pendant_mod
from cmm.control.access import Control
from cmm.ui.pendant import start_pendant_server

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(120),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

STOP_WITHIN = 0.3  # s from the input's release to zero velocity


@pytest.fixture
def station(stations):
    # homed on the uncapped clock (2 machine s), then paced (as netutil.SIM_PACED): the page's wall-time jog
    # refreshes meet the dead-man
    return stations.station(pace=1.0)


@pytest.fixture
def control(station):
    return Control(access_code="right-code", on_holder_lost=lambda _cid: station.controller.jog_release(None))


@pytest.fixture
def server(station, control):
    station.controller.use_policy_of(control)  # as the composition root (StationApp) wires it
    handle = start_pendant_server(station.controller.commands, control, "127.0.0.1", 0)
    yield handle
    handle.close()


@pytest.fixture(scope="module")
def context():
    with bs.browser_context() as ctx:
        yield ctx


@pytest.fixture
def page(context):
    page = context.new_page()
    page.add_init_script(bs.FAKE_GAMEPAD)
    log = bs.PageLog()
    log.attach(page)
    page.log = log
    yield page
    page.close()


def velocity(station):
    return [a.velocity for a in station.machine.state.axes]


def speed(station) -> float:
    return max(abs(v) for v in velocity(station))


def open_pendant(page, server, take: bool = True, code: str | None = None):
    page.goto(server.url)
    page.wait_for_function("document.getElementById('px').textContent !== '–'")
    page.wait_for_function("document.getElementById('link').classList.contains('on')")
    if code is not None:
        page.fill("#code", code)
    if take:
        page.click("#take")
        if code is None:
            page.wait_for_function("document.getElementById('control').textContent === 'you have control'")


def test_pendant_loads_and_shows_position(page, server, station):
    open_pendant(page, server, take=False)
    x, y, z = station.machine.state.position
    assert page.text_content("#px") == f"{x:.3f}"
    assert page.text_content("#pz") == f"{z:.3f}"
    assert page.text_content("#control") == "observer"
    assert "Test gamepad" in page.text_content("#gamepad")
    page.wait_for_timeout(300)
    bs.screenshot(page, "pendant-observer")
    assert page.log.problems == []


def test_pendant_in_an_iframe(page, server):
    page.set_content(f'<body style="margin:0;background:#333"><iframe src="{server.url}" '
                     'style="width:420px;height:760px;border:0"></iframe></body>')
    frame = page.frame_locator("iframe")
    frame.locator("#link.on").wait_for()
    frame.locator("#take").click()
    frame.locator("#control.you").wait_for()
    page.wait_for_timeout(200)
    bs.screenshot(page, "pendant-embedded")
    assert page.log.problems == []


def held_live(station, rec, axis: int, since: float, what: str, far: float = 150.0) -> None:
    """Until the page's holds have kept the jog on ``axis`` live for one window after ``since`` (machine time), or it
    went ``far`` mm (the page never refreshed it in time: the speed assertion after it fails with the summary)."""
    x0 = station.machine.state.position[axis]
    bs.wait_until(lambda: len(rec.live_speeds(axis, since)) >= 1
                  or abs(station.machine.state.position[axis] - x0) > far,
                  60.0, what, poll=0.05, why=rec.summary)


def stopped_by_the_release(rec, let_go: float, what: str) -> float:
    """Machine time the page's release (sent after ``let_go``) reached the station; asserts the release stopped the
    jog within STOP_WITHIN s of machine time of its arrival (not the dead-man: the page's holds stop with it)."""
    released, stop, _rest = rec.stop_after_release(let_go, what)
    assert stop < STOP_WITHIN, (what, stop)
    assert not [td for td in rec.deadman if released <= td <= released + stop], (what, "stopped by the dead-man")
    return released


def assert_speeds(speeds, expected: float, rel: float, rec) -> None:
    assert speeds and max(abs(np.array(speeds) / expected - 1)) < rel, (np.round(speeds, 3), expected, rec.summary())


def test_gamepad_moves_and_stops(page, server, station):
    """The left stick jogs: full right +X at jog_fast; with A held, up +Y at the fine speed; half up (A let go) at
    the cubic curve's much slower speed; back to centre or B stops. Speeds are position over the machine's clock
    in the windows the page's refreshes kept the jog live (bm.JogRecord), stops counted from the page's release
    reaching the station: how fast a loaded computer runs the browser is not judged."""
    open_pendant(page, server)
    start = station.machine.state.position.copy()
    fast, fine = station.config.speeds.jog_fast, station.config.speeds.jog_fine
    with bm.JogRecord(station) as rec:
        page.evaluate("window.__pad.axes[0] = 1.0")  # left stick full right: +X at jog_fast
        bs.wait_until(lambda: station.machine.state.position[0] > start[0] + 0.01, 60.0, "the jog at jog_fast")
        t0 = station.machine.state.time
        held_live(station, rec, 0, t0 + 0.1, "a live jog at jog_fast")  # 400 mm/s^2: at 40 mm/s within 0.1 s
        assert station.machine.state.jogging
        bs.screenshot(page, "pendant-jogging")
        let_go = station.machine.state.time
        page.evaluate("window.__pad.axes[0] = 0.0")  # back to centre: one release
        released = stopped_by_the_release(rec, let_go, "the stick back to centre")
        assert_speeds(rec.live_speeds(0, t0 + 0.1, released), fast, 0.03, rec)
    assert station.machine.state.position[0] > start[0] + 2

    # hold A: fine (probing) speed; the cubic curve makes a half deflection much slower than half speed
    half = ((0.5 - 0.15) / 0.85) ** 3 * fast
    with bm.JogRecord(station) as rec:
        y0 = station.machine.state.position[1]
        page.evaluate("window.__pad.buttons[0] = 1; window.__pad.axes[1] = -1.0")  # stick up: +Y
        bs.wait_until(lambda: station.machine.state.position[1] > y0 + 0.01, 60.0, "the fine jog")
        t0 = station.machine.state.time
        held_live(station, rec, 1, t0 + 0.05, "a live fine jog")
        page.evaluate("window.__pad.buttons[0] = 0; window.__pad.axes[1] = -0.5")
        bs.wait_until(lambda: rec.first_hold(lambda v: v[1] > 2 * fine) is not None, 60.0, "the half deflection's jog")
        t1 = rec.first_hold(lambda v: v[1] > 2 * fine)
        held_live(station, rec, 1, t1 + 0.05, "a live half-deflection jog")
        assert_speeds(rec.live_speeds(1, t0 + 0.05, t1), fine, 0.05, rec)
        let_go = station.machine.state.time
        page.evaluate("window.__pad.buttons[1] = 1")  # B: stop (the page releases the jog first)
        released = stopped_by_the_release(rec, let_go, "B")
        assert_speeds(rec.live_speeds(1, t1 + 0.05, released), half, 0.05, rec)
    page.evaluate("window.__pad.buttons[1] = 0; window.__pad.axes[1] = 0")
    bs.wait_until(lambda: station.controller.state.mode.value != "jogging", 60.0, "the end of the jog")
    assert page.log.problems == []


def test_gamepad_inside_dead_zone_does_not_move(page, server, station):
    open_pendant(page, server)
    page.evaluate("window.__pad.axes[0] = 0.12; window.__pad.axes[1] = -0.1")
    page.wait_for_timeout(400)
    assert speed(station) == 0


def test_keyboard_jog_and_keyup_stop(page, server, station):
    """Arrow keys jog at the slow speed, Shift at the fast one, PageDown Z-; key-up and a lost focus stop. Speeds
    and stops on the machine's clock as in test_gamepad_moves_and_stops."""
    open_pendant(page, server)
    start = station.machine.state.position.copy()
    slow, fast = station.config.speeds.jog_slow, station.config.speeds.jog_fast
    with bm.JogRecord(station) as rec:
        page.keyboard.down("ArrowRight")
        bs.wait_until(lambda: station.machine.state.position[0] > start[0] + 0.01, 60.0, "the keyboard jog")
        t0 = station.machine.state.time
        held_live(station, rec, 0, t0 + 0.05, "a live keyboard jog")
        let_go = station.machine.state.time
        page.keyboard.up("ArrowRight")
        released = stopped_by_the_release(rec, let_go, "the key-up")
        assert_speeds(rec.live_speeds(0, t0 + 0.05, released), slow, 0.03, rec)
    moved = station.machine.state.position - start
    assert moved[0] > 0.5 and abs(moved[1]) < 1e-9 and abs(moved[2]) < 1e-9
    with bm.JogRecord(station) as rec:
        y0 = station.machine.state.position[1]
        page.keyboard.down("Shift")
        page.keyboard.down("ArrowUp")
        bs.wait_until(lambda: station.machine.state.position[1] > y0 + 0.01, 60.0, "the fast keyboard jog")
        t0 = station.machine.state.time
        held_live(station, rec, 1, t0 + 0.1, "a live fast keyboard jog")
        let_go = station.machine.state.time
        page.keyboard.up("ArrowUp")
        page.keyboard.up("Shift")
        released = stopped_by_the_release(rec, let_go, "the fast jog's key-up")
        assert_speeds(rec.live_speeds(1, t0 + 0.1, released), fast, 0.03, rec)
    with bm.JogRecord(station) as rec:
        z0 = station.machine.state.position[2]
        page.keyboard.down("PageDown")  # Z-
        bs.wait_until(lambda: station.machine.state.position[2] < z0 - 0.01, 60.0, "the Z jog")
        let_go = station.machine.state.time
        page.evaluate("window.dispatchEvent(new Event('blur'))")  # focus lost while a key is down
        stopped_by_the_release(rec, let_go, "the blur")
        page.keyboard.up("PageDown")
    assert page.log.problems == []


def test_hold_button(page, server, station):
    """A held on-screen button jogs; sliding off it releases (the machine stops within STOP_WITHIN s of machine time
    of the release reaching the station); Fine and Fast chosen on the page jog at their speeds while the page's
    holds keep the jog live (position over the machine's clock: a starved browser's late holds let the dead-man
    stop it, which is not judged here)."""
    open_pendant(page, server)
    box = page.locator(".pad .xp").bounding_box()
    centre = (box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    with bm.JogRecord(station) as rec:
        page.mouse.move(*centre)
        page.mouse.down()
        bs.wait_until(lambda: velocity(station)[0] > 0.9 * station.config.speeds.jog_slow, 60.0, "the button jog")
        let_go = station.machine.state.time
        page.mouse.move(box["x"] - 60, centre[1])  # slide off the button: pointerleave
        released, stop, _rest = rec.stop_after_release(let_go, "leaving the button")
        assert stop < STOP_WITHIN, stop
        assert not [td for td in rec.deadman if released <= td <= released + stop], "the dead-man stopped it, not the release"
        page.mouse.up()
    # the speed buttons: Fine, then Fast chosen on the page; holding X+ jogs at that speed
    for label, expected in (("Fine", station.config.speeds.jog_fine), ("Fast", station.config.speeds.jog_fast)):
        page.get_by_role("button", name=label, exact=True).click()
        assert page.locator(".speeds button.sel").inner_text() == label
        x0 = station.machine.state.position[0]
        with bm.JogRecord(station) as rec:
            page.mouse.move(*centre)
            page.mouse.down()
            try:
                bs.wait_until(lambda: station.machine.state.position[0] > x0 + 0.01, 60.0, f"the {label} button jog")
                t0 = station.machine.state.time
                bs.wait_until(lambda: len(rec.live_speeds(0, t0 + 0.1)) >= 1 or station.machine.state.position[0] > x0 + 150,
                              60.0, f"a live {label} jog", poll=0.1, why=rec.summary)
            finally:
                let_go = station.machine.state.time
                page.mouse.up()
            released, stop, _rest = rec.stop_after_release(let_go, f"the {label} jog")
            assert stop < STOP_WITHIN, (label, stop)
            assert not [td for td in rec.deadman if released <= td <= released + stop], (label, "stopped by the dead-man")
            speeds = rec.live_speeds(0, t0 + 0.1, released)  # 400 mm/s^2: at 40 mm/s within 0.1 s
            assert speeds and max(abs(np.array(speeds) / expected - 1)) < 0.05, (label, np.round(speeds, 3),
                                                                                 rec.summary())
    bs.screenshot(page, "pendant-speed-fast")


def test_observer_cannot_move(page, server, station, control, monkeypatch):
    monkeypatch.setattr(pendant_mod, "is_local_connection", lambda _addr, _host=None: False)  # the browser counts as remote
    open_pendant(page, server, code="wrong-code")
    page.wait_for_function("document.getElementById('message').textContent.includes('wrong access code')")
    start = station.machine.state.position.copy()
    page.keyboard.down("ArrowRight")
    page.evaluate("window.__pad.axes[0] = 1.0")
    page.wait_for_timeout(500)
    assert speed(station) == 0 and (station.machine.state.position == start).all()
    assert control.holder is None
    assert page.text_content("#control") == "observer"
    bs.screenshot(page, "pendant-wrong-code")
    page.keyboard.up("ArrowRight")
    page.evaluate("window.__pad.axes[0] = 0")
    # with the right code the same page may move
    page.fill("#code", "right-code")
    page.click("#take")
    page.wait_for_function("document.getElementById('control').textContent === 'you have control'")
    page.keyboard.down("ArrowRight")
    bs.wait_until(lambda: velocity(station)[0] > 1.0, 2.0, "the jog after the right code")
    page.keyboard.up("ArrowRight")
    bs.wait_until(lambda: speed(station) < 1e-9, 2.0, "the stop")


def test_the_page_says_why_a_jog_does_not_start(page, server, station):
    """Without control a held gamepad says so; homed at X = 0, -X says which way X can go (it moved nothing)."""
    open_pendant(page, server, take=False)
    page.evaluate("window.__pad.axes[0] = 1.0")
    page.wait_for_function("document.getElementById('message').textContent === 'take control to jog'")
    page.evaluate("window.__pad.axes[0] = 0")
    page.click("#take")
    page.wait_for_function("document.getElementById('control').textContent === 'you have control'")
    start = station.machine.state.position.copy()
    page.keyboard.down("ArrowLeft")  # -X from X = 0
    page.wait_for_function("document.getElementById('message').textContent"
                           " === 'X is at the end of its travel (0 mm): it can only jog +X'")
    page.keyboard.up("ArrowLeft")
    assert speed(station) == 0 and station.machine.state.position[0] == pytest.approx(start[0], abs=0.002)
    assert page.log.problems == []


def test_another_holder_makes_the_page_an_observer(page, server, station, control):
    open_pendant(page, server)
    assert control.take("someone-else", is_local=True)
    page.wait_for_function("document.getElementById('control').textContent.includes('another client')")
    page.keyboard.down("ArrowRight")
    page.wait_for_timeout(400)
    assert speed(station) == 0
    page.keyboard.up("ArrowRight")


# --- the viser app (the other half of the UI) ---------------------------------------------------

def _viser_app_available() -> bool:
    if importlib.util.find_spec("cmm.ui.app") is None:
        return False
    from cmm import cli

    return "serve" in cli.COMMANDS


@pytest.mark.skipif(not _viser_app_available(), reason="viser app not available")
@pytest.mark.timeout(400)  # `cmm serve` starting, then up to 2 min for the page's first paint on a loaded machine
def test_viser_app_loads(context, tmp_path):
    """`cmm serve` as an operator starts it: the page loads without console errors; one screenshot per tab."""
    port, pendant_port = bs.free_port(), bs.free_port()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen([sys.executable, "-m", "cmm.cli", "serve", "--http-port", str(port),
                             "--pendant-port", str(pendant_port), "--sessions", str(tmp_path / "sessions")],
                            cwd=tmp_path, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, env=env)
    try:
        url = f"http://127.0.0.1:{port}/"
        end = time.monotonic() + 60
        while True:
            try:
                urllib.request.urlopen(url, timeout=2).close()
                break
            except OSError:
                if proc.poll() is not None or time.monotonic() > end:
                    if proc.poll() is None:
                        proc.kill()
                    out = proc.stdout.read().decode(errors="replace") if proc.stdout else ""
                    raise AssertionError(f"`cmm serve` did not come up on {url}:\n{out[-2000:]}")
                time.sleep(0.2)
        page = context.new_page()
        page.set_viewport_size({"width": 1400, "height": 900})
        log = bs.PageLog()
        log.attach(page)
        page.goto(f"{url}?fixedDpr={bs.VIEW_SCALE:g}")  # as bs.app_url (the product's shadows kept)
        bs.viser_ready(page)  # the scene and the panels that arrived over viser's socket
        bs.shows(page, "Who is operating?")  # the start dialog; Skip leaves it unnamed
        # its content comes in messages of its own (a page whose frames stall applies them late: diagnosed here;
        # once, beside two CPU hogs, the title showed and no Skip button came within 120 s)
        bs.shows(page, "Your name goes in the status bar")
        page.wait_for_timeout(500)
        page.get_by_role("dialog").get_by_role("button", name="Skip", exact=True).click()
        page.get_by_text("Who is operating?").wait_for(state="hidden")
        assert bs.render_passes(page) > 1  # `cmm serve` draws the probe's shadow (a pass per light)
        bs.screenshot(page, "viser-main")
        # The tab screenshots are of the panels. With the product's shadows a frame of the view costs chromium's
        # software WebGL several times a plain one, and beside two CPU hogs a screenshot waited over 2 min behind
        # them: the view now draws once every 5 s (the panels do not wait for its frames).
        page.evaluate("window.__cmmFrameMs = 5000")
        shot = 0
        for top, subs in bs.TABS.items():  # every tab and sub-tab of the grouped side panel
            for sub in subs or (None,):
                bs.open_tab(page, top, sub)
                page.wait_for_timeout(400)
                bs.screenshot(page, "viser-tab-" + (sub or top).lower().replace(" ", "-"))
                shot += 1
        page.close()
        assert log.console_errors == [] and log.page_errors == [], log.problems

        pendant = context.new_page()  # the pendant the app serves beside it
        plog = bs.PageLog()
        plog.attach(pendant)
        pendant.goto(f"http://127.0.0.1:{pendant_port}/")
        pendant.wait_for_function("document.getElementById('px').textContent !== '\u2013'")
        bs.screenshot(pendant, "viser-app-pendant")
        pendant.close()
        assert plog.problems == []
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def test_keyboard_step_mode_one_press_one_step(page, server, station):
    """Keys 1-4 pick a step size (shown on the page); each arrow press is one step; 0 returns to hold-to-jog."""
    open_pendant(page, server)
    start = station.machine.state.position.copy()
    page.keyboard.press("3")  # 1 mm steps
    assert page.locator(".steps button.sel").inner_text() == "1"
    page.keyboard.press("ArrowRight")
    bs.wait_until(lambda: abs(station.machine.state.position[0] - start[0] - 1.0) < 0.003 and not station.machine.state.moving,
                  10.0, "the 1 mm step")
    page.keyboard.press("PageDown")
    bs.wait_until(lambda: abs(station.machine.state.position[2] - start[2] + 1.0) < 0.003 and not station.machine.state.moving,
                  10.0, "the Z- step")
    page.keyboard.press("2")
    page.keyboard.down("ArrowUp")  # held: still one 0.1 mm step (no auto-repeat steps)
    page.wait_for_timeout(600)
    page.keyboard.up("ArrowUp")
    bs.wait_until(lambda: not station.machine.state.moving, 5.0, "the end of the step")
    moved = station.machine.state.position - start
    assert moved == pytest.approx([1.0, 0.1, -1.0], abs=0.003)
    page.keyboard.press("0")
    assert page.locator(".steps button.sel").inner_text() == "Hold"
    assert page.log.page_errors == [], page.log.problems
