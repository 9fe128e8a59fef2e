"""Auto-measure of the sample part's conical boss on the simulator (virtual clock), end to end: the plan
determines the cone, the fit reports the cone near the CAD nominal, and the feature tree and the report show
the same numbers from the same result."""

from __future__ import annotations

import math
import time
from html import escape as e

import numpy as np
import pytest

from cmm.machine.probing import Hit
from cmm.measurement.plan import plan_at_pick, run_plan
from cmm.metrology.characteristics import characteristics
from cmm.metrology.fit_ls import fit_cone
from cmm.metrology.pick import NominalFeature
from cmm.session.export import session_json
from cmm.session.report import features_csv, render
from cmm.sim.cmm_sim import TRUE_PART_POSE
from cmm.journal.store import DirectoryStore, load_session
from cmm.ui.panel_features import feature_chars, tree_html

HALF_ANGLE = math.degrees(math.atan(0.5))  # the sample part's cone: radius 12 at z 40, 6 at z 52
# eight tip centres from the simulator's cone (two rings of four at the same angles) with 0.5 um of noise: a
# cone across the axis (half angle 1.94 deg) fits them better than the probed one, the nominal
CHECK_TIPS = np.array([[284.3420629, 184.3399339, 49.2523202], [283.8040525, 196.1937322, 49.6301808],
                       [296.192652, 196.1924735, 49.6296481], [295.6533673, 184.3436884, 49.2480207],
                       [282.2168375, 182.2178906, 43.251377], [281.6796339, 198.3177279, 43.6318418],
                       [298.3162058, 198.3165213, 43.6299357], [297.7786832, 182.2196674, 43.2501758]])
CHECK_NOMINAL = {"kind": "cone", "apex": [290.0, 190.0, 64.0], "direction": [0.0, 0.0, -1.0],
                 "half_angle": math.atan(0.5)}


@pytest.fixture
def station(stations):
    return stations.station("cone")


def _cone_face(model) -> int:
    pose = model.part.pose
    origin = (pose @ np.array([109.0, 40.0, 100.0, 1.0]))[:3]  # above the cone's flank (radius 9 at z 46)
    hit, nominal = model.pick(origin, [0.0, 0.0, -1.0])
    assert nominal is not None and nominal.kind == "cone"
    return hit.face_id


def test_the_conical_boss_is_measured_as_the_cone_near_its_nominal(station, tmp_path):
    model = station.measurement
    model.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
    face = _cone_face(model)
    plan = plan_at_pick(model, face, n=4)
    assert plan.kind == "cone" and len(plan) == 8 and plan.notes == ()
    z = np.sort(plan.points[:, 2])
    assert z[4:].mean() - z[:4].mean() > 0.5 * 12.0  # the rings are more than half the cone's height apart
    axis = plan.nominal.params["apex"]
    angles = np.degrees(np.arctan2(plan.points[:, 1] - axis[1], plan.points[:, 0] - axis[0]))
    lower, upper = np.sort(angles[:4] % 360), np.sort(angles[4:] % 360)
    assert np.allclose(np.abs(((upper - lower) + 180) % 360 - 180), 45.0, atol=1.0)  # staggered by half a step

    feature = run_plan(model, plan, name="cone")
    r = feature.result
    assert r.half_angle_deg == pytest.approx(HALF_ANGLE, abs=0.02) and not r.check and not r.warnings
    chars = {c.name: c for c in feature_chars(feature)}
    assert chars["half angle"].ok and chars["position ⌀"].actual < 0.05 and chars["position ⌀"].ok
    # the location point is the foot of the hits' centroid on the axis
    centroid = np.mean([model.hits[i].point for i in feature.hit_ids], axis=0)
    assert abs((centroid - r.point) @ r.direction) < 0.05 and np.linalg.norm(np.cross(centroid - r.point,
                                                                                      r.direction)) < 10.0

    # fewer hits than the cone needs (2 rings of 3 = 6 hits for 6 parameters: the fit can pass exactly through
    # them on a cone of 14.9 deg): the plan takes 4 per ring and says so; measured, it is the nominal cone
    few = plan_at_pick(model, face, n=3)
    assert len(few) == 8 and few.per_ring == 4 and len(few.notes) == 1
    assert few.notes[0].startswith("3 hits per ring were asked for; a cone has 6 parameters and needs 4 per ring")
    assert few.notes[0].endswith("planned 4 per ring")
    z = np.sort(few.points[:, 2])
    assert z[4:].min() - z[:4].max() > 2.0  # the rings well apart in height
    again = run_plan(model, few, name="cone again")
    assert again.result.half_angle_deg == pytest.approx(HALF_ANGLE, abs=0.02) and not again.result.check

    # the feature tree and the report read the same numbers
    model.journal.close()
    session = load_session(DirectoryStore(tmp_path), "cone")
    rec = next(f for f in session.state.features.values() if f.name == "cone")
    from_report = rec.characteristics({**(rec.tolerance or {}), "size": 0.02, "form": 0.02,
                                                "location": 0.02})
    assert from_report == feature_chars(feature)
    tree = tree_html(station.controller.commands)
    html = render(session)
    csv = features_csv(session)
    for c in from_report:
        assert f"{c.actual:.4f}" in tree and f"{c.actual:.4f}" in html and f"{c.actual:.6f}" in csv


