"""Routines on the simulator (virtual clock): a 6-feature routine taught on one part, edited, saved, and run on
a second part placed differently (moved and turned on the table): manual 3-2-1 hits prompted first, then the
datums measured automatically, then every feature, the construction and the report; pause / skip / cancel;
a fault in the middle of a routine (an obstacle the probe runs into) resumed after Reset from the stopped step;
a probe change between steps and the probe of each feature in the report."""

from __future__ import annotations

import numpy as np
import pytest
import session_support as sup
from netutil import free_port

from cmm.control import OpenPolicy
from cmm.control.access import Client, Control
from cmm.measurement.routine import Routine, RoutineError, teach_routine
from cmm.measurement.routine_host import StationRoutineHost
from cmm.measurement.routine_run import RoutineCancelled, RoutineRun
from cmm.metrology.transform import invert
from cmm.program.toml_program import from_toml, load, machine_targets
from cmm.journal.writer import read_events
from cmm.session.report import features_csv, render
from cmm.journal.store import open_session
from cmm.sim.cmm_sim import TRUE_PART_POSE, pose_matrix

FACES = sup.BLOCK_FACES
# where the second part stands: 6 mm and 4 mm off, turned 3 degrees
SECOND_POSE = pose_matrix((196.0, 146.0, 0.0), rz_deg=3.5)
# the operator's 3-2-1 hits by hand (part coordinates): point on the face, approach into it
MANUAL = [((15.0, 10.0, 40.0), (0, 0, -1)), ((105.0, 12.0, 40.0), (0, 0, -1)), ((50.0, 70.0, 40.0), (0, 0, -1)),
          ((15.0, 0.0, 15.0), (0, 1, 0)), ((105.0, 0.0, 15.0), (0, 1, 0)), ((0.0, 20.0, 15.0), (1, 0, 0))]


@pytest.fixture(scope="module")
def taught(module_stations, tmp_path_factory):
    """A station that measured the six features on the first part, aligned 3-2-1 and constructed a distance;
    the routine taught from that session."""
    st = module_stations.station("teach", calibration_dir=tmp_path_factory.mktemp("routine-calibration"))
    model = st.measurement
    sup.teach_block(model)
    session = open_session(model.journal.path)
    routine = teach_routine(session, name="block", part_mesh=model.part.mesh,
                            part_nominals=model.part.nominal_features)
    return st, routine


def test_teaching_gives_the_steps_in_order_and_the_file_round_trips(taught, tmp_path):
    _st, routine = taught
    kinds = [s["kind"] for s in routine.steps]
    assert kinds == ["align", "feature", "feature", "feature", "feature", "feature", "feature", "construct",
                     "report"]
    assert routine.steps[0]["datums"] == ["TOP", "FRONT", "LEFT"] and routine.steps[0]["manual"]
    assert [s["name"] for s in routine.steps[1:7]] == [n for n, *_ in FACES]
    assert routine.steps[7] == {"kind": "construct", "name": "bore-boss", "operation": "distance",
                                "of": ["bore", "boss"]}
    path = routine.save(tmp_path / "block.toml")
    again = Routine(load(path))
    assert again.steps == routine.steps and again.lines() == routine.lines()
    assert "align 3-2-1: TOP | FRONT | LEFT" in again.lines()[0]


