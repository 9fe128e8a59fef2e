"""The prompted hand alignment in the page and the room to work, in headless chromium at 1280 x 800 (a laptop) and
820 x 1180 (a tablet): before and once control is taken the status block (state, holder, DRO, link; STOP and E-STOP
on one row, Take control or Release beside the DRO's frame) and the folded operator name leave at least 60 % of the
panel's height to the tabs, the status block covers nothing, and the plane-line-point wizard marks, counts, fits and
aligns. The screenshots go to docs/images/ for the
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
PHONE = (390, 844)
IMAGES = Path(__file__).resolve().parents[1] / "docs" / "images"

# the side panel's parts, by layout: its scroll box and the height it may grow to (the tallest the panel is: a short
# tab shrinks the box, not the room), the pinned status block, the tab bar, the buttons always at hand, the 3-D view
# and the keyboard hint on it
LAYOUT_JS = """() => {
  const box = e => { if (!e) return null; const b = e.getBoundingClientRect();
                     return {top: b.top, bottom: b.bottom, left: b.left, right: b.right}; };
  const bar = document.getElementById("cmm-status");
  let panel = bar; while (panel && !/(auto|scroll)/.test(getComputedStyle(panel).overflowY)) panel = panel.parentElement;
  let limit = panel.getBoundingClientRect().bottom;
  for (let e = panel; e; e = e.parentElement) {
    const max = getComputedStyle(e).maxHeight;
    if (max.endsWith("px")) { limit = Math.max(limit, e.getBoundingClientRect().top + parseFloat(max)); break; }
  }
  const pinned = bar.closest(".mantine-Paper-root");
  const tabs = [...document.querySelectorAll("[role=tablist]")].find(t => t.textContent.includes("Align"));
  const button = n => [...document.querySelectorAll("button")].find(b => b.textContent.trim() === n
                                                                     && b.getClientRects().length);
  const t = box(tabs);
  const atTabs = document.elementFromPoint((t.left + t.right) / 2, t.top + 3);
  const canvas = [...document.querySelectorAll("canvas")].sort((a, b) => b.width * b.height - a.width * a.height)[0];
  return {panel: box(panel), limit, pinned: box(pinned), tabs: t, tabsOnTop: tabs.contains(atTabs),
          stop: box(button("STOP")), estop: box(button("E-STOP")), take: box(button("Take control")),
          release: box(button("Release")), view: box(canvas), hint: box(document.getElementById("cmm-view-keys")),
          viewport: [window.innerWidth, window.innerHeight]};
}"""
GIZMO_PX = 90  # viser's axis gizmo: the bottom-left 90 px of the 3-D view


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    yield from bs.sim_station(tmp_path_factory, "align-layout")


@pytest.fixture(scope="module")
def app(station):
    yield from bs.station_app(station, pendant_port=0)  # the pendant server: the view's keyboard hint is drawn


def _take_control(page, app):
    bs.press_until(page, "Take control", lambda: app.control.holder == page.capp.client_id, "taking control")
    # the name folder and Take control leave the page, Release takes the button's place
    take = page.get_by_role("button", name="Take control", exact=True)
    bs.wait_until(lambda: take.count() == 0, 60.0, "the Control folder folding", poll=0.2,
                  why=lambda: f"{take.count()} buttons; the station's is visible: {page.capp.gui['take'].visible}")
    page.get_by_role("button", name="Release", exact=True).wait_for()


def _overlap(a, b) -> bool:
    return a["left"] < b["right"] and b["left"] < a["right"] and a["top"] < b["bottom"] and b["top"] < a["bottom"]


def _assert_room(page, where, control_button):
    """The share of the panel's height below the top of the tab bar, with the checks of the layout around it."""
    m = page.evaluate(LAYOUT_JS)
    panel, pinned, tabs = m["panel"], m["pinned"], m["tabs"]
    height = m["limit"] - panel["top"]
    work = m["limit"] - tabs["top"]
    assert work >= 0.6 * height, f"{where}: the tabs have {work:.0f} of the panel's {height:.0f} px: {m}"
    assert pinned["bottom"] <= tabs["top"] + 0.5 and m["tabsOnTop"], f"{where}: the status block covers the tabs: {m}"
    w, h = m["viewport"]
    for name in ("stop", "estop", control_button):  # STOP, E-STOP and Take control / Release in the pinned block
        b = m[name]
        assert b is not None, f"{where}: no {name} button on the page: {m}"
        assert 0 <= b["top"] and b["bottom"] <= h and 0 <= b["left"] and b["right"] <= w, (where, name, b)
        assert pinned["top"] <= b["top"] and b["bottom"] <= pinned["bottom"], (where, name)
    assert abs(m["stop"]["top"] - m["estop"]["top"]) < 1.0, f"{where}: STOP and E-STOP not on one row"
    view, hint = m["view"], m["hint"]
    if hint is not None:  # the keyboard hint on the 3-D view covers neither the axis gizmo nor the panel
        gizmo = {"left": view["left"], "right": view["left"] + GIZMO_PX, "top": view["bottom"] - GIZMO_PX,
                 "bottom": view["bottom"]}
        assert not _overlap(hint, gizmo), f"{where}: the 3-D view's hint covers the axis gizmo: {hint}"
        assert not _overlap(hint, panel), f"{where}: the 3-D view's hint is under the panel: {hint}"
    return work / height, m


