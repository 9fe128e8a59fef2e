"""The operator's station in headless chromium: status bar, auto-measure, feature tree, alignment, report.

One walk through what an operator does on the simulated CMM (1280 x 800, the
laptop layout): the always-visible status bar, auto-measure of faces picked
on the part (plan drawn, Run), the feature tree with pass/fail colours, a hit
removed and the feature refitted, a hit re-taken (Probe here) and the feature
refitted, a constructed angle, a 3-2-1 alignment from the measured planes (the
DRO switches to part coordinates), the report header, the customer report
printed to PDF by chromium, and a fault: the link to the modules drops, the
status bar says FAULT and why, a move is refused with the reason, Reset is
refused until the link answers, then Reset from the page. Then the idle
page's bandwidth and the tablet (pendant-only) layout. Screenshots go to
test-artifacts/station-*.png.
"""

from __future__ import annotations

import re
import time

import numpy as np
import pytest

import browser_support as bs
import browser_moves as bm
from control_support import BreakablePort

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(600),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")

from cmm.journal.session import Session  # noqa: E402
from cmm.journal.writer import read_events  # noqa: E402
from cmm.session.report import features_csv, render  # noqa: E402
from cmm.sim.cmm_sim import TRUE_PART_POSE  # noqa: E402

LAPTOP = (1280, 800)
TABLET = (820, 1180)  # a 10.9" tablet, portrait


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    yield from bs.sim_station(tmp_path_factory, "walk")


@pytest.fixture(scope="module")
def app(station):
    yield from bs.station_app(station, pendant_port=0)


def scrolled_by(page) -> float:
    """How far the scroll box around the status bar (viser's side panel) is scrolled down, px."""
    return page.evaluate("""() => { let e = document.getElementById("cmm-status");
        while (e && !/(auto|scroll)/.test(getComputedStyle(e).overflowY)) e = e.parentElement;
        return e ? e.scrollTop : -1; }""")


def assert_status_bar_on_screen(page, viewport, where):
    """The status bar, STOP and E-STOP lie inside the viewport and on top (a click there reaches them, not the
    content scrolled under them)."""
    w, h = viewport
    for name, loc, sel in (("status", page.locator("#cmm-status"), "#cmm-status"),
                           ("STOP", page.get_by_role("button", name="STOP", exact=True), "button"),
                           ("E-STOP", page.get_by_role("button", name="E-STOP", exact=True), "button")):
        box = loc.bounding_box()
        assert box is not None and 0 <= box["y"] and box["y"] + box["height"] <= h and 0 <= box["x"] \
            and box["x"] + box["width"] <= w, f"{where}: {name} is off screen at {box}"
        centre = [box["x"] + box["width"] / 2, box["y"] + box["height"] / 2]
        top = page.evaluate("""([x, y, sel]) => { const e = document.elementFromPoint(x, y);
            const hit = e && e.closest(sel); return hit ? (sel === "button" ? hit.textContent.trim() : hit.id) : null; }""",
                            [*centre, sel])
        assert top == (name if sel == "button" else "cmm-status"), f"{where}: {name} is covered ({top!r} is on top)"


def measure_face(page, station, local_point, outward, hits_per_ring, timeout=90.0):
    """Auto-measure a face with what the Plan and Run buttons call (the buttons themselves are pressed once,
    for the top face, in the walk below)."""
    bm.pick_face(page, station, local_point, outward)
    assert page.capp.measure.make_plan(hits_per_ring) is not None, page.capp.messages[-2:]
    before = set(station.measurement.features)
    assert page.capp.measure.run(wait=True), page.capp.messages[-2:]
    (fid,) = set(station.measurement.features) - before
    return page.capp.measure.plan, station.measurement.features[fid]


def _started(page, station, before) -> bool:
    """The tab's auto-measure run has started (or already ended with its feature)."""
    running = page.capp.measure.running
    return (running is not None and running.is_alive()) or bool(set(station.measurement.features) - before)