def test_edits_rename_reorder_refuse_what_would_break_the_routine(taught):
    _st, routine = taught
    r = Routine(from_toml(routine.text()))
    r.rename(4, "BORE")  # a feature step: its feature and the construction's reference follow
    assert r.program.feature("BORE") and r.steps[7]["of"] == ["BORE", "boss"]
    with pytest.raises(RoutineError, match="before it is measured"):
        r.move(7, -4)  # the construction cannot come before the bore
    assert r.steps[7]["kind"] == "construct"  # the refused edit changed nothing
    assert r.move(6, -1) == 5 and r.steps[5]["name"] == "dome"
    with pytest.raises(RoutineError, match="same name"):
        r.rename(5, "boss")
    r.set_tolerance("BORE", size=0.005)
    assert r.program.feature("BORE").tolerance["size"] == 0.005
    r.set_nominal("BORE", radius=15.01)
    assert r.program.feature("BORE").nominal["radius"] == 15.01
    with pytest.raises(RoutineError, match="no 'diameter'"):
        r.set_nominal("BORE", diameter=30)
    with pytest.raises(RoutineError, match="below hit"):
        r.set_clearance("TOP", 10.0)
    r.set_clearance("TOP", 80.0)
    assert all(h.clearance_z == 80.0 for h in r.program.hits if h.id in r.program.feature("TOP").hits)
    # the bore's hits stand at two depths: a height between them is refused for all of them, none changed
    bore = [h for h in r.program.hits if h.id in r.program.feature("BORE").hits]
    zs = sorted({round(h.point[2], 3) for h in bore})
    assert len(zs) >= 2, zs
    before = [h.clearance_z for h in bore]
    r.program.hits.sort(key=lambda h: h.point[2])  # whatever order the file keeps them in: the deepest first here
    with pytest.raises(RoutineError, match="below hit .*nothing was changed"):
        r.set_clearance("BORE", (zs[0] + zs[-1]) / 2)
    assert [h.clearance_z for h in bore] == before
    r.delete(8)
    r.insert(8, {"kind": "report", "name": "final report"})
    with pytest.raises(RoutineError, match="not a feature"):
        r.insert(1, {"kind": "feature", "name": "nothing"})


def _manual_hits_on(st, pose):
    """The operator's hands: the 6 hits of a manual 3-2-1, taken where the part really is."""
    model = st.measurement
    queue = [((pose @ np.array([*p, 1.0]))[:3], pose[:3, :3] @ np.array(u, float)) for p, u in MANUAL]
    prompts = []

    def take(prompt: str, n: int) -> list[int]:
        prompts.append(prompt)
        ids = []
        for _ in range(n):
            p, u = queue.pop(0)
            hit = model.probe(p, u, clearance_z=90.0).wait(120)
            ids.append(model.hit_id(hit))
        return ids

    return take, prompts


def test_the_routine_runs_on_a_second_part_placed_differently(taught):
    st, routine = taught
    st.sim.place_part(SECOND_POSE)
    take, prompts = _manual_hits_on(st, SECOND_POSE)
    seen = []
    run = RoutineRun(routine, StationRoutineHost(st.measurement, st.controller), part_name="part 2",
                     on_progress=lambda p: seen.append((p.state, p.hits)))
    progress = run.run(manual_hits=take)
    assert prompts == ["Take 3 hits by hand on TOP (primary datum)", "Take 2 hits by hand on FRONT (secondary datum)",
                       "Take 1 hit by hand on LEFT (tertiary datum)"]
    assert progress.state == "done" and progress.hits == progress.total_hits == sum(
        len(routine.program.feature(n).hits) for n, *_ in FACES)
    # the alignment found the second part: the model's pose is the simulator's within microns
    pose = st.measurement.part.pose
    delta = pose @ invert(SECOND_POSE)
    assert np.linalg.norm(delta[:3, 3]) < 0.01 and np.degrees(np.arccos(min(1.0, (np.trace(delta[:3, :3]) - 1) / 2))) < 0.01
    bore, boss, dome = (progress.results[n] for n in ("bore", "boss", "dome"))
    assert bore.result.geometry()["radius"] == pytest.approx(15.0, abs=0.005)
    assert boss.result.geometry()["radius"] == pytest.approx(10.0, abs=0.005)
    # five hits on a 45 deg cap: its radius is several times less certain than one hit
    assert dome.result.geometry()["radius"] == pytest.approx(10.0, abs=0.02)
    centre = invert(pose) @ np.array([*bore.result.geometry()["point"], 1.0])
    assert np.hypot(centre[0] - 30.0, centre[1] - 40.0) < 0.02  # in part coordinates, where the drawing has it
    dist = progress.results["bore-boss"]
    assert dist.result.value == pytest.approx(np.hypot(70 - 30, 22 - 40), abs=0.01)
    assert seen[-1][0] == "done" and [h for _s, h in seen] == sorted(h for _s, h in seen)
    assert str(progress.session).find("part 2") >= 0  # the part's results are a session of their own
    report = progress.results["report"].read_text()  # the report step wrote the part's report beside it
    assert progress.results["report"].suffix == ".html" and "bore" in report and "dome" in report


