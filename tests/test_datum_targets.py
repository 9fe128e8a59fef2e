"""Datum targets (ISO 5459 / ASME Y14.5): datum planes established by target points (3 on the primary, 2 on the
secondary, 1 on the tertiary) instead of the whole surface; known frames and the bad definitions explained."""

from __future__ import annotations

import numpy as np
import pytest

from cmm.metrology.datums import DatumError, build_drf, datum_from_feature, datum_from_targets
from cmm.metrology.gdt_eval import MeasuredFeature, check_datum, datum_of, evaluate_one, target_points

A_TARGETS = np.array([[5.0, 5.0, 0.0], [95.0, 5.0, 0.0], [50.0, 75.0, 0.0]])
B_TARGETS = np.array([[10.0, 0.0, -5.0], [90.0, 0.08, -5.0]])  # the front face turned by 1 mrad
C_TARGET = np.array([[0.0, 40.0, -5.0]])


def expected_frame():
    """Z = +z (A's targets lie at z 0); X = B's outward normal square to Z through both targets; the origin where
    A, B and the plane through C's target square to both meet: computed here from the targets alone."""
    z = np.array([0.0, 0, 1])
    s = B_TARGETS[1] - B_TARGETS[0]
    x = np.cross(s, z)
    x = x / np.linalg.norm(x)
    if x[1] > 0:
        x = -x  # B's outward normal is -y
    y = np.cross(z, x)
    origin = np.linalg.solve(np.array([z, x, y]), [0.0, x @ B_TARGETS[0], y @ C_TARGET[0]])
    return x, y, z, origin


def test_targets_make_the_frame_exactly_through_them():
    a = datum_from_targets("A", A_TARGETS, [0, 0, 1])
    b = datum_from_targets("B", B_TARGETS, [0, -1, 0])
    c = datum_from_targets("C", C_TARGET, [-1, 0, 0])
    drf = build_drf([a, b, c])
    x, y, z, origin = expected_frame()
    assert np.allclose(drf.rotation, np.column_stack([x, y, z]), atol=1e-12)
    assert np.allclose(drf.origin, origin, atol=1e-12)
    assert set(drf.constrained) == {"Tx", "Ty", "Tz", "Rx", "Ry", "Rz"}
    # every target lies on its simulated datum plane
    local = drf.to_local(np.vstack([A_TARGETS, B_TARGETS, C_TARGET]))
    assert np.allclose(local[:3, 2], 0.0, atol=1e-12) and np.allclose(local[3:5, 0], 0.0, atol=1e-12)
    assert local[5, 1] == pytest.approx(0.0, abs=1e-12)


def plate_features(bump=0.05):
    """A (top, z 0, with a 0.05 bump between its targets), B (front), C (left) as measured planes whose hits include
    the targets (hit ids 101.., 201.., 301..), and a bore at (30, 40) whose nominal is there in the part frame."""
    g = np.linspace(10, 90, 5)
    others = np.array([(x, y, bump) for x in g[1:-1] for y in (30.0, 50.0)])
    top = np.vstack([A_TARGETS, others])
    front = np.vstack([B_TARGETS, [[50.0, 0.04, -2.0], [30.0, 0.02, -8.0]]])
    left = np.vstack([C_TARGET, [[0.0, 10.0, -2.0], [0.0, 70.0, -8.0]]])

    def plane(name, pts, normal, nominal_point, first):
        return MeasuredFeature(name, "plane", {"point": pts.mean(axis=0).tolist(), "normal": normal},
                               {"kind": "plane", "point": nominal_point, "normal": normal}, pts,
                               hit_ids=tuple(range(first, first + len(pts))))

    bore = MeasuredFeature("bore", "circle", {"center": [30.0, 40.0, -5.0], "normal": [0, 0, 1], "radius": 5.0},
                           {"kind": "cylinder", "point": [30.0, 40.0, 0.0], "direction": [0, 0, 1], "radius": 5.0,
                            "bore": True}, np.zeros((0, 3)))
    return {1: plane("top", top, [0, 0, 1], [50, 40, 0], 101), 2: plane("front", front, [0, -1, 0], [50, 0, -5], 201),
            3: plane("left", left, [-1, 0, 0], [0, 40, -5], 301), 4: bore}


