"""The Sessions tab's report with trends: a session whose run was added to a series as a part gets that series'
control charts in its report (as ``cmm report --trend``); a session that is no part of a series says so."""

from __future__ import annotations

import pytest

pytest.importorskip("viser")

from cmm.dmis.runner import run_text  # noqa: E402
from cmm.session.trends import Trends  # noqa: E402

TOP = ("FILNAM/'top face'\nUNITS/MM, ANGDEC\nD(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0\n"
       "GOTO/10, 10, 50\nF(TOP) = FEAT/PLANE, CART, 60, 40, 40, 0, 0, 1\nMEAS/PLANE, F(TOP), 3\n"
       "PTMEAS/CART, 10, 10, 40, 0, 0, 1\nPTMEAS/CART, 60, 5, 40, 0, 0, 1\nPTMEAS/CART, 110, 10, 40, 0, 0, 1\n"
       "ENDMES\nT(F) = TOL/FLAT, 0.01\nOUTPUT/FA(TOP), TA(F)\nENDFIL\n")


def _wait(job, timeout=60.0):
    assert job is not None
    assert job.wait(timeout), f"{job.title} did not finish"
    return job


def test_the_sessions_report_includes_the_series_charts(stations, tmp_path):
    station = stations.station("p0", session_dir=tmp_path / "sessions")
    ui = stations.app(station, pendant=False)
    try:
        station.measurement.trends = Trends(tmp_path / "trends", station="cmm-a")
        op = ui.add_client(client_id="operator", is_local=True)
        assert op.take_control()
        panel = op.sessions
        for name in ("p1", "p2"):  # two parts of the series 'top.dmi'
            assert panel.new_session(name) is not None, op.messages[-2:]
            run_text(TOP, station.controller.commands, name="top.dmi", client="operator")
        assert panel.new_session("p3") is not None
        job = _wait(panel.report("p2", trends=True))
        assert job.error is None, job.error
        html = job.result[0].read_text()
        assert "Trends across parts" in html and "top.dmi" in html and "FLAT T(F)" in html
        assert html.count("<svg class=\"trend\"") == 1  # the one characteristic's chart, over both parts
        # without the box ticked: no charts; a session that is no part of a series: said so
        job = _wait(panel.report("p2"))
        assert job.error is None and "Trends across parts" not in job.result[0].read_text()
        job = _wait(panel.report("p0", trends=True))
        assert "p0 was not recorded as a part of a series" in str(job.error)
    finally:
        ui.close()
        if station.measurement.trends is not None:
            station.measurement.trends.close()
        station.close()
