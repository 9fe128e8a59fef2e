"""The coverage factor of the uncertainty budget: Student's t at 95.45 % for each value's effective degrees of
freedom (GUM G.3, G.4), the sampling term carrying the residuals' degrees of freedom and the form prior's; and the
coverage it gives on the simulator's error model where k = 2 fell short."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from cmm.metrology.fit_ls import fit_plane, fit_sphere
from cmm.metrology.uncertainty import PRIOR_DOF, Sources, budget, characteristic_k, coverage_factor

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


def _cap():
    c = np.array([70, 58, 39.0])
    a = np.radians([0, 90, 180, 270])
    ring = np.c_[10 * np.cos(np.pi / 4) * np.cos(a), 10 * np.cos(np.pi / 4) * np.sin(a),
                 np.full(4, 10 * np.sin(np.pi / 4))]
    return np.r_[[c + [0, 0, 10]], c + ring]


def test_coverage_factor_is_students_t_at_95_45_percent():
    # GUM table G.2, p = 95.45 %
    for nu, k in ((1, 13.97), (3, 3.31), (10, 2.28), (20, 2.13), (50, 2.05), (100, 2.03)):
        assert coverage_factor(nu) == pytest.approx(k, abs=0.006), nu
    assert coverage_factor(math.inf) == 2.0


def test_a_five_hit_cap_expands_by_t_of_its_welch_satterthwaite_degrees_of_freedom():
    pts = _cap()
    # a directionally compensated probe (no lobing, no Z/XY residual left): the form prior dominates the cap
    b = budget("sphere", pts, fit_sphere(pts), Sources(lobing=0.0, z_xy=0.0))
    samp = next(t for t in b.terms if t.source == "sampling")
    assert samp.dof == 5 - 4 + PRIOR_DOF  # one residual degree of freedom and the prior's
    uc = b.combined()
    for name in ("diameter", "x", "z"):
        nu = uc[name] ** 4 / (samp.u[name] ** 4 / samp.dof)
        assert b.effective_dof()[name] == pytest.approx(nu, rel=1e-9)
        assert 9.0 < nu < 12.0  # the sampling term is nearly all of the cap's U
        k = coverage_factor(nu)
        assert 2.2 < k < 2.3
        assert b.expanded()[name] == pytest.approx(k * uc[name], rel=1e-12)
    s = b.summary()
    assert s["k"]["diameter"] == pytest.approx(b.coverage_factors()["diameter"])
    assert s["k"]["form"] == 2.0 and s["nu_eff"]["form"] is None  # the form value has no sampling term
    assert characteristic_k("diameter", s) == pytest.approx(s["k"]["diameter"])
    # a position combines x, y, z, each with its own k: its k is its U over its u_c
    k_pos = characteristic_k("position", s)
    assert min(s["k"][v] for v in "xyz") <= k_pos <= max(s["k"][v] for v in "xyz")


def test_k_is_2_when_the_sampling_term_is_negligible():
    g = np.random.default_rng(0).normal(size=(40, 3))
    sph = 10.0 * g / np.linalg.norm(g, axis=1)[:, None] + [100, 50, 20]
    b = budget("sphere", sph, fit_sphere(sph), Sources(form_prior=0.0))
    # (the form's k comes from the distribution of the range of its residuals' errors, not from Student's t)
    assert all(k == pytest.approx(2.0, abs=1e-3) for name, k in b.coverage_factors().items() if name != "form")
    plane = np.array([[0, 0, 0], [50, 0, 0], [50, 40, 0], [0, 40, 0.0]])
    b = budget("plane", plane, fit_plane(plane), Sources(form_prior=0.0))
    assert b.coverage_factors()["offset"] == 2.0


def test_the_cap_is_covered_95_percent_where_k_2_was_not():
    """The sample part's sphere cap (5 hits: 1 residual degree of freedom) on the simulator's error model with 1 um
    of form (benchmarks/bench_uncertainty.py), 160 trials at a fixed seed: with k = 2 its diameter was covered in
    149 of them (93.1 %) and its height in 151 (94.4 %); with Student's t for the effective degrees of freedom
    (k about 2.27) each of its values in 155 or more (96.9 %). Over 2000 trials: 95.0 % and 94.8 % at k = 2,
    97.8 % and 97.0 % now."""
    from bench_uncertainty import run

    res = run(160, seed=3, verbose=False, features=("dome",), form=0.001)["dome"]
    for name in ("diameter", "x", "y", "z"):
        assert res[name]["coverage"] >= 0.95, (name, res[name])
        assert res[name]["worst"] <= 2.0, (name, res[name])
        assert res[name]["U_over_spread"] <= 3.0, (name, res[name])



def test_the_form_value_is_covered_without_the_two_hit_overstatement():
    """The form values (flatness of the 4-hit plane, the cone's form) on the simulator's error model with 1 um of
    form, 80 trials at a fixed seed: U / the errors' spread was 3.0-3.2 with each hit's scatter counted at both
    ends independently; through the fit's residual projection and the range of the residuals' errors it is about
    2.2-2.6, coverage kept."""
    from bench_uncertainty import run

    res = run(80, seed=4, verbose=False, features=("top_plane", "cone"), form=0.001, local_fits=True)
    for name in ("top_plane", "cone"):
        r = res[name]["form"]
        assert r["coverage"] >= 0.95 and r["worst"] < 2.0, (name, r)
        assert r["U_over_spread"] <= 2.9, (name, r)
