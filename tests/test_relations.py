"""Relations (distances, angles, intersections, projections, GD&T) and probe
compensation of fitted features (side logic for bores and bosses)."""

from __future__ import annotations

import numpy as np
import pytest

from cmm.metrology import fit_criteria, fit_ls, probe_offset as po
from cmm.metrology import relations as rel
from cmm.metrology.features import FitError
from cmm.metrology.relations import Axis

TOL = 1e-12


class P:  # minimal plane-like datum
    def __init__(self, point, normal):
        self.point, self.normal = np.asarray(point, float), np.asarray(normal, float) / np.linalg.norm(normal)


def axis(p, u):
    return Axis.through(np.asarray(p, float), np.asarray(u, float))


def test_distances():
    assert rel.distance_point_point([0, 0, 0], [3, 4, 0]) == pytest.approx(5.0)
    assert rel.distance_point_line([1, 5, 7], axis([0, 0, 0], [1, 0, 0])) == pytest.approx(np.hypot(5, 7))
    assert rel.distance_point_plane([0, 0, 2], P([5, 5, 1], [0, 0, 1])) == pytest.approx(1.0)
    assert rel.distance_point_plane([0, 0, 0], P([5, 5, 1], [0, 0, 1])) == pytest.approx(-1.0)
    # skew lines: x axis and a line parallel to y at z = 3
    assert rel.distance_line_line(axis([0, 0, 0], [1, 0, 0]), axis([7, 0, 3], [0, 1, 0])) == pytest.approx(3.0)
    assert rel.distance_line_line(axis([0, 0, 0], [1, 0, 0]), axis([0, 2, 0], [-1, 0, 0])) == pytest.approx(2.0)
    assert rel.distance_line_plane(axis([0, 0, 4], [1, 1, 0]), P([0, 0, 1], [0, 0, 1])) == pytest.approx(3.0)
    assert rel.distance_line_plane(axis([0, 0, 4], [1, 1, 1]), P([0, 0, 1], [0, 0, 1])) == 0.0
    assert rel.distance_plane_plane(P([0, 0, 1], [0, 0, 1]), P([3, 3, 6], [0, 0, -1])) == pytest.approx(5.0)
    # tilted planes: a step height from b's centroid to plane a (no longer refused)
    assert rel.distance_plane_plane(P([0, 0, 1], [0, 0, 1]), P([4, 0, 3], [0, 1, 1])) == pytest.approx(2.0)


def test_angles():
    a = np.radians(30.0)
    tilted = axis([0, 0, 0], [np.cos(a), np.sin(a), 0])
    assert rel.angle_line_line(tilted, axis([0, 0, 0], [-1, 0, 0])) == pytest.approx(a, abs=TOL)
    assert rel.angle_line_plane(tilted, P([0, 0, 0], [0, 1, 0])) == pytest.approx(a, abs=TOL)
    assert rel.angle_plane_plane(P([0, 0, 0], [0, 0, 1]), P([0, 0, 0], [0, np.sin(a), -np.cos(a)])) == pytest.approx(a, abs=TOL)
    assert rel.angle_between([1, 0, 0], [1, 1e-10, 0]) == pytest.approx(1e-10, rel=1e-6)  # no acos rounding


def test_intersections_and_projections():
    x = rel.intersect_line_plane(axis([1, 2, 0], [0, 0, 1]), P([0, 0, 5], [0, 0, 1]))
    assert np.allclose(x, [1, 2, 5], atol=TOL)
    line = rel.intersect_plane_plane(P([0, 0, 5], [0, 0, 1]), P([3, 0, 0], [1, 0, 0]))
    assert np.allclose(line.point, [3, 0, 5], atol=TOL) and np.allclose(np.abs(line.direction), [0, 1, 0])
    with pytest.raises(FitError, match="parallel"):
        rel.intersect_plane_plane(P([0, 0, 5], [0, 0, 1]), P([0, 0, 1], [0, 0, -1]))
    with pytest.raises(FitError, match="parallel"):
        rel.intersect_line_plane(axis([0, 0, 0], [1, 0, 0]), P([0, 0, 5], [0, 0, 1]))
    plane = P([0, 0, 5], [0, 0, 1])
    assert np.allclose(rel.project_point([1, 2, 3], plane), [1, 2, 5])
    circle = fit_ls.fit_circle(np.array([[10.0, 0, 1], [0, 10, 1], [-10, 0, 1], [0, -10, 1]]) + [4, 5, 0])
    assert np.allclose(rel.project_point(circle, plane), [4, 5, 5], atol=1e-9)
    proj = rel.project_line(axis([0, 0, 0], [1, 0, 1]), plane)
    assert np.allclose(proj.point, [0, 0, 5]) and np.allclose(proj.direction, [1, 0, 0])
    xy, frame = rel.to_plane_2d([[1, 2, 9]], plane)
    assert np.allclose(plane.point + frame[:, :2] @ xy[0], [1, 2, 5])


