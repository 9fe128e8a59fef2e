"""Least-squares fits against null-space known answers (tests/knownanswer.py)."""

from __future__ import annotations

import numpy as np
import pytest

import knownanswer as ka
from cmm.metrology import fit_ls
from cmm.metrology.features import FitError

TOL = 1e-9  # mm and rad
FAR = np.array([1000.0, -700.0, 650.0])  # 1000 mm class distance from the origin
TILT = np.array([0.3, -0.5, 0.81])


def foot(p, u, q):
    """The location point of an axis feature: the foot of the data centroid q on the axis (p, u)."""
    u = u / np.linalg.norm(u)
    return p + ((q - p) @ u) * u


def assert_dir(u, v):
    """Directions equal up to sign, to TOL rad."""
    assert np.linalg.norm(np.cross(u, v)) < TOL
    assert abs(np.linalg.norm(u) - 1.0) < 1e-14


def assert_stats(res, data):
    e = data.residuals
    dof = e.size - data.n_params
    if dof > 0:
        assert res.sigma == pytest.approx(np.linalg.norm(e) / np.sqrt(dof), rel=1e-6)
    assert res.n_points == len(data.points)
    assert res.covariance.shape == (data.n_params, data.n_params)


OFFSETS = {"origin": np.zeros(3), "far": FAR}


@pytest.mark.parametrize("where", OFFSETS)
@pytest.mark.parametrize("cap", [360.0, 30.0])
def test_sphere(where, cap):
    data = ka.sphere(OFFSETS[where] + [1.0, 2.0, 3.0], 12.5, cap_deg=cap, form=0.004 if cap < 360 else 0.02)
    res = fit_ls.fit_sphere(data.points)
    assert np.abs(res.center - data.answer["center"]).max() < TOL
    assert abs(res.radius - data.answer["radius"]) < TOL
    assert res.diameter == pytest.approx(25.0, abs=2 * TOL)
    assert np.abs(res.residuals - data.residuals).max() < TOL
    assert res.form == pytest.approx(data.residuals.max() - data.residuals.min(), abs=TOL)
    assert_stats(res, data)


@pytest.mark.parametrize("where", OFFSETS)
def test_plane(where):
    data = ka.plane(OFFSETS[where] + [5.0, 0.0, 1.0], TILT)
    res = fit_ls.fit_plane(data.points)
    assert_dir(res.normal, data.answer["normal"])
    assert abs((res.point - data.answer["point"]) @ res.normal) < TOL
    assert res.normal[np.argmax(np.abs(res.normal))] > 0  # canonical sign
    assert np.abs(np.abs(res.residuals) - np.abs(data.residuals)).max() < TOL
    assert_stats(res, data)


@pytest.mark.parametrize("where", OFFSETS)
def test_line(where):
    data = ka.line(OFFSETS[where], TILT)
    res = fit_ls.fit_line(data.points)
    assert_dir(res.direction, data.answer["direction"])
    assert np.abs(res.point - foot(data.answer["point"], res.direction, data.points.mean(axis=0))).max() < TOL
    assert np.abs(res.point - data.points.mean(axis=0)).max() < TOL  # the LS line passes through the centroid
    dist = np.hypot(*data.residuals.reshape(2, -1))
    assert np.abs(res.residuals - dist).max() < TOL
    assert res.form == pytest.approx(2 * dist.max(), abs=TOL)
    assert_stats(res, data)


@pytest.mark.parametrize("where", OFFSETS)
@pytest.mark.parametrize("arc", [360.0, 30.0])
def test_circle_2d(where, arc):
    data = ka.circle2d(OFFSETS[where][:2] + [3.0, -4.0], 20.0, arc_deg=arc, form=0.002 if arc < 360 else 0.01)
    res = fit_ls.fit_circle_2d(data.points)
    assert np.abs(res.center - data.answer["center"]).max() < TOL
    assert abs(res.radius - 20.0) < TOL
    assert np.abs(res.residuals - data.residuals).max() < TOL
    assert_stats(res, data)


