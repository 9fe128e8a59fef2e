"""An operator's whole day in headless chromium, on the simulator: every step through the grouped tabs.

At 1280 x 800, Ada names herself in the start dialog, takes control, homes the machine, qualifies the probe
from a fresh calibration folder (the reference sphere's certificate typed in the page), auto-measures three
planes and aligns 3-2-1 on them, auto-measures a bore, a boss and a sphere, gives the bore a tolerance, teaches
the six-feature routine and saves it, runs it on a second part the simulator placed elsewhere and turned (the
manual 3-2-1 hits taken where the page prompts, by hand: Go to typed near each, then the armed jog held until the
probe touches), and writes the first part's report from Report > Sessions.
Then Ben, on a tablet (820 x 1180), takes control (Ada's page is told by name), opens the saved routine and
runs it on a third part. Every part's features are checked against the simulator's true part (the CAD
feature of the mesh where the simulator really put it) within probing noise, and the reports name the
operator and the features. Screenshots go to test-artifacts/walk-*.png.
"""

from __future__ import annotations

import numpy as np
import pytest

import browser_support as bs
import browser_moves as bm

_reason = bs.unavailable_reason()
pytestmark = [pytest.mark.browser, pytest.mark.timeout(1200),
              pytest.mark.skipif(_reason is not None, reason=_reason or "")]

pytest.importorskip("viser")

from cmm.metrology.nominal_match import nominal_for_points  # noqa: E402
from cmm.sim.cmm_sim import TRUE_PART_POSE, pose_matrix  # noqa: E402

LAPTOP = (1280, 800)
TABLET = (820, 1180)
SECOND_POSE = pose_matrix((194.0, 147.0, 0.0), rz_deg=2.0)  # the next part: moved 4 mm and turned 1.5 deg
THIRD_POSE = pose_matrix((186.5, 152.0, 0.0), rz_deg=-1.0)
PROMPTS = {0: "Take 3 hits by hand on TOP (primary datum)", 3: "Take 2 hits by hand on FRONT (secondary datum)",
           5: "Take 1 hit by hand on LEFT (tertiary datum)"}
FEATURES = ("TOP", "FRONT", "LEFT", "BORE", "BOSS", "DOME")


@pytest.fixture(scope="module")
def station(module_stations, tmp_path_factory):
    """A station on the simulator, not homed, with an empty calibration folder (no certificate, no probe record)."""
    return module_stations.station("day-part-1", home=False,
                                   calibration_dir=tmp_path_factory.mktemp("fresh-calibration"))


@pytest.fixture(scope="module")
def app(station):
    yield from bs.station_app(station, pendant=False, ask_name=True)


def assert_true_feature(station, feature, pose, hits, what):
    """``feature`` (machine coordinates) agrees with the simulator's true part at ``pose`` within probing noise:
    the CAD feature its hits lie on, on the mesh where the simulator put it."""
    points = [hits[h].point for h in feature.hit_ids]
    true = nominal_for_points(station.sim.part_mesh, pose, points, feature.kind)
    assert true is not None, f"{what}: its hits lie on no CAD {feature.kind} of the true part"
    r, p = feature.result, true.params
    if feature.kind == "plane":
        assert abs(np.dot(r.point - p["point"], p["normal"])) < 0.005, what
        assert np.degrees(np.arccos(min(1.0, abs(np.dot(r.normal, p["normal"]))))) < 0.02, what
    elif feature.kind == "cylinder":
        assert abs(r.radius - p["radius"]) < 0.005, (what, r.radius, p["radius"])
        off = r.point - p["point"]
        assert np.linalg.norm(off - np.dot(off, p["direction"]) * p["direction"]) < 0.01, what  # on the true axis
        assert np.degrees(np.arccos(min(1.0, abs(np.dot(r.direction, p["direction"]))))) < 0.2, what
    elif feature.kind == "sphere":
        assert abs(r.radius - p["radius"]) < 0.010, (what, r.radius, p["radius"])  # 5 hits on a 45 deg cap
        assert np.linalg.norm(r.center - p["center"]) < 0.015, what
    else:
        raise AssertionError(f"{what}: no check for a {feature.kind}")


def run_routine_on(page, station, pose, part_name):
    """Routine: the part name typed, Run on next part, the manual 3-2-1 hits taken as prompted, the rest runs by
    itself to DONE; the run's progress (its features and report)."""
    station.sim.place_part(pose)  # the operator puts the next part on the table, not where the last one was
    bs.open_tab(page, "Routine")
    bs.text_field(page, "Part name").fill(part_name)
    bs.wait_until(lambda: page.capp.routine.gui["part"].value == part_name, 30.0, "the part name at the station")
    bs.press(page, "Run on next part")
    page.get_by_text("WAITING FOR THE OPERATOR").filter(visible=True).first.wait_for(timeout=120_000)
    taken = bm.manual_321_by_jog(page, station, pose, bm.SAMPLE_321_HITS, PROMPTS)  # by hand: the page's armed jog
    run = page.capp.routine
    bs.wait_until(lambda: run.run_ is not None and run.run_.progress.state in ("done", "failed", "cancelled"),
                  600.0, "the routine's end")
    assert run.run_.progress.state == "done", run.run_.progress.message
    bs.shows(page, "DONE")
    progress = run.run_.progress
    assert part_name in str(progress.session)
    bm.assert_taken_by_jog(station, progress.session, taken)  # its manual 3-2-1: the hits the page's jog took
    hits = station.measurement.hits
    for name in FEATURES:
        assert_true_feature(station, progress.results[name], pose, hits, f"{part_name} {name}")
    return progress


