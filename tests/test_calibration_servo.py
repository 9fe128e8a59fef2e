"""Servo tuning assistant on the simulated modules: proposes, never applies by itself."""

from cmm.calibration.servo import apply_gains, step_response, svg_plot, tune_servos
from cmm.nmc.codec import Gains


def test_step_response_figures(sim_machine):
    _, m, _ = sim_machine
    t = step_response(m, "x", m.config.axis("x").gains)
    assert abs(t.final_error) <= 1 and t.overshoot <= 5 and not t.buzzing
    assert 0 < t.settling_time < 0.05 and len(t.times) == len(t.positions) > 50


def test_tuning_proposes_gains_and_restores_the_old_ones(sim_machine, tmp_path):
    _, m, _ = sim_machine
    before = m.modules[0].gains
    r = tune_servos(m, ("x",), progress=lambda f, s: None)
    g = r.proposed["x"]
    assert g.kd > 0 and g.kp > 0
    assert [t.stage for t in r.trials][:2] == ["kd", "kd"]  # Kd first, then Kp
    assert m.modules[0].gains == before  # not applied
    final = step_response(m, "x", g)
    assert abs(final.final_error) <= 1 and not final.buzzing
    svg = svg_plot(r.trials, tmp_path / "x.svg")
    assert svg.read_text().startswith("<svg") and "polyline" in svg.read_text()
    assert "proposed X" in r.table()
    apply_gains(m, {"x": Gains(**{**g.__dict__})})
    assert m.modules[0].gains == g


def test_cli_accepts_gains_through_the_station(tmp_path, capsys):
    """`cmm calibrate servo --accept`: tuned on a station (homed first), the gains sent through the command API
    and recorded (no proposal left)."""
    from cmm.calibration.records import load_servo_record
    from cmm.cli import main

    assert main(["calibrate", "servo", "--records", str(tmp_path), "--quiet", "--accept"]) == 0
    out = capsys.readouterr().out
    assert "applied and recorded in" in out and (tmp_path / "servo-x.svg").is_file()
    rec = load_servo_record(tmp_path / "servo.toml")
    assert rec.accepted and set(rec.gains) == {"x", "y", "z"} and all(g["kp"] > 0 for g in rec.gains.values())
    assert not (tmp_path / "servo-proposal.toml").exists()