@pytest.mark.parametrize("where", OFFSETS)
@pytest.mark.parametrize("arc", [360.0, 30.0])
def test_circle_3d_standard(where, arc):
    """Default 3D circle: least-squares plane, then the 2D least-squares circle in it."""
    data = ka.circle3d_standard(OFFSETS[where] + [1.0, 1.0, 1.0], TILT, 20.0, arc_deg=arc,
                                form=0.002 if arc < 360 else 0.01)
    res = fit_ls.fit_circle(data.points)
    assert np.abs(res.center - data.answer["center"]).max() < TOL
    assert_dir(res.normal, data.answer["normal"])
    assert abs(res.radius - 20.0) < TOL
    m = len(data.points)
    assert np.abs(res.plane_residuals - data.residuals[:m] * np.sign(res.normal @ data.answer["normal"])).max() < TOL
    assert np.abs(res.residuals - data.residuals[m:]).max() < TOL
    assert_stats(res, data)
    # the 3D-distance circle is a different estimate on the same data
    if arc < 360:
        other = fit_ls.fit_circle_3d_distance(data.points)
        assert np.linalg.norm(other.center - res.center) > 1e-6


@pytest.mark.parametrize("where", OFFSETS)
@pytest.mark.parametrize("arc", [360.0, 30.0])
def test_circle_3d_distance_option(where, arc):
    data = ka.circle3d(OFFSETS[where] + [1.0, 1.0, 1.0], TILT, 20.0, arc_deg=arc, form=0.002 if arc < 360 else 0.01)
    res = fit_ls.fit_circle_3d_distance(data.points)
    assert np.abs(res.center - data.answer["center"]).max() < TOL
    assert_dir(res.normal, data.answer["normal"])
    assert abs(res.radius - 20.0) < TOL
    m = len(data.points)
    sign = np.sign(res.normal @ data.answer["normal"])
    assert np.abs(res.plane_residuals - sign * data.residuals[:m]).max() < TOL
    assert np.abs(res.residuals - data.residuals[m:]).max() < TOL
    assert_stats(res, data)


@pytest.mark.parametrize("where", OFFSETS)
@pytest.mark.parametrize("arc", [360.0, 30.0])
def test_cylinder(where, arc):
    data = ka.cylinder(OFFSETS[where] + [2.0, 0.0, 0.0], TILT, 8.0, length=60.0 if arc < 360 else 40.0,
                       arc_deg=arc, form=0.002 if arc < 360 else 0.01)
    res = fit_ls.fit_cylinder(data.points)
    assert_dir(res.direction, data.answer["direction"])
    assert np.abs(res.point - foot(data.answer["point"], res.direction, data.points.mean(axis=0))).max() < TOL
    assert abs(res.radius - 8.0) < TOL
    assert np.abs(res.residuals - data.residuals).max() < TOL
    assert_stats(res, data)


def test_short_cylinder_ring_uses_plane_normal_start():
    data = ka.cylinder(FAR, TILT, 30.0, length=3.0, m=40)
    res = fit_ls.fit_cylinder(data.points)
    assert_dir(res.direction, data.answer["direction"])
    assert abs(res.radius - 30.0) < TOL


@pytest.mark.parametrize("where", OFFSETS)
def test_cone(where):
    data = ka.cone(OFFSETS[where] + [0.0, 3.0, 0.0], TILT, np.radians(20.0))
    res = fit_ls.fit_cone(data.points)
    assert np.abs(res.apex - data.answer["apex"]).max() < TOL
    assert np.linalg.norm(res.direction - data.answer["direction"]) < TOL  # oriented: apex into the cone
    assert abs(res.half_angle - data.answer["half_angle"]) < TOL
    assert res.half_angle_deg == pytest.approx(20.0, abs=1e-7)
    assert np.abs(res.residuals - data.residuals).max() < TOL
    assert_stats(res, data)


def test_cone_partial_arc_with_nominal():
    data = ka.cone(FAR, TILT, np.radians(30.0), arc_deg=60.0, form=0.002)
    nominal = {"apex": data.answer["apex"] + 0.3, "direction": data.answer["direction"] + [0.02, 0, 0],
               "half_angle_deg": 29.0}
    res = fit_ls.fit_cone(data.points, nominal=nominal)
    assert np.abs(res.apex - data.answer["apex"]).max() < TOL
    assert abs(res.half_angle - data.answer["half_angle"]) < TOL


