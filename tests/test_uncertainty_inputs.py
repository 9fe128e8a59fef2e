"""The uncertainty budget's inputs from the station's own data: the probe qualification record (its radius's
uncertainty, the uncertainties of the directional pre-travel coefficients the compensation applies, the single-hit
scatter), the geometry calibration record or the configured MPE, the configured and the session's temperature;
each term says where its input came from. And the budget is no wider than the errors it covers: on the
simulator's error model, with the station's own qualification, U / spread of a bore's diameter is at most about 3
(it was 5.2 with the uncorrected Z/XY pre-travel difference counted as an uncertainty)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from cmm.calibration.probe import analyse_qualification, qualification_pattern
from cmm.calibration.records import MachineRecord, ProbeRecord, SphereCertificate, load_probe_record, save_record
from cmm.metrology.fit_ls import fit_cylinder
from cmm.metrology.uncertainty import Sources, budget
from cmm.metrology.uncertainty_inputs import probe_sources, station_sources

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


def _bore(n_per_ring=4):
    a = np.arange(n_per_ring) * 2 * np.pi / n_per_ring
    rings = [np.c_[30 + 15 * np.cos(a + t), 40 + 15 * np.sin(a + t), np.full(n_per_ring, z)]
             for z, t in ((8.0, 0.0), (32.0, np.pi / 4))]
    return np.vstack(rings)


def _record(**kw):
    base = dict(date="2026-11-28T10:00:00+00:00", artifact="sphere D25", tip_radius=0.997,
                pretravel={"const": 0.0007, "z2": -0.002, "s2_cos3": 0.0015, "s2_sin3": 0.0},
                nominal_tip_radius=1.0, sphere_centre=(400.0, 300.0, 100.0), uncertainty_um=0.3,
                pretravel_u_um={"z2": 0.09, "s2_cos3": 0.04, "s2_sin3": 0.04}, hit_sigma_um=0.25,
                pretravel_mean={"z2": 0.33, "s2_cos3": 0.0, "s2_sin3": 0.0})
    base.update(kw)
    return ProbeRecord(**base)


def _terms(b):
    return {t.source: t for t in b.terms}


def test_a_qualified_probe_leaves_what_its_record_says_known_answer():
    """Hits compensated by the record's directional model: no Z/XY and lobing terms of an uncompensated probe;
    the model's own uncertainty reaches horizontal hits as -mean(z2) x u(z2): a bore's diameter moves by twice."""
    pts = _bore()
    fit = fit_cylinder(pts, nominal={"direction": [0, 0, 1.0], "point": [30, 40, 0.0], "radius": 15.0})
    src = probe_sources(_record(), Sources(mpe_k=1e12, temperature_allowance=0.0, cte_u=0.0, form_prior=0.0))
    b = budget("cylinder", pts, fit, src)
    t = _terms(b)
    assert "probe Z/XY" not in t and "probe lobing" not in t
    # 4 hits per ring at 90 deg: the 3-lobed terms do not reach the diameter; z2 does, by 2 x 0.33 x 0.09 um
    assert t["probe direction"].u["diameter"] == pytest.approx(2 * 0.33 * 0.00009, rel=1e-4)
    assert t["probe qualification"].u["diameter"] == pytest.approx(2 * 0.00015, rel=1e-4)
    assert t["scatter"].note.startswith("repeatability 0.25 um")
    assert t["probe direction"].origin == "probe record 2026-11-28"
    # the old budget (nominal probe figures) had 2 um of Z/XY on this diameter alone
    old = _terms(budget("cylinder", pts, fit, Sources()))
    assert old["probe Z/XY"].u["diameter"] == pytest.approx(0.002, rel=1e-3)


def test_qualification_records_the_uncertainty_of_its_directional_model(tmp_path):
    rng = np.random.default_rng(4)
    n = qualification_pattern((35.0, 80.0, 120.0), 24)
    s2 = 1 - n[:, 2] ** 2
    phi = np.arctan2(-n[:, 1], -n[:, 0])
    depth = s2 * (0.004 + 0.0015 * np.cos(3 * phi)) + (1 - s2) * 0.002 + rng.normal(0, 0.0003, len(n))
    t = np.array([400, 300, 100.0]) + (13.5 - depth)[:, None] * n
    rec = analyse_qualification(t, -n, SphereCertificate("s", 25.0, uncertainty=0.0002), nominal_tip_radius=1.0).record
    assert set(rec.pretravel_u_um) == {"z2", "s2_cos3", "s2_sin3"}
    # 73 points with 0.3 um noise: each coefficient known to a few tenths of the noise
    assert all(0.01 < v < 0.3 for v in rec.pretravel_u_um.values()), rec.pretravel_u_um
    assert rec.hit_sigma_um == pytest.approx(0.3, rel=0.3)
    assert rec.pretravel_mean["z2"] == pytest.approx(np.mean(n[:, 2] ** 2), rel=1e-9)
    back = load_probe_record(save_record(rec, tmp_path / "probe.toml"))
    assert back.pretravel_u_um == pytest.approx(rec.pretravel_u_um)
    assert back.pretravel_mean == pytest.approx(rec.pretravel_mean) and back.hit_sigma_um == rec.hit_sigma_um


def test_station_sources_say_where_each_input_came_from(tmp_path):
    from cmm.machine.config import ConfigError, load

    cfg_text = (Path(__file__).resolve().parents[1] / "cmm" / "data" / "machine.toml").read_text()
    path = tmp_path / "m.toml"
    path.write_text(cfg_text + "\n[uncertainty]\nmpe_a_um = 1.5\nmpe_k = 400\ncte = 23e-6\n")
    config = load(path)
    src = station_sources(config, temperature=21.5)
    assert src.mpe_a_um == 1.5 and src.cte == 23e-6 and src.temperature == 21.5
    b = budget("cylinder", _bore(), fit_cylinder(_bore(), nominal={"direction": [0, 0, 1.0], "point": [30, 40, 0.0],
                                                                       "radius": 15.0}), src)
    t = _terms(b)
    assert t["machine scale"].origin == "configuration m.toml: MPE 1.5 + L/400 um"
    assert t["thermal"].origin == "session temperature 21.5 C; configuration m.toml: CTE, allowance"
    assert t["probe Z/XY"].origin == "default"
    # a geometry record and a probe record replace the configured MPE and the nominal probe figures
    machine = MachineRecord("2026-11-27T09:00:00", "ball bar", (1.0, 2.0, 3.0), (4.0, 5.0, 6.0),
                            uncertainty_scale_ppm=0.8, uncertainty_squareness_urad=1.2)
    src = station_sources(config, probe_record=_record(), machine_record=machine,
                          probing_test={"size_um": 0.6, "form_um": 1.0})
    assert src.machine_scale_u() == pytest.approx(0.4e-6) and src.machine_squareness_u() == pytest.approx(0.6e-6)
    assert src.u_tip == pytest.approx(math.sqrt(0.00015 ** 2 + 0.0003 ** 2 / 3))
    text = budget("plane", np.array([[0, 0, 0], [50, 0, 0], [50, 40, 0], [0, 40, 0.0]]), None, src).text()
    assert "geometry record 2026-11-27" in text and "probe record 2026-11-28, ISO 10360-5 P_Size +0.60 um" in text
    # a wrong [uncertainty] table is refused when the configuration loads, in a sentence
    path.write_text(cfg_text + "\n[uncertainty]\nmpe_kk = 400\n")
    with pytest.raises(ConfigError, match=r"\[uncertainty.mpe_kk\] is not a known setting"):
        load(path)


def test_budget_inputs_travel_with_the_budget():
    src = probe_sources(_record(), Sources(reference=(1.0, 2.0, 3.0)))
    b = budget("plane", np.array([[0, 0, 0], [50, 0, 0], [50, 40, 0], [0, 40, 0.0]]), None, src)
    again = Sources.from_dict(b.summary()["inputs"])
    assert again == src


def test_bore_uncertainty_is_honest_on_the_simulator_error_model():
    """The bench's error model with the station's qualification per trial and a part whose form is the budget's
    prior (1 um): the bore's diameter and centre are covered and U is no wider than about 3 spreads."""
    from bench_uncertainty import run

    res = run(30, seed=5, verbose=False, features=("bore",), form=0.001)
    for name in ("diameter", "x", "y"):
        r = res["bore"][name]
        assert r["worst"] <= 2.0, (name, r)
        assert r["coverage"] >= 27 / 30, (name, r)  # a 95 % interval: 1.5 misses expected in 30
        assert 1.4 <= r["U_over_spread"] <= 3.5, (name, r)


