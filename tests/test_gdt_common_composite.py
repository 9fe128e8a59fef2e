"""Common datums (A-B: two coaxial bores as one axis, two faces as one plane) and composite position frames
(ASME Y14.5: pattern-locating and feature-relating tiers): known answers from constructed features, and the
bad definitions explained."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cmm.metrology import gdt
from cmm.metrology.datums import DatumError, build_drf, common_datum, datum_from_feature
from cmm.metrology.gdt_eval import MeasuredFeature, check_definition, evaluate, evaluate_one, tolerance_text


def bore(name, centre, direction=(0, 0, 1), radius=5.0, length=10.0, nominal_centre=None):
    """A cylinder feature (its location point the centre of its length) with points on its surface."""
    c = np.asarray(centre, float)
    u = np.asarray(direction, float) / np.linalg.norm(direction)
    f = np.linalg.qr(np.column_stack([u, [1, 0, 0], [0, 1, 0]]))[0]
    e1, e2 = f[:, 1], f[:, 2]
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    pts = np.array([c + radius * (math.cos(a) * e1 + math.sin(a) * e2) + z * u
                    for z in (-length / 2, length / 2) for a in t])
    nom_c = c if nominal_centre is None else np.asarray(nominal_centre, float)
    return MeasuredFeature(name, "cylinder", {"point": c.tolist(), "direction": u.tolist(), "radius": radius},
                           {"kind": "cylinder", "point": nom_c.tolist(), "direction": [0, 0, 1], "radius": radius,
                            "bore": True}, pts)


def test_common_axis_of_two_coaxial_bores_known_coaxiality():
    """Bores A (centre z 5) and B (centre z 55, 0.02 off in x): the common axis runs through both centres. A third
    bore at z 25..35 parallel to that line and 0.03 off it in y has coaxiality 0.06 to A-B; to A alone (the axis
    of A, along z) its ends 0.008 and 0.012 off in x count too."""
    a = bore("bore A", (0, 0, 5))
    b = bore("bore B", (0.02, 0, 55))
    mid = bore("middle", (0.01, 0.03, 30), direction=(0.02, 0, 50))
    feats = {1: a, 2: b, 3: mid}
    datums = {"A": {"label": "A", "feature": 1}, "B": {"label": "B", "feature": 2}}
    r = evaluate_one({"characteristic": "coaxiality", "feature": 3, "tolerance": 0.05, "datums": ["A-B"]},
                     datums, feats)
    assert r.value == pytest.approx(0.06, abs=1e-9) and r.drf == "A-B" and not r.ok
    alone = evaluate_one({"characteristic": "coaxiality", "feature": 3, "tolerance": 0.05, "datums": ["A"]},
                         datums, feats)
    assert alone.value == pytest.approx(2 * math.hypot(0.012, 0.03), abs=1e-9)
    # the frame of the common axis constrains what one axis does: two translations and two rotations
    drf = build_drf([common_datum(datum_from_feature("A", "cylinder", a.geometry),
                                  datum_from_feature("B", "cylinder", b.geometry))])
    assert set(drf.constrained) == {"Tx", "Ty", "Rx", "Ry"} and drf.labels == "A-B"
    assert np.allclose(drf.rotation[:, 2], np.array([0.02, 0, 50]) / math.hypot(0.02, 50))


def test_common_datum_plane_of_two_faces():
    top1 = datum_from_feature("A", "plane", {"point": [0, 0, 10.0], "normal": [0, 0, 1]})
    top2 = datum_from_feature("B", "plane", {"point": [50, 0, 10.02], "normal": [0, 0.0004, 1]})
    c = common_datum(top1, top2)
    assert c.kind == "plane" and c.label == "A-B"
    assert np.allclose(c.origin, [25, 0, 10.01]) and c.direction[2] > 0.99999
    assert c.direction[1] == pytest.approx(0.0002, rel=1e-3)


@pytest.mark.parametrize("first, second, message", [
    (("plane", {"point": [0, 0, 0], "normal": [0, 0, 1]}), ("cylinder", {"point": [0, 0, 20], "direction": [0, 0, 1], "radius": 5}),
     "A is a plane and B an axis; a common datum is two axes .* or two planes"),
    (("cylinder", {"point": [0, 0, 0], "direction": [0, 0, 1], "radius": 5}),
     ("cylinder", {"point": [0, 0, 0.5], "direction": [0, 0, 1], "radius": 5}),
     "the centres of A and B are 0.5 mm apart"),
    (("cylinder", {"point": [0, 0, 0], "direction": [0, 0, 1], "radius": 5}),
     ("cylinder", {"point": [10, 0, 50], "direction": [0, 0, 1], "radius": 5}),
     r"A and the line through the centres of A and B are 11.3 degrees apart .*not coaxial"),
    (("plane", {"point": [0, 0, 0], "normal": [0, 0, 1]}), ("plane", {"point": [50, 0, 0], "normal": [0, 1, 1]}),
     "planes A and B are 45.0 degrees apart"),
    (("sphere", {"center": [0, 0, 0], "radius": 3}), ("sphere", {"center": [0, 0, 30], "radius": 3}),
     "A is a point and B a point"),
])
def test_bad_common_datums_are_explained(first, second, message):
    a = datum_from_feature("A", first[0], first[1])
    b = datum_from_feature("B", second[0], second[1])
    with pytest.raises(DatumError, match=f"common datum A-B: {message}"):
        common_datum(a, b)


def test_a_common_datum_at_mmb_is_refused():
    a = datum_from_feature("A", "cylinder", {"point": [0, 0, 0], "direction": [0, 0, 1], "radius": 5},
                           modifier="MMB", boundary=10.0, internal=True)
    b = datum_from_feature("B", "cylinder", {"point": [0, 0, 50], "direction": [0, 0, 1], "radius": 5})
    with pytest.raises(DatumError, match="referenced regardless of size here"):
        common_datum(a, b)


# ---------------------------------------------------------------- composite position


def plate():
    """Datums A (top z = 0, normal +z), B (y = 0), C (x = 0) as planes with points."""
    g = np.linspace(0, 1, 4)
    top = np.array([(100 * a, 100 * b, 0.0) for a in g for b in g])
    side_b = np.array([(100 * a, 0.0, -10 * b) for a in g for b in g])
    side_c = np.array([(0.0, 100 * a, -10 * b) for a in g for b in g])
    return {
        1: MeasuredFeature("A", "plane", {"point": [50, 50, 0], "normal": [0, 0, 1]},
                           {"kind": "plane", "point": [50, 50, 0], "normal": [0, 0, 1]}, top),
        2: MeasuredFeature("B", "plane", {"point": [50, 0, -5], "normal": [0, 1, 0]},
                           {"kind": "plane", "point": [50, 0, -5], "normal": [0, 1, 0]}, side_b),
        3: MeasuredFeature("C", "plane", {"point": [0, 50, -5], "normal": [1, 0, 0]},
                           {"kind": "plane", "point": [0, 50, -5], "normal": [1, 0, 0]}, side_c),
    }


DATUMS = {"A": {"label": "A", "feature": 1}, "B": {"label": "B", "feature": 2}, "C": {"label": "C", "feature": 3}}
CENTRE = np.array([50.0, 50.0])
NOMINALS = [CENTRE + 20 * np.array(s) for s in ((1, 1), (-1, 1), (-1, -1), (1, -1))]


def pattern(shift=(0.1, 0.05), turn=0.0005, radial=0.004):
    """Four holes on a 40 x 40 square about (50, 50): the whole pattern moved by ``shift`` and turned by ``turn``
    (rad) about its centre, and each hole ``radial`` further out from the centre. Translation and rotation
    cannot take up the outward deviations (symmetric, across the rotation): the feature-relating value is
    2 x radial; the pattern-locating one per hole is twice its whole deviation, computed here directly."""
    feats = plate()
    c, s = math.cos(turn), math.sin(turn)
    expected = []
    for k, n in enumerate(NOMINALS):
        rel = n - CENTRE
        out = rel + radial * rel / np.linalg.norm(rel)
        actual = CENTRE + np.array([c * out[0] - s * out[1], s * out[0] + c * out[1]]) + shift
        feats[10 + k] = bore(f"hole {k + 1}", (actual[0], actual[1], -5.0), nominal_centre=(n[0], n[1], -5.0))
        expected.append(2 * float(np.linalg.norm(actual - n)))
    return feats, expected


def composite(lower_datums=("A",), lower=0.02, upper=0.5, **kw):
    return {"id": 7, "name": "holes", "characteristic": "position", "feature": 10, "pattern": [10, 11, 12, 13],
            "tolerance": upper, "datums": ["A", "B", "C"],
            "composite": {"tolerance": lower, "datums": list(lower_datums)}, **kw}


def test_composite_position_known_answers_per_tier():
    feats, expected = pattern()
    rows = evaluate([composite()], DATUMS, feats)
    assert len(rows) == 5
    for (_, c), want, k in zip(rows[:4], expected, range(4)):
        assert c.feature == f"hole {k + 1}" and c.actual == pytest.approx(want, abs=1e-9)
        assert c.datums == "A|B|C" and c.upper == 0.5 and c.ok and "pattern-locating tier" in c.note
    _, low = rows[4]
    assert low.feature == "pattern of 4" and low.datums == "A" and low.upper == 0.02
    assert low.actual == pytest.approx(2 * 0.004, abs=1e-7) and low.ok
    assert "feature-relating tier (FRTZF) of hole 1, hole 2, hole 3, hole 4" in low.note
    assert "rotation about the pattern axis free" in low.note
    assert tolerance_text(composite()) == "⊕ ⌀0.5000 | A|B|C / ⌀0.0200 | A"


def test_composite_lower_tier_with_a_secondary_keeps_the_pattern_clocked():
    """Lower tier A|B: the pattern may not turn, so its 0.0005 rad turn counts; translations still float. The
    turn about the centre moves each hole 20 sqrt(2) x 0.0005 across the line to it; with the outward 0.004
    the four deviations (after the best translation, zero by symmetry) have length hypot(0.004, 0.01414)."""
    feats, _ = pattern()
    (*_, (_, low)) = evaluate([composite(lower_datums=("A", "B"))], DATUMS, feats)
    r = 20 * math.sqrt(2)
    out = r + 0.004
    want = 2 * math.hypot(out * math.cos(0.0005) - r, out * math.sin(0.0005))
    assert low.actual == pytest.approx(want, abs=1e-9) and low.datums == "A|B" and not low.ok
    assert "translations free, orientation by the datums" in low.note


def test_composite_pattern_shift_fails_the_upper_tier_only():
    feats, expected = pattern(shift=(0.3, 0.0), turn=0.0, radial=0.0)
    rows = evaluate([composite(upper=0.5)], DATUMS, feats)
    assert all(c.actual == pytest.approx(0.6, abs=1e-9) and not c.ok for _, c in rows[:4])
    assert rows[4][1].actual == pytest.approx(0.0, abs=1e-9) and rows[4][1].ok  # the holes are right to each other


@pytest.mark.parametrize("change, message", [
    ({"composite": {"tolerance": 0.6, "datums": ["A"]}}, "lower. tolerance 0.6 must be smaller than the pattern-locating"),
    ({"composite": {"tolerance": 0.02, "datums": []}}, "needs the datum that orients the pattern"),
    ({"composite": {"tolerance": 0.02, "datums": ["B"]}}, "must repeat the upper tier's A|B|C from the primary on"),
    ({"composite": {"tolerance": 0.02, "datums": ["A", "B", "C"]}}, "at most two: they orient the pattern"),
    ({"pattern": [10]}, "applies to a pattern: give two or more features"),
    ({"material": "MMC"}, "regardless of feature size here"),
    ({"characteristic": "flatness", "datums": []}, "a composite frame .* is a position tolerance"),
    ({"composite": "0.02"}, "needs its feature-relating .lower. tier"),
])
def test_bad_composite_frames_are_explained(change, message):
    with pytest.raises(gdt.GdtError, match=message):
        check_definition({**composite(), **change})


def test_a_pattern_of_holes_that_are_not_parallel_is_refused_in_words():
    feats, _ = pattern()
    f = feats[11]
    feats[11] = MeasuredFeature(f.name, f.kind, f.geometry, {**f.nominal, "direction": [0, 0.1, 1]}, f.points)
    (_, row), *_ = evaluate([composite()], DATUMS, feats)
    assert row.ok is None and "the features of the pattern are not parallel" in row.note


def test_common_datum_in_a_composite_frame_and_the_datum_checks():
    """A pattern datum cannot be one of its own features; a common datum A-B is accepted as a reference."""
    feats, _ = pattern()
    datums = {**DATUMS, "D": {"label": "D", "feature": 10}}
    (_, row), *_ = evaluate([{**composite(), "datums": ["A", "D"], "composite": {"tolerance": 0.02, "datums": ["A"]}}],
                            datums, feats)
    assert row.ok is None and "hole 1 is datum D" in row.note
    with pytest.raises(gdt.GdtError, match="not a datum reference: use a letter .A. or a common datum of two"):
        check_definition({"characteristic": "coaxiality", "feature": 3, "tolerance": 0.1, "datums": ["A-B-C"]})