@pytest.mark.parametrize("where", OFFSETS)
def test_torus(where):
    data = ka.torus(OFFSETS[where], TILT, 25.0, 4.0)
    res = fit_ls.fit_torus(data.points)
    assert np.abs(res.center - data.answer["center"]).max() < TOL
    assert_dir(res.normal, data.answer["normal"])
    assert abs(res.major_radius - 25.0) < TOL and abs(res.minor_radius - 4.0) < TOL
    assert np.abs(res.residuals - data.residuals).max() < TOL
    assert_stats(res, data)


def test_nominal_start_is_used_for_cylinder():
    data = ka.cylinder(FAR, TILT, 8.0, arc_deg=90.0, form=0.001)
    nominal = {"point": data.answer["point"] + 0.2, "direction": data.answer["direction"], "radius": 8.1}
    res = fit_ls.fit_cylinder(data.points, nominal=nominal)
    assert abs(res.radius - 8.0) < TOL


# ---------------------------------------------------------------- refusals

@pytest.mark.parametrize(
    "fit, m, words",
    [
        (fit_ls.fit_line, 1, "a line needs at least 2 points, got 1"),
        (fit_ls.fit_plane, 2, "a plane needs at least 3 points, got 2"),
        (fit_ls.fit_circle, 2, "a circle needs at least 3 points, got 2"),
        (fit_ls.fit_sphere, 3, "a sphere needs at least 4 points, got 3"),
        (fit_ls.fit_cylinder, 4, "a cylinder needs at least 5 points, got 4"),
        (fit_ls.fit_cone, 5, "a cone needs at least 6 points, got 5"),
        (fit_ls.fit_torus, 6, "a torus needs at least 7 points, got 6"),
    ],
)
def test_too_few_points(fit, m, words):
    pts = np.random.default_rng(0).random((m, 3))
    with pytest.raises(FitError, match=words):
        fit(pts)


def test_nan_refused():
    pts = np.random.default_rng(0).random((10, 3))
    pts[4, 1] = np.nan
    with pytest.raises(FitError, match="point 5 of 10 has a NaN"):
        fit_ls.fit_sphere(pts)


def test_collinear_plane_and_circle_refused():
    pts = np.outer(np.linspace(0, 1, 6), [1.0, 2.0, 3.0]) + 1000.0
    for fit in (fit_ls.fit_plane, fit_ls.fit_circle):
        with pytest.raises(FitError, match="collinear"):
            fit(pts)


def test_coplanar_sphere_cylinder_cone_refused():
    t = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    pts = np.column_stack([10 * np.cos(t), 10 * np.sin(t), np.zeros_like(t)])
    for fit in (fit_ls.fit_sphere, fit_ls.fit_cylinder, fit_ls.fit_cone):
        with pytest.raises(FitError, match="coplanar"):
            fit(pts)


def test_coincident_points_refused():
    with pytest.raises(FitError, match="coincide"):
        fit_ls.fit_line(np.ones((5, 3)))


def test_exact_fit_has_undefined_sigma():
    res = fit_ls.fit_circle(np.array([[10.0, 0, 0], [0, 10.0, 0], [-10.0, 0, 0]]))
    assert res.radius == pytest.approx(10.0, abs=1e-12)
    assert np.isnan(res.sigma)
    assert res.summary()["sigma"] is None


# ---------------------------------------------------------------- short arcs, sparse partial features


@pytest.mark.parametrize("m", [10, 1000, 100_000])
def test_circle_10_degree_arc_large_residuals(m):
    """A 10 degree arc with +-0.2 mm residuals: convergence judged on the step, not the flat cost."""
    data = ka.circle3d_standard(FAR, TILT, 50.0, m=m, arc_deg=10.0, form=0.4, plane_form=0.02, seed=1)
    res = fit_ls.fit_circle(data.points)
    assert np.abs(res.center - data.answer["center"]).max() < TOL
    assert_dir(res.normal, data.answer["normal"])
    assert abs(res.radius - 50.0) < TOL
    assert any("poorly" in w for w in res.warnings)  # a 10 degree arc does not fix the circle well


