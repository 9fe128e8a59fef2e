"""Actuals where the operator looks (in the alignment's frame, named, in the Features tree, the detail, the report
and the CSV; machine coordinates on demand) and no stale probe data (Machine > Probe and the report header show
the probe data the hits were taken with, a requalification applied during the session included). Through the real
station on the simulator."""

from __future__ import annotations

import csv
import io
import re
from types import SimpleNamespace

import numpy as np
import pytest

from cmm.calibration.records import ProbeRecord
from cmm.control.access import Client
from cmm.metrology.actuals import model_frame
from cmm.metrology.compensation import PretravelModel
from cmm.session.report import features_csv, render
from cmm.journal.store import open_session
from cmm.sim.cmm_sim import TRUE_PART_POSE
from cmm.ui.panel_features import tree_html
from cmm.ui.panels import probe_markdown

ME = Client("page", local=True)


@pytest.fixture(scope="module")
def station(module_stations, tmp_path_factory):
    # qualified: the simulator's probe, as qualified
    return module_stations.station("actuals", qualified=True,
                                   calibration_dir=tmp_path_factory.mktemp("actuals-calibration"))


def _bore_hits(st, z=20.0):
    """Four programmed hits in the bore (part: centre (30, 40), D 30) where the part really is."""
    pose = st.measurement.part.pose
    ids = []
    for a in np.radians([20, 110, 200, 290]):
        n = np.array([np.cos(a), np.sin(a), 0.0])
        p = np.array([30.0, 40.0, z]) + 15.0 * n
        hit = st.measurement.probe(pose[:3, :3] @ p + pose[:3, 3], pose[:3, :3] @ n).wait()
        ids.append(st.measurement.hit_id(hit))
    return ids


def _numbers(text, *keys):
    return [float(re.search(rf"\b{k} (-?\d+\.\d+)", text).group(1)) for k in keys]


def test_actuals_are_in_the_alignment_frame_and_name_it(station):
    st = station
    st.measurement.set_alignment(TRUE_PART_POSE, "3-2-1", names=["TOP", "FRONT", "LEFT"])
    bore = st.controller.commands.invoke(ME, "measure_feature", kind="circle", hits=_bore_hits(st), name="bore")
    # the tree: X, Y, Z, D in part coordinates, the frame named at the top
    tree = tree_html(st.controller.commands)
    assert "actuals in <b>part coordinates (3-2-1 TOP/FRONT/LEFT)</b>" in tree
    row = re.search(r"class='cmm-actual'[^>]*>([^<]+)<", tree).group(1)
    x, y, z, d = _numbers(row, "X", "Y", "Z", "D")
    assert (x, y, z, d) == pytest.approx((30.0, 40.0, 20.0, 30.0), abs=0.005)
    # machine coordinates on demand
    machine = tree_html(st.controller.commands, machine=True)
    assert "actuals in <b>machine coordinates</b>" in machine
    mx, my = _numbers(re.search(r"class='cmm-actual'[^>]*>([^<]+)<", machine).group(1), "X", "Y")
    centre = TRUE_PART_POSE @ np.array([30.0, 40.0, 20.0, 1.0])
    assert (mx, my) == pytest.approx(tuple(centre[:2]), abs=0.005)
    assert model_frame(st.measurement).label == "part coordinates (3-2-1 TOP/FRONT/LEFT)"
    # the report and the CSV: the same actuals, the same frame
    session = open_session(st.measurement.journal.path)
    html = render(session)
    assert "Actuals in part coordinates (3-2-1 TOP/FRONT/LEFT)" in html
    assert "actuals in</dt><dd>part coordinates (3-2-1 TOP/FRONT/LEFT)" in html
    rows = [r for r in csv.DictReader(io.StringIO(features_csv(session))) if r["feature"] == "bore"]
    assert rows and all(r["frame"] == "part coordinates (3-2-1 TOP/FRONT/LEFT)" for r in rows)
    assert float(rows[0]["actual_x"]) == pytest.approx(30.0, abs=0.005)
    assert float(rows[0]["actual_y"]) == pytest.approx(40.0, abs=0.005)
    assert float(rows[0]["actual_d"]) == pytest.approx(30.0, abs=0.005)
    assert f"{float(rows[0]['actual_x']):.4f}" in html and f"{float(rows[0]['actual_x']):.4f}" in tree
    assert bore.id in st.measurement.features


def _requalify(st, radius, date):
    """A probe qualification saved and applied as the page's Save record does (the save_calibration verb)."""
    record = ProbeRecord(date, "sphere D25", radius, {"const": 0.0}, 1.0, (400.0, 300.0, 100.0))
    result = SimpleNamespace(record=record, probe=None, settings=SimpleNamespace(pretravel=PretravelModel({"const": 0.0})))
    st.controller.commands.invoke(ME, "save_calibration", routine="probe", result=result)


def test_probe_data_shown_is_the_data_the_hits_used(station):
    st = station
    _requalify(st, 0.9981, "2026-11-01T08:00:00")
    st.controller.commands.invoke(ME, "new_session", name="after-first")
    start = open_session(st.measurement.journal.path).start
    assert start["calibration"]["probe"]["date"].startswith("2026-11-01")
    # requalified after the session started, before any hit: Machine > Probe shows it at once
    _requalify(st, 0.9975, "2026-11-02T09:30:00")
    text = probe_markdown(st.controller.commands)
    assert "0.99750 mm" in text and "qualified 2026-11-02" in text
    st.measurement.set_alignment(TRUE_PART_POSE, "3-2-1", names=["TOP", "FRONT", "LEFT"])
    _bore_hits(st)
    html = render(open_session(st.measurement.journal.path))
    head = html[html.index("<div class='head'>"):html.index("<h2>Features")]
    # every hit came after the requalification: the header names it, not the start's
    assert "probe qualified 2026-11-02" in head and "2026-11-01" not in head
    assert "r 0.99750 mm, qualified 2026-11-02 09:30" in head and "(4 hits)" in head
    # a requalification in the middle: the header shows both, each with its hits
    _requalify(st, 0.9990, "2026-11-03T10:00:00")
    assert "0.99900 mm" in probe_markdown(st.controller.commands)
    _bore_hits(st, z=25.0)
    head = render(open_session(st.measurement.journal.path))
    head = head[head.index("<div class='head'>"):head.index("<h2>Features")]
    assert "probe qualified 2026-11-02, 2026-11-03" in head
    assert "r 0.99750 mm, qualified 2026-11-02 09:30, pre-travel constant 0.00 um (4 hits)" in head
    assert "r 0.99900 mm, qualified 2026-11-03 10:00, pre-travel constant 0.00 um (4 hits)" in head
