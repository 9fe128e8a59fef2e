"""Teach and repeat: a program taught on one set-up runs on a second part pose after alignment."""

from __future__ import annotations

import numpy as np
import pytest

import session_support as sup
from cmm.measurement.model import Part
from cmm.measurement.program import run_on, run_program
from cmm.measurement.recording import record
from cmm.program import toml_program as prog
from cmm.journal.store import DirectoryStore, load_session
from cmm.sim.sample_part import reference_sphere

COUNT = 0.002


@pytest.fixture(scope="module")
def taught(tmp_path_factory):
    root = tmp_path_factory.mktemp("programs")
    sup.recorded_copy(root)
    session = load_session(DirectoryStore(root), "taught")
    sim, _, _ = sup.setup()
    return prog.teach(session, name="sample-part check", part_mesh=sim.part_mesh, part_nominals=sim.nominal_features)


def _part_coords(feature, pose):
    """The fitted feature's characteristic values in part coordinates."""
    inv = np.linalg.inv(pose)
    g = feature.result.geometry()
    R, t = inv[:3, :3], inv[:3, 3]
    if feature.kind == "plane":
        n = R @ np.array(g["normal"])
        return {"offset": float(n @ (R @ np.array(g["point"]) + t)), "normal": n}
    if feature.kind == "cylinder":
        d = R @ np.array(g["direction"])
        p = R @ np.array(g["point"]) + t
        p40 = p + (40.0 - p[2]) / d[2] * d  # the axis at part z = 40
        return {"radius": g["radius"], "axis_xy": p40[:2], "direction": d * np.sign(d[2])}
    if feature.kind == "sphere":
        return {"radius": g["radius"], "center": R @ np.array(g["center"]) + t}
    raise AssertionError(feature.kind)


def test_program_round_trips_through_toml(taught, tmp_path):
    path = prog.save(taught, tmp_path / "check.toml")
    text = path.read_text()
    assert 'format = "cmm-program/1"' in text and "[[hits]]" in text and "clearance_z" in text
    again = prog.load(path)
    assert again == taught
    assert [f.name for f in again.features] == ["top_plane", "boss", "dome"]
    assert len(again.hits) == 17
    boss = again.feature("boss")
    assert boss.kind == "cylinder" and boss.method == "ls" and boss.nominal_ref == "boss"
    assert boss.nominal["radius"] == pytest.approx(10.0)
    # hits are in part coordinates: the boss hits lie on its nominal surface
    for i in boss.hits:
        h = next(h for h in again.hits if h.id == i)
        assert np.hypot(h.point[0] - 70, h.point[1] - 22) == pytest.approx(10.0, abs=0.01)


def test_program_taught_on_one_pose_measures_the_same_on_a_second_pose(taught, tmp_path):
    # first set-up: the features as the taught session measured them (re-run the program there too)
    results = []
    for true_pose, guess in ((None, sup.NOMINAL_PART_POSE), (sup.SECOND_POSE, sup.SECOND_GUESS)):
        sim, machine, prober = sup.setup(true_pose)
        part = Part("sample part", sim.part_mesh, guess.copy(), dict(sim.nominal_features))
        rec = record(DirectoryStore(tmp_path).create(f"run{len(results)}"), machine, prober, part)
        try:
            pose = sup.align(rec, guess)
            run = run_program(taught, rec, pose)
        finally:
            rec.close()
            machine.close()
        assert set(run.features) == {"top_plane", "boss", "dome"}
        assert len(run.hit_ids) == 17
        results.append({name: _part_coords(f, pose) for name, f in run.features.items()})
    a, b = results
    tol = 2 * COUNT
    assert abs(a["top_plane"]["offset"] - b["top_plane"]["offset"]) <= tol
    assert a["top_plane"]["offset"] == pytest.approx(40.0, abs=tol)
    assert abs(a["boss"]["radius"] - b["boss"]["radius"]) <= tol
    assert np.linalg.norm(a["boss"]["axis_xy"] - b["boss"]["axis_xy"]) <= tol
    assert np.linalg.norm(a["boss"]["axis_xy"] - [70, 22]) <= tol
    assert abs(a["dome"]["radius"] - b["dome"]["radius"]) <= tol
    assert np.linalg.norm(a["dome"]["center"] - b["dome"]["center"]) <= tol
    # the second run's session records the alignment, the hits and the fitted features
    s = load_session(DirectoryStore(tmp_path), "run1")
    assert len(s.state.alignments) == 1 and len(s.features) == 3 and len(s.hits) == 9 + 17
    assert any("program" in text for _, text in s.state.notes)


def _recorder(tmp_path, mesh=None, nominals=None):
    sim, machine, prober = sup.setup()
    part = Part("other", mesh if mesh is not None else sim.part_mesh, sup.NOMINAL_PART_POSE.copy(),
                    dict(sim.nominal_features) if nominals is None else nominals)
    return record(DirectoryStore(tmp_path).create("refused"), machine, prober, part), machine


def _refused(program, tmp_path, match, **kw):
    rec, machine = _recorder(tmp_path, **kw)
    start = machine.position.copy()
    try:
        with pytest.raises(prog.ProgramError, match=match):
            run_program(program, rec, sup.NOMINAL_PART_POSE)
        assert np.allclose(machine.position, start)  # nothing moved
        assert rec.hits == {}
    finally:
        rec.close()
        machine.close()


def test_a_program_for_another_part_is_refused_before_anything_moves(taught, tmp_path):
    other, _ = reference_sphere()
    _refused(taught, tmp_path, r"taught on part 'sample part' \(sha256 .*loaded part 'other'", mesh=other)


