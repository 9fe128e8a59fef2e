"""Tolerance definitions evaluated on measured features (cmm.metrology.gdt_eval): the path the tree, the report
and the exports share."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cmm.metrology import gdt
from cmm.metrology.gdt_eval import MeasuredFeature, check_definition, evaluate, evaluate_one


def grid(f, n=6):
    return np.array([f(a, b) for a in np.linspace(0, 1, n) for b in np.linspace(0, 1, n)])


def block(eps=0.0):
    """A (bottom, z = 0), B (left, x = 0) and a front face y = 0 turned by eps about z."""
    bottom = grid(lambda a, b: (40 * a, 30 * b, 0.0))
    left = grid(lambda a, b: (0.0, 30 * a, 20 * b))
    front = grid(lambda a, b: (40 * a, 40 * a * math.tan(eps), 20 * b))
    return {
        1: MeasuredFeature("bottom", "plane", {"point": [20, 15, 0], "normal": [0, 0, 1]},
                           {"kind": "plane", "point": [20, 15, 0], "normal": [0, 0, -1]}, bottom),
        2: MeasuredFeature("left", "plane", {"point": [0, 15, 10], "normal": [1, 0, 0]},
                           {"kind": "plane", "point": [0, 15, 10], "normal": [-1, 0, 0]}, left),
        3: MeasuredFeature("front", "plane", {"point": [20, 0, 10], "normal": [-math.sin(eps), math.cos(eps), 0]},
                           {"kind": "plane", "point": [20, 0, 10], "normal": [0, -1, 0]}, front),
    }


DATUMS = {"A": {"label": "A", "feature": 1}, "B": {"label": "B", "feature": 2}}


def test_a_secondary_datum_orients_the_zone():
    eps = 0.001
    feats = block(eps)
    free = evaluate_one({"characteristic": "perpendicularity", "feature": 3, "tolerance": 0.02, "datums": ["A"]},
                        DATUMS, feats)
    to_b = evaluate_one({"characteristic": "perpendicularity", "feature": 3, "tolerance": 0.02,
                         "datums": ["A", "B"]}, DATUMS, feats)
    # against A alone the turned face is perfectly perpendicular; A|B also fixes its direction: 40 tan(eps)
    assert free.value == pytest.approx(0.0, abs=1e-9)
    assert to_b.value == pytest.approx(40 * math.tan(eps), rel=1e-9) and to_b.drf == "A|B" and not to_b.ok


def test_rows_for_the_report_and_what_cannot_be_evaluated():
    feats = block()
    defs = [{"id": 1, "name": "front flat", "characteristic": "flatness", "feature": 3, "tolerance": 0.01},
            {"id": 2, "characteristic": "parallelism", "feature": 3, "tolerance": 0.01, "datums": ["C"]},
            {"id": 3, "characteristic": "profile of a surface", "feature": 3, "tolerance": 0.01},
            {"id": 4, "characteristic": "position", "feature": 9, "tolerance": 0.01}]
    rows = evaluate(defs, DATUMS, feats)
    (d1, flat), (_, par), (_, prof), (_, pos) = rows
    assert flat.ok is True and flat.actual == pytest.approx(0.0, abs=1e-9) and flat.name == "⏥ flatness"
    assert flat.note == "front flat: minimum zone"
    assert par.ok is None and "datum C is not defined" in par.note and par.datums == "C"
    assert prof.ok is None and "profile tolerance needs the part mesh" in prof.note
    assert pos.ok is None and "feature 9 is not measured" in pos.note


@pytest.mark.parametrize("definition, message", [
    ({"characteristic": "wobble", "feature": 1, "tolerance": 0.1}, "unknown geometric tolerance 'wobble'"),
    ({"characteristic": "flatness", "feature": 1, "tolerance": 0.1, "datums": ["A"]}, "takes no datums"),
    ({"characteristic": "runout", "feature": 1, "tolerance": 0.1}, "unknown geometric tolerance"),
    ({"characteristic": "total runout", "feature": 1, "tolerance": 0.1}, "needs a datum"),
    ({"characteristic": "angularity", "feature": 1, "tolerance": 0.1, "datums": ["A"]}, "basic angle"),
    ({"characteristic": "flatness", "feature": 1, "tolerance": 0}, "positive number"),
    ({"characteristic": "parallelism", "feature": 1, "tolerance": 0.1, "datums": ["A"], "material": "MMC"},
     "only to position"),
])
def test_bad_definitions_are_explained(definition, message):
    with pytest.raises(gdt.GdtError, match=message):
        check_definition(definition)


def test_straightness_and_axis_angularity_known_answers():
    # a line bowed by 0.01 in the middle: the thinnest cylinder containing it has diameter 0.01
    pts = np.array([[x, 0.0, 0.01 * (1 - ((x - 25) / 25) ** 2)] for x in np.linspace(0, 50, 51)])
    assert gdt.form("straightness", pts, 0.02).value == pytest.approx(0.01, rel=1e-3)
    # an axis at 45.05 deg to datum A (a plane) over 20 mm, basic angle 45: 20 sin(0.05 deg)
    from cmm.metrology.datums import build_drf, datum_from_feature

    drf = build_drf([datum_from_feature("A", "plane", {"point": (0, 0, 0), "normal": (0, 0, 1)})])
    a = math.radians(45.05)  # from the plane: the axis makes 45.05 deg with A
    u = np.array([math.cos(a), 0.0, math.sin(a)])
    axis_pts = np.array([t * u + (0, 3 * s, 0) for t in (0.0, 20.0) for s in (-1, 1)])
    r = gdt.orientation("angularity", "cylinder", {"point": [0, 0, 0], "direction": u.tolist(), "radius": 3},
                        axis_pts, drf, 0.05, angle_deg=45.0)
    assert r.value == pytest.approx(20 * math.sin(math.radians(0.05)), rel=1e-9)


def test_datum_bore_at_mmb_shifts_the_frame():
    bottom = MeasuredFeature("bottom", "plane", {"point": [0, 0, 0], "normal": [0, 0, 1]},
                             {"kind": "plane", "point": [0, 0, 0], "normal": [0, 0, 1]},
                             grid(lambda a, b: (80 * a - 40, 80 * b - 40, 0.0)))
    # B: a bore of 20.04 (nominal 20 +- 0.02: MMB 19.98), so the frame may shift by up to 0.03 across it
    bore = MeasuredFeature("bore", "cylinder", {"point": [0, 0, 0], "direction": [0, 0, 1], "radius": 10.02},
                           {"kind": "cylinder", "point": [0, 0, 0], "direction": [0, 0, 1], "radius": 10.0,
                            "bore": True}, np.zeros((0, 3)), 0.02)
    hole = MeasuredFeature("hole", "circle", {"center": [30.05, 0, 5], "normal": [0, 0, 1], "radius": 3.0},
                           {"kind": "cylinder", "point": [30, 0, 0], "direction": [0, 0, 1], "radius": 3.0,
                            "bore": True})
    feats = {1: bottom, 2: bore, 3: hole}
    datums = {"A": {"label": "A", "feature": 1}, "B": {"label": "B", "feature": 2, "modifier": "MMB"}}
    ((_, mmb),) = evaluate([{"characteristic": "position", "feature": 3, "tolerance": 0.05, "datums": ["A", "B"]}],
                           datums, feats)
    assert mmb.actual == pytest.approx(2 * (0.05 - 0.03), abs=1e-9) and mmb.datums == "A|B(M)" and mmb.ok
    rfs = evaluate_one({"characteristic": "position", "feature": 3, "tolerance": 0.05, "datums": ["A", "B"]},
                       {**datums, "B": {"label": "B", "feature": 2}}, feats)
    assert rfs.value == pytest.approx(0.1, abs=1e-9) and not rfs.ok
