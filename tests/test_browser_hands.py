"""The operator's hands in the station page (headless chromium) at 1280 x 800 and on a portrait tablet (820 x 1180,
touch): the armed jog takes one hit per touch, and a run refused or stopped is said where the operator looks.

One hit per touch: the armed jog's button is held onto the part (with the mouse at 1280 x 800, with a finger on the
tablet: touch events, which the page turns into pointer events); the touch takes one hit, the probe backs off, and
the still-held button drives nothing in again for 3 s of machine time; let go and pressed again, it takes the next
hit. Asserted on the station's hits and the simulator's clock, never on wall time.

A refused or stopped run: a DMIS program whose straight line passes through the part is refused before anything
moves, and a routine run stopped with the status block's STOP: each is a toast and the status block's state
(STOPPED and why), not only a line in a folder, and the status block does not say stopped while an axis moves.
"""

from __future__ import annotations

import pytest

import browser_support as bs
import browser_moves as bm
from dmis_programs import APPROACH, FRONT_FACE, program

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(900),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")

LAPTOP = (1280, 800)
TABLET = (820, 1180)
ABOVE_TOP_FACE = [250.0, 190.0, 42.5]  # machine mm: 2.5 mm above the simulator part's top face (Z 40) with a 1 mm tip


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    yield from bs.sim_station(tmp_path_factory, "hands")


@pytest.fixture(scope="module")
def app(station):
    yield from bs.station_app(station, pendant_port=0)


class Finger:
    """Holds a button with the mouse (laptop) or a finger (touch events through the DevTools protocol)."""

    def __init__(self, page, touch: bool) -> None:
        self.page, self.touch = page, touch
        self.cdp = page.context.new_cdp_session(page) if touch else None
        self.at = (0.0, 0.0)

    def down(self, name: str) -> None:
        self.at = bs.finger_over(self.page, name)
        if self.touch:
            self.cdp.send("Input.dispatchTouchEvent",
                          {"type": "touchStart", "touchPoints": [{"x": self.at[0], "y": self.at[1]}]})
        else:
            self.page.mouse.down()

    def up(self) -> None:
        if self.touch:
            self.cdp.send("Input.dispatchTouchEvent", {"type": "touchEnd", "touchPoints": []})
        else:
            self.page.mouse.up()


def _hold(page, station, finger, name, done, what, then_s: float = 0.0, limit: float = 240.0) -> None:
    """``name`` held (on the simulator's hand pace) until ``done()``, then ``then_s`` s of machine time more."""
    network = station.sim.network
    pace = network.pace
    network.set_pace(bm.HAND_PACE)
    try:
        finger.down(name)
        try:
            bs.wait_until(done, limit, what, why=lambda: f"Z {station.machine.state.position[2]:.3f}, "
                                                        f"told {page.capp.messages[-3:]}")
            t = station.machine.state.time
            bs.wait_until(lambda: station.machine.state.time > t + then_s, 120.0, f"{then_s:g} s held past {what}")
        finally:
            finger.up()
    finally:
        network.set_pace(pace)
    bs.wait_until(lambda: not station.machine.state.jogging, 60.0, "the jog's end")


def _held_until(page, station, finger, done, what, then_s: float = 0.0) -> None:
    """``hold Z −`` held until ``done()``. A jog that a late page's dead-man ended while it braked onto the part
    touched without a hit (a contact, not a hit: the station then refuses a jog on into the part); the operator
    jogs off the surface (``hold Z +`` until the probe is free) and presses again, as jog_to_touch does."""
    model = station.measurement
    for _ in range(4):
        state = station.machine.state
        if state.probe_triggered:
            _hold(page, station, finger, "hold Z +", lambda: not station.machine.state.probe_triggered,
                  "the probe free again", limit=120.0)
        n = len(model.hits)
        _hold(page, station, finger, "hold Z −",
              lambda: done() or len(model.hits) > n or station.machine.state.probe_triggered, what, then_s=then_s)
        if done():
            return
    raise AssertionError(f"{what} did not happen in four presses; told {page.capp.messages[-3:]}")