def _part_on_screen(page, station):
    """The part's bounding box as this page's camera shows it at start, in CSS px: (left, right, top, bottom), by
    projecting its eight corners through the camera the page reported (position, look-at, up, vertical view angle)."""
    from cmm.ui.scene import SCALE

    cam = page.capp.client.camera
    bs.wait_until(lambda: cam.image_width > 0, 60.0, "the page's camera reported")
    part = station.measurement.part
    corners = np.array([[x, y, z] for x in part.mesh.bounds[:, 0] for y in part.mesh.bounds[:, 1]
                        for z in part.mesh.bounds[:, 2]])
    pose = np.asarray(part.pose, float)
    world = (corners @ pose[:3, :3].T + pose[:3, 3]) * SCALE
    position, look_at = np.asarray(cam.position, float), np.asarray(cam.look_at, float)
    forward = (look_at - position) / np.linalg.norm(look_at - position)
    right = np.cross(forward, np.asarray(cam.up_direction, float))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    v = world - position
    depth = v @ forward
    t = np.tan(cam.fov / 2)
    w, h = page.viewport_size["width"], page.viewport_size["height"]
    xs = ((v @ right) / (depth * t * w / h) + 1) / 2 * w
    ys = (1 - (v @ up) / (depth * t)) / 2 * h
    return float(xs.min()), float(xs.max()), float(ys.min()), float(ys.max())


def test_room_to_work_at_1280x800_and_on_a_tablet(app, station):
    """Before and after taking control, at 1280 x 800 and on a portrait tablet: the tabs have at least 60 % of the
    panel's height, the status block (state, holder, DRO, link; STOP, E-STOP and Take control / Release at hand)
    covers nothing, the keyboard hint leaves the axis gizmo free, the six top tabs are one row, and at start the part
    fills the view beside the panel; on an upright phone the whole part is in the view at start."""
    IMAGES.mkdir(parents=True, exist_ok=True)
    shares = {}
    for name, size in (("1280x800", LAPTOP), ("tablet", TABLET)):
        with bs.browser_context(size, device_scale_factor=1) as context:  # README-sharp screenshots
            page = bs.open_page(context, app, size)
            # measured once the panel has laid out (viser applies one message at a time)
            bs.wait_until(lambda: page.evaluate(LAYOUT_JS)["tabs"]["top"] < 0.5 * size[1], 60.0, "the panel laid out",
                          poll=0.5)
            assert bs.top_tab_rows(page) == [list(bs.TABS)], (name, bs.top_tab_rows(page))
            shares[f"{name} before control"], m = _assert_room(page, f"{name} before control", "take")
            left, right, top, bottom = _part_on_screen(page, station)
            free = m["panel"]["left"]  # the view left of the panel
            assert (left + right) / 2 < free and 0 <= top and bottom <= size[1], (name, left, right, top, bottom)
            if name == "1280x800":  # across most of the view beside the panel, and not under it
                assert 0 <= left and right <= free and right - left >= 0.4 * free, (left, right, free)
            else:  # upright: the part is not cut at the view's left edge (viser's view angle is vertical)
                assert 0 <= left and right - left >= 0.3 * free, (left, right, free)
            _take_control(page, app)
            bs.wait_until(lambda: page.evaluate(LAYOUT_JS)["release"] is not None, 60.0, "Release laid out", poll=0.5)
            shares[f"{name} in control"], _ = _assert_room(page, f"{name} in control", "release")
            assert bs.top_tab_rows(page) == [list(bs.TABS)], (name, bs.top_tab_rows(page))
            # the README's picture: without the toasts of the moment (software WebGL, "you control the machine")
            page.locator(".mantine-Notification-root button").evaluate_all("bs => bs.forEach(b => b.click())")
            page.wait_for_timeout(1500)  # the toasts gone, the 3-D view drawn (software WebGL)
            page.screenshot(path=str(IMAGES / f"station-{name}.png"), timeout=bs.PAGE_WAIT_MS)
            bs.press(page, "Release")
            bs.wait_until(lambda: app.control.holder is None, 30.0, "the release")
    print("working area, share of the panel's height:", {k: f"{v:.0%}" for k, v in shares.items()})
    assert all(s >= 0.6 for s in shares.values()), shares
    with bs.browser_context(PHONE) as context:  # upright and narrow: viser's view angle is vertical, so the start
        page = bs.open_page(context, app, PHONE)  # view backs off until the part fits across the view too
        # the station moves the camera once the page has reported its start view (a callback of viser's thread pool:
        # on a loaded machine after the page's first camera report)
        bs.wait_until(lambda: _part_on_screen(page, station)[0] >= 0, 60.0, "the start view backed off for the phone",
                      poll=0.5, why=lambda: _part_on_screen(page, station))
        left, right, top, bottom = _part_on_screen(page, station)
        assert 0 <= left and right <= PHONE[0] and 0 <= top and bottom <= PHONE[1], (left, right, top, bottom)


@pytest.mark.parametrize("size", [LAPTOP, TABLET], ids=["1280x800", "tablet"])
def test_the_prompted_plane_line_point_alignment_in_the_page(app, station, size):
    with bs.browser_context(size, device_scale_factor=1) as context:
        page = bs.open_page(context, app, size)
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
                if size == LAPTOP:
                    page.screenshot(path=str(IMAGES / "align-wizard.png"), timeout=bs.PAGE_WAIT_MS)
        # the prompt's whole words: Playwright's text match ignores case, and the 3-2-1 section below the wizard
        # says "no alignment computed" all along (a wait for "Alignment computed" alone was met at once, and the
        # last element's fit read before it was made)
        bs.shows(page, "Alignment computed: check it, then Apply", station_has=lambda: capp.align.wizard_text())
        assert w.done and sum(len(s.hit_ids) for s in w.steps) == 6  # exactly the hits asked for
        assert all(s.feature is not None for s in w.steps), [(s.hit_ids, s.feature) for s in w.steps]
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