def automeasure_in_page(page, station, local_point, outward, hits_per_ring, proposal, shot=None):
    """Auto-measure a feature through the page: the pick a click on it sends, the hits per ring typed, Plan (the
    proposal and its path shown), Run (the feature measured and fitted against its CAD nominal)."""
    bm.pick_face(page, station, local_point, outward)
    page.get_by_label("Hits (per ring)", exact=True).fill(str(hits_per_ring))
    page.get_by_label("Hits (per ring)", exact=True).press("Enter")
    bs.wait_until(lambda: page.capp.measure.gui["hits"].value == hits_per_ring, 30.0, "the typed hits per ring")
    planned_before = page.capp.measure.plan
    measure = page.capp.measure
    bs.press_until(page, "Plan", lambda: measure.plan is not None and measure.plan is not planned_before, "the plan")
    planned = lambda: getattr(measure.plan, "description", "")  # noqa: E731
    bs.wait_until(lambda: proposal in planned(), 60.0, f"the plan at the station: {proposal}",
                  why=lambda: f"planned {planned()!r}; told {page.capp.messages[-3:]}")
    bs.shows(page, proposal, lambda: f"the proposal: {proposal in measure.gui['plan'].content}, a plan: "
             f"{measure.plan is not None}, {measure.gui['plan'].content[:200]}")  # the proposal and its hits
    plan = page.capp.measure.plan
    bs.shows(page, f"{len(plan)} hits · clearance plane")
    # the planned path is drawn in this tab's scene (after the plan's text: its clearance proofs take a while)
    bs.wait_until(lambda: page.capp.measure.preview.nodes, 60.0, "the planned path drawn")
    if shot:
        bs.screenshot(page, shot)
    before = set(station.measurement.features)
    # pressed in the page (a click at the button's place can miss it while the panel re-lays out its path text)
    bs.press_until(page, "Run", lambda: _started(page, station, before), "the run", every=30.0)
    bs.wait_until(lambda: set(station.measurement.features) - before, 90.0, f"the auto-measured {proposal}",
                  why=lambda: f"{page.capp.measure.progress!r}; told {page.capp.messages[-3:]}")
    (fid,) = set(station.measurement.features) - before
    feature = station.measurement.features[fid]
    bs.shows(page, f"done: {feature.name}", lambda: page.capp.measure.gui["plan"].content)
    assert len(feature.hit_ids) == len(plan)
    return plan, feature