def test_form_values_match_criteria():
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(0, 50, (60, 2)), rng.uniform(-0.01, 0.01, 60)])
    assert rel.flatness(pts) == pytest.approx(fit_criteria.fit("plane", pts, "minzone").form)
    assert rel.flatness(pts) <= 0.02
    t = rng.uniform(0, 2 * np.pi, 80)
    ring = np.column_stack([10 * np.cos(t), 10 * np.sin(t), np.zeros(80)]) * rng.uniform(0.999, 1.001, (80, 1))
    assert rel.roundness(ring) == pytest.approx(rel.roundness(ring[:, :2]), abs=1e-12)
    assert rel.roundness(ring) <= 0.02
    line_pts = np.column_stack([np.linspace(0, 100, 30), rng.uniform(-0.005, 0.005, 30), np.zeros(30)])
    assert rel.straightness(line_pts, P([0, 0, 0], [0, 0, 1])) <= 0.01
    # a cylinder holding planar points is at least as wide as the thinnest strip in their plane
    assert rel.straightness(line_pts) >= rel.straightness(line_pts, P([0, 0, 0], [0, 0, 1])) - 1e-12


def test_orientation_zones():
    rng = np.random.default_rng(1)
    base = P([0, 0, 0], [0, 0, 1])
    # a face 0.02 mm out of parallel over its length plus 0.005 mm flatness noise
    xy = rng.uniform(0, 100, (50, 2))
    top = np.column_stack([xy, 20 + 0.0002 * xy[:, 0] + rng.uniform(0, 0.005, 50)])
    par = rel.parallelism(top, base)
    assert par == pytest.approx(np.ptp(top[:, 2]))
    assert par >= rel.flatness(top) - 1e-12
    # a wall perpendicular to the base within a 0.02 mm box: 4 corners on the zone, the rest inside
    z = rng.uniform(0, 30, 40)
    corners = np.array([[50, 0, 5], [50, 80, 25], [50.02, 0, 15], [50.02, 80, 3]])
    inner = np.column_stack([rng.uniform(50.001, 50.019, 40), rng.uniform(1, 79, 40), z])
    wall = np.vstack([corners, inner])
    assert rel.perpendicularity(wall, base) == pytest.approx(0.02, abs=1e-12)
    # a wall against a datum axis (z): zone planes perpendicular to z -> height spread
    assert rel.perpendicularity(wall, axis([0, 0, 0], [0, 0, 1])) == pytest.approx(np.ptp(wall[:, 2]))
    # an axis (circle centres at several heights) perpendicular to the base: cylinder zone
    centres = np.array([[0, 0, 0], [0.01, 0, 10], [0, 0.01, 20.0]])
    d = rel.perpendicularity(centres, base, feature="axis")
    assert d == pytest.approx(np.sqrt(2) * 0.01, abs=1e-12)  # circle through 3 points, right angle at origin


def test_true_position():
    circle = fit_ls.fit_circle(np.array([[10.0, 0, 0], [0, 10, 0], [-10, 0, 0], [0, -10, 0]]) + [30.03, 19.96, 2])
    assert rel.position(circle, [30, 20, 0]) == pytest.approx(2 * np.hypot(0.03, 0.04), abs=1e-9)
    cyl = Axis.through(np.array([5.0, 5.0, 0.0]), np.array([0.0, 0.001, 1.0]))
    # axis crosses z = 10 at y = 5.01: deviation 0.01 -> diameter 0.02
    assert rel.position(cyl, [5, 5, 10], datum_normal=[0, 0, 1]) == pytest.approx(0.02, abs=1e-9)


# ---------------------------------------------------------------- probe compensation

R_EFF = 0.98
C = np.array([500.0, 200.0, -100.0])


def sphere_dirs(m=40, seed=0):
    d = np.random.default_rng(seed).standard_normal((m, 3))
    d[:, 2] = np.abs(d[:, 2])  # upper hemisphere, as probed from above
    return d / np.linalg.norm(d, axis=1)[:, None]