@pytest.mark.parametrize("size", [LAPTOP, TABLET], ids=["1280x800", "tablet-touch"])
def test_one_hit_per_touch_and_a_new_press_takes_the_next(app, station, size):
    touch = size == TABLET
    options = {"has_touch": True, "is_mobile": True} if touch else {}
    with bs.browser_context(viewport=size, **options) as context:
        page = bs.open_page(context, app, size)
        bs.press_until(page, "Take control", lambda: app.control.holder == page.capp.client_id, "control taken")
        if station.controller.state.mode.value != "idle":
            page.capp.reset()
        bs.wait_until(lambda: station.controller.state.mode.value == "idle", 60.0, "the machine idle")
        bs.open_tab(page, "Machine", "Jog")
        page.capp.go_to(ABOVE_TOP_FACE, frame="machine").wait(120)
        bs.tick_until(page, "Manual probing (armed jog)", True, lambda: page.capp.ctx.manual_probe, "the armed jog")
        model = station.measurement
        before = len(model.hits)
        finger = Finger(page, touch)
        # held onto the part, and 3 s of machine time past the touch: one hit, backed off, nothing driven in again
        _held_until(page, station, finger, lambda: len(model.hits) > before, "the touch's hit", then_s=3.0)
        assert len(model.hits) == before + 1, [model.hits[h].machine for h in sorted(model.hits)[before:]]
        first = model.hits[max(model.hits)]
        assert first.mode == "manual"
        assert station.machine.state.position[2] > first.machine[2] + 0.5  # backed off, and stayed there
        # let go, then a new press: the next hit, at the same face
        _held_until(page, station, finger, lambda: len(model.hits) > before + 1, "the new press's hit")
        assert len(model.hits) == before + 2
        second = model.hits[max(model.hits)]
        assert second.mode == "manual" and abs(second.point[2] - first.point[2]) < 0.01, (first.point, second.point)
        bs.tick_until(page, "Manual probing (armed jog)", False, lambda: not page.capp.ctx.manual_probe,
                      "the armed jog unticked")
        bs.screenshot(page, f"hands-one-hit-{size[0]}x{size[1]}")
        bs.press(page, "Release")
        bs.wait_until(lambda: app.control.holder is None, 30.0, "the release")
        assert page.log.page_errors == [], page.log.problems


# three hits on the simulator part's front face (its set-up at the part's true place), with moves between them
FRONT = program("front", APPROACH, "GOTO/60, -30, 60\nGOTO/20, -30, 60\nGOTO/100, -30, 60\nGOTO/20, -15, 20\n",
                FRONT_FACE)
# from in front of the front face, below the part's top, straight through the part to its back
THROUGH = program("through", "GOTO/60, 90, 20\n")


def _status(page) -> str:
    return page.locator("#cmm-status").inner_text()


def _run_dmis_in_page(page, name: str) -> None:
    """Routine tab, *DMIS program* folder: the program's file name typed into *DMIS file*, *Open DMIS* (checked), then *Run DMIS*."""
    panel = page.capp.routine
    bs.open_folder(page, "DMIS program", "DMIS file")
    bs.text_field(page, "DMIS file").fill(name)
    bs.typed(page, "DMIS file", name)
    bs.press_until(page, "Open DMIS", lambda: panel.dmis is not None and panel.dmis[0].name == name,
                   f"{name} opened", every=20.0)
    before = len(page.capp.messages)
    bs.press_until(page, "Run DMIS", lambda: panel.dmis_running or len(page.capp.messages) > before,
                   f"{name} started or refused", every=30.0)