def test_each_run_of_a_routine_is_a_part_of_its_trends_series(taught, tmp_path):
    """Two parts through the routine: both in the routine's series, with their features' and constructions'
    characteristics and the part names as serials."""
    from cmm.session.trends import Trends

    st, routine = taught
    r = Routine(from_toml(routine.text()))
    r.steps[0]["manual"] = None  # the parts are aligned: the datums are measured automatically
    r.delete(8)  # no report step: the trends are what this test reads
    next(s for s in r.steps if s["name"] == "dome")["skip"] = True  # nor the dome (a shorter run)
    st.measurement.trends = trends = Trends(tmp_path / "trends", station="cmm-test")
    try:
        parts = []
        for name, pose in (("P1", TRUE_PART_POSE), ("P2", SECOND_POSE)):
            st.sim.place_part(pose)
            st.measurement.set_alignment(pose, "manual", note=f"{name} placed")
            parts.append(RoutineRun(r, StationRoutineHost(st.measurement, st.controller), part_name=name).run().part)
        assert [p.serial for p in parts] == ["P1", "P2"] and trends.series() == ["block"]
        names = [n for n, _ in trends.characteristics("block")]
        diameter = next(n for n in names if n.startswith("bore / diameter"))
        assert any(n.startswith("bore-boss / ") for n in names) and any(n.startswith("TOP / ") for n in names)
        h = trends.history("block", diameter)
        assert h.serial == ["P1", "P2"] and h.station == ["cmm-test"] * 2 and np.allclose(h.value, 30.0, atol=0.01)
    finally:
        st.measurement.trends = None
        trends.close()


def test_pause_skip_and_cancel_between_hits(taught):
    st, routine = taught
    st.sim.place_part(TRUE_PART_POSE)
    st.measurement.set_alignment(TRUE_PART_POSE, "manual", note="back on the first part")
    r = Routine(from_toml(routine.text()))
    r.steps[0]["manual"] = None  # this part is aligned: the datums are measured automatically
    run = RoutineRun(r, StationRoutineHost(st.measurement, st.controller), part_name="part 3")
    events, cancelled, refused = [], [], []
    done = set()
    api, holder, observer = st.controller.commands, Client("page", local=True), Client("lan-tab")
    control = Control(lan=True, access_code="c0de")
    assert control.take("page", is_local=True)

    def on_progress(p):
        events.append((p.state, p.step, p.hits))
        if p.hits == 2 and "pause" not in done:  # the operator pauses after the second hit (an observer may not) ...
            done.add("pause")
            refused.append(api.call(observer, "pause"))
            assert api.call(holder, "pause").result["paused"] == ["routine 'block'"]
        elif p.state == "paused" and "resume" not in done:  # ... and resumes (only the holder)
            done.add("resume")
            refused.append(api.call(Client("pendant", local=True), "resume"))
            assert api.call(holder, "resume").result["resumed"] == ["routine 'block'"]
        elif p.step == 4 and p.hits == 13 and "skip" not in done:  # the first bore hit taken: skip the bore
            done.add("skip")
            refused.append(api.call(observer, "skip_step"))
            assert api.call(holder, "skip_step").result["skipped"] == ["routine 'block'"]
        elif p.step == 6 and "cancel" not in done:  # any front end's cancel verb ends the routine between hits
            done.add("cancel")
            cancelled.append(st.controller.commands.call(None, "cancel"))

    run.on_progress = on_progress
    st.controller.use_policy_of(control)
    try:
        with pytest.raises(RoutineCancelled):
            run.run()
    finally:
        st.controller.policy = OpenPolicy()
    assert [x.error["code"] for x in refused] == ["refused"] * 3, refused
    assert ("paused", 0, 2) in events
    assert "bore" not in run.progress.results and "FRONT" in run.progress.results
    assert run.progress.state == "cancelled"
    assert cancelled[0].ok and "routine 'block'" in cancelled[0].result["cancelled"]
    assert st.controller.jobs.descriptions() == []
    notes = [e.get("text", "") for e in read_events(st.measurement.journal.path).events if e["kind"] == "note"]
    assert any("bore skipped by the operator after 1 of" in n for n in notes)
    assert any(n.startswith("routine 'block' cancelled") for n in notes)