def test_station_fit_uses_the_records_in_force(tmp_path):
    """On the simulated station with a probe record and a geometry record applied: the bore's budget names them,
    keeps its inputs, and its diameter U is no longer dominated by the uncompensated Z/XY difference."""
    import session_support as sup
    from cmm.calibration.records import LoadedCalibration

    gen = sup.sim_station(tmp_path, "inputs")
    station = next(gen)
    try:
        s = station.prober.settings
        rec = _record(tip_radius=s.tip_radius, pretravel=dict(s.pretravel.coefficients))
        machine = MachineRecord("2026-11-27T09:00:00", "ball bar", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                                uncertainty_scale_ppm=0.8, uncertainty_squareness_urad=1.2)
        station.calibration.apply(LoadedCalibration(probe=rec, machine=machine))
        m = station.measurement
        m.set_info(temperature=20.5)
        ids = []
        for p in _bore() + [190.0, 150.0, 0.0]:
            n = np.r_[p[:2] - [220.0, 190.0], 0.0]
            n /= np.linalg.norm(n)
            hit = m.probe(p, n, clearance_z=70.0).wait()
            ids.append(m.hit_id(hit))
        f = m.fit_feature("cylinder", ids)
        origins = {t["source"]: t["from"] for t in f.budget["terms"]}
        assert origins["probe qualification"] == "probe record 2026-11-28"
        assert origins["machine scale"] == "geometry record 2026-11-27"
        assert origins["thermal"].startswith("session temperature 20.5 C")
        assert f.budget["inputs"]["u_tip"] == pytest.approx(0.00015)
        assert f.budget["U"]["diameter"] < 0.003
    finally:
        gen.close()


