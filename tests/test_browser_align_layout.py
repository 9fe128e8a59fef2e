"""The prompted hand alignment in the page and the room to work, in headless chromium at 1280 x 800 (a laptop) and
820 x 1180 (a tablet): once control is taken the status block (state, holder, DRO, link, STOP and E-STOP on one
row) and the folded Control folder leave at least 60 % of the panel's height to the tabs, the status block covers
nothing, and the plane-line-point wizard marks, counts, fits and aligns. The screenshots go to docs/images/ for the
README and the operator's guide."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import browser_support as bs

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(900),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")

from cmm.metrology.transform import invert  # noqa: E402
from cmm.sim.cmm_sim import TRUE_PART_POSE  # noqa: E402

LAPTOP = (1280, 800)
TABLET = (820, 1180)
IMAGES = Path(__file__).resolve().parents[1] / "docs" / "images"

# the side panel's parts, by layout: its scroll box, the pinned status block, the Control folder, the tab bar
LAYOUT_JS = """() => {
  const box = e => { const b = e.getBoundingClientRect(); return {top: b.top, bottom: b.bottom, left: b.left, right: b.right}; };
  const bar = document.getElementById("cmm-status");
  let panel = bar; while (panel && !/(auto|scroll)/.test(getComputedStyle(panel).overflowY)) panel = panel.parentElement;
  const pinned = bar.closest(".mantine-Paper-root");
  const control = [...document.querySelectorAll(".mantine-Paper-root")].find(p => p.firstElementChild
      && p.firstElementChild.classList.contains("mantine-Paper-root") && p.firstElementChild.textContent.trim() === "Control");
  const tabs = [...document.querySelectorAll("[role=tablist]")].find(t => t.textContent.includes("Align"));
  const button = n => [...document.querySelectorAll("button")].find(b => b.textContent.trim() === n);
  const c = box(control);
  const atControl = document.elementFromPoint((c.left + c.right) / 2, c.top + 3);
  return {panel: box(panel), pinned: box(pinned), control: c, tabs: box(tabs), stop: box(button("STOP")),
          estop: box(button("E-STOP")), controlOnTop: control.contains(atControl),
          viewport: [window.innerWidth, window.innerHeight]};
}"""


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    yield from bs.sim_station(tmp_path_factory, "align-layout")


@pytest.fixture(scope="module")
def app(station):
    yield from bs.station_app(station, pendant=False)


def _take_control(page, app):
    bs.press_until(page, "Take control", lambda: app.control.holder == page.capp.client_id, "taking control")
    # the Control folder folds: its name, code and Take control fields leave the page
    take = page.get_by_role("button", name="Take control", exact=True)
    bs.wait_until(lambda: take.count() == 0, 60.0, "the Control folder folding", poll=0.2,
                  why=lambda: f"{take.count()} buttons; the station's is visible: {page.capp.gui['take'].visible}")


def _assert_room(page, where):
    m = page.evaluate(LAYOUT_JS)
    panel, pinned, control, tabs = m["panel"], m["pinned"], m["control"], m["tabs"]
    height = panel["bottom"] - panel["top"]
    work = panel["bottom"] - tabs["top"]
    assert work >= 0.6 * height, f"{where}: the tabs have {work:.0f} of the panel's {height:.0f} px: {m}"
    assert pinned["bottom"] <= control["top"] + 0.5, f"{where}: the status block overlaps the Control folder: {m}"
    assert m["controlOnTop"], f"{where}: something covers the top of the Control folder"
    w, h = m["viewport"]
    for name in ("stop", "estop"):  # STOP and E-STOP on screen, side by side, in the pinned block
        b = m[name]
        assert 0 <= b["top"] and b["bottom"] <= h and 0 <= b["left"] and b["right"] <= w, (where, name, b)
        assert pinned["top"] <= b["top"] and b["bottom"] <= pinned["bottom"], (where, name)
    assert abs(m["stop"]["top"] - m["estop"]["top"]) < 1.0, f"{where}: STOP and E-STOP not on one row"
    return work / height


def test_room_to_work_at_1280x800_and_on_a_tablet(app):
    IMAGES.mkdir(parents=True, exist_ok=True)
    shares = {}
    for name, size in (("1280x800", LAPTOP), ("tablet", TABLET)):
        with bs.browser_context(size, device_scale_factor=1) as context:  # README-sharp screenshots
            page = bs.open_page(context, app, size)
            _take_control(page, app)
            # measured once the panel has laid out the folded Control folder (viser applies one message at a time)
            bs.wait_until(lambda: page.evaluate(LAYOUT_JS)["tabs"]["top"] < 0.5 * size[1], 60.0, "the panel laid out",
                          poll=0.5)
            shares[name] = _assert_room(page, name)
            page.wait_for_timeout(1500)  # the 3-D view drawn (software WebGL)
            page.screenshot(path=str(IMAGES / f"station-{name}.png"), timeout=bs.PAGE_WAIT_MS)
            bs.press(page, "Release")
            bs.wait_until(lambda: app.control.holder is None, 30.0, "the release")
    assert all(s >= 0.6 for s in shares.values()), shares


def test_the_prompted_plane_line_point_alignment_in_the_page(app, station):
    with bs.browser_context(LAPTOP, device_scale_factor=1) as context:
        page = bs.open_page(context, app, LAPTOP)
        _take_control(page, app)
        bs.open_tab(page, "Align")
        bs.press(page, "Start alignment")
        bs.shows(page, "Step 1 of 3: touch the top face at the markers (primary plane): hit 1 of 3")
        capp = page.capp
        w = capp.align.wizard
        assert w is not None and w.kind == "plane-line-point" and len(capp.align._markers) == 6  # 3 spheres, 3 arrows
        for taken in range(1, 7):
            # pressed again only if the press was lost (a panel re-drawn under it): a press while the hit is
            # taken is ignored, one touch per press
            bs.press_until(page, "Touch at the marker", lambda: sum(len(s.hit_ids) for s in w.steps) >= taken,
                           f"hit {taken} counted", timeout=240.0, every=20.0)
            if taken == 3:  # the plane fitted and shown, the next element prompted with its own markers
                bs.shows(page, "primary plane: 3 of 3 hits: normal")
                bs.shows(page, "Step 2 of 3: touch the front face at the markers (secondary line): hit 1 of 2")
                page.screenshot(path=str(IMAGES / "align-wizard.png"), timeout=bs.PAGE_WAIT_MS)
        bs.shows(page, "Alignment computed")
        assert sum(len(s.hit_ids) for s in w.steps) == 6  # exactly the hits asked for
        assert w.steps[1].feature.nominal is None and w.steps[2].feature.nominal is None  # no CAD nominal needed
        bs.press_until(page, "Apply this alignment", lambda: w.applied, "the alignment applied", timeout=120.0,
                       every=30.0)
        bs.shows(page, "Alignment applied.", station_has=lambda: (capp.align.wizard_text(), capp.messages[-3:]))
        d = station.measurement.part.pose @ invert(TRUE_PART_POSE)
        assert np.linalg.norm(d[:3, 3]) < 0.02
        assert np.degrees(np.arccos(min(1.0, (np.trace(d[:3, :3]) - 1) / 2))) < 0.01
        # the Features tab names the alignment's frame
        bs.open_tab(page, "Measure", "Features")
        bs.shows(page, "part coordinates (3-2-1 ALN primary plane/ALN secondary line/ALN tertiary point)")
        assert not page.log.page_errors, page.log.page_errors
