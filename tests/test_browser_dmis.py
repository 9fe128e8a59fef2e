"""A DMIS program in the Routine tab of headless chromium at 1280 x 800: uploaded from the operator's computer,
checked and listed, run; the program asks the operator (TEXT/MAN), the operator pauses the run and answers, the
page shows PAUSED with the progress bar, Resume finishes it and the page shows DONE with the program's results.
Screenshot: test-artifacts/dmis-paused.png, dmis-done.png."""

from __future__ import annotations

import pytest

import browser_support as bs

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(600),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")

PROGRAM = """FILNAM/'page'
UNITS/MM, ANGDEC
D(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0
SNSET/APPRCH, 5
SNSET/RETRCT, 5
GOTO/70, 22, 70
F(PT) = FEAT/POINT, CART, 70, 22, 55, 0, 0, 1
TEXT/MAN, 'Clamp the part'
MEAS/POINT, F(PT), 1
  PTMEAS/CART, 70, 22, 55, 0, 0, 1
ENDMES
GOTO/70, 22, 70
OUTPUT/FA(PT)
ENDFIL
"""


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    yield from bs.sim_station(tmp_path_factory, "dmis-page")


@pytest.fixture(scope="module")
def app(station):
    yield from bs.station_app(station, pendant=False)


def press_shown(page, name):
    """Press the visible button ``name`` (other tabs hold buttons of the same name, hidden)."""
    button = page.get_by_role("button", name=name, exact=True).filter(visible=True).first
    button.wait_for()
    button.evaluate("b => b.click()")


def upload(page, button, path):
    """The file ``path`` chosen in the upload button ``button`` (viser's hidden file input beside it)."""
    uuid = page.get_by_role("button", name=button, exact=True).filter(visible=True).first.get_attribute("id")
    page.locator(f'[id="file_upload_{uuid}"]').set_input_files(str(path))


def test_a_dmis_program_is_uploaded_run_paused_and_resumed_in_the_routine_tab(app, station, tmp_path):
    with bs.browser_context(viewport=(1280, 800)) as ctx:
        page = bs.open_page(ctx, app)
        panel = page.capp.routine
        press_shown(page, "Take control")
        bs.shows(page, "You control the machine.")
        bs.open_tab(page, "Routine")
        bs.open_folder(page, "DMIS program", "Upload DMIS")
        program = tmp_path / "page.dms"
        program.write_text(PROGRAM)
        upload(page, "Upload DMIS", program)
        bs.wait_until(lambda: panel.dmis is not None, 120.0, "the uploaded program checked",
                      why=lambda: page.capp.messages[-2:])
        bs.shows(page, "14 statements, all supported")
        press_shown(page, "Run DMIS")
        bs.wait_until(lambda: panel.dmis_question, 300.0, "the program's question", why=lambda: panel.dmis_status)
        bs.shows(page, "QUESTION")
        # paused while it asks: answered, it holds before its next statement (the point's MEAS)
        press_shown(page, "Pause")
        press_shown(page, "Answer")
        bs.wait_until(lambda: panel.dmis_status.startswith("**PAUSED**"), 300.0, "the pause",
                      why=lambda: panel.dmis_status)
        bs.shows(page, "paused before line 9: MEAS/POINT")
        page.locator(".mantine-Progress-root").filter(visible=True).first.wait_for()
        assert panel.gui["bar"].value > 0  # the statements before the point's MEAS: over half the program
        bs.screenshot(page, "dmis-paused")
        press_shown(page, "Resume")
        bs.wait_until(lambda: not panel.dmis_running and panel.dmis_status.startswith(("**DONE**", "**STOPPED**")),
                      300.0, "the program's end", why=lambda: panel.dmis_status)
        assert panel.dmis_status.startswith("**DONE**: 1 features, 1 hits"), panel.dmis_status
        bs.shows(page, "DONE")
        (result,) = panel.dmis_results
        assert "FA(PT) = FEAT/POINT" in result.outputs[None]
        assert any(line.endswith("paused by the operator") for line in result.log), result.log
        bs.screenshot(page, "dmis-done")
        assert not page.log.page_errors, page.log.page_errors
