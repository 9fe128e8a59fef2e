"""Minimum zone / MIC / MCC against constructed exact answers.

Each set puts the defining points exactly on the limiting circles, spheres,
lines or planes and every other point strictly between them, so the answer
is known by construction.
"""

from __future__ import annotations

import numpy as np
import pytest

import knownanswer as ka
from cmm.metrology import fit_criteria as fc
from cmm.metrology import fit_ls
from cmm.metrology.features import FitError

TOL = 1e-9
C2 = np.array([1000.0, -600.0])
C3 = np.array([1000.0, -600.0, 400.0])


def ring(c, radii, angles):
    return c + np.column_stack([radii * np.cos(angles), radii * np.sin(angles)])


def rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    return q


def embed(points2, center3, seed):
    """2D points into a tilted plane through center3."""
    rot = rotation(seed)
    return center3 + points2 @ rot[:, :2].T, rot


# ---------------------------------------------------------------- circles


def mcc_set(rng, r=10.0, m=40):
    limit = rng.uniform(0, 2 * np.pi) + np.array([0.0, 2.2, 4.3])  # acute triangle around the centre
    inner = rng.uniform(0.3 * r, r - 1e-3, m)
    rel = np.vstack([ring(0, r, limit), ring(0, inner, rng.uniform(0, 2 * np.pi, m))])
    return rng.permutation(rel)


def mic_set(rng, r=10.0, m=60):
    limit = rng.uniform(0, 2 * np.pi) + np.array([0.0, 2.0, 4.2])
    outer = rng.uniform(r + 1e-3, r + 0.5, m)
    angles = np.linspace(0, 2 * np.pi, m, endpoint=False) + 0.01
    return rng.permutation(np.vstack([ring(0, r, limit), ring(0, outer, angles)]))


def minzone_set(rng, r_in=9.99, r_out=10.01, m=50):
    a, phi = rng.uniform(0, np.pi), rng.uniform(0.3, np.pi - 0.3)
    outer = ring(0, r_out, a + np.array([0.0, np.pi]))
    inner = ring(0, r_in, a + phi + np.array([0.0, np.pi]))
    rest = ring(0, rng.uniform(r_in + 1e-4, r_out - 1e-4, m), rng.uniform(0, 2 * np.pi, m))
    return rng.permutation(np.vstack([outer, inner, rest]))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_mcc_circle_2d_exact(seed):
    res = fc.fit("circle2d", C2 + mcc_set(np.random.default_rng(seed)), "mcc")
    assert np.abs(res.center - C2).max() < TOL and abs(res.radius - 10.0) < TOL
    assert res.residuals.max() == pytest.approx(0.0, abs=TOL)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_mic_circle_2d_exact(seed):
    res = fc.fit("circle2d", C2 + mic_set(np.random.default_rng(seed)), "mic")
    assert np.abs(res.center - C2).max() < TOL and abs(res.radius - 10.0) < TOL
    assert res.residuals.min() == pytest.approx(0.0, abs=TOL)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_minzone_circle_2d_exact(seed):
    res = fc.fit("circle2d", C2 + minzone_set(np.random.default_rng(seed)), "minzone")
    assert np.abs(res.center - C2).max() < TOL
    assert abs(res.form - 0.02) < TOL and abs(res.radius - 10.0) < TOL
    ls = fit_ls.fit_circle_2d(C2 + minzone_set(np.random.default_rng(seed)))
    assert res.form <= ls.form


@pytest.mark.parametrize("method, builder", [("mcc", mcc_set), ("mic", mic_set), ("minzone", minzone_set)])
def test_circle_3d_criteria_in_a_tilted_plane(method, builder):
    pts, rot = embed(builder(np.random.default_rng(7)), C3, seed=5)
    res = fc.fit("circle", pts, method)
    assert np.abs(res.center - C3).max() < TOL and abs(res.radius - 10.0) < TOL
    assert np.linalg.norm(np.cross(res.normal, rot[:, 2])) < TOL
    assert res.method == method


# ---------------------------------------------------------------- spheres