def test_a_better_cone_far_from_the_nominal_is_shown_as_check_not_reported():
    """Eight tip centres from the simulator's cone (two rings of four at the same angles: the old plan) with
    0.5 um of noise: a cone across the axis (half angle 1.94 deg) fits them better than the probed one.
    With the CAD nominal the probed cone is reported and the other is the alternative to check."""
    tips, nominal = CHECK_TIPS, CHECK_NOMINAL
    alone = fit_cone(tips)
    assert alone.half_angle_deg < 5.0  # without a nominal the best fit wins: not the probed cone
    r = fit_cone(tips, nominal)
    assert r.half_angle_deg == pytest.approx(HALF_ANGLE, abs=0.02) and r.check
    assert r.alternative.half_angle_deg == pytest.approx(alone.half_angle_deg, abs=1e-6)
    assert r.warnings[0].startswith("check: a different cone fits the hits better (half angle 1.9")
    chars = characteristics("cone", "cone", r.summary(), nominal)
    assert {c.verdict for c in chars} == {"check"}
    angle = next(c for c in chars if c.name == "half angle")
    assert angle.actual == pytest.approx(HALF_ANGLE, abs=0.02) and "half angle 1.9" in angle.check


def test_bore_to_boss_distance_is_axis_to_axis_in_the_alignment_plane(station):
    """The sample part's bore (30, 40) and boss (70, 22): nominal distance hypot(40, 18) = 43.8634, measured by
    auto-measure on the simulator and constructed in the alignment's XY plane (and in 3-D on request)."""
    model = station.measurement
    model.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
    pose = model.part.pose
    ids = []
    for start, direction in (((30.0, 40.0, 20.0), (-1.0, 0.0, 0.0)), ((90.0, 22.0, 47.0), (-1.0, 0.0, 0.0))):
        hit, _ = model.pick((pose @ np.array([*start, 1.0]))[:3], pose[:3, :3] @ np.array(direction))
        feature = run_plan(model, plan_at_pick(model, hit.face_id), name="bore" if not ids else "boss")
        assert feature.kind == "cylinder" and not feature.result.check
        ids.append(feature.id)
    planar = model.construct_feature("distance", ids[0], ids[1], "bore-boss")
    assert planar.nominal.value == pytest.approx(math.hypot(40.0, 18.0), abs=1e-9)
    assert planar.result.value == pytest.approx(planar.nominal.value, abs=0.01)
    assert "XY plane" in planar.result.projection
    spatial = model.construct_feature("distance", ids[0], ids[1], "bore-boss 3-D", three_d=True)
    assert "3-D" in spatial.result.projection and spatial.result.value == pytest.approx(planar.result.value, abs=0.01)


