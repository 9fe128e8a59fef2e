"""The expanded uncertainty of geometric tolerances (cmm.metrology.uncertainty_gdt): the budgets' sources moved
through the feature's and the datums' fits and the zone's evaluation."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from cmm.metrology.fit_ls import fit_cylinder, fit_plane, fit_sphere
from cmm.metrology.gdt_eval import MeasuredFeature, evaluate, evaluate_one
from cmm.metrology.uncertainty import Sources, budget
from cmm.metrology.uncertainty_gdt import gdt_uncertainty

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

SRC = Sources(reference=(0.0, 0.0, 0.0))


def _sphere():
    rng = np.random.default_rng(0)
    g = rng.normal(size=(9, 3))
    g[:, 2] = np.abs(g[:, 2])
    pts = 10 * g / np.linalg.norm(g, axis=1)[:, None] + [100, 50, 20] + rng.normal(0, 0.0005, (9, 3))
    return pts, fit_sphere(pts)


def test_a_position_far_from_its_nominal_has_twice_the_u_of_its_centre_along_the_deviation():
    """A sphere 10 um off its nominal along X, no datums: the position 2 |deviation| moves by twice the centre's
    x, so its U is twice the feature budget's U of x (the same sources, the same Student's t)."""
    pts, fit = _sphere()
    b = budget("sphere", pts, fit, SRC)
    centre = np.asarray(fit.center)
    nominal = {"kind": "sphere", "center": (centre - [0.01, 0, 0]).tolist(), "radius": 10.0}
    feats = {1: MeasuredFeature("S", "sphere", fit.summary(), nominal, pts, budget=b.summary())}
    (d, c), = evaluate([{"id": 1, "name": "pos", "characteristic": "position", "feature": 1, "tolerance": 0.05,
                         "datums": []}], {}, feats)
    assert c.actual == pytest.approx(0.02, abs=1e-9)
    assert c.uncertainty == pytest.approx(2 * b.expanded()["x"], rel=0.03)
    assert c.uncertainty_k == pytest.approx(b.coverage_factors()["x"], abs=0.01)
    # without a budget (another criterion's fit) it has none, and says why
    feats = {1: MeasuredFeature("S", "sphere", fit.summary(), nominal, pts)}
    (d, c), = evaluate([d], {}, feats)
    assert c.uncertainty is None and "has no uncertainty budget" in c.uncertainty_why


def test_perpendicularity_to_a_datum_plane_carries_the_machine_squareness_known_answer():
    """A 20 mm long axis exactly perpendicular to its datum plane: a uniform expansion, the tip radius and the
    axes' scales tilt neither; the xz and yz squareness errors tilt the axis by their angle and leave the plane
    (its hits at one Z): each moves the perpendicularity (20 mm x |tilt|) by 20 mm x u, in quadrature."""
    plane = np.array([[0, 0, 0], [80, 0, 0], [80, 60, 0], [0, 60, 0], [40, 30, 0]], float)
    ang = np.linspace(0, 2 * np.pi, 4, endpoint=False)
    cyl = np.vstack([np.c_[30 + 10 * np.cos(ang + o), 40 + 10 * np.sin(ang + o), np.full(4, z)]
                     for z, o in ((5.0, 0.0), (25.0, math.pi / 4))])
    fp, fc = fit_plane(plane), fit_cylinder(cyl)
    feats = {1: MeasuredFeature("A", "plane", fp.summary(), {"kind": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]},
                                plane, budget=budget("plane", plane, fp, SRC).summary()),
             2: MeasuredFeature("C", "cylinder", fc.summary(), None, cyl,
                                budget=budget("cylinder", cyl, fc, SRC).summary())}
    d = {"id": 1, "name": "perp", "characteristic": "perpendicularity", "feature": 2, "tolerance": 0.05,
         "datums": ["A"]}
    datums = {"A": {"label": "A", "feature": 1}}
    (_, c), = evaluate([d], datums, feats)
    assert c.actual == pytest.approx(0.0, abs=1e-7)
    u = gdt_uncertainty(d, datums, feats, c.actual, evaluate_one)
    t = u["terms"]
    assert t["machine squareness"] == pytest.approx(math.sqrt(2) * 20.0 * SRC.machine_squareness_u(), rel=0.02)
    assert t["thermal"] < 1e-7 and t["probe qualification"] < 1e-7 and t["machine scale"] < 1e-7
    assert "sampling C" in t and "sampling A" in t  # the axis's fitted geometry, and the datum's
    assert c.uncertainty == pytest.approx(u["U"]) and c.uncertainty > 0


def _box_face(n_x=4, n_y=3):
    """A 100 x 60 x 40 box (trimesh) centred at the origin at the identity pose, and points on its top face."""
    import trimesh

    g = np.stack(np.meshgrid(np.linspace(-40, 40, n_x), np.linspace(-22, 22, n_y)), -1).reshape(-1, 2)
    return trimesh.creation.box(extents=(100, 60, 40)), np.c_[g, np.full(len(g), 20.0)]


PROFILE = {"id": 1, "name": "prof", "characteristic": "profile of a surface", "feature": 1, "tolerance": 0.02,
           "datums": []}


def test_a_profile_is_propagated_through_its_best_fit_and_covers_a_simulated_error():
    """A profile of a surface (no datums: a best fit in all six DOF) of 12 hits on a box's top face, true value 0:
    each trial's hits scatter by the repeatability along the face's normal. Near zero the value is the largest of
    12 scatters, so U is twice its 95.45 % point (about 2 x 2.9 sigma), not the change of the largest hit: every
    trial is covered, and U is not more than about 3x the value's RMS."""
    mesh, exact = _box_face()
    rng = np.random.default_rng(3)
    values, us = [], []
    for _ in range(24):
        pts = exact + np.c_[np.zeros((len(exact), 2)), rng.normal(0, SRC.repeatability, len(exact))]
        fit = fit_plane(pts)
        f = MeasuredFeature("top", "plane", fit.summary(), None, pts, budget=budget("plane", pts, fit, SRC).summary())
        (_, c), = evaluate([PROFILE], {}, {1: f}, mesh, np.eye(4))
        assert c.uncertainty is not None, c.uncertainty_why
        values.append(c.actual)
        us.append(c.uncertainty)
    values, us = np.array(values), np.array(us)
    assert np.all(values <= us) and np.mean(us) / math.sqrt(np.mean(values ** 2)) < 3.0
    assert np.mean(us) == pytest.approx(2 * 2.87 * SRC.repeatability, rel=0.1)
    # without a budget anywhere the hits take the station's default sources, and say so
    u = gdt_uncertainty(PROFILE, {}, {1: MeasuredFeature("top", "plane", fit.summary(), None, exact)}, 0.0,
                        evaluate_one, mesh, np.eye(4))
    assert u["U"] > 0 and "default sources" in u["note"]


