"""Probe qualification and the ISO 10360-5 test on the simulated CMM (3-lobed pre-travel, 2 um counts)."""

import numpy as np
import pytest

from cmm.calibration.iso10360 import evaluate, iso25_pattern, run_iso10360_5
from cmm.calibration.probe import analyse_qualification, qualification_pattern, qualify_probe
from cmm.calibration.records import CalibrationError, SphereCertificate

CERT = SphereCertificate("reference sphere", 25.0, 0.0002, 0.0001, approx_centre=(400.3, 299.7, 100.2))


def test_patterns():
    d = iso25_pattern()
    assert d.shape == (25, 3) and np.allclose(np.linalg.norm(d, axis=1), 1)
    polar = np.round(np.degrees(np.arccos(d[:, 2])), 3)
    assert [int((polar == p).sum()) for p in (0, 22.5, 45, 67.5, 90)] == [1, 4, 8, 4, 8]
    assert qualification_pattern().shape == (73, 3)


def test_qualification_recovers_the_3_lobed_pretravel_and_the_iso_form_drops_below_1um(sim_machine):
    sim, m, _ = sim_machine
    calls = []
    q = qualify_probe(m, CERT, repeats=2, progress=lambda f, s: calls.append((f, s)))
    assert calls and calls[-1][0] == 1.0 and all(0 <= f <= 1 for f, _ in calls)
    p = sim.settings.probe
    coef = q.settings.pretravel.coefficients
    assert coef["s2_cos3"] == pytest.approx(p.pretravel_lobe, abs=0.0004)  # 1.5 um lobe
    assert abs(coef["s2_sin3"]) < 0.0004
    assert np.linalg.norm(q.centre - np.array(sim.settings.sphere_centre)) < 0.002
    # r_eff = r - mean pre-travel (about 3..4 um here, plus the latch of one servo tick)
    assert 0.994 < q.record.tip_radius < 0.9985
    assert q.record.form_after_um < q.record.form_before_um
    # ISO 10360-5 pattern, each point the mean of dithered hits (single hits are count-quantised)
    iso = run_iso10360_5(m, CERT, q.settings, repeats=16)
    assert iso.figures["calibrated"].form_um < 1.0
    assert iso.figures["calibrated"].form_um < iso.figures["radius only"].form_um - 1.0
    assert abs(iso.figures["calibrated"].size_um) < 2.0
    assert abs(iso.figures["uncalibrated"].size_um) > 5.0  # nominal radius: the pre-travel shows as size


def test_sphere_not_where_expected_stops_with_a_clear_message(sim_machine):
    _, m, _ = sim_machine
    cert = SphereCertificate("reference sphere", 25.0, approx_centre=(250.0, 350.0, 150.0))
    with pytest.raises(CalibrationError, match="sphere was not found near"):
        qualify_probe(m, cert, repeats=1, per_ring=4, polar_deg=(45.0, 90.0))


def test_too_few_points_and_a_wrong_artifact_are_refused():
    n = qualification_pattern((45.0,), 6)
    t = np.array([400, 300, 100]) + 13.5 * n
    with pytest.raises(CalibrationError, match="only 7 valid points"):
        analyse_qualification(t, -n, CERT, nominal_tip_radius=1.0)
    n = qualification_pattern((45.0, 90.0), 8)
    with pytest.raises(CalibrationError, match="wrong artifact"):
        analyse_qualification(np.array([400, 300, 100]) + 20.0 * n, -n, CERT, nominal_tip_radius=1.0)


def test_analysis_on_synthetic_centres_follows_the_convention():
    """T = C + delta(u) u with a 3-lobed delta: r_eff = r - mean delta, the model holds the rest with zero mean."""
    n = qualification_pattern()
    u = -n
    s2 = 1 - n[:, 2] ** 2
    phi = np.arctan2(u[:, 1], u[:, 0])
    delta = s2 * (0.004 + 0.0015 * np.cos(3 * phi)) + (1 - s2) * 0.002
    c = np.array([400.0, 300.0, 100.0])
    t = c + 13.5 * n + delta[:, None] * u
    q = analyse_qualification(t, u, CERT, nominal_tip_radius=1.0)
    assert q.record.form_after_um < 1e-6
    assert np.mean(q.settings.pretravel(u)) == pytest.approx(0, abs=1e-12)
    assert q.record.tip_radius == pytest.approx(1.0 - np.mean(delta), abs=1e-9)
    assert q.settings.pretravel.coefficients["s2_cos3"] == pytest.approx(0.0015, abs=1e-9)
    n25 = iso25_pattern()
    s2 = 1 - n25[:, 2] ** 2
    phi = np.arctan2(-n25[:, 1], -n25[:, 0])
    d25 = s2 * (0.004 + 0.0015 * np.cos(3 * phi)) + (1 - s2) * 0.002
    fig = evaluate(c + 13.5 * n25 - d25[:, None] * n25, -n25, q.settings, 25.0)
    assert fig.form_um < 0.01
    assert abs(fig.size_um) < 0.5  # the zero mean is over the qualification pattern, not this one