@pytest.mark.parametrize("side", ["boss", "bore"])
def test_sphere_side(side):
    n = sphere_dirs()
    radius = 12.5
    # boss: tip centres outside by r_eff, approach towards the centre; bore: inside, approach outward
    sign = 1.0 if side == "boss" else -1.0
    tips = C + (radius + sign * R_EFF) * n
    approach = -sign * n
    fitted = fit_ls.fit_sphere(tips)
    surf = po.offset_feature(fitted, tips, approach, R_EFF)
    assert surf.radius == pytest.approx(radius, abs=1e-9)
    assert po.probing_side(fitted, tips, approach) == (po.BOSS if side == "boss" else po.BORE)
    assert np.abs(surf.center - C).max() < 1e-9


@pytest.mark.parametrize("side", ["boss", "bore"])
def test_cylinder_side_with_tilted_approach(side):
    rng = np.random.default_rng(1)
    t, z = rng.uniform(0, 2 * np.pi, 30), rng.uniform(-10, 10, 30)
    radial = np.column_stack([np.cos(t), np.sin(t), np.zeros(30)])
    sign = 1.0 if side == "boss" else -1.0
    tips = C + (8.0 + sign * R_EFF) * radial + np.outer(z, [0, 0, 1.0])
    approach = -sign * radial + [0, 0, -0.3]  # not exactly normal: only the side matters
    surf = po.offset_feature(fit_ls.fit_cylinder(tips), tips, approach, R_EFF)
    assert surf.radius == pytest.approx(8.0, abs=1e-9)


def test_plane_shifted_towards_approach_side():
    rng = np.random.default_rng(2)
    tips = np.column_stack([rng.uniform(0, 50, (20, 2)), np.full(20, 10.0 + R_EFF)])
    plane = fit_ls.fit_plane(tips)
    surf = po.offset_feature(plane, tips, [0, 0, -1.0], R_EFF)  # probing down onto a top face
    assert surf.point[2] == pytest.approx(10.0, abs=1e-12)
    surf = po.offset_feature(plane, tips, [0, 0, 1.0], R_EFF)  # probing up against an underside
    assert surf.point[2] == pytest.approx(10.0 + 2 * R_EFF, abs=1e-12)


def test_cone_apex_moves_along_axis():
    psi = np.radians(30.0)
    rng = np.random.default_rng(3)
    t, z = rng.uniform(0, 2 * np.pi, 40), rng.uniform(5, 20, 40)
    e = np.column_stack([np.cos(t), np.sin(t), np.zeros(40)])
    surface = z[:, None] * np.tan(psi) * e + np.outer(z, [0, 0, 1.0])
    normal = np.cos(psi) * e - np.sin(psi) * np.array([0, 0, 1.0])
    tips = surface + R_EFF * normal  # boss: tips outside, approach inward
    surf = po.offset_feature(fit_ls.fit_cone(tips), tips, -normal, R_EFF)
    assert np.abs(surf.apex).max() < 1e-9
    assert surf.half_angle == pytest.approx(psi, abs=1e-12)


def test_mixed_approach_is_refused():
    n = sphere_dirs()
    tips = C + 13.0 * n
    approach = -n
    approach[3] = n[3]
    with pytest.raises(FitError, match="do not show one side"):
        po.offset_feature(fit_ls.fit_sphere(tips), tips, approach, R_EFF)


def test_compensate_points_with_feature_normals():
    n = sphere_dirs(seed=4)
    tips = C + (10.0 + R_EFF) * n
    approach = -n + 0.2 * np.array([1.0, 0, 0])  # 10 degree-ish off-normal approach
    fitted = fit_ls.fit_sphere(tips)
    contact = po.compensate_points(tips, R_EFF, po.contact_normals(fitted, tips, approach))
    assert np.abs(np.linalg.norm(contact - C, axis=1) - 10.0).max() < 1e-9
    naive = po.compensate_points(tips, R_EFF, approach)  # approach direction: cosine error
    assert np.abs(np.linalg.norm(naive - C, axis=1) - 10.0).max() > 1e-3


def test_single_point_compensation():
    out = po.compensate_points([[1.0, 2.0, 3.0]], 0.5, [[0.0, 0.0, -2.0]])
    assert np.allclose(out, [[1.0, 2.0, 2.5]])
