"""GD&T end to end on the simulator's sample part (virtual clock): datums A (top), B (front), C (left) and the
position of the bore, defined in the station, journalled, and read the same by the feature tree, the report,
the CSV and JSON exports, a replay and a re-evaluation from the raw counts."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from cmm.cli import main
from cmm.measurement.model import MeasurementError
from cmm.measurement.plan import plan_at_pick, run_plan
from cmm.metrology.relations import distance_point_plane
from cmm.session.export import session_json
from cmm.session.reevaluate import reevaluate
from cmm.session.replay import Replay
from cmm.session.report import features_csv, render
from cmm.journal.store import DirectoryStore, load_session
from cmm.sim.cmm_sim import TRUE_PART_POSE
from cmm.ui.panel_features import tree_html


@pytest.fixture
def station(stations):
    return stations.station("gdt")


def _measure(model, origin, direction, name, n=None):
    """Auto-measure the face a ray (part coordinates) hits."""
    T = model.part.pose
    o = (T @ np.r_[origin, 1.0])[:3]
    d = T[:3, :3] @ np.asarray(direction, float)
    hit, _ = model.pick(o, d / np.linalg.norm(d))
    return run_plan(model, plan_at_pick(model, hit.face_id, n=n), name=name)


def test_position_of_the_bore_to_datums_a_b_c(station, tmp_path, capsys):
    model = station.measurement
    model.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
    top = _measure(model, (10, 70, 100), (0, 0, -1), "top", n=3)
    front = _measure(model, (60, -50, 20), (0, 1, 0), "front", n=3)
    left = _measure(model, (-50, 60, 20), (1, 0, 0), "left", n=3)
    bore = _measure(model, (30, 40, 60), (0.5, 0, -0.866), "bore")
    assert bore.kind == "cylinder" and bore.nominal.params.get("bore")
    for label, f in (("A", top), ("B", front), ("C", left)):
        model.define_datum(label, f.id)
    d, c = model.define_gdt("position", bore.id, 0.05, "A|B|C", name="bore position")
    # independent: the bore axis at both ends of its hits, measured from the fitted B and C planes (nominal
    # 40 and 30 mm: B and C are square to A and to each other within a few urad, negligible over 40 mm)
    g = bore.result
    t = (np.array([model.hits[h].point for h in bore.hit_ids]) - g.point) @ g.direction
    ends = [g.point + t.min() * g.direction, g.point + t.max() * g.direction]
    expected = 2 * max(math.hypot(abs(distance_point_plane(e, front.result)) - 40.0,
                                  abs(distance_point_plane(e, left.result)) - 30.0) for e in ends)
    assert c.actual == pytest.approx(expected, abs=0.001)
    assert c.actual < 0.05 and c.ok and c.datums == "A|B|C"
    # at MMC the hole's departure from its smallest size is the bonus
    size_tol = 0.02
    d_mmc, c_mmc = model.define_gdt("position", bore.id, 0.05, ["A", "B", "C"], material="MMC")
    assert c_mmc.upper == pytest.approx(0.05 + max(0.0, 2 * g.radius - (30.0 - size_tol)), abs=1e-9)
    assert c_mmc.actual == pytest.approx(c.actual, abs=1e-12)
    # orientation and form on the same features
    _, perp = model.define_gdt("perpendicularity", bore.id, 0.02, "A")
    _, flat = model.define_gdt("flatness", top.id, 0.01)
    assert perp.ok and flat.actual == pytest.approx(top.result.form, abs=1e-6)
    _, prof = model.define_gdt("profile of a surface", top.id, 0.02, "")
    _, prof_ab = model.define_gdt("profile of a surface", left.id, 0.02, "A|B")
    assert prof.ok and prof.actual < 0.01 and prof_ab.ok and prof_ab.datums == "A|B"
    with pytest.raises(MeasurementError, match="top is datum A: a feature is not toleranced against itself"):
        model.define_gdt("profile of a surface", top.id, 0.02, "A|B|C")

    # refusals: a datum parallel to A; a characteristic that needs a datum
    model.define_datum("D", top.id)
    with pytest.raises(MeasurementError, match="datum D \\(plane\\) is parallel to datum A"):
        model.define_gdt("position", bore.id, 0.05, "A|D")
    with pytest.raises(MeasurementError, match="parallelism needs a datum"):
        model.define_gdt("parallelism", top.id, 0.05, "")
    with pytest.raises(MeasurementError, match="no fitted feature 99"):
        model.define_datum("E", 99)

    rows = model.gdt_characteristics()
    assert len(rows) == 6
    tree = tree_html(station.controller.commands)
    assert "Geometric tolerances" in tree and f"{c.actual:.4f}" in tree and "A|B|C" in tree

    # journalled: the report, the CSV, the JSON and a replay read the same numbers
    model.journal.close()
    session = load_session(DirectoryStore(tmp_path), "gdt")
    assert set(session.state.datums) == {"A", "B", "C", "D"} and len(session.state.gdt) == 6
    html = render(session, mesh=model.part.mesh)
    csv = features_csv(session, mesh=model.part.mesh)
    exported = session_json(session, mesh=model.part.mesh)
    for _, ch in rows:
        assert f"{ch.actual:.4f}" in html and f"{ch.actual:.6f}" in csv
    assert "Geometric tolerances" in html and "⊕ ⌀0.0500(M) | A|B|C" in html
    pos = next(x for x in exported["gdt"] if x["id"] == d["id"])
    assert pos["value"] == pytest.approx(c.actual, abs=1e-12) and pos["drf"] == "A|B|C" and pos["result"] == "pass"
    json.dumps(exported, allow_nan=False)
    assert Replay(session).at(-1).gdt == session.state.gdt

    # re-evaluation from the raw counts refits the features and reproduces the characteristics
    again = reevaluate(session)
    from cmm.session.gdt_session import session_gdt

    redo = {dd["id"]: cc for dd, cc in session_gdt(again, model.part.mesh)}
    for dd, cc in rows:
        assert redo[dd["id"]].actual == pytest.approx(cc.actual, abs=1e-6)
    # and from the command line, each tolerance recorded -> re-evaluated
    assert main(["sessions", "--store", str(tmp_path), "reevaluate", "gdt", "gdt-again"]) == 0
    out = capsys.readouterr().out
    assert f"bore: ⊕ position | A|B|C: {c.actual:.4f} -> {redo[d['id']].actual:.4f} (allowed 0.0500) pass" in out
