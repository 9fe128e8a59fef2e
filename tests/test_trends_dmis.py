"""A DMIS run on the station is a part of the program's series: its tolerance results become trend values."""

from __future__ import annotations

import pytest
from test_dmis import placed_simple_program, station  # noqa: F401 - the DMIS tests' station fixture

from cmm.dmis.runner import run_text
from cmm.dmis.tolerances import Evaluation, Tolerance
from cmm.session.trends import Trends, tolerance_values


def test_dmis_tolerance_results_as_trend_values():
    evs = [Evaluation(Tolerance("D1", "DIAM", -0.02, 0.03), 0.011, True, ["BORE"]),
           Evaluation(Tolerance("A1", "ANGLB", -0.5, 0.5, 90.0), -0.2, True, ["TOP", "FRONT"]),
           Evaluation(Tolerance("P1", "POS", 0.0, 0.04), 0.05, False, ["BOSS"]),
           Evaluation(Tolerance("P1", "POS", 0.0, 0.04), 0.03, True, ["BOSS"])]  # output twice: the last counts
    vals = tolerance_values(evs)
    assert [v.name for v in vals] == ["BORE / DIAM T(D1)", "TOP-FRONT / ANGLB T(A1)", "BOSS / POS T(P1)"]
    d, a, p = vals
    assert (d.value, d.nominal, d.lower, d.upper, d.ok) == (0.011, 0.0, -0.02, 0.03, True)
    assert a.unit == "deg" and (p.lower, p.upper, p.value, p.ok) == (None, 0.04, 0.03, True)


def test_a_dmis_run_on_the_station_records_a_part(station, tmp_path):  # noqa: F811 - the fixture
    text = placed_simple_program().replace("OUTPUT/FA(A_CIRCLE)", "T(DIA) = TOL/DIAM, -0.05, 0.05\n"
                                                                 "OUTPUT/FA(A_CIRCLE), TA(DIA)")
    with Trends(tmp_path / "trends", station="cmm-dmis") as t:
        station.measurement.trends = t
        result = run_text(text, station.controller.commands, name="simple_in.dms")
        (ev,) = result.evaluations
        h = t.history("simple_in.dms", "A_CIRCLE / DIAM T(DIA)")
        assert len(h) == 1 and h.station == ["cmm-dmis"]
        # the program's nominal is its D50 hole, our bore is D30: 20 mm under size, out of tolerance
        assert h.value[0] == pytest.approx(ev.value) and h.value[0] == pytest.approx(-20.0, abs=0.01)
        assert (h.lower[0], h.upper[0]) == (-0.05, 0.05) and not ev.intol


def test_cmm_run_records_the_run_in_a_trends_folder(tmp_path, monkeypatch, capsys):
    from cmm.cli import main

    monkeypatch.chdir(tmp_path)  # the DMIS output and report are written here
    monkeypatch.delenv("CMM_TRENDS_DB", raising=False)
    program = tmp_path / "bore.dmi"
    program.write_text(placed_simple_program().replace(
        "OUTPUT/FA(A_CIRCLE)", "T(DIA) = TOL/DIAM, -0.05, 0.05\nOUTPUT/FA(A_CIRCLE), TA(DIA)"))
    assert main(["run", str(program), "--sessions", str(tmp_path / "sessions"), "--trends", str(tmp_path / "trends"),
                 "--station", "cmm-cli"]) == 0
    assert "trends: station cmm-cli, local trends only" in capsys.readouterr().out
    with Trends(tmp_path / "trends") as t:
        h = t.history("bore.dmi", "A_CIRCLE / DIAM T(DIA)")
    assert h.station == ["cmm-cli"] and h.value[0] == pytest.approx(-20.0, abs=0.05)