def tetra(rng):
    v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float) / np.sqrt(3)
    return v @ rotation(int(rng.integers(1000))).T


def shell(rng, lo, hi, m):
    d = rng.standard_normal((m, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return d * rng.uniform(lo, hi, (m, 1))


def test_mcc_sphere_exact():
    rng = np.random.default_rng(3)
    pts = C3 + np.vstack([10.0 * tetra(rng), shell(rng, 2.0, 9.999, 200)])
    res = fc.fit("sphere", rng.permutation(pts), "mcc")
    assert np.abs(res.center - C3).max() < TOL and abs(res.radius - 10.0) < TOL


def test_mic_sphere_exact():
    rng = np.random.default_rng(4)
    pts = C3 + np.vstack([10.0 * tetra(rng), shell(rng, 10.001, 11.0, 400)])
    res = fc.fit("sphere", pts, "mic")
    assert np.abs(res.center - C3).max() < TOL and abs(res.radius - 10.0) < TOL


def test_minzone_sphere_exact():
    rng = np.random.default_rng(5)
    rot = rotation(9)
    outer = 10.01 * np.array([[1, 0, 0], [-1, 0, 0], [0, 0, 1], [0, 0, -1]], float)
    inner = 9.99 * np.array([[0, 1, 0], [0, -1, 0]], float)
    pts = C3 + np.vstack([outer, inner, shell(rng, 9.9901, 10.0099, 200)]) @ rot.T
    res = fc.fit("sphere", pts, "minzone")
    assert np.abs(res.center - C3).max() < TOL
    assert abs(res.form - 0.02) < TOL and abs(res.radius - 10.0) < TOL


# ---------------------------------------------------------------- flatness and straightness


def slab_points(top_uv, bottom_uv, w, rng, m=100):
    """Points in a tilted plane frame: given top (+w/2) and bottom (-w/2) points, the rest inside."""
    lo, hi = np.min(np.vstack([top_uv, bottom_uv]), 0), np.max(np.vstack([top_uv, bottom_uv]), 0)
    rest = np.column_stack([rng.uniform(lo, hi, (m, 2)), rng.uniform(-w / 2 + 1e-4, w / 2 - 1e-4, m)])
    local = np.vstack([np.column_stack([top_uv, np.full(len(top_uv), w / 2)]),
                       np.column_stack([bottom_uv, np.full(len(bottom_uv), -w / 2)]), rest])
    rot = rotation(11)
    return C3 + local @ rot.T, rot


@pytest.mark.parametrize("case", ["facet-vertex", "edge-edge"])
def test_flatness_exact(case):
    rng = np.random.default_rng(2)
    if case == "facet-vertex":
        top, bottom = np.array([[-40.0, -30], [40, -30], [0, 40]]), np.array([[1.0, 2.0]])
    else:  # two crossing ridges: no facet is flush with the zone
        top, bottom = np.array([[-40.0, 0], [40, 0]]), np.array([[0.0, -40], [0, 40]])
    pts, rot = slab_points(top, bottom, 0.05, rng)
    res = fc.fit("plane", pts, "minzone")
    assert abs(res.form - 0.05) < TOL
    assert np.linalg.norm(np.cross(res.normal, rot[:, 2])) < TOL
    assert abs((res.point - C3) @ res.normal) < TOL
    assert res.form < fit_ls.fit_plane(pts).form


def test_straightness_2d_exact():
    rng = np.random.default_rng(3)
    ang = 0.4
    t, n = np.array([np.cos(ang), np.sin(ang)]), np.array([-np.sin(ang), np.cos(ang)])
    along = np.concatenate([[-50.0, 50.0, 3.0], rng.uniform(-50, 50, 60)])
    across = np.concatenate([[0.01, 0.01, -0.01], rng.uniform(-0.0099, 0.0099, 60)])
    pts = C2 + np.outer(along, t) + np.outer(across, n)
    res = fc.fit("line2d", pts, "minzone")
    assert abs(res.form - 0.02) < TOL
    assert abs(res.direction[0] * t[1] - res.direction[1] * t[0]) < TOL
    assert abs((C2 - res.point) @ res.normal) < TOL


def test_straightness_3d_cylindrical_zone():
    data = ka.line(C3, [0.2, 0.3, 0.9], m=80, form=0.02)
    res = fc.fit("line", data.points, "minzone")
    assert res.form <= fit_ls.fit_line(data.points).form + 1e-12
    # every point inside the zone, and the zone touched
    assert res.residuals.max() == pytest.approx(res.form / 2, abs=1e-12)


# ---------------------------------------------------------------- cylinders


@pytest.mark.parametrize("method", ["minzone", "mic", "mcc"])
def test_cylinder_criteria_properties(method):
    data = ka.cylinder(C3, [0.2, 0.3, 0.9], 8.0, m=200, form=0.02)
    ls = fit_ls.fit_cylinder(data.points)
    res = fc.fit("cylinder", data.points, method)
    if method == "mcc":
        assert res.residuals.max() == pytest.approx(0.0, abs=1e-12) and res.radius > ls.radius
    elif method == "mic":
        assert res.residuals.min() == pytest.approx(0.0, abs=1e-12) and res.radius < ls.radius
    else:
        assert res.form < ls.form
        assert res.residuals.max() == pytest.approx(-res.residuals.min(), abs=1e-12)
    assert np.linalg.norm(np.cross(res.direction, ls.direction)) < 1e-3


def test_minzone_cylinder_exact_symmetric_set():
    # outer generators at +-x, inner at +-y, at two heights: the zone is fixed by symmetry
    rng = np.random.default_rng(8)
    rot = rotation(3)
    ang = np.array([0.0, np.pi, 0.5 * np.pi, 1.5 * np.pi])
    rad = np.array([8.01, 8.01, 7.99, 7.99])
    key = np.vstack([np.column_stack([ring(0, rad, ang), np.full(4, z)]) for z in (-20.0, 20.0)])
    a = rng.uniform(0, 2 * np.pi, 150)
    rest = np.column_stack([ring(0, rng.uniform(7.9901, 8.0099, 150), a), rng.uniform(-19, 19, 150)])
    pts = C3 + np.vstack([key, rest]) @ rot.T
    res = fc.fit("cylinder", pts, "minzone")
    assert abs(res.form - 0.02) < TOL and abs(res.radius - 8.0) < TOL
    assert np.linalg.norm(np.cross(res.direction, rot[:, 2])) < TOL


# ---------------------------------------------------------------- dispatcher


def test_unsupported_method_is_refused():
    with pytest.raises(FitError, match="method 'mic' is not available for a plane; choose one of: ls, minzone"):
        fc.fit("plane", np.random.default_rng(0).random((10, 3)), "mic")


def test_mic_needs_surrounding_points():
    pts = C2 + ring(0, 10.0, np.linspace(0, 0.3, 10))  # short arc: no interior Voronoi vertex
    pts[::2] += 0.001
    with pytest.raises(FitError):
        fc.fit("circle2d", pts, "mic")


def test_methods_for():
    assert fc.methods_for("circle") == ("ls", "minzone", "mic", "mcc")
    assert fc.methods_for("cone") == ("ls",)


# ---------------------------------------------------------------- global optima, partial features


def dome_plate(m, seed=0):
    """100 mm plate with 5 um of convexity and 0.5 um noise, tilted, 1000 mm from the origin."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-50, 50, (m, 2))
    w = 0.005 * (1 - (uv**2).sum(axis=1) / 5000.0) + 0.0005 * rng.standard_normal(m)
    return C3 + np.column_stack([uv, w]) @ rotation(21).T


def test_flatness_lp_matches_exact_hull_enumeration_and_is_certified():
    from cmm.metrology.fit_hull import min_width_3d, min_width_direction

    pts = dome_plate(300)
    res = fc.fit("plane", pts, "minzone")
    exact, _ = min_width_direction(pts - pts.mean(axis=0))  # all facet and edge-pair directions
    assert abs(res.form - exact) < 1e-12
    _, _, gap = min_width_3d(pts - pts.mean(axis=0), fit_ls.fit_plane(pts).normal)
    assert gap < 1e-9 and res.warnings == ()


def test_flatness_of_a_bulky_point_set_falls_back_to_the_exact_search():
    rng = np.random.default_rng(4)
    pts = C3 + rng.uniform(-10, 10, (60, 3)) * [1.0, 1.0, 0.5]  # a box of points, not a plate
    from cmm.metrology.fit_hull import min_width_direction

    exact, _ = min_width_direction(pts - pts.mean(axis=0))
    assert fc.fit("plane", pts, "minzone").form == pytest.approx(exact, abs=1e-12)


def test_mcc_sphere_of_a_cap_is_exact_and_says_it_is_partial():
    rng = np.random.default_rng(6)
    polar, az = np.radians(30) * np.sqrt(rng.random(80)), rng.uniform(0, 2 * np.pi, 80)
    n = np.column_stack([np.sin(polar) * np.cos(az), np.sin(polar) * np.sin(az), np.cos(polar)])
    pts = C3 + 10.0 * n
    res = fc.fit("sphere", pts, "mcc")
    assert res.residuals.max() == pytest.approx(0.0, abs=1e-12)
    assert res.radius < 10.0 and any("only part of the sphere" in w for w in res.warnings)
    with pytest.raises(FitError, match="maximum inscribed sphere is not defined"):
        fc.fit("sphere", pts, "mic")
    mz = fc.fit("sphere", pts + 0.001 * rng.standard_normal(pts.shape), "minzone")
    assert any("global optimum is not proven" in w for w in mz.warnings)


def test_mcc_short_cylinder_is_not_beaten_by_any_axis_direction():
    """The MCC radius is at most the exact 2D enclosing radius along every direction of a grid."""
    from cmm.metrology.fit_enclosing import min_enclosing_ball
    from cmm.metrology.geom_basics import frame_with_axis

    rng = np.random.default_rng(2)
    t, z = rng.uniform(0, 2 * np.pi, 120), rng.uniform(-3, 3, 120)
    r = 10 + 0.01 * np.cos(3 * t + 1) + 0.004 * np.cos(2 * t) * z / 3 + 0.002 * rng.standard_normal(120)
    rot = rotation(5)
    pts = C3 + np.column_stack([r * np.cos(t), r * np.sin(t), z]) @ rot.T
    res = fc.fit("cylinder", pts, "mcc")
    assert res.residuals.max() == pytest.approx(0.0, abs=1e-12)
    assert res.warnings == ()  # proven by the branch and bound over the directions in the cone
    x = pts - pts.mean(axis=0)
    f = frame_with_axis(rot[:, 2])
    best = np.inf
    for a in np.radians([0.0, 0.25, 0.5, 1.0, 2.0, 4.0]):
        for b in np.linspace(0, 2 * np.pi, 12 if a else 1, endpoint=False):
            u = f @ np.array([np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), np.cos(a)])
            best = min(best, min_enclosing_ball(x @ frame_with_axis(u)[:, :2])[1])
    assert res.radius <= best + 1e-12


@pytest.mark.parametrize("kind,method", [("plane", "ls"), ("plane", "minzone"), ("circle", "mcc"), ("cylinder", "ls"),
                                         ("cylinder", "minzone"), ("sphere", "ls"), ("line", "ls"), ("cone", "ls")])
def test_huge_coordinates_are_refused_as_too_large_not_as_coincident(kind, method):
    rng = np.random.default_rng(1)
    pts = rng.uniform(-10, 10, (40, 3))
    pts[7] = [1e308, 0.0, 0.0]
    with pytest.raises(FitError, match=r"^coordinates too large: point 8 of 40 has a coordinate of 1e\+308 mm"):
        fc.fit(kind, pts, method)
    pts[7] = [0.0, -2e9, 0.0]
    with pytest.raises(FitError, match="coordinates too large"):
        fc.fit(kind, pts, method)


@pytest.mark.parametrize("shape", ["bowed", "two-level"])
def test_flatness_of_a_bowed_or_stepped_plate_by_constraint_generation(shape):
    """A 100 mm plate bowed 5 um (every point on its hull: 5 um from its centre to its corners) or stepped
    h = 5 um at u = 0 (points on both levels along the step and at the far edges: the zone tilts by h / 50 to
    h / sqrt(1 + (h / 50)^2)), found by the constraint-generation LP and equal to one LP over every point."""
    from cmm.metrology import fit_hull

    rng = np.random.default_rng(5)
    uv = np.vstack([rng.uniform(-50, 50, (20_000, 2)), [[0, 0], [50, 50], [-50, 50], [50, -50], [-50, -50]]])
    u, v = uv.T
    h = 0.005
    if shape == "bowed":
        w, answer = h * (1 - (u * u + v * v) / 5000.0), h
    else:
        w = np.where(u > 0, h, 0.0)
        step_edge = np.array([[0.0, -50.0, h], [0.0, 0.0, h], [0.0, 50.0, h], [0.0, -50.0, 0.0], [0.0, 50.0, 0.0]])
        uv, w = np.vstack([uv, step_edge[:, :2]]), np.concatenate([w, step_edge[:, 2]])
        answer = h / np.sqrt(1.0 + (h / 50.0) ** 2)
    q, _ = np.linalg.qr(np.random.default_rng(99).standard_normal((3, 3)))
    pts = np.array([1000.0, -400.0, 300.0]) + np.column_stack([uv, w]) @ q.T
    res = fc.fit("plane", pts, "minzone")
    # within 0.1 nm: the step's zone is as wide for every tilt up to h / 50, and the LP may stop at any of them
    assert res.form == pytest.approx(answer, abs=1e-10) and not res.warnings
    local = np.column_stack([uv, w])
    width, ab, active = fit_hull._vertical_width_lp(local)
    every, ab_all, _ = fit_hull._vertical_width_lp_all(local)
    assert width == pytest.approx(every, abs=1e-12) and len(active) < len(local) / 10  # a small active set


def test_cylinder_mic_refuses_an_arc_as_circles_do():
    data = ka.cylinder(C3, [0.2, 0.3, 0.9], 20.0, m=200, length=40.0, arc_deg=180.0, form=0.01)
    with pytest.raises(FitError, match=r"cover only 1[78]\d degrees around the axis: a maximum inscribed cylinder is "
                                       "not defined"):
        fc.fit("cylinder", data.points, "mic")
    mcc = fc.fit("cylinder", data.points, "mcc")  # defined (the smallest holding them) but not proven: said
    assert mcc.radius < 1e3 and any("not proven" in w for w in mcc.warnings)


@pytest.mark.parametrize("method", ["mcc", "mic", "minzone"])
def test_a_full_40_mm_cylinder_is_proven_without_a_warning(method):
    data = ka.cylinder(C3, [0.2, 0.3, 0.9], 20.0, m=300, length=40.0, form=0.01)
    res = fc.fit("cylinder", data.points, method)
    assert res.warnings == ()
    assert np.degrees(np.arccos(abs(res.direction @ data.answer["direction"]))) < 0.1


@pytest.mark.parametrize("length", [2.0, 4.0])
def test_short_cylinder_mcc_stays_the_probed_feature(length):
    """Two rings of radius 20 (D 40) 2-4 mm apart, exact: tilted 78-85 deg a smaller cylinder passes through
    them, which is not the probed feature. The search keeps to atan(length / diameter) around the LS axis,
    where the rings' own cylinder (radius 20, the LS axis) is the proven minimum."""
    t = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    ring0 = np.column_stack([20 * np.cos(t), 20 * np.sin(t)])
    rot = rotation(7)
    pts = C3 + np.vstack([np.column_stack([ring0, np.full(24, z)]) for z in (-length / 2, length / 2)]) @ rot.T
    res = fc.fit("cylinder", pts, "mcc")
    assert res.radius == pytest.approx(20.0, abs=1e-9) and res.warnings == ()
    assert np.degrees(np.arccos(min(1.0, abs(res.direction @ rot[:, 2])))) < 1e-4
    assert fc.cone_deg(length, 40.0) == pytest.approx(np.degrees(np.arctan(length / 40.0)))
