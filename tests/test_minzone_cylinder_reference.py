"""The minimum-zone cylinder solver (constraint-generation SLP, the proof's linear programs straight to HiGHS)
reaches a zone no wider than a plain Nelder-Mead over the axis, on seeded point sets: full cylinders and a band
shorter than its diameter (a short band: the axis held near the least-squares one)."""

from __future__ import annotations

import numpy as np
import pytest

import knownanswer as ka
from minzone_reference import nelder_mead_zone

from cmm.metrology import fit_criteria, lp_small
from cmm.metrology.fit_chebyshev import _lp_rows, _lp_step

FAR = np.array([1000.0, -400.0, 300.0])
AXIS = np.array([0.3, -0.5, 0.81])


@pytest.mark.parametrize("seed,radius,length,m", [(0, 8.0, 40.0, 600), (1, 8.0, 40.0, 1500), (2, 20.0, 40.0, 800),
                                                  (3, 20.0, 15.0, 800)])
def test_zone_no_wider_than_nelder_mead(seed, radius, length, m):
    data = ka.cylinder(FAR, AXIS, radius, m=m, length=length, form=0.01, seed=seed)
    res = fit_criteria.fit("cylinder", data.points, "minzone")
    cone = res.proof["cone_deg"] if res.proof else 0.25
    reference = nelder_mead_zone(data.points, cone)
    assert res.form <= reference + 1e-9
    # the form is the zone of every point about the reported axis (not of a subset)
    x = data.points - res.point
    r = np.linalg.norm(x - np.outer(x @ res.direction, res.direction), axis=1)
    assert np.ptp(r) == pytest.approx(res.form, abs=1e-9)
    if length >= radius:  # the full cylinders: proven as before
        assert res.proof["proven"] and not res.warnings


def test_constraint_generation_step_equals_the_program_on_every_point():
    """An SLP step from the points with the largest residuals, violators added, is the step of the program
    on every point (same optimum)."""
    rng = np.random.default_rng(4)
    jac = rng.normal(size=(3000, 5))  # above GENERATE_ABOVE: generated
    jac[:, -1] = -1.0  # the radius column: a residual is distance - radius
    d = rng.normal(scale=0.01, size=3000)
    for criterion in ("minzone", "mcc", "mic"):
        step = _lp_step(d, jac, criterion, 0.05)
        full = lp_small.solve(*_lp_rows(d, jac, criterion, 0.05))
        lin, lin_full = d + jac @ step, d + jac @ full.x[:5]
        if criterion == "minzone":
            assert np.abs(lin).max() == pytest.approx(np.abs(lin_full).max(), rel=1e-9, abs=1e-12)
        else:  # mcc / mic: the radius step (last) optimal and every point feasible
            assert step[-1] == pytest.approx(full.x[4], rel=1e-9, abs=1e-12)
            assert (lin.max() if criterion == "mcc" else -lin.min()) <= 1e-9