def test_a_fault_mid_routine_is_resumed_from_the_stopped_step_with_another_probe_per_step(taught):
    """Bore (Probe1) and boss (T2, a second stylus of the same ball) on the aligned first part; an obstacle on the
    way to the bore's second hit stops the run there with an unexpected contact; the operator clears it,
    resets and resumes: the machine retracts, the bore's first hit is discarded (still in the journal), the bore is
    measured again from its first hit, the probe changes to T2 for the boss, and the part's session is complete."""
    st, routine = taught
    model = st.measurement
    st.sim.place_part(TRUE_PART_POSE)
    model.set_alignment(TRUE_PART_POSE, "manual", note="the first part again")
    r = Routine(from_toml(routine.text()))
    for name in ("alignment", "TOP", "FRONT", "LEFT", "dome"):
        r.delete(next(i for i, s in enumerate(r.steps) if s["name"] == name))
    assert [s["name"] for s in r.steps] == ["bore", "boss", "bore-boss", "report"]
    assert r.steps[0]["probe"] == "Probe1"  # taught: the probe that took the bore
    tip_d = 2 * st.config.probe.tip_radius
    st.calibration.add_probe("T2", tip_d)
    r.set_probe(1, "T2")
    assert "[T2]" in r.lines()[1] and 'probe = "T2"' in r.text()
    # the obstacle: a 2 mm ball halfway along the straight rapid inside the bore from its first hit's retract to
    # its second hit's pre-hit point
    cfg = st.config.probe
    bore = r.program.feature("bore")
    targets = {h.id: (p, u) for h, p, u, _cz in machine_targets(r.program, TRUE_PART_POSE)}
    (p1, u1), (p2, u2) = targets[bore.hits[0]], targets[bore.hits[1]]
    retract = p1 - (cfg.tip_radius + cfg.retract_distance) * u1
    pre = p2 - (cfg.tip_radius + cfg.approach_distance) * u2
    st.sim.place_artifacts([((retract + pre) / 2, 2.0)])
    run = RoutineRun(r, StationRoutineHost(model, st.controller, select_probes=True), part_name="part 4")
    with pytest.raises(Exception, match="unexpected probe contact"):
        run.run()
    assert run.progress.state == "failed" and run.faulted == 0 and run.can_resume
    assert run.progress.message.startswith("step 1 (bore) stopped: unexpected probe contact")
    assert run.progress.hits == 1
    session = run.progress.session
    first_hit = max(model.hits)
    st.sim.place_artifacts([])  # the operator takes the obstacle away
    st.controller.reset(None)
    progress = run.resume_after_fault()
    assert progress.state == "done" and progress.session == session
    assert run.discarded == [first_hit] and first_hit not in model.hits
    assert progress.hits == progress.total_hits == len(bore.hits) + len(r.program.feature("boss").hits)
    b, k = progress.results["bore"], progress.results["boss"]
    assert first_hit not in b.hit_ids and len(b.hit_ids) == len(bore.hits)
    assert b.result.geometry()["radius"] == pytest.approx(15.0, abs=0.005)
    assert k.result.geometry()["radius"] == pytest.approx(10.0, abs=0.005)
    assert progress.results["bore-boss"].result.value == pytest.approx(np.hypot(70 - 30, 22 - 40), abs=0.01)
    assert model.feature_probe(b) == "Probe1" and model.feature_probe(k) == "T2" and model.probe_name == "T2"
    events = read_events(session).events
    assert sum(e["kind"] == "routine" for e in events) == 1  # one part, one session
    assert any(e["kind"] == "hit" and e["id"] == first_hit for e in events)  # the discarded hit is kept ...
    assert any(e["kind"] == "hit_deleted" and e["id"] == first_hit for e in events)  # ... as deleted
    assert any(e["kind"] == "routine_discarded" and e["hit_ids"] == [first_hit] for e in events)
    notes = [e.get("text", "") for e in events if e["kind"] == "note"]
    retract = [n for n in notes if "retracted to the clearance height" in n]
    assert retract and float(retract[0].rsplit("Z", 1)[1]) >= model.clearance_z() - 1e-6
    assert notes.index(retract[0]) < notes.index("routine 'block' resumed from step 1")
    # the report names the probe of every feature
    saved = open_session(session)
    rows = [line.split(",") for line in features_csv(saved).splitlines()]
    col = rows[0].index("probe")
    assert {row[0]: row[col] for row in rows[1:] if row[1] in ("cylinder",)} == {"bore": "Probe1", "boss": "T2"}
    html = render(saved)
    assert "<th class='l'>probe</th>" in html and ">T2<" in html and ">Probe1<" in html
    st.calibration.select_probe(None, "Probe1")


