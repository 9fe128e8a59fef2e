"""Certificates and records: formats, validation messages, atomic writes, CLI failure keeps the old record."""

import os

import numpy as np
import pytest

from cmm.calibration import records as rec
from cmm.calibration.records import CalibrationError
from cmm.machine.config import load

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_shipped_certificates_load():
    s = rec.load_sphere_certificate(os.path.join(REPO, "calibration/artifacts/reference-sphere.toml"))
    assert s.diameter == 25.0 and s.form == 0.0002 and s.approx_centre == (400.0, 300.0, 100.0)
    b = rec.load_ball_bar_certificate(os.path.join(REPO, "calibration/artifacts/ball-bar-300.toml"))
    assert b.length == 300.0


@pytest.mark.parametrize("text, message", [
    (None, "is missing"),
    ("[artifact\nkind=", "not valid TOML"),
    ("[artifact]\nkind = 'cube'\n", "kind must be"),
    ("[artifact]\nkind = 'sphere'\n", "'diameter' is missing"),
    ("[artifact]\nkind = 'sphere'\ndiameter = -25\n", "greater than 0"),
    ("[artifact]\nkind = 'sphere'\ndiameter = '25'\n", "must be a number"),
    ("[artifact]\nkind = 'sphere'\ndiameter = 25\n[setup]\ncentre = [1, 2]\n", "list of 3 numbers"),
    ("kind = 'sphere'\n", "[artifact] table is missing"),
])
def test_bad_certificates_name_the_problem(tmp_path, text, message):
    p = tmp_path / "c.toml"
    if text is not None:
        p.write_text(text)
    with pytest.raises(CalibrationError, match=message.replace("[", r"\[").replace("]", r"\]")):
        rec.load_sphere_certificate(p)


def test_records_round_trip_and_write_atomically(tmp_path):
    pr = rec.ProbeRecord("2025-01-01", "sphere", 0.9961, {"const": 1e-4, "s2_cos3": 0.0015}, 1.0, (400, 300, 100))
    mr = rec.MachineRecord("2025-01-01", "bars", (50.0, 0.0, -1.0), (30.0, 0.0, 0.0),
                           length_errors_before_um={"X": -15.0, "XY+": -11.7}, length_errors_after_um={"XY-": 0.4})
    sr = rec.ServoRecord("2025-01-01", {"x": {"kp": 4000, "kd": 16000, "ki": 0, "il": 0}}, True)
    rec.save_record(pr, tmp_path / "probe.toml")
    rec.save_record(mr, tmp_path / "machine.toml")
    rec.save_record(sr, tmp_path / "servo.toml")
    assert rec.load_probe_record(tmp_path / "probe.toml").pretravel == pr.pretravel
    got = rec.load_machine_record(tmp_path / "machine.toml")
    assert got.correction == mr.correction  # set-up names such as "XY+" are written as quoted keys
    assert got.length_errors_before_um == mr.length_errors_before_um and got.length_errors_after_um == {"XY-": 0.4}
    assert rec.load_servo_record(tmp_path / "servo.toml").gains == sr.gains
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no temporaries left
    with pytest.raises(ValueError):
        rec.save_record(rec.ProbeRecord("d", "a", float("nan"), {}, 1.0, (0, 0, 0)), tmp_path / "probe.toml")
    assert rec.load_probe_record(tmp_path / "probe.toml").tip_radius == 0.9961  # the old record survived


def test_station_calibration_applies_good_records_and_refuses_bad_ones(stations, tmp_path):
    rec.save_record(rec.MachineRecord("d", "bars", (50.0, 0.0, 0.0), (30.0, 0.0, 0.0)), tmp_path / "machine.toml")
    (tmp_path / "probe.toml").write_text("[record]\nkind = 'probe'\n[results]\ntip_radius = 'big'\n")
    loaded = rec.load_station_calibration(tmp_path)
    assert loaded.probe is None and "tip_radius" in loaded.problems[0]
    config = load()
    _, m, prober = stations.machine(config)
    try:
        done = rec.apply_calibration(loaded, m, prober)
        assert len(done) == 1 and m.correction.scale_ppm == (50.0, 0.0, 0.0)
        assert prober.settings.tip_radius == config.probe.tip_radius
    finally:
        m.close()


def test_cli_failure_leaves_the_previous_record(tmp_path, capsys):
    from cmm.cli import main

    (tmp_path / "artifacts").mkdir()
    (tmp_path / "artifacts" / "reference-sphere.toml").write_text("[artifact]\nkind = 'sphere'\n")
    old = rec.ProbeRecord("old", "sphere", 0.997, {"const": 0.0}, 1.0, (400, 300, 100))
    rec.save_record(old, tmp_path / "probe.toml")
    before = (tmp_path / "probe.toml").read_text()
    assert main(["calibrate", "probe", "--records", str(tmp_path), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "'diameter' is missing" in err and "previous calibration stays in force" in err
    assert (tmp_path / "probe.toml").read_text() == before


def test_cli_probe_then_iso_on_the_simulator(tmp_path, capsys):
    from cmm.cli import main

    (tmp_path / "artifacts").mkdir()
    src = os.path.join(REPO, "calibration/artifacts/reference-sphere.toml")
    (tmp_path / "artifacts" / "reference-sphere.toml").write_text(open(src).read())
    assert main(["calibrate", "probe", "--records", str(tmp_path), "--quiet", "--repeats", "1"]) == 0
    r = rec.load_probe_record(tmp_path / "probe.toml")
    assert 0.99 < r.tip_radius < 1.0 and r.n_points == 73
    assert main(["calibrate", "iso10360-5", "--records", str(tmp_path), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "in force: probe" in out and "P_Form.Sph.1x25" in out
    assert np.isfinite(r.form_after_um)


def test_probe_list_round_trip_and_bad_entries_are_named(tmp_path):
    from cmm.calibration.records import (ProbeDefinition, load_probe_list, probe_expiry, save_probe_list,
                                         write_sphere_certificate)

    probes = [ProbeDefinition("T1", 2.0), ProbeDefinition("D3-x", 3.0, (1.0, 0.0, 0.0))]
    save_probe_list(tmp_path, probes, "D3-x")
    assert load_probe_list(tmp_path) == (probes, "D3-x")
    (tmp_path / "probes.toml").write_text('selected = "T9"\n[probes.T1]\ntip_diameter = 2.0\n')
    with pytest.raises(CalibrationError, match="selected probe 'T9' is not in the list"):
        load_probe_list(tmp_path)
    (tmp_path / "probes.toml").write_text('[probes.T1]\ntip_diameter = -2.0\n')
    with pytest.raises(CalibrationError, match="tip diameter of T1 must be between"):
        load_probe_list(tmp_path)
    assert probe_expiry("2026-01-10T08:00:00+00:00") == "2026-02-09" and probe_expiry("soon") == ""
    cert_path = tmp_path / "artifacts" / "reference-sphere.toml"
    with pytest.raises(CalibrationError, match="diameter must be a number"):
        write_sphere_certificate(cert_path, diameter="twenty-five", serial="S1", uncertainty=0.0001)
    assert not cert_path.exists()
    cert = write_sphere_certificate(cert_path, diameter=25.001, serial="S1", uncertainty=0.0001, centre=(1, 2, 3))
    assert (cert.diameter, cert.serial, cert.approx_centre) == (25.001, "S1", (1.0, 2.0, 3.0))