def test_a_flatness_near_zero_is_bounded_by_its_largest_hit_errors():
    """A flatness (the zone of the feature's own 20 hits) whose true value is 0: the value read is the range of 20
    scatters after the fit. The hit-by-hit change of its two extreme hits covered such a value 85 % of the time (a
    value read large by chance took the smaller linear U); twice the 95.45 % point of the largest of 20 scatters
    bounds it."""
    _, exact = _box_face(5, 4)
    rng = np.random.default_rng(3)
    d = {"id": 1, "name": "flat", "characteristic": "flatness", "feature": 1, "tolerance": 0.02, "datums": []}
    values, us = [], []
    for _ in range(16):
        pts = exact + np.c_[np.zeros((len(exact), 2)), rng.normal(0, SRC.repeatability, len(exact))]
        fit = fit_plane(pts)
        f = MeasuredFeature("top", "plane", fit.summary(), None, pts, budget=budget("plane", pts, fit, SRC).summary())
        (_, c), = evaluate([d], {}, {1: f})
        values.append(c.actual)
        us.append(c.uncertainty)
    values, us = np.array(values), np.array(us)
    assert np.all(values <= us) and np.mean(us) / math.sqrt(np.mean(values ** 2)) < 3.0
    assert np.mean(us) == pytest.approx(2 * 3.04 * SRC.repeatability, rel=0.05)


def test_values_without_an_honest_propagation_say_why():
    mesh, pts = _box_face(9, 7)
    fit = fit_plane(pts)
    feats = {1: MeasuredFeature("top", "plane", fit.summary(), None, pts,
                                budget=budget("plane", pts, fit, SRC).summary())}
    why = gdt_uncertainty(PROFILE, {}, feats, 0.0, evaluate_one, mesh, np.eye(4))["why"]
    assert "a profile of 63 points (more than 60) is not propagated" in why
    assert "needs its points, the CAD mesh" in gdt_uncertainty(PROFILE, {}, feats, 0.0, evaluate_one)["why"]
    sphere_pts, sphere = _sphere()
    feats = {1: MeasuredFeature("S", "sphere", sphere.summary(), {"kind": "sphere", "center": [100, 50, 20]},
                                sphere_pts)}
    assert "has no uncertainty budget" in gdt_uncertainty({"characteristic": "position", "feature": 1}, {}, feats,
                                                          0.0, evaluate_one)["why"]


def _fitted(name, kind, pts, nominal, src):
    fit = (fit_plane if kind == "plane" else fit_cylinder)(pts)
    return MeasuredFeature(name, kind, fit.summary(), nominal, pts, budget=budget(kind, pts, fit, src).summary())


