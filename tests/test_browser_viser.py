"""The viser station page in real headless chromium, driving a real (simulated) station in-process.

The station and the viser app run in this process (loopback only), so the tests
assert on ``station.machine.state`` / ``station.measurement.hits`` and on the per-client
:class:`~cmm.ui.panels.ClientApp` while chromium presses the buttons and clicks
the 3D canvas. Needs the Python package ``playwright`` and Debian's
``chromium``; skipped with the reason otherwise. Screenshots go to
test-artifacts/ (git-ignored).
"""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
from control_support import wait_idle
from netutil import SIM_PACED

import browser_support as bs
import browser_moves as bm

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(400),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")

from cmm.sim.url import open_world, release as release_world  # noqa: E402
from stations import station_page  # noqa: E402
from cmm.ui.scene import SCALE  # noqa: E402

VIEWPORT = (1400, 900)
# s of machine time from the button's release to zero velocity. The release is an event of a WebGL page rendered in
# software here, paced in wall time: on a busy 2-core test machine it comes late. The bound is generous (the
# page's hold events stop with the release too, so the dead-man would stop it 0.15 s later anyway); the station's
# release-to-stop latency itself is measured by benchmarks/bench_jog_release.py, not asserted here.
STOP_WITHIN = 0.6
# s of machine time from the release's arrival at the station's jog pipeline to zero velocity: the config promises a
# released jog stops within 0.2 s (config.py); a few polls of slack for the machine loop of this busy test process.
RELEASE_STOP = 0.3
# simulated s per wall s while a test holds a jog button (held_on_a_slow_clock): a starved browser's holds, up to
# 0.5 s apart on a loaded machine, still come within the 0.15 s dead-man of machine time (0.75 s of wall time here)
HELD_PACE = 0.2
HOLD_WALL_LIMIT = 90.0  # s of wall time a test holds a jog button at most, waiting for the page's holds to keep it live
TOP_Z = 40.0  # machine Z of the sample part's top face (the part sits on the table at Z=0)
# candidate points on the top face, part coordinates (mm): clear of the bore, boss, dome and cone
TOP_FACE_CANDIDATES = ((15.0, 68.0), (10.0, 12.0), (112.0, 72.0), (45.0, 70.0), (110.0, 10.0), (60.0, 40.0))


# --- fixtures ------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def world():
    """The simulated CMM, paced at the wall clock (a person's wall-time input meets the dead-man)."""
    world = open_world(SIM_PACED)
    yield world
    release_world(world.url)


@pytest.fixture(scope="module")
def station(world, module_stations):
    return module_stations.station(port=world.url)


@contextlib.contextmanager
def held_on_a_slow_clock(world):
    """While a jog button is held: the simulated machine's clock at HELD_PACE simulated s per wall s. The page's
    hold events are paced in wall time by a browser that renders WebGL in software and, on a loaded test machine,
    gets little CPU: on a slowed machine clock they still come within the dead-man, so what the machine does
    while they keep the jog live can be judged (its speeds and stops are all in machine time)."""
    world.network.set_pace(HELD_PACE)
    try:
        yield
    finally:
        world.network.set_pace(1.0)


@pytest.fixture(scope="module")
def app(station):
    ui = station_page(station, host="127.0.0.1", port=bs.free_port(), pendant_port=0, ask_name=False, shadows=False)
    yield ui
    ui.close()


@pytest.fixture(scope="module")
def context():
    with bs.browser_context(viewport=VIEWPORT) as ctx:
        yield ctx


@pytest.fixture
def open_page(context, app, station):
    """Opens viser pages (each one its own viser client); closes them and settles the machine afterwards."""
    pages = []

    def opener():
        page = bs.open_page(context, app)
        pages.append(page)
        return page

    yield opener
    for page in pages:
        page.close()
    station.controller.stop(None)
    wait_idle(station, 20)
    bs.wait_until(lambda: app.control.holder is None, 5.0, "control released by the closed pages")


