"""Setup > Part in headless chromium at 1280 x 800: the NIST simple part's STEP file (read in place from the shared
folder) is uploaded where the fields place it, placed again turned otherwise, and "Next part" puts the simulator's
part down moved and turned from there. Screenshot: test-artifacts/part-next.png."""

from __future__ import annotations

import numpy as np
import pytest

import browser_support as bs
from shared_refs import require

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(600),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")
pytest.importorskip("OCP")

from cmm.sim.cmm_sim import pose_matrix  # noqa: E402


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    yield from bs.sim_station(tmp_path_factory, "part-page")


@pytest.fixture(scope="module")
def app(station):
    yield from bs.station_app(station, pendant=False)


def press_shown(page, name):
    button = page.get_by_role("button", name=name, exact=True).filter(visible=True).first
    button.wait_for()
    button.evaluate("b => b.click()")


def field_inputs(page, label):
    return page.locator(f"xpath=//label[normalize-space()='{label}']/ancestor::div[contains(@class, "
                        "'mantine-Flex-root')][1]//input")


def enter(field, value):
    field.fill(f"{value:g}")
    field.press("Enter")


def test_a_step_part_is_loaded_placed_and_the_next_part_put_down_turned(app, station):
    stp = require("cad", "ipp_simple.stp")
    with bs.browser_context(viewport=(1280, 800)) as ctx:
        page = bs.open_page(ctx, app)
        panel = page.capp.part
        press_shown(page, "Take control")
        bs.shows(page, "You control the machine.")
        bs.open_tab(page, "Setup", "Part")
        origin = field_inputs(page, "Part origin X, Y, Z (mm)")
        for k, v in enumerate((150.0, 120.0, 0.0)):
            enter(origin.nth(k), v)
        enter(field_inputs(page, "Turned about Z (°)").first, 30.0)
        bs.wait_until(lambda: np.allclose(panel.pose_fields(), [150.0, 120.0, 0.0, 30.0]), 60.0,
                      "the pose typed into the fields", why=panel.pose_fields)
        uuid = page.get_by_role("button", name="Load part file", exact=True).filter(visible=True).first.get_attribute("id")
        page.locator(f'[id="file_upload_{uuid}"]').set_input_files(str(stp))
        model = station.measurement
        bs.wait_until(lambda: model.part is not None and model.part.name == "ipp_simple.stp", 300.0,
                      "the STEP part loaded", why=lambda: page.capp.messages[-2:])
        np.testing.assert_allclose(station.sim.settings.part_pose, pose_matrix((150.0, 120.0, 0.0), rz_deg=30.0),
                                   atol=1e-9)
        bs.shows(page, "ipp_simple.stp")
        # placed again, turned 20 degrees instead
        enter(field_inputs(page, "Turned about Z (°)").first, 20.0)
        bs.wait_until(lambda: panel.pose_fields()[3] == 20.0, 60.0, "the new turn in the field")
        press_shown(page, "Place")
        placed = pose_matrix((150.0, 120.0, 0.0), rz_deg=20.0)
        # the simulator's table first, then the station's nominal (the STEP file is read again): both in the end
        bs.wait_until(lambda: np.allclose(station.sim.settings.part_pose, placed, atol=1e-9)
                      and np.allclose(model.part.pose, placed, atol=1e-9), 300.0, "the placing",
                      why=lambda: (page.capp.messages[-2:], model.part.pose[:2].round(6).tolist()))
        # the next part (the simulator's only): moved by the fields' 5, -3 mm and turned 2 degrees more
        press_shown(page, "Next part")
        moved = pose_matrix((155.0, 117.0, 0.0), rz_deg=22.0)
        bs.wait_until(lambda: np.allclose(station.sim.settings.part_pose, moved, atol=1e-9), 300.0, "the next part",
                      why=lambda: page.capp.messages[-2:])
        np.testing.assert_allclose(model.part.pose, placed, atol=1e-9)  # the station finds it by aligning
        bs.shows(page, "the part now lies at X 155.000 Y 117.000")
        bs.screenshot(page, "part-next")
        assert not page.log.page_errors, page.log.page_errors
