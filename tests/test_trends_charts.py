"""A characteristic's trend: statistics, the SVG chart, the CSV, the report section and `cmm trends`."""

from __future__ import annotations

import csv
import io
import re

import numpy as np
import pytest

from cmm.cli import main
from cmm.metrology import spc
from cmm.session.report import render
from cmm.journal.store import DirectoryStore, load_session
from cmm.session.trends import Measured, Trends
from cmm.session.trends_chart import history_csv, summary, trend, trend_svg
from test_spc import PISTON_RINGS

BORE = "bore / diameter"


@pytest.fixture()
def rings(tmp_path):
    """The piston rings as 125 parts of series 'rings' from two stations (alternating subgroups); part 30
    (index 29, station B) is out of its 73.95 .. 74.05 tolerance."""
    values = list(np.ravel(PISTON_RINGS))
    values[29] = 74.06
    with Trends(tmp_path / "a", station="cmm-a") as a, Trends(tmp_path / "b", station="cmm-b") as b:
        for i, v in enumerate(values):
            t = a if (i // 5) % 2 == 0 else b
            t.record_part("rings", [Measured(BORE, v, 74.0, 73.95, 74.05)], serial=f"R{i + 1}", when=1e9 + i)
    return tmp_path, values


def _merged(root):
    """Both stations' histories in time order (as the shared database gives them)."""
    from cmm.session.trends import history_from_rows

    rows = []
    for d in ("a", "b"):
        with Trends(root / d, station=d) as t:
            rows += t.index.rows("rings", BORE, None)
    return history_from_rows("rings", BORE, sorted(rows), "database")


def test_the_trend_of_a_series_has_the_charts_limits_and_the_bad_part(rings):
    root, values = rings
    h = _merged(root)
    assert len(h) == 125 and h.station[:10] == ["cmm-a"] * 5 + ["cmm-b"] * 5
    tc = trend(h, 5)
    ref = spc.xbar_r_chart(values, 5)
    assert tc.chart.location == ref.location and tc.chart.spread == ref.spread
    assert tc.out_of_tolerance == [29] and (tc.lower, tc.upper, tc.nominal) == (73.95, 74.05, 74.0)
    assert tc.capability.cpk == pytest.approx(spc.capability(values, 73.95, 74.05, ref.sigma).cpk)
    text = dict(summary(tc))
    assert text["parts"] == "125 from 2 stations (cmm-a, cmm-b)"
    assert text["out of tolerance"] == "1 part: R30 (cmm-b, 74.0600)"
    assert "X-bar-R, subgroups of 5" in text["chart"] and "Cpk" in text["capability"]
    svg = trend_svg(tc)
    dots = re.findall(r'<circle [^>]*fill="([^"]+)"', svg)
    assert len(dots) == 125 and dots.count("#c62828") == 1  # every part, the bad one in red
    assert "● cmm-a" in svg and "● cmm-b" in svg and "X̄ UCL" in svg and "USL 74.0500" in svg
    i = trend(h)  # individuals
    assert i.chart.kind == "I-MR" and len(i.chart.spread_points) == 124
    rows = list(csv.DictReader(io.StringIO(history_csv(h))))
    assert len(rows) == 125 and rows[29]["result"] == "FAIL" and rows[29]["serial"] == "R30"
    assert {r["station"] for r in rows} == {"cmm-a", "cmm-b"} and rows[0]["upper_limit"] == "74.050000"


def test_too_few_parts_give_a_sentence_not_a_chart(tmp_path):
    with Trends(tmp_path, station="a") as t:
        t.record_part("x", [Measured(BORE, 30.0, 30.0, 29.98, 30.02)])
        tc = trend(t.history("x", BORE), 5)
    assert tc.chart is None and tc.capability is None
    assert dict(summary(tc))["chart"] == "an X-bar-R chart of subgroups of 5 needs at least 10 values, there is 1"
    assert "<circle" in trend_svg(tc)


def test_the_report_includes_the_series_charts_and_the_cli_prints_and_exports(rings, tmp_path, capsys):
    root, _ = rings
    trends_dir = str(root / "a")
    assert main(["trends", "--trends", trends_dir, "show", "rings", "--subgroup", "5"]) == 0
    out = capsys.readouterr().out
    assert "rings: bore / diameter" in out and "chart: X-bar-R, subgroups of 5" in out and "Cpk" in out
    assert "parts: 65 (cmm-a)" in out  # this folder holds station A's parts only
    assert main(["trends", "--trends", trends_dir, "export", "rings", BORE, "-o", str(tmp_path / "b.csv")]) == 0
    assert len((tmp_path / "b.csv").read_text().splitlines()) == 66
    assert main(["trends", "--trends", trends_dir, "show", "gears"]) == 1
    assert "there is no series 'gears' (recorded series: rings)" in capsys.readouterr().err
    assert main(["trends", "--trends", trends_dir, "show", "rings", "bore / radius"]) == 1
    assert "has no characteristic 'bore / radius'; it has: bore / diameter" in capsys.readouterr().err
    assert main(["trends", "--trends", trends_dir, "sync"]) == 2  # no database given
    # the report of a session with the series' charts
    with DirectoryStore(tmp_path / "sessions").create("empty") as j:  # no part: no colour map to draw
        j.append("start")
    html = render(load_session(DirectoryStore(tmp_path / "sessions"), "empty"), trends=[trend(_merged(root))])
    assert "<h2>Trends across parts</h2>" in html and "every station's parts" in html
    assert html.count('<svg class="trend"') == 1 and "74.06000 OUT OF TOLERANCE" in html
    assert main(["report", "empty", "--store", str(tmp_path / "sessions"), "-o", str(tmp_path / "r.html"),
                 "--trend", "rings", "--trends", trends_dir]) == 0
    assert "this station's parts (local journal)" in (tmp_path / "r.html").read_text()


def test_cmm_serve_opens_the_stations_trends_from_its_options(tmp_path, monkeypatch):
    from cmm.cli import build_parser
    from cmm.cli.serve import open_trends

    monkeypatch.delenv("CMM_TRENDS_DB", raising=False)
    args = build_parser().parse_args(["serve", "--trends", str(tmp_path / "t"), "--station", "cmm-7"])
    with open_trends(args) as t:
        assert t.station == "cmm-7" and t.database_url is None and t.directory == tmp_path / "t"
        assert "local trends only" in t.status_text()
    args = build_parser().parse_args(["serve", "--trends", str(tmp_path / "t"), "--sessions",
                                      "postgresql://nobody@127.0.0.1:1/x?connect_timeout=1"])
    with open_trends(args) as t:  # the session store's database is the trends database too; down: local
        assert t.database_url.startswith("postgresql://") and t.source == "local"
        assert "unreachable" in t.status_text()