# --- helpers --------------------------------------------------------------------------------------

def speed(station) -> float:
    return max(abs(a.velocity) for a in station.machine.state.axes)


def take_control(page, app) -> None:
    bs.press_until(page, "Take control", lambda: app.control.holder == page.capp.client_id, "control taken")
    bs.shows(page, "You control the machine.")
    assert app.control.holder == page.capp.client_id


def machine_row(page, axis: str) -> list[str]:
    row = page.get_by_role("row").filter(has=page.get_by_role("cell", name=axis, exact=True))
    return [c.strip() for c in row.first.get_by_role("cell").all_inner_texts()]


def camera_of(app, cid: int):
    client = app.server.get_clients()[cid]
    # the camera properties assert until the page has reported its camera once
    bs.wait_until(lambda: client.camera._state.update_timestamp and client.camera.image_width > 0, 10.0,
               "the page's camera report")
    return client.camera


def project(camera, point_scene: np.ndarray) -> tuple[float, float]:
    """World point (scene metres) -> pixel in the client's canvas image (viser's OpenCV camera: +Z forward)."""
    w, x, y, z = camera.wxyz
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    p = R.T @ (np.asarray(point_scene, float) - camera.position)
    assert p[2] > 0, "the point is behind the camera"
    f = camera.image_height / 2 / np.tan(camera.fov / 2)
    return camera.image_width / 2 + f * p[0] / p[2], camera.image_height / 2 + f * p[1] / p[2]


def visible_top_point(station, camera) -> np.ndarray:
    """A point of the part's top face (machine mm) that the camera sees directly (nothing in front of it)."""
    pose = station.measurement.part.pose
    eye_mm = np.asarray(camera.position) / SCALE
    for u, v in TOP_FACE_CANDIDATES:
        target = pose[:3, :3] @ np.array([u, v, TOP_Z]) + pose[:3, 3]
        result = station.measurement.pick(eye_mm, target - eye_mm)
        if result is not None and np.linalg.norm(result[0].point - target) < 0.5:
            return target
    raise AssertionError("no candidate point of the top face is visible from the initial camera")


# --- tests ------------------------------------------------------------------------------------------

def test_page_loads_and_shows_the_position(open_page, station):
    page = open_page()
    page.wait_for_timeout(1500)  # let the scene render and any late errors surface
    x, y, z = station.machine.state.position
    for axis, value in zip("XYZ", (x, y, z)):
        cells = machine_row(page, axis)
        assert cells[1] == f"{value:.4f}", (axis, cells)
    assert page.get_by_text("Nobody controls the machine. You observe.").first.is_visible()
    bs.screenshot(page, "viser-browser-loaded")
    # the software-WebGL notice (if any) is a warning, not an error: only errors count
    assert page.log.console_errors == [] and page.log.page_errors == [], page.log.problems


