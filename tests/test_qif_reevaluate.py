"""A DMIS session re-evaluated from raw counts: its QIF document carries every DMIS-only tolerance of the run
(PERPEND, PARLEL, ANGLR, DISTB, ANGLB, PROFS, PROFL, RUNOUT, CONCEN), evaluated again on the refitted features.

The sample part's program up to the sphere, with a constructed point and a tolerance of every such kind, runs on
the simulator (``cmm run --qif``); ``cmm sessions reevaluate`` runs the program again on the hits recomputed from
their counts (cmm.dmis.replay). With the recorded probe the values are the run's; with a 0.01 mm bigger tip they
move, and each one is the direct recomputation on the refitted features: the station's GD&T, the distance and
angle between them, the hits' distances from the nominal surfaces placed in the part frame the refitted datums
make. A session recorded without what the replay needs says in its document and on the command line what is left
out and why. The replay itself, on given hits: the operator's recorded answers, and where it cannot follow the run.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import qif_support
from qif_support import NS
from test_qif import DMIS_ONLY, SAMPLE, characteristics

TOLERANCES = [
    "CONST/POINT, F(BI), INTOF, FA(BORE), FA(TOP)",
    "T(PERP_B) = TOL/PERPEND, 0.020, DAT(A)", "T(PERP_C) = TOL/PERPEND, 0.020, DAT(A)",
    "T(PAR_BOSS) = TOL/PARLEL, 0.020, DAT(B)", "T(ANG_C) = TOL/ANGLR, 90, 0.020, DAT(A)",
    "T(DIST_BOSS) = TOL/DISTB, NOMINL, 43.863, -0.030, 0.030", "T(ANG_TF) = TOL/ANGLB, NOMINL, 90, -0.05, 0.05",
    "T(DIST_BI) = TOL/DISTB, NOMINL, 43.875, -0.01, 0.01",
    "T(PROF_TOP) = TOL/PROFS, 0.020", "T(PROF_SPH) = TOL/PROFS, 0.020", "T(PROFL_B) = TOL/PROFL, 0.025",
    "T(RUN_TOP) = TOL/RUNOUT, CIRCLR, 0.020, DAT(B)", "T(CON_SPH) = TOL/CONCEN, 0.020, DAT(B)",
    "T(DIAM_B) = TOL/DIAM, -0.020, 0.020",
    "OUTPUT/FA(BORE), TA(DIAM_B), TA(PERP_B), TA(PROFL_B)", "OUTPUT/FA(FRONT), TA(PERP_C), TA(ANG_C)",
    "OUTPUT/FA(BOSS), TA(PAR_BOSS)", "OUTPUT/FA(BORE), FA(BOSS), TA(DIST_BOSS)",
    "OUTPUT/FA(TOP), FA(FRONT), TA(ANG_TF)", "OUTPUT/FA(BI), FA(SPHERE), TA(DIST_BI)",
    "OUTPUT/FA(TOP), TA(PROF_TOP), TA(RUN_TOP)", "OUTPUT/FA(SPHERE), TA(PROF_SPH), TA(CON_SPH)", "ENDFIL", ""]
LABELS = ["PERP_B", "PROFL_B", "PERP_C", "ANG_C", "PAR_BOSS", "DIST_BOSS", "ANG_TF", "DIST_BI", "PROF_TOP", "RUN_TOP",
          "PROF_SPH", "CON_SPH"]


def cli(*argv: str) -> int:
    from cmm.cli import main

    return main(list(argv))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """The program run on the simulator: (its folder, the sessions folder, the session's name)."""
    qif_support.schema_or_skip()
    d = tmp_path_factory.mktemp("reeval")
    lines = SAMPLE.read_text().splitlines()
    sphere = lines.index("ENDMES", lines.index(next(x for x in lines if x.startswith("F(SPHERE)"))))
    program = d / "reeval.dmi"
    program.write_text("\n".join([ln for ln in lines[:sphere + 1] if "DID(REPORT)" not in ln] + TOLERANCES))
    (d / "out").mkdir()
    cwd = os.getcwd()
    os.chdir(d)
    try:
        assert cli("run", str(program), "--sessions", str(d / "sessions"), "-o", str(d / "out" / "out.dms"),
                   "--qif") == 0
    finally:
        os.chdir(cwd)
    from cmm.journal.store import open_store

    (info,) = open_store(str(d / "sessions")).list()
    return d, str(d / "sessions"), info.name


def dmis_only(root) -> dict[str, dict]:
    """The document's DMIS-only characteristics by tolerance label."""
    return {c["name"].rsplit("T(", 1)[1][:-1]: c for c in characteristics(root) if DMIS_ONLY.search(c["name"])}


def reevaluated(sessions: str, name: str, new: str, out: Path, *options: str):
    assert cli("sessions", "--store", sessions, "reevaluate", name, new, *options) == 0
    assert cli("sessions", "--store", sessions, "export", new, "--qif", str(out)) == 0
    return qif_support.validate(out)


def status(value: float, low: float, high: float) -> str:
    return "PASS" if low - 1e-12 <= value <= high + 1e-12 else "FAIL"


def test_a_reevaluated_dmis_session_recomputes_every_dmis_only_tolerance(run, tmp_path, capsys):
    d, sessions, name = run
    ran = dmis_only(qif_support.validate(d / "out" / "reeval.qif"))
    assert sorted(ran) == sorted(LABELS)
    # the recorded probe: the program run again on the same hits gives the run's values
    same = dmis_only(reevaluated(sessions, name, "same", tmp_path / "same.qif"))
    assert sorted(same) == sorted(LABELS)
    for label, c in ran.items():
        assert same[label]["value"] == pytest.approx(c["value"], abs=1e-9), label
        assert (same[label]["status"], same[label]["type"], same[label]["features"]) == \
            (c["status"], c["type"], c["features"]), label
    capsys.readouterr()

    # a 0.01 mm bigger tip: every DMIS-only tolerance evaluated again on the refitted features
    root = reevaluated(sessions, name, "big", tmp_path / "big.qif", "--tip-radius", "1.01")
    said = capsys.readouterr()
    assert "warning" not in said.err and root.find(".//q:NotedEvents", NS) is None
    big = dmis_only(root)
    assert sorted(big) == sorted(LABELS)
    expected = known_answers(sessions, "big")
    for label, c in big.items():
        value = c["value"] - (c["target"] or 0.0) if c["type"] in ("DistanceBetween", "AngleBetween") else c["value"]
        assert value == pytest.approx(expected[label], abs=1e-9), label
        low, high = (c["min"], c["max"]) if c["zone"] is None else (0.0, c["zone"])
        assert c["status"] == status(value, low, high), label
        assert f"T({label}) TOL/" in said.out, label  # the command line lists them, run -> re-evaluated
    # the bigger tip moves the surface points: the bore's and sphere's profiles and the point on the top face
    assert big["PROFL_B"]["value"] - ran["PROFL_B"]["value"] == pytest.approx(0.02, abs=2e-3)  # 0.01 each side
    assert big["PROF_SPH"]["value"] - ran["PROF_SPH"]["value"] > 5e-3
    assert abs(big["DIST_BI"]["value"] - ran["DIST_BI"]["value"]) > 1e-4
    assert big["PROFL_B"]["status"] == "FAIL" != ran["PROFL_B"]["status"]  # 0.030 against 0.025
    # the nominals move with the part as the program's alignment on the refitted datums puts it: the top face,
    # datum A itself, stays on its nominal (kept where the run's alignment put it, its profile would be 0.02)
    assert big["PROF_TOP"]["value"] < 1e-6
    # the Sessions tab's Re-evaluate: the session worker's process, with the DMIS replay handed to it
    from cmm.dmis.replay import reevaluate_event
    from cmm.journal.store import load_session, open_store
    from cmm.session import worker
    from cmm.session.qif_dmis import session_evaluations

    pool = worker.SessionWorker(1)
    try:
        result = pool.call(worker.reevaluate, sessions, name, "big-ui", 1.01, None, reevaluate_event)
    finally:
        pool.close()
    assert result["errors"] == [] and result["left_out"] == ""
    ui = {e.tolerance.label: e.value for e in session_evaluations(load_session(open_store(sessions), "big-ui"))}
    assert {k: ui[k] for k in LABELS} == pytest.approx({k: expected[k] for k in LABELS}, abs=1e-9)


def known_answers(sessions: str, name: str) -> dict[str, float]:
    """Each DMIS-only tolerance computed directly on the re-evaluated session's refitted features."""
    from cmm.journal.store import load_session, open_store
    from cmm.metrology.gdt_eval import MeasuredFeature, evaluate_one

    s = load_session(open_store(sessions), name)
    st = s.state
    hits = {**st.deleted_hits, **st.hits}
    recs = {f.name: f for f in st.features.values()}
    pts = {n: np.array([hits[h].point for h in f.hit_ids], float) for n, f in recs.items()}
    g = {n: f.fit for n, f in recs.items()}
    unit = lambda v: np.asarray(v, float) / np.linalg.norm(v)  # noqa: E731

    def gdt(characteristic: str, feature: str, datum: str, **kw) -> float:
        feats = {0: MeasuredFeature(feature, recs[feature].kind, g[feature], None, pts[feature]),
                 1: MeasuredFeature(datum, recs[datum].kind, g[datum], None, pts[datum])}
        return evaluate_one({"characteristic": characteristic, "feature": 0, "tolerance": 0.02, "datums": ["A"], **kw},
                            {"A": {"label": "A", "feature": 1, "modifier": ""}}, feats).value

    # the part frame D(PART) = DATSET/DAT(A), ZDIR, ZORIG, DAT(C), YMINUS, DAT(B), XORIG, YORIG on the refits
    z = unit(g["TOP"]["normal"]) * np.sign(g["TOP"]["normal"][2])
    y = -unit(g["FRONT"]["normal"]) * np.sign(-g["FRONT"]["normal"][1])
    y = unit(y - (y @ z) * z)
    x = np.cross(y, z)
    a_point, b_point, b_axis = (np.asarray(g["TOP"]["point"]), np.asarray(g["BORE"]["point"]),
                                unit(g["BORE"]["direction"]))
    bi = b_point + ((a_point - b_point) @ z) / (b_axis @ z) * b_axis  # CONST/POINT, F(BI), INTOF, FA(BORE), FA(TOP)
    origin = bi
    sphere_nominal = origin + 40 * x + 18 * y - 1 * z  # F(SPHERE) = FEAT/SPHERE, OUTER, CART, 40, 18, -1, 20

    def off_axis(p, q, d):
        r = np.atleast_2d(p - q)
        return np.linalg.norm(r - np.outer(r @ d, d), axis=1)

    boss_point, boss_axis = np.asarray(g["BOSS"]["point"]), unit(g["BOSS"]["direction"])
    # DISTB of two nominally parallel axes: the mean of each one's distance from the other where it was measured
    # the axis points nearest their nominal locations: F(BORE) at setup Z0, 40 below the top, F(BOSS) on the top
    bore_nominal, boss_nominal = origin - 40 * z, origin + 40 * x - 18 * y
    bore_at = b_point + ((bore_nominal - b_point) @ b_axis) * b_axis
    boss_at = boss_point + ((boss_nominal - boss_point) @ boss_axis) * boss_axis
    axes = 0.5 * (off_axis(bore_at, boss_at, boss_axis)[0] + off_axis(boss_at, bore_at, b_axis)[0])
    angle = math.degrees(math.acos(abs(unit(g["TOP"]["normal"]) @ unit(g["FRONT"]["normal"]))))
    sphere_centre = np.asarray(g["SPHERE"]["center"])
    return {
        "PERP_B": gdt("perpendicularity", "BORE", "TOP"), "PERP_C": gdt("perpendicularity", "FRONT", "TOP"),
        "ANG_C": gdt("angularity", "FRONT", "TOP", angle=90.0), "PAR_BOSS": gdt("parallelism", "BOSS", "BORE"),
        "RUN_TOP": gdt("circular runout", "TOP", "BORE", direction="axial"),
        "CON_SPH": 2.0 * off_axis(sphere_centre, b_point, b_axis)[0],
        "DIST_BOSS": axes - 43.863, "ANG_TF": angle - 90.0,
        "DIST_BI": float(np.linalg.norm(sphere_centre - bi)) - 43.875,
        # profiles: twice the largest distance of the hits from the nominal surface in the part frame
        "PROF_TOP": 2.0 * float(np.max(np.abs((pts["TOP"] - origin) @ z))),
        "PROF_SPH": 2.0 * float(np.max(np.abs(np.linalg.norm(pts["SPHERE"] - sphere_nominal, axis=1) - 10.0))),
        "PROFL_B": 2.0 * float(np.max(np.abs(off_axis(pts["BORE"], origin, z) - 15.0))),
    }


def test_a_session_without_what_the_replay_needs_says_what_its_document_leaves_out(run, tmp_path, capsys):
    """A DMIS session recorded before runs kept their program and hits (its event without ``replay``), and one
    re-evaluated without the DMIS replay: their documents leave the DMIS-only tolerances out and say so, in a
    NotedEvent and on the command line; the report's characteristics are all there."""
    from cmm.journal.store import load_session, open_store, write_session
    from cmm.session.qif import write_qif
    from cmm.session.qif_dmis import EVENT, left_out
    from cmm.session.reevaluate import reevaluate

    _d, sessions, name = run
    store = open_store(sessions)
    s = load_session(store, name)
    older = [{k: v for k, v in e.items() if k != "replay"} for e in s.events]
    write_session(store, "older", older)
    root = reevaluated(sessions, "older", "older-r", tmp_path / "older.qif", "--tip-radius", "1.01")
    err = capsys.readouterr().err
    assert not dmis_only(root)
    (noted,) = root.findall(".//q:NotedEvents/q:NotedEvent/q:Description", NS)
    sentence = noted.text
    assert sentence.startswith("The DMIS tolerances T(PERP_B), T(PROFL_B)") and "T(DIAM_B)" not in sentence
    assert all(f"T({label})" in sentence for label in LABELS)
    assert "recorded before DMIS runs kept their program and hits" in sentence
    assert sentence.endswith(".") and ". " not in sentence  # one sentence
    assert f"warning: {sentence}" in err
    assert {c["name"] for c in characteristics(root)} >= {"BORE diameter", "TOP flatness"}
    # the library's re-evaluation without the replay (a caller that does not run DMIS): left out, said
    bare = reevaluate(s, s.probe_settings(), name="bare")
    assert [e for e in bare.events if e.get("kind") == EVENT][0].get("reevaluated") is None
    why = left_out(bare)
    assert "re-evaluated without running the program again" in why and "T(CON_SPH)" in why
    doc = qif_support.validate(write_qif(bare, tmp_path / "bare.qif"))
    assert not dmis_only(doc) and doc.find(".//q:NotedEvent/q:Description", NS).text == why
    # a feature the criterion cannot refit stops the program where it is measured: all left out, said where and why
    root = reevaluated(sessions, name, "mcc", tmp_path / "mcc.qif", "--method", "mcc")
    (noted,) = root.findall(".//q:NotedEvents/q:NotedEvent/q:Description", NS)
    assert not dmis_only(root) and all(f"T({label})" in noted.text for label in LABELS)
    assert "running the program again on the refitted features stopped at line 25: F(TOP) could not be fitted: " \
           "TOP could not be refitted: method 'mcc' is not available for a plane" in noted.text
    # the run's own session has nothing left out
    assert left_out(s) == "" and write_qif(s, tmp_path / "run.qif").read_text().count("NotedEvent") == 0
    events = [e for e in s.events if e.get("kind") == EVENT]
    replay = json.loads(json.dumps(events[-1]["replay"]))  # plain JSON in the journal
    assert len(replay["hit_ids"]) == 26 and replay["text"].startswith("DMISMN") and replay["aligned"] == [True]


REPLAYED = """DMISMN/'replayed', 05.0
UNITS/MM, ANGDEC
DECL/CHAR, 10, ANS
F(A) = FEAT/PLANE, CART, 0, 0, 0, 0, 0, 1
MEAS/PLANE, F(A), 4
  PTMEAS/CART, 0, 0, 0, 0, 0, 1
  PTMEAS/CART, 50, 0, 0, 0, 0, 1
  PTMEAS/CART, 50, 50, 0, 0, 0, 1
  PTMEAS/CART, 0, 50, 0, 0, 0, 1
ENDMES
F(B) = FEAT/PLANE, CART, 0, 0, 10, 0, 0, 1
MEAS/PLANE, F(B), 4
  PTMEAS/CART, 0, 0, 10, 0, 0, 1
  PTMEAS/CART, 50, 0, 10, 0, 0, 1
  PTMEAS/CART, 50, 50, 10, 0, 0, 1
  PTMEAS/CART, 0, 50, 10, 0, 0, 1
ENDMES
DATDEF/FA(A), DAT(A)
T(PAR) = TOL/PARLEL, 0.020, DAT(A)
T(DIST) = TOL/DISTB, NOMINL, 10, -0.01, 0.01
TEXT/QUERY, (ANS), 10, ALPHA, L, 'Parallelism too?'
IF/(ANS .EQ. 'Y')
  OUTPUT/FA(B), TA(PAR)
ENDIF
OUTPUT/FA(A), FA(B), TA(DIST)
ENDFIL
"""


def test_the_replay_takes_the_runs_hits_and_answers_and_says_where_it_cannot_follow_the_run():
    """The program run again on given hits (no simulator): the operator's recorded answer takes the same branch,
    each MEAS takes the next hits and the refitted plane of them; the values are the direct computation. A run
    whose answer was not recorded, or that took more hits than the program does, is left out with why."""
    from types import SimpleNamespace

    from cmm.dmis.replay import reevaluate_event
    from cmm.journal.records import FeatureRecord
    from cmm.metrology.fit_ls import fit_plane

    a = np.array([[0, 0, 0.001], [50, 0, -0.002], [50, 50, 0.0], [0, 50, 0.001]], float)
    b = np.array([[0, 0, 10.004], [50, 0, 10.0], [50, 50, 9.998], [0, 50, 10.003]], float)
    hits = {i + 1: SimpleNamespace(point=tuple(p)) for i, p in enumerate(np.vstack([a, b]))}
    features = {1: FeatureRecord.of(fit_plane(a), id=1, name="A", hit_ids=[1, 2, 3, 4], kind="plane"),
                2: FeatureRecord.of(fit_plane(b), id=2, name="B", hit_ids=[5, 6, 7, 8], kind="plane")}
    run = ({"label": "PAR", "word": "PARLEL", "features": ["B"]},
           {"label": "DIST", "word": "DISTB", "features": ["A", "B"]})
    event = {"kind": "dmis_tolerances", "program": "replayed.dmi", "evaluations": [dict(r, value=0.0) for r in run],
             "replay": {"text": REPLAYED, "hit_ids": list(range(1, 9)), "answers": ["Y"], "aligned": []}}
    out = reevaluate_event(event, features, hits, {})
    assert out["reevaluated"] and out["left_out"] == []
    got = {r["label"]: r for r in out["evaluations"]}
    normal = np.asarray(features[1].fit["normal"])
    assert got["PAR"]["value"] == pytest.approx(float(np.ptp(b @ normal)), abs=1e-12)  # between two planes || A
    assert got["PAR"]["intol"] is True
    from cmm.metrology.construct import construct

    distance = construct("distance", ("plane", features[1].fit), ("plane", features[2].fit)).value
    assert got["DIST"]["value"] == pytest.approx(distance - 10.0, abs=1e-12)
    # no recorded answer: the program stops at the question, before any tolerance
    no_answer = reevaluate_event({**event, "replay": {**event["replay"], "answers": []}}, features, hits, {})
    assert no_answer["evaluations"] == [] and [g["label"] for g in no_answer["left_out"]] == ["PAR", "DIST"]
    assert {g["why"] for g in no_answer["left_out"]} == {
        "running the program again on the refitted features stopped at line 21: the run did not record the "
        "operator's answer"}
    # a run that took more hits than the program takes again did not follow it: nothing is trusted
    more = reevaluate_event({**event, "replay": {**event["replay"], "hit_ids": list(range(1, 10))}}, features,
                            {**hits, 9: hits[8]}, {})
    assert more["evaluations"] == [] and more["left_out"][0]["why"] == \
        "running the program again took 8 of the run's 9 hits, so it did not follow the run"
