"""Machine geometry from a ball bar: the fit on synthetic data and the routine on the simulator."""

import numpy as np
import pytest

from cmm.calibration.geometry import BarMeasurement, calibrate_geometry, default_setups, fit_geometry
from cmm.calibration.records import BallBarCertificate, CalibrationError
from cmm.machine.geometry import GeometryCorrection, geometry_matrix
from cmm.machine.probing import ProbeSettings
from cmm.metrology.compensation import PretravelModel
from cmm.sim.cmm_sim import CmmSimSettings
from cmm.sim.probe_world import GeometryErrors

CERTS = {"ball_bar_300": BallBarCertificate("ball bar 300", 300.0, 25.0, 0.0005),
         "ball_bar_200": BallBarCertificate("ball bar 200", 200.0, 25.0, 0.0004)}


def synthetic(scale, square, noise=0.0, seed=0):
    m = geometry_matrix(scale, square)
    rng = np.random.default_rng(seed)
    out = []
    for s in default_setups():
        true = np.subtract(s.ball2, s.ball1)  # the bar's true vector
        raw = np.linalg.solve(m, true) + rng.normal(0, noise, 3)
        out.append(BarMeasurement(s.name, CERTS[s.artifact].length, raw, float(np.linalg.norm(raw))))
    return out


def test_fit_recovers_scale_and_squareness_exactly_without_noise():
    corr, res, _, _ = fit_geometry(synthetic((50.0, -20.0, 10.0), (30.0, -15.0, 8.0)))
    assert np.allclose(corr.scale_ppm, (50, -20, 10), atol=1e-3)
    assert np.allclose(corr.squareness_urad, (30, -15, 8), atol=1e-3)
    assert max(abs(v) for v in res.values()) < 1e-3


def test_fit_needs_enough_setups():
    with pytest.raises(CalibrationError, match="at least 6"):
        fit_geometry(synthetic((0, 0, 0), (0, 0, 0))[:4])


@pytest.mark.timeout(900)  # about 40 s of CPU on the virtual clock: beside CPU hogs it takes several times that
def test_ball_bar_routine_recovers_injected_scale_and_squareness(stations):
    sim, m, _ = stations.machine(settings=CmmSimSettings(errors=GeometryErrors((50.0, 0.0, 0.0), (30.0, 0.0, 0.0))))
    p = sim.settings.probe
    settings = ProbeSettings(p.tip_radius, PretravelModel({"const": 0.0, "s2_cos3": p.pretravel_lobe,
                                                           "z2": p.pretravel_z - p.pretravel_xy}))
    rng = np.random.default_rng(3)

    def place(s):  # the operator clamps the bar within 0.3 mm of the set-up
        off = rng.uniform(-0.3, 0.3, 3)
        sim.place_artifacts([(np.add(s.ball1, off), 25.0), (np.add(s.ball2, off), 25.0)])

    seen = []
    try:
        # two dithered hits per point: with 2 um counts a 200 mm bar resolves squareness to ~5 urad per hit
        r = calibrate_geometry(m, settings, CERTS, place=place, repeats=2, verify=False,
                               progress=lambda f, s: seen.append(f))
    finally:
        m.close()
    assert seen[-1] == 1.0
    assert abs(r.correction.scale_ppm[0] - 50.0) < 5.0
    assert abs(r.correction.scale_ppm[1]) < 5.0 and abs(r.correction.scale_ppm[2]) < 5.0
    assert abs(r.correction.squareness_urad[0] - 30.0) < 5.0
    assert all(abs(a) < 5.0 for a in r.correction.squareness_urad[1:])
    assert m.correction == r.correction  # applied for the verification pass; the caller saves the record
    rec = r.record("ball bars")
    assert rec.correction == GeometryCorrection(rec.scale_ppm, rec.squareness_urad)


def test_the_station_saves_a_geometry_result_and_applies_it(stations, tmp_path):
    """The save step of `cmm calibrate geometry` and the tab (the station's calibration service) on a fitted
    result with its nine set-ups ("XY+" ... as record keys): the record loads again and the machine has the
    correction. (The routine itself through the CLI costs ~45 s CPU on the virtual clock: not run here.)"""
    from cmm.calibration.geometry import GeometryResult
    from cmm.calibration.records import load_machine_record

    meas = synthetic((50.0, 0.0, 0.0), (30.0, 0.0, 0.0), noise=0.0005, seed=1)
    corr, res, us, ua = fit_geometry(meas)
    result = GeometryResult(corr, meas, res, us, ua, verification=synthetic((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
    station = stations.station(start=False)
    try:
        station.controller.connect()
        station.calibration.load(tmp_path)
        path, applied = station.calibration.save(None, "geometry", result)
        assert applied and path == tmp_path / "machine.toml"
        rec = load_machine_record(path)
        assert rec.correction == GeometryCorrection(tuple(round(x, 3) for x in corr.scale_ppm),
                                                    tuple(round(x, 3) for x in corr.squareness_urad))
        assert set(rec.length_errors_before_um) == {s.name for s in default_setups()} and "XY+" in rec.length_errors_after_um
        assert station.machine.correction == rec.correction
        assert any(line.startswith("machine") for line in station.calibration.log), station.calibration.log
    finally:
        station.close()