def test_operator_walk_status_automeasure_tree_alignment_report(app, station):
    with bs.browser_context(viewport=LAPTOP) as context:
        page = bs.open_page(context, app)
        # --- status bar: state, who has control, DRO, probe; STOP / E-STOP
        status = page.locator("#cmm-status")
        status.get_by_text("IDLE").filter(visible=True).first.wait_for()
        x, y, z = station.machine.state.position
        text = status.inner_text()
        assert f"X {x:.4f}" in text and f"Z {z:.4f}" in text, text
        assert "Nobody controls the machine" in text and "not qualified" in text, text
        bs.press_until(page, "Take control", lambda: app.control.holder == page.capp.client_id, "control taken")
        status.get_by_text("You control the machine.").filter(visible=True).first.wait_for()

        # --- auto-measure in the browser: pick the top face, Plan (path drawn), Run
        bm.pick_face(page, station, (20.0, 60.0, 40.0), (0, 0, 1))
        bs.open_tab(page, "Measure", "Auto-measure")
        bs.press_until(page, "Plan", lambda: page.capp.measure.plan is not None, "the plan")
        bs.shows(page, "4 hits · clearance plane")
        name_field = page.get_by_text("Feature name", exact=True).locator("xpath=following::input[1]")
        bs.shows(page, "the top face at X")  # the tab says what was picked
        assert page.get_by_label("Hits (per ring)", exact=True).input_value() == "4"  # the plan's, not 0
        # the planned path is drawn in this tab's scene (after the plan's text: its clearance proofs take a while)
        bs.wait_until(lambda: page.capp.measure.preview.nodes, 60.0, "the planned path drawn")
        bs.screenshot(page, "station-automeasure-plan")
        name_field.fill("TOP")  # the operator's name for it is kept
        bs.wait_until(lambda: page.capp.measure.gui["name"].value == "TOP", 20.0, "the typed name at the server")
        bs.press_until(page, "Run", lambda: _started(page, station, set()), "the run", every=30.0)
        bs.wait_until(lambda: station.measurement.features, 90.0, "the auto-measured top face")
        (top,) = station.measurement.features.values()
        assert top.kind == "plane" and len(top.hit_ids) == 4
        assert top.nominal is not None and top.nominal.kind == "plane" and top.name == "TOP"
        bs.wait_until(lambda: page.capp.measure.progress == "done: TOP", 120.0, "the run's end at the station",
                      why=lambda: f"progress {page.capp.measure.progress!r}, mode {station.controller.state.mode}, "
                                  f"jobs {station.controller.jobs!r}, told {page.capp.messages[-3:]}")
        bs.shows(page, "done: TOP")
        bs.wait_until(lambda: name_field.input_value() == "", 20.0,
                      "the name field cleared for the next feature")
        # the front and left faces (3 hits each)
        _, front = measure_face(page, station, (60.0, 0.0, 25.0), (0, -1, 0), 3)
        _, left = measure_face(page, station, (0.0, 40.0, 25.0), (-1, 0, 0), 3)
        # the boss (two rings of 3: a cylinder), the dome (pole + 4 at 45 deg: a sphere), the conical boss (two
        # rings of 4: 3 typed, a cone needs 4), each through the page: Plan, the proposal shown, Run
        _, boss = automeasure_in_page(page, station, (80.0, 22.0, 47.0), (1, 0, 0), 3, "cylinder (boss): two rings of 3 hits")
        assert boss.kind == "cylinder" and boss.nominal.params["radius"] == pytest.approx(10.0)
        assert abs(boss.result.geometry()["radius"] - 10.0) < 0.005
        _, dome = automeasure_in_page(page, station, (70.0, 58.0, 49.0), (0, 0, 1), 4,
                                      "sphere: the pole and 4 hits at 45°", shot="station-automeasure-sphere-plan")
        assert dome.kind == "sphere" and dome.nominal.kind == "sphere"
        # 5 hits on a 45-degree cap: its radius is ~3x less certain than one hit (2 um counts, pre-travel of a probe
        # not yet qualified), so 10 um here, not the 5 um of the boss's two full rings
        assert abs(dome.result.geometry()["radius"] - 10.0) < 0.010
        z = 46.0  # the cone's flank: radius 12.5 at z 39 to 6 at z 52
        r = 12.5 - 6.5 * (z - 39.0) / 13.0
        # 3 hits per ring typed: a cone needs 4 (6 parameters and one to check), the plan takes 4 and says so
        _, cone = automeasure_in_page(page, station, (100.0 + r, 40.0, z), (2 / 5 ** 0.5, 0, 1 / 5 ** 0.5), 3,
                                      "cone (boss): two rings of 4 hits", shot="station-automeasure-cone-plan")
        assert cone.kind == "cone" and cone.nominal.kind == "cone"
        assert abs(np.degrees(cone.result.geometry()["half_angle"]) - np.degrees(np.arctan(6.5 / 13.0))) < 0.2

        # --- feature tree: every feature with its characteristics and pass / fail colours
        bs.open_tab(page, "Measure", "Features")
        tree = page.locator(".cmm-tree")
        tree.get_by_text("cylindricity").filter(visible=True).first.wait_for()
        for f in (top, front, left, boss):
            assert f.name in tree.inner_text()
        assert "position ⌀" in tree.inner_text() and "flatness" in tree.inner_text()
        # select the top plane (it and its hits highlighted); remove a hit and it refits
        page.capp.features._chosen(f"{top.id} {top.name}")  # what choosing it in the Feature dropdown calls
        assert page.capp.ctx.selected_feature == top.id and app.view.selected == top.id
        bs.shows(page, f"{top.name} hits (residual)")
        bs.open_folder(page, "Hits of the feature", "Hit")
        page.get_by_label("Hit", exact=True).fill(str(top.hit_ids[0]))
        page.get_by_label("Hit", exact=True).press("Enter")
        bs.typed(page, "Hit", top.hit_ids[0])  # the button acts on the number the station holds
        # on the element (a click at coordinates missed while the panels above re-flowed), again if not refitted
        bs.press_until(page, "Remove hit and refit", lambda: len(station.measurement.features[top.id].hit_ids) == 3,
                       "the refit without the hit")
        assert station.measurement.features[top.id].hit_ids == top.hit_ids[1:]
        # re-take a hit: Re-take arms it, the next hit (Probe here at the same point of the face, from the Go to
        # tab) replaces it in the plane, which refits; the old hit goes to the deleted ones
        kept = station.measurement.features[top.id].hit_ids
        old = kept[0]
        old_point = np.array(station.measurement.hits[old].point, float)
        page.get_by_label("Hit", exact=True).fill(str(old))
        page.get_by_label("Hit", exact=True).press("Enter")
        bs.typed(page, "Hit", old)
        bs.press(page, "Re-take hit")
        bs.wait_until(lambda: page.capp.features.retake is not None, 20.0, "the re-take armed")
        assert page.capp.features.retake[:2] == (top.id, old)
        pose = station.measurement.part.pose
        bm.pick_face(page, station, pose[:3, :3].T @ (old_point - pose[:3, 3]), (0, 0, 1))
        bs.open_tab(page, "Machine", "Go to")
        bs.press(page, "Probe here")
        bs.wait_until(lambda: old not in station.measurement.hits, 90.0,
                      f"hit {old} replaced by the re-taken one (told {page.capp.messages[-3:]})")
        refit = station.measurement.features[top.id]
        new = refit.hit_ids[0]
        assert new not in kept and refit.hit_ids[1:] == kept[1:] and old in station.measurement.deleted
        assert np.linalg.norm(np.asarray(station.measurement.hits[new].point) - old_point) < 0.01  # the same point, probed again
        bs.wait_until(lambda: any(t == "Re-take" and f"hit {old} replaced by hit {new}" in b
                                  for _l, t, b in page.capp.messages), 20.0, "the page told of the re-take")
        bs.open_tab(page, "Measure", "Features")
        residuals = page.get_by_text(f"{top.name} hits (residual)")
        bs.wait_until(lambda: re.search(rf"\b{new}: ", residuals.inner_text())
                      and not re.search(rf"\b{old}: ", residuals.inner_text()), 20.0,
                      "the re-taken hit listed with its residual")
        bs.screenshot(page, "station-retaken-hit")
        # a nominal and a tolerance typed for the boss: a 20.1 mm nominal fails it, a +-0.15 mm size tolerance passes it
        def fails():
            return tree.inner_text().count("FAIL")

        clean = fails()
        page.capp.features._chosen(f"{boss.id} {boss.name}")  # what choosing it in the Feature dropdown calls
        bs.open_folder(page, "Nominal and tolerance", "Nominal diameter")
        page.get_by_label("Nominal diameter", exact=True).fill("20.1")
        page.get_by_label("Nominal diameter", exact=True).press("Enter")
        bs.typed(page, "Nominal diameter", 20.1)
        bs.press(page, "Apply typed nominal")
        bs.wait_until(lambda: station.measurement.features[boss.id].nominal.params["radius"] == pytest.approx(10.05), 20.0,
                      "the typed nominal diameter")
        bs.wait_until(lambda: fails() > clean, 20.0, "the boss shown as FAIL in the tree")
        page.get_by_label("Size ± (mm)", exact=True).fill("0.15")
        page.get_by_label("Size ± (mm)", exact=True).press("Enter")
        bs.typed(page, "Size ± (mm)", 0.15)
        bs.press(page, "Apply tolerances")
        bs.wait_until(lambda: (station.measurement.features[boss.id].tolerance or {}).get("size") == pytest.approx(0.15), 20.0,
                      "the typed size tolerance")
        bs.wait_until(lambda: fails() == clean, 20.0, "the boss passing with its typed tolerance")
        bs.screenshot(page, "station-typed-nominal-tolerance")
        # a constructed angle between the front and left faces: 90 degrees, its nominal from the CAD
        angle = page.capp.features.construct("angle", front.id, left.id)
        assert angle.result.value == pytest.approx(90.0, abs=0.05) and angle.nominal.value == pytest.approx(90.0)
        tree.get_by_text("angle", exact=True).filter(visible=True).first.wait_for()
        page.mouse.move(1100, 600)
        page.mouse.wheel(0, -5000)  # back to the top of the tab: the tree under the tab bar
        page.wait_for_timeout(500)
        bs.screenshot(page, "station-feature-tree")

        # --- the status bar stays on screen while the panel scrolls to the end of a long tab

        def text_input(label):  # viser's text fields: the input after their label text; the Report header folder
            # comes after the Control folder's own "Operator" (the tab's name): the last field of that label
            return page.get_by_text(label, exact=True).last.locator("xpath=following::input[1]")

        text_input("Operator").fill("A. Operator")
        text_input("Temperature (°C)").fill("20.3")
        bs.press(page, "Save header")
        bs.wait_until(lambda: station.measurement.info.get("temperature") == 20.3, 20.0, "the report header saved")
        save_box = page.get_by_role("button", name="Save header").bounding_box()
        assert save_box["y"] > LAPTOP[1] / 2 and scrolled_by(page) > 200  # scrolled down to the end of the tab ...
        assert_status_bar_on_screen(page, LAPTOP, "laptop, Features tab scrolled")  # ... the bar on screen
        bs.screenshot(page, "station-scrolled-status-bar")

        # --- 3-2-1 alignment from the top, front and left planes; the DRO switches to part coordinates
        bs.open_tab(page, "Align")
        page.capp.align.refresh()
        for key, f in (("p", top), ("s", front), ("t", left)):
            page.capp.align.gui[key].value = f"{f.id} {f.name} ({f.kind})"
        bs.press(page, "Compute 3-2-1")
        bs.shows(page, "part origin at")
        before = np.abs(station.measurement.part.pose[:3, 3] - TRUE_PART_POSE[:3, 3]).max()
        bs.press(page, "Apply alignment")
        bs.wait_until(lambda: station.measurement.aligned, 20.0, "the alignment applied")
        after = np.abs(station.measurement.part.pose[:3, 3] - TRUE_PART_POSE[:3, 3]).max()
        assert before > 0.1 and after < 0.01, (before, after)  # the set-up error is found to a few um
        bs.wait_until(lambda: page.capp.status.frame == "Part", 20.0, "the DRO in part coordinates")
        status.get_by_text("part", exact=True).filter(visible=True).first.wait_for()
        pos = station.measurement.part.pose[:3, :3].T @ (station.machine.state.position - station.measurement.part.pose[:3, 3])
        assert f"X {pos[0]:.4f}" in status.inner_text()
        bs.screenshot(page, "station-aligned")

        # --- best fit of all hits to the mesh from the Align tab: transform and residuals shown, then applied
        bs.press(page, "Machine")  # the DRO back in machine axes
        status.get_by_text("machine", exact=True).filter(visible=True).first.wait_for()
        bs.press(page, "Compute best fit")
        page.get_by_text("best_fit", exact=True).filter(visible=True).first.wait_for()
        bs.shows(page, "RMS:")
        fit = page.capp.align.result
        assert fit.method == "best_fit" and fit.residuals["RMS"] < 0.005, fit.residuals  # um-level on a true part
        assert np.abs(fit.pose[:3, 3] - TRUE_PART_POSE[:3, 3]).max() < 0.01
        bs.shows(page, "moved ")  # the shift from the 3-2-1 set-up it replaces
        bs.screenshot(page, "station-best-fit")
        bs.press(page, "Apply alignment")
        bs.wait_until(lambda: page.capp.status.frame == "Part", 20.0, "the DRO in part coordinates after the best fit")
        status.get_by_text("part", exact=True).filter(visible=True).first.wait_for()
        assert np.abs(station.measurement.part.pose[:3, 3] - TRUE_PART_POSE[:3, 3]).max() < 0.01
        assert page.log.page_errors == [], page.log.problems

        # --- the customer report of this session, printed to PDF by chromium
        session = Session.from_events(read_events(station.measurement.journal.path).events, "walk")  # fsync'ed per event
        html = render(session, mesh=station.measurement.part.mesh)
        assert "A. Operator" in html and "20.3 °C" in html
        assert "No alignment was made" not in html  # aligned; the features measured before it moved with the part
        assert "angle" in html and "position ⌀" in html
        rows = features_csv(session).splitlines()
        assert rows[0].startswith("feature,kind,method") and any(",angle,deg," in r for r in rows)
        report = bs.ARTIFACTS / "station-report.html"
        report.write_text(html, encoding="utf-8")
        rp = context.new_page()
        rp.goto(report.as_uri())
        bs.screenshot(rp, "station-report", full_page=True)
        pdf = rp.pdf(format="A4")
        (bs.ARTIFACTS / "station-report.pdf").write_bytes(pdf)
        assert pdf.startswith(b"%PDF") and pdf.count(b"/Type /Page") >= 2
        rp.close()
        page.bring_to_front()

        # --- a fault the way a real failure makes one: the link to the modules drops (the simulated port's plug
        # pulled under the running station), the machine loop stops every axis and enters fault with the reason
        bus = station.machine.bus
        plug = BreakablePort(bus.port)
        bus.port = plug
        try:
            page.mouse.move(1100, 600)
            page.mouse.wheel(0, -5000)  # the panel back to the top: the tab bar out from under the status bar
            page.wait_for_timeout(500)
            bs.open_tab(page, "Machine", "Go to")
            plug.broken = True
            bs.wait_until(lambda: station.controller.state.mode.value == "fault", 20.0, "the fault on the dropped link")
            status.get_by_text("FAULT", exact=True).filter(visible=True).first.wait_for()
            bs.wait_until(lambda: "link failure" in status.inner_text() and "SILENT" in status.inner_text(), 20.0,
                          f"the fault's reason and the silent link in the status bar ({status.inner_text()!r})")
            # the pendant says FAULT and why, never "idle"
            pendant = context.new_page()
            pendant.goto(app.pendant.url)
            bs.wait_until(lambda: pendant.locator("#motion").inner_text().startswith("FAULT: link failure"), 30.0,
                          "the pendant's FAULT and its reason")
            pendant.close()
            # a motion button (Probe here, at the point picked for the re-take) is refused with the reason, on the page
            bs.press(page, "Probe here")
            page.get_by_text("cannot probe: the machine is in fault (link failure").filter(visible=True).first.wait_for()
            assert any(t == "Probe here refused" and "Reset (or reconnect) first" in b
                       for _l, t, b in page.capp.messages), page.capp.messages[-3:]
            assert not station.machine.state.moving
            bs.screenshot(page, "station-fault")
            # Reset while the link is down: refused (Reconnect first); the Machine tab says the way back
            page.mouse.wheel(0, -5000)
            page.wait_for_timeout(500)
            bs.open_tab(page, "Machine", "Home")
            bs.shows(page, "then Home (positions are lost)")
            bs.press(page, "Reset")
            bs.wait_until(lambda: any(t == "Reset refused" and "Reconnect first" in b
                                      for _l, t, b in page.capp.messages), 20.0, "Reset refused on a dead link")
            assert station.controller.state.mode.value == "fault"
            # the plug back in: the loop finds the modules answering; Reset from the page clears the fault
            plug.broken = False
            bs.wait_until(lambda: station.controller.state.link_ok, 20.0, "the link answering again")
            bs.shows(page, "press Reset (the link answers)")
            bs.press(page, "Reset")
            status.get_by_text("IDLE", exact=True).filter(visible=True).first.wait_for()
            bs.wait_until(lambda: "link ok" in status.inner_text() and "link failure" not in status.inner_text(),
                          20.0, f"the status bar clear of the fault ({status.inner_text()!r})")
            cs = station.controller.state
            assert cs.mode.value == "idle" and cs.homed and cs.link_ok  # the modules kept power: still homed
            bs.screenshot(page, "station-fault-reset")
        finally:
            plug.broken = False
            bus.port = plug.inner
        assert page.log.page_errors == [], page.log.problems


