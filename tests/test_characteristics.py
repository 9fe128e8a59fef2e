"""Plain tests: the shared colour scale, toleranced characteristics (true position as a diameter),
CAD nominals found from where hits lie, residuals for form plots, machine events in words."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cmm.metrology.characteristics import characteristics, true_position, verdict
from cmm.metrology.colour_scale import BLUE, CYAN, GREEN, GREY, RED, AMBER, ColourScale
from cmm.metrology.feature_distance import around_axis, surface_distance
from cmm.metrology.nominal_match import nominal_for_points
from cmm.metrology.transform import as_pose
from cmm.journal.wording import error_text, event_text, event_title, grouped
from cmm.sim.sample_part import sample_part


def test_colour_scale_bands_cutoff_and_legend():
    s = ColourScale(0.02, cutoff=0.5)  # out of tolerance beyond +-20 um, warning from +-10 um (50 %)
    assert [s.colour(d) for d in (0.0, 0.01, -0.01)] == [GREEN] * 3  # the warning limits are still green
    assert s.colour(0.015) == AMBER and s.colour(0.02) == AMBER and s.colour(0.03) == RED
    assert s.colour(-0.015) == CYAN and s.colour(-0.02) == CYAN and s.colour(-0.03) == BLUE
    assert s.colour(0.6) == GREY and s.colour(-0.6) == GREY and s.colour(math.nan) == GREY and s.colour(None) == GREY
    assert ColourScale(0.02).max_distance == pytest.approx(0.5)  # default cut-off: 25 x the tolerance
    assert ColourScale(0.02, warning=0.8).colour(0.015) == GREEN  # a warning limit at 80 % of the tolerance
    colours = s.colours(np.array([0.0, 0.03, math.nan, -0.015]))
    assert colours.dtype == np.uint8 and colours.tolist() == [list(GREEN), list(RED), list(GREY), list(CYAN)]
    assert [s.colour(d) for d in (0.0, 0.03, math.nan, -0.015)] == [tuple(c) for c in colours.tolist()]
    edges = [0.01, -0.01, 0.02, -0.02, 0.5, -0.5, 0.50001, -0.0, math.inf, -math.inf]  # the scalar twin agrees
    assert [s.band(d) for d in edges] == s.bands(np.array(edges)).tolist()
    legend = s.legend()
    assert [c for c, _ in legend] == [RED, AMBER, GREEN, CYAN, BLUE, GREY]
    assert legend[0][1] == "> +20 µm out of tolerance" and legend[1][1] == "+10 .. +20 µm warning"
    assert legend[2][1] == "within ±10 µm" and "0.5 mm" in legend[-1][1] and "15 mm" in legend[-1][1]
    assert [c for c, _ in ColourScale(0.02, warning=1.0).legend()] == [RED, GREEN, BLUE, GREY]  # no warning band
    assert s.counts([0.0, 0.015, 1.0, None]) == {2: 0, 1: 1, 0: 1, -1: 0, -2: 0, 3: 2}
    for bad in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError, match="positive"):
            ColourScale(bad)
    with pytest.raises(ValueError, match="reach"):
        ColourScale(reach=0.0)
    with pytest.raises(ValueError, match="warning"):
        ColourScale(warning=1.5)


def test_true_position_is_the_diameter_of_the_zone():
    nominal = {"kind": "cylinder", "point": [0, 0, 0], "direction": [0, 0, 1], "radius": 5.0}
    # the axis is 0.003 mm off in X and 0.004 in Y (radial 0.005) and 7 mm along the axis (which does not count)
    fit = {"point": [0.003, 0.004, 7.0], "direction": [0, 0, 1], "radius": 5.004, "form": 0.002}
    assert true_position("cylinder", fit, nominal) == pytest.approx(0.010)
    chars = {c.name: c for c in characteristics("bore", "cylinder", fit, nominal, {"position": 0.008})}
    assert chars["position ⌀"].actual == pytest.approx(0.010) and chars["position ⌀"].ok is False
    assert chars["position ⌀"].out_of_tolerance == pytest.approx(0.002)
    assert chars["position ⌀"].tolerance_text == "⌀ 0.0080"
    assert chars["diameter"].nominal == 10.0 and chars["diameter"].deviation == pytest.approx(0.008)
    assert chars["diameter"].ok is True and chars["cylindricity"].ok is True  # default +-0.02 / 0.02
    # default position zone: twice the +- location tolerance
    assert next(c for c in characteristics("b", "cylinder", fit, nominal) if c.name == "position ⌀").upper == 0.04
    sphere = {"center": [1.0, 2.0, 3.0], "radius": 2.0}
    assert true_position("sphere", {"center": [1.0, 2.0, 3.006]}, sphere) == pytest.approx(0.012)
    assert verdict(characteristics("bore", "cylinder", fit, nominal, {"position": 0.008}))[:2] == ("FAIL", 1)


def test_no_nominal_is_not_evaluated_never_a_pass():
    fit = {"center": [0, 0, 0], "normal": [0, 0, 1], "radius": 5.0, "form": 0.001}
    chars = characteristics("c", "circle", fit, None)
    size, pos, form = chars
    assert (size.name, size.nominal, size.ok, size.verdict) == ("diameter", None, None, "no nominal")
    assert pos.actual is None and pos.ok is None
    assert form.name == "roundness" and form.ok is True
    assert verdict(chars) == ("INCOMPLETE", 0, 2)
    # a nominal of another kind does not compare (a plane fitted to a bore's hits)
    plane = characteristics("p", "plane", {"point": [0, 0, 0], "normal": [0, 0, 1], "form": 0.0},
                            {"kind": "cylinder", "point": [0, 0, 0], "direction": [0, 0, 1], "radius": 3.0})
    assert plane[0].ok is None and "not comparable" in plane[0].note
    cone = characteristics("k", "cone", {"apex": [0, 0, 0], "direction": [0, 0, 1], "half_angle": math.radians(30.05),
                                         "form": 0.0},
                           {"kind": "cone", "apex": [0, 0, 0.001], "direction": [0, 0, 1], "half_angle": math.radians(30)})
    assert cone[0].name == "half angle" and cone[0].unit == "deg" and cone[0].deviation == pytest.approx(0.05)
    assert cone[1].actual == pytest.approx(0.002)


def _ring(centre, radius, z, n=8, normal_out=True):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.c_[centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a), np.full(n, z)]


def test_cad_nominal_from_where_the_hits_lie():
    mesh, nominal = sample_part()
    pose = as_pose(np.eye(4))
    pose[:3, 3] = [190.0, 150.0, 0.0]
    boss = _ring((70 + 190.0, 22 + 150.0), 10.0, 47.0) + np.array([0.0, 0.0, 0.0])
    found = nominal_for_points(mesh, pose, boss, "circle")
    assert found is not None and found.kind == "cylinder" and not found.params["bore"]
    assert found.params["radius"] == pytest.approx(10.0, abs=1e-3)
    assert np.allclose(found.params["point"][:2], [260.0, 172.0], atol=1e-3)
    bore = _ring((30 + 190.0, 40 + 150.0), 15.0, 20.0)
    found = nominal_for_points(mesh, pose, bore + 0.3, "cylinder")  # 0.3 mm set-up error: still the bore
    assert found is not None and found.params["bore"] and found.params["radius"] == pytest.approx(15.0, abs=1e-3)
    top = np.array([[200.0, 160.0, 40.0], [300.0, 220.0, 40.0], [210.0, 215.0, 40.0]])
    found = nominal_for_points(mesh, pose, top, "plane")
    assert found.kind == "plane" and np.allclose(found.params["normal"], [0, 0, 1])
    assert nominal_for_points(mesh, pose, top, "sphere") is None  # a sphere on a flat face: no nominal
    assert nominal_for_points(mesh, pose, top + [0, 0, 30.0], "plane") is None  # far from the part


def test_residuals_and_angles_for_form_plots():
    ring = _ring((0, 0), 5.0, 0.0, n=4) * np.array([[1.001], [1.0], [1.0], [1.0]])
    g = {"center": [0, 0, 0], "normal": [0, 0, 1], "radius": 5.0}
    assert np.allclose(surface_distance("circle", g, ring), [0.005, 0, 0, 0], atol=1e-12)
    ang = around_axis("circle", g, ring)
    assert np.allclose(np.sort(np.diff(np.sort(ang))), [np.pi / 2] * 3)
    assert surface_distance("plane", {"point": [0, 0, 1], "normal": [0, 0, 2]}, [[5, 5, 1.5]])[0] == pytest.approx(0.5)
    cone = {"apex": [0, 0, 0], "direction": [0, 0, 1], "half_angle": math.radians(45)}
    assert surface_distance("cone", cone, [[1, 0, 1]])[0] == pytest.approx(0.0, abs=1e-12)
    assert around_axis("plane", {"point": [0, 0, 0], "normal": [0, 0, 1]}, ring) is None


def test_machine_events_in_words():
    assert event_text("contact", {"position": [201.3341, 150.02, 38.1149]}) == (
        "Unexpected probe contact at X 201.334 Y 150.020 Z 38.115: the machine stopped and recorded no hit.")
    assert "dead-man" in event_text("deadman", {"after": 0.16})
    assert event_text("limit", {"axis": "y"}) == "The jog stopped at the end of travel of the Y axis."
    assert event_text("error", {"message": "the probe is still deflected after the retract"}).startswith("the probe")
    # journals written before the wording recorded str(dict)
    assert error_text("machine:contact", "{'position': [1.0, 2.0, 3.0]}").startswith("Unexpected probe contact at X 1.000")
    assert error_text("recorder", "plain words") == "plain words"
    assert grouped(["a", "b", "a"]) == [("a", 2), ("b", 1)]
    assert event_title("contact") == "Unexpected probe contact" and event_title("deadman") == "Jog stopped"
    assert event_text("fault", {"message": "module 2 did not answer"}) == "module 2 did not answer"


def test_constructed_features_and_their_nominals():
    from cmm.metrology.characteristics import constructed_characteristics
    from cmm.metrology.construct import construct, nominal_geometry
    from cmm.metrology.features import FitError

    top = ("plane", {"point": [0, 0, 40.0], "normal": [0, 0, 1.0]})
    front = ("plane", {"point": [0, 0, 0.0], "normal": [0, -1.0, 0]})
    line = construct("intersection", top, front)
    assert line.kind == "line" and np.allclose(np.abs(line.geometry["direction"]), [1, 0, 0])
    assert np.allclose(line.geometry["point"], [0, 0, 40])
    bore = ("circle", {"center": [30.0, 40.0, 40.0], "normal": [0, 0, 1.0], "radius": 15.0})
    boss = ("cylinder", {"point": [70.0, 22.0, 0.0], "direction": [0, 0, 1.0], "radius": 10.0})
    pierce = construct("intersection", boss, top)
    assert np.allclose(pierce.geometry["point"], [70, 22, 40])
    assert construct("distance", bore, ("point", pierce.geometry)).value == pytest.approx(math.hypot(40, 18))
    assert construct("distance", bore, boss).value == pytest.approx(math.hypot(40, 18))  # parallel axes
    assert construct("distance", ("sphere", {"center": [0, 0, 50.0]}), top).value == pytest.approx(10.0)
    assert construct("angle", top, front).value == pytest.approx(90.0)
    assert construct("midpoint", bore, ("sphere", {"center": [70.0, 58.0, 40.0]})).geometry["point"] == [50, 49, 40]
    with pytest.raises(FitError, match="parallel"):
        construct("intersection", top, ("plane", {"point": [0, 0, 1.0], "normal": [0, 0, 1.0]}))
    with pytest.raises(FitError, match="mid-point"):
        construct("midpoint", top, bore)
    # the nominal of a circle measured on a cylindrical bore
    assert nominal_geometry("circle", {"kind": "cylinder", "point": [1, 2, 3], "direction": [0, 0, 1], "radius": 4})[0] == "circle"
    (dist,) = constructed_characteristics("d", {"kind": "distance", "value": 43.87}, {"kind": "distance", "value": 43.86},
                                          {"location": 0.005})
    assert dist.deviation == pytest.approx(0.01) and dist.ok is False
    (ang,) = constructed_characteristics("a", {"kind": "angle", "value": 90.02}, None)
    assert ang.ok is None and "no nominal" in ang.note


def test_auto_measure_plans_hits_on_the_picked_surface():
    from cmm.metrology.hit_plan import PlanError, plan_feature
    from cmm.metrology.pick import pick, suggest_feature

    mesh, _ = sample_part()
    pose = as_pose(np.eye(4))
    pose[:3, 3] = [190.0, 150.0, 0.0]

    def plan_at(point, direction, **kw):
        hit = pick(mesh, None, np.asarray(point, float) - 30 * np.asarray(direction, float), direction)
        s = suggest_feature(mesh, hit.face_id)
        return plan_feature(mesh, pose, s.feature, s.face_ids, **kw)

    top = plan_at((10, 70, 40), (0, 0, -1))
    assert top.kind == "plane" and len(top) == 4 and np.allclose(top.approaches, [0, 0, -1])
    assert np.allclose(top.points[:, 2], 40.0) and top.clearance_z == pytest.approx(55.0 + 15.0)
    spread = np.linalg.norm(top.points[:, None] - top.points[None], axis=2)
    assert spread[spread > 0].min() > 20.0  # spread over the face, not bunched
    boss = plan_at((80, 22, 47), (-1, 0, 0))
    assert boss.kind == "cylinder" and len(boss) == 8 and boss.nominal.params["bore"] is False
    radial = boss.points[:, :2] - [260.0, 172.0]
    assert np.allclose(np.linalg.norm(radial, axis=1), 10.0)
    assert np.allclose(np.einsum("ij,ij->i", boss.approaches[:, :2], radial / 10.0), -1.0)  # into the boss
    bore = plan_at((15, 40, 20), (-1, 0, 0))
    radial = bore.points[:, :2] - [220.0, 190.0]
    assert bore.nominal.params["bore"] and np.allclose(np.einsum("ij,ij->i", bore.approaches[:, :2], radial / 15.0), 1.0)
    dome = plan_at((70, 58, 49), (0, 0, -1))
    assert dome.kind == "sphere" and len(dome) == 5
    with pytest.raises(PlanError, match="too small"):
        plan_at((10, 70, 40), (0, 0, -1), n=4, margin=60.0)
