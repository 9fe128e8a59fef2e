"""The uncertainty budget: known answers for single terms, and coverage on the simulator's
error model (probe pre-travel and lobing, noise, scale and squareness, thermal) for the sample part's plane and
sphere cap with their default plans (benchmarks/bench_uncertainty.py runs every feature, more trials)."""

from __future__ import annotations

import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from cmm.metrology.fit_ls import fit_plane, fit_sphere
from cmm.metrology.uncertainty import Sources, budget

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


def _terms(b):
    return {t.source: t.u for t in b.terms}


def test_single_terms_known_answers():
    src = Sources(u_tip=0.0005, lobing=0.0, z_xy=0.0, repeatability=0.0, mpe_k=1e12, temperature_allowance=0.0,
                  cte_u=0.0, form_prior=0.0)
    plane = np.array([[0, 0, 0], [50, 0, 0], [50, 40, 0], [0, 40, 0.0]])
    b = budget("plane", plane, fit_plane(plane), src)
    assert _terms(b)["probe qualification"]["offset"] == pytest.approx(0.0005, rel=1e-6)
    assert b.expanded()["offset"] == pytest.approx(0.001, rel=1e-6)
    # a sphere all round: the tip radius moves the diameter by twice, the centre not at all
    g = np.random.default_rng(0).normal(size=(40, 3))
    sph = 10.0 * g / np.linalg.norm(g, axis=1)[:, None] + [100, 50, 20]
    b = budget("sphere", sph, fit_sphere(sph), src)
    t = _terms(b)["probe qualification"]
    assert t["diameter"] == pytest.approx(0.001, rel=1e-5) and t["x"] < 1e-9
    # thermal at 21 C, CTE 11.5e-6 (no allowance): the diameter 20 mm grows by 0.23 um; U = 2 x that
    warm = Sources(u_tip=0.0, lobing=0.0, z_xy=0.0, repeatability=0.0, mpe_k=1e12, temperature=21.0,
                   temperature_allowance=0.0, cte_u=0.0, form_prior=0.0)
    b = budget("sphere", sph, fit_sphere(sph), warm)
    assert _terms(b)["thermal"]["diameter"] == pytest.approx(20 * 11.5e-6, rel=1e-5)
    assert "U = k u_c" in b.text() and "k (95 %)" in b.text() and set(b.summary()["U"]) == {"diameter", "x", "y", "z", "form"}


def test_a_five_hit_cap_has_a_sampling_term_from_the_prior():
    c = np.array([70, 58, 39.0])
    a = np.radians([0, 90, 180, 270])
    ring = np.c_[10 * np.cos(np.pi / 4) * np.cos(a), 10 * np.cos(np.pi / 4) * np.sin(a), np.full(4, 10 * np.sin(np.pi / 4))]
    pts = np.r_[[c + [0, 0, 10]], c + ring]
    b = budget("sphere", pts, fit_sphere(pts), Sources())
    assert "residual degrees of freedom" in next(t.note for t in b.terms if t.source == "sampling")
    # the cap amplifies the probe's errors: U of the diameter is several times the tip's own
    assert b.expanded()["diameter"] > 4 * 2 * Sources().u_tip


def test_coverage_on_the_simulator_error_model():
    from bench_uncertainty import run

    res = run(12, seed=3, verbose=False, features=("top_plane", "dome"))
    for feature, values in res.items():
        for name, r in values.items():
            if r["U"] < 1e-9:
                continue
            assert r["worst"] <= 2.0, (feature, name, r)
            assert r["coverage"] >= 11 / 12, (feature, name, r)


def test_station_features_carry_their_budget_into_the_session_and_the_csv(tmp_path):
    """On the simulated station: the bore measured by a DMIS program has a budget (U and its k) in the journal, a
    comment with U in the DMIS output and a U column in the CSV; its diameter is within U of the true 30 mm."""
    import csv
    import io

    import session_support as sup
    from cmm.dmis.runner import run_text
    from cmm.session.report import features_csv
    from cmm.journal.store import DirectoryStore, load_session

    gen = sup.sim_station(tmp_path, "budget")
    station = next(gen)
    try:
        text = """FILNAM/'bore'
UNITS/MM, ANGDEC
D(SETUP) = TRANS/XORIG, 190, YORIG, 150, ZORIG, 0
GOTO/30, 40, 70
GOTO/30, 40, 30
F(BORE) = FEAT/CYLNDR, INNER, CART, 30, 40, 0, 0, 0, 1, 30, 40
MEAS/CYLNDR, F(BORE), 8
  PTMEAS/CART, 45.0000, 40.0000, 30, -1, 0, 0
  PTMEAS/CART, 30.0000, 55.0000, 30, 0, -1, 0
  PTMEAS/CART, 15.0000, 40.0000, 30, 1, 0, 0
  PTMEAS/CART, 30.0000, 25.0000, 30, 0, 1, 0
  PTMEAS/CART, 40.6066, 50.6066, 10, -0.707107, -0.707107, 0
  PTMEAS/CART, 19.3934, 50.6066, 10, 0.707107, -0.707107, 0
  PTMEAS/CART, 19.3934, 29.3934, 10, 0.707107, 0.707107, 0
  PTMEAS/CART, 40.6066, 29.3934, 10, -0.707107, 0.707107, 0
ENDMES
GOTO/30, 40, 70
OUTPUT/FA(BORE)
ENDFIL
"""
        result = run_text(text, station.controller.commands, name="bore.dmi")
        assert re.search(r"^\$\$ FA\(BORE\): U \(95 %\) diameter 0\.00\d+ k=\d\.\d\d, x ", result.outputs[None], re.M)
        feats = list(station.measurement.features.values())
        assert len(feats) == 1 and feats[0].budget is not None
        U = feats[0].budget["U"]["diameter"]
        assert 0 < U < 0.01
        assert abs(2 * feats[0].result.radius - 30.0) <= U
        session = load_session(DirectoryStore(station.measurement.session_dir), "budget")
        rows = list(csv.DictReader(io.StringIO(features_csv(session))))
        dia = next(r for r in rows if r["characteristic"] == "diameter")
        assert float(dia["U"]) == pytest.approx(U, abs=1e-6)
        assert float(dia["k"]) == pytest.approx(feats[0].budget["k"]["diameter"], abs=0.006)
        # the same U beside the actual in the HTML report and in the page's feature tree
        from cmm.session.report import render
        from cmm.ui.panel_features import tree_html

        assert "<th>U (95 %)</th>" in render(session) and f"<td class='muted'>{U:.4f}</td>" in render(session)
        assert f"±{U:.4f}" in tree_html(station.controller.commands)
    finally:
        gen.close()
