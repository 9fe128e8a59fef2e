"""On the station (in-process simulator): each program run is a part of the program's series, and the Trends tab
charts it (driven through its panel's methods, as its widgets call them)."""

from __future__ import annotations

import csv

import numpy as np
import pytest
import ui_support
from netutil import free_port

from cmm.measurement.program import run_on
from cmm.program import toml_program as prog
from cmm.session.trends import Trends

pytest.importorskip("viser")


def _program(part) -> prog.Program:
    """The top plane (3 hits) and the dome (4 hits) of the sample part, with its nominals and tolerances."""
    noms = part.nominal_features
    hits = [prog.ProgramHit(i + 1, (x, y, 40.0), (0.0, 0.0, -1.0), 60.0)
            for i, (x, y) in enumerate(((8.0, 8.0), (50.0, 8.0), (8.0, 72.0)))]
    c = np.array([70.0, 58.0, 39.0])
    dirs = [np.array([0.0, 0.0, 1.0])] + [np.array([np.cos(a) * 0.7071, np.sin(a) * 0.7071, 0.7071])
                                          for a in np.radians([0, 120, 240])]
    for k, d in enumerate(dirs):
        hits.append(prog.ProgramHit(4 + k, tuple(c + 10.0 * d), tuple(-d), 60.0))
    feats = [prog.ProgramFeature("top_plane", "plane", "ls", [1, 2, 3], {"size": 0.02, "form": 0.02,
                                 "location": 0.5}, noms["top_plane"].to_dict()),
             prog.ProgramFeature("dome", "sphere", "ls", [4, 5, 6, 7], {"size": 0.03, "form": 0.02,
                                 "location": 0.5}, noms["dome"].to_dict())]
    return prog.Program("dome check", part.name, part.sha256, feats, hits, 10.0)


@pytest.fixture(scope="module")
def station(module_stations, tmp_path_factory):
    root = tmp_path_factory.mktemp("trends-station")
    st = module_stations.station("runs", session_dir=root / "sessions")
    st.measurement.trends = Trends(root / "trends", station="cmm-test")
    yield st
    st.close()
    st.measurement.trends.close()


def test_program_runs_are_parts_of_a_series_and_the_trends_tab_charts_them(station, tmp_path):
    from stations import station_page

    program = _program(station.measurement.part)
    run = run_on(station.controller, station.measurement, program, serial="P1")
    t = station.measurement.trends
    assert run.part is not None and run.part.station == "cmm-test" and run.part.serial == "P1"
    # a second part of the series (as the next run would record it: the same call runs use)
    t.record_part("dome check", [(v.name, v.value + 0.002, v.nominal, v.lower, v.upper, v.unit)
                                 for v in run.part.values], serial="P2")
    assert t.series() == ["dome check"]
    names = [n for n, _ in t.characteristics("dome check")]
    assert names == ["top_plane / location (along the normal)", "top_plane / flatness", "dome / diameter",
                     "dome / position ⌀", "dome / sphericity"]
    h = t.history("dome check", "dome / diameter")
    assert h.serial == ["P1", "P2"] and h.station == ["cmm-test"] * 2
    assert h.value[0] == pytest.approx(2 * run.features["dome"].result.geometry()["radius"])
    assert np.allclose(h.lower, 19.97) and np.allclose(h.upper, 20.03) and np.allclose(h.value, 20.0, atol=0.03)
    flat = t.history("dome check", "top_plane / flatness")
    assert np.all(np.isnan(flat.lower)) and np.allclose(flat.upper, 0.02)

    app = station_page(station, host="127.0.0.1", port=free_port(), pendant=False)
    try:
        tab = app.add_client(client_id="viewer", is_local=False)  # an observer may read the charts
        panel = tab.trends
        panel.update()
        assert panel.series == "dome check" and panel.characteristic == names[0]
        panel.choose_characteristic("dome / diameter")
        assert panel.chart.history.serial == ["P1", "P2"] and panel.chart.chart.kind == "I-MR"
        panel.set_subgroup(30)
        assert "choose 1 (individuals chart) to 25" in tab.ctx.messages[-1][2] and panel.subgroup == 1
        panel.choose_station("other-station")
        assert len(panel.chart.history) == 0 and panel.chart.chart is None
        panel.choose_station("all stations")
        path = panel.export_csv(tmp_path / "dome.csv")
        with path.open() as f:
            rows = list(csv.DictReader(f))
        assert [r["serial"] for r in rows] == ["P1", "P2"] and rows[0]["station"] == "cmm-test"
        # a part recorded on the station redraws the chart on the tab's next refresh
        t.record_part("dome check", [("dome / diameter", 20.05, 20.0, 19.97, 20.03)], serial="P3")
        panel.refresh()
        assert panel.chart.history.serial[-1] == "P3" and panel.chart.out_of_tolerance == [2]
        _browser_tab_shows_the_chart(app)
    finally:
        app.close()


def _browser_tab_shows_the_chart(app):
    """A real viser connection builds the Trends tab with the series and its chart."""
    with ui_support.viser_tab(app) as (_ws, tab):
        g = tab.trends.gui
        assert g["series"].options == ("dome check",) and g["series"].value == "dome check"
        assert "dome / diameter" in g["characteristic"].options and g["station"].options == ("all stations", "cmm-test")
        assert g["chart"].content.startswith('<svg class="trend"') and "Cp" in g["summary"].content
        tab.trends.choose_characteristic("dome / diameter")
        assert g["characteristic"].value == "dome / diameter"
        assert "dome check: dome / diameter" in g["chart"].content