def test_restart_and_cancel_after_a_fault(taught):
    """A run stopped by E-STOP: Resume is refused until Reset; Restart discards what the run measured and runs
    again from the first step; a second stop, then Cancel ends it."""
    st, routine = taught
    model = st.measurement
    model.set_alignment(TRUE_PART_POSE, "manual", note="the first part again")
    r = Routine(from_toml(routine.text()))
    for name in ("alignment", "TOP", "FRONT", "LEFT", "dome", "bore-boss", "boss"):
        r.delete(next(i for i, s in enumerate(r.steps) if s["name"] == name))
    assert [s["name"] for s in r.steps] == ["bore", "report"]
    run = RoutineRun(r, StationRoutineHost(model, st.controller), part_name="part 5")
    stopped = []

    def on_progress(p):
        if p.hits == 3 and not stopped:
            stopped.append(st.controller.emergency_stop(None))

    run.on_progress = on_progress
    with pytest.raises(Exception):
        run.run()
    assert stopped and run.progress.state == "failed" and run.faulted == 0
    with pytest.raises(RoutineError, match="emergency stopped: press Reset"):
        run.resume_after_fault()  # still latched: nothing moved, nothing discarded
    assert run.discarded == [] and run.can_resume
    st.controller.reset(None)
    taken = sorted(model.hits)[-3:]
    run.on_progress = None
    progress = run.restart()
    assert progress.state == "done" and progress.hits == len(r.program.feature("bore").hits)
    assert set(taken) <= set(run.discarded) and not set(taken) & set(progress.results["bore"].hit_ids)
    assert progress.results["bore"].result.geometry()["radius"] == pytest.approx(15.0, abs=0.005)
    with pytest.raises(RoutineError, match="no stopped"):
        run.resume_after_fault()
    run2 = RoutineRun(r, StationRoutineHost(model, st.controller), part_name="part 6")
    run2.on_progress = lambda p: p.hits == 1 and st.controller.emergency_stop(None)
    with pytest.raises(Exception):
        run2.run()
    run2.cancel()
    assert run2.progress.state == "cancelled" and not run2.can_resume
    st.controller.reset(None)
    notes = [e.get("text", "") for e in read_events(run2.progress.session).events if e["kind"] == "note"]
    assert any("cancelled after the fault at step 1" in n for n in notes)