def test_form_values_carry_their_uncertainty_known_answer():
    """The form (max - min residual) moves with its two extreme hits' residuals after the refit: each hit's scatter
    through the residuals' projection R = I - H (var = sigma^2 (R_aa + R_bb - 2 R_ab), not 2 sigma^2), what the fit
    absorbs (tip radius, a plane's affine errors) cancels, a circle's anisotropic scale does not (an ellipse). U is
    the 95.45 % quantile of the range of the residuals' errors, which bounds the form's error."""
    from cmm.metrology.characteristics import characteristics
    from cmm.metrology.fit_ls import fit_circle, fit_plane
    from cmm.metrology.uncertainty import COVERAGE, characteristic_u

    plane = np.array([[0, 0, 0], [50, 0, 0], [50, 40, 0], [0, 40, 0.0], [25, 20, 0.004]])
    src = Sources(repeatability=0.00025, lobing=0.0015, z_xy=0.001)
    b = budget("plane", plane, fit_plane(plane), src)
    assert b.values["form"] == pytest.approx(fit_plane(plane).form)
    # an independent propagation: the plane z = a + b x + c y fitted by linear least squares
    design = np.c_[np.ones(5), plane[:, :2]]
    proj = np.eye(5) - design @ np.linalg.pinv(design)
    resid = proj @ plane[:, 2]
    a, lo = int(np.argmax(resid)), int(np.argmin(resid))
    u_lin = 0.00025 * math.sqrt(proj[a, a] + proj[lo, lo] - 2 * proj[a, lo])
    assert u_lin < 0.9 * math.sqrt(2) * 0.00025  # the old two-hit propagation (sqrt 2 sigma) overstated it
    assert b.combined()["form"] == pytest.approx(u_lin, rel=1e-4)  # all normals along Z: lobing, Z/XY cancel
    ranges = np.ptp(np.random.default_rng(7).normal(0, 0.00025, (40000, 5)) @ proj, axis=1)
    assert b.expanded()["form"] == pytest.approx(float(np.quantile(ranges, COVERAGE)), rel=0.03)
    assert characteristic_u("flatness", b.expanded()) == b.expanded()["form"]
    # a circle: out at 0 deg, in at 60 deg: the 3-lobed pattern differs by 2 there (cos 0 - cos 180)
    ang = np.radians(np.arange(0, 360, 30))
    r = 10 + np.where(np.isclose(ang, 0), 0.003, 0) + np.where(np.isclose(ang, np.radians(60)), -0.003, 0)
    circle = np.c_[r * np.cos(ang), r * np.sin(ang), np.zeros_like(ang)]
    fit = fit_circle(circle)
    b = budget("circle", circle, fit, src)
    t = _terms(b)
    assert t["probe lobing"].u["form"] == pytest.approx(0.0015 / math.sqrt(2) * 2, rel=1e-3)
    assert t["probe qualification"].u["form"] == pytest.approx(0.0, abs=1e-9)  # the radius takes it
    # an x (y) scale error s makes an ellipse: residuals r s cos 2phi / 2 (- ...): 3/4 r s between 0 and 60 deg
    assert t["machine scale"].u["form"] == pytest.approx(math.sqrt(2) * 0.75 * 10 * src.machine_scale_u(), rel=2e-2)
    # the feature's characteristics: roundness with its U
    chars = characteristics("c", "circle", {**fit.summary(), "form": fit.form}, None)
    roundness = next(c for c in chars if c.name == "roundness")
    assert characteristic_u(roundness.name, b.expanded()) == pytest.approx(b.expanded()["form"])


def test_the_probing_test_run_after_the_qualification_is_loaded_with_the_records(tmp_path):
    from cmm.calibration.records import load_station_calibration

    save_record(_record(), tmp_path / "probe.toml")
    iso = "[record]\nkind = 'iso10360-5'\ndate = '{}'\n[results.calibrated]\nform_um = 1.1\nsize_um = -0.4\n"
    (tmp_path / "iso10360-5.toml").write_text(iso.format("2026-11-28T11:00:00+00:00"))
    loaded = load_station_calibration(tmp_path)
    assert loaded.probing_test == {"date": "2026-11-28T11:00:00+00:00", "form_um": 1.1, "size_um": -0.4}
    # a test from before the qualification in force says nothing about it
    (tmp_path / "iso10360-5.toml").write_text(iso.format("2026-11-20T11:00:00+00:00"))
    assert load_station_calibration(tmp_path).probing_test is None