def test_position_to_a_frame_of_datum_targets():
    """The bore's centre is at (30, 40) of the part frame; in the target frame (B turned by 1 mrad through its
    targets) it is off its nominal by what the turn and the targets' offsets make: computed from the targets."""
    feats = plate_features()
    datums = {"A": {"label": "A", "feature": 1, "targets": [101, 102, 103]},
              "B": {"label": "B", "feature": 2, "targets": [201, 202]},
              "C": {"label": "C", "feature": 3, "targets": [301]}}
    r = evaluate_one({"characteristic": "position", "feature": 4, "tolerance": 0.05, "datums": ["A", "B", "C"]},
                     datums, feats)
    x, y, z, origin = expected_frame()
    local = (np.array([30.0, 40.0, -5.0]) - origin) @ np.column_stack([x, y, z])
    # the nominal frame: the datum features' nominal planes, through the part's zero; the bore's nominal in it
    nominal = build_drf([datum_from_feature("A", "plane", {"point": [0, 0, 0], "normal": [0, 0, 1]}),
                         datum_from_feature("B", "plane", {"point": [0, 0, 0], "normal": [0, -1, 0]}),
                         datum_from_feature("C", "plane", {"point": [0, 0, 0], "normal": [-1, 0, 0]})])
    nom = nominal.to_local(np.array([30.0, 40.0, 0.0]))
    assert r.value == pytest.approx(2 * float(np.hypot(*(local - nom)[:2])), abs=1e-9) and r.drf == "A|B|C"
    # the whole surface as datum A (least squares, lifted by the bump) moves nothing across Z here, but the
    # frame's origin height differs: the targets' plane is at z 0, the fitted one's at its points' mean height
    assert build_drf([datum_from_targets("A", A_TARGETS, [0, 0, 1])]).origin[2] == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("points, normal, message", [
    (A_TARGETS[:1].repeat(4, axis=0), [0, 0, 1], "datum targets are 1, 2 or 3 points .A1 A2 A3., got 4"),
    ([[0, 0, 0], [50, 0, 0], [100, 0, 0]], [0, 0, 1], "target points A1, A2, A3 lie in a line"),
    ([[0, 0, 0], [0.2, 0, 0]], [0, 0, 1], "target points A1 and A2 are 0.2 mm apart"),
])
def test_bad_targets_are_explained(points, normal, message):
    with pytest.raises(DatumError, match=f"datum A: {message}"):
        datum_from_targets("A", points, normal)


def test_targets_must_suit_the_datums_place_in_the_frame():
    two = datum_from_targets("A", B_TARGETS, [0, -1, 0])
    with pytest.raises(DatumError, match="datum A has 2 target point.s.: as the primary datum a plane needs 3"):
        build_drf([two])
    a = datum_from_targets("A", A_TARGETS, [0, 0, 1])
    with pytest.raises(DatumError, match="datum B has 3 target point.s.: as the secondary datum a plane needs 2"):
        build_drf([a, datum_from_targets("B", [[0, 0, -1], [50, 0, -1], [0, 0, -9]], [0, -1, 0])])


def test_target_definitions_in_a_session_are_checked():
    feats = plate_features()
    position = {"characteristic": "position", "feature": 4, "tolerance": 0.05, "datums": ["A"]}
    with pytest.raises(DatumError, match="datum A: hit 999 is not a hit of top; its targets are hits of the datum "
                                         "feature"):
        evaluate_one(position, {"A": {"label": "A", "feature": 1, "targets": [101, 102, 999]}}, feats)
    with pytest.raises(DatumError, match="datum targets here are points on a plane feature; bore is a circle"):
        evaluate_one({**position, "feature": 1}, {"A": {"label": "A", "feature": 4, "targets": [1, 2, 3]}}, feats)
    with pytest.raises(DatumError, match="from target points is a plane: it cannot be referenced at MMB"):
        check_datum({"label": "A", "feature": 1, "targets": [101, 102, 103], "modifier": "MMB"})
    with pytest.raises(DatumError, match="the targets are hit numbers"):
        check_datum({"label": "A", "feature": 1, "targets": ["one"]})


# target areas and lines: the hits taken in each (hit ids 11.., 21.., 31..)
AREA_1 = [(3.0, 5.0, 0.0), (5.0, 5.0, 0.02), (7.0, 5.0, 0.01)]  # the pad meets the 0.02 high spot
AREA_2 = [(93.0, 5.0, 0.0), (95.0, 5.0, 0.005)]
POINT_3 = (50.0, 75.0, 0.0)
LINE_B = [(10.0, 0.0, -5.0), (50.0, -0.03, -5.0), (90.0, 0.0, -5.0)]  # runs along X; its middle stands out 0.03


