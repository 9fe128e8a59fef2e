"""Defined feature semantics: where a line, cylinder or cone is (the foot of the data centroid on its axis, with
the uncertainty valid there) and what a constructed distance or angle between features measures."""

from __future__ import annotations

import math

import knownanswer as ka
import numpy as np
import pytest

from cmm.metrology import fit_criteria
from cmm.metrology.construct import construct

BORE = ("cylinder", {"point": [30.0, 40.0, 0.0], "direction": [0.0, 0.0, 1.0], "radius": 15.0})
BOSS = ("cylinder", {"point": [70.0, 22.0, 40.0], "direction": [0.0, 0.0, 1.0], "radius": 10.0})
Z = np.array([0.0, 0.0, 1.0])


def _foot(p, u, q):
    u = np.asarray(u, float) / np.linalg.norm(u)
    return np.asarray(p, float) + ((np.asarray(q, float) - p) @ u) * u


@pytest.mark.parametrize("kind,method", [("line", "ls"), ("line", "minzone"), ("cylinder", "ls"),
                                         ("cylinder", "minzone"), ("cylinder", "mcc"), ("cone", "ls")])
def test_the_location_point_is_the_foot_of_the_data_centroid_5000_mm_out(kind, method):
    far = np.array([5000.0, -300.0, 200.0])
    u = np.array([0.2, 0.3, 0.93])
    if kind == "line":
        data = ka.line(far, u, form=0.01)
        axis_point = far
    elif kind == "cylinder":
        data = ka.cylinder(far, u, 20.0, form=0.01)
        axis_point = far
    else:
        data = ka.cone(far, u, math.radians(20.0), form=0.01)
        axis_point = far
    res = fit_criteria.fit(kind, data.points, method)
    expected = _foot(axis_point, res.direction, data.points.mean(axis=0))
    assert np.abs(res.point - expected).max() < (1e-9 if method == "ls" else 0.02)
    assert abs(res.point[0] - 5000.0) < 60.0  # near the data, not at the foot of the origin (x = 0 for this line)


def test_the_reported_position_uncertainty_holds_at_the_location_point():
    """Monte Carlo: the scatter of the reported cylinder point (across the axis) matches the reported u."""
    rng = np.random.default_rng(3)
    far = np.array([900.0, 400.0, 300.0])
    u = np.array([0.0, 0.6, 0.8])
    base = ka.cylinder(far, u, 20.0, m=120, length=40.0, form=0.0)  # > fit_ls.SPARSE: no wide search
    pts0 = base.points
    frame = np.linalg.svd(np.outer(u, u))[0]
    across = frame[:, 1:]  # two directions perpendicular to the axis
    shifts, reported = [], []
    for _ in range(80):
        res = fit_criteria.fit("cylinder", pts0 + 0.002 * rng.standard_normal(pts0.shape), "ls")
        shifts.append((res.point - _foot(far, u, pts0.mean(axis=0))) @ across)
        reported.append(res.uncertainty["axis_position"])
    scatter = float(np.sqrt(np.sum(np.var(np.array(shifts), axis=0))))  # root-sum-square of both components
    assert scatter == pytest.approx(np.mean(reported), rel=0.25)


def test_distance_between_parallel_bore_and_boss_is_axis_to_axis_in_the_alignment_plane():
    """The nominal bore-boss distance is hypot(40, 18) = 43.8634. Measured axes tilt a little, each its own way:
    their shortest distance is taken along their common perpendicular, whose direction those tilts decide
    (here y: 18.0), which is how 43.8634 read as 41.0138. The axis-to-axis distance stays 43.8634."""
    nominal = construct("distance", BORE, BOSS, workplane=Z)
    assert nominal.value == pytest.approx(math.hypot(40.0, 18.0), abs=1e-12)
    assert "XY plane" in nominal.projection
    tilt = 1e-4
    bore = ("cylinder", {"point": [30.0, 40.0, 20.0], "direction": [0.0, 0.0, 1.0], "radius": 15.0})
    boss = ("cylinder", {"point": [70.0, 22.0, 47.5], "direction": [tilt, 0.0, 1.0], "radius": 10.0})
    from types import SimpleNamespace

    from cmm.metrology import relations

    skew = relations.distance_line_line(*(SimpleNamespace(point=np.array(g["point"]), direction=np.array(g["direction"]))
                                          for _, g in (bore, boss)))
    assert skew == pytest.approx(18.0, abs=1e-6)  # the common perpendicular runs along y: the old "distance"
    actual = construct("distance", bore, boss, workplane=Z)
    assert actual.value == pytest.approx(math.hypot(40.0, 18.0), abs=1e-12)
    three_d = construct("distance", bore, boss, workplane=Z, three_d=True)
    assert "3-D" in three_d.projection and three_d.value == pytest.approx(math.hypot(40.0, 18.0), abs=1e-2)
    # circles of the bore and the boss at different heights: the same axis-to-axis distance, not centre to centre
    c1 = ("circle", {"center": [30.0, 40.0, 20.0], "normal": [0.0, 0.0, 1.0], "radius": 15.0})
    c2 = ("circle", {"center": [70.0, 22.0, 47.0], "normal": [0.0, 0.0, -1.0], "radius": 10.0})
    assert construct("distance", c1, c2, workplane=Z).value == pytest.approx(math.hypot(40.0, 18.0), abs=1e-12)
    # horizontal parallel axes (not along the alignment's Z): perpendicular to the axes, wherever the data lie
    h1 = ("cylinder", {"point": [0.0, 0.0, 10.0], "direction": [1.0, 0.0, 0.0], "radius": 5.0})
    h2 = ("cylinder", {"point": [80.0, 30.0, 50.0], "direction": [1.0, 0.0, 0.0], "radius": 5.0})
    d = construct("distance", h1, h2, workplane=Z)
    assert d.value == pytest.approx(50.0, abs=1e-12) and "perpendicular to the mean axis" in d.projection
    # skew axes: the shortest distance, named so
    s1 = ("line", {"point": [0.0, 0.0, 0.0], "direction": [1.0, 0.0, 0.0]})
    s2 = ("line", {"point": [0.0, 0.0, 7.0], "direction": [0.0, 1.0, 0.0]})
    s = construct("distance", s1, s2, workplane=Z)
    assert s.value == pytest.approx(7.0) and "skew" in s.projection


def test_angles_between_lines_and_planes_name_what_they_measure():
    p1 = ("plane", {"point": [0, 0, 0], "normal": [0.0, 0.0, 1.0]})
    p2 = ("plane", {"point": [0, 0, 0], "normal": [0.0, math.sin(math.radians(30)), math.cos(math.radians(30))]})
    line = ("line", {"point": [0, 0, 0], "direction": [1.0, 0.0, 2.0]})
    a = construct("angle", p1, p2)
    assert a.value == pytest.approx(30.0, abs=1e-12) and "normal of the plane" in a.projection
    b = construct("angle", line, p1)
    # a line against a plane (ISO): 90 deg minus its angle to the normal, atan(1 / 2) = 26.57 deg
    assert b.value == pytest.approx(90.0 - math.degrees(math.atan(0.5)), abs=1e-12)
    assert "axis of the line and the plane" in b.projection
    c = construct("angle", line, ("line", {"point": [0, 0, 0], "direction": [0.0, 0.0, 1.0]}))
    assert c.value == pytest.approx(math.degrees(math.atan(0.5)), abs=1e-12) and "axis of the line" in c.projection