def test_an_operators_day_on_the_laptop_then_the_next_part_from_a_tablet(app, station, tmp_path):
    model = station.measurement
    with bs.browser_context(LAPTOP) as context:
        context.set_default_timeout(60_000)  # software WebGL on a loaded 2-core machine
        page = bs.open_page(context, app)
        status = page.locator("#cmm-status")
        # --- who operates: the start dialog; the status bar and the control messages name her
        bs.start_as(page, "Ada")
        bs.press_until(page, "Take control", lambda: app.control.holder == page.capp.client_id, "Ada's control")
        status.get_by_text("Ada (you) controls the machine").filter(visible=True).first.wait_for()
        # the report header's operator: recorded by the Take control click's callback after the control itself, so
        # the status bar's refresher can show the holder first
        bs.wait_until(lambda: model.info.get("operator") == "Ada", 30.0, "Ada recorded as the session's operator")

        # --- Machine > Home
        bs.open_tab(page, "Machine", "Home")
        bs.shows(page, "Press Home before measuring")
        bs.press(page, "Home")
        bs.wait_until(lambda: station.controller.state.homed and station.controller.state.mode.value == "idle",
                      180.0, "the homing cycle")

        # --- Setup > Calibration: a fresh folder has no certificate; typed in the page, then the probe qualified
        bs.open_tab(page, "Setup", "Calibration")
        bs.shows(page, "certificate problem")
        bs.enter_sphere_certificate(page, 25.0002, "RS-77", 0.12)
        # the Calibration tab's certificate line is redrawn at its next read-out (5 Hz), after the serial shows
        bs.wait_until(lambda: page.get_by_text("certificate problem").count() == 0, 30.0, "the certificate problem gone")
        bs.open_folder(page, "Probe options", "Points per ring")
        for label, value in (("Points per ring", 8), ("Hits per point", 1)):  # a quick qualification
            page.get_by_label(label, exact=True).fill(str(value))
            page.get_by_label(label, exact=True).press("Enter")
        calib = page.capp.calibration
        bs.wait_until(lambda: (calib.gui["per_ring"].value, calib.gui["repeats"].value) == (8, 1), 30.0,
                      "the qualification options at the station")
        bs.press(page, "Run")
        bs.wait_until(lambda: calib.job is not None and calib.job.done, 300.0, "the probe qualification")
        assert calib.job.error is None and calib.result[0] == "probe", calib.job.error
        bs.press_until(page, "Save record", lambda: station.calibration.status.get("probe"), "the qualification applied")
        status.get_by_text("qualified 20").filter(visible=True).first.wait_for()  # the status bar: qualified and when
        assert "not qualified" not in status.inner_text()
        bs.screenshot(page, "walk-qualified")

        # --- Measure > Auto-measure: three planes, named; Align: 3-2-1 on them
        bm.pick_face(page, station, (20.0, 60.0, 40.0), (0, 0, 1))
        bs.open_tab(page, "Measure", "Auto-measure")
        bs.shows(page, "the top face at X")  # the tab says what was picked
        _, top = bm.automeasure_in_page(page, station, 4, name="TOP", shot="walk-plan-top")
        bm.pick_face(page, station, (60.0, 0.0, 25.0), (0, -1, 0))
        _, front = bm.automeasure_in_page(page, station, 3, name="FRONT")
        bm.pick_face(page, station, (0.0, 40.0, 25.0), (-1, 0, 0))
        _, left = bm.automeasure_in_page(page, station, 3, name="LEFT")
        bs.open_tab(page, "Align")
        page.capp.align.refresh()
        for key, f in (("p", top), ("s", front), ("t", left)):  # what choosing them in the dropdowns sets
            page.capp.align.gui[key].value = f"{f.id} {f.name} ({f.kind})"
        bs.press(page, "Compute 3-2-1")
        bs.shows(page, "part origin at")
        bs.press(page, "Apply alignment")
        bs.wait_until(lambda: model.aligned, 30.0, "the alignment applied")
        assert np.abs(model.part.pose[:3, 3] - TRUE_PART_POSE[:3, 3]).max() < 0.01  # the set-up found to um

        # --- the bore, the boss and the dome
        bm.pick_ray(page, station, (30.0, 40.0, 20.0), (1, 0, 0))  # from the bore's axis to its wall
        _, bore = bm.automeasure_in_page(page, station, 4, proposal="cylinder (bore)", name="BORE")
        bm.pick_face(page, station, (80.0, 22.0, 47.0), (1, 0, 0))
        _, boss = bm.automeasure_in_page(page, station, 3, proposal="cylinder (boss)", name="BOSS")
        bm.pick_face(page, station, (70.0, 58.0, 49.0), (0, 0, 1))
        _, dome = bm.automeasure_in_page(page, station, 4, proposal="sphere: the pole and 4 hits at 45°", name="DOME")
        for f in (top, front, left, bore, boss, dome):  # part 1 against the simulator's true part
            assert_true_feature(station, model.features[f.id], TRUE_PART_POSE, model.hits, f"part 1 {f.name}")

        # --- Measure > Features: the bore's size tolerance
        bs.open_tab(page, "Measure", "Features")
        page.capp.features._chosen(f"{bore.id} {bore.name}")  # what choosing it in the Feature dropdown calls
        bs.open_folder(page, "Nominal and tolerance", "Size ± (mm)")
        page.get_by_label("Size ± (mm)", exact=True).fill("0.01")
        page.get_by_label("Size ± (mm)", exact=True).press("Enter")
        bs.typed(page, "Size ± (mm)", 0.01)
        bs.press(page, "Apply tolerances")
        bs.wait_until(lambda: (model.features[bore.id].tolerance or {}).get("size") == pytest.approx(0.01), 30.0,
                      "the bore's tolerance")

        # --- Routine: taught from this session (the alignment, the six features, the report), saved as a file
        bs.open_tab(page, "Routine")
        bs.press(page, "Teach from this session")
        bs.shows(page, "align 3-2-1: TOP | FRONT | LEFT")
        routine = page.capp.routine.routine
        assert routine.measured_features() == list(FEATURES)
        assert routine.program.feature("BORE").tolerance.get("size") == pytest.approx(0.01)
        bs.open_folder(page, "File", "Routine file")
        bs.text_field(page, "Routine file").fill("day.toml")
        bs.wait_until(lambda: page.capp.routine.gui["file"].value == "day.toml", 30.0, "the file name at the station")
        bs.press_until(page, "Save", lambda: (station.measurement.session_dir / "day.toml").exists(), "the routine file")
        bs.screenshot(page, "walk-routine-taught")

        # --- the next part, placed elsewhere and turned: the routine runs on it from the page
        progress = run_routine_on(page, station, SECOND_POSE, "SN-2")
        bs.screenshot(page, "walk-routine-done")
        report2 = progress.results["report"]
        html = report2.read_text(encoding="utf-8")
        assert "Ada" in html and all(name in html for name in FEATURES)

        # --- Report > Sessions: the first part's report (HTML + CSV)
        bs.open_tab(page, "Report", "Sessions")
        sessions = page.capp.sessions
        sessions.refresh_list()
        sessions.gui["session"].value = "day-part-1"  # what choosing it in the Session dropdown sets
        bs.open_folder(page, "Export", "Report (HTML + CSV)")
        bs.press_until(page, "Report (HTML + CSV)", lambda: any(f.suffix == ".html" for f in sessions.last_files),
                       "the report", timeout=120.0, every=30.0)
        html = next(f for f in sessions.last_files if f.suffix == ".html").read_text(encoding="utf-8")
        assert "Ada" in html and all(name in html for name in FEATURES)
        bs.shows(page, "-report.html")
        assert page.log.page_errors == [], page.log.problems

        # --- Ben, on a tablet, takes over: Ada's page names him; he runs the saved routine on the third part
        page.evaluate("() => localStorage.removeItem('cmm-operator')")  # Ben's page asks who operates
        tablet = bs.open_page(context, app, viewport=TABLET)
        bs.start_as(tablet, "Ben")
        assert bs.top_tab_rows(tablet) == [list(bs.TABS)]
        bs.press_until(tablet, "Take control", lambda: app.control.holder == tablet.capp.client_id, "Ben's control")
        tablet.locator("#cmm-status").get_by_text("Ben (you) controls the machine").filter(visible=True).first.wait_for()
        status.get_by_text("control is held by Ben").filter(visible=True).first.wait_for()
        bs.wait_until(lambda: any(title == "Control taken" and "Ben now controls the machine" in body
                                  for _level, title, body in page.capp.messages), 30.0,
                      "Ada's 'Control taken' message", why=lambda: str(page.capp.messages[-3:]))
        assert model.info.get("operator") == "Ben"
        bs.open_tab(tablet, "Routine")
        bs.open_folder(tablet, "File", "Routine file")
        bs.text_field(tablet, "Routine file").fill("day.toml")
        bs.wait_until(lambda: tablet.capp.routine.gui["file"].value == "day.toml", 30.0, "the file name")
        bs.press_until(tablet, "Open", lambda: tablet.capp.routine.routine is not None, "the routine opened")
        progress = run_routine_on(tablet, station, THIRD_POSE, "SN-3")
        bs.screenshot(tablet, "walk-tablet-routine-done")
        html = progress.results["report"].read_text(encoding="utf-8")
        assert "Ben" in html and all(name in html for name in FEATURES)
        assert tablet.log.page_errors == [], tablet.log.problems