def test_a_refused_and_a_stopped_dmis_run_are_toasts_and_the_status_block_says_stopped(app, station):
    """Run DMIS refused (its straight line passes through the part) is a toast and the status block's STOPPED with
    the program and why, not only a line in the Routine tab; a DMIS run stopped with the status block's STOP while
    it moves is a toast too, and the status block says STOPPED only once every axis stands."""
    from cmm.sim.cmm_sim import TRUE_PART_POSE
    import numpy as np

    folder = station.measurement.session_dir
    (folder / "through.dmi").write_text(THROUGH)
    (folder / "front.dmi").write_text(FRONT)
    with bs.browser_context(viewport=LAPTOP) as context:
        page = bs.open_page(context, app, LAPTOP)
        bs.press_until(page, "Take control", lambda: app.control.holder == page.capp.client_id, "control taken")
        if station.controller.state.mode.value != "idle":
            page.capp.reset()
        bs.wait_until(lambda: station.controller.state.mode.value == "idle", 60.0, "the machine idle")
        # the tip 3 mm in front of the front face, below the part's top (where a routine's last hit leaves it)
        page.capp.go_to(list(TRUE_PART_POSE @ np.array([60.0, -30.0, 60.0, 1.0]))[:3], frame="machine").wait(120)
        page.capp.go_to(list(TRUE_PART_POSE @ np.array([60.0, -3.0, 20.0, 1.0]))[:3], frame="machine").wait(120)
        bs.open_tab(page, "Routine")
        _run_dmis_in_page(page, "through.dmi")
        bs.shows(page, "DMIS program stopped", station_has=lambda: page.capp.messages[-3:])  # the toast
        assert any(t == "DMIS program stopped" and "straight line" in b for _l, t, b in page.capp.messages[-3:])
        bs.wait_until(lambda: "through.dmi stopped" in _status(page), 60.0, "the status block's STOPPED",
                      why=lambda: _status(page))
        text = _status(page)
        assert "STOPPED" in text and "IDLE" not in text, text
        assert np.allclose([a.velocity for a in station.machine.state.axes], 0.0)  # nothing moved
        bs.screenshot(page, "hands-dmis-refused")

        # a program that runs: STOP pressed in the status block while the machine moves
        _run_dmis_in_page(page, "front.dmi")
        bs.wait_until(lambda: page.capp.routine.dmis_running and max(
            abs(a.velocity) for a in station.machine.state.axes) > 1.0, 120.0, "the program moving the machine",
            why=lambda: page.capp.messages[-3:])
        bs.wait_until(lambda: "RUNNING" in _status(page), 60.0, "the status block's RUNNING", why=lambda: _status(page))
        last = page.capp.messages[-1]  # the list keeps the last 50: what came after is found by identity

        def after_stop() -> list:
            shown = list(page.capp.messages)
            mark = max((i for i, m in enumerate(shown) if m is last), default=-1)
            return shown[mark + 1:]

        page.get_by_role("button", name="STOP", exact=True).click()
        # the status block says STOPPED (and no message while the run runs) only once the axes stand: watched while
        # it brakes
        end = station.machine.state.time + 10.0
        while station.machine.state.time < end and "STOPPED" not in _status(page):
            # the page is read before the machine: a STOPPED seen while an axis still moves afterwards was early
            text = _status(page).upper()
            said = [(t, b) for _l, t, b in after_stop() if "stopped" in (t + b).lower()
                    ] if page.capp.routine.dmis_running else []  # the run's end may be told while it brakes
            # more than a count a tick (a servo holding its place may move one either way)
            moving = max(abs(a.counts_per_tick) for a in station.machine.state.axes) > 1
            if moving:
                assert "STOPPED" not in text, f"the status block says stopped while an axis moves: {text}"
                assert not said, f"a message says stopped while an axis moves: {said}"
        bs.wait_until(lambda: "STOPPED" in _status(page), 60.0, "the status block's STOPPED", why=lambda: _status(page))
        # and the axes stand: within a count of where they are for the next 0.3 s of machine time
        rest, since = np.array(station.machine.state.counts), station.machine.state.time
        while station.machine.state.time < since + 0.3:
            drift = np.abs(np.array(station.machine.state.counts) - rest)
            assert drift.max() <= 1, f"an axis moved {drift} counts after the status block said STOPPED"
            station.controller.clock.sleep(0.005)
        bs.shows(page, "DMIS program stopped", station_has=lambda: page.capp.messages[-3:])  # the toast
        bs.wait_until(lambda: not page.capp.routine.dmis_running, 60.0, "the run's end")
        bs.screenshot(page, "hands-dmis-stopped")
        assert page.log.page_errors == [], page.log.problems