def test_click_on_the_part_picks_and_probe_here_adds_a_hit(open_page, app, station):
    page = open_page()
    take_control(page, app)
    bs.open_tab(page, "Machine", "Go to")
    camera = camera_of(app, page.cid)
    target = visible_top_point(station, camera)
    u, v = project(camera, target * SCALE)
    box = page.locator("canvas").first.bounding_box()
    px = box["x"] + u * box["width"] / camera.image_width
    py = box["y"] + v * box["height"] / camera.image_height
    page.mouse.click(px, py)
    bs.wait_until(lambda: page.capp.ctx.picked is not None, 5.0, "the pick from the canvas click")
    hit, nominal = page.capp.ctx.picked
    assert hit.point[2] == pytest.approx(TOP_Z, abs=1e-6)
    assert np.allclose(hit.normal, (0, 0, 1), atol=1e-6)
    assert np.linalg.norm(hit.point[:2] - target[:2]) < 5.0, (hit.point, target)  # a few pixels of slack
    assert nominal is not None and nominal.kind == "plane"
    shown = "picked X={:.3f} Y={:.3f} Z={:.3f}, normal (".format(*hit.point)
    bs.shows(page, shown)  # the Go to panel shows it (refresher, 5 Hz)
    page.wait_for_timeout(300)  # the pick marker drawn
    bs.screenshot(page, "viser-browser-picked")
    bs.screenshot(page, "viser-browser-picked-zoom", clip={"x": max(px - 80, 0), "y": max(py - 80, 0),
                                                            "width": 160, "height": 160})

    before = len(station.measurement.hits)
    bs.press(page, "Probe here")  # on the element: not idempotent, so pressed once
    bs.wait_until(lambda: len(station.measurement.hits) == before + 1, 40.0, "the hit from Probe here")
    newest = station.measurement.hits[max(station.measurement.hits)]
    assert np.linalg.norm(newest.point - hit.point) < 0.1, (newest.point, hit.point)
    bs.open_tab(page, "Machine", "Probe")
    bs.shows(page, "contact point (machine):")
    page.wait_for_timeout(500)
    bs.screenshot(page, "viser-browser-probe-tab")
    assert page.log.console_errors == [] and page.log.page_errors == [], page.log.problems


def test_observer_cannot_jog(open_page, app, station):
    observer = open_page()
    holder = app.add_client(client_id="other-operator", is_local=True)  # another client holds control
    try:
        assert holder.take_control()
        observer.get_by_text("Observing; control is held by").filter(visible=True).first.wait_for()
        bs.open_tab(observer, "Machine", "Jog")
        wait_idle(station, 20)
        start = station.machine.state.position.copy()
        for _ in range(2):  # while another client holds control, then with nobody in control
            bs.finger_over(observer, "hold X +")
            observer.mouse.down()
            observer.wait_for_timeout(600)
            moved = speed(station)
            observer.mouse.up()
            assert moved == 0 and np.array_equal(station.machine.state.position, start)
            # the refusal is told (throttled: the same text at most every 2 s)
            assert any(title == "Jog" and "only observes" in body for _lvl, title, body in observer.capp.messages), \
                observer.capp.messages[-3:]
            holder.release_control()
            observer.get_by_text("Nobody controls the machine. You observe.").filter(visible=True).first.wait_for()
    finally:
        holder.release_control()
    bs.screenshot(observer, "viser-browser-observer")
    # the same press moves the machine once this page takes control (the refusal above was not a dead button)
    take_control(observer, app)
    bs.finger_over(observer, "hold X +")
    observer.mouse.down()
    try:
        # the position, not the sampled velocity: at the probing jog speed a tick moves less than a count,
        # and software WebGL on a busy machine can delay viser's first hold refresh
        bs.wait_until(lambda: station.machine.state.position[0] > start[0] + 0.01, 60.0, "the jog after taking control",
                      why=lambda: (app.control.holder, observer.capp.messages[-3:]))
    finally:
        observer.mouse.up()
    bs.wait_until(lambda: speed(station) < 1e-9, 2.0, "the stop")
    assert station.machine.state.position[0] > start[0]