@pytest.mark.parametrize("radius, seed", [(20.0, 5), (50.0, 8), (100.0, 4), (100.0, 15)])
def test_circle_10_points_10_degree_arc_flat_cost(radius, seed):
    """Cases where the cost is flat to 1e-13 while the centre is still 1e-6 mm off."""
    data = ka.circle3d_standard(FAR, TILT, radius, m=10, arc_deg=10.0, form=0.4, plane_form=0.02, seed=seed)
    res = fit_ls.fit_circle(data.points)
    assert np.abs(res.center - data.answer["center"]).max() < TOL and abs(res.radius - radius) < TOL


@pytest.mark.parametrize("m", [10, 1000])
def test_circle_2d_10_degree_arc(m):
    data = ka.circle2d(FAR[:2], 50.0, m=m, arc_deg=10.0, form=0.4, seed=2)
    res = fit_ls.fit_circle_2d(data.points)
    assert np.abs(res.center - data.answer["center"]).max() < TOL and abs(res.radius - 50.0) < TOL


def test_cylinder_10_degree_arc():
    data = ka.cylinder(FAR, TILT, 50.0, m=1000, length=40.0, arc_deg=10.0, form=0.4, seed=0)
    res = fit_ls.fit_cylinder(data.points)
    assert_dir(res.direction, data.answer["direction"])
    assert np.abs(res.point - foot(data.answer["point"], res.direction, data.points.mean(axis=0))).max() < TOL
    assert abs(res.radius - 50.0) < TOL


def _cost(res):
    return float(np.sum(res.residuals**2))


@pytest.mark.parametrize("seed", [4, 8, 12, 14, 18])
def test_sparse_partial_cone_global_or_warned(seed):
    """10 points on a 30 degree arc of a cone: the known answer (or a better fit) or a warning."""
    data = ka.cone(FAR, TILT, np.radians(20.0), m=10, arc_deg=30.0, form=0.01, seed=seed)
    res = fit_ls.fit_cone(data.points)
    ok = np.abs(res.apex - data.answer["apex"]).max() < 1e-6 and abs(res.half_angle - data.answer["half_angle"]) < 1e-9
    better = _cost(res) < np.sum(data.residuals**2) * (1 - 1e-9)
    assert ok or better or any("clearly different" in w for w in res.warnings)
    assert _cost(res) <= np.sum(data.residuals**2) * 1.01  # never a bad local minimum (was 3-218x)


@pytest.mark.parametrize("seed", [0, 1])
def test_sparse_partial_cylinder_reaches_known_answer(seed):
    data = ka.cylinder(FAR, TILT, 50.0, m=10, length=40.0, arc_deg=30.0, form=0.1, seed=seed)
    res = fit_ls.fit_cylinder(data.points)
    assert abs(res.radius - 50.0) < 1e-8
    assert np.linalg.norm(np.cross(res.direction, data.answer["direction"])) < 1e-10


def test_nominal_far_from_the_best_fit_is_flagged():
    data = ka.cylinder(FAR, TILT, 50.0, m=10, length=40.0, arc_deg=30.0, form=0.01, seed=0)
    wrong = {"point": data.answer["point"] + [0.0, 60.0, 0.0], "direction": [1.0, 0.0, 0.0], "radius": 20.0}
    res = fit_ls.fit_cylinder(data.points, nominal=wrong)
    # the minimum near the nominal is reported; the global optimum far from it is kept for the operator's check
    assert abs(res.radius - 50.0) > 1.0 and res.check
    assert abs(res.alternative.radius - 50.0) < 1e-8
    assert np.linalg.norm(np.cross(res.alternative.direction, data.answer["direction"])) < 1e-10
    assert res.warnings[0].startswith("check: a different cylinder fits the hits better")
    assert "alternative" in res.summary() and res.summary()["alternative"]["radius"] == pytest.approx(50.0)
    # the nominal near the true cylinder: no check
    good = fit_ls.fit_cylinder(data.points, nominal={"point": data.answer["point"], "direction": TILT})
    assert abs(good.radius - 50.0) < 1e-8 and not good.check and good.warnings == res.alternative.warnings