def test_every_edit_of_the_routine_tab(taught):
    """The Routine tab's edits on a taught routine (no page: the panel's actions): rename, reorder, skip, delete,
    insert (feature, alignment, construction, report), tolerance, clearance, nominal, hit plan, one hit, probe,
    manual alignment; a wrong entry is refused with a sentence and changes nothing."""
    from stations import station_page

    st, routine = taught
    ui = station_page(st, host="127.0.0.1", port=free_port(), pendant=False, ask_name=False)
    try:
        capp = ui.add_client(client_id="operator", is_local=True)
        panel = capp.routine
        panel.routine = r = Routine(from_toml(routine.text()))

        def refused(*edit, says):
            before = r.text()
            assert not (panel.insert_text(edit[1]) if edit[0] == "insert" else panel.edit(*edit))
            assert says in capp.messages[-1][2], capp.messages[-1]
            assert r.text() == before  # nothing changed

        panel.select(4)  # the bore
        assert panel.edit("rename", "BORE") and r.steps[4]["name"] == "BORE" and r.steps[7]["of"][0] == "BORE"
        assert panel.edit("nominal", "radius=15.01 point=30 40 0")
        assert r.program.feature("BORE").nominal["radius"] == 15.01
        assert r.program.feature("BORE").nominal["point"] == [30.0, 40.0, 0.0]
        refused("nominal", "diameter=30", says="no 'diameter'")
        refused("nominal", "radius=-1", says="more than 0")
        refused("nominal", "radius", says="name=value")
        hits = list(r.program.feature("BORE").hits)
        assert panel.edit("hits", " ".join(map(str, hits[1:][::-1])))  # one hit dropped, the order reversed
        assert r.program.feature("BORE").hits == hits[1:][::-1]
        refused("hits", str(hits[1]), says="needs at least")
        refused("hits", f"{hits[1]} {hits[2]} 9999 {hits[3]} {hits[4]} {hits[5]}", says="no hit 9999")
        x, y, z = next(h for h in r.program.hits if h.id == hits[2]).point
        assert panel.edit("hit", f"{hits[2]} {x} {y} {z - 1.0}")
        assert next(h for h in r.program.hits if h.id == hits[2]).point == pytest.approx((x, y, z - 1.0))
        refused("hit", f"{hits[0]} 1 2 3", says="not one of BORE's hits")  # dropped from the plan above
        refused("hit", f"{hits[2]} 1 2 300", says="above its clearance")
        assert panel.edit("tolerance", "0.01 0.005 0.02")
        tol = r.program.feature("BORE").tolerance
        assert (tol["size"], tol["form"], tol["location"]) == (0.01, 0.005, 0.02)
        refused("tolerance", "0.01 0.01", says="three tolerances")
        refused("tolerance", "0.01 -1 0.01", says="positive")
        assert panel.edit("clearance", 75.0)
        assert panel.edit("probe", "T2") and r.steps[4]["probe"] == "T2" and "[T2]" in r.lines()[4]
        assert panel.edit("probe", "") and "probe" not in r.text().split("[[steps]]")[5]
        assert panel.edit("up") and r.steps[3]["name"] == "BORE"
        assert panel.edit("down") and r.steps[4]["name"] == "BORE"
        assert panel.edit("skip") and r.steps[4]["skip"] and "(skipped)" in r.lines()[4]
        assert panel.edit("skip") and not r.steps[4].get("skip")
        panel.select(6)  # the dome
        assert panel.edit("delete") and "dome" not in [s["name"] for s in r.steps]
        panel.select(5)
        assert panel.insert_text("feature dome") and r.steps[6]["name"] == "dome"
        refused("insert", "feature dome", says="same name")
        refused("insert", "feature nothing", says="not a feature")
        assert panel.insert_text("angle TOP FRONT top-front") and r.steps[7]["operation"] == "angle"
        assert panel.insert_text("report final") and r.steps[8] == {"kind": "report", "name": "final"}
        refused("insert", "angle TOP nothing", says="before it is measured")
        refused("insert", "sideways", says="write 'report NAME'")
        panel.select(0)
        assert panel.edit("manual") and not r.steps[0].get("manual") and "(automatic)" in r.lines()[0]
        assert panel.edit("manual") and r.steps[0]["manual"]
        panel.select(1)
        refused("manual", says="not an alignment")
        assert panel.edit("delete") and r.steps[0]["kind"] == "align"  # TOP deleted: the alignment's datum stays
        again = Routine(from_toml(r.text()))  # every edit is in the file
        assert again.lines() == r.lines() and again.program.feature("BORE").hits == hits[1:][::-1]
    finally:
        ui.close()


