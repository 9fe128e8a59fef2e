"""U of a constructed distance from its two features' budgets, and the reason in words where there is none."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cmm.metrology.characteristics import constructed_characteristics
from cmm.metrology.construct import construct
from cmm.metrology.fit_ls import fit_plane, fit_sphere
from cmm.metrology.uncertainty import Sources, budget, coverage_factor
from cmm.metrology.uncertainty_construct import distance_uncertainty


def _sphere(centre, n=12, seed=0):
    g = np.random.default_rng(seed).normal(size=(n, 3))
    pts = 10.0 * g / np.linalg.norm(g, axis=1)[:, None] + centre
    fit = fit_sphere(pts)
    src = Sources(reference=(0.0, 0.0, 0.0), lobing=0.0, z_xy=0.0)
    return ("sphere", {"center": list(map(float, fit.center)), "radius": float(fit.radius)}), \
        budget("sphere", pts, fit, src).summary()


def test_centre_to_centre_distance_along_x_combines_the_two_budgets():
    a, ba = _sphere([0.0, 0.0, 0.0])
    b, bb = _sphere([100.0, 0.0, 0.0], seed=1)
    out = distance_uncertainty("distance", a, b, (ba, bb))
    # along x the distance moves with each centre's x only (its y and z second order)
    by_a = {t["source"]: t for t in ba["terms"]}
    by_b = {t["source"]: t for t in bb["terms"]}
    sys_ = sum((by_a[s]["u"]["x"] + by_b[s]["u"]["x"]) ** 2 for s in by_a if s not in ("scatter", "sampling"))
    rnd = sum(by_a[s]["u"]["x"] ** 2 + by_b[s]["u"]["x"] ** 2 for s in ("scatter", "sampling"))
    u = math.sqrt(sys_ + rnd)
    assert out["u_c"] == pytest.approx(u, rel=2e-3)
    nu = u ** 4 / sum(t["u"]["x"] ** 4 / t["dof"] for t in (by_a["sampling"], by_b["sampling"]))
    assert out["k"] == pytest.approx(coverage_factor(nu), rel=1e-3)
    assert out["U"] == pytest.approx(out["k"] * out["u_c"])
    # more than either centre's own U: two features' errors add
    assert out["U"] > max(ba["U"]["x"], bb["U"]["x"])
    # the characteristic carries it; the construction's summary keeps it
    c = construct("distance", a, b)
    c.uncertainty = out
    ch = constructed_characteristics("d", c.summary(), None)[0]
    assert ch.uncertainty == pytest.approx(out["U"]) and ch.uncertainty_k == pytest.approx(out["k"])
    assert ch.uncertainty_why == ""


def test_no_uncertainty_is_said_in_words():
    a, ba = _sphere([0.0, 0.0, 0.0])
    plane_pts = np.array([[0, 0, -30], [60, 0, -30], [60, 40, -30], [0, 40, -30.0]])
    pf = fit_plane(plane_pts)
    p = ("plane", {"point": list(map(float, pf.point)), "normal": list(map(float, pf.normal))})
    bp = budget("plane", plane_pts, pf, Sources()).summary()
    # the distance of a centre to a plane depends on the plane's normal: its budget has no direction
    why = distance_uncertainty("distance", a, p, (ba, bp))["why"]
    assert why.startswith("no uncertainty") and "normal" in why
    assert "direction" in distance_uncertainty("angle", p, p, (bp, bp))["why"]
    assert "no uncertainty budget" in distance_uncertainty("distance", a, a, (ba, None))["why"]
    # the characteristic of a construction without a U says why instead of showing nothing
    c = construct("distance", a, p)
    c.uncertainty = distance_uncertainty("distance", a, p, (ba, bp))
    ch = constructed_characteristics("d", c.summary(), None)[0]
    assert ch.uncertainty is None and "normal" in ch.uncertainty_why
    old = constructed_characteristics("d", construct("distance", a, p).summary(), None)[0]
    assert old.uncertainty is None and old.uncertainty_why.startswith("no uncertainty")


def test_a_station_construction_carries_the_u_of_its_features_budgets():
    """construct_pair (the station's construction of two fitted features) propagates their budgets."""
    from types import SimpleNamespace

    from cmm.measurement.session_files import construct_pair

    feats = []
    for centre, seed in (([0.0, 0.0, 0.0], 0), ([80.0, 30.0, 0.0], 1)):
        g = np.random.default_rng(seed).normal(size=(12, 3))
        pts = 10.0 * g / np.linalg.norm(g, axis=1)[:, None] + centre
        fit = fit_sphere(pts)
        feats.append(SimpleNamespace(kind="sphere", result=fit, nominal=None,
                                     budget=budget("sphere", pts, fit, Sources(reference=(0.0, 0.0, 0.0))).summary()))
    result, _ = construct_pair("distance", feats[0], feats[1], None, False)
    unc = result.summary()["uncertainty"]
    assert unc["U"] > 0 and unc["k"] >= 2.0 and "fully correlated" in unc["note"]
    ch = constructed_characteristics("d", result.summary(), None)[0]
    assert ch.uncertainty == pytest.approx(unc["U"])
    feats[1].budget = None  # a fit without a budget: the reason, not a blank
    result, _ = construct_pair("distance", feats[0], feats[1], None, False)
    assert "second feature has no uncertainty budget" in result.summary()["uncertainty"]["why"]