def test_idle_page_is_quiet_and_layouts_fit_laptop_and_tablet(app, station):
    """An idle station page receives (almost) nothing; the six top tabs are one row at 1280 x 800 and on a
    tablet; the Jog tab documents the keyboard at 1280 x 800; the pendant page alone fits a tablet with the position, STOP and the jog pad on screen."""
    with bs.browser_context(viewport=LAPTOP) as context:
        received = []
        page = context.new_page()
        page.on("websocket", lambda ws: ws.on("framereceived", lambda payload: received.append(
            (ws.url, len(payload) if isinstance(payload, (bytes, str)) else 0))) if f":{app.port}" in ws.url else None)
        page.goto(bs.app_url(app))
        page.get_by_role("button", name="E-STOP").wait_for()
        page.wait_for_timeout(3000)  # the initial GUI and scene
        received.clear()
        since = time.monotonic()
        assert bs.render_passes(page, 4000) == 1  # without shadows (--no-shadows, as every test station): one pass
        rate = sum(n for _, n in received) / (time.monotonic() - since)
        assert rate < 2000, f"an idle page received {rate:.0f} B/s"  # was ~80 kB/s (the plot re-sent 5x/s)
        assert bs.top_tab_rows(page) == [list(bs.TABS)], bs.top_tab_rows(page)  # the six tabs in one row
        bs.open_tab(page, "Machine", "Jog")
        bs.shows(page, "Keyboard")
        page.get_by_text("PageUp/PageDown").scroll_into_view_if_needed()
        page.wait_for_timeout(500)
        bs.screenshot(page, "station-jog-laptop")

    with bs.browser_context(viewport=TABLET, has_touch=True, is_mobile=True) as context:
        # the station page on a tablet: the status bar stays on screen at the end of a long tab
        page = context.new_page()
        page.goto(bs.app_url(app))
        page.locator("#cmm-status").wait_for()
        assert bs.top_tab_rows(page) == [list(bs.TABS)], bs.top_tab_rows(page)
        bs.open_tab(page, "Measure", "Features")
        page.get_by_role("button", name="Save header").scroll_into_view_if_needed()
        page.wait_for_timeout(500)
        assert scrolled_by(page) > 80, scrolled_by(page)  # more than the bar's top margin: unpinned, it would leave
        assert_status_bar_on_screen(page, TABLET, "tablet, Features tab scrolled")
        bs.screenshot(page, "station-tablet-scrolled-status-bar")
        page.close()
        pendant = context.new_page()
        pendant.goto(app.pendant.url)
        pendant.locator("#stop").wait_for()
        for sel in ("#stop", ".pad"):
            box = pendant.locator(sel).bounding_box()
            assert box is not None and 0 <= box["y"] and box["y"] + box["height"] <= TABLET[1], (sel, box)
        x = station.machine.state.position[0]
        bs.shows(pendant, f"{x:.3f}")  # the DRO
        bs.screenshot(pendant, "station-pendant-tablet")