def test_the_routine_tab_shows_each_steps_settings_and_fills_the_edit_fields_with_them(taught):
    """A step chosen in the page's Step list fills the edit fields with what the step has (the hit plan's ids, the
    nominal, the tolerance, the clearance), and the list shows each feature's settings after an edit, without
    saving the file."""
    import ui_support
    from stations import station_page

    st, routine = taught
    ui = station_page(st, host="127.0.0.1", port=free_port(), pendant=False, ask_name=False)
    try:
        with ui_support.viser_tab(ui, lambda c: "hits" in c.routine.gui) as (_ws, capp):
            panel = capp.routine
            panel.routine = r = Routine(from_toml(routine.text()))
            panel._show(select=0)
            k = next(i for i, s in enumerate(r.steps) if s["name"] == "bore")
            panel.select(k)
            f = r.program.feature("bore")
            clearance = max(h.clearance_z for h in r.program.hits if h.id in f.hits)
            assert panel.gui["hits"].value == " ".join(map(str, f.hits))
            assert "radius=15" in panel.gui["nominal"].value and "point=" in panel.gui["nominal"].value
            assert panel.gui["clearance"].value == pytest.approx(clearance)
            size, form, location = (float(x) for x in panel.gui["tolerance"].value.split())
            assert (size, form, location) == (f.tolerance["size"], f.tolerance["form"], f.tolerance["location"])
            assert panel.edit("tolerance", "0.01 0.005 0.02") and panel.edit("clearance", clearance + 5.0)
            assert f"± 0.01 0.005 0.02 mm (size form location) · clearance Z {clearance + 5.0:g}" in panel.text()
            panel.select(0)  # the alignment: nothing of a feature to fill, the fields keep what they had
            assert panel.gui["hits"].value == " ".join(map(str, f.hits))
    finally:
        ui.close()


def _csv_rows(path):
    import csv
    import io

    rows = list(csv.DictReader(io.StringIO(features_csv(open_session(path)))))
    return {(r["feature"], r["kind"], r["method"], r["characteristic"]): r for r in rows}


def test_a_taught_routine_keeps_gdt_datums_tolerances_and_constructions(taught):
    """the GD&T position with datums A|B|C was dropped from the taught routine (the next part's report
    had no datum-referenced position) and the routine list showed the bore's location tolerance as 0. A part is
    measured by the routine, the operator adds datums A|B|C, feature control frames (position at MMC to A|B|C,
    flatness, perpendicularity to A), a position-only tolerance on the bore and a toleranced construction; the
    routine taught from that session runs on a second part placed differently, and its report has the same
    characteristics, line by line, with the same tolerances and values within microns."""
    st, routine = taught
    model = st.measurement
    r = Routine(from_toml(routine.text()))
    r.steps[0]["manual"] = None  # the parts are aligned by hand beforehand: the datums are measured automatically
    next(s for s in r.steps if s["name"] == "dome")["skip"] = True  # a shorter run
    r.program.feature("bore").tolerance = {"position": 0.05, "size": 0.01}  # no location given
    st.sim.place_part(TRUE_PART_POSE)
    model.set_alignment(TRUE_PART_POSE, "manual", note="GDT1 placed")
    # part names no other test's run took
    first = RoutineRun(r, StationRoutineHost(model, st.controller), part_name="GDT1").run()
    fids = {n: f.id for n, f in first.results.items() if hasattr(f, "id")}
    for label, name in zip("ABC", ("TOP", "FRONT", "LEFT")):
        model.define_datum(label, fids[name])
    model.define_gdt("position", fids["bore"], 0.05, "A|B|C", material="MMC", name="bore position")
    model.define_gdt("flatness", fids["TOP"], 0.02, name="TOP flatness")
    model.define_gdt("perpendicularity", fids["boss"], 0.05, "A", name="boss perpendicularity")
    model.construct_feature("distance", fids["bore"], fids["boss"], "bore-boss toleranced", tolerance={"location": 0.03})
    p1 = first.session
    taught2 = teach_routine(open_session(p1), name="block2", part_mesh=model.part.mesh,
                            part_nominals=model.part.nominal_features, manual_alignment=False)
    assert not taught2.program.untaught, taught2.program.untaught
    assert [d["label"] for d in taught2.program.datums] == ["A", "B", "C"]
    assert {g["name"] for g in taught2.program.gdt} == {"bore position", "TOP flatness", "boss perpendicularity"}
    again = Routine(from_toml(taught2.text()))  # through the file, as a saved routine is
    assert again.program.gdt == taught2.program.gdt and again.program.datums == taught2.program.datums
    bore_step = next(i for i, s in enumerate(again.steps) if s["name"] == "bore")
    assert again.settings(bore_step)["tolerance"] == "0.01 0.02 0.02"  # size form location: location not 0
    assert again.program.feature("bore").tolerance["position"] == 0.05
    assert next(s for s in again.steps if s["name"] == "bore-boss toleranced")["tolerance"] == {"location": 0.03}
    st.sim.place_part(SECOND_POSE)
    model.set_alignment(SECOND_POSE, "manual", note="GDT2 placed")
    second = RoutineRun(again, StationRoutineHost(model, st.controller), part_name="GDT2").run()
    assert second.state == "done"
    # the run ends with the tip at the clearance plane (it stood beside the cone at part Z 43)
    assert st.controller.frame_position("machine")[2] >= st.controller.workspace.clearance_z() - 0.01
    a, b = _csv_rows(p1), _csv_rows(second.session)
    gdt_lines = {k for k in a if k[1] == "gdt"}
    assert ("bore", "gdt", "A|B|C", "⊕ position") in gdt_lines, gdt_lines
    assert set(a) == set(b), (set(a) ^ set(b))  # every characteristic of the first part, and no other
    for key, ra in a.items():
        rb = b[key]
        for col in ("nominal", "upper_tol", "lower_tol"):
            if ra[col] or rb[col]:
                assert float(rb[col]) == pytest.approx(float(ra[col]), abs=0.005), (key, col, ra[col], rb[col])
        if ra["actual"]:
            assert rb["actual"], key
            assert float(rb["actual"]) == pytest.approx(float(ra["actual"]), abs=0.02), (key, ra["actual"], rb["actual"])
        assert ra["result"] == rb["result"], (key, ra["result"], rb["result"])