def test_two_rings_at_the_same_angles_lie_on_a_cylinder_across_the_axis():
    """Two rings of four hits at the same angles (z = +-3, radii 10.01 and 9.99): a cylinder along y fits them
    exactly (axis at z0 = (10.01^2 - 9.99^2) / 24, radius sqrt(10.01^2 / 2 + (3 - z0)^2)); the nominal's
    vertical cylinder fits with residuals +-0.01 at radius 10. With the nominal, the vertical one is reported
    and the exact one across the axis is kept as the alternative to check; without one, the best fit wins."""
    pts = np.array([[r * np.cos(a), r * np.sin(a), z] for z, r in ((3.0, 10.01), (-3.0, 9.99))
                    for a in np.radians([45, 135, 225, 315])]) + FAR
    z0 = (10.01**2 - 9.99**2) / 24.0
    across = np.sqrt(10.01**2 / 2 + (3.0 - z0) ** 2)
    res = fit_ls.fit_cylinder(pts, nominal={"point": FAR, "direction": [0, 0, 1.0]})
    assert abs(res.radius - 10.0) < 1e-9 and abs(res.direction[2]) == pytest.approx(1.0, abs=1e-12)
    assert np.abs(res.point - FAR).max() < 1e-9  # the foot of the data centroid on the axis
    assert np.abs(res.residuals).max() == pytest.approx(0.01, rel=1e-6)
    alt = res.alternative
    assert res.check and alt.radius == pytest.approx(across, abs=1e-9) and abs(alt.direction[2]) < 1e-9
    assert alt.point[2] == pytest.approx(FAR[2] + z0, abs=1e-9) and np.abs(alt.residuals).max() < 1e-9
    best = fit_ls.fit_cylinder(pts)
    assert best.radius == pytest.approx(across, abs=1e-9) and not best.check


# ---------------------------------------------------------------- uncertainties and conditioning


def test_uncertainty_matches_monte_carlo():
    """Reported u(radius), u(center) agree with the scatter of repeated fits to noisy data."""
    rng = np.random.default_rng(7)
    t = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    truth = np.column_stack([20 * np.cos(t), 20 * np.sin(t)]) + FAR[:2]
    radii, reported = [], []
    for _ in range(300):
        noisy = truth + 0.002 * rng.standard_normal(truth.shape)
        res = fit_ls.fit_circle_2d(noisy)
        radii.append(res.radius)
        reported.append(res.uncertainty["radius"])
    assert np.std(radii) == pytest.approx(np.mean(reported), rel=0.15)
    assert np.mean(reported) == pytest.approx(0.002 / np.sqrt(24), rel=0.15)  # radius of a full ring


def test_uncertainty_from_covariance_in_summary():
    data = ka.sphere(FAR, 12.5, m=60, form=0.01)
    res = fit_ls.fit_sphere(data.points)
    cov = res.covariance
    assert res.uncertainty["radius"] == pytest.approx(np.sqrt(cov[3, 3]), rel=1e-12)
    assert res.uncertainty["center"] == pytest.approx(np.sqrt(np.trace(cov[:3, :3])), rel=1e-12)
    assert res.uncertainty["diameter"] == pytest.approx(2 * res.uncertainty["radius"])
    s = res.summary()
    assert s["uncertainty"]["radius"] == res.uncertainty["radius"] and s["warnings"] == []


def test_small_cap_sphere_warns():
    """1 degree cap, 1 um noise: the radius is meaningless and the fit says so."""
    rng = np.random.default_rng(1)
    polar, az = np.radians(0.5) * np.sqrt(rng.random(200)), rng.uniform(0, 2 * np.pi, 200)
    n = np.column_stack([np.sin(polar) * np.cos(az), np.sin(polar) * np.sin(az), np.cos(polar)])
    pts = FAR + (10.0 + 0.001 * rng.standard_normal(200))[:, None] * n
    res = fit_ls.fit_sphere(pts)
    assert any("sphere's center and radius poorly" in w for w in res.warnings)
    assert res.uncertainty["radius"] > 0.5  # honest: several tenths of a mm at least
    full = fit_ls.fit_sphere(ka.sphere(FAR, 10.0, m=60, form=0.002).points)
    assert full.warnings == ()


def test_cone_on_cylinder_data_warns():
    data = ka.cylinder(FAR, TILT, 8.0, m=60, length=40.0)
    res = fit_ls.fit_cone(data.points)
    assert any("nearly a cylinder" in w for w in res.warnings)
    assert res.uncertainty["apex"] > 100.0
    good = fit_ls.fit_cone(ka.cone(FAR, TILT, np.radians(20.0)).points)
    assert good.warnings == () and good.uncertainty["apex"] < 0.1