def test_hold_jog_moves_smoothly_while_held_and_stops_on_release(open_page, app, station, world):
    """Holding "X +" moves at the jog speed while the page's holds keep the jog live (position over the machine's
    own clock, in every window the holds bridged: a stop and re-start would show as a dip), with no dead-man stop
    while they came on time: the page's hold refresher (a Web Worker, whose timers a page busy rendering WebGL
    frames in software does not hold up) refreshes it every 40 ms beside viser's own hold events.
    The release stops the machine, by itself (no dead-man stop after it), within RELEASE_STOP s of machine time of
    reaching the station, and nothing creeps or restarts afterwards. Then the Speed selector: a held jog at "fine"
    and at "positioning" moves at that speed. How fast the browser sends its events is not judged (on a loaded
    machine it is starved of CPU, and the machine must stop when the holds come late): the machine's clock runs
    slow while the button is held (held_on_a_slow_clock), and only the windows the holds kept live are judged."""
    page = open_page()
    take_control(page, app)
    here = station.machine.state.position
    if not 100.0 <= here[0] <= 300.0:  # room on X for the jogs below (at most 150 mm each way)
        page.capp.go_to(200.0, here[1], here[2]).wait(60)
    bs.open_tab(page, "Machine", "Jog")
    bs.screenshot(page, "viser-browser-jog-tab")
    start = station.machine.state.position.copy()
    jog = station.config.speeds.jog_slow  # "probing", the Jog tab's default speed
    timeout = station.config.deadman_timeout
    with bm.JogRecord(station, page.capp) as rec, held_on_a_slow_clock(world):
        bs.finger_over(page, "hold X +")
        page.mouse.down()
        try:
            bs.wait_until(lambda: station.machine.state.position[0] > start[0] + 0.01, 60.0, "the hold jog")
            t0 = station.machine.state.time
            # held for 1.5 s of machine time, and on until the page's holds have kept the jog live for 2 windows
            bs.wait_until(lambda: station.machine.state.time - t0 > 1.5
                           and len(rec.live_speeds(0, t0 + 0.3)) >= 2 or station.machine.state.position[0] > start[0] + 150,
                          HOLD_WALL_LIMIT, "2 windows of a live hold jog", poll=0.1,
                          why=rec.summary)
        finally:
            let_go = station.machine.state.time
            page.mouse.up()
        released, stop, rest = rec.stop_after_release(let_go, "the release of X +")
        assert stop < RELEASE_STOP, f"the machine stopped {stop:.3f} s (machine time) after the release arrived"
        assert not [td for td in rec.deadman if released <= td <= released + stop], \
            "the release did not stop the jog: the dead-man did"
        # nothing creeps or restarts for 0.4 s of machine time after the stop: the reported velocity is whole counts
        # per tick, so the last few micrometres of the stop (servo settling) may still come in after it reads 0
        bs.wait_until(lambda: rec.trace[-1][0] > rest + 0.4, 60.0, "0.4 s of machine time after the stop")
        t, pos, v = rec.arrays()
        after = t >= rest
        assert np.abs(pos[after] - pos[after][0]).max() <= 0.0041, "the machine moved on after the release stopped it"
        # a dead-man stop while held is a failure unless the page's holds did not come for half the dead-man time
        # before it (the browser starved of CPU): then stopping is what the machine must do
        holds = np.sort(np.array(rec.holds))
        for td in rec.deadman:
            window = holds[(holds > td - 2 * timeout) & (holds <= td)]
            gaps = np.diff(np.concatenate([window, [td]]))
            assert len(window) == 0 or gaps.max() >= timeout / 2, \
                f"a dead-man stop at {td:.2f} s while the button was held and refreshed on time: {np.round(gaps, 3)}"
        if rec.deadman:
            print(f"{len(rec.deadman)} dead-man stop(s) while the browser was starved of CPU (holds late)")
        speeds = rec.live_speeds(0, t0 + 0.3, released)
        assert len(speeds) >= 2 and min(speeds) > 0.9 * jog and max(speeds) < 1.1 * jog, (np.round(speeds, 2),
                                                                                          rec.summary())
    stopped = station.machine.state.position
    assert stopped[0] > start[0] and np.allclose(stopped[1:], start[1:])
    assert not page.capp._jogging

    # the speed selector: "fine", then "positioning" chosen on the page; a held jog runs at that speed while the holds
    # keep it live. X - at the fast speed retraces the path just jogged.
    for mode, button, axis_sign, expected in (("fine", "hold X +", 1, station.config.speeds.jog_fine),
                                               ("positioning", "hold X −", -1, station.config.speeds.jog_fast)):
        bs.press_until(page, mode, lambda: page.capp.speed_mode == mode, f"the {mode} speed chosen")
        x0 = station.machine.state.position[0]
        with bm.JogRecord(station, page.capp) as rec, held_on_a_slow_clock(world):
            bs.finger_over(page, button)
            page.mouse.down()
            try:
                bs.wait_until(lambda: axis_sign * (station.machine.state.position[0] - x0) > 0.01, 60.0,
                              f"the {mode} jog")
                t0 = station.machine.state.time
                bs.wait_until(lambda: len(rec.live_speeds(0, t0 + 0.1)) >= 1 or abs(station.machine.state.position[0] - x0) > 120,
                              HOLD_WALL_LIMIT, f"a live {mode} jog", poll=0.1,
                              why=rec.summary)
            finally:
                let_go = station.machine.state.time
                page.mouse.up()
            released, stop, _rest = rec.stop_after_release(let_go, f"the {mode} jog")
            assert stop < RELEASE_STOP, (mode, stop)
            speeds = rec.live_speeds(0, t0 + 0.1, released)  # 400 mm/s^2: at 40 mm/s within 0.1 s
            assert speeds and max(abs(np.array(speeds) / expected - 1)) < 0.1, (mode, np.round(speeds, 3), expected,
                                                                                rec.summary())
        if mode == "positioning":
            bs.screenshot(page, "viser-browser-jog-speed-positioning")
    assert page.log.page_errors == [], page.log.problems