def test_a_program_whose_features_do_not_match_is_refused_before_anything_moves(taught, tmp_path):
    text = prog.to_toml(taught)
    bad = prog.from_toml(text.replace('nominal_ref = "boss"', 'nominal_ref = "flange"'))
    _refused(bad, tmp_path / "a", r"nominal feature 'flange'.*does not have")
    bad = prog.from_toml(text)
    bad.features[1].hits.append(99)
    _refused(bad, tmp_path / "b", r"refers to hits \[99\]")
    bad = prog.from_toml(text.replace('kind = "sphere"', 'kind = "sphere"\nmethod = "mcc"', 0))
    bad.features[0].method = "mic"
    _refused(bad, tmp_path / "c", r"method 'mic' is not available for a plane")


def test_bad_program_files_are_refused_with_a_message(tmp_path):
    with pytest.raises(prog.ProgramError, match="not valid TOML"):
        prog.from_toml("name = [", "x.toml")
    with pytest.raises(prog.ProgramError, match="format must be"):
        prog.from_toml('name = "x"')
    with pytest.raises(prog.ProgramError, match="sha256"):
        prog.from_toml('format = "cmm-program/1"\n[part]\nname = "x"\n')
    with pytest.raises(prog.ProgramError, match="three finite numbers"):
        prog.from_toml('format = "cmm-program/1"\n[part]\nsha256 = "ab"\n[[hits]]\nid = 1\npoint = [1, 2]\n'
                       'approach = [0, 0, -1]\nclearance_z = 50.0\n')
    with pytest.raises(prog.ProgramError, match="cannot read"):
        prog.load(tmp_path / "missing.toml")


def test_a_program_runs_on_a_measurement_model_only(tmp_path):
    with pytest.raises(TypeError, match="runs on a measurement model, not on object"):
        run_program(prog.Program("x", "p", "ab", [], [], 10.0), object())


def test_a_program_run_on_the_station_journals_its_features_with_their_tolerances(taught, stations, tmp_path):
    """The front ends' path (a job of the control core, on the station's model) records each feature's tolerance."""
    program = prog.from_toml(prog.to_toml(taught))
    program.features = [f for f in program.features if f.name != "boss"]  # fewer hits: a faster test
    used = {i for f in program.features for i in f.hits}
    program.hits = [h for h in program.hits if h.id in used]
    tolerances = {f.name: {"size": 0.031 + k / 1000, "form": 0.017, "location": 0.023}
                  for k, f in enumerate(program.features)}
    for f in program.features:
        f.tolerance = tolerances[f.name]
    station = stations.station("station-run")
    try:
        run = run_on(station.controller, station.measurement, program)
        assert set(run.features) == {"top_plane", "dome"}
        assert {f.name: f.tolerance for f in station.measurement.features.values()} == tolerances
    finally:
        station.close()
    s = load_session(DirectoryStore(tmp_path), "station-run")
    assert {f.name: f.tolerance for f in s.features.values()} == tolerances
    assert any("program 'sample-part check' finished" in text for _, text in s.state.notes)


def test_a_programs_later_hits_of_a_feature_hop_below_the_clearance_height_and_fit_the_same(taught, stations):
    """The CLI's program runner hops within a feature as the routine runner does: on the station (rails, the part
    mesh) the plane's later hits never climb to the clearance height, each takes less machine time (the
    simulator's virtual clock) and the fitted plane is the one the clearance route gives, within probing noise."""
    from cmm.sim.cmm_sim import TRUE_PART_POSE

    program = prog.from_toml(prog.to_toml(taught))
    program.features = [f for f in program.features if f.name == "top_plane"]
    program.hits = [h for h in program.hits if h.id in program.features[0].hits]
    assert len(program.hits) >= 4
    station = stations.station("program-hops")
    try:
        model = station.measurement
        model.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
        clearance = min(cz for *_, cz in prog.machine_targets(program, TRUE_PART_POSE))  # the hits' own
        runs = {}
        for hops in (False, True):
            zs, done = [], []
            station.sim.network.add_tick_hook(lambda net, tick: zs.append(station.sim.axis_readings()[2]))
            clock = station.machine.clock
            try:
                run = station.controller.run_job(None, "program", lambda: run_program(
                    program, model, progress=lambda k, n: done.append((len(zs), clock.now())), hops=hops))
            finally:
                station.sim.network.tick_hooks.pop()
            later = zs[done[0][0]:done[-1][0]]  # the tip from the first hit's end to the last one's
            per_hit = (done[-1][1] - done[0][1]) / (len(done) - 1)
            runs[hops] = (max(later), per_hit, _part_coords(run.features["top_plane"], TRUE_PART_POSE))
    finally:
        station.close()
    (z_over, s_over, over), (z_hop, s_hop, hop) = runs[False], runs[True]
    print(f"top plane, later hits: over the clearance height {s_over:.2f} machine s/hit (Z up to {z_over:.1f}), "
          f"hopping {s_hop:.2f} machine s/hit (Z up to {z_hop:.1f})")
    assert z_over > clearance - 0.5  # every hit over the clearance height
    assert z_hop < clearance - 5.0  # the later hits hop low over the plane
    assert s_hop < 0.9 * s_over  # the hits lie far apart: most of the time is the travel across
    assert hop["offset"] == pytest.approx(over["offset"], abs=5 * COUNT)
    assert np.allclose(hop["normal"], over["normal"], atol=1e-4)