def test_check_reaches_the_tree_and_the_report_for_the_feature_and_its_gdt(station, tmp_path):
    """The cone of CHECK_TIPS recorded and fitted with its nominal: its characteristics, a geometric tolerance on
    it and one with it as the datum are "check" in the feature tree, the HTML report, the CSV and the JSON."""
    model = station.measurement
    model.set_alignment(TRUE_PART_POSE, "manual", note="the simulator's true set-up")
    tip = station.prober.settings.tip_radius
    axis, apex = np.array([0.0, 0.0, -1.0]), np.array(CHECK_NOMINAL["apex"])
    ids = []
    for t in CHECK_TIPS:
        radial = t - apex - ((t - apex) @ axis) * axis
        n = math.cos(math.atan(0.5)) * radial / np.linalg.norm(radial) - math.sin(math.atan(0.5)) * axis
        ids.append(model.add_hit(Hit(counts=(0, 0, 0), machine=tuple(t), approach=tuple(-n), speed=5.0,
                                     time=time.time(), point=tuple(t - tip * n))))
    nominal = NominalFeature("cone", {k: v for k, v in CHECK_NOMINAL.items() if k != "kind"})
    cone = model.fit_feature("cone", ids, "ls", "cone", nominal=nominal)
    assert cone.result.check
    top = []  # the part's top face (z 40), a plane toleranced against the cone's axis
    for x, y in ((10.0, 10.0), (110.0, 10.0), (60.0, 70.0), (20.0, 60.0)):
        p = (model.part.pose @ np.array([x, y, 40.0, 1.0]))[:3]
        top.append(model.add_hit(Hit(counts=(0, 0, 0), machine=tuple(p + [0, 0, tip]), approach=(0.0, 0.0, -1.0),
                                     speed=5.0, time=time.time(), point=tuple(p))))
    plane = model.fit_feature("plane", top, "ls", "top")
    assert not plane.result.check
    model.define_datum("A", cone.id)
    model.define_gdt("cylindricity", cone.id, 0.05, name="cone form")
    model.define_gdt("perpendicularity", plane.id, 0.05, "A", name="top to the cone")
    model.define_gdt("flatness", plane.id, 0.05, name="top flat")
    rows = {d["name"]: c for d, c in model.gdt_characteristics()}
    assert rows["cone form"].verdict == rows["top to the cone"].verdict == "check"
    assert "cone" in rows["top to the cone"].check and rows["top flat"].verdict != "check"
    feature_rows = feature_chars(cone)
    assert {c.verdict for c in feature_rows} == {"check"}

    tree = tree_html(station.controller.commands)
    model.journal.close()
    session = load_session(DirectoryStore(tmp_path), "cone")
    html = render(session)
    csv_rows = [r.split(",") for r in features_csv(session).splitlines()[1:]]
    exported = session_json(session)["gdt"]
    assert "CHECK (" in html
    for c in [*feature_rows, *rows.values()]:
        assert f"{c.actual:.4f}" in tree and f"{c.actual:.4f}" in html
        kind = "gdt" if c in rows.values() else "cone"
        row = next(r for r in csv_rows if r[0] == c.feature and r[1] == kind and r[4] == c.name)
        assert row[12] == c.verdict and row[9] == f"{c.actual:.6f}"
    assert html.count("<td class='chk'>check</td>") == len(feature_rows) + 2
    assert html.count("check: another fit of cone fits the hits better") == 2
    # the tree: the check word on each such row, with the reason
    assert tree.count(">check</td>") == len(feature_rows) + 2
    assert e(rows["top to the cone"].check) in tree
    assert [x["result"] for x in exported] == ["check", "check", "pass"]
    assert exported[1]["check"] == rows["top to the cone"].check