def test_embedded_pendant_shares_the_page_control(open_page, app, station, context):
    """The pendant in the Jog tab acts for its page: it shows "you have control" when the page takes control, jogs
    as the page, and follows the page's release. Its grant cannot be used by another tab (nor a forged one, nor
    after the page closed), and a page from another origin is refused at the handshake as before."""
    page = open_page()
    bs.open_tab(page, "Machine", "Jog")
    frame_el = page.locator('iframe[title="pendant"]')
    frame_el.scroll_into_view_if_needed()
    frame = page.frame_locator('iframe[title="pendant"]')
    control = frame.locator("#control")
    bs.wait_until(lambda: control.inner_text() == "observer", 30.0, "the embedded pendant connected")
    take_control(page, app)
    bs.wait_until(lambda: control.inner_text() == "you have control (with the station page)", 10.0,
                  f"the embedded pendant sharing the page's control (shows {control.inner_text()!r})")
    # hold X + in the embedded pendant: the machine jogs for the page's client, and stops on release
    wait_idle(station, 20)
    start = station.machine.state.position.copy()
    # the pad is below the fold of the 300 px frame (scrolled by script: a cross-origin frame's animation frames,
    # which Playwright's own scrolling waits for, may be throttled while it is partly hidden)
    frame.locator(".pad .xp").evaluate("e => e.scrollIntoView({block: 'center'})")
    page.wait_for_timeout(300)
    box = frame.locator(".pad .xp").bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    try:
        bs.wait_until(lambda: station.machine.state.position[0] > start[0] + 0.5, 20.0, "the embedded pendant's jog")
        bs.screenshot(page, "viser-browser-embedded-pendant-shared")
    finally:
        page.mouse.up()
    assert bs.stop_time(station, station.machine.state.time, "the stop on release") < STOP_WITHIN
    assert app.control.holder == page.capp.client_id  # the pendant never became a holder of its own

    # another tab that copied the token: refused while the embedded pendant uses it; it stays an observer
    token = page.capp.pendant_token
    other = context.new_page()
    try:
        other.goto(f"{app.pendant.url}#as={token}")
        bs.shows(other, "already open in another frame")
        assert other.locator("#control").inner_text() == "observer: another client has control"
        forged = context.new_page()
        forged.goto(f"{app.pendant.url}#as={token[:-2]}xx")
        forged.get_by_text("grant is not valid").filter(visible=True).first.wait_for()
        forged.close()
        # the page releases control: the embedded pendant follows
        bs.press_until(page, "Release", lambda: app.control.holder != page.capp.client_id, "the release")
        bs.wait_until(lambda: control.inner_text() == "observer", 30.0, "the embedded pendant following the release")
        # the page closes: its grant dies with it
        page.close()
        bs.wait_until(lambda: token not in app.pendant.grants._grants, 10.0, "the grant revoked")
        other.reload()
        bs.shows(other, "grant is not valid")
        assert other.locator("#control").inner_text() == "observer"
    finally:
        other.close()