def test_the_wizard_prompts_the_routines_manual_alignment(taught):
    """The routine's manual 3-2-1 is prompted by the Align tab's wizard: its datums' faces marked, the hits counted as
    the operator takes them (here where the part really is, beside each marker), then the routine aligns and runs."""
    import threading

    from cmm.measurement.align_wizard import AlignWizard, routine_elements, routine_manual_hits

    st, routine = taught
    st.controller.policy = OpenPolicy()  # the bench's open policy (a test before may have served a LAN policy)
    pose = pose_matrix((193.0, 148.0, 0.0), rz_deg=1.5)
    st.sim.place_part(pose)
    model = st.measurement
    me = Client("page", local=True)
    wizards = []

    def wizard_for(datums):
        w = AlignWizard(model, lambda verb, **p: st.controller.commands.invoke(me, verb, **p), "routine",
                        elements=routine_elements(routine, datums))
        w.listen()
        wizards.append(w)
        return w

    run = RoutineRun(routine, StationRoutineHost(model, st.controller, me), part_name="wizard part")
    done = []
    worker = threading.Thread(target=lambda: done.append(run.run(manual_hits=routine_manual_hits(run, wizard_for))),
                              daemon=True)
    worker.start()
    import time

    end = time.monotonic() + 120
    while not wizards and time.monotonic() < end:
        time.sleep(0.05)
    (w,) = wizards
    assert [s.element.name for s in w.steps] == ["TOP (primary datum)", "FRONT (secondary datum)",
                                                 "LEFT (tertiary datum)"]
    assert "touch TOP at the markers" in w.prompt() and [s.element.hits for s in w.steps] == [3, 2, 1]
    for _ in range(6):
        s = w.step
        p, n = s.targets[len(s.hit_ids)]  # the marker (part coordinates): touched where the part really is
        model.probe((pose @ np.array([*p, 1.0]))[:3], -(pose[:3, :3] @ n), clearance_z=90.0).wait(120)
        w.settle()
    assert w.done and "the routine aligns the part" in w.prompt()
    worker.join(600)
    assert done and done[0].state == "done", run.progress.message
    delta = model.part.pose @ invert(pose)
    assert np.linalg.norm(delta[:3, 3]) < 0.01