def test_a_composite_positions_tiers_each_get_their_u_known_answers():
    """Two holes 40 sqrt(2) mm apart on datums A|B|C, each 4 um out from the pattern's centre: the lower tier
    (translations and the rotation free) is 2 x 4 um. Each hole's pattern-locating row has the U of the same
    hole's plain position to A|B|C (the same propagation: the other hole's hits do not move it); the pattern's
    row has its own, and in it the part's expansion about any point (the translation is free) opens the pattern
    by 2 x (20 sqrt(2) mm) x the expansion: its term is that times the thermal u, while the hits of B and C, which
    only locate the pattern, count nothing in it."""
    src = Sources(reference=(50.0, 50.0, 0.0))
    sq = np.array([(0, 0), (1, 0), (1, 1), (0, 1)])
    feats = {1: _fitted("A", "plane", np.c_[100 * sq, np.zeros(4)], {"kind": "plane", "point": [50, 50, 0],
                                                                      "normal": [0, 0, 1]}, src),
             2: _fitted("B", "plane", np.c_[100 * sq[:, 0], np.zeros(4), -2 - 6 * sq[:, 1]],
                        {"kind": "plane", "point": [50, 0, -5], "normal": [0, -1, 0]}, src),
             3: _fitted("C", "plane", np.c_[np.zeros(4), 100 * sq[:, 0], -2 - 6 * sq[:, 1]],
                        {"kind": "plane", "point": [0, 50, -5], "normal": [-1, 0, 0]}, src)}
    ang = np.linspace(0, 2 * np.pi, 4, endpoint=False)
    for k, s in enumerate(((1, 1), (-1, -1))):
        nom = np.array([50.0, 50.0]) + 20 * np.array(s)
        act = nom + 0.004 * np.array(s) / math.sqrt(2)
        pts = np.vstack([np.c_[act[0] + 5 * np.cos(ang + o), act[1] + 5 * np.sin(ang + o), np.full(4, z)]
                         for z, o in ((-2.0, 0.0), (-8.0, math.pi / 4))])
        feats[10 + k] = _fitted(f"hole {k + 1}", "cylinder", pts, {"kind": "cylinder", "point": [*nom, -5],
                                                                   "direction": [0, 0, 1], "radius": 5.0}, src)
    datums = {x: {"label": x, "feature": i} for i, x in enumerate("ABC", 1)}
    d = {"id": 7, "name": "holes", "characteristic": "position", "feature": 10, "pattern": [10, 11],
         "tolerance": 0.5, "datums": ["A", "B", "C"], "composite": {"tolerance": 0.02, "datums": ["A"]}}
    rows = evaluate([d], datums, feats)
    plain = evaluate([{"id": 8, "name": "p", "characteristic": "position", "feature": 10 + k, "tolerance": 0.5,
                       "datums": ["A", "B", "C"]} for k in range(2)], datums, feats)
    for (_, tier), (_, alone) in zip(rows[:2], plain):
        assert tier.uncertainty == pytest.approx(alone.uncertainty, rel=1e-6) and tier.uncertainty_k > 2.0
    low = rows[2][1]
    assert low.feature == "pattern of 2" and low.actual == pytest.approx(0.008, abs=1e-9)
    from cmm.metrology.gdt_eval import _row_values
    from cmm.metrology.uncertainty_gdt import row_uncertainties

    us = row_uncertainties(d, datums, feats, [c.actual for _, c in rows], _row_values)
    assert [u["U"] for u in us] == pytest.approx([c.uncertainty for _, c in rows])
    t = us[2]["terms"]
    assert t["thermal"] == pytest.approx(2 * 20 * math.sqrt(2) * src.thermal_u(), rel=1e-3)
    assert t["sampling B"] < 1e-9 and t["sampling C"] < 1e-9 and t["sampling hole 1"] > 0.1 * low.uncertainty
    assert 0 < low.uncertainty < rows[0][1].uncertainty  # the pattern's own form, not its location


def test_position_and_perpendicularity_are_covered_on_the_simulator():
    """The boss's position to A|B (true value 10 um) and perpendicularity to A on the simulator's error model, the
    features and their datums measured in one set-up (benchmarks/bench_uncertainty.py --gdt), 30 trials at a fixed
    seed: every error within U but at most a few, none beyond 2U, and U at most 3x the errors' RMS (their spread
    about the truth: the perpendicularity's, whose true value is 0, cannot go negative, and its std is small
    against any honest U)."""
    from bench_uncertainty import run_gdt

    res = run_gdt(30, seed=5, form=0.001, verbose=False)
    for name in ("position", "perpendicularity"):
        r = res[name]
        assert r["coverage"] >= 0.93 and r["worst"] < 2.0 and r["U_over_rms"] <= 3.0, (name, r)