def test_manual_probing_jog_takes_the_hit_at_the_qualified_speed(open_page, app, station, world):
    """Manual probing from the Jog tab: with the armed jog ticked and the *positioning* speed chosen, holding "Z −"
    above the part descends at the probe's qualified speed while the page's holds keep the jog live (position over
    machine time), never faster, and the touch is a manual hit latched at that speed on the top face."""
    page = open_page()
    take_control(page, app)
    bs.open_tab(page, "Machine", "Jog")
    target = station.measurement.part.pose[:3, :3] @ np.array([15.0, 68.0, TOP_Z + 4.0]) + station.measurement.part.pose[:3, 3]
    page.capp.go_to(*target).wait(60)
    # pressed until it takes (a press on a page being re-drawn can be lost; the loaded run lost one here)
    bs.press_until(page, "positioning", lambda: page.capp.speed_mode == "positioning", "the positioning speed")
    bs.tick_until(page, "Manual probing (armed jog)", True, lambda: page.capp.ctx.manual_probe, "the armed jog")
    assert page.capp.speed_mode == "positioning"
    qualified = page.capp.station_probing_speed()
    assert qualified < station.config.speeds.jog_fast / 4
    hits = len(station.measurement.hits)
    bs.finger_over(page, "hold Z −")
    with bm.JogRecord(station, page.capp) as rec, held_on_a_slow_clock(world):
        page.mouse.down()
        try:
            bs.wait_until(lambda: station.machine.state.position[2] < target[2] - 0.05, 60.0, "the armed jog down")
            t0 = station.machine.state.time
            bs.wait_until(lambda: len(station.measurement.hits) > hits, HOLD_WALL_LIMIT,
                          f"the manual hit (Z {station.machine.state.position[2]:.3f}; told {page.capp.messages[-3:]})")
        finally:
            page.mouse.up()
        t, pos, _v = rec.arrays()
    hit = station.measurement.hits[max(station.measurement.hits)]
    # the latched hit: manual, on the top face, at the speed the probe was qualified at (what its pretravel
    # compensation assumes), approaching straight down
    assert hit.mode == "manual" and hit.point[2] == pytest.approx(TOP_Z, abs=0.01)
    assert hit.speed == pytest.approx(qualified) and np.allclose(hit.approach, (0, 0, -1))
    # what the machine did on its way down: never faster than the qualified speed (the armed jog is clamped, though
    # "positioning" was chosen), and at it while the page's holds kept the jog live, before the touch
    near = np.flatnonzero((t >= t0) & (pos[:, 2] <= hit.machine[2] + 0.5))[0]  # 0.5 mm above the touch
    descent = (t >= t0) & (np.arange(len(t)) < near)
    td, zd = t[descent], pos[descent, 2]
    fastest = max(abs(np.interp(w + bm.WINDOW, td, zd) - np.interp(w, td, zd)) / bm.WINDOW
                  for w in np.arange(td[0], td[-1] - bm.WINDOW, bm.WINDOW / 2))
    assert fastest < 1.1 * qualified, (fastest, qualified)
    live = rec.live_speeds(2, t0 + 0.3, td[-1])  # none when the page's holds never kept it live for a window
    assert not live or max(abs(np.array(live) / qualified - 1)) < 0.1, (np.round(live, 3), qualified, rec.summary())
    bs.screenshot(page, "viser-browser-manual-hit")
    assert page.log.page_errors == [], page.log.problems
