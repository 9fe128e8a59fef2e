"""The Routine tab in headless chromium (1280 x 800, then the tablet size): a routine taught from the session
the operator measured, a step renamed in the page, and "Run on next part" on a part placed differently on the
simulator: the page prompts for the manual 3-2-1 hits, the operator takes them, the rest runs by itself, and
the page shows the progress and DONE. Screenshots go to test-artifacts/routine-*.png."""

from __future__ import annotations

import re

import numpy as np
import pytest

import browser_support as bs

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(600),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")

from cmm.measurement.alignment import align_features, apply  # noqa: E402
from cmm.measurement.plan import plan_at_pick, run_plan  # noqa: E402
from cmm.metrology.transform import invert  # noqa: E402
from cmm.sim.cmm_sim import TRUE_PART_POSE, pose_matrix  # noqa: E402

LAPTOP = (1280, 800)
TABLET = (820, 1180)
SECOND_POSE = pose_matrix((194.0, 147.0, 0.0), rz_deg=2.0)
# (name, ray origin in part coordinates, direction, hits per ring)
FACES = [("TOP", (20.0, 10.0, 100.0), (0, 0, -1), 3), ("FRONT", (20.0, -50.0, 20.0), (0, 1, 0), 3),
         ("LEFT", (-50.0, 10.0, 20.0), (1, 0, 0), 3), ("bore", (30.0, 40.0, 20.0), (1, 0, 0), 4)]
MANUAL = [((15.0, 10.0, 40.0), (0, 0, -1)), ((105.0, 12.0, 40.0), (0, 0, -1)), ((50.0, 70.0, 40.0), (0, 0, -1)),
          ((15.0, 0.0, 15.0), (0, 1, 0)), ((105.0, 0.0, 15.0), (0, 1, 0)), ((0.0, 20.0, 15.0), (1, 0, 0))]


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    yield from bs.sim_station(tmp_path_factory, "routine")


@pytest.fixture(scope="module")
def app(station):
    yield from bs.station_app(station, pendant_port=0)


def press(page, name):
    """Click a button as a person would, without Playwright's wait for animation frames (a software-rendered
    WebGL page on a loaded machine gives few)."""
    button = page.get_by_role("button", name=name, exact=True)
    button.wait_for(timeout=120_000)  # software WebGL on a loaded 2-core machine: the page answers late
    button.evaluate("b => b.click()", timeout=120_000)


def _measured_first_part(station):
    """What the operator did on the first part: three planes and the bore auto-measured, a 3-2-1."""
    model = station.measurement
    model.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
    ids = {}
    for name, origin, direction, n in FACES:
        pose = model.part.pose
        picked = model.pick((pose @ np.array([*origin, 1.0]))[:3], pose[:3, :3] @ np.array(direction, float))
        ids[name] = run_plan(model, plan_at_pick(model, picked[0].face_id, n=n), name=name).id
    apply(model, align_features(model, ids["TOP"], ids["FRONT"], ids["LEFT"]))


def test_teach_rename_and_run_the_routine_on_the_next_part_from_the_page(app, station):
    _measured_first_part(station)
    with bs.browser_context(LAPTOP) as context:
        page = bs.open_page(context, app)
        capp = page.capp
        press(page, "Take control")
        page.get_by_text("You control the machine.").first.wait_for()
        bs.open_tab(page, "Routine")
        page.get_by_text("No routine yet").first.wait_for()
        press(page, "Teach from this session")
        page.get_by_text("align 3-2-1: TOP | FRONT | LEFT (manual hits, then automatic)").first.wait_for()
        page.get_by_text("bore: cylinder, 8 hits, ls").first.wait_for()

        # rename the bore in the page
        choose_step(page, 5)
        bs.text_field(page, "New name").fill("BORE")
        bs.text_field(page, "New name").press("Enter")
        page.wait_for_timeout(300)
        press(page, "Rename")
        page.get_by_text(re.compile(r"BORE: cylinder, 8 hits, ls")).first.wait_for()  # case-sensitive: renamed
        assert capp.routine.routine.program.feature("BORE")
        bs.screenshot(page, "routine-taught")

        # the next part stands elsewhere; Run on next part
        station.sim.place_part(SECOND_POSE)
        bs.text_field(page, "Part name").fill("SN-0002")
        bs.text_field(page, "Part name").press("Enter")
        page.wait_for_timeout(300)
        press(page, "Run on next part")
        page.get_by_text("WAITING FOR THE OPERATOR").first.wait_for()
        page.get_by_text("Take 3 hits by hand on TOP (primary datum)").first.wait_for()
        bs.screenshot(page, "routine-prompt")
        model = station.measurement
        for k, (p, u) in enumerate(MANUAL):  # the operator's hands: each hit where the part really is
            if k == 3:
                page.get_by_text("Take 2 hits by hand on FRONT (secondary datum)").first.wait_for()
            if k == 5:
                page.get_by_text("Take 1 hit by hand on LEFT (tertiary datum)").first.wait_for()
            target = (SECOND_POSE @ np.array([*p, 1.0]))[:3]
            bs.wait_until(lambda: not station.controller.state.mode.value.startswith("prob"), 30.0, "idle")
            model.probe(target, SECOND_POSE[:3, :3] @ np.array(u, float), clearance_z=90.0).wait(120)
        page.get_by_text("RUNNING").first.wait_for()
        bs.wait_until(lambda: capp.routine.run_.progress.state in ("done", "failed"), 400.0, "the routine's end")
        assert capp.routine.run_.progress.state == "done", capp.routine.run_.progress.message
        page.get_by_text("DONE").first.wait_for()
        bs.screenshot(page, "routine-done")
        progress = capp.routine.run_.progress
        delta = model.part.pose @ invert(SECOND_POSE)
        assert np.linalg.norm(delta[:3, 3]) < 0.02  # aligned on the second part (3-hit datum planes: each a few um off)
        bore = progress.results["BORE"]
        assert bore.result.geometry()["radius"] == pytest.approx(15.0, abs=0.005)
        assert "SN-0002" in str(progress.session)

        page.set_viewport_size({"width": TABLET[0], "height": TABLET[1]})
        page.wait_for_timeout(500)
        box = page.get_by_role("button", name="Run on next part").bounding_box()
        assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= TABLET[0]
        bs.screenshot(page, "routine-tablet")
        assert not page.log.page_errors, page.log.page_errors


def choose_step(page, number):
    """Select step ``number`` (1-based) in the Step dropdown, as the operator does."""
    page.get_by_label("Step", exact=True).click(force=True)
    page.get_by_role("option", name=re.compile(rf"^{number}\. ")).first.click(force=True)
    page.wait_for_timeout(300)