def test_target_areas_and_lines_touch_where_the_simulator_would():
    """A from two target areas and a point, B from one target line, C from a point: each area contacts at its
    hit furthest out of the material, the line along the direction its hits run through its furthest-out hit."""
    top = np.array(AREA_1 + AREA_2 + [POINT_3])
    front = np.array(LINE_B)
    left = np.array([C_TARGET[0]])
    feats = {1: MeasuredFeature("top", "plane", {"point": top.mean(axis=0).tolist(), "normal": [0, 0, 1]},
                                {"kind": "plane", "point": [50, 40, 0], "normal": [0, 0, 1]}, top,
                                hit_ids=(11, 12, 13, 14, 15, 16)),
             2: MeasuredFeature("front", "plane", {"point": front.mean(axis=0).tolist(), "normal": [0, 1, 0]},
                                {"kind": "plane", "point": [50, 0, -5], "normal": [0, -1, 0]}, front,
                                hit_ids=(21, 22, 23)),
             3: MeasuredFeature("left", "plane", {"point": left[0].tolist(), "normal": [-1, 0, 0]},
                                {"kind": "plane", "point": [0, 40, -5], "normal": [-1, 0, 0]}, left, hit_ids=(31,))}
    defs = {"A": check_datum({"label": "A", "feature": 1, "targets": [{"area": [11, 12, 13]}, {"area": [14, 15]}, 16]}),
            "B": check_datum({"label": "B", "feature": 2, "targets": [{"line": [21, 22, 23]}]}),
            "C": check_datum({"label": "C", "feature": 3, "targets": [31]})}
    drf = build_drf([datum_of(x, defs, feats, False) for x in "ABC"])
    # expected, from the contact points alone: A through (5, 5, 0.02), (95, 5, 0.005), (50, 75, 0); B through the
    # line X at Y -0.03, Z -5, square to A; C through C's target square to both
    a1, a2, a3 = np.array([5.0, 5.0, 0.02]), np.array([95.0, 5.0, 0.005]), np.array(POINT_3)
    z = np.cross(a2 - a1, a3 - a1)
    z /= np.linalg.norm(z)
    x = np.cross([1.0, 0.0, 0.0], z)
    x = -x / np.linalg.norm(x) if x[1] > 0 else x / np.linalg.norm(x)  # B's outward normal is -y
    y = np.cross(z, x)
    origin = np.linalg.solve(np.array([z, x, y]), [z @ a1, x @ np.array([50.0, -0.03, -5.0]), y @ C_TARGET[0]])
    assert np.allclose(drf.rotation, np.column_stack([x, y, z]), atol=1e-12)
    assert np.allclose(drf.origin, origin, atol=1e-9)
    # the whole face instead of the areas: the plane lies lower by the pads' high spots
    assert datum_from_feature("A", "plane", feats[1].geometry).origin[2] < origin[2]


@pytest.mark.parametrize("target, message", [
    ({"area": [11]}, "a target area needs 2 or more different hits taken in it, got 1"),
    ({"line": [21, 21]}, "a target line needs 2 or more different hits taken in it, got 1"),
    ({"circle": [11, 12]}, "a target is a hit number, {'area': \\[hits\\]} or {'line': \\[hits\\]}"),
    ("one", "the targets are hit numbers \\(or target areas and lines of hits\\)"),
])
def test_bad_target_areas_and_lines_are_explained(target, message):
    with pytest.raises(DatumError, match=f"datum A: {message}"):
        check_datum({"label": "A", "feature": 1, "targets": [target]})


def test_a_target_line_on_one_spot_is_refused():
    with pytest.raises(DatumError, match="datum B: the hits of a target line lie on one spot"):
        target_points("B", [{"line": [1, 2]}], {1: np.array([0.0, 0, 0]), 2: np.array([0.0, 0, 1e-9])}, [0, -1, 0])


def test_targets_as_typed_in_the_features_tab():
    from cmm.ui.ids import parse_targets

    assert parse_targets("area(11-13) line(21 22, 23) 31") == [{"area": [11, 12, 13]}, {"line": [21, 22, 23]}, 31]
    assert parse_targets("101, line(21-23) 102") == [101, {"line": [21, 22, 23]}, 102]
    with pytest.raises(ValueError, match="'circle' is not a hit number, a range like 3-7, area\\(hits\\) or line"):
        parse_targets("circle(1 2)")
