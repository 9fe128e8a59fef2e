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
